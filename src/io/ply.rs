//! PLY meshes as photogrammetry and scanning tools write them (Meshroom, OpenMVS, COLMAP, MeshLab, Open3D):
//! ASCII and binary (little/big endian), read with the `ply-rs-bw` crate (maintained, and it caps the memory it
//! reserves from counts in a file's header).
//!
//! Read: `vertex` x/y/z (any numeric type), colours `red`/`green`/`blue` (or `r`/`g`/`b`, `diffuse_*`; 8-bit
//! or 16-bit integers, or floats in `[0, 1]`, all sRGB), per-vertex texture coordinates (`s`/`t`, `u`/`v`,
//! `texture_u`/`texture_v`) and `face` `vertex_indices` (or `vertex_index`) polygons, fan-triangulated, with
//! MeshLab's per-face `texcoord` lists; the texture is named by a `comment TextureFile NAME` header line.
//! Point clouds (no faces) are refused with a sentence saying so.

use std::io::BufReader;
use std::path::Path;

use glam::{Vec2, Vec3};
use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{PropertyAccess, PropertyAccessResult};

use super::mesh_io::{check_mesh, load_texture, Material, MeshIoError, TexturedMesh};
use crate::buffer::{srgb8_to_linear, srgb_to_linear};
use crate::geometry::mesh::TriMesh;

/// Largest polygon accepted (vertices per face).
const MAX_POLYGON: usize = 1024;

#[derive(Debug, Default)]
struct PlyVertex {
    p: [f64; 3],
    /// Colour channels as read and the largest value their type holds (1 for floats).
    c: [f64; 3],
    c_max: f64,
    has_color: u8,
    uv: [f64; 2],
    has_uv: u8,
}

impl PlyVertex {
    fn set(&mut self, name: &str, v: f64, max: f64) -> PropertyAccessResult {
        let slot = |c: &mut [f64; 3], k: usize, has: &mut u8, c_max: &mut f64| {
            c[k] = v;
            *has |= 1 << k;
            *c_max = max;
        };
        match name {
            "x" => self.p[0] = v,
            "y" => self.p[1] = v,
            "z" => self.p[2] = v,
            "red" | "r" | "diffuse_red" => slot(&mut self.c, 0, &mut self.has_color, &mut self.c_max),
            "green" | "g" | "diffuse_green" => slot(&mut self.c, 1, &mut self.has_color, &mut self.c_max),
            "blue" | "b" | "diffuse_blue" => slot(&mut self.c, 2, &mut self.has_color, &mut self.c_max),
            "s" | "u" | "texture_u" | "texture_s" => {
                self.uv[0] = v;
                self.has_uv |= 1;
            }
            "t" | "v" | "texture_v" | "texture_t" => {
                self.uv[1] = v;
                self.has_uv |= 2;
            }
            _ => return PropertyAccessResult::Ignored,
        }
        PropertyAccessResult::Set
    }
}

impl PropertyAccess for PlyVertex {
    fn new() -> Self {
        Self::default()
    }
    fn set_char(&mut self, name: &str, v: i8) -> PropertyAccessResult {
        self.set(name, v as f64, i8::MAX as f64)
    }
    fn set_uchar(&mut self, name: &str, v: u8) -> PropertyAccessResult {
        self.set(name, v as f64, u8::MAX as f64)
    }
    fn set_short(&mut self, name: &str, v: i16) -> PropertyAccessResult {
        self.set(name, v as f64, i16::MAX as f64)
    }
    fn set_ushort(&mut self, name: &str, v: u16) -> PropertyAccessResult {
        self.set(name, v as f64, u16::MAX as f64)
    }
    fn set_int(&mut self, name: &str, v: i32) -> PropertyAccessResult {
        self.set(name, v as f64, 255.0)
    }
    fn set_uint(&mut self, name: &str, v: u32) -> PropertyAccessResult {
        self.set(name, v as f64, 255.0)
    }
    fn set_float(&mut self, name: &str, v: f32) -> PropertyAccessResult {
        self.set(name, v as f64, 1.0)
    }
    fn set_double(&mut self, name: &str, v: f64) -> PropertyAccessResult {
        self.set(name, v, 1.0)
    }
}

#[derive(Debug, Default)]
struct PlyFace {
    indices: Vec<i64>,
    texcoord: Vec<f32>,
}

impl PlyFace {
    fn indices(&mut self, name: &str, v: impl Iterator<Item = i64>) -> PropertyAccessResult {
        if name == "vertex_indices" || name == "vertex_index" {
            self.indices = v.collect();
            PropertyAccessResult::Set
        } else {
            PropertyAccessResult::Ignored
        }
    }
}

impl PropertyAccess for PlyFace {
    fn new() -> Self {
        Self::default()
    }
    fn set_list_char(&mut self, name: &str, v: Vec<i8>) -> PropertyAccessResult {
        self.indices(name, v.into_iter().map(i64::from))
    }
    fn set_list_uchar(&mut self, name: &str, v: Vec<u8>) -> PropertyAccessResult {
        self.indices(name, v.into_iter().map(i64::from))
    }
    fn set_list_short(&mut self, name: &str, v: Vec<i16>) -> PropertyAccessResult {
        self.indices(name, v.into_iter().map(i64::from))
    }
    fn set_list_ushort(&mut self, name: &str, v: Vec<u16>) -> PropertyAccessResult {
        self.indices(name, v.into_iter().map(i64::from))
    }
    fn set_list_int(&mut self, name: &str, v: Vec<i32>) -> PropertyAccessResult {
        self.indices(name, v.into_iter().map(i64::from))
    }
    fn set_list_uint(&mut self, name: &str, v: Vec<u32>) -> PropertyAccessResult {
        self.indices(name, v.into_iter().map(i64::from))
    }
    fn set_list_float(&mut self, name: &str, v: Vec<f32>) -> PropertyAccessResult {
        if name == "texcoord" {
            self.texcoord = v;
            return PropertyAccessResult::Set;
        }
        PropertyAccessResult::Ignored
    }
    fn set_list_double(&mut self, name: &str, v: Vec<f64>) -> PropertyAccessResult {
        self.set_list_float(name, v.into_iter().map(|x| x as f32).collect())
    }
}

/// Reads a PLY mesh (see the module documentation). Vertex colours become [`TriMesh::colors`] (linear); UVs (per
/// vertex, or per face corner with seam vertices split) and a `TextureFile` become one textured material.
pub fn read_ply(path: &Path) -> Result<TexturedMesh, MeshIoError> {
    let perr = |message: String| MeshIoError::Ply { path: path.to_path_buf(), message };
    let file = std::fs::File::open(path).map_err(|source| MeshIoError::Io { path: path.to_path_buf(), source })?;
    let mut reader = Reader::new(BufReader::new(file));
    let vertex_parser = Parser::<PlyVertex>::new();
    let header = vertex_parser.read_header(&mut reader).map_err(|e| perr(e.to_string()))?;
    let mut vertices: Vec<PlyVertex> = Vec::new();
    let mut faces: Vec<PlyFace> = Vec::new();
    // Elements must be read in header order; unknown ones (edges, materials) are parsed and dropped.
    for (name, element) in &header.elements {
        match name.as_str() {
            "vertex" => {
                vertices = vertex_parser
                    .read_payload_for_element(&mut reader, element, &header)
                    .map_err(|e| perr(format!("vertex data: {e}")))?
            }
            "face" => {
                faces = Parser::<PlyFace>::new()
                    .read_payload_for_element(&mut reader, element, &header)
                    .map_err(|e| perr(format!("face data: {e}")))?
            }
            other => {
                Parser::<ply_rs_bw::ply::DefaultElement>::new()
                    .read_payload_for_element(&mut reader, element, &header)
                    .map_err(|e| perr(format!("{other} data: {e}")))?;
            }
        }
    }
    if faces.is_empty() {
        return Err(perr(format!(
            "no faces ({} vertices): a point cloud, not a mesh; mesh it first (e.g. Poisson reconstruction in \
             MeshLab or Open3D)",
            vertices.len()
        )));
    }
    let texture_name = header.comments.iter().chain(&header.obj_infos).find_map(|c| {
        let (key, rest) = c.trim().split_once(char::is_whitespace)?;
        key.eq_ignore_ascii_case("TextureFile").then(|| rest.trim().to_string())
    });

    let nv = vertices.len();
    let positions: Vec<Vec3> =
        vertices.iter().map(|v| Vec3::new(v.p[0] as f32, v.p[1] as f32, v.p[2] as f32)).collect();
    let has_color = vertices.iter().any(|v| v.has_color == 7);
    let colors: Vec<Vec3> = if has_color {
        vertices
            .iter()
            .map(|v| {
                if v.has_color != 7 {
                    return Vec3::ONE;
                }
                let c = v.c.map(|x| if x.is_finite() { (x / v.c_max.max(1e-9)).clamp(0.0, 1.0) } else { 0.0 });
                if v.c_max == u8::MAX as f64 {
                    Vec3::from(c.map(|x| srgb8_to_linear((x * 255.0).round() as u8)))
                } else {
                    Vec3::from(c.map(|x| srgb_to_linear(x as f32)))
                }
            })
            .collect()
    } else {
        Vec::new()
    };
    let vertex_uv = vertices.iter().any(|v| v.has_uv == 3);
    let face_uv = faces.iter().any(|f| !f.texcoord.is_empty());
    let textured = texture_name.is_some() && (vertex_uv || face_uv);

    // Triangles, with corners as (vertex, per-face UV) when the UVs come per face.
    let mut out_pos = Vec::new();
    let mut out_col = Vec::new();
    let mut out_uv = Vec::new();
    let mut triangles = Vec::new();
    let mut remap: std::collections::HashMap<(u32, [u32; 2]), u32> = std::collections::HashMap::new();
    let mut corner = |vi: u32, uv: Vec2| -> u32 {
        let key = (vi, if face_uv && textured { [uv.x.to_bits(), uv.y.to_bits()] } else { [0, 0] });
        *remap.entry(key).or_insert_with(|| {
            out_pos.push(positions[vi as usize]);
            if has_color {
                out_col.push(colors[vi as usize]);
            }
            if textured {
                out_uv.push(uv);
            }
            (out_pos.len() - 1) as u32
        })
    };
    for (f, face) in faces.iter().enumerate() {
        let k = face.indices.len();
        if !(3..=MAX_POLYGON).contains(&k) {
            return Err(perr(format!("face {f} has {k} vertices (3 to {MAX_POLYGON} expected)")));
        }
        if let Some(&bad) = face.indices.iter().find(|&&i| i < 0 || i as usize >= nv) {
            return Err(perr(format!("face {f} names vertex {bad}, but there are {nv}")));
        }
        let uv_of = |c: usize| -> Vec2 {
            let v = &vertices[face.indices[c] as usize];
            // PLY texture coordinates are OpenGL's (v up); glTF's v goes down.
            let (u, t) = match face.texcoord.get(2 * c..2 * c + 2) {
                Some(p) if face_uv => (p[0] as f64, p[1] as f64),
                _ => (v.uv[0], v.uv[1]),
            };
            Vec2::new(u as f32, 1.0 - t as f32)
        };
        let c0 = corner(face.indices[0] as u32, uv_of(0));
        let mut prev = corner(face.indices[1] as u32, uv_of(1));
        for c in 2..k {
            let next = corner(face.indices[c] as u32, uv_of(c));
            triangles.push([c0, prev, next]);
            prev = next;
        }
    }
    let mut mesh = TriMesh::new(out_pos, triangles);
    mesh.colors = out_col;
    mesh.uvs = out_uv;
    let materials = match (&texture_name, textured) {
        (Some(name), true) => {
            let dir = path.parent().unwrap_or(Path::new("."));
            vec![Material::textured(name, load_texture(dir, name, path)?)]
        }
        _ => Vec::new(),
    };
    let out = TexturedMesh { mesh, materials, triangle_materials: Vec::new() };
    check_mesh(path, &out)?;
    Ok(out)
}
