//! Converts a Quake 3 / OpenArena MD3 **player** (three parts joined by tags) into one textured OBJ+MTL, standing,
//! Y up and facing +z, for `r2human eval --scan` (test material of `scripts/scan-check.sh`, not a product importer).
//!
//! ```text
//! cargo run --release --example md3_to_obj -- SOURCE PLAYER OUT_DIR [SKIN]
//! ```
//! `SOURCE` is a `.pk3` (a zip, e.g. Debian `openarena-081-players`' `pak2-players.pk3`) or a folder holding
//! `models/players/PLAYER/`; `SKIN` is the skin name (`default`). Writes `OUT_DIR/PLAYER.obj`, `PLAYER.mtl` and
//! the skin's textures next to them (as found, TGA or JPEG).
//!
//! A player is `lower.md3` (legs), `upper.md3` (torso) and `head.md3`: `lower.md3`'s `tag_torso` carries the
//! torso's origin, `upper.md3`'s `tag_head` the head's, as the game places them (`CG_PositionRotatedEntityOnTag`).
//! `assimp export lower.md3 x.obj` also loads the three parts (its multipart MD3 option) but assembles them wrongly
//! (measured on sergei: the torso about 5x and the head about 40x too large and displaced), so the parts are joined
//! here by their tags. The pose is the first frame of `TORSO_STAND` for the torso and of `LEGS_IDLE` for the
//! legs, read from `animation.cfg` with Quake 3's rule that leg frame numbers there count the torso-only frames
//! too (`CG_ParseAnimationFile`: every `LEGS_*` first frame minus `LEGS_WALKCR`'s minus `TORSO_GESTURE`'s).
//!
//! No maintained MD3 crate exists on crates.io; MD3 is a small fixed-layout little-endian format (header,
//! frames, tags, surfaces with per-frame int16 vertices in 1/64 units), read here with bounds checks: a short or
//! corrupt file is an error naming the file, never a panic.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context, Result};
use glam::Vec3;

/// MD3 vertex coordinates are int16 in 1/64 units.
const XYZ_SCALE: f32 = 1.0 / 64.0;

/// The animation order of `animation.cfg` (Quake 3's `animNumber_t`, the first 25 lines with numbers).
const TORSO_GESTURE: usize = 6;
const TORSO_STAND: usize = 11;
const LEGS_WALKCR: usize = 13;
const LEGS_IDLE: usize = 22;

/// A tag: an origin and three axis vectors (the child's x, y, z in the parent's coordinates).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Tag {
    origin: Vec3,
    axis: [Vec3; 3],
}

impl Tag {
    /// The identity placement.
    const IDENTITY: Tag = Tag { origin: Vec3::ZERO, axis: [Vec3::X, Vec3::Y, Vec3::Z] };

    /// A point of the child's coordinates in the parent's.
    fn apply(&self, p: Vec3) -> Vec3 {
        self.origin + p.x * self.axis[0] + p.y * self.axis[1] + p.z * self.axis[2]
    }

    /// `self` placed in `parent`'s frame (the game's `CG_PositionRotatedEntityOnTag` with the parent's placement).
    fn within(&self, parent: &Tag) -> Tag {
        let rot = |v: Vec3| v.x * parent.axis[0] + v.y * parent.axis[1] + v.z * parent.axis[2];
        Tag { origin: parent.apply(self.origin), axis: self.axis.map(rot) }
    }
}

/// One surface of an MD3 at one frame.
#[derive(Clone, Debug)]
struct Surface {
    name: String,
    /// The shader named in the file (used when the skin does not name the surface).
    shader: String,
    positions: Vec<Vec3>,
    texcoords: Vec<[f32; 2]>,
    triangles: Vec<[u32; 3]>,
}

/// An MD3 read at one frame.
#[derive(Clone, Debug)]
struct Md3 {
    frames: usize,
    tags: BTreeMap<String, Tag>,
    surfaces: Vec<Surface>,
}

/// Bounds-checked little-endian reads.
struct Reader<'a> {
    data: &'a [u8],
}

impl Reader<'_> {
    fn bytes(&self, at: usize, n: usize) -> Result<&[u8]> {
        at.checked_add(n)
            .and_then(|end| self.data.get(at..end))
            .ok_or_else(|| anyhow!("truncated: {n} bytes at offset {at} beyond the file's {} bytes", self.data.len()))
    }
    fn i32(&self, at: usize) -> Result<i32> {
        Ok(i32::from_le_bytes(self.bytes(at, 4)?.try_into()?))
    }
    fn count(&self, at: usize, what: &str) -> Result<usize> {
        let v = self.i32(at)?;
        usize::try_from(v).map_err(|_| anyhow!("negative {what} ({v}) at offset {at}"))
    }
    fn f32(&self, at: usize) -> Result<f32> {
        Ok(f32::from_le_bytes(self.bytes(at, 4)?.try_into()?))
    }
    fn i16(&self, at: usize) -> Result<i16> {
        Ok(i16::from_le_bytes(self.bytes(at, 2)?.try_into()?))
    }
    fn vec3(&self, at: usize) -> Result<Vec3> {
        Ok(Vec3::new(self.f32(at)?, self.f32(at + 4)?, self.f32(at + 8)?))
    }
    fn name(&self, at: usize, len: usize) -> Result<String> {
        let b = self.bytes(at, len)?;
        let end = b.iter().position(|&c| c == 0).unwrap_or(len);
        Ok(String::from_utf8_lossy(&b[..end]).into_owned())
    }
}

/// Reads `data` (an MD3 file) at `frame` (clamped to the file's last frame, as the game does for single-frame
/// heads).
fn parse_md3(data: &[u8], frame: usize) -> Result<Md3> {
    let r = Reader { data };
    if r.bytes(0, 4)? != b"IDP3" {
        bail!("not an MD3 (no IDP3 magic)");
    }
    let version = r.i32(4)?;
    if version != 15 {
        bail!("MD3 version {version}, expected 15");
    }
    let frames = r.count(76, "frame count")?;
    let num_tags = r.count(80, "tag count")?;
    let num_surfaces = r.count(84, "surface count")?;
    let ofs_tags = r.count(96, "tag offset")?;
    let ofs_surfaces = r.count(100, "surface offset")?;
    if frames == 0 {
        bail!("no frames");
    }
    let frame = frame.min(frames - 1);
    let mut tags = BTreeMap::new();
    for t in 0..num_tags {
        let at = ofs_tags + (frame * num_tags + t) * 112;
        let name = r.name(at, 64)?;
        let axis = [r.vec3(at + 76)?, r.vec3(at + 88)?, r.vec3(at + 100)?];
        // The game normalises every tag axis (`R_LerpTag`): many players store them scaled (sergei by 8.1, liz
        // by 4.7, beret by 3.1), which would blow the torso and head up by that factor.
        let tag = Tag { origin: r.vec3(at + 64)?, axis: axis.map(|a| a.normalize_or_zero()) };
        if !tag.origin.is_finite() || tag.axis.contains(&Vec3::ZERO) {
            bail!("tag {name:?}: non-finite values or a zero axis");
        }
        tags.insert(name, tag);
    }
    let mut surfaces = Vec::with_capacity(num_surfaces.min(64));
    let mut at = ofs_surfaces;
    for s in 0..num_surfaces {
        if r.bytes(at, 4)? != b"IDP3" {
            bail!("surface {s}: no IDP3 magic at offset {at}");
        }
        let name = r.name(at + 4, 64)?;
        let surface_frames = r.count(at + 72, "surface frame count")?;
        let num_shaders = r.count(at + 76, "shader count")?;
        let num_verts = r.count(at + 80, "vertex count")?;
        let num_tris = r.count(at + 84, "triangle count")?;
        let [ofs_tris, ofs_shaders, ofs_st, ofs_xyz, ofs_end] =
            [88, 92, 96, 100, 104].map(|o| r.count(at + o, "surface offset"));
        let (ofs_tris, ofs_shaders, ofs_st, ofs_xyz, ofs_end) = (ofs_tris?, ofs_shaders?, ofs_st?, ofs_xyz?, ofs_end?);
        if surface_frames != frames {
            bail!("surface {name:?}: {surface_frames} frames, the header says {frames}");
        }
        let shader = if num_shaders > 0 { r.name(at + ofs_shaders, 64)? } else { String::new() };
        let mut triangles = Vec::with_capacity(num_tris.min(1 << 20));
        for i in 0..num_tris {
            let t = at + ofs_tris + i * 12;
            let idx = [r.i32(t)?, r.i32(t + 4)?, r.i32(t + 8)?];
            if idx.iter().any(|&k| k < 0 || k as usize >= num_verts) {
                bail!("surface {name:?}: triangle {i} has an index outside its {num_verts} vertices: {idx:?}");
            }
            triangles.push(idx.map(|k| k as u32));
        }
        let mut texcoords = Vec::with_capacity(num_verts.min(1 << 20));
        let mut positions = Vec::with_capacity(num_verts.min(1 << 20));
        for v in 0..num_verts {
            let st = at + ofs_st + v * 8;
            texcoords.push([r.f32(st)?, r.f32(st + 4)?]);
            let p = at + ofs_xyz + (frame * num_verts + v) * 8;
            positions.push(Vec3::new(r.i16(p)? as f32, r.i16(p + 2)? as f32, r.i16(p + 4)? as f32) * XYZ_SCALE);
        }
        if texcoords.iter().flatten().any(|c| !c.is_finite()) {
            bail!("surface {name:?}: non-finite texture coordinates");
        }
        if ofs_end == 0 {
            bail!("surface {s}: zero size");
        }
        r.bytes(at, ofs_end).with_context(|| format!("surface {name:?} is cut short"))?;
        surfaces.push(Surface { name, shader, positions, texcoords, triangles });
        at += ofs_end;
    }
    Ok(Md3 { frames, tags, surfaces })
}

/// The first frames of `TORSO_STAND` and `LEGS_IDLE` from an `animation.cfg`, the legs' corrected by Quake 3's
/// skip (leg frame numbers there count the torso-only frames too).
fn standing_frames(cfg: &str) -> Result<(usize, usize)> {
    let mut first = Vec::new();
    for line in cfg.lines() {
        let line = line.split("//").next().unwrap_or("");
        let mut tokens = line.split_whitespace();
        let Some(tok) = tokens.next() else { continue };
        // Keyword lines (sex, headoffset, footsteps, fixedlegs, ...) come before the numbers.
        if let Ok(n) = tok.parse::<i64>() {
            first.push(n);
        }
    }
    if first.len() <= LEGS_IDLE {
        bail!("animation.cfg: {} animations, need at least {}", first.len(), LEGS_IDLE + 1);
    }
    let skip = first[LEGS_WALKCR] - first[TORSO_GESTURE];
    let torso = first[TORSO_STAND];
    let legs = first[LEGS_IDLE] - skip;
    let frame = |v: i64, what: &str| usize::try_from(v).map_err(|_| anyhow!("animation.cfg: {what} frame {v}"));
    Ok((frame(torso, "TORSO_STAND")?, frame(legs, "LEGS_IDLE (after the skip)")?))
}

/// A `.skin` file: surface name -> shader/texture path (lower case). `tag_*` lines are skipped.
fn parse_skin(text: &str) -> BTreeMap<String, String> {
    text.lines()
        .filter_map(|l| {
            let (surface, shader) = l.trim().split_once(',')?;
            let surface = surface.trim().to_ascii_lowercase();
            (!surface.starts_with("tag_") && !surface.is_empty())
                .then(|| (surface, shader.trim().replace('\\', "/").to_ascii_lowercase()))
        })
        .collect()
}

/// Where the model files come from.
enum Source {
    Pk3(zip::ZipArchive<std::fs::File>),
    Dir(PathBuf),
}

impl Source {
    fn open(path: &Path) -> Result<Self> {
        if path.is_dir() {
            return Ok(Source::Dir(path.to_path_buf()));
        }
        let f = std::fs::File::open(path).with_context(|| format!("{}: cannot open", path.display()))?;
        Ok(Source::Pk3(zip::ZipArchive::new(f).with_context(|| format!("{}: not a pk3 (zip)", path.display()))?))
    }

    /// The file at `name` (case-insensitive, as the game's file system), or `None`.
    fn read(&mut self, name: &str) -> Result<Option<Vec<u8>>> {
        match self {
            Source::Dir(root) => {
                let p = root.join(name);
                match std::fs::read(&p) {
                    Ok(b) => Ok(Some(b)),
                    Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
                    Err(e) => Err(e).with_context(|| format!("{}: cannot read", p.display())),
                }
            }
            Source::Pk3(zip) => {
                let want = name.to_ascii_lowercase();
                let Some(real) = zip.file_names().find(|n| n.to_ascii_lowercase() == want).map(str::to_string) else {
                    return Ok(None);
                };
                let mut f = zip.by_name(&real)?;
                let mut b = Vec::with_capacity(f.size().min(1 << 28) as usize);
                f.read_to_end(&mut b).with_context(|| format!("{real}: cannot read from the pk3"))?;
                Ok(Some(b))
            }
        }
    }

    /// An image as the game finds it: the path as written, else the same stem as TGA, JPEG or PNG
    /// (`R_FindImageFile` tries the other extensions too). Returns the path found and its bytes.
    fn image(&mut self, path: &str) -> Result<Option<(String, Vec<u8>)>> {
        let stem = path.rsplit_once('.').filter(|(_, ext)| !ext.contains('/')).map(|(s, _)| s).unwrap_or(path);
        for candidate in [path.to_string(), format!("{stem}.tga"), format!("{stem}.jpg"), format!("{stem}.png")] {
            if let Some(b) = self.read(&candidate)? {
                return Ok(Some((candidate, b)));
            }
        }
        Ok(None)
    }

    /// The texture of a skin's shader name as the game draws it: a shader script of that name (`scripts/*.shader`)
    /// takes precedence and gives its first stage's image; otherwise the name is an image path ([`Self::image`]).
    fn texture(&mut self, shader: &str, scripts: &BTreeMap<String, String>) -> Result<Option<(String, Vec<u8>)>> {
        let stem = shader.rsplit_once('.').filter(|(_, ext)| !ext.contains('/')).map(|(s, _)| s).unwrap_or(shader);
        if let Some(map) = scripts.get(stem) {
            if let Some(found) = self.image(map)? {
                return Ok(Some(found));
            }
        }
        self.image(shader)
    }

    /// Every shader script's first image (`map`, `clampMap` or the first frame of `animMap`), by shader name
    /// (lower case), from the `scripts/*.shader` files of the source.
    fn shader_scripts(&mut self) -> Result<BTreeMap<String, String>> {
        let names: Vec<String> = match self {
            Source::Pk3(zip) => zip
                .file_names()
                .filter(|n| {
                    n.to_ascii_lowercase().starts_with("scripts/") && n.to_ascii_lowercase().ends_with(".shader")
                })
                .map(str::to_string)
                .collect(),
            Source::Dir(root) => match std::fs::read_dir(root.join("scripts")) {
                Ok(rd) => rd
                    .filter_map(|e| e.ok())
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .filter(|n| n.to_ascii_lowercase().ends_with(".shader"))
                    .map(|n| format!("scripts/{n}"))
                    .collect(),
                Err(_) => Vec::new(),
            },
        };
        let mut out = BTreeMap::new();
        for name in names {
            if let Some(bytes) = self.read(&name)? {
                parse_shader_scripts(&String::from_utf8_lossy(&bytes), &mut out);
            }
        }
        Ok(out)
    }
}

/// Adds each shader of a Quake 3 shader script `text` with its first stage image to `out` (the first definition
/// of a name wins, as in the game).
fn parse_shader_scripts(text: &str, out: &mut BTreeMap<String, String>) {
    let mut depth = 0usize;
    let mut current: Option<String> = None;
    let mut found = false;
    for line in text.lines() {
        let mut tokens = line.split("//").next().unwrap_or("").split_whitespace();
        while let Some(token) = tokens.next() {
            match token.to_ascii_lowercase().as_str() {
                "{" => depth += 1,
                "}" => {
                    depth = depth.saturating_sub(1);
                    if depth == 0 {
                        current = None;
                    }
                }
                name if depth == 0 => {
                    current = Some(name.replace('\\', "/"));
                    found = false;
                }
                key @ ("map" | "clampmap" | "animmap") if depth == 2 && !found => {
                    // animMap's first argument is its frequency.
                    let image = if key == "animmap" { tokens.nth(1) } else { tokens.next() };
                    if let (Some(name), Some(image)) = (&current, image) {
                        if !image.starts_with('$') {
                            out.entry(name.clone()).or_insert_with(|| image.replace('\\', "/").to_ascii_lowercase());
                            found = true;
                        }
                    }
                }
                _ => {}
            }
        }
    }
}

/// The assembled player: vertices in Quake coordinates (x forward, y left, z up), per-surface texture path.
struct Player {
    surfaces: Vec<(Surface, Option<String>)>,
}

/// Joins the three parts by their tags at the standing frames (`parts` = lower, upper, head, each with its skin).
fn assemble(parts: [(&Md3, &BTreeMap<String, String>); 3]) -> Result<Player> {
    let [(lower, lower_skin), (upper, upper_skin), (head, head_skin)] = parts;
    let torso = *lower.tags.get("tag_torso").ok_or_else(|| anyhow!("lower.md3 has no tag_torso"))?;
    let head_tag = *upper.tags.get("tag_head").ok_or_else(|| anyhow!("upper.md3 has no tag_head"))?;
    let placements = [Tag::IDENTITY, torso, head_tag.within(&torso)];
    let mut surfaces = Vec::new();
    for ((md3, skin), place) in
        [(lower, lower_skin), (upper, upper_skin), (head, head_skin)].into_iter().zip(placements)
    {
        for s in &md3.surfaces {
            let shader =
                skin.get(&s.name.to_ascii_lowercase()).cloned().unwrap_or_else(|| s.shader.to_ascii_lowercase());
            // Surfaces the skin hides (`nodraw`, or no shader at all) are not drawn by the game either; empty ones are
            // left out.
            if shader.is_empty() || shader.ends_with("nodraw") || s.triangles.is_empty() {
                continue;
            }
            let mut s = s.clone();
            for p in &mut s.positions {
                *p = place.apply(*p);
            }
            surfaces.push((s, Some(shader)));
        }
    }
    Ok(Player { surfaces })
}

/// Quake (x forward, y left, z up) -> the OBJ's (x = the character's left = the viewer's right, y up, z forward):
/// a cyclic permutation of the axes, i.e. a rotation (no mirror).
fn to_obj_axes(p: Vec3) -> Vec3 {
    Vec3::new(p.y, p.z, p.x)
}

/// Six times the signed volume enclosed by the triangles (positive when they wind counter-clockwise seen from
/// outside).
fn signed_volume6(surfaces: &[(Surface, Option<String>)]) -> f32 {
    surfaces
        .iter()
        .flat_map(|(s, _)| s.triangles.iter().map(move |t| t.map(|i| to_obj_axes(s.positions[i as usize]))))
        .map(|[a, b, c]| a.dot(b.cross(c)))
        .sum()
}

/// The OBJ and MTL text of `player` (textures named by `texture_names`: shader path -> file name next to the OBJ).
/// Triangles are written counter-clockwise seen from outside (the order that gives a positive enclosed volume:
/// MD3 files store them the other way round, clockwise as the game's front faces).
fn write_obj(player: &Player, mtl_name: &str, texture_names: &BTreeMap<String, String>) -> (String, String) {
    let flip = signed_volume6(&player.surfaces) < 0.0;
    let mut obj = format!("# md3_to_obj: a Quake 3 player joined by its tags, Y up, facing +z\nmtllib {mtl_name}\n");
    let mut mtl = String::new();
    let mut base = 1usize;
    for (k, (s, shader)) in player.surfaces.iter().enumerate() {
        let material = format!("m{k}_{}", s.name.replace(|c: char| !c.is_ascii_alphanumeric(), "_"));
        mtl.push_str(&format!("newmtl {material}\nKd 1 1 1\n"));
        if let Some(file) = shader.as_ref().and_then(|sh| texture_names.get(sh)) {
            mtl.push_str(&format!("map_Kd {file}\n"));
        }
        mtl.push('\n');
        obj.push_str(&format!("o {}\nusemtl {material}\n", s.name));
        for p in &s.positions {
            let q = to_obj_axes(*p);
            obj.push_str(&format!("v {} {} {}\n", q.x, q.y, q.z));
        }
        // MD3 texture t runs down the image; OBJ v runs up.
        for [u, v] in &s.texcoords {
            obj.push_str(&format!("vt {u} {}\n", 1.0 - v));
        }
        for t in &s.triangles {
            let [a, b, c] = if flip { [t[0], t[2], t[1]] } else { *t };
            let [a, b, c] = [a, b, c].map(|i| i as usize + base);
            obj.push_str(&format!("f {a}/{a} {b}/{b} {c}/{c}\n"));
        }
        base += s.positions.len();
    }
    (obj, mtl)
}

/// Writes `bytes` to `path` through a temporary file and a rename (nothing half-written is left on failure).
fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = path.with_extension("part");
    std::fs::write(&tmp, bytes).with_context(|| format!("{}: cannot write", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("{}: cannot rename into place", path.display()))
}

/// Converts `player` of `source` with skin `skin` into `out/<player>.obj` (+ MTL and textures).
fn convert(source: &Path, player: &str, skin: &str, out: &Path) -> Result<PathBuf> {
    let mut src = Source::open(source)?;
    let dir = format!("models/players/{player}");
    let mut need = |name: &str| -> Result<Vec<u8>> {
        src.read(&format!("{dir}/{name}"))?.ok_or_else(|| anyhow!("{}: no {dir}/{name}", source.display()))
    };
    let cfg = String::from_utf8_lossy(&need("animation.cfg")?).into_owned();
    let (torso_frame, legs_frame) = standing_frames(&cfg).with_context(|| format!("{dir}/animation.cfg"))?;
    let mut parts = Vec::new();
    for (part, frame) in [("lower", legs_frame), ("upper", torso_frame), ("head", 0)] {
        let md3 = parse_md3(&need(&format!("{part}.md3"))?, frame).with_context(|| format!("{dir}/{part}.md3"))?;
        if frame >= md3.frames && part != "head" {
            bail!("{dir}/{part}.md3: frame {frame} asked, the file has {}", md3.frames);
        }
        let skin_text = String::from_utf8_lossy(&need(&format!("{part}_{skin}.skin"))?).into_owned();
        parts.push((md3, parse_skin(&skin_text)));
    }
    let player_model = assemble([(&parts[0].0, &parts[0].1), (&parts[1].0, &parts[1].1), (&parts[2].0, &parts[2].1)])?;
    std::fs::create_dir_all(out).with_context(|| format!("{}: cannot create", out.display()))?;
    let scripts = src.shader_scripts()?;
    let mut texture_names = BTreeMap::new();
    for (s, shader) in &player_model.surfaces {
        eprintln!("  {}: {} triangles, shader {shader:?}", s.name, s.triangles.len());
    }
    for shader in player_model.surfaces.iter().filter_map(|(_, s)| s.clone()) {
        if texture_names.contains_key(&shader) {
            continue;
        }
        match src.texture(&shader, &scripts)? {
            Some((found, bytes)) => {
                // Flattened so two players' textures of the same name cannot collide.
                let name = found.trim_start_matches("models/players/").replace('/', "_");
                write_file(&out.join(&name), &bytes)?;
                texture_names.insert(shader, name);
            }
            None => eprintln!("warning: {player}: texture {shader:?} not found (a shader script?); drawn white"),
        }
    }
    let mtl_name = format!("{player}.mtl");
    let (obj, mtl) = write_obj(&player_model, &mtl_name, &texture_names);
    write_file(&out.join(&mtl_name), mtl.as_bytes())?;
    let obj_path = out.join(format!("{player}.obj"));
    write_file(&obj_path, obj.as_bytes())?;
    let tris: usize = player_model.surfaces.iter().map(|(s, _)| s.triangles.len()).sum();
    eprintln!(
        "{player}: torso frame {torso_frame}, legs frame {legs_frame}, {} surfaces, {tris} triangles, {} textures -> {}",
        player_model.surfaces.len(),
        texture_names.len(),
        obj_path.display()
    );
    Ok(obj_path)
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if !(3..=4).contains(&args.len()) {
        bail!("usage: md3_to_obj SOURCE(.pk3 or folder) PLAYER OUT_DIR [SKIN (default)]");
    }
    let skin = args.get(3).map(String::as_str).unwrap_or("default");
    convert(Path::new(&args[0]), &args[1], skin, Path::new(&args[2]))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An MD3 file: one surface of `verts` (in 1/64 units) with one triangle, `tags` at every frame, `frames`
    /// frames (frame f shifts every vertex by f units in x).
    fn md3_bytes(surface: &str, verts: [[i16; 3]; 3], tags: &[(&str, Tag)], frames: usize) -> Vec<u8> {
        let mut b = Vec::new();
        let i = |b: &mut Vec<u8>, v: i32| b.extend_from_slice(&v.to_le_bytes());
        let f = |b: &mut Vec<u8>, v: f32| b.extend_from_slice(&v.to_le_bytes());
        let name = |b: &mut Vec<u8>, s: &str, len: usize| {
            let mut n = s.as_bytes().to_vec();
            n.resize(len, 0);
            b.extend_from_slice(&n);
        };
        let ofs_frames = 108;
        let ofs_tags = ofs_frames + 56 * frames;
        let ofs_surfaces = ofs_tags + 112 * tags.len() * frames;
        let surface_size = 108 + 68 + 12 + 8 * 3 + 8 * 3 * frames;
        b.extend_from_slice(b"IDP3");
        i(&mut b, 15);
        name(&mut b, "test", 64);
        for v in [0, frames as i32, tags.len() as i32, 1, 0, ofs_frames as i32, ofs_tags as i32, ofs_surfaces as i32] {
            i(&mut b, v);
        }
        i(&mut b, (ofs_surfaces + surface_size) as i32);
        for _ in 0..frames {
            b.extend_from_slice(&[0u8; 40]);
            name(&mut b, "frame", 16);
        }
        for _ in 0..frames {
            for (n, t) in tags {
                name(&mut b, n, 64);
                for v in [t.origin, t.axis[0], t.axis[1], t.axis[2]] {
                    f(&mut b, v.x);
                    f(&mut b, v.y);
                    f(&mut b, v.z);
                }
            }
        }
        b.extend_from_slice(b"IDP3");
        name(&mut b, surface, 64);
        let (ofs_shaders, ofs_tris, ofs_st, ofs_xyz) = (108, 176, 188, 212);
        for v in [0, frames as i32, 1, 3, 1, ofs_tris, ofs_shaders, ofs_st, ofs_xyz, surface_size as i32] {
            i(&mut b, v);
        }
        name(&mut b, "models/test/inner.tga", 64);
        i(&mut b, 0);
        for v in [0, 1, 2] {
            i(&mut b, v);
        }
        for st in [[0.0, 0.0], [1.0, 0.0], [0.0, 0.25]] {
            f(&mut b, st[0]);
            f(&mut b, st[1]);
        }
        for fr in 0..frames {
            for v in verts {
                for (k, c) in v.iter().enumerate() {
                    let c = if k == 0 { c + 64 * fr as i16 } else { *c };
                    b.extend_from_slice(&c.to_le_bytes());
                }
                b.extend_from_slice(&0i16.to_le_bytes());
            }
        }
        assert_eq!(b.len(), ofs_surfaces + surface_size);
        b
    }

    /// A 90 degree turn about z (x -> y, y -> -x) at `origin`.
    fn turn_z(origin: Vec3) -> Tag {
        Tag { origin, axis: [Vec3::Y, -Vec3::X, Vec3::Z] }
    }

    #[test]
    fn tags_join_the_parts_at_their_closed_form_placement() {
        // Stored with scaled axes (as many real players are): the game normalises them.
        let torso = turn_z(Vec3::new(1.0, 2.0, 3.0));
        let torso = Tag { axis: torso.axis.map(|a| a * 8.1), ..torso };
        let head = Tag { origin: Vec3::new(0.0, 0.0, 4.0), axis: [Vec3::X * 0.5, Vec3::Z * 0.5, -Vec3::Y * 0.5] };
        let unit = [[64, 0, 0], [0, 64, 0], [0, 0, 64]];
        // Lower: two frames, frame 1 is the standing one (shifted by +1 in x).
        let lower = parse_md3(&md3_bytes("l_legs", unit, &[("tag_torso", torso)], 2), 1).unwrap();
        let upper = parse_md3(&md3_bytes("u_torso", unit, &[("tag_head", head)], 1), 0).unwrap();
        let head_md3 = parse_md3(&md3_bytes("h_head", unit, &[], 1), 0).unwrap();
        assert_eq!(
            lower.positions_of("l_legs"),
            vec![Vec3::new(2.0, 0.0, 0.0), Vec3::new(1.0, 1.0, 0.0), Vec3::Z + Vec3::X]
        );
        let skin = parse_skin("l_legs,models/test/legs.tga\ntag_torso,\nu_torso,models/test/torso.tga\n");
        let head_skin = parse_skin("h_head,models/test/head.jpg");
        let p = assemble([(&lower, &skin), (&upper, &skin), (&head_md3, &head_skin)]).unwrap();
        let pos = |k: usize| p.surfaces[k].0.positions.clone();
        let close =
            |a: Vec<Vec3>, b: Vec<Vec3>| a.len() == b.len() && a.iter().zip(&b).all(|(x, y)| x.distance(*y) < 1e-5);
        // Torso: origin (1,2,3) plus the point turned 90 degrees about z.
        assert!(close(pos(1), vec![Vec3::new(1.0, 3.0, 3.0), Vec3::new(0.0, 2.0, 3.0), Vec3::new(1.0, 2.0, 4.0)]));
        // Head: first its tag in the torso's frame (origin (0,0,4), y -> z, z -> -y), then the torso's placement.
        // Head x (1,0,0) -> torso (1,0,4) -> world (1,3,7); head y -> torso (0,0,5) -> (1,2,8);
        // head z -> torso (0,-1,4) -> world (2,2,7).
        assert!(close(pos(2), vec![Vec3::new(1.0, 3.0, 7.0), Vec3::new(1.0, 2.0, 8.0), Vec3::new(2.0, 2.0, 7.0)]));
        assert_eq!(p.surfaces[0].1.as_deref(), Some("models/test/legs.tga"));
        assert_eq!(p.surfaces[2].1.as_deref(), Some("models/test/head.jpg"));
    }

    #[test]
    fn surfaces_missing_from_the_skin_use_their_own_shader_and_nodraw_hides() {
        let unit = [[64, 0, 0], [0, 64, 0], [0, 0, 64]];
        let lower = parse_md3(&md3_bytes("l_legs", unit, &[("tag_torso", Tag::IDENTITY)], 1), 0).unwrap();
        let upper = parse_md3(&md3_bytes("u_torso", unit, &[("tag_head", Tag::IDENTITY)], 1), 0).unwrap();
        let head = parse_md3(&md3_bytes("h_head", unit, &[], 1), 0).unwrap();
        let empty = BTreeMap::new();
        let hide = parse_skin("h_head,nodraw");
        let p = assemble([(&lower, &empty), (&upper, &empty), (&head, &hide)]).unwrap();
        assert_eq!(p.surfaces.len(), 2);
        assert_eq!(p.surfaces[0].1.as_deref(), Some("models/test/inner.tga"));
    }

    #[test]
    fn standing_frames_apply_quake3s_leg_skip() {
        let mut cfg = String::from("sex m\nheadoffset 0 0 0\n");
        // 25 animations: first frames 0, 10, 20, ...; TORSO_GESTURE = 60, LEGS_WALKCR = 130 -> skip 70.
        for k in 0..25 {
            cfg.push_str(&format!("{}\t5\t0\t20\t\t// anim {k}\n", k * 10));
        }
        assert_eq!(standing_frames(&cfg).unwrap(), (110, 220 - 70));
        assert!(standing_frames("sex m\n0 1 1 1\n").is_err());
    }

    #[test]
    fn corrupt_files_are_errors_not_panics() {
        let good = md3_bytes("s", [[64, 0, 0], [0, 64, 0], [0, 0, 64]], &[("tag_torso", Tag::IDENTITY)], 1);
        for cut in [0, 3, 50, 107, 200, good.len() - 1] {
            assert!(parse_md3(&good[..cut], 0).is_err(), "cut at {cut}");
        }
        let mut bad_index = good.clone();
        // The first triangle index (surface start + 176).
        let tri = 108 + 56 + 112 + 176;
        bad_index[tri..tri + 4].copy_from_slice(&7i32.to_le_bytes());
        assert!(parse_md3(&bad_index, 0).unwrap_err().to_string().contains("outside"));
        let mut negative = good;
        negative[76..80].copy_from_slice(&(-1i32).to_le_bytes());
        assert!(parse_md3(&negative, 0).is_err());
    }

    #[test]
    fn obj_axes_are_a_rotation_and_faces_wind_outward() {
        // Quake forward (+x) becomes +z, up (+z) becomes +y, left (+y) becomes +x: determinant +1.
        let m = glam::Mat3::from_cols(to_obj_axes(Vec3::X), to_obj_axes(Vec3::Y), to_obj_axes(Vec3::Z));
        assert_eq!(m.determinant(), 1.0);
        assert_eq!(to_obj_axes(Vec3::X), Vec3::Z);
        // A tetrahedron wound clockwise from outside (as MD3 stores them) is written counter-clockwise.
        let positions = vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z];
        let inward = vec![[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]];
        let outward: Vec<[u32; 3]> = inward.iter().map(|t| [t[0], t[2], t[1]]).collect();
        for (tris, flipped) in [(inward, true), (outward, false)] {
            let s = Surface {
                name: "s".into(),
                shader: String::new(),
                positions: positions.clone(),
                texcoords: vec![[0.0, 0.0]; 4],
                triangles: tris.clone(),
            };
            let player = Player { surfaces: vec![(s, None)] };
            let (obj, mtl) = write_obj(&player, "x.mtl", &BTreeMap::new());
            assert!(mtl.contains("newmtl m0_s") && !mtl.contains("map_Kd"));
            let first = obj.lines().find(|l| l.starts_with("f ")).unwrap();
            let t = tris[0];
            let expect = if flipped { [t[0], t[2], t[1]] } else { t }.map(|i| i + 1);
            assert_eq!(first, format!("f {0}/{0} {1}/{1} {2}/{2}", expect[0], expect[1], expect[2]));
            assert!(obj.contains("vt 0 1\n"), "t flipped to OBJ's v");
        }
    }

    #[test]
    fn shader_scripts_give_their_first_stage_image() {
        let text = "// comment\nmodels/p/dress\n{\n\tcull disable\n\t{\n\t\tmap $lightmap\n\t}\n\t{\n\t\tmap models/p/Lower.tga\n\
                    \t}\n\t{\n\t\tmap models/p/other.tga\n\t}\n}\nmodels/p/anim {\n{\nanimMap 8 models/p/a.tga models/p/b.tga\n}\n}\n";
        let mut out = BTreeMap::new();
        parse_shader_scripts(text, &mut out);
        assert_eq!(out.get("models/p/dress").map(String::as_str), Some("models/p/lower.tga"));
        assert_eq!(out.get("models/p/anim").map(String::as_str), Some("models/p/a.tga"));
        assert_eq!(out.len(), 2);
    }

    impl Md3 {
        fn positions_of(&self, surface: &str) -> Vec<Vec3> {
            self.surfaces.iter().find(|s| s.name == surface).map(|s| s.positions.clone()).unwrap_or_default()
        }
    }
}
