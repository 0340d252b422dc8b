//! Converts a MegaGlest unit (a G3D v4 morph mesh) into one textured OBJ+MTL, standing, Y up and facing +z, for
//! `r2human eval --scan` (test material of `scripts/scan-megaglest.sh`, not a product importer).
//!
//! ```text
//! cargo run --release --example g3d_to_obj -- UNIT_XML NAME OUT_DIR
//! ```
//! `UNIT_XML` is a unit's XML in Debian `megaglest-data` (e.g.
//! `/usr/share/games/megaglest/techs/megapack/factions/tech/units/worker/worker.xml`). The pose is frame 0 of the
//! first animation of the unit's first skill of type `stop` (the idle pose the game shows). Writes
//! `OUT_DIR/NAME.obj`, `NAME.mtl` and one PNG per textured mesh.
//!
//! G3D v4 (little-endian): `G3D`, version byte 4; a model header (uint16 mesh count, uint8 type); per mesh a header
//! (64-byte name, uint32 frames, vertices, indices, diffuse rgb, specular rgb, specular power, opacity as float32,
//! uint32 properties, uint32 texture bits), a 64-byte path per set texture bit (bit 0: the diffuse texture, the
//! one used), then every frame's vertices, every frame's normals (float32 x3), the texture coordinates once
//! (float32 x2, when any texture bit is set) and the triangle indices (uint32). A mesh with the custom-colour
//! property (bit 0) shows the player's colour where its texture is transparent: here the first player's red,
//! mixed in by the texture's alpha, so the PNG written is opaque. The megapack's units stand Y up facing +z, as the
//! OBJ is written (positions unchanged; texture coordinates as stored, v up the image). Read with bounds checks: a short or corrupt file is an error naming the
//! file, never a panic.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context, Result};
use glam::Vec3;

/// MegaGlest's first player colour (red), drawn where a custom-colour mesh's texture is transparent.
const PLAYER_COLOUR: [f32; 3] = [1.0, 0.0, 0.0];

/// A little-endian reader over a file's bytes with bounds-checked reads.
struct Reader<'a> {
    data: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
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
    fn u8(&mut self) -> Result<u8> {
        Ok(self.take(1)?[0])
    }
    fn u16(&mut self) -> Result<u16> {
        Ok(u16::from_le_bytes(self.take(2)?.try_into()?))
    }
    fn u32(&mut self) -> Result<usize> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into()?) as usize)
    }
    fn f32(&mut self) -> Result<f32> {
        Ok(f32::from_le_bytes(self.take(4)?.try_into()?))
    }
    fn name(&mut self) -> Result<String> {
        let raw = self.take(64)?;
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

/// One mesh of one frame: positions, texture coordinates (as stored, v up) and triangles of vertex indices.
#[derive(Debug, Default)]
struct Mesh {
    positions: Vec<Vec3>,
    texcoords: Vec<[f32; 2]>,
    triangles: Vec<[usize; 3]>,
    /// The diffuse texture's path as stored (relative to the model's folder).
    texture: Option<String>,
    custom_colour: bool,
    two_sided: bool,
}

/// The meshes of a G3D v4 file at `frame`.
fn parse_g3d(data: &[u8], frame: usize) -> Result<Vec<Mesh>> {
    let mut r = Reader { data, at: 0 };
    if r.take(3)? != b"G3D" {
        bail!("not a G3D file");
    }
    let version = r.u8()?;
    if version != 4 {
        bail!("G3D version {version}, only 4 is read");
    }
    let meshes = r.u16()? as usize;
    let _model_type = r.u8()?;
    let mut out = Vec::with_capacity(meshes.min(256));
    for m in 0..meshes {
        let name = r.name()?;
        let (frames, vertices, indices) = (r.u32()?, r.u32()?, r.u32()?);
        for _ in 0..8 {
            r.f32()?; // diffuse, specular, specular power, opacity
        }
        let properties = r.u32()?;
        let textures = r.u32()?;
        let mut texture = None;
        for bit in 0..3 {
            if textures & (1 << bit) != 0 {
                let path = r.name()?;
                if bit == 0 {
                    texture = Some(path);
                }
            }
        }
        if frame >= frames {
            bail!("mesh {m} ({name}): frame {frame} of {frames}");
        }
        if indices % 3 != 0 {
            bail!("mesh {m} ({name}): {indices} indices, not triangles");
        }
        r.check(frames, vertices.checked_mul(24).ok_or_else(|| anyhow!("vertex count {vertices} overflows"))?)?;
        let skip = frame * vertices * 12;
        r.take(skip)?;
        let mut positions = Vec::with_capacity(vertices);
        for _ in 0..vertices {
            positions.push(Vec3::new(r.f32()?, r.f32()?, r.f32()?));
        }
        r.take((frames - frame - 1) * vertices * 12)?; // the later frames' vertices
        r.take(frames * vertices * 12)?; // normals
        let mut texcoords = Vec::new();
        if textures != 0 {
            r.check(vertices, 8)?;
            for _ in 0..vertices {
                texcoords.push([r.f32()?, r.f32()?]);
            }
        }
        r.check(indices, 4)?;
        let mut triangles = Vec::with_capacity(indices / 3);
        for _ in 0..indices / 3 {
            let t = [r.u32()?, r.u32()?, r.u32()?];
            if t.iter().any(|&i| i >= vertices) {
                bail!("mesh {m} ({name}): index out of {vertices} vertices");
            }
            triangles.push(t);
        }
        out.push(Mesh {
            positions,
            texcoords,
            triangles,
            texture,
            custom_colour: properties & 1 != 0,
            two_sided: properties & 2 != 0,
        });
    }
    Ok(out)
}

/// The model path of the first animation of the first `stop` skill in a unit's XML (relative to the XML's folder).
fn stop_animation(xml: &str) -> Result<String> {
    let mut rest = xml;
    while let Some(start) = rest.find("<skill>") {
        let body = &rest[start..];
        let end = body.find("</skill>").ok_or_else(|| anyhow!("a <skill> without </skill>"))?;
        let skill = &body[..end];
        if skill.contains("<type value=\"stop\"") {
            let a = skill.find("<animation path=\"").ok_or_else(|| anyhow!("the stop skill has no animation"))?;
            let path = &skill[a + 17..];
            let q = path.find('"').ok_or_else(|| anyhow!("unterminated animation path"))?;
            return Ok(path[..q].to_owned());
        }
        rest = &body[end..];
    }
    bail!("no skill of type stop")
}

/// The texture at `path` as an opaque RGB PNG, the player's colour mixed in by alpha for a custom-colour mesh.
fn opaque_texture(path: &Path, custom_colour: bool) -> Result<image::RgbImage> {
    let img = image::open(path).with_context(|| format!("{}: cannot read", path.display()))?.to_rgba8();
    let mut out = image::RgbImage::new(img.width(), img.height());
    for (x, y, p) in img.enumerate_pixels() {
        let a = if custom_colour { p[3] as f32 / 255.0 } else { 1.0 };
        let c = |k: usize| (p[k] as f32 * a + PLAYER_COLOUR[k] * 255.0 * (1.0 - a)).round() as u8;
        out.put_pixel(x, y, image::Rgb([c(0), c(1), c(2)]));
    }
    Ok(out)
}

/// The OBJ and MTL text of `meshes` with their texture file names; triangles counter-clockwise seen from outside
/// (flipped as a whole when the signed volume is negative). Two-sided meshes (sheets) are written as they are.
fn write_obj(meshes: &[(Mesh, Option<String>)], header: &str, mtl_name: &str) -> (String, String) {
    let volume6: f32 = meshes
        .iter()
        .filter(|(m, _)| !m.two_sided)
        .flat_map(|(m, _)| m.triangles.iter().map(|t| t.map(|v| m.positions[v])))
        .map(|[a, b, c]| a.dot(b.cross(c)))
        .sum();
    let mut obj = format!("# g3d_to_obj: {header}, Y up, facing +z\nmtllib {mtl_name}\n");
    let mut mtl = String::new();
    let mut base = 1usize;
    for (k, (m, texture)) in meshes.iter().enumerate() {
        mtl.push_str(&format!("newmtl part{k}\nKd 1 1 1\n"));
        if let Some(t) = texture {
            mtl.push_str(&format!("map_Kd {t}\n"));
        }
        obj.push_str(&format!("o part{k}\nusemtl part{k}\n"));
        for p in &m.positions {
            obj.push_str(&format!("v {} {} {}\n", p.x, p.y, p.z));
        }
        let textured = texture.is_some() && m.texcoords.len() == m.positions.len();
        if textured {
            for [s, t] in &m.texcoords {
                obj.push_str(&format!("vt {s} {t}\n"));
            }
        }
        for t in &m.triangles {
            let t = if volume6 < 0.0 { [t[0], t[2], t[1]] } else { *t };
            let c = t.map(|v| if textured { format!("{}/{}", v + base, v + base) } else { format!("{}", v + base) });
            obj.push_str(&format!("f {} {} {}\n", c[0], c[1], c[2]));
        }
        base += m.positions.len();
    }
    (obj, mtl)
}

fn convert(xml_path: &Path, name: &str, out: &Path) -> Result<()> {
    let xml = std::fs::read_to_string(xml_path).with_context(|| format!("{}: cannot read", xml_path.display()))?;
    let unit_dir = xml_path.parent().unwrap_or(Path::new("."));
    let model: PathBuf = unit_dir.join(stop_animation(&xml).with_context(|| format!("{}", xml_path.display()))?);
    let data = std::fs::read(&model).with_context(|| format!("{}: cannot read", model.display()))?;
    let meshes = parse_g3d(&data, 0).with_context(|| format!("{}", model.display()))?;
    let model_dir = model.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(out).with_context(|| format!("{}: cannot create", out.display()))?;
    let mut parts = Vec::new();
    for (k, mesh) in meshes.into_iter().enumerate() {
        let mut texture = None;
        if let Some(t) = &mesh.texture {
            let file = format!("{name}_part{k}.png");
            let img = opaque_texture(&model_dir.join(t), mesh.custom_colour)?;
            img.save(out.join(&file)).with_context(|| format!("{}: cannot write", out.display()))?;
            texture = Some(file);
        }
        parts.push((mesh, texture));
    }
    let mtl_name = format!("{name}.mtl");
    let (obj, mtl) = write_obj(&parts, &model.display().to_string(), &mtl_name);
    std::fs::write(out.join(&mtl_name), mtl).with_context(|| format!("{}: cannot write", out.display()))?;
    std::fs::write(out.join(format!("{name}.obj")), obj).with_context(|| format!("{}: cannot write", out.display()))?;
    let tris: usize = parts.iter().map(|(m, _)| m.triangles.len()).sum();
    eprintln!("{name}: {} frame 0, {} meshes, {tris} triangles -> {}", model.display(), parts.len(), out.display());
    Ok(())
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [xml, name, out] = args.as_slice() else {
        bail!("usage: g3d_to_obj UNIT_XML NAME OUT_DIR");
    };
    convert(Path::new(xml), name, Path::new(out))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A G3D v4 of one mesh of one triangle, two frames (frame k's vertices moved by k along x), a diffuse
    /// texture `t.png` and the custom-colour property.
    fn g3d() -> Vec<u8> {
        let mut d = b"G3D\x04".to_vec();
        d.extend(1u16.to_le_bytes());
        d.push(0);
        let mut name = b"body".to_vec();
        name.resize(64, 0);
        d.extend(name);
        for v in [2u32, 3, 3] {
            d.extend(v.to_le_bytes());
        }
        for _ in 0..8 {
            d.extend(1f32.to_le_bytes());
        }
        d.extend(1u32.to_le_bytes());
        d.extend(1u32.to_le_bytes());
        let mut tex = b"t.png".to_vec();
        tex.resize(64, 0);
        d.extend(tex);
        for k in 0..2 {
            for v in [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 2.0]] {
                for (i, c) in v.iter().enumerate() {
                    d.extend((c + if i == 0 { k as f32 } else { 0.0 }).to_le_bytes());
                }
            }
        }
        d.extend(vec![0u8; 2 * 3 * 12]);
        for uv in [0.0f32, 0.0, 1.0, 0.0, 0.0, 1.0] {
            d.extend(uv.to_le_bytes());
        }
        for i in [0u32, 1, 2] {
            d.extend(i.to_le_bytes());
        }
        d
    }

    #[test]
    fn a_frame_is_read_with_its_texture_and_properties() {
        let m = parse_g3d(&g3d(), 1).unwrap();
        assert_eq!(m.len(), 1);
        assert_eq!(m[0].positions, vec![Vec3::new(1.0, 0.0, 0.0), Vec3::new(2.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 2.0)]);
        assert_eq!(m[0].texcoords, vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]);
        assert_eq!(m[0].triangles, vec![[0, 1, 2]]);
        assert_eq!(m[0].texture.as_deref(), Some("t.png"));
        assert!(m[0].custom_colour && !m[0].two_sided);
        assert!(parse_g3d(&g3d(), 2).is_err(), "past the last frame");
        let full = g3d();
        assert!(parse_g3d(&full[..full.len() - 3], 0).is_err(), "truncated");
        let mut v3 = g3d();
        v3[3] = 3;
        assert!(parse_g3d(&v3, 0).is_err(), "version 3");
    }

    #[test]
    fn the_first_stop_skill_gives_the_pose() {
        let xml = "<skills><skill><type value=\"move\"/><animation path=\"m/walk.g3d\"/></skill>\
                   <skill><type value=\"stop\"/><animation path=\"m/idle1.g3d\"/><animation path=\"m/idle2.g3d\"/>\
                   </skill></skills>";
        assert_eq!(stop_animation(xml).unwrap(), "m/idle1.g3d");
        assert!(stop_animation("<skill><type value=\"move\"/></skill>").is_err());
    }
}
