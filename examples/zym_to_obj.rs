//! Converts a Nexuiz player character (a ZYMOTIC skeletal model in the game's `data.pk3`) into one textured
//! OBJ+MTL, standing, Y up and facing +z, for `r2human eval --scan` (test material of `scripts/scan-nexuiz.sh`,
//! not a product importer).
//!
//! ```text
//! cargo run --release --example zym_to_obj -- DATA_DIR CHARACTER OUT_DIR
//! ```
//! `DATA_DIR` is Debian `nexuiz-data`'s `/usr/share/games/nexuiz/data`, with the game's `data.pk3` (models) and
//! `textures.pk3` (skins), zip archives read with the `zip` crate; `CHARACTER` a player's name as in
//! `models/player/CHARACTER.txt` of `data.pk3` (its lines: the name shown, the skin's base path, the skin number,
//! the model; `models/player/CHARACTER.tga` beside it is the menu's picture of the character, not a skin). The pose is the first pose of the model's scene `idle` (the game's
//! standing animation). Writes `OUT_DIR/CHARACTER.obj`, `CHARACTER.mtl` and one PNG per shader.
//!
//! ZYMOTIC type 1 (big-endian, DarkPlaces' `model_zymotic.h`): `ZYMOTICMODEL`, int type (1: skeletal pose), file
//! size, float mins, maxs, radius, ints vertex, triangle, shader, bone and scene counts, then nine lumps (int
//! start, length from the file's start): scenes (32-byte name, mins, maxs, radius, framerate, int flags, first
//! pose, pose count), poses (per pose, per bone, a 3×4 matrix from the bone's frame to its parent's, float32 rows;
//! the root's parent is the model), bones (32-byte name, int flags, parent, -1 for a root, earlier than the bone), vertex bone counts (int per vertex), vertex influences (per vertex, its count of int bone
//! and float32 position in that bone's frame; the vertex is the mean of its influences' model positions), texture
//! coordinates (float32 s, t per vertex, t down the image), the render list (per shader an int triangle count and
//! that many triples of vertex indices), shader names (32 bytes each) and a triangle zone byte each (unused here).
//! A shader's texture is named by the skin file `MODEL_SKIN.skin` (lines `shader,texture`), else by the
//! character's skin base path: `textures/TEXTURE.tga` in `textures.pk3`, else in `data.pk3`, with the game's
//! team-colour layers `TEXTURE_shirt.tga` and `TEXTURE_pants.tga` (grey masks, black in the base skin) added in
//! [`SHIRT`] and [`PANTS`]. Nexuiz models stand Z up facing +x (Quake's axes, y to
//! the character's left); written as (y, z, x): Y up, facing +z, the character's left on +x. Read with bounds
//! checks: a short or corrupt file is an error naming the file, never a panic.

use std::io::Read;
use std::path::Path;

use anyhow::{anyhow, bail, Context, Result};
use glam::{Vec3, Vec4};

/// The colour the shirt layer's mask is drawn in (the first player's red, as MegaGlest's team colour).
const SHIRT: [f32; 3] = [1.0, 0.0, 0.0];

/// The colour the pants layer's mask is drawn in.
const PANTS: [f32; 3] = [0.2, 0.3, 0.8];

/// A big-endian reader over a file's bytes with bounds-checked reads.
struct Reader<'a> {
    data: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn at(data: &'a [u8], at: usize) -> Result<Self> {
        if at > data.len() {
            bail!("offset {at} past the end of the file ({} bytes)", data.len());
        }
        Ok(Self { data, at })
    }
    fn take(&mut self, n: usize) -> Result<&'a [u8]> {
        let end = self
            .at
            .checked_add(n)
            .filter(|&e| e <= self.data.len())
            .ok_or_else(|| anyhow!("truncated: {n} bytes at {}, the file has {}", self.at, self.data.len()))?;
        let s = &self.data[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn i32(&mut self) -> Result<i32> {
        Ok(i32::from_be_bytes(self.take(4)?.try_into()?))
    }
    /// A count or index: a non-negative int.
    fn count(&mut self) -> Result<usize> {
        let v = self.i32()?;
        usize::try_from(v).map_err(|_| anyhow!("negative count {v} at {}", self.at - 4))
    }
    fn f32(&mut self) -> Result<f32> {
        let v = f32::from_be_bytes(self.take(4)?.try_into()?);
        if !v.is_finite() {
            bail!("a non-finite float at {}", self.at - 4);
        }
        Ok(v)
    }
    fn name(&mut self) -> Result<String> {
        let raw = self.take(32)?;
        let end = raw.iter().position(|&b| b == 0).unwrap_or(raw.len());
        Ok(String::from_utf8_lossy(&raw[..end]).into_owned())
    }
    /// `n` items of `size` bytes, checked against the bytes left before allocating.
    fn check(&self, n: usize, size: usize) -> Result<()> {
        let need = n.checked_mul(size).ok_or_else(|| anyhow!("count {n} overflows"))?;
        if need > self.data.len() - self.at {
            bail!("truncated: {n} items of {size} bytes at {}, the file has {}", self.at, self.data.len());
        }
        Ok(())
    }
}

/// The lumps of the header, in file order.
const LUMPS: usize = 9;

/// One shader's triangles of the posed model.
#[derive(Debug, PartialEq)]
struct Part {
    shader: String,
    triangles: Vec<[usize; 3]>,
}

/// A ZYMOTIC model posed at the first pose of one scene: positions (Quake axes), texture coordinates (t down the
/// image, as stored) and the triangles of each shader.
#[derive(Debug)]
struct Posed {
    positions: Vec<Vec3>,
    texcoords: Vec<[f32; 2]>,
    parts: Vec<Part>,
}

/// The model in `data` at the first pose of the scene named `scene`.
fn parse_zym(data: &[u8], scene: &str) -> Result<Posed> {
    let mut r = Reader::at(data, 0)?;
    if r.take(12)? != b"ZYMOTICMODEL" {
        bail!("not a ZYMOTIC model");
    }
    let kind = r.i32()?;
    if kind != 1 {
        bail!("ZYMOTIC type {kind}; only type 1 (skeletal pose) is read");
    }
    r.take(4 + 7 * 4)?;
    let (verts, tris, shaders, bones, scenes) = (r.count()?, r.count()?, r.count()?, r.count()?, r.count()?);
    let mut lumps = [(0usize, 0usize); LUMPS];
    for l in &mut lumps {
        *l = (r.count()?, r.count()?);
    }
    let lump = |k: usize| -> Result<Reader<'_>> {
        let (start, len) = lumps[k];
        if start.checked_add(len).is_none_or(|e| e > data.len()) {
            bail!("lump {k} ({start}+{len}) past the end of the file ({} bytes)", data.len());
        }
        Reader::at(&data[..start + len], start)
    };
    // Scenes: the first pose of `scene`.
    let mut s = lump(0)?;
    let mut first = None;
    for _ in 0..scenes {
        let name = s.name()?;
        // mins, maxs, radius, framerate, flags.
        s.take(9 * 4)?;
        let (start, length) = (s.count()?, s.count()?);
        if first.is_none() && name.eq_ignore_ascii_case(scene) && length > 0 {
            first = Some(start);
        }
    }
    let pose = first.ok_or_else(|| anyhow!("no scene named {scene}"))?;
    // Bone matrices of that pose.
    let mut p = lump(1)?;
    let stride = bones.checked_mul(48).ok_or_else(|| anyhow!("{bones} bones overflow"))?;
    p.take(pose.checked_mul(stride).ok_or_else(|| anyhow!("pose {pose} overflows"))?)?;
    p.check(bones, 48)?;
    let mut b = lump(2)?;
    b.check(bones, 40)?;
    let mut matrices: Vec<[Vec4; 3]> = Vec::with_capacity(bones);
    for bone in 0..bones {
        let mut rows = [Vec4::ZERO; 3];
        for row in &mut rows {
            *row = Vec4::new(p.f32()?, p.f32()?, p.f32()?, p.f32()?);
        }
        b.take(36)?;
        let parent = b.i32()?;
        let to_model = match usize::try_from(parent) {
            Err(_) => rows,
            Ok(q) if q < bone => compose(&matrices[q], &rows),
            Ok(q) => bail!("bone {bone}'s parent {q} does not come before it"),
        };
        matrices.push(to_model);
    }
    // Vertices: the mean of their influences.
    let mut counts = lump(3)?;
    counts.check(verts, 4)?;
    let mut influences = lump(4)?;
    let mut positions = Vec::with_capacity(verts);
    for v in 0..verts {
        let n = counts.count()?;
        if n == 0 {
            bail!("vertex {v} has no bone");
        }
        influences.check(n, 16)?;
        let mut sum = Vec3::ZERO;
        for _ in 0..n {
            let b = influences.count()?;
            let m = matrices.get(b).ok_or_else(|| anyhow!("vertex {v}: bone {b} of {bones}"))?;
            let o = Vec4::new(influences.f32()?, influences.f32()?, influences.f32()?, 1.0);
            sum += Vec3::new(m[0].dot(o), m[1].dot(o), m[2].dot(o));
        }
        positions.push(sum / n as f32);
    }
    let mut t = lump(5)?;
    t.check(verts, 8)?;
    let texcoords = (0..verts).map(|_| Ok([t.f32()?, t.f32()?])).collect::<Result<Vec<_>>>()?;
    // Shader names, then each shader's triangles from the render list.
    let mut n = lump(7)?;
    n.check(shaders, 32)?;
    let names = (0..shaders).map(|_| n.name()).collect::<Result<Vec<_>>>()?;
    let mut list = lump(6)?;
    let mut parts = Vec::with_capacity(shaders);
    for shader in names {
        let count = list.count()?;
        list.check(count, 12)?;
        let mut triangles = Vec::with_capacity(count);
        for _ in 0..count {
            let t = [list.count()?, list.count()?, list.count()?];
            if let Some(&bad) = t.iter().find(|&&i| i >= verts) {
                bail!("a triangle of {shader} names vertex {bad} of {verts}");
            }
            triangles.push(t);
        }
        parts.push(Part { shader, triangles });
    }
    let total: usize = parts.iter().map(|p| p.triangles.len()).sum();
    if total != tris {
        bail!("the render list has {total} triangles, the header {tris}");
    }
    Ok(Posed { positions, texcoords, parts })
}

/// The 3×4 matrix (rows) of `a` after `b`: `a · b`, both affine.
fn compose(a: &[Vec4; 3], b: &[Vec4; 3]) -> [Vec4; 3] {
    let column = |j: usize| Vec4::new(b[0][j], b[1][j], b[2][j], if j == 3 { 1.0 } else { 0.0 });
    a.map(|row| Vec4::new(row.dot(column(0)), row.dot(column(1)), row.dot(column(2)), row.dot(column(3))))
}

/// What `models/player/CHARACTER.txt` says: the skin's base path, the skin number and the model's path.
#[derive(Debug, PartialEq)]
struct Character {
    skin_base: String,
    skin: usize,
    model: String,
}

fn parse_character(txt: &str) -> Result<Character> {
    let lines: Vec<&str> = txt.lines().map(str::trim).collect();
    let [_, base, skin, model, ..] = lines.as_slice() else {
        bail!("a character file has at least four lines (name, skin base, skin number, model)");
    };
    let skin = skin.parse().with_context(|| format!("skin number {skin:?}"))?;
    Ok(Character { skin_base: base.to_string(), skin, model: model.to_string() })
}

/// The texture (a name without extension) a skin file's lines `shader,texture` give `shader`.
fn skin_texture(skin: &str, shader: &str) -> Option<String> {
    skin.lines().find_map(|l| {
        let (s, t) = l.trim().split_once(',')?;
        s.trim().eq_ignore_ascii_case(shader).then(|| t.trim().to_string())
    })
}

/// One file of the archive, or `None` when it has no such file.
fn read_entry(pk3: &mut zip::ZipArchive<std::fs::File>, name: &str) -> Result<Option<Vec<u8>>> {
    let mut entry = match pk3.by_name(name) {
        Ok(e) => e,
        Err(zip::result::ZipError::FileNotFound) => return Ok(None),
        Err(e) => return Err(e).with_context(|| format!("{name}: cannot read")),
    };
    let mut out = Vec::new();
    entry.read_to_end(&mut out).with_context(|| format!("{name}: cannot read"))?;
    Ok(Some(out))
}

/// Quake's axes (x forward, y left, z up) to the OBJ's (Y up, facing +z, the character's left on +x).
fn to_obj_axes(p: Vec3) -> Vec3 {
    Vec3::new(p.y, p.z, p.x)
}

/// The OBJ and MTL text of `model` with one texture file per part (`None`: untextured); triangles
/// counter-clockwise seen from outside (flipped as a whole when the signed volume is negative).
fn write_obj(model: &Posed, textures: &[Option<String>], header: &str, mtl_name: &str) -> (String, String) {
    let p: Vec<Vec3> = model.positions.iter().map(|&v| to_obj_axes(v)).collect();
    let volume6: f32 = model
        .parts
        .iter()
        .flat_map(|part| part.triangles.iter().map(|t| t.map(|v| p[v])))
        .map(|[a, b, c]| a.dot(b.cross(c)))
        .sum();
    let mut obj = format!("# zym_to_obj: {header}, Y up, facing +z\nmtllib {mtl_name}\n");
    for v in &p {
        obj.push_str(&format!("v {} {} {}\n", v.x, v.y, v.z));
    }
    for [s, t] in &model.texcoords {
        obj.push_str(&format!("vt {s} {t}\n"));
    }
    let mut mtl = String::new();
    for (k, (part, texture)) in model.parts.iter().zip(textures).enumerate() {
        mtl.push_str(&format!("newmtl part{k}\nKd 1 1 1\n"));
        if let Some(t) = texture {
            mtl.push_str(&format!("map_Kd {t}\n"));
        }
        obj.push_str(&format!("o {}\nusemtl part{k}\n", part.shader));
        for t in &part.triangles {
            let t = if volume6 < 0.0 { [t[0], t[2], t[1]] } else { *t };
            let c = t.map(|v| format!("{}/{}", v + 1, v + 1));
            obj.push_str(&format!("f {} {} {}\n", c[0], c[1], c[2]));
        }
    }
    (obj, mtl)
}

/// Adds `colour` to `img` weighted by `mask`'s grey level (the game's colour map), clamped.
fn add_layer(img: &mut image::RgbImage, mask: &image::RgbImage, colour: [f32; 3]) {
    for (p, m) in img.pixels_mut().zip(mask.pixels()) {
        let w = (m[0] as f32 + m[1] as f32 + m[2] as f32) / 3.0;
        for k in 0..3 {
            p[k] = (p[k] as f32 + w * colour[k]).round().clamp(0.0, 255.0) as u8;
        }
    }
}

/// The zip archive at `path`.
fn open_pk3(path: &Path) -> Result<zip::ZipArchive<std::fs::File>> {
    let file = std::fs::File::open(path).with_context(|| format!("{}: cannot open", path.display()))?;
    zip::ZipArchive::new(file).with_context(|| format!("{}: not a zip archive", path.display()))
}

fn convert(data_dir: &Path, character: &str, out: &Path) -> Result<()> {
    let mut pk3 = open_pk3(&data_dir.join("data.pk3"))?;
    let mut skins = open_pk3(&data_dir.join("textures.pk3"))?;
    let txt_name = format!("models/player/{character}.txt");
    let txt = read_entry(&mut pk3, &txt_name)?.ok_or_else(|| anyhow!("{txt_name}: not in the archive"))?;
    let who = parse_character(&String::from_utf8_lossy(&txt)).with_context(|| txt_name.clone())?;
    let data = read_entry(&mut pk3, &who.model)?.ok_or_else(|| anyhow!("{}: not in the archive", who.model))?;
    let model = parse_zym(&data, "idle").with_context(|| who.model.clone())?;
    let skin = read_entry(&mut pk3, &format!("{}_{}.skin", who.model, who.skin))?
        .map(|s| String::from_utf8_lossy(&s).into_owned());
    let base = who.skin_base.rsplit('/').next().unwrap_or(&who.skin_base).to_string();
    std::fs::create_dir_all(out).with_context(|| format!("{}: cannot create", out.display()))?;
    let mut textures = Vec::new();
    for (k, part) in model.parts.iter().enumerate() {
        let name = skin.as_deref().and_then(|s| skin_texture(s, &part.shader)).unwrap_or_else(|| base.clone());
        let mut tga = |file: &str| -> Result<Option<image::RgbImage>> {
            let path = format!("textures/{file}.tga");
            let bytes = match read_entry(&mut skins, &path)? {
                Some(b) => b,
                None => match read_entry(&mut pk3, &path)? {
                    Some(b) => b,
                    None => return Ok(None),
                },
            };
            let img = image::load_from_memory_with_format(&bytes, image::ImageFormat::Tga)
                .with_context(|| format!("{path}: cannot decode"))?;
            Ok(Some(img.to_rgb8()))
        };
        let Some(mut img) = tga(&name)? else {
            eprintln!("{character}: textures/{name}.tga is in neither archive; part {} untextured", part.shader);
            textures.push(None);
            continue;
        };
        for (layer, colour) in [("shirt", SHIRT), ("pants", PANTS)] {
            if let Some(mask) = tga(&format!("{name}_{layer}"))?.filter(|m| m.dimensions() == img.dimensions()) {
                add_layer(&mut img, &mask, colour);
            }
        }
        let file = format!("{character}_part{k}.png");
        img.save(out.join(&file)).with_context(|| format!("{}: cannot write", out.display()))?;
        textures.push(Some(file));
    }
    let mtl_name = format!("{character}.mtl");
    let (obj, mtl) = write_obj(&model, &textures, &who.model, &mtl_name);
    std::fs::write(out.join(&mtl_name), mtl).with_context(|| format!("{}: cannot write", out.display()))?;
    std::fs::write(out.join(format!("{character}.obj")), obj)
        .with_context(|| format!("{}: cannot write", out.display()))?;
    let tris: usize = model.parts.iter().map(|p| p.triangles.len()).sum();
    eprintln!(
        "{character}: {} at idle, {} shaders, {tris} triangles -> {}",
        who.model,
        model.parts.len(),
        out.display()
    );
    Ok(())
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [data_dir, character, out] = args.as_slice() else {
        bail!("usage: zym_to_obj DATA_DIR CHARACTER OUT_DIR");
    };
    convert(Path::new(data_dir), character, Path::new(out))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn be_i(d: &mut Vec<u8>, v: i32) {
        d.extend(v.to_be_bytes());
    }
    fn be_f(d: &mut Vec<u8>, v: f32) {
        d.extend(v.to_be_bytes());
    }
    fn name32(d: &mut Vec<u8>, s: &str) {
        let mut n = s.as_bytes().to_vec();
        n.resize(32, 0);
        d.extend(n);
    }

    /// A ZYMOTIC type 1 model of one triangle, two bones and two scenes of one pose each ("walk", then "idle"):
    /// in the idle pose the root is moved by (1, 0, 0) and bone 1 (its child) by (0, 0, 10) from it; vertex 2 is
    /// half on each bone.
    fn zym() -> Vec<u8> {
        let header = 12 + 2 * 4 + 7 * 4 + 5 * 4 + LUMPS * 8;
        let mut lumps: Vec<Vec<u8>> = vec![Vec::new(); LUMPS];
        for (k, name) in ["walk", "idle"].iter().enumerate() {
            name32(&mut lumps[0], name);
            (0..8).for_each(|_| be_f(&mut lumps[0], 0.0));
            be_i(&mut lumps[0], 0);
            be_i(&mut lumps[0], k as i32);
            be_i(&mut lumps[0], 1);
        }
        for lift in [0.0f32, 10.0] {
            for bone in 0..2 {
                let (dx, dz) = if bone == 1 { (0.0, lift) } else { (lift / 10.0, 0.0) };
                for row in [[1.0, 0.0, 0.0, dx], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, dz]] {
                    row.iter().for_each(|&v| be_f(&mut lumps[1], v));
                }
            }
        }
        for (bone, parent) in [("root", -1), ("head", 0)] {
            name32(&mut lumps[2], bone);
            be_i(&mut lumps[2], 0);
            be_i(&mut lumps[2], parent);
        }
        for c in [1, 1, 2] {
            be_i(&mut lumps[3], c);
        }
        for (b, o) in [(0, [0.0, 0.0, 0.0]), (0, [1.0, 0.0, 0.0]), (0, [0.0, 1.0, 0.0]), (1, [0.0, 1.0, 0.0])] {
            be_i(&mut lumps[4], b);
            o.iter().for_each(|&v| be_f(&mut lumps[4], v));
        }
        for v in [0.0f32, 0.0, 1.0, 0.0, 0.0, 1.0] {
            be_f(&mut lumps[5], v);
        }
        for v in [1, 0, 1, 2] {
            be_i(&mut lumps[6], v);
        }
        name32(&mut lumps[7], "skin");
        lumps[8].push(0);
        let mut d = b"ZYMOTICMODEL".to_vec();
        be_i(&mut d, 1);
        be_i(&mut d, 0);
        (0..7).for_each(|_| be_f(&mut d, 0.0));
        for v in [3, 1, 1, 2, 2] {
            be_i(&mut d, v);
        }
        let mut at = header;
        for l in &lumps {
            be_i(&mut d, at as i32);
            be_i(&mut d, l.len() as i32);
            at += l.len();
        }
        lumps.iter().for_each(|l| d.extend(l));
        d
    }

    #[test]
    fn the_idle_pose_places_each_vertex_at_the_mean_of_its_bones() {
        let m = parse_zym(&zym(), "idle").unwrap();
        assert_eq!(m.positions, vec![Vec3::X, Vec3::new(2.0, 0.0, 0.0), Vec3::new(1.0, 1.0, 5.0)]);
        assert_eq!(m.texcoords, vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]);
        assert_eq!(m.parts, vec![Part { shader: "skin".into(), triangles: vec![[0, 1, 2]] }]);
        let walk = parse_zym(&zym(), "walk").unwrap();
        assert_eq!(walk.positions[2], Vec3::Y, "the other scene's pose");
        assert!(parse_zym(&zym(), "run").is_err(), "no such scene");
        let full = zym();
        assert!(parse_zym(&full[..full.len() - 5], "idle").is_err(), "truncated");
        let mut morph = zym();
        morph[15] = 0;
        assert!(parse_zym(&morph, "idle").is_err(), "type 0");
    }

    #[test]
    fn character_and_skin_files_name_the_model_and_textures() {
        let c = parse_character("Marine\nmodels/player/marine\n0\nmodels/player/marine.zym\nspecies human\n").unwrap();
        assert_eq!(
            c,
            Character { skin_base: "models/player/marine".into(), skin: 0, model: "models/player/marine.zym".into() }
        );
        assert!(parse_character("Marine\nmodels/player/marine\n").is_err());
        assert_eq!(skin_texture("femaleshock,skadi\n", "FemaleShock").as_deref(), Some("skadi"));
        assert_eq!(skin_texture("marine,marine", "other"), None);
        assert_eq!(to_obj_axes(Vec3::new(1.0, 2.0, 3.0)), Vec3::new(2.0, 3.0, 1.0), "facing +z, left on +x");
    }
}
