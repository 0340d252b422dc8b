//! The MakeHuman "hm08" base mesh (CC0, copied in `assets/makehuman/`, compiled into the binary): the full
//! 19,158-vertex mesh (body, helpers and joint cubes, which the rig and morph targets need) and the body-only
//! surface (first 13,380 vertices, first 13,378 quads, triangulated, UV seams split).
//!
//! Units are MakeHuman's: decimetres, +Y up, the model faces +Z, +X is the model's left.

use std::collections::HashMap;

use glam::{Vec2, Vec3};

use super::BodyError;

const BASE_OBJ: &str = include_str!("../../assets/makehuman/base.obj");
const VERTEX_GROUPS_JSON: &str = include_str!("../../assets/makehuman/basemesh_vertex_groups.json");

/// Vertices of the full base mesh.
pub const FULL_VERTEX_COUNT: usize = 19_158;
/// Vertices of the body surface (a prefix of the full mesh).
pub const BODY_VERTEX_COUNT: usize = 13_380;
/// Quads of the body surface (a prefix of the faces).
pub const BODY_QUAD_COUNT: usize = 13_378;

/// The parsed base mesh.
#[derive(Clone, Debug)]
pub struct BaseMesh {
    /// All 19,158 vertex positions (decimetres).
    pub full_positions: Vec<Vec3>,
    /// Named vertex groups as inclusive index ranges (joint cubes, helpers, `body`, `Left`...).
    pub groups: HashMap<String, Vec<[u32; 2]>>,
    /// Body triangles over split vertices (CCW from outside).
    pub triangles: Vec<[u32; 3]>,
    /// For each split vertex, its index in the base mesh (`< BODY_VERTEX_COUNT`).
    pub source_vertex: Vec<u32>,
    /// Per split vertex UV, glTF convention (v down).
    pub uvs: Vec<Vec2>,
    /// Body quads over base-mesh vertex indices (unsplit), for topology checks.
    pub quads: Vec<[u32; 4]>,
}

impl BaseMesh {
    /// Parses the embedded `base.obj` and `basemesh_vertex_groups.json`, checking the facts the body extraction
    /// relies on (counts, index ranges).
    pub fn load() -> Result<Self, BodyError> {
        let bad = |m: String| BodyError::Asset { what: "assets/makehuman/base.obj".into(), message: m };
        let mut full_positions = Vec::with_capacity(FULL_VERTEX_COUNT);
        let mut texcoords = Vec::with_capacity(21_334);
        let mut group = String::new();
        let mut quads = Vec::with_capacity(BODY_QUAD_COUNT);
        let mut quad_uvs = Vec::with_capacity(BODY_QUAD_COUNT);
        for (n, line) in BASE_OBJ.lines().enumerate() {
            let mut it = line.split_whitespace();
            let nums = |it: std::str::SplitWhitespace| -> Vec<f32> { it.filter_map(|t| t.parse().ok()).collect() };
            match it.next() {
                Some("v") => {
                    let c = nums(it);
                    if c.len() < 3 {
                        return Err(bad(format!("line {}: short vertex", n + 1)));
                    }
                    full_positions.push(Vec3::new(c[0], c[1], c[2]));
                }
                Some("vt") => {
                    let c = nums(it);
                    if c.len() < 2 {
                        return Err(bad(format!("line {}: short texcoord", n + 1)));
                    }
                    texcoords.push(Vec2::new(c[0], 1.0 - c[1]));
                }
                Some("g") => group = it.next().unwrap_or("").to_string(),
                Some("f") if group == "body" => {
                    let mut q = [0u32; 4];
                    let mut t = [0u32; 4];
                    let corners: Vec<&str> = it.collect();
                    if corners.len() != 4 {
                        return Err(bad(format!("line {}: body face is not a quad", n + 1)));
                    }
                    for (k, c) in corners.iter().enumerate() {
                        let mut p = c.split('/');
                        let vi: u32 = p.next().and_then(|s| s.parse().ok()).ok_or(bad(format!("line {}", n + 1)))?;
                        let ti: u32 = p.next().and_then(|s| s.parse().ok()).ok_or(bad(format!("line {}", n + 1)))?;
                        q[k] = vi - 1;
                        t[k] = ti - 1;
                    }
                    quads.push(q);
                    quad_uvs.push(t);
                }
                _ => {}
            }
        }
        if full_positions.len() != FULL_VERTEX_COUNT || quads.len() != BODY_QUAD_COUNT {
            return Err(bad(format!(
                "expected {FULL_VERTEX_COUNT} vertices and {BODY_QUAD_COUNT} body quads, found {} and {}",
                full_positions.len(),
                quads.len()
            )));
        }
        if quads.iter().flatten().any(|&v| v as usize >= BODY_VERTEX_COUNT)
            || quad_uvs.iter().flatten().any(|&t| t as usize >= texcoords.len())
        {
            return Err(bad("a body face indexes outside the body vertices or texcoords".into()));
        }
        let groups: HashMap<String, Vec<[u32; 2]>> = serde_json::from_str(VERTEX_GROUPS_JSON).map_err(|e| {
            BodyError::Asset { what: "assets/makehuman/basemesh_vertex_groups.json".into(), message: e.to_string() }
        })?;

        // Split seam vertices: one output vertex per (vertex, texcoord) pair.
        let mut remap: HashMap<(u32, u32), u32> = HashMap::with_capacity(BODY_VERTEX_COUNT + 1200);
        let mut source_vertex = Vec::with_capacity(BODY_VERTEX_COUNT + 1200);
        let mut uvs = Vec::with_capacity(BODY_VERTEX_COUNT + 1200);
        let mut triangles = Vec::with_capacity(2 * BODY_QUAD_COUNT);
        for (q, t) in quads.iter().zip(&quad_uvs) {
            let mut idx = [0u32; 4];
            for k in 0..4 {
                idx[k] = *remap.entry((q[k], t[k])).or_insert_with(|| {
                    source_vertex.push(q[k]);
                    uvs.push(texcoords[t[k] as usize]);
                    (source_vertex.len() - 1) as u32
                });
            }
            // Split each (possibly non-planar) quad along its shorter diagonal.
            let p = q.map(|i| full_positions[i as usize]);
            if p[0].distance_squared(p[2]) <= p[1].distance_squared(p[3]) {
                triangles.push([idx[0], idx[1], idx[2]]);
                triangles.push([idx[0], idx[2], idx[3]]);
            } else {
                triangles.push([idx[0], idx[1], idx[3]]);
                triangles.push([idx[1], idx[2], idx[3]]);
            }
        }
        Ok(Self { full_positions, groups, triangles, source_vertex, uvs, quads })
    }

    /// The vertex indices of a named group (empty when the group does not exist).
    pub fn group_vertices(&self, name: &str) -> Vec<u32> {
        self.groups.get(name).map(|r| r.iter().flat_map(|&[a, b]| a..=b).collect()).unwrap_or_default()
    }

    /// Centroid of a named group in the given full-mesh positions.
    pub fn group_centroid(&self, name: &str, positions: &[Vec3]) -> Option<Vec3> {
        let v = self.group_vertices(name);
        if v.is_empty() || v.iter().any(|&i| i as usize >= positions.len()) {
            return None;
        }
        Some(v.iter().map(|&i| positions[i as usize]).sum::<Vec3>() / v.len() as f32)
    }

    /// Body positions for the split vertices, taken from full-mesh positions.
    pub fn body_positions(&self, full: &[Vec3]) -> Vec<Vec3> {
        self.source_vertex.iter().map(|&i| full[i as usize]).collect()
    }
}
