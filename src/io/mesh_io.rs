//! Textured meshes on disk: glTF 2.0 binary (`.glb`) writing, and reading of textured glTF/GLB and Wavefront
//! OBJ + MTL (`map_Kd`) scans such as THuman2.0 and 2K2K.
//!
//! Every error names the offending file. Reading does not normalise (see `synth::scan` for that); it checks that
//! the mesh is non-empty, finite and references only existing vertices.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{Mat4, Vec2, Vec3};
use serde_json::json;

use crate::buffer::{linear_to_srgb, srgb_to_linear};
use crate::geometry::mesh::TriMesh;

/// Errors reading or writing mesh files. Each names the file concerned.
#[derive(Debug, thiserror::Error)]
pub enum MeshIoError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file extension is not one of `.obj`, `.gltf`, `.glb`.
    #[error("{path}: unsupported mesh format (expected .obj, .gltf or .glb)")]
    UnsupportedFormat {
        /// The file.
        path: PathBuf,
    },
    /// Malformed OBJ or MTL text.
    #[error("{path}:{line}: {message}")]
    Obj {
        /// The OBJ or MTL file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// The glTF/GLB file is corrupt, truncated or uses something this reader does not support.
    #[error("{path}: invalid glTF: {message}")]
    Gltf {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A texture the mesh references is missing or cannot be decoded.
    #[error("{path}: texture {texture:?} cannot be used: {message}")]
    Texture {
        /// The mesh (or material) file that references the texture.
        path: PathBuf,
        /// The texture as referenced.
        texture: String,
        /// What is wrong.
        message: String,
    },
    /// The mesh has no triangles.
    #[error("{path}: the mesh has no triangles")]
    Empty {
        /// The file.
        path: PathBuf,
    },
    /// A vertex coordinate is NaN or infinite.
    #[error("{path}: vertex {index} is not finite ({value:?})")]
    NonFinite {
        /// The file.
        path: PathBuf,
        /// 0-based vertex index.
        index: usize,
        /// The offending position.
        value: [f32; 3],
    },
    /// The mesh cannot be encoded (e.g. more vertices than 32-bit indices allow, or a bad texture).
    #[error("{path}: cannot encode: {message}")]
    Encode {
        /// The destination file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

/// A triangle mesh with optional per-vertex UVs ([`TriMesh::uvs`], glTF convention) and an optional base-colour
/// texture (8-bit sRGB). Without a texture, appearance comes from [`TriMesh::colors`] (linear RGB) when present.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TexturedMesh {
    /// Geometry, normals, UVs and optional colours.
    pub mesh: TriMesh,
    /// Base-colour texture, 8-bit sRGB (row 0 at the top, sampled at glTF UVs).
    pub texture: Option<image::RgbImage>,
}

impl TexturedMesh {
    /// Linear RGB albedo of the texture at a glTF UV; `None` without a texture.
    pub fn albedo_at_uv(&self, uv: Vec2) -> Option<Vec3> {
        self.texture.as_ref().map(|t| sample_texture(t, uv))
    }
}

/// Bilinear lookup of an sRGB texture at a glTF UV (origin top-left, repeat wrapping) returning linear RGB.
pub fn sample_texture(tex: &image::RgbImage, uv: Vec2) -> Vec3 {
    let (w, h) = (tex.width() as i64, tex.height() as i64);
    if w == 0 || h == 0 || !uv.is_finite() {
        return Vec3::splat(0.5);
    }
    let x = uv.x.rem_euclid(1.0) * w as f32 - 0.5;
    let y = uv.y.rem_euclid(1.0) * h as f32 - 0.5;
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let texel = |xi: i64, yi: i64| {
        let p = tex.get_pixel(xi.rem_euclid(w) as u32, yi.rem_euclid(h) as u32);
        Vec3::new(SRGB_LUT[p[0] as usize], SRGB_LUT[p[1] as usize], SRGB_LUT[p[2] as usize])
    };
    let (xi, yi) = (x0 as i64, y0 as i64);
    let top = texel(xi, yi).lerp(texel(xi + 1, yi), fx);
    let bottom = texel(xi, yi + 1).lerp(texel(xi + 1, yi + 1), fx);
    top.lerp(bottom, fy)
}

static SRGB_LUT: std::sync::LazyLock<[f32; 256]> =
    std::sync::LazyLock::new(|| std::array::from_fn(|i| srgb_to_linear(i as f32 / 255.0)));

/// Reads a textured mesh, choosing the reader by extension (`.obj`, `.gltf`, `.glb`, case-insensitive).
pub fn read_mesh(path: &Path) -> Result<TexturedMesh, MeshIoError> {
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("obj") => read_obj(path),
        Some("gltf") | Some("glb") => read_gltf(path),
        _ => Err(MeshIoError::UnsupportedFormat { path: path.to_path_buf() }),
    }
}

/// Checks the common invariants of a freshly read mesh: triangles present, finite vertices, indices in range.
fn check_mesh(path: &Path, mesh: &TriMesh) -> Result<(), MeshIoError> {
    if mesh.is_empty() {
        return Err(MeshIoError::Empty { path: path.to_path_buf() });
    }
    if let Some(index) = mesh.positions.iter().position(|p| !p.is_finite()) {
        let p = mesh.positions[index];
        return Err(MeshIoError::NonFinite { path: path.to_path_buf(), index, value: p.to_array() });
    }
    mesh.validate().map_err(|message| MeshIoError::Gltf { path: path.to_path_buf(), message })
}

// ------------------------------------------------------------------------------------------------------------
// OBJ + MTL
// ------------------------------------------------------------------------------------------------------------

#[derive(Default, Clone)]
struct ObjMaterial {
    kd: Option<Vec3>,
    map_kd: Option<String>,
}

/// Reads a Wavefront OBJ with its MTL materials. Polygons are fan-triangulated, negative indices resolved, UVs
/// (OBJ convention, v up) flipped to glTF's (v down) with seam vertices split. The `map_Kd` texture (relative to
/// the MTL file) becomes the texture; without one, per-vertex colours (`v x y z r g b`) or the material `Kd`
/// become [`TriMesh::colors`]. Materials with different textures are not supported (an error says so).
pub fn read_obj(path: &Path) -> Result<TexturedMesh, MeshIoError> {
    let bytes = std::fs::read(path).map_err(|source| MeshIoError::Io { path: path.to_path_buf(), source })?;
    let text = String::from_utf8_lossy(&bytes);
    let dir = path.parent().unwrap_or(Path::new("."));
    let obj_err = |line: usize, message: String| MeshIoError::Obj { path: path.to_path_buf(), line, message };

    let mut positions: Vec<Vec3> = Vec::new();
    let mut vcolors: Vec<Vec3> = Vec::new();
    let mut texcoords: Vec<Vec2> = Vec::new();
    let mut materials: HashMap<String, ObjMaterial> = HashMap::new();
    let mut mtl_files: Vec<PathBuf> = Vec::new();
    let mut current_material: Option<usize> = None;
    // Per triangle: corners as (position index, texcoord index or u32::MAX), and its material.
    let mut corners: Vec<[(u32, u32); 3]> = Vec::new();
    // Material names are interned: a triangle stores an index (a long name repeated per triangle would multiply
    // the memory a small file needs).
    let mut tri_material: Vec<Option<usize>> = Vec::new();
    let mut material_names: Vec<String> = Vec::new();
    let mut material_index: HashMap<String, usize> = HashMap::new();
    let mut material_used: Vec<bool> = Vec::new();

    let parse_f = |tok: Option<&str>, line: usize, what: &str| -> Result<f32, MeshIoError> {
        let tok = tok.ok_or_else(|| obj_err(line, format!("{what}: missing coordinate")))?;
        tok.parse::<f32>().map_err(|_| obj_err(line, format!("{what}: {tok:?} is not a number")))
    };

    for (lineno, raw) in text.lines().enumerate() {
        let line = lineno + 1;
        let l = raw.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let (key, rest) = l.split_once(char::is_whitespace).unwrap_or((l, ""));
        let rest = rest.trim();
        match key {
            "v" => {
                let mut it = rest.split_whitespace();
                let x = parse_f(it.next(), line, "v")?;
                let y = parse_f(it.next(), line, "v")?;
                let z = parse_f(it.next(), line, "v")?;
                positions.push(Vec3::new(x, y, z));
                let c: Vec<f32> = it.filter_map(|t| t.parse().ok()).collect();
                if c.len() >= 3 {
                    vcolors.resize(positions.len() - 1, Vec3::splat(0.7));
                    vcolors.push(Vec3::new(c[0], c[1], c[2]));
                }
            }
            "vt" => {
                let mut it = rest.split_whitespace();
                let u = parse_f(it.next(), line, "vt")?;
                let v =
                    it.next().map(|t| t.parse::<f32>()).transpose().map_err(|_| obj_err(line, "vt: bad v".into()))?;
                texcoords.push(Vec2::new(u, 1.0 - v.unwrap_or(0.0)));
            }
            "f" => {
                let mut poly: Vec<(u32, u32)> = Vec::with_capacity(4);
                for tok in rest.split_whitespace() {
                    let mut parts = tok.split('/');
                    let resolve = |s: &str, n: usize, what: &str| -> Result<u32, MeshIoError> {
                        let i: i64 = s.parse().map_err(|_| obj_err(line, format!("f: bad {what} index {s:?}")))?;
                        let idx = if i > 0 { i - 1 } else { n as i64 + i };
                        if i == 0 || idx < 0 || idx >= n as i64 {
                            return Err(obj_err(line, format!("f: {what} index {i} out of range (have {n})")));
                        }
                        Ok(idx as u32)
                    };
                    let vi = resolve(parts.next().unwrap_or(""), positions.len(), "vertex")?;
                    let ti = match parts.next() {
                        Some(s) if !s.is_empty() => resolve(s, texcoords.len(), "texcoord")?,
                        _ => u32::MAX,
                    };
                    poly.push((vi, ti));
                }
                if poly.len() < 3 {
                    return Err(obj_err(line, format!("f: a face needs 3 vertices, got {}", poly.len())));
                }
                if let Some(m) = current_material {
                    material_used[m] = true;
                }
                for k in 1..poly.len() - 1 {
                    corners.push([poly[0], poly[k], poly[k + 1]]);
                    tri_material.push(current_material);
                }
            }
            "mtllib" => {
                for name in split_file_list(rest) {
                    let mtl_path = dir.join(name.replace('\\', "/"));
                    if mtl_files.contains(&mtl_path) {
                        continue; // already read (only existing files get here, so the list stays short)
                    }
                    parse_mtl(&mtl_path, &mut materials).map_err(|e| match e {
                        // A missing or unreadable library: say which OBJ line asked for it.
                        MeshIoError::Io { path: mtl, source } => {
                            obj_err(line, format!("mtllib: cannot read {}: {source}", mtl.display()))
                        }
                        other => other,
                    })?;
                    mtl_files.push(mtl_path);
                }
            }
            "usemtl" => {
                let at = *material_index.entry(rest.to_string()).or_insert_with(|| {
                    material_names.push(rest.to_string());
                    material_used.push(false);
                    material_names.len() - 1
                });
                current_material = Some(at);
            }
            _ => {}
        }
    }

    // The single texture used by the faces, if any.
    let mtl_path = mtl_files.first().cloned().unwrap_or_else(|| path.to_path_buf());
    let mut texture_name: Option<String> = None;
    for m in material_names.iter().zip(&material_used).filter(|(_, &used)| used).map(|(m, _)| m) {
        if let Some(map) = materials.get(m).and_then(|m| m.map_kd.clone()) {
            match &texture_name {
                Some(t) if *t != map => {
                    return Err(MeshIoError::Texture {
                        path: mtl_path,
                        texture: map,
                        message: format!("a second base-colour texture (first was {t:?}); bake them into one"),
                    })
                }
                _ => texture_name = Some(map),
            }
        }
    }
    let texture = match &texture_name {
        Some(name) => {
            let tex_path = mtl_path.parent().unwrap_or(dir).join(name.replace('\\', "/"));
            let img = crate::io::image_io::decode_file(&tex_path).map_err(|e| MeshIoError::Texture {
                path: mtl_path.clone(),
                texture: tex_path.display().to_string(),
                message: e.to_string(),
            })?;
            Some(img.to_rgb8())
        }
        None => None,
    };
    let textured = texture.is_some() && !texcoords.is_empty();

    // Split vertices per (position, texcoord) pair so UVs are per vertex.
    let mut remap: HashMap<(u32, u32), u32> = HashMap::new();
    let mut out_pos = Vec::new();
    let mut out_uv = Vec::new();
    let mut out_col = Vec::new();
    let mut triangles = Vec::with_capacity(corners.len());
    for (t, tri) in corners.iter().enumerate() {
        let mut idx = [0u32; 3];
        for (k, &(vi, ti)) in tri.iter().enumerate() {
            let key = if textured { (vi, ti) } else { (vi, u32::MAX) };
            idx[k] = *remap.entry(key).or_insert_with(|| {
                out_pos.push(positions[vi as usize]);
                if textured {
                    out_uv.push(if ti == u32::MAX { Vec2::ZERO } else { texcoords[ti as usize] });
                } else {
                    let kd = tri_material[t].and_then(|m| materials.get(&material_names[m])).and_then(|m| m.kd);
                    let c = vcolors.get(vi as usize).copied().or(kd).unwrap_or(Vec3::splat(0.7));
                    out_col.push(c);
                }
                (out_pos.len() - 1) as u32
            });
        }
        triangles.push(idx);
    }
    let mut mesh = TriMesh::new(out_pos, triangles);
    mesh.uvs = out_uv;
    mesh.colors = out_col;
    check_mesh(path, &mesh)?;
    Ok(TexturedMesh { mesh, texture: if textured { texture } else { None } })
}

/// File names on an `mtllib` line: whitespace separated unless the whole rest names one file with spaces.
fn split_file_list(rest: &str) -> Vec<String> {
    if rest.to_ascii_lowercase().matches(".mtl").count() <= 1 {
        vec![rest.to_string()]
    } else {
        rest.split_whitespace().map(str::to_string).collect()
    }
}

fn parse_mtl(path: &Path, materials: &mut HashMap<String, ObjMaterial>) -> Result<(), MeshIoError> {
    let text = std::fs::read_to_string(path).map_err(|source| MeshIoError::Io { path: path.to_path_buf(), source })?;
    let mut current: Option<String> = None;
    for (lineno, raw) in text.lines().enumerate() {
        let l = raw.trim();
        let (key, rest) = l.split_once(char::is_whitespace).unwrap_or((l, ""));
        let rest = rest.trim();
        match key {
            "newmtl" => {
                current = Some(rest.to_string());
                materials.entry(rest.to_string()).or_default();
            }
            "Kd" | "map_Kd" => {
                let Some(name) = &current else {
                    return Err(MeshIoError::Obj {
                        path: path.to_path_buf(),
                        line: lineno + 1,
                        message: format!("{key} before any newmtl"),
                    });
                };
                let m = materials.entry(name.clone()).or_default();
                if key == "Kd" {
                    let c: Vec<f32> = rest.split_whitespace().filter_map(|t| t.parse().ok()).collect();
                    if c.len() >= 3 {
                        m.kd = Some(Vec3::new(c[0], c[1], c[2]));
                    }
                } else {
                    m.map_kd = Some(strip_map_options(rest));
                }
            }
            _ => {}
        }
    }
    Ok(())
}

/// The file name of a `map_Kd` statement, skipping options such as `-s 1 1 1`, `-bm 0.5` or `-clamp on`. The
/// last token is always kept as (part of) the name.
fn strip_map_options(rest: &str) -> String {
    let toks: Vec<&str> = rest.split_whitespace().collect();
    let mut i = 0;
    while i + 1 < toks.len() && toks[i].starts_with('-') {
        i += 1;
        while i + 1 < toks.len() && (toks[i].parse::<f32>().is_ok() || matches!(toks[i], "on" | "off")) {
            i += 1;
        }
    }
    toks[i.min(toks.len().saturating_sub(1))..].join(" ")
}

// ------------------------------------------------------------------------------------------------------------
// glTF / GLB
// ------------------------------------------------------------------------------------------------------------

/// Reads a glTF 2.0 file (`.gltf` with its buffers/images, or `.glb`): every triangle primitive of the default
/// scene, with node transforms applied, merged into one mesh. UVs are `TEXCOORD_0`; the texture is the base-colour
/// texture of the materials (one texture at most); untextured primitives get the material's base colour factor
/// (or `COLOR_0`) as per-vertex colour.
pub fn read_gltf(path: &Path) -> Result<TexturedMesh, MeshIoError> {
    let gerr = |message: String| MeshIoError::Gltf { path: path.to_path_buf(), message };
    let bytes = std::fs::read(path).map_err(|source| MeshIoError::Io { path: path.to_path_buf(), source })?;
    let raw = gltf::Gltf::from_slice_without_validation(&bytes).map_err(|e| gerr(e.to_string()))?;
    check_gltf_references(raw.document.as_json()).map_err(gerr)?;
    let document = gltf::Document::from_json(raw.document.into_json()).map_err(|e| gerr(e.to_string()))?;
    let blob = raw.blob;
    let dir = path.parent().unwrap_or(Path::new("."));
    // Name a missing external texture or buffer before the importer fails with a generic message.
    for image in document.images() {
        if let gltf::image::Source::Uri { uri, .. } = image.source() {
            if !uri.starts_with("data:") && !dir.join(percent_decode(uri)).is_file() {
                return Err(MeshIoError::Texture {
                    path: path.to_path_buf(),
                    texture: uri.to_string(),
                    message: "file not found".into(),
                });
            }
        }
    }
    let buffers = gltf::import_buffers(&document, Some(dir), blob).map_err(|e| gerr(format!("buffers: {e}")))?;

    let mut positions = Vec::new();
    let mut uvs = Vec::new();
    let mut colors = Vec::new();
    let mut triangles = Vec::new();
    let mut texture_index: Option<usize> = None;
    let mut any_untextured = false;

    let scene = document.default_scene().or_else(|| document.scenes().next());
    let mut stack: Vec<(gltf::Node, Mat4)> = match &scene {
        Some(s) => s.nodes().map(|n| (n, Mat4::IDENTITY)).collect(),
        None => document.nodes().map(|n| (n, Mat4::IDENTITY)).collect(),
    };
    // The node hierarchy must be a forest (glTF 2.0, 3.5.3); a node reached twice is a cycle or a shared child,
    // which would otherwise loop forever or duplicate geometry without bound.
    let mut visited = vec![false; document.nodes().len()];
    while let Some((node, parent)) = stack.pop() {
        match visited.get_mut(node.index()) {
            Some(seen) if !*seen => *seen = true,
            _ => return Err(gerr(format!("node {} appears twice in the node hierarchy (a cycle)", node.index()))),
        }
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        for child in node.children() {
            stack.push((child, world));
        }
        let Some(mesh) = node.mesh() else { continue };
        for prim in mesh.primitives() {
            if prim.mode() != gltf::mesh::Mode::Triangles {
                continue;
            }
            check_primitive_accessors(&prim).map_err(gerr)?;
            let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
            let Some(pos) = reader.read_positions() else { continue };
            let base = positions.len() as u32;
            let local: Vec<Vec3> = pos.map(|p| world.transform_point3(Vec3::from(p))).collect();
            let n = local.len();
            let material = prim.material();
            let pbr = material.pbr_metallic_roughness();
            let tex = pbr.base_color_texture();
            let prim_uv: Option<Vec<Vec2>> = tex
                .as_ref()
                .and_then(|t| reader.read_tex_coords(t.tex_coord()))
                .map(|tc| tc.into_f32().map(Vec2::from).collect());
            match (&tex, &prim_uv) {
                (Some(t), Some(uv)) if uv.len() == n => {
                    let idx = t.texture().source().index();
                    if texture_index.is_some_and(|i| i != idx) {
                        return Err(MeshIoError::Texture {
                            path: path.to_path_buf(),
                            texture: format!("image {idx}"),
                            message: "a second base-colour texture; bake them into one".into(),
                        });
                    }
                    texture_index = Some(idx);
                    uvs.resize(base as usize, Vec2::ZERO);
                    uvs.extend_from_slice(uv);
                }
                _ => any_untextured = true,
            }
            let factor = Vec3::from_slice(&pbr.base_color_factor()[..3]);
            let vcol: Option<Vec<Vec3>> =
                reader.read_colors(0).map(|c| c.into_rgb_f32().map(|c| Vec3::from(c) * factor).collect());
            colors.resize(base as usize, Vec3::splat(0.7));
            match vcol {
                Some(c) if c.len() == n => colors.extend(c),
                _ => colors.extend(std::iter::repeat_n(factor, n)),
            }
            positions.extend(local);
            let flip = world.determinant() < 0.0;
            let mut push = |a: u32, b: u32, c: u32| {
                if a.max(b).max(c) as usize >= n {
                    return Err(gerr(format!("primitive index {} past its {n} vertices", a.max(b).max(c))));
                }
                triangles.push(if flip { [base + a, base + c, base + b] } else { [base + a, base + b, base + c] });
                Ok(())
            };
            match reader.read_indices() {
                Some(ind) => {
                    let ind: Vec<u32> = ind.into_u32().collect();
                    for t in ind.chunks_exact(3) {
                        push(t[0], t[1], t[2])?;
                    }
                }
                None => {
                    for t in 0..(n / 3) as u32 {
                        push(3 * t, 3 * t + 1, 3 * t + 2)?;
                    }
                }
            }
        }
    }
    let texture = match texture_index {
        Some(i) => {
            let image = document.images().nth(i).ok_or_else(|| gerr(format!("image {i} does not exist")))?;
            Some(gltf_texture(path, dir, image.source(), &buffers).map_err(|message| MeshIoError::Texture {
                path: path.to_path_buf(),
                texture: format!("image {i}"),
                message,
            })?)
        }
        None => None,
    };
    let mut mesh = TriMesh::new(positions, triangles);
    if texture.is_some() {
        uvs.resize(mesh.positions.len(), Vec2::ZERO);
        mesh.uvs = uvs;
        if any_untextured {
            // Mixed primitives: keep per-vertex colours too so untextured parts keep their base colour.
            mesh.colors = colors;
        }
    } else {
        mesh.colors = colors;
    }
    check_mesh(path, &mesh)?;
    Ok(TexturedMesh { mesh, texture })
}

/// Checks what `gltf` 1.4's validation does not but its reader relies on (each of these made it panic in
/// `tests/fuzz.rs`; the inputs are in `tests/corpus/glb`, `tests/corpus/gltf`): before validation, that every
/// primitive's accessors exist (validation indexes them) and that images say where their bytes are.
fn check_gltf_references(root: &gltf::json::Root) -> Result<(), String> {
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            for index in prim.attributes.values().chain(prim.indices.iter()) {
                if index.value() >= root.accessors.len() {
                    return Err(format!(
                        "mesh {m} primitive {p} uses accessor {} but there are {}",
                        index.value(),
                        root.accessors.len()
                    ));
                }
            }
        }
    }
    for (i, image) in root.images.iter().enumerate() {
        match (&image.buffer_view, &image.mime_type, &image.uri) {
            (Some(_), None, _) => return Err(format!("image {i} is in a buffer view but has no mimeType")),
            (None, _, None) => return Err(format!("image {i} has neither a uri nor a bufferView")),
            _ => {}
        }
    }
    Ok(())
}

/// After validation: the accessors this reader reads (positions, the first UVs and colours, indices) have the
/// component types and shapes the `gltf` reader handles (others reach an `unreachable!`) and lie inside their
/// buffer views (so the number of elements read is bounded by the file's size).
fn check_primitive_accessors(prim: &gltf::Primitive<'_>) -> Result<(), String> {
    use gltf::accessor::{DataType as T, Dimensions as D};
    use gltf::Semantic;
    for (semantic, acc) in prim.attributes() {
        let allowed: &[(T, D)] = match semantic {
            Semantic::Positions => &[(T::F32, D::Vec3)],
            Semantic::TexCoords(_) => &[(T::F32, D::Vec2), (T::U8, D::Vec2), (T::U16, D::Vec2)],
            Semantic::Colors(_) => &[
                (T::F32, D::Vec3),
                (T::U8, D::Vec3),
                (T::U16, D::Vec3),
                (T::F32, D::Vec4),
                (T::U8, D::Vec4),
                (T::U16, D::Vec4),
            ],
            _ => continue,
        };
        check_accessor(&acc, &format!("{semantic:?}"), allowed)?;
    }
    if let Some(acc) = prim.indices() {
        check_accessor(&acc, "indices", &[(T::U8, D::Scalar), (T::U16, D::Scalar), (T::U32, D::Scalar)])?;
    }
    Ok(())
}

fn check_accessor(
    acc: &gltf::Accessor<'_>,
    what: &str,
    allowed: &[(gltf::accessor::DataType, gltf::accessor::Dimensions)],
) -> Result<(), String> {
    let kind = (acc.data_type(), acc.dimensions());
    if !allowed.contains(&kind) {
        return Err(format!(
            "accessor {} ({what}) is {:?} {:?}, which this reader does not take",
            acc.index(),
            kind.0,
            kind.1
        ));
    }
    let out = |detail: String| format!("accessor {} ({what}) {detail}", acc.index());
    // The byte range of `count` elements of `size` bytes at `stride` from `offset` must fit the view.
    let fits = |view: &gltf::buffer::View<'_>, offset: usize, count: usize, size: usize| -> Result<(), String> {
        let stride = view.stride().unwrap_or(size);
        if stride < size {
            return Err(out(format!("has a byte stride of {stride}, less than its {size}-byte elements")));
        }
        let end = match count {
            0 => Some(offset),
            n => stride.checked_mul(n - 1).and_then(|s| s.checked_add(offset)).and_then(|e| e.checked_add(size)),
        };
        let view_end = view.offset().checked_add(view.length());
        match (end, view_end) {
            (Some(e), Some(v)) if e <= view.length() && v <= view.buffer().length() => Ok(()),
            _ => Err(out(format!("reads {count} elements past the end of buffer view {}", view.index()))),
        }
    };
    if let Some(view) = acc.view() {
        fits(&view, acc.offset(), acc.count(), acc.size())?;
    }
    if let Some(sparse) = acc.sparse() {
        if acc.count() == 0 || sparse.count() == 0 {
            return Err(out("is sparse with no elements".into()));
        }
        let indices = sparse.indices();
        fits(&indices.view(), indices.offset(), sparse.count(), indices.index_type().size())?;
        fits(&sparse.values().view(), sparse.values().offset(), sparse.count(), acc.size())?;
    }
    Ok(())
}

fn percent_decode(uri: &str) -> String {
    let b = uri.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' && i + 2 < b.len() {
            if let Ok(v) = u8::from_str_radix(&uri[i + 1..i + 3], 16) {
                out.push(v);
                i += 3;
                continue;
            }
        }
        out.push(b[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// Decodes a glTF image (in a buffer view, a `data:` URI or a file next to the glTF) into 8-bit sRGB, with the
/// photo loader's size checks (a forged header cannot allocate more than the file can hold).
fn gltf_texture(
    path: &Path,
    dir: &Path,
    source: gltf::image::Source<'_>,
    buffers: &[gltf::buffer::Data],
) -> Result<image::RgbImage, String> {
    use crate::io::image_io::{decode_bytes, decode_file};
    let image = match source {
        gltf::image::Source::View { view, .. } => {
            let buffer = buffers.get(view.buffer().index()).ok_or("its buffer does not exist")?;
            let bytes = view
                .offset()
                .checked_add(view.length())
                .and_then(|end| buffer.0.get(view.offset()..end))
                .ok_or("its buffer view lies past the end of the buffer")?;
            decode_bytes(bytes, path)
        }
        gltf::image::Source::Uri { uri, .. } => match uri.strip_prefix("data:") {
            Some(data) => {
                let (header, payload) = data.split_once(',').ok_or("a data: URI without a comma")?;
                let bytes = if header.ends_with(";base64") {
                    base64::decode(payload).map_err(|e| format!("data: URI: {e}"))?
                } else {
                    percent_decode(payload).into_bytes()
                };
                decode_bytes(&bytes, path)
            }
            None => decode_file(&dir.join(percent_decode(uri))),
        },
    };
    Ok(image.map_err(|e| e.to_string())?.to_rgb8())
}

/// Encodes a mesh as glTF 2.0 binary: positions, normals, `TEXCOORD_0` and an embedded PNG base-colour texture
/// when present (else `COLOR_0` when per-vertex colours are present), `u32` indices, and an unlit material
/// (`KHR_materials_unlit`, so viewers show the albedo as the ground truth sees it). `name` labels the file in
/// errors.
pub fn glb_bytes(mesh: &TexturedMesh, name: &Path) -> Result<Vec<u8>, MeshIoError> {
    let enc = |message: String| MeshIoError::Encode { path: name.to_path_buf(), message };
    let m = &mesh.mesh;
    let nv = m.positions.len();
    if m.is_empty() {
        return Err(MeshIoError::Empty { path: name.to_path_buf() });
    }
    m.validate().map_err(enc)?;
    if u32::try_from(nv).is_err() {
        return Err(enc("too many vertices for 32-bit indices".into()));
    }
    let normals: Vec<Vec3> = if m.normals.len() == nv {
        m.normals.clone()
    } else {
        let mut c = m.clone();
        c.compute_normals();
        c.normals
    };
    let textured = mesh.texture.is_some() && m.uvs.len() == nv;
    let colored = !textured && m.colors.len() == nv;

    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    let mut push_view = |bin: &mut Vec<u8>, data: &[u8], target: Option<u32>| -> usize {
        while bin.len() % 4 != 0 {
            bin.push(0);
        }
        let mut v = json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": data.len()});
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        bin.extend_from_slice(data);
        views.push(v);
        views.len() - 1
    };
    let f32_bytes = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();

    let (lo, hi) = m.bounds().unwrap_or((Vec3::ZERO, Vec3::ZERO));
    let flat: Vec<f32> = m.positions.iter().flat_map(|p| p.to_array()).collect();
    let v = push_view(&mut bin, &f32_bytes(&flat), Some(34962));
    accessors.push(json!({"bufferView": v, "componentType": 5126, "count": nv, "type": "VEC3",
        "min": lo.to_array(), "max": hi.to_array()}));
    let flat: Vec<f32> = normals.iter().flat_map(|p| p.to_array()).collect();
    let v = push_view(&mut bin, &f32_bytes(&flat), Some(34962));
    accessors.push(json!({"bufferView": v, "componentType": 5126, "count": nv, "type": "VEC3"}));
    let mut attributes = json!({"POSITION": 0, "NORMAL": 1});
    if textured {
        let flat: Vec<f32> = m.uvs.iter().flat_map(|p| p.to_array()).collect();
        let v = push_view(&mut bin, &f32_bytes(&flat), Some(34962));
        accessors.push(json!({"bufferView": v, "componentType": 5126, "count": nv, "type": "VEC2"}));
        attributes["TEXCOORD_0"] = json!(accessors.len() - 1);
    } else if colored {
        let flat: Vec<f32> = m.colors.iter().flat_map(|c| c.clamp(Vec3::ZERO, Vec3::ONE).to_array()).collect();
        let v = push_view(&mut bin, &f32_bytes(&flat), Some(34962));
        accessors.push(json!({"bufferView": v, "componentType": 5126, "count": nv, "type": "VEC3"}));
        attributes["COLOR_0"] = json!(accessors.len() - 1);
    }
    let idx: Vec<u8> = m.triangles.iter().flatten().flat_map(|i| i.to_le_bytes()).collect();
    let v = push_view(&mut bin, &idx, Some(34963));
    accessors.push(json!({"bufferView": v, "componentType": 5125, "count": m.triangles.len() * 3, "type": "SCALAR"}));
    let indices = accessors.len() - 1;

    let mut root = json!({
        "asset": {"version": "2.0", "generator": "r2human"},
        "extensionsUsed": ["KHR_materials_unlit"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "subject"}],
        "meshes": [{"primitives": [{"attributes": attributes, "indices": indices, "material": 0, "mode": 4}]}],
    });
    let mut material = json!({
        "name": "albedo",
        "pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 1.0},
        "extensions": {"KHR_materials_unlit": {}},
    });
    if textured {
        let tex = mesh.texture.as_ref().ok_or_else(|| enc("texture vanished".into()))?;
        let mut png = Vec::new();
        let encoder = image::codecs::png::PngEncoder::new_with_quality(
            &mut png,
            image::codecs::png::CompressionType::Fast,
            image::codecs::png::FilterType::Adaptive,
        );
        image::ImageEncoder::write_image(
            encoder,
            tex.as_raw(),
            tex.width(),
            tex.height(),
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|e| enc(format!("texture PNG: {e}")))?;
        let v = push_view(&mut bin, &png, None);
        root["images"] = json!([{"bufferView": v, "mimeType": "image/png"}]);
        root["samplers"] = json!([{"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}]);
        root["textures"] = json!([{"sampler": 0, "source": 0}]);
        material["pbrMetallicRoughness"]["baseColorTexture"] = json!({"index": 0});
    }
    root["materials"] = json!([material]);
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    root["bufferViews"] = json!(views);
    root["accessors"] = json!(accessors);
    root["buffers"] = json!([{"byteLength": bin.len()}]);
    let mut js = serde_json::to_vec(&root).map_err(|e| enc(e.to_string()))?;
    while js.len() % 4 != 0 {
        js.push(b' ');
    }
    let total = 12 + 8 + js.len() + 8 + bin.len();
    let total32 = u32::try_from(total).map_err(|_| enc("file larger than 4 GiB".into()))?;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&total32.to_le_bytes());
    out.extend_from_slice(&(js.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&js);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    Ok(out)
}

/// Writes a mesh as `.glb` (see [`glb_bytes`]) atomically: a temporary file in the same folder, then a rename.
pub fn write_glb(path: &Path, mesh: &TexturedMesh) -> Result<(), MeshIoError> {
    let bytes = glb_bytes(mesh, path)?;
    crate::io::npy::write_atomic(path, &bytes).map_err(|source| MeshIoError::Io { path: path.to_path_buf(), source })
}

/// Converts a linear RGB colour in `[0, 1]` to 8-bit sRGB (through a 16k-entry table: at most one level off the
/// exact curve).
pub fn linear_to_srgb8(c: Vec3) -> [u8; 3] {
    const N: usize = 16384;
    static LUT: std::sync::LazyLock<Vec<u8>> = std::sync::LazyLock::new(|| {
        (0..N).map(|i| (linear_to_srgb(i as f32 / (N - 1) as f32) * 255.0 + 0.5) as u8).collect()
    });
    c.to_array().map(|v| {
        let v = if v.is_finite() { v.clamp(0.0, 1.0) } else { 0.0 };
        LUT[(v * (N - 1) as f32 + 0.5) as usize]
    })
}
