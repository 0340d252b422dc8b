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
    /// `image_io::load_image` on the scan texture formats: BMP (plain and RLE), TGA (plain and RLE), WebP
    /// (lossless and lossy).
    ScanImage,
    /// `mesh_io::read_mesh` on an `.obj` with its `.mtl` and a BMP, TGA or WebP `map_Kd` texture.
    ObjTextures,
    /// `mesh_io::read_mesh` on a `.gltf` with an external buffer and a BMP, TGA or WebP texture.
    GltfTextures,
    /// `mesh_io::read_mesh` on a `.ply` (ASCII, binary little and big endian; colours, UVs per vertex or per
    /// face corner, a `TextureFile`).
    Ply,
}

impl Target {
    /// Every target, in report order.
    pub const ALL: [Target; 13] = [
        Target::Image,
        Target::Mask,
        Target::Panorama,
        Target::Gltf,
        Target::Glb,
        Target::Obj,
        Target::Npy,
        Target::Model,
        Target::Ffprobe,
        Target::ScanImage,
        Target::ObjTextures,
        Target::GltfTextures,
        Target::Ply,
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
            Target::ScanImage => "scan_image",
            Target::ObjTextures => "obj_textures",
            Target::GltfTextures => "gltf_textures",
            Target::Ply => "ply",
        }
    }

    /// The target called `name`.
    pub fn from_name(name: &str) -> Option<Target> {
        Target::ALL.into_iter().find(|t| t.name() == name)
    }

    /// The files of one input, the loaded one first. Image-like targets name their file after its content and
    /// a texture (`skin.*`) takes the name its mesh or material file gives it (see [`Case::from_bytes`]), so
    /// this is the default only.
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
            Target::ScanImage => &["photo.tga"],
            Target::ObjTextures => &["mesh.obj", "mesh.mtl", "skin.png"],
            Target::GltfTextures => &["mesh.gltf", "mesh.bin", "skin.png"],
            Target::Ply => &["mesh.ply", "skin.png"],
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
        match target {
            Target::Image => files[0].0 = format!("photo.{}", sniff_extension(&files[0].1).unwrap_or("png")),
            Target::Panorama => files[0].0 = format!("panorama.{}", sniff_extension(&files[0].1).unwrap_or("png")),
            // TGA is the one format without a signature.
            Target::ScanImage => files[0].0 = format!("photo.{}", sniff_extension(&files[0].1).unwrap_or("tga")),
            _ => {}
        }
        // A texture is called what the file that uses it calls it (`skin.bmp` in an MTL's `map_Kd`), so the
        // extension tells the loader the format where the content cannot (TGA).
        if let Some(k) = files.iter().position(|(n, _)| n.starts_with("skin.")) {
            let named = files.iter().take(k).find_map(|(_, b)| referenced_texture_extension(b));
            if let Some(ext) = named {
                files[k].0 = format!("skin.{ext}");
            }
        }
        Case { files }
    }

    /// The texture file of the input (`skin.*`), if it has one.
    pub fn texture(&self) -> Option<&(String, Vec<u8>)> {
        self.files.iter().find(|(n, _)| n.starts_with("skin."))
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

/// The extension a user's file with these bytes would most likely have (the panorama loader decides HDR by it,
/// TGA has no signature), `None` when the bytes start with no known signature.
fn sniff_extension(bytes: &[u8]) -> Option<&'static str> {
    let signatures: [(&[u8], &str); 6] = [
        (b"\x89PNG", "png"),
        (&[0xFF, 0xD8], "jpg"),
        (b"#?", "hdr"),
        (b"GIF8", "gif"),
        (b"BM", "bmp"),
        (b"RIFF", "webp"),
    ];
    signatures.iter().find(|(magic, _)| bytes.starts_with(magic)).map(|(_, ext)| *ext)
}

/// Texture extensions a fuzz input's mesh or material file may give its `skin.*` texture.
const TEXTURE_EXTENSIONS: [&str; 7] = ["png", "jpg", "jpeg", "bmp", "tga", "webp", "gif"];

/// The extension of the first `skin.EXT` this file names, when it is a texture extension.
fn referenced_texture_extension(bytes: &[u8]) -> Option<&'static str> {
    let at = find(bytes, b"skin.")? + 5;
    let ext: Vec<u8> = bytes[at..].iter().take_while(|b| b.is_ascii_alphanumeric()).take(5).copied().collect();
    let ext = std::str::from_utf8(&ext).ok()?.to_ascii_lowercase();
    TEXTURE_EXTENSIONS.into_iter().find(|e| *e == ext)
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

/// One libFuzzer iteration (the `cargo fuzz` targets in `fuzz/`): runs `target` on `data` in a work folder of
/// this process under the system's temporary folder; a property violation panics, which libFuzzer reports as a
/// crash (as it does a panic inside the loader). Time and memory bounds are libFuzzer's (`-timeout`,
/// `-rss_limit_mb`, `-malloc_limit_mb`).
pub fn fuzz_one(target: Target, data: &[u8]) {
    let dir = std::env::temp_dir().join(format!("r2human-fuzz-{}-{}", target.name(), std::process::id()));
    if let Err(violation) = run(target, data, &dir) {
        panic!("{}: {violation}", target.name());
    }
}

/// libFuzzer's custom mutator hook (`fuzz_mutator!`): applies [`mutate`] to the first `size` bytes of `data`
/// (structure-aware: GLB containers rebuilt, PNG checksums repaired, dictionary tokens, numbers out of range),
/// and returns the new size, at most `max_size` (the tail is cut).
pub fn mutate_in_place(target: Target, data: &mut [u8], size: usize, max_size: usize, seed: u64) -> usize {
    let mut bytes = data[..size.min(data.len())].to_vec();
    mutate(target, &mut bytes, &[], &mut Rng::new(seed));
    let n = bytes.len().min(max_size).min(data.len());
    data[..n].copy_from_slice(&bytes[..n]);
    n
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
        Target::Image | Target::ScanImage => image_io::load_image(path).map(drop).map_err(err),
        Target::Mask => image_io::load_mask(path, MASK_SIZE.0, MASK_SIZE.1).map(drop).map_err(err),
        Target::Panorama => Environment::load(path).map(drop).map_err(err),
        Target::Gltf | Target::Glb | Target::Obj | Target::ObjTextures | Target::GltfTextures | Target::Ply => {
            mesh_io::read_mesh(path).map(drop).map_err(err)
        }
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
        Target::Gltf => vec![gltf_parts(Some(Texture::Embedded), false), gltf_parts(None, true)],
        Target::Obj => vec![obj_parts(Some(("png", png_texture()))), obj_parts(None)],
        Target::Npy => npy_seeds(),
        Target::Model => onnx_fixtures(root),
        Target::Ffprobe => FFPROBE_SEEDS.iter().map(|s| s.as_bytes().to_vec()).collect(),
        Target::ScanImage => scan_textures(root).into_iter().map(|(_, bytes)| bytes).collect(),
        Target::ObjTextures => scan_textures(root).into_iter().map(|t| obj_parts(Some(t))).collect(),
        Target::GltfTextures => scan_textures(root)
            .into_iter()
            .enumerate()
            .map(|(i, (ext, bytes))| gltf_parts(Some(Texture::File(ext, bytes)), i % 2 == 1))
            .collect(),
        Target::Ply => ply_seeds(),
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
        Target::Gltf | Target::Glb | Target::GltfTextures => &[
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
        Target::Obj | Target::ObjTextures => &[
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
        Target::ScanImage => {
            &["BM", "RIFF", "WEBP", "VP8 ", "VP8L", "VP8X", "ALPH", "ANIM", "ANMF", "ICCP", "TRUEVISION-XFILE.\0"]
        }
        Target::Ply => &[
            "element vertex 4294967295\n",
            "element face 2147483648\n",
            "element vertex 0\n",
            "property list uchar int vertex_indices\n",
            "property list uint uint vertex_indices\n",
            "property list int int vertex_indices\n",
            "property list uchar float texcoord\n",
            "property float x\n",
            "property double s\n",
            "property uchar red\n",
            "format binary_big_endian 1.0\n",
            "format binary_little_endian 1.0\n",
            "format ascii 1.0\n",
            "comment TextureFile skin.png\n",
            "comment TextureFile ../skin.png\n",
            "obj_info TextureFile skin.bmp\n",
            "end_header\n",
            "255 ",
            "nan ",
            "-1 ",
            "1025 ",
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

/// The texture of a `.gltf` seed.
enum Texture {
    /// The box's own PNG (taken out of its GLB).
    Embedded,
    /// This file (extension, bytes).
    File(&'static str, Vec<u8>),
}

/// A `.gltf` + `.bin` (+ texture) of the box: the buffer and texture as external files; `hierarchy` adds a
/// parent node with a transform.
fn gltf_parts(texture: Option<Texture>, hierarchy: bool) -> Vec<u8> {
    let (mut json, bin) = glb_chunks(&glb(texture.is_some()));
    json["buffers"][0]["uri"] = serde_json::json!("mesh.bin");
    let mut skin = Vec::new();
    if let Some(texture) = texture {
        let ext = match texture {
            Texture::Embedded => {
                let view = json["images"][0]["bufferView"].as_u64().expect("image view") as usize;
                let v = &json["bufferViews"][view];
                let (off, len) =
                    (v["byteOffset"].as_u64().unwrap() as usize, v["byteLength"].as_u64().unwrap() as usize);
                skin = bin[off..off + len].to_vec();
                "png"
            }
            Texture::File(ext, bytes) => {
                skin = bytes;
                ext
            }
        };
        json["images"] = serde_json::json!([{ "uri": format!("skin.{ext}") }]);
    }
    if hierarchy {
        json["nodes"] = serde_json::json!([
            {"mesh": 0, "name": "subject", "translation": [0.0, 0.1, 0.0]},
            {"name": "root", "children": [0], "rotation": [0.0, 0.382_683_43, 0.0, 0.923_879_5], "scale": [1.0, 2.0, 1.0]}
        ]);
        json["scenes"] = serde_json::json!([{"nodes": [1]}]);
    }
    let text = serde_json::to_vec_pretty(&json).expect("JSON");
    Case { files: vec![("mesh.gltf".into(), text), ("mesh.bin".into(), bin), ("skin.png".into(), skin)] }.to_bytes()
}

/// An `.obj` of the box; with a texture (extension, bytes), also its `.mtl` and the texture.
fn obj_parts(texture: Option<(&str, Vec<u8>)>) -> Vec<u8> {
    let textured = texture.is_some();
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
    let Some((ext, tex)) = texture else { return obj.into_bytes() };
    let mtl = format!("newmtl skin\nKd 0.8 0.6 0.5\nmap_Kd -s 1 1 1 skin.{ext}\n");
    let name = format!("skin.{ext}");
    Case { files: vec![("mesh.obj".into(), obj.into_bytes()), ("mesh.mtl".into(), mtl.into_bytes()), (name, tex)] }
        .to_bytes()
}

/// The 8x8 PNG texture of the OBJ seed.
fn png_texture() -> Vec<u8> {
    png(rgb_pattern(8, 8), image::ExtendedColorType::Rgb8)
}

/// Small files of the scan texture formats, with their extension: BMP (24-bit, 8-bit palette, 32-bit, RLE8 with
/// every escape), TGA (RLE and plain, colour and grey), lossless WebP (made here), and the lossy WebPs of
/// `tests/corpus/scan_image/` (made with ffmpeg's libwebp; this crate's encoder writes lossless only).
fn scan_textures(root: &Path) -> Vec<(&'static str, Vec<u8>)> {
    use image::codecs::{bmp::BmpEncoder, tga::TgaEncoder, webp::WebPEncoder};
    use image::{ExtendedColorType as C, ImageEncoder};
    let encode = |f: &dyn Fn(&mut Vec<u8>) -> image::ImageResult<()>| {
        let mut out = Vec::new();
        f(&mut out).expect("encoding a small texture in memory");
        out
    };
    let (rgb, w, h) = rgb_pattern(12, 8);
    let (rgba, wa, ha) = rgba_pattern(10, 6);
    let (gray, wg, hg) = gray_pattern(9, 7);
    let mut out = vec![
        ("bmp", encode(&|o| BmpEncoder::new(o).write_image(&rgb, w, h, C::Rgb8))),
        ("bmp", encode(&|o| BmpEncoder::new(o).write_image(&gray, wg, hg, C::L8))),
        ("bmp", encode(&|o| BmpEncoder::new(o).write_image(&rgba, wa, ha, C::Rgba8))),
        ("bmp", bmp_rle8()),
        ("tga", encode(&|o| TgaEncoder::new(o).write_image(&rgb, w, h, C::Rgb8))),
        ("tga", encode(&|o| TgaEncoder::new(o).disable_rle().write_image(&rgba, wa, ha, C::Rgba8))),
        ("tga", encode(&|o| TgaEncoder::new(o).write_image(&gray, wg, hg, C::L8))),
        ("webp", encode(&|o| WebPEncoder::new_lossless(o).write_image(&rgb, w, h, C::Rgb8))),
        ("webp", encode(&|o| WebPEncoder::new_lossless(o).write_image(&rgba, wa, ha, C::Rgba8))),
    ];
    let dir = root.join("tests/corpus/scan_image");
    for name in ["lossy.webp", "lossy-alpha.webp"] {
        if let Ok(bytes) = std::fs::read(dir.join(name)) {
            out.push(("webp", bytes));
        }
    }
    out
}

/// A 16x6 8-bit BMP compressed with RLE8, using encoded runs, an absolute run, end of line, a delta and end of
/// bitmap (the rows it skips stay unset).
fn bmp_rle8() -> Vec<u8> {
    let palette: [[u8; 4]; 4] = [[0, 0, 0, 0], [40, 80, 200, 0], [200, 120, 40, 0], [90, 200, 90, 0]];
    let data: &[u8] = &[
        16, 1, 0, 0, // row 0: 16 x colour 1, end of line
        4, 2, 0, 6, 1, 2, 3, 1, 2, 3, 6, 3, 0, 0, // row 1: run, absolute run of 6, run
        0, 2, 3, 1, 8, 2, 0, 0, // row 2: delta (3 right, 1 up), run of 8
        10, 3, 0, 1, // row 4: run, end of bitmap (row 5 unset)
    ];
    let offset = 14 + 40 + palette.len() * 4;
    let mut out = Vec::new();
    out.extend_from_slice(b"BM");
    out.extend_from_slice(&((offset + data.len()) as u32).to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    out.extend_from_slice(&(offset as u32).to_le_bytes());
    for v in [40u32, 16, 6] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&1u16.to_le_bytes()); // planes
    out.extend_from_slice(&8u16.to_le_bytes()); // bits per pixel
    for v in [1u32, data.len() as u32, 2835, 2835, palette.len() as u32, 0] {
        out.extend_from_slice(&v.to_le_bytes()); // BI_RLE8, data size, resolution, colours used, important
    }
    out.extend(palette.iter().flatten());
    out.extend_from_slice(data);
    out
}

/// PLY files of the box: ASCII with 8-bit colours and quads; binary little endian with float UVs per vertex and
/// a PNG `TextureFile`; binary big endian with per-corner `texcoord` lists, 16-bit colours and a BMP texture;
/// ASCII with float colours and a vertex element property the reader skips.
fn ply_seeds() -> Vec<Vec<u8>> {
    let mesh = box_mesh(true).mesh;
    let (png_tex, bmp_tex) = (png_texture(), scan_textures(Path::new(""))[0].1.clone());
    let quads: Vec<[u32; 4]> = mesh.triangles.chunks(2).map(|q| [q[0][0], q[0][1], q[0][2], q[1][2]]).collect();
    let n = mesh.positions.len();
    let mut out = Vec::new();

    // ASCII, uchar colours, quads.
    let mut a = format!(
        "ply\nformat ascii 1.0\ncomment box\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float \
         z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nelement face {}\nproperty list uchar int \
         vertex_indices\nend_header\n",
        quads.len()
    );
    for (i, p) in mesh.positions.iter().enumerate() {
        a.push_str(&format!("{} {} {} {} {} {}\n", p.x, p.y, p.z, i * 10 % 256, 128, 255 - i * 7 % 256));
    }
    for q in &quads {
        a.push_str(&format!("4 {} {} {} {}\n", q[0], q[1], q[2], q[3]));
    }
    out.push(a.into_bytes());

    // Binary little endian: float x y z s t, uint index lists, a PNG texture.
    let mut b = format!(
        "ply\nformat binary_little_endian 1.0\ncomment TextureFile skin.png\nelement vertex {n}\nproperty float \
         x\nproperty float y\nproperty float z\nproperty float s\nproperty float t\nelement face {}\nproperty list \
         uchar uint vertex_indices\nend_header\n",
        mesh.triangles.len()
    )
    .into_bytes();
    for (p, uv) in mesh.positions.iter().zip(&mesh.uvs) {
        for v in [p.x, p.y, p.z, uv.x, 1.0 - uv.y] {
            b.extend_from_slice(&v.to_le_bytes());
        }
    }
    for t in &mesh.triangles {
        b.push(3);
        t.iter().for_each(|i| b.extend_from_slice(&i.to_le_bytes()));
    }
    out.push(Case { files: vec![("mesh.ply".into(), b), ("skin.png".into(), png_tex)] }.to_bytes());

    // Binary big endian: double x y z, ushort colours, int index lists with per-corner texcoord, a BMP texture.
    let mut c = format!(
        "ply\nformat binary_big_endian 1.0\ncomment TextureFile skin.bmp\nelement vertex {n}\nproperty double \
         x\nproperty double y\nproperty double z\nproperty ushort red\nproperty ushort green\nproperty ushort \
         blue\nelement face {}\nproperty list uchar int vertex_indices\nproperty list uchar float texcoord\n\
         end_header\n",
        mesh.triangles.len()
    )
    .into_bytes();
    for (i, p) in mesh.positions.iter().enumerate() {
        for v in [p.x, p.y, p.z] {
            c.extend_from_slice(&(v as f64).to_be_bytes());
        }
        for v in [i as u16 * 2000, 30000, 65535 - i as u16 * 1000] {
            c.extend_from_slice(&v.to_be_bytes());
        }
    }
    for t in &mesh.triangles {
        c.push(3);
        t.iter().for_each(|&i| c.extend_from_slice(&(i as i32).to_be_bytes()));
        c.push(6);
        for &i in t {
            let uv = mesh.uvs[i as usize];
            c.extend_from_slice(&uv.x.to_be_bytes());
            c.extend_from_slice(&(1.0 - uv.y).to_be_bytes());
        }
    }
    out.push(Case { files: vec![("mesh.ply".into(), c), ("skin.bmp".into(), bmp_tex)] }.to_bytes());

    // ASCII, float colours, an extra property and an edge element the reader skips.
    let mut d = format!(
        "ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\n\
         property float quality\nproperty float r\nproperty float g\nproperty float b\nelement edge 1\nproperty \
         int vertex1\nproperty int vertex2\nelement face {}\nproperty list uchar int vertex_index\nend_header\n",
        mesh.triangles.len()
    );
    for (i, p) in mesh.positions.iter().enumerate() {
        d.push_str(&format!("{} {} {} 0.5 {} 0.25 1\n", p.x, p.y, p.z, i as f32 / n as f32));
    }
    d.push_str("0 1\n");
    for t in &mesh.triangles {
        d.push_str(&format!("3 {} {} {}\n", t[0], t[1], t[2]));
    }
    out.push(d.into_bytes());
    out
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
        let case = Case::from_bytes(Target::Obj, &obj_parts(Some(("png", png_texture()))));
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
        let seed = obj_parts(Some(("png", png_texture())));
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
