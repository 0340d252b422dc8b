//! The body's own frame: carrying points between a fitted pose and the rest pose of the same body.
//!
//! Linear blend skinning poses a body vertex `v` by the weighted sum of its bones' transforms,
//! `x = sum_b w_vb G_b r` with `sum_b w_vb = 1`; a weighted sum of affine maps with weights summing to one is an
//! affine map, `M_v = sum_b w_vb G_b`, so `x = M_v r` and the rest position is `r = M_v^-1 x`. [`BodyFrame`]
//! keeps `M_v` and its inverse per body vertex for one pose: a point on (or near) the posed body, carried by the
//! transform of a vertex or of a triangle (the barycentric blend of its corners' transforms, the same rule one
//! level up), goes to the rest pose and back exactly up to rounding. This is the frame a person model that
//! persists across the frames of a live source keeps what it has seen in: the rest pose does not move when the
//! person turns or raises an arm.
//!
//! A blend of very different rotations can be singular (two bones turned +90 and -90 degrees about one axis,
//! weighted half and half, flatten that axis's plane): such a vertex has no inverse ([`BodyFrame::to_rest`] gives
//! `None`), never a NaN.

use glam::{DAffine3, DMat3, DVec3};

use super::base::BODY_VERTEX_COUNT;
use super::model::{BodyModel, Pose};

/// `|det|` of a blended transform's linear part, relative to the cube of its scale (the pose's uniform scale),
/// below which the vertex has no inverse.
pub const MIN_RELATIVE_DETERMINANT: f64 = 1e-6;

/// One pose of a body: per body vertex (base-mesh index `< BODY_VERTEX_COUNT`) its rest position, its posed one
/// and the blended skinning transform between them.
#[derive(Clone, Debug)]
pub struct BodyFrame {
    /// Rest positions of the pose's shape (decimetres).
    pub rest: Vec<DVec3>,
    /// Posed positions (body cube).
    pub posed: Vec<DVec3>,
    /// `M_v`: rest to posed.
    blend: Vec<DAffine3>,
    /// `M_v^-1` where `M_v` is invertible.
    inverse: Vec<Option<DAffine3>>,
    /// The transforms' uniform scale (the invertibility test's reference).
    scale: f64,
}

/// The weighted sum of affine maps `sum_k w_k g_k` (weights summing to one give an affine map).
pub fn blend(weights: impl IntoIterator<Item = (f64, DAffine3)>) -> DAffine3 {
    let mut m = DMat3::ZERO;
    let mut t = DVec3::ZERO;
    for (w, g) in weights {
        m += g.matrix3 * w;
        t += g.translation * w;
    }
    DAffine3::from_mat3_translation(m, t)
}

/// The inverse of `m` when its linear part's `|det|` is at least [`MIN_RELATIVE_DETERMINANT`] times `scale³`
/// and everything is finite.
fn invert(m: &DAffine3, scale: f64) -> Option<DAffine3> {
    let det = m.matrix3.determinant();
    let floor = MIN_RELATIVE_DETERMINANT * scale.abs().powi(3);
    if !det.is_finite() || det.abs() < floor || !m.translation.is_finite() {
        return None;
    }
    let inv = m.inverse();
    (inv.matrix3.is_finite() && inv.translation.is_finite()).then_some(inv)
}

impl BodyFrame {
    /// The frame of `pose` on `model`.
    pub fn new(model: &BodyModel, pose: &Pose) -> Self {
        let heads = model.rest_heads(&pose.shape);
        let g = model.skinning(pose, &heads);
        let mut rest = Vec::with_capacity(BODY_VERTEX_COUNT);
        let mut blends = Vec::with_capacity(BODY_VERTEX_COUNT);
        for v in 0..BODY_VERTEX_COUNT {
            rest.push(model.rest_vertex(v as u32, &pose.shape));
            let m = match model.rig.weights.get(v) {
                // The rig's weights sum to one in f32; summed again in f64 they are renormalised, so the blend is an
                // affine combination to f64 precision.
                Some(list) if list.iter().map(|&(_, w)| w as f64).sum::<f64>() > 0.0 => {
                    let sum: f64 = list.iter().map(|&(_, w)| w as f64).sum();
                    blend(list.iter().map(|&(b, w)| (w as f64 / sum, g[b as usize])))
                }
                // A vertex without weights stays where it is, as `skin_vertex` leaves it (the rig gives every body
                // vertex weights; this is only the out-of-range case).
                _ => DAffine3::IDENTITY,
            };
            blends.push(m);
        }
        Self::from_blends(rest, blends, pose.scale)
    }

    /// A frame from rest positions and their blended transforms (`scale`: the transforms' uniform scale, for the
    /// invertibility test).
    pub fn from_blends(rest: Vec<DVec3>, blend: Vec<DAffine3>, scale: f64) -> Self {
        let posed = rest.iter().zip(&blend).map(|(r, m)| m.transform_point3(*r)).collect();
        let inverse = blend.iter().map(|m| invert(m, scale)).collect();
        Self { rest, posed, blend, inverse, scale }
    }

    /// Body vertices in the frame.
    pub fn len(&self) -> usize {
        self.rest.len()
    }

    /// Whether the frame has no vertex.
    pub fn is_empty(&self) -> bool {
        self.rest.is_empty()
    }

    /// Posed point `p`, carried by vertex `v`'s transform, in the rest pose (`None`: `v` out of range, or its
    /// transform is singular, or `p` is not finite).
    pub fn to_rest(&self, v: usize, p: DVec3) -> Option<DVec3> {
        let inv = (*self.inverse.get(v)?)?;
        p.is_finite().then(|| inv.transform_point3(p))
    }

    /// Rest point `r`, carried by vertex `v`'s transform, in the pose (`None`: `v` out of range or `r` not finite).
    pub fn to_pose(&self, v: usize, r: DVec3) -> Option<DVec3> {
        let m = self.blend.get(v)?;
        r.is_finite().then(|| m.transform_point3(r))
    }

    /// The transform of a point of triangle `corners` at barycentric weights `bary` (summing to one): the blend of
    /// the corners' transforms (`None` for an index out of range).
    pub fn triangle_transform(&self, corners: [u32; 3], bary: [f64; 3]) -> Option<DAffine3> {
        let mut parts = [(0.0, DAffine3::IDENTITY); 3];
        for k in 0..3 {
            parts[k] = (bary[k], *self.blend.get(corners[k] as usize)?);
        }
        Some(blend(parts))
    }

    /// Posed point `p` near triangle `corners` (body vertex indices) at barycentric weights `bary`, in the rest
    /// pose by [`BodyFrame::triangle_transform`] (`None` when singular or not finite).
    pub fn to_rest_at(&self, corners: [u32; 3], bary: [f64; 3], p: DVec3) -> Option<DVec3> {
        let inv = invert(&self.triangle_transform(corners, bary)?, self.scale)?;
        p.is_finite().then(|| inv.transform_point3(p))
    }

    /// Rest point `r` at triangle `corners`, barycentric `bary`, in the pose.
    pub fn to_pose_at(&self, corners: [u32; 3], bary: [f64; 3], r: DVec3) -> Option<DVec3> {
        let m = self.triangle_transform(corners, bary)?;
        r.is_finite().then(|| m.transform_point3(r))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DQuat;

    use super::super::model::{JOINT_PARAMS, SHAPE_COUNT};

    /// A pose far from rest: every joint turned, the body turned, scaled and moved, the shape off neutral.
    fn busy_pose(model: &BodyModel) -> Pose {
        let mut joints = [0.0; JOINT_PARAMS];
        for (k, j) in joints.iter_mut().enumerate() {
            *j = 0.55 * ((k as f64 * 1.7).sin());
        }
        Pose {
            scale: 1.8 / model.rest_height,
            translation: DVec3::new(0.1, -0.05, 0.2),
            global: DVec3::new(0.2, 2.4, -0.1),
            joints,
            shape: [0.2, 0.9, 0.6, 0.35],
        }
    }

    #[test]
    fn pose_rest_pose_is_exact_on_the_bodys_own_vertices() {
        let model = BodyModel::shared().expect("body model data (bash scripts/setup.d/synth.sh)");
        let pose = busy_pose(model);
        let frame = BodyFrame::new(model, &pose);
        assert_eq!(frame.len(), BODY_VERTEX_COUNT);
        // The blended transforms pose the body as the model's own skinning does (which sums the f32 weights
        // without renormalising them in f64: 1e-7 of a coordinate apart).
        let heads = model.rest_heads(&pose.shape);
        let g = model.skinning(&pose, &heads);
        let (mut worst_rest, mut worst_pose, mut worst_skin) = (0.0f64, 0.0f64, 0.0f64);
        for v in 0..frame.len() {
            let skinned = model.skin_vertex(v as u32, &pose.shape, &g);
            worst_skin = worst_skin.max((frame.posed[v] - skinned).length());
            let r = frame.to_rest(v, frame.posed[v]).expect("every vertex of this pose is invertible");
            worst_rest = worst_rest.max((r - frame.rest[v]).length());
            let back = frame.to_pose(v, r).unwrap();
            worst_pose = worst_pose.max((back - frame.posed[v]).length());
        }
        // Rest positions are decimetres (the body ~17 high), posed ones cube units (~1.8 high): 1e-9 of either.
        assert!(worst_skin < 1e-6, "skinning {worst_skin:e}");
        assert!(worst_rest < 1e-9, "pose -> rest {worst_rest:e}");
        assert!(worst_pose < 1e-10, "pose -> rest -> pose {worst_pose:e}");
        // A point off the surface, carried by a triangle's blended transform, comes back too.
        let t = model.base.triangles[1234].map(|i| model.base.source_vertex[i as usize]);
        let bary = [0.2, 0.5, 0.3];
        let p = (0..3).map(|k| frame.posed[t[k] as usize] * bary[k]).sum::<DVec3>() + DVec3::new(0.01, -0.02, 0.015);
        let r = frame.to_rest_at(t, bary, p).unwrap();
        assert!((frame.to_pose_at(t, bary, r).unwrap() - p).length() < 1e-10);
        // The rest pose itself (identity joints, unit scale, no move) leaves rest points where they are.
        let rest = Pose {
            scale: 1.0,
            translation: DVec3::ZERO,
            global: DVec3::ZERO,
            joints: [0.0; JOINT_PARAMS],
            shape: [0.5; SHAPE_COUNT],
        };
        let still = BodyFrame::new(model, &rest);
        // ... up to the move of the hip centre (the pivot of the global similarity) to the origin.
        let neutral = model.rest_heads(&rest.shape);
        let pivot = 0.5 * (neutral[model.joint_bones[7]] + neutral[model.joint_bones[8]]);
        for v in 0..still.len() {
            assert!((still.posed[v] - (still.rest[v] - pivot)).length() < 1e-12, "vertex {v}");
        }
    }

    #[test]
    fn a_blend_is_the_closed_form_and_a_flattening_blend_has_no_inverse() {
        // Half of a +t and half of a -t rotation about z: [[cos t, 0], [0, cos t]] in the xy plane, 1 along z.
        for t in [0.3f64, 1.0, 1.4] {
            let (a, b) =
                (DAffine3::from_quat(DQuat::from_rotation_z(t)), DAffine3::from_quat(DQuat::from_rotation_z(-t)));
            let m = blend([(0.5, a), (0.5, b)]);
            let want = DMat3::from_diagonal(DVec3::new(t.cos(), t.cos(), 1.0));
            assert!(m.matrix3.abs_diff_eq(want, 1e-12), "{t}");
            let f = BodyFrame::from_blends(vec![DVec3::new(1.0, 2.0, 3.0)], vec![m], 1.0);
            let x = f.posed[0];
            assert!((x - DVec3::new(t.cos(), 2.0 * t.cos(), 3.0)).length() < 1e-12);
            assert!((f.to_rest(0, x).unwrap() - DVec3::new(1.0, 2.0, 3.0)).length() < 1e-9);
        }
        // At 90 degrees the blend flattens the xy plane: no inverse, no NaN.
        let t = std::f64::consts::FRAC_PI_2;
        let (a, b) = (DAffine3::from_quat(DQuat::from_rotation_z(t)), DAffine3::from_quat(DQuat::from_rotation_z(-t)));
        let f = BodyFrame::from_blends(vec![DVec3::ONE], vec![blend([(0.5, a), (0.5, b)])], 1.0);
        assert_eq!(f.to_rest(0, DVec3::ONE), None);
        // Out of range and non-finite inputs.
        assert_eq!(f.to_rest(5, DVec3::ONE), None);
        let id = BodyFrame::from_blends(vec![DVec3::ZERO], vec![DAffine3::IDENTITY], 1.0);
        assert_eq!(id.to_rest(0, DVec3::NAN), None);
        assert_eq!(id.to_pose(0, DVec3::INFINITY), None);
        assert_eq!(id.to_pose(1, DVec3::ONE), None);
    }
}
