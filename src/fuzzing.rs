//! Fuzz targets for every file loader, shared by the stable `cargo test` harness (`tests/fuzz.rs`) and the
//! `cargo fuzz` crate (`fuzz/`, libFuzzer, nightly): the target function per loader, valid seed files, and a
//! seeded mutator. Not part of the application's API.
//!
//! A fuzz input is the bytes of one file, or for loaders that read several files (OBJ + MTL + texture, glTF +
//! buffer + texture) the files joined by [`PART_SEPARATOR`] in the order of [`Target::file_names`]. [`run`]
//! writes them into an empty folder, calls the loader on the first one and checks what can be checked from inside
//! the call: the result is `Ok` or an error whose message names one of the files, and the folder holds exactly
//! what was written (the loader wrote nothing). A panic propagates to the caller (the harness catches it, libFuzzer
//! reports it); time and memory bounds are the harness's.

use std::path::{Path, PathBuf};

use crate::capture::video;
use crate::io::{environment::Environment, image_io, mesh_io, npy::NpyArray};

/// Separates the files of a multi-file fuzz input.
pub const PART_SEPARATOR: &[u8] = b"\n%%r2human-fuzz-part%%\n";

/// Largest fuzz input the mutator produces (bytes).
pub const MAX_INPUT_LEN: usize = 1 << 20;

/// One loader under test.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Target {
    /// `image_io::load_image` (PNG, JPEG, HDR, GIF photos).
    Image,
    /// `image_io::load_mask` against a 32x48 photo.
    Mask,
    /// `Environment::load` (PNG/JPEG panoramas, Radiance `.hdr` tone-mapped).
    Panorama,
    /// `mesh_io::read_mesh` on a `.gltf` with an external buffer and texture.
    Gltf,
    /// `mesh_io::read_mesh` on a `.glb` (embedded buffer and texture).
    Glb,
    /// `mesh_io::read_mesh` on an `.obj` with its `.mtl` and `map_Kd` texture.
    Obj,
    /// `NpyArray::read`.
    Npy,
    /// The neural models' loading, metadata and signature checks (`FofNet`/`Encoder`/`Decoder::load` on ONNX
    /// Runtime).
    Model,
    /// The video reader's parsing of `ffprobe` output and the frame buffer it implies.
    Ffprobe,
}

impl Target {
    /// Every target, in report order.
    pub const ALL: [Target; 9] = [
        Target::Image,
        Target::Mask,
        Target::Panorama,
        Target::Gltf,
        Target::Glb,
        Target::Obj,
        Target::Npy,
        Target::Model,
        Target::Ffprobe,
    ];

    /// Short name (corpus folder, cargo-fuzz target name).
    pub fn name(self) -> &'static str {
        match self {
            Target::Image => "image",
            Target::Mask => "mask",
            Target::Panorama => "panorama",
            Target::Gltf => "gltf",
            Target::Glb => "glb",
            Target::Obj => "obj",
            Target::Npy => "npy",
            Target::Model => "model",
            Target::Ffprobe => "ffprobe",
        }
    }

    /// The target called `name`.
    pub fn from_name(name: &str) -> Option<Target> {
        Target::ALL.into_iter().find(|t| t.name() == name)
    }

    /// The files of one input, the loaded one first. Image-like targets name their file after its content
    /// (see [`Case::from_bytes`]), so this is the default only.
    pub fn file_names(self) -> &'static [&'static str] {
        match self {
            Target::Image => &["photo.png"],
            Target::Mask => &["mask.png"],
            Target::Panorama => &["panorama.png"],
            Target::Gltf => &["mesh.gltf", "mesh.bin", "skin.png"],
            Target::Glb => &["mesh.glb"],
            Target::Obj => &["mesh.obj", "mesh.mtl", "skin.png"],
            Target::Npy => &["array.npy"],
            Target::Model => &["model.onnx"],
            Target::Ffprobe => &["clip.mp4"],
        }
    }
}

/// The files of one fuzz input.
#[derive(Clone, Debug, PartialEq)]
pub struct Case {
    /// `(file name, bytes)`, the loaded file first.
    pub files: Vec<(String, Vec<u8>)>,
}

impl Case {
    /// Splits a fuzz input into its files (missing trailing parts are simply absent; extra parts are ignored).
    pub fn from_bytes(target: Target, data: &[u8]) -> Case {
        let names = target.file_names();
        let parts: Vec<&[u8]> =
            if names.len() == 1 { vec![data] } else { split(data, PART_SEPARATOR).take(names.len()).collect() };
        let mut files: Vec<(String, Vec<u8>)> =
            names.iter().zip(parts).map(|(n, p)| (n.to_string(), p.to_vec())).collect();
        if matches!(target, Target::Image | Target::Panorama) {
            let stem = if target == Target::Image { "photo" } else { "panorama" };
            files[0].0 = format!("{stem}.{}", sniff_extension(&files[0].1));
        }
        Case { files }
    }

    /// The fuzz input of these files (inverse of [`Case::from_bytes`]).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::new();
        for (i, (_, bytes)) in self.files.iter().enumerate() {
            if i > 0 {
                out.extend_from_slice(PART_SEPARATOR);
            }
            out.extend_from_slice(bytes);
        }
        out
    }
}

fn split<'a>(data: &'a [u8], sep: &'a [u8]) -> impl Iterator<Item = &'a [u8]> + 'a {
    let mut rest = Some(data);
    std::iter::from_fn(move || {
        let r = rest?;
        match find(r, sep) {
            Some(i) => {
                rest = Some(&r[i + sep.len()..]);
                Some(&r[..i])
            }
            None => {
                rest = None;
                Some(r)
            }
        }
    })
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    let (&first, rest) = needle.split_first()?;
    let last_start = hay.len().checked_sub(needle.len())?;
    (0..=last_start).find(|&i| hay[i] == first && &hay[i + 1..i + needle.len()] == rest)
}

/// The extension a user's file with these bytes would most likely have (the panorama loader decides HDR by it).
fn sniff_extension(bytes: &[u8]) -> &'static str {
    if bytes.starts_with(b"\x89PNG") {
        "png"
    } else if bytes.starts_with(&[0xFF, 0xD8]) {
        "jpg"
    } else if bytes.starts_with(b"#?") {
        "hdr"
    } else if bytes.starts_with(b"GIF8") {
        "gif"
    } else {
        "png"
    }
}

/// How one input ended (all of these satisfy the property).
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome {
    /// The loader accepted the input.
    Accepted,
    /// The loader refused it with this message (which names a file of the input).
    Rejected(String),
    /// The target cannot run here (e.g. no ONNX Runtime library); the reason.
    Skipped(String),
}

/// A property violation other than a panic (which propagates), a hang or excess memory (the harness's checks).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum Violation {
    /// The error message does not name any of the input's files.
    #[error("the error does not name the file: {0:?}")]
    Unnamed(String),
    /// The loader created, changed or removed files in the input's folder.
    #[error("the loader changed the folder: before {before:?}, after {after:?}")]
    Wrote {
        /// Files and sizes before the call.
        before: Vec<(String, u64)>,
        /// Files and sizes after the call.
        after: Vec<(String, u64)>,
    },
    /// The test setup failed (cannot write the input files).
    #[error("setup: {0}")]
    Setup(String),
}

/// Runs `target` on the fuzz input `data` in `dir` (created if needed and emptied first).
pub fn run(target: Target, data: &[u8], dir: &Path) -> Result<Outcome, Violation> {
    let case = Case::from_bytes(target, data);
    run_case(target, &case, dir)
}

/// Runs `target` on the files of `case` in `dir` (created if needed and emptied first).
pub fn run_case(target: Target, case: &Case, dir: &Path) -> Result<Outcome, Violation> {
    let setup = |e: std::io::Error| Violation::Setup(format!("{}: {e}", dir.display()));
    if dir.exists() {
        std::fs::remove_dir_all(dir).map_err(setup)?;
    }
    std::fs::create_dir_all(dir).map_err(setup)?;
    for (name, bytes) in &case.files {
        std::fs::write(dir.join(name), bytes).map_err(setup)?;
    }
    let before = listing(dir);
    let main = dir.join(&case.files[0].0);
    let result = load(target, &main);
    let after = listing(dir);
    if before != after {
        return Err(Violation::Wrote { before, after });
    }
    match result {
        Ok(()) => Ok(Outcome::Accepted),
        Err(Failure::Skipped(why)) => Ok(Outcome::Skipped(why)),
        Err(Failure::Error(message)) => {
            if case.files.iter().any(|(name, _)| message.contains(name.as_str())) {
                Ok(Outcome::Rejected(message))
            } else {
                Err(Violation::Unnamed(message))
            }
        }
    }
}

enum Failure {
    Error(String),
    Skipped(String),
}

fn err(e: impl std::fmt::Display) -> Failure {
    Failure::Error(e.to_string())
}

/// The mask target's expected photo size.
pub const MASK_SIZE: (usize, usize) = (32, 48);

fn load(target: Target, path: &Path) -> Result<(), Failure> {
    match target {
        Target::Image => image_io::load_image(path).map(drop).map_err(err),
        Target::Mask => image_io::load_mask(path, MASK_SIZE.0, MASK_SIZE.1).map(drop).map_err(err),
        Target::Panorama => Environment::load(path).map(drop).map_err(err),
        Target::Gltf | Target::Glb | Target::Obj => mesh_io::read_mesh(path).map(drop).map_err(err),
        Target::Npy => NpyArray::read(path).map(drop).map_err(err),
        Target::Model => load_model(path),
        Target::Ffprobe => {
            let bytes = std::fs::read(path).map_err(err)?;
            let info = video::info_from_ffprobe(path, &bytes).map_err(err)?;
            // What the reader allocates per frame once the stream is open: bounded by the size limit.
            let frame = info.frame_bytes();
            let max = (image_io::MAX_INPUT_SIDE as usize).pow(2) * 4;
            assert!(frame <= max, "{}: a {frame}-byte frame buffer passed the size check", path.display());
            Ok(())
        }
    }
}

fn load_model(path: &Path) -> Result<(), Failure> {
    use crate::neural::{environment, Decoder, Encoder, ExecutionProvider, FofNet, RuntimeOptions};
    let options = RuntimeOptions { ep: ExecutionProvider::Cpu, intra_threads: Some(1), ..Default::default() };
    environment(&options).map_err(|e| Failure::Skipped(format!("no ONNX Runtime: {e}")))?;
    let bytes = std::fs::read(path).map_err(err)?;
    // The loader a user would point at this file: by the kind its metadata claims.
    if find(&bytes, b"encoder").is_some() {
        Encoder::load(path, &options).map(drop).map_err(err)
    } else if find(&bytes, b"decoder").is_some() {
        Decoder::load(path, &options).map(drop).map_err(err)
    } else {
        FofNet::load(path, &options).map(drop).map_err(err)
    }
}

/// Files and sizes in `dir`, sorted (hidden temporary files included).
fn listing(dir: &Path) -> Vec<(String, u64)> {
    let mut out: Vec<(String, u64)> = std::fs::read_dir(dir)
        .map(|entries| {
            entries
                .filter_map(|e| e.ok())
                .map(|e| (e.file_name().to_string_lossy().into_owned(), e.metadata().map(|m| m.len()).unwrap_or(0)))
                .collect()
        })
        .unwrap_or_default();
    out.sort();
    out
}

// ------------------------------------------------------------------------------------------------------------
// Seeds: small valid files of every kind the loaders accept.
// ------------------------------------------------------------------------------------------------------------

/// Valid inputs for `target`, generated here (small, deterministic). `root` is the project folder, for seeds
/// that are files of the repository (the ONNX fixtures of `tests/data`).
pub fn seeds(target: Target, root: &Path) -> Vec<Vec<u8>> {
    match target {
        Target::Image => vec![
            png(rgba_pattern(24, 32), image::ExtendedColorType::Rgba8),
            png(rgb_pattern(16, 16), image::ExtendedColorType::Rgb8),
            png(gray_pattern(20, 12), image::ExtendedColorType::L8),
            png(gray16_pattern(8, 8), image::ExtendedColorType::L16),
            jpeg(&image::DynamicImage::ImageRgb8(rgb_pattern_img(24, 32))),
            jpeg(&image::DynamicImage::ImageLuma8(image::GrayImage::from_fn(16, 24, |c, r| {
                image::Luma([(c * 9 + r * 5) as u8])
            }))),
            hdr(16, 8),
            gif(12, 10),
        ],
        Target::Mask => vec![
            png(gray_pattern(MASK_SIZE.0 as u32, MASK_SIZE.1 as u32), image::ExtendedColorType::L8),
            png(rgba_pattern(MASK_SIZE.0 as u32, MASK_SIZE.1 as u32), image::ExtendedColorType::Rgba8),
            jpeg(&image::DynamicImage::ImageRgb8(rgb_pattern_img(MASK_SIZE.0 as u32, MASK_SIZE.1 as u32))),
        ],
        Target::Panorama => vec![
            hdr(32, 16),
            hdr(4, 2),
            png(rgb_pattern(32, 16), image::ExtendedColorType::Rgb8),
            jpeg(&image::DynamicImage::ImageRgb8(rgb_pattern_img(32, 16))),
        ],
        Target::Glb => vec![glb(true), glb(false)],
        Target::Gltf => vec![gltf_parts(true, false), gltf_parts(false, true)],
        Target::Obj => vec![obj_parts(true), obj_parts(false)],
        Target::Npy => npy_seeds(),
        Target::Model => onnx_fixtures(root),
        Target::Ffprobe => FFPROBE_SEEDS.iter().map(|s| s.as_bytes().to_vec()).collect(),
    }
}

/// Text tokens worth inserting into inputs of `target` (a dictionary, as libFuzzer's `-dict`).
pub fn dictionary(target: Target) -> &'static [&'static str] {
    match target {
        Target::Image | Target::Mask | Target::Panorama => &[
            "IHDR",
            "IDAT",
            "IEND",
            "PLTE",
            "tRNS",
            "acTL",
            "#?RADIANCE\n",
            "FORMAT=32-bit_rle_rgbe\n\n",
            "-Y ",
            " +X ",
        ],
        Target::Gltf | Target::Glb => &[
            "\"children\":[0]",
            "\"count\":4294967295",
            "\"byteOffset\":-1",
            "\"byteLength\":2147483648",
            "\"byteStride\":255",
            "\"uri\":\"../../etc/passwd\"",
            "\"uri\":\"data:application/octet-stream;base64,AAAA\"",
            "\"mode\":4",
            "\"sparse\":{\"count\":1}",
            "\"matrix\":[0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0]",
            "\"scale\":[1e39,1,1]",
            "\"componentType\":5126",
            "\"type\":\"MAT4\"",
            "\"normalized\":true",
        ],
        Target::Obj => &[
            "f -1 -2 -3\n",
            "f 0 1 2\n",
            "f 1/99 2/99 3/99\n",
            "f 4294967296 1 2\n",
            "v nan inf -inf\n",
            "v 1e39 0 0\n",
            "vt 1e39 nan\n",
            "usemtl skin\n",
            "usemtl \n",
            "mtllib mesh.mtl\n",
            "mtllib ../mesh.mtl\n",
            "map_Kd -s 1 1 1 skin.png\n",
            "map_Kd\n",
            "newmtl skin\n",
            "Kd nan 1 1\n",
        ],
        Target::Npy => &[
            "'shape': (4294967296, 4294967296), ",
            "'shape': (-1,), ",
            "'shape': ((((((((",
            "'descr': '<f8', ",
            "'descr': '>f4', ",
            "'fortran_order': True, ",
            "\u{93}NUMPY\u{3}\u{0}",
        ],
        Target::Model => &["r2human.resolution", "r2human.fof_n", "r2human.kind", "encoder", "decoder", "fof"],
        Target::Ffprobe => &[
            "\"width\": 4294967296",
            "\"height\": -1",
            "\"avg_frame_rate\": \"1/0\"",
            "\"r_frame_rate\": \"nan\"",
            "\"pix_fmt\": \"rgba\"",
            "\"streams\": {}",
            "[[[[[[[[[[[[[[[[",
        ],
    }
}

const FFPROBE_SEEDS: &[&str] = &[
    r#"{
    "programs": [

    ],
    "streams": [
        {
            "width": 640,
            "height": 480,
            "pix_fmt": "yuv420p",
            "r_frame_rate": "30000/1001",
            "avg_frame_rate": "30000/1001"
        }
    ]
}
"#,
    r#"{"programs":[],"streams":[{"width":320,"height":240,"pix_fmt":"yuva420p","r_frame_rate":"25/1","avg_frame_rate":"0/0"}]}"#,
    r#"{"streams":[{"width":16,"height":16,"pix_fmt":"rgba","r_frame_rate":"10","avg_frame_rate":"10/1"}]}"#,
];

fn rgba_pattern(w: u32, h: u32) -> (Vec<u8>, u32, u32) {
    let mut v = Vec::new();
    for r in 0..h {
        for c in 0..w {
            let inside = (c as i32 - w as i32 / 2).pow(2) * 4 + (r as i32 - h as i32 / 2).pow(2) < (h * h / 5) as i32;
            v.extend_from_slice(&[(c * 10) as u8, (r * 7) as u8, 128, if inside { 255 } else { 0 }]);
        }
    }
    (v, w, h)
}

fn rgb_pattern_img(w: u32, h: u32) -> image::RgbImage {
    image::RgbImage::from_fn(w, h, |c, r| image::Rgb([(c * 10) as u8, (r * 7) as u8, ((c ^ r) * 16) as u8]))
}

fn rgb_pattern(w: u32, h: u32) -> (Vec<u8>, u32, u32) {
    (rgb_pattern_img(w, h).into_raw(), w, h)
}

fn gray_pattern(w: u32, h: u32) -> (Vec<u8>, u32, u32) {
    let v = (0..w * h).map(|i| if (i % w) * 3 > w && (i % w) * 3 < 2 * w { 255 } else { 0 }).collect();
    (v, w, h)
}

fn gray16_pattern(w: u32, h: u32) -> (Vec<u8>, u32, u32) {
    // The PNG encoder takes 16-bit samples in native byte order.
    let v = (0..w * h).flat_map(|i| ((i * 997) as u16).to_ne_bytes()).collect();
    (v, w, h)
}

fn png((data, w, h): (Vec<u8>, u32, u32), color: image::ExtendedColorType) -> Vec<u8> {
    let mut out = Vec::new();
    let encoder = image::codecs::png::PngEncoder::new(&mut out);
    image::ImageEncoder::write_image(encoder, &data, w, h, color).expect("encoding a small PNG in memory");
    out
}

fn jpeg(img: &image::DynamicImage) -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Jpeg).expect("encoding a small JPEG in memory");
    out.into_inner()
}

fn hdr(w: u32, h: u32) -> Vec<u8> {
    let px: Vec<image::Rgb<f32>> = (0..w * h)
        .map(|i| {
            let (c, r) = ((i % w) as f32, (i / w) as f32);
            image::Rgb([0.1 + c * 0.3, 2.0 + r, 40.0 * (c + r) / (w + h) as f32])
        })
        .collect();
    let mut out = Vec::new();
    image::codecs::hdr::HdrEncoder::new(&mut out).encode(&px, w as usize, h as usize).expect("encoding a small HDR");
    out
}

fn gif(w: u32, h: u32) -> Vec<u8> {
    let img = image::DynamicImage::ImageRgba8(image::RgbaImage::from_fn(w, h, |c, r| {
        image::Rgba([(c * 20) as u8, (r * 20) as u8, 90, if c > 2 { 255 } else { 0 }])
    }));
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Gif).expect("encoding a small GIF");
    out.into_inner()
}

/// A box with per-face UVs, as a textured mesh.
fn box_mesh(textured: bool) -> mesh_io::TexturedMesh {
    use glam::{Vec2, Vec3};
    let mut positions = Vec::new();
    let mut uvs = Vec::new();
    let mut triangles = Vec::new();
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let n = Vec3::from_array(std::array::from_fn(|k| if k == axis { sign } else { 0.0 }));
            let u = Vec3::from_array(std::array::from_fn(|k| if k == (axis + 1) % 3 { 1.0 } else { 0.0 }));
            let v = n.cross(u);
            let base = positions.len() as u32;
            for (a, b) in [(-1.0f32, -1.0f32), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                positions.push(n * 0.5 + u * (0.4 * a) + v * (0.6 * b));
                uvs.push(Vec2::new((a + 1.0) * 0.5, (b + 1.0) * 0.5));
            }
            triangles.push([base, base + 1, base + 2]);
            triangles.push([base, base + 2, base + 3]);
        }
    }
    let mut mesh = crate::geometry::mesh::TriMesh::new(positions, triangles);
    if textured {
        mesh.uvs = uvs;
        let texture = image::RgbImage::from_fn(8, 8, |c, r| image::Rgb([(c * 30) as u8, (r * 30) as u8, 60]));
        mesh_io::TexturedMesh::textured(mesh, texture)
    } else {
        mesh.colors = mesh.positions.iter().map(|p| *p + Vec3::splat(0.5)).collect();
        mesh_io::TexturedMesh::untextured(mesh)
    }
}

fn glb(textured: bool) -> Vec<u8> {
    mesh_io::glb_bytes(&box_mesh(textured), Path::new("seed.glb")).expect("encoding a box as GLB")
}

/// Splits a GLB into its JSON and binary chunks.
fn glb_chunks(glb: &[u8]) -> (serde_json::Value, Vec<u8>) {
    let (json, bin) = glb_split(glb).expect("our own GLB");
    (serde_json::from_slice(&json).expect("our own GLB JSON"), bin)
}

/// A `.gltf` + `.bin` (+ `.png`) of the box: the buffer and texture as external files; `hierarchy` adds a parent
/// node with a transform.
fn gltf_parts(textured: bool, hierarchy: bool) -> Vec<u8> {
    let (mut json, bin) = glb_chunks(&glb(textured));
    json["buffers"][0]["uri"] = serde_json::json!("mesh.bin");
    let mut texture = Vec::new();
    if textured {
        let view = json["images"][0]["bufferView"].as_u64().expect("image view") as usize;
        let v = &json["bufferViews"][view];
        let (off, len) = (v["byteOffset"].as_u64().unwrap() as usize, v["byteLength"].as_u64().unwrap() as usize);
        texture = bin[off..off + len].to_vec();
        json["images"] = serde_json::json!([{"uri": "skin.png"}]);
    }
    if hierarchy {
        json["nodes"] = serde_json::json!([
            {"mesh": 0, "name": "subject", "translation": [0.0, 0.1, 0.0]},
            {"name": "root", "children": [0], "rotation": [0.0, 0.382_683_43, 0.0, 0.923_879_5], "scale": [1.0, 2.0, 1.0]}
        ]);
        json["scenes"] = serde_json::json!([{"nodes": [1]}]);
    }
    let text = serde_json::to_vec_pretty(&json).expect("JSON");
    Case { files: vec![("mesh.gltf".into(), text), ("mesh.bin".into(), bin), ("skin.png".into(), texture)] }.to_bytes()
}

fn obj_parts(textured: bool) -> Vec<u8> {
    let mesh = box_mesh(true).mesh;
    let mut obj = String::from("# box\n");
    if textured {
        obj.push_str("mtllib mesh.mtl\nusemtl skin\n");
    }
    for (i, p) in mesh.positions.iter().enumerate() {
        if textured {
            obj.push_str(&format!("v {} {} {}\n", p.x, p.y, p.z));
        } else {
            obj.push_str(&format!("v {} {} {} {} {} {}\n", p.x, p.y, p.z, (i % 3) as f32 / 2.0, 0.5, 0.25));
        }
    }
    for uv in &mesh.uvs {
        obj.push_str(&format!("vt {} {}\n", uv.x, 1.0 - uv.y));
    }
    obj.push_str("vn 0 0 1\n");
    for (k, quad) in mesh.triangles.chunks(2).enumerate() {
        let [a, b, c] = quad[0];
        let d = quad[1][2];
        if k % 2 == 0 {
            obj.push_str(&format!("f {0}/{0}/1 {1}/{1}/1 {2}/{2}/1 {3}/{3}/1\n", a + 1, b + 1, c + 1, d + 1));
        } else {
            // Negative (relative) indices.
            let n = mesh.positions.len() as i64;
            let rel = |i: u32| i as i64 - n;
            obj.push_str(&format!("f {} {} {} {}\n", rel(a), rel(b), rel(c), rel(d)));
        }
    }
    if !textured {
        return obj.into_bytes();
    }
    let mtl = "newmtl skin\nKd 0.8 0.6 0.5\nmap_Kd -s 1 1 1 skin.png\n";
    let tex = png(rgb_pattern(8, 8), image::ExtendedColorType::Rgb8);
    Case {
        files: vec![("mesh.obj".into(), obj.into_bytes()), ("mesh.mtl".into(), mtl.into()), ("skin.png".into(), tex)],
    }
    .to_bytes()
}

fn npy_seeds() -> Vec<Vec<u8>> {
    use crate::io::npy::NpyData;
    let arrays = [
        NpyArray::new(vec![4, 5], NpyData::F32((0..20).map(|i| i as f32 * 0.25 - 2.0).collect())),
        NpyArray::new(vec![3], NpyData::U8(vec![0, 128, 255])),
        NpyArray::new(vec![2, 3], NpyData::I16(vec![-32768, -1, 0, 1, 2, 32767])),
        NpyArray::new(vec![2, 2], NpyData::U16(vec![0, 1, 65534, 65535])),
        NpyArray::new(vec![2, 2, 3], NpyData::F32(vec![0.5; 12])),
    ];
    let mut out: Vec<Vec<u8>> = arrays.into_iter().map(|a| a.expect("consistent seed").to_bytes()).collect();
    // A version 2.0 header (4-byte header length).
    let header = "{'descr': '<f4', 'fortran_order': False, 'shape': (2,), }";
    let unpadded = 12 + header.len() + 1;
    let pad = (64 - unpadded % 64) % 64;
    let mut v2 = b"\x93NUMPY\x02\x00".to_vec();
    v2.extend_from_slice(&((header.len() + pad + 1) as u32).to_le_bytes());
    v2.extend_from_slice(header.as_bytes());
    v2.extend(std::iter::repeat_n(b' ', pad));
    v2.push(b'\n');
    v2.extend_from_slice(&1.5f32.to_le_bytes());
    v2.extend_from_slice(&(-3.0f32).to_le_bytes());
    out.push(v2);
    out
}

/// The small ONNX fixtures of the repository (metadata and signature variants of the three networks).
fn onnx_fixtures(root: &Path) -> Vec<Vec<u8>> {
    let mut files: Vec<PathBuf> = ["tests/data/fof_net", "tests/data/neural"]
        .iter()
        .filter_map(|d| std::fs::read_dir(root.join(d)).ok())
        .flat_map(|entries| entries.filter_map(|e| e.ok()).map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "onnx"))
        .collect();
    files.sort();
    files.iter().filter_map(|p| std::fs::read(p).ok()).collect()
}

// ------------------------------------------------------------------------------------------------------------
// The mutator.
// ------------------------------------------------------------------------------------------------------------

/// A small deterministic generator (SplitMix64): the harness's cases are reproducible from their seed.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A generator started at `seed`.
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (0 when `n` is 0).
    pub fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next_u64() % n as u64) as usize
        }
    }

    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64 * 1.0 < p
    }
}

const INTERESTING_WORDS: &[u64] = &[
    0,
    1,
    0x7F,
    0xFF,
    0x7FFF,
    0xFFFF,
    0x1_0000,
    20_000,
    100_000,
    1 << 24,
    0x7FFF_FFFF,
    0x8000_0000,
    0xFFFF_FFFF,
    0x1_0000_0000,
    u64::MAX,
];

const INTERESTING_NUMBERS: &[&str] = &[
    "0",
    "-1",
    "1",
    "-0",
    "65536",
    "2147483648",
    "4294967295",
    "4294967296",
    "18446744073709551615",
    "99999999999999999999",
    "1e39",
    "-1e39",
    "3.4028236e38",
    "1e-45",
    "nan",
    "NaN",
    "inf",
    "-inf",
    "Infinity",
];

/// Mutates a fuzz input of `target` in place: one to four stacked mutations (bit flips, interesting bytes and
/// words such as huge sizes, truncation, deletion, duplication, NaN/Inf floats in binary or text, numbers and
/// indices out of range, dictionary tokens, deep nesting, splicing with `others`). Multi-file inputs mutate one
/// of their files. PNG chunk checksums are repaired most of the time so the decoder looks past them.
pub fn mutate(target: Target, data: &mut Vec<u8>, others: &[Vec<u8>], rng: &mut Rng) {
    if target == Target::Glb && rng.chance(0.7) {
        if let Some((json, bin)) = glb_split(data) {
            // Mutate the JSON or the binary chunk and rebuild the container with consistent lengths, so the
            // mutation reaches the glTF reader instead of failing the container check.
            let mut parts = [json, bin];
            let k = rng.below(2);
            for _ in 0..1 + rng.below(4) {
                mutate_once(target, &mut parts[k], &[], rng);
            }
            *data = glb_join(&parts[0], &parts[1]);
            return;
        }
    }
    let mut case = Case::from_bytes(target, data);
    let k = rng.below(case.files.len());
    // One other input's file `k`, for splicing.
    let others_k: Vec<Vec<u8>> = match others.len() {
        0 => Vec::new(),
        n => {
            Case::from_bytes(target, &others[rng.below(n)]).files.into_iter().nth(k).map(|f| f.1).into_iter().collect()
        }
    };
    let file = &mut case.files[k].1;
    let rounds = 1 + rng.below(4);
    for _ in 0..rounds {
        mutate_once(target, file, &others_k, rng);
    }
    if file.starts_with(b"\x89PNG\r\n\x1a\n") && rng.chance(0.85) {
        fix_png_crcs(file);
    }
    file.truncate(MAX_INPUT_LEN);
    *data = case.to_bytes();
}

fn mutate_once(target: Target, data: &mut Vec<u8>, others: &[Vec<u8>], rng: &mut Rng) {
    let len = data.len();
    match rng.below(13) {
        0 => {
            for _ in 0..1 + rng.below(8) {
                if len > 0 {
                    let i = rng.below(len);
                    data[i] ^= 1 << rng.below(8);
                }
            }
        }
        1 if len > 0 => {
            let i = rng.below(len);
            data[i] = [0u8, 1, 0x7F, 0x80, 0xFF, b'0', b'9', b'-'][rng.below(8)];
        }
        2 if len > 0 => {
            // A huge (or zero) declared size: an interesting word at any offset, either byte order.
            let width = [2usize, 4, 8][rng.below(3)];
            let i = rng.below(len);
            let v = INTERESTING_WORDS[rng.below(INTERESTING_WORDS.len())];
            let bytes = if rng.chance(0.5) { v.to_le_bytes() } else { v.to_be_bytes() };
            let src = if rng.chance(0.5) { &bytes[..width] } else { &bytes[8 - width..] };
            for (j, b) in src.iter().enumerate() {
                if let Some(d) = data.get_mut(i + j) {
                    *d = *b;
                }
            }
        }
        3 if len > 0 => data.truncate(rng.below(len)),
        4 if len > 1 => {
            let a = rng.below(len);
            let b = (a + 1 + rng.below(64.min(len - a))).min(len);
            data.drain(a..b);
        }
        5 if len > 0 => {
            // Duplicate a range (repeated chunks, rows, lines).
            let a = rng.below(len);
            let b = (a + 1 + rng.below(256.min(len - a))).min(len);
            let chunk = data[a..b].to_vec();
            let at = rng.below(len + 1);
            for _ in 0..1 + rng.below(4) {
                data.splice(at..at, chunk.iter().copied());
            }
        }
        6 => {
            let at = rng.below(len + 1);
            let n = 1 + rng.below(16);
            let bytes: Vec<u8> = (0..n).map(|_| rng.next_u64() as u8).collect();
            data.splice(at..at, bytes);
        }
        7 => replace_number(data, rng),
        8 if len >= 4 => {
            // NaN/Inf/extreme floats in binary data (npy payloads, glTF buffers, HDR pixels).
            let i = rng.below(len - 3) & !3;
            let f = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, f32::MAX, -f32::MAX, 1e-45, -0.0][rng.below(7)];
            data[i..i + 4].copy_from_slice(&f.to_le_bytes());
        }
        9 => {
            let dict = dictionary(target);
            if !dict.is_empty() {
                let tok = dict[rng.below(dict.len())].as_bytes();
                let at = rng.below(len + 1);
                data.splice(at..at, tok.iter().copied());
            }
        }
        10 => {
            // Deep nesting: thousands of open brackets / repeated statements.
            let n = 100 + rng.below(50_000);
            let unit: &[u8] = match target {
                Target::Obj => b"usemtl m\n",
                Target::Npy => b"(",
                _ if rng.chance(0.5) => b"[",
                _ => b"{\"a\":",
            };
            let at = rng.below(len + 1);
            let nested: Vec<u8> = unit.iter().copied().cycle().take(unit.len() * n).collect();
            data.splice(at..at, nested);
        }
        11 if !others.is_empty() => {
            let other = &others[rng.below(others.len())];
            let a = rng.below(len + 1);
            let b = rng.below(other.len() + 1);
            data.truncate(a);
            data.extend_from_slice(&other[b..]);
        }
        _ => {
            if len > 0 {
                let i = rng.below(len);
                data[i] = rng.next_u64() as u8;
            }
        }
    }
}

/// The JSON and BIN chunk payloads of a GLB whose container is intact (no BIN chunk: empty).
fn glb_split(glb: &[u8]) -> Option<(Vec<u8>, Vec<u8>)> {
    let chunks = mesh_io::glb_chunks(glb).ok()?;
    Some((chunks.json.to_vec(), chunks.bin.unwrap_or_default().to_vec()))
}

/// A GLB container around a JSON and a BIN chunk (none when `bin` is empty).
fn glb_join(json: &[u8], bin: &[u8]) -> Vec<u8> {
    mesh_io::glb_container(json, (!bin.is_empty()).then_some(bin)).expect("a fuzz input is far below 4 GiB")
}

/// Replaces one ASCII number in the data by an interesting one (huge, negative, NaN, an index one past).
fn replace_number(data: &mut Vec<u8>, rng: &mut Rng) {
    let is_num = |b: u8| b.is_ascii_digit() || b == b'.' || b == b'-' || b == b'+' || b == b'e' || b == b'E';
    let mut spans = Vec::new();
    let mut i = 0;
    while i < data.len() && spans.len() < 4096 {
        if data[i].is_ascii_digit() {
            let mut a = i;
            while a > 0 && is_num(data[a - 1]) && data[a - 1] != b'e' && data[a - 1] != b'E' {
                a -= 1;
            }
            let mut b = i;
            while b < data.len() && is_num(data[b]) {
                b += 1;
            }
            spans.push((a, b));
            i = b;
        } else {
            i += 1;
        }
    }
    if spans.is_empty() {
        return;
    }
    let (a, b) = spans[rng.below(spans.len())];
    let replacement = if rng.chance(0.25) {
        // An index one past (or before) its neighbour: off-by-one out of range.
        let old: i64 = std::str::from_utf8(&data[a..b]).ok().and_then(|s| s.parse().ok()).unwrap_or(0);
        (old + [1i64, -1, 2, 1000][rng.below(4)]).to_string()
    } else {
        INTERESTING_NUMBERS[rng.below(INTERESTING_NUMBERS.len())].to_string()
    };
    data.splice(a..b, replacement.into_bytes());
}

/// Recomputes every chunk CRC of a PNG (walking the chunk lengths as declared; stops at the first inconsistent
/// one), so mutations of chunk data reach the decoder instead of failing the checksum.
pub fn fix_png_crcs(data: &mut [u8]) {
    let mut at = 8;
    while at + 12 <= data.len() {
        let n = u32::from_be_bytes([data[at], data[at + 1], data[at + 2], data[at + 3]]) as usize;
        let Some(end) = at.checked_add(8 + n).filter(|&e| e + 4 <= data.len()) else { break };
        let crc = crate::io::image_io::crc32(&data[at + 4..end]);
        data[end..end + 4].copy_from_slice(&crc.to_be_bytes());
        at = end + 4;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cases_round_trip_through_bytes() {
        let case = Case::from_bytes(Target::Obj, &obj_parts(true));
        assert_eq!(case.files.len(), 3);
        assert_eq!(case.files[1].0, "mesh.mtl");
        assert!(case.files[1].1.starts_with(b"newmtl"));
        assert_eq!(Case::from_bytes(Target::Obj, &case.to_bytes()), case);
        // A separator destroyed by a mutation: fewer files, never a panic.
        assert_eq!(Case::from_bytes(Target::Obj, b"v 1 2 3").files.len(), 1);
        assert_eq!(Case::from_bytes(Target::Image, &hdr(4, 2)).files[0].0, "photo.hdr");
        // A GLB splits into its chunks and joins back byte for byte.
        let g = glb(true);
        let (json, bin) = glb_split(&g).unwrap();
        assert_eq!(glb_join(&json, &bin), g);
    }

    #[test]
    fn crc_matches_the_png_standard() {
        // CRC-32 of "IEND" (every PNG ends with it): AE 42 60 82.
        assert_eq!(crate::io::image_io::crc32(b"IEND"), 0xAE42_6082);
        let mut p = png(rgb_pattern(4, 4), image::ExtendedColorType::Rgb8);
        let good = p.clone();
        p[29] ^= 0xFF; // the IHDR CRC
        fix_png_crcs(&mut p);
        assert_eq!(p, good);
    }

    #[test]
    fn mutations_are_deterministic_and_change_the_input() {
        let seed = obj_parts(true);
        let run = |s: u64| {
            let mut rng = Rng::new(s);
            let mut d = seed.clone();
            mutate(Target::Obj, &mut d, &[], &mut rng);
            d
        };
        assert_eq!(run(7), run(7));
        let changed = (0..50).filter(|&s| run(s) != seed).count();
        assert!(changed >= 45, "{changed} of 50 mutations changed the input");
    }
}
