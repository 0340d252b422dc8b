//! Converts a UFO: Alien Invasion character (an MD2 body and an MD2 head joined by the body's `tag_head`) into one
//! textured OBJ+MTL, standing, Y up and facing +z, for `r2human eval --scan` (test material of
//! `scripts/scan-check.sh`, not a product importer).
//!
//! ```text
//! cargo run --release --example md2_to_obj -- PK3 BODY HEAD NAME OUT_DIR
//! ```
//! `PK3` is Debian `ufoai-data`'s `0models.pk3` (a zip); `BODY` and `HEAD` are paths inside it without `.md2`
//! (e.g. `models/civilians/female/body01` and `models/civilians/female/head01a`). Writes `OUT_DIR/NAME.obj`,
//! `NAME.mtl` and the two textures.
//!
//! The pose is the body's `stand_menu` frame (the standing pose the game's menus show), read from `BODY.anm`
//! (`name first last fps` lines). The head is placed by `tag_head` at that frame from `BODY.tag` (UFO:AI's `JDP2`
//! tag file: a header of 8 int32 — magic, version, tags, frames, offsets of names, tags, end, extract end — then
//! 64-byte names, then per tag (tag-major) per frame 12 floats: the child's x, y, z axes and the origin). A part's
//! texture is its MD2's first skin name (`.NAME`: NAME in the model's folder) as `.jpg`, `.png` or `.tga`.
//!
//! MD2 is a small fixed-layout little-endian format (header of 17 int32, skins, texture coordinates in pixels,
//! triangles of vertex and texture indices, frames of a scale, a translation, a name and one byte per axis per
//! vertex), read here with bounds checks: a short or corrupt file is an error naming the file, never a panic.

use std::io::Read;
use std::path::Path;

use anyhow::{anyhow, bail, Context, Result};
use glam::Vec3;

/// A little-endian view of a file's bytes with bounds-checked reads.
struct Le<'a>(&'a [u8]);

impl Le<'_> {
    fn at(&self, at: usize, n: usize) -> Result<&[u8]> {
        at.checked_add(n)
            .and_then(|end| self.0.get(at..end))
            .ok_or_else(|| anyhow!("truncated: {n} bytes at {at}, the file has {}", self.0.len()))
    }
    fn word(&self, at: usize) -> Result<[u8; 4]> {
        Ok(self.at(at, 4)?.try_into()?)
    }
    fn usize(&self, at: usize) -> Result<usize> {
        let v = i32::from_le_bytes(self.word(at)?);
        usize::try_from(v).map_err(|_| anyhow!("negative count or offset {v} at {at}"))
    }
    fn f32(&self, at: usize) -> Result<f32> {
        Ok(f32::from_le_bytes(self.word(at)?))
    }
    fn u16(&self, at: usize) -> Result<usize> {
        Ok(u16::from_le_bytes(self.at(at, 2)?.try_into()?) as usize)
    }
    fn vec3(&self, at: usize) -> Result<Vec3> {
        Ok(Vec3::new(self.f32(at)?, self.f32(at + 4)?, self.f32(at + 8)?))
    }
}

/// One MD2 frame as triangles with texture coordinates (0..1, t down the image).
#[derive(Debug, Default)]
struct Mesh {
    positions: Vec<Vec3>,
    texcoords: Vec<[f32; 2]>,
    /// Per triangle, (position index, texcoord index) at each corner.
    triangles: Vec<[(usize, usize); 3]>,
    /// The first skin name, as written (empty when the file names none).
    skin: String,
}

/// Reads frame `frame` of an MD2 file (`IDP2`, version 8).
fn parse_md2(data: &[u8], frame: usize) -> Result<Mesh> {
    let r = Le(data);
    if r.at(0, 4)? != b"IDP2" || r.usize(4)? != 8 {
        bail!("not an MD2 version 8 (no IDP2 magic)");
    }
    let h = |k: usize| r.usize(8 + 4 * k);
    let (skin_w, skin_h, frame_size) = (h(0)? as f32, h(1)? as f32, h(2)?);
    let (num_skins, num_xyz, num_st, num_tris, num_frames) = (h(3)?, h(4)?, h(5)?, h(6)?, h(8)?);
    let (ofs_skins, ofs_st, ofs_tris, ofs_frames) = (h(9)?, h(10)?, h(11)?, h(12)?);
    let skin = if num_skins > 0 {
        let b = r.at(ofs_skins, 64)?;
        String::from_utf8_lossy(b.split(|&c| c == 0).next().unwrap_or_default()).into_owned()
    } else {
        String::new()
    };
    if frame >= num_frames {
        bail!("frame {frame} asked, the file has {num_frames}");
    }
    if skin_w <= 0.0 || skin_h <= 0.0 {
        bail!("skin size {skin_w} x {skin_h}");
    }
    let texcoords = (0..num_st)
        .map(|i| Ok([r.u16(ofs_st + 4 * i)? as f32 / skin_w, r.u16(ofs_st + 4 * i + 2)? as f32 / skin_h]))
        .collect::<Result<Vec<_>>>()?;
    let f = ofs_frames + frame * frame_size;
    let (scale, translate) = (r.vec3(f)?, r.vec3(f + 12)?);
    let bytes = r.at(f + 40, 4 * num_xyz)?;
    let positions = (0..num_xyz)
        .map(|i| Vec3::new(bytes[4 * i] as f32, bytes[4 * i + 1] as f32, bytes[4 * i + 2] as f32) * scale + translate)
        .collect();
    let mut triangles = Vec::with_capacity(num_tris);
    for t in 0..num_tris {
        let at = ofs_tris + 12 * t;
        let corner = |k: usize| -> Result<(usize, usize)> {
            let (v, s) = (r.u16(at + 2 * k)?, r.u16(at + 6 + 2 * k)?);
            if v >= num_xyz || s >= num_st {
                bail!("triangle {t} points past the vertices ({v} of {num_xyz}) or texcoords ({s} of {num_st})");
            }
            Ok((v, s))
        };
        triangles.push([corner(0)?, corner(1)?, corner(2)?]);
    }
    Ok(Mesh { positions, texcoords, triangles, skin })
}

/// The first frame of animation `name` in an `.anm` text (`name first last fps` per line, `//` comments).
fn anim_first_frame(anm: &str, name: &str) -> Result<usize> {
    anm.lines()
        .map(|l| l.split("//").next().unwrap_or("").split_whitespace().collect::<Vec<_>>())
        .find(|w| w.first() == Some(&name))
        .and_then(|w| w.get(1).and_then(|v| v.parse().ok()))
        .ok_or_else(|| anyhow!("no animation {name:?} with a first frame"))
}

/// The placement of tag `name` at `frame` of a `JDP2` tag file: (origin, the child's x, y, z axes, normalised).
fn parse_tag(data: &[u8], name: &str, frame: usize) -> Result<(Vec3, [Vec3; 3])> {
    let r = Le(data);
    if r.at(0, 4)? != b"JDP2" {
        bail!("not a UFO:AI tag file (no JDP2 magic)");
    }
    let (tags, frames, ofs_names, ofs_tags) = (r.usize(8)?, r.usize(12)?, r.usize(16)?, r.usize(20)?);
    let index = (0..tags)
        .find(|&t| r.at(ofs_names + 64 * t, 64).is_ok_and(|b| b.split(|&c| c == 0).next() == Some(name.as_bytes())))
        .ok_or_else(|| anyhow!("no tag {name:?} among {tags}"))?;
    if frame >= frames {
        bail!("frame {frame} asked, the tags have {frames}");
    }
    let at = ofs_tags + 48 * (index * frames + frame);
    let axis = [r.vec3(at)?, r.vec3(at + 12)?, r.vec3(at + 24)?].map(|a| a.normalize_or_zero());
    let origin = r.vec3(at + 36)?;
    if !origin.is_finite() || axis.contains(&Vec3::ZERO) {
        bail!("tag {name:?}: non-finite values or a zero axis");
    }
    Ok((origin, axis))
}

/// Quake (x forward, y left, z up) -> the OBJ's (x = the character's left, y up, z forward): a rotation.
fn to_obj_axes(p: Vec3) -> Vec3 {
    Vec3::new(p.y, p.z, p.x)
}

/// The OBJ and MTL text of `parts` (mesh, texture file name), triangles counter-clockwise seen from outside.
fn write_obj(parts: &[(Mesh, Option<String>)], mtl_name: &str) -> (String, String) {
    let corners = |m: &Mesh, t: &[(usize, usize); 3]| t.map(|(v, _)| to_obj_axes(m.positions[v]));
    let volume6: f32 = parts
        .iter()
        .flat_map(|(m, _)| m.triangles.iter().map(|t| corners(m, t)))
        .map(|[a, b, c]| a.dot(b.cross(c)))
        .sum();
    let mut obj =
        format!("# md2_to_obj: a UFO:AI body and head joined by tag_head, Y up, facing +z\nmtllib {mtl_name}\n");
    let mut mtl = String::new();
    let (mut vbase, mut tbase) = (1usize, 1usize);
    for (k, (m, texture)) in parts.iter().enumerate() {
        mtl.push_str(&format!("newmtl part{k}\nKd 1 1 1\n"));
        if let Some(t) = texture {
            mtl.push_str(&format!("map_Kd {t}\n"));
        }
        obj.push_str(&format!("o part{k}\nusemtl part{k}\n"));
        for p in &m.positions {
            let q = to_obj_axes(*p);
            obj.push_str(&format!("v {} {} {}\n", q.x, q.y, q.z));
        }
        for [s, t] in &m.texcoords {
            obj.push_str(&format!("vt {s} {}\n", 1.0 - t));
        }
        for t in &m.triangles {
            let t = if volume6 < 0.0 { [t[0], t[2], t[1]] } else { *t };
            let c = t.map(|(v, s)| format!("{}/{}", v + vbase, s + tbase));
            obj.push_str(&format!("f {} {} {}\n", c[0], c[1], c[2]));
        }
        vbase += m.positions.len();
        tbase += m.texcoords.len();
    }
    (obj, mtl)
}

/// The bytes of `name` in the zip `archive`, `None` when it has no such file.
fn read_entry(archive: &mut zip::ZipArchive<std::fs::File>, name: &str) -> Result<Option<Vec<u8>>> {
    let mut file = match archive.by_name(name) {
        Ok(f) => f,
        Err(zip::result::ZipError::FileNotFound) => return Ok(None),
        Err(e) => return Err(e).with_context(|| format!("reading {name}")),
    };
    let mut bytes = Vec::new();
    file.read_to_end(&mut bytes).with_context(|| format!("reading {name}"))?;
    Ok(Some(bytes))
}

fn convert(pk3: &Path, body: &str, head: &str, name: &str, out: &Path) -> Result<()> {
    let file = std::fs::File::open(pk3).with_context(|| format!("{}: cannot open", pk3.display()))?;
    let mut archive = zip::ZipArchive::new(file).with_context(|| format!("{}: not a zip", pk3.display()))?;
    let mut need = |path: String| -> Result<Vec<u8>> {
        read_entry(&mut archive, &path)?.ok_or_else(|| anyhow!("{}: no {path}", pk3.display()))
    };
    let anm = String::from_utf8_lossy(&need(format!("{body}.anm"))?).into_owned();
    let frame = anim_first_frame(&anm, "stand_menu").with_context(|| format!("{body}.anm"))?;
    let body_mesh = parse_md2(&need(format!("{body}.md2"))?, frame).with_context(|| format!("{body}.md2"))?;
    let (origin, axis) =
        parse_tag(&need(format!("{body}.tag"))?, "tag_head", frame).with_context(|| format!("{body}.tag"))?;
    let mut head_mesh = parse_md2(&need(format!("{head}.md2"))?, 0).with_context(|| format!("{head}.md2"))?;
    for p in &mut head_mesh.positions {
        *p = origin + p.x * axis[0] + p.y * axis[1] + p.z * axis[2];
    }
    std::fs::create_dir_all(out).with_context(|| format!("{}: cannot create", out.display()))?;
    let mut parts = Vec::new();
    for (stem, mesh) in [(body, body_mesh), (head, head_mesh)] {
        let mut texture = None;
        let folder = stem.rsplit_once('/').map_or("", |(f, _)| f);
        let skin = mesh.skin.strip_prefix('.').unwrap_or(&mesh.skin).to_owned();
        for candidate in ["jpg", "png", "tga"].map(|ext| format!("{folder}/{skin}.{ext}")) {
            if let Some(bytes) = read_entry(&mut archive, &candidate)? {
                let file_name = candidate.rsplit('/').next().unwrap_or(&candidate).to_owned();
                std::fs::write(out.join(&file_name), bytes)
                    .with_context(|| format!("{}: cannot write", out.display()))?;
                texture = Some(file_name);
                break;
            }
        }
        if texture.is_none() {
            eprintln!("warning: {stem}: no texture {skin:?} found; drawn white");
        }
        parts.push((mesh, texture));
    }
    let mtl_name = format!("{name}.mtl");
    let (obj, mtl) = write_obj(&parts, &mtl_name);
    std::fs::write(out.join(&mtl_name), mtl).with_context(|| format!("{}: cannot write", out.display()))?;
    std::fs::write(out.join(format!("{name}.obj")), obj).with_context(|| format!("{}: cannot write", out.display()))?;
    let tris: usize = parts.iter().map(|(m, _)| m.triangles.len()).sum();
    eprintln!("{name}: {body} frame {frame} + {head}, {tris} triangles -> {}", out.display());
    Ok(())
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [pk3, body, head, name, out] = args.as_slice() else {
        bail!("usage: md2_to_obj PK3 BODY HEAD NAME OUT_DIR (BODY, HEAD: paths inside the pk3 without .md2)");
    };
    convert(Path::new(pk3), body, head, name, Path::new(out))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An MD2 of one triangle, one skin (`.body01a`), two frames: frame k's vertices are bytes (1, 2, 3), (4, 5, 6), (7, 8, 9) scaled by
    /// (k + 1) and moved by (10 k, 0, 0).
    fn md2() -> Vec<u8> {
        let (num_xyz, num_st, frame_size) = (3usize, 3usize, 40 + 4 * 3);
        let ofs_skins = 68;
        let ofs_st = ofs_skins + 64;
        let ofs_tris = ofs_st + 4 * num_st;
        let ofs_frames = ofs_tris + 12;
        let header =
            [8, 64, 32, frame_size, 1, num_xyz, num_st, 1, 0, 2, ofs_skins, ofs_st, ofs_tris, ofs_frames, 0, 0];
        let mut d = b"IDP2".to_vec();
        d.extend(header.map(|v| (v as i32).to_le_bytes()).concat());
        assert_eq!(d.len(), 68);
        let mut skin = b".body01a".to_vec();
        skin.resize(64, 0);
        d.extend(skin);
        for (s, t) in [(0u16, 0u16), (32, 0), (0, 16)] {
            d.extend(s.to_le_bytes());
            d.extend(t.to_le_bytes());
        }
        for v in [0u16, 1, 2, 0, 1, 2] {
            d.extend(v.to_le_bytes());
        }
        for k in 0..2 {
            let s = (k + 1) as f32;
            for v in [s, s, s, 10.0 * k as f32, 0.0, 0.0] {
                d.extend(v.to_le_bytes());
            }
            d.extend([0u8; 16]);
            for v in [1u8, 2, 3, 0, 4, 5, 6, 0, 7, 8, 9, 0] {
                d.push(v);
            }
        }
        d
    }

    #[test]
    fn a_frame_is_its_bytes_scaled_and_moved() {
        let m = parse_md2(&md2(), 1).unwrap();
        assert_eq!(
            m.positions,
            vec![Vec3::new(12.0, 4.0, 6.0), Vec3::new(18.0, 10.0, 12.0), Vec3::new(24.0, 16.0, 18.0)]
        );
        assert_eq!(m.texcoords, vec![[0.0, 0.0], [0.5, 0.0], [0.0, 0.5]]);
        assert_eq!(m.triangles, vec![[(0, 0), (1, 1), (2, 2)]]);
        assert_eq!(m.skin, ".body01a");
        assert!(parse_md2(&md2(), 2).is_err(), "past the last frame");
        let short = md2();
        assert!(parse_md2(&short[..short.len() - 5], 1).is_err(), "truncated");
        assert!(parse_md2(b"IDP3", 0).is_err());
    }

    #[test]
    fn the_tag_is_read_tag_major_with_normalised_axes() {
        // Two tags over two frames: tag "b" at frame 1 is the 4th block (tag-major).
        let mut d = b"JDP2".to_vec();
        for v in [1i32, 2, 2, 32, 160, 0, 0] {
            d.extend(v.to_le_bytes());
        }
        for n in ["a", "b"] {
            let mut name = n.as_bytes().to_vec();
            name.resize(64, 0);
            d.extend(name);
        }
        for block in 0..4 {
            let axes = [2.0f32, 0.0, 0.0, 0.0, 3.0, 0.0, 0.0, 0.0, 4.0];
            for v in axes.iter().chain(&[block as f32, 0.0, 1.0]) {
                d.extend(v.to_le_bytes());
            }
        }
        let (origin, axis) = parse_tag(&d, "b", 1).unwrap();
        assert_eq!(origin, Vec3::new(3.0, 0.0, 1.0));
        assert_eq!(axis, [Vec3::X, Vec3::Y, Vec3::Z]);
        assert!(parse_tag(&d, "c", 0).is_err() && parse_tag(&d, "a", 2).is_err());
        assert_eq!(anim_first_frame("// x\nstand0 1 2 3\nstand_menu\t\t69 70 1\n", "stand_menu").unwrap(), 69);
        assert!(anim_first_frame("stand0 1 2 3", "stand_menu").is_err());
    }
}
