//! Fitting the body model ([`super::model`]) to a photo's pose landmarks under the orthographic source camera.
//!
//! Least squares over the [`Pose`] parameters, solved with Levenberg–Marquardt (the `levenberg-marquardt`
//! crate over nalgebra; analytic Jacobian in the pose parameters, forward differences in the four shape sliders,
//! checked against central differences by a unit test; [`FitOptions::stepbound`] keeps the first steps small):
//! - **2-D landmarks**: the model point of each landmark projects (x, y of the body cube) onto the landmark,
//!   weighted by its visibility; landmarks the network does not see (visibility < [`FitOptions::min_visibility`])
//!   or that lie outside the photo's frame are left out, so nothing is invented where the photo is cut and a
//!   hidden arm (its own joints, no residual) cannot pull a visible one.
//! - **Relative depths** of the world landmarks: the model points' depths about their weighted mean follow the
//!   world landmarks' (metres, scaled to cube units by the least-squares ratio of the 2-D landmarks to the world
//!   landmarks' x, y).
//! - **Beyond the frame**: a landmark the network places beyond an edge of the photo's frame that cuts the person
//!   (the mask reaches it: the legs of a photo cut at the waist) must not come back inside the frame: one-sided, by how far inside the frame the model puts its point. Without
//!   it nothing stops a thigh of a cut photo from pointing at the camera (its knee then projects inside the photo,
//!   behind the visible body, where the one-sided silhouette term does not see it).
//! - **Silhouette**: sampled body vertices that fall outside the person's mask (and inside the photo) are pulled
//!   in by the mask's distance transform (one-sided: clothes and hair make the mask larger than the body).
//! - **Legs the photo does not show**: a leg whose hip is used but whose knee is not hangs from that hip as in the
//!   rest pose (weak knee and ankle targets, [`HANGING_WEIGHT`]); without them such a leg followed the pelvis, and
//!   a person bent at the waist got legs sticking out behind (with [`super::prior::legs_it_sees`], release
//!   builds: `r2human eval --subjects 8` mean volumetric IoU of the body prior 0.560 -> 0.567, the Mr. Fixit scan
//!   0.436 -> 0.476; docs/geometry.md, "The body prior").
//! - **Prior**: every joint rotation is pulled toward the rest pose, the shape toward the neutral body, the hip
//!   centre toward depth 0; joint limits (hinge penalties) keep elbows and knees bending one way and every joint
//!   inside a plausible range, so a bad landmark cannot give an impossible body.
//!
//! Live input warm-starts from the previous frame's [`Pose`] ([`fit_body`] with `start`).

use glam::{DAffine3, DMat3, DQuat, DVec2, DVec3, Vec2};
use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{storage::Owned, DMatrix, DVector, Dyn};

use super::distance::DistanceField;
use super::model::{BodyModel, ModelPoint, Pose, JOINTS, JOINT_PARAMS, PARAM_COUNT};
use super::pose::{PoseLandmarks, LANDMARK_COUNT};
use crate::buffer::GrayImage;

/// Settings of the fit.
#[derive(Clone, Debug)]
pub struct FitOptions {
    /// Landmarks below this visibility are not used.
    pub min_visibility: f32,
    /// Standard deviation of a 2-D landmark (cube units).
    pub sigma_2d: f64,
    /// Standard deviation of a relative landmark depth (cube units).
    pub sigma_depth: f64,
    /// Distance outside the mask that costs as much as one landmark sigma (cube units).
    pub sigma_silhouette: f64,
    /// Prior standard deviation of the shape sliders.
    pub sigma_shape: f64,
    /// Prior standard deviation of the torso's lean in depth (the depth component of the unit hip-to-shoulder
    /// vector; 0 switches the prior off): a person stands upright unless the landmarks say otherwise.
    pub sigma_upright: f64,
    /// Residual evaluations the solver may spend, per parameter (the crate's `patience`).
    pub patience: usize,
    /// How the Jacobian is computed.
    pub jacobian: JacobianKind,
    /// The solver's first trust region, as a fraction of the scaled parameter vector's length (the crate's
    /// `stepbound`, MINPACK's `factor`). The crate's default of 100 lets the first Gauss–Newton step from the rest
    /// pose swing an arm through 150° into a folded local minimum (synthetic seed 3: cost 45.9 instead of 5.8);
    /// 0.03–0.3 all reach the low minimum on the test subjects (`cargo test --test body`), 1 and above do not.
    pub stepbound: f64,
    /// Relative tolerance of the solver on the cost's reduction and on the step (the crate's `ftol` and `xtol`; its
    /// default, 30 machine epsilons, spent half the evaluations polishing the last digits). At 1e-4 the test
    /// subjects' joints are the same to 1e-4 units with 30 instead of 65 evaluations cold, 12 instead of 40 warm.
    pub tolerance: f64,
    /// A warm start (the previous frame's pose) is kept as it is when the solver lowers the cost from it by less
    /// than this fraction: the frame asks for no change the fit can see. The cost is flat along some directions
    /// (an arm's depth, the legs'), and on a still person each warm restart otherwise slid along them: the same
    /// frame fitted again moved the joints by 0.036 cube units and `--geometry body-placed` flickered from the
    /// side. 0 turns it off.
    pub warm_hold: f64,
    /// How far a warm fit may move from its start (the previous frame's pose), in units of [`anchor_step`]: each
    /// parameter gets a residual `(x - start) / (warm_anchor * step)`, a pull toward the last frame that the
    /// photo's own terms outweigh when the person moves. Live frames of a photo shifted by up to a pixel (the
    /// pose network's landmarks then move 2-17 px) flickered from the side with the fit following them (body
    /// frozen: 0.997 consecutive mask IoU, followed: 0.983); at 0.5 a person moving 3 px a frame agrees with
    /// fits made cold frame by frame no worse than without it (docs/live.md, "Stability"). 0 turns it off; cold fits
    /// have none.
    pub warm_anchor: f64,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            min_visibility: 0.5,
            sigma_2d: 0.012,
            sigma_depth: 0.03,
            sigma_silhouette: 0.02,
            sigma_shape: 0.35,
            sigma_upright: 0.2,
            patience: 12,
            jacobian: JacobianKind::default(),
            stepbound: 0.1,
            tolerance: 1e-4,
            warm_hold: 0.01,
            warm_anchor: 0.5,
        }
    }
}

/// Prior standard deviation (radians) and limit (radians, on the rotation angle; `(lo, hi)` for 1-DOF joints) of
/// each joint in [`JOINTS`] order.
const JOINT_PRIOR: [(f64, (f64, f64)); 11] = [
    (0.25, (0.0, 0.6)), // lower spine
    (0.25, (0.0, 0.6)), // chest
    (0.45, (0.0, 1.1)), // neck
    (1.2, (0.0, 2.6)),  // upper arm L
    (1.2, (0.0, 2.6)),  // upper arm R
    (1.4, (-0.1, 2.7)), // elbow L (positive bends the forearm forward)
    (1.4, (-0.1, 2.7)), // elbow R
    (0.7, (0.0, 2.0)),  // thigh L
    (0.7, (0.0, 2.0)),  // thigh R
    (1.0, (-2.6, 0.1)), // knee L (negative bends the shin backward)
    (1.0, (-2.6, 0.1)), // knee R
];
/// Weight of a joint-limit violation (per radian beyond the limit).
const LIMIT_WEIGHT: f64 = 30.0;

/// The photo-side data of a fit: landmarks in a `resolution`² source view and the distance transform of the
/// person's mask there.
pub struct FitTarget<'a> {
    /// Landmarks in the source view.
    pub landmarks: &'a PoseLandmarks,
    /// Source view side (pixels).
    pub resolution: usize,
    /// Distance (pixels) to the person's mask.
    pub outside: DistanceField,
    /// Which edges of the photo's frame cut the person (the mask reaches them): left, top, right, bottom.
    pub cut_edges: [bool; 4],
}

impl<'a> FitTarget<'a> {
    /// The target of landmarks and the person's mask (`[0, 1]`, threshold 0.5) in the same source view.
    pub fn new(landmarks: &'a PoseLandmarks, mask: &GrayImage) -> Self {
        let outside = DistanceField::new(mask.width, mask.height, |i| mask.data[i] >= 0.5);
        let cut_edges = cut_edges(mask, landmarks.frame_min, landmarks.frame_max);
        Self { landmarks, resolution: mask.width.max(1), outside, cut_edges }
    }
}

/// Which edges of the frame `(lo, hi)` (pixels) the mask reaches (a mask pixel in the first or last pixel row or
/// column inside the frame): left, top, right, bottom.
pub fn cut_edges(mask: &GrayImage, lo: Vec2, hi: Vec2) -> [bool; 4] {
    let (w, h) = (mask.width as i64, mask.height as i64);
    if w == 0 || h == 0 || !(lo.is_finite() && hi.is_finite()) {
        return [false; 4];
    }
    let clamp_c = |x: f32| (x.floor() as i64).clamp(0, w - 1) as usize;
    let clamp_r = |y: f32| (y.floor() as i64).clamp(0, h - 1) as usize;
    let (c0, c1) = (clamp_c(lo.x), clamp_c(hi.x - 1.0));
    let (r0, r1) = (clamp_r(lo.y), clamp_r(hi.y - 1.0));
    let on = |c: usize, r: usize| *mask.get(c, r) >= 0.5;
    [
        (r0..=r1).any(|r| on(c0, r)),
        (c0..=c1).any(|c| on(c, r0)),
        (r0..=r1).any(|r| on(c1, r)),
        (c0..=c1).any(|c| on(c, r1)),
    ]
}

/// The result of a fit.
#[derive(Clone, Debug)]
pub struct BodyFit {
    /// The fitted pose and shape.
    pub pose: Pose,
    /// Landmarks that took part (index, weight).
    pub used: Vec<(usize, f64)>,
    /// Final cost (half the sum of squared residuals).
    pub cost: f64,
    /// Residual evaluations the solver made.
    pub evaluations: usize,
}

/// One used landmark: model point, target (cube x, y), relative depth target, weight.
#[derive(Clone, Copy, Debug)]
struct Term {
    point: ModelPoint,
    xy: DVec2,
    depth: f64,
    weight: f64,
}

struct Problem<'a> {
    model: &'a BodyModel,
    target: &'a FitTarget<'a>,
    terms: Vec<Term>,
    /// Model points of the landmarks the network places outside the photo's frame.
    beyond: Vec<ModelPoint>,
    options: FitOptions,
    params: DVector<f64>,
    residual_count: usize,
    /// The warm start and how far each parameter may move from it ([`FitOptions::warm_anchor`]); `None` on a cold
    /// fit.
    anchor: Option<([f64; PARAM_COUNT], [f64; PARAM_COUNT])>,
}

/// The unit of [`FitOptions::warm_anchor`] per parameter of `start`: about how much a parameter of a still person's
/// fit moves from frame to frame with the pose network's jitter: 1 % of the scale, 0.01 body-cube units of
/// translation in the image plane and 0.05 in depth, 0.05 rad of rotation and per joint angle, 0.05 of each shape
/// target.
pub fn anchor_step(start: &Pose) -> [f64; PARAM_COUNT] {
    let mut step = [0.05; PARAM_COUNT];
    step[0] = 0.01 * start.scale.abs().max(1e-3);
    step[1] = 0.01;
    step[2] = 0.01;
    step
}

fn to_cube(p: Vec2, resolution: usize) -> DVec2 {
    let half = resolution as f64 * 0.5;
    DVec2::new(p.x as f64 / half - 1.0, 1.0 - p.y as f64 / half)
}

fn to_pixel(p: DVec3, resolution: usize) -> (f32, f32) {
    let half = resolution as f64 * 0.5;
    (((p.x + 1.0) * half) as f32, ((1.0 - p.y) * half) as f32)
}

impl Problem<'_> {
    fn residuals_of(&self, x: &[f64], out: &mut Vec<f64>) {
        out.clear();
        let pose = Pose::from_slice(x);
        let model = self.model;
        let heads = model.rest_heads(&pose.shape);
        let g = model.skinning(&pose, &heads);
        let o = &self.options;
        // 2-D landmarks and relative depths.
        let pts: Vec<DVec3> = self.terms.iter().map(|t| model.point(t.point, &pose.shape, &heads, &g)).collect();
        let wsum: f64 = self.terms.iter().map(|t| t.weight).sum::<f64>().max(1e-9);
        let zmean = self.terms.iter().zip(&pts).map(|(t, p)| t.weight * p.z).sum::<f64>() / wsum;
        for (t, p) in self.terms.iter().zip(&pts) {
            let w = t.weight.sqrt();
            out.push(w * (p.x - t.xy.x) / o.sigma_2d);
            out.push(w * (p.y - t.xy.y) / o.sigma_2d);
            out.push(w * ((p.z - zmean) - t.depth) / o.sigma_depth);
        }
        // Silhouette: sampled vertices inside the photo but outside the mask.
        let res = self.target.resolution;
        let px = 2.0 / res as f64;
        let lm = self.target.landmarks;
        // Landmarks beyond the photo's frame stay beyond it (one-sided: how far inside the frame the model puts them).
        for &b in &self.beyond {
            let (u, w) = to_pixel(model.point(b, &pose.shape, &heads, &g), res);
            let inside = (u - lm.frame_min.x).min(w - lm.frame_min.y).min(lm.frame_max.x - u).min(lm.frame_max.y - w);
            out.push(inside.max(0.0) as f64 * px / o.sigma_2d);
        }
        for &v in &model.samples {
            let p = model.skin_vertex(v, &pose.shape, &g);
            let (u, w) = to_pixel(p, res);
            let inside_photo = u >= lm.frame_min.x && w >= lm.frame_min.y && u <= lm.frame_max.x && w <= lm.frame_max.y;
            let d = if inside_photo { self.target.outside.distance_at(u, w) as f64 * px } else { 0.0 };
            out.push(if d.is_finite() { d / o.sigma_silhouette } else { 0.0 });
        }
        // Priors and limits.
        let mut k = 0;
        for (j, (_, dof)) in JOINTS.iter().enumerate() {
            let (sigma, (lo, hi)) = JOINT_PRIOR[j];
            let v = &x[7 + k..7 + k + dof];
            for &a in v {
                out.push(a / sigma);
            }
            if *dof == 3 {
                let angle = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                out.push(LIMIT_WEIGHT * (angle - hi).max(0.0));
            } else {
                out.push(LIMIT_WEIGHT * ((lo - v[0]).max(0.0) + (v[0] - hi).max(0.0)));
            }
            k += dof;
        }
        for &b in &pose.shape {
            out.push((b - 0.5) / o.sigma_shape);
            out.push(LIMIT_WEIGHT * ((-b).max(0.0) + (b - 1.0).max(0.0)));
        }
        // Global rotation: people stand roughly upright (pitch and roll), any yaw.
        out.push(pose.global.x / 0.5);
        out.push(pose.global.z / 0.5);
        out.push(pose.translation.z / 0.2);
        out.push(self.upright(x));
        if let Some((start, spread)) = &self.anchor {
            out.extend(x.iter().zip(start).zip(spread).map(|((v, s), d)| (v - s) / d));
        }
        for r in out.iter_mut() {
            if !r.is_finite() {
                *r = 1e6;
            }
        }
    }
}

impl Problem<'_> {
    /// The torso's lean in depth: the depth component of the unit vector from the model's hip centre to its
    /// shoulder centre, over [`FitOptions::sigma_upright`] (0 when the prior is off or the torso degenerate).
    fn upright(&self, x: &[f64]) -> f64 {
        use super::pose::index::{LEFT_HIP, LEFT_SHOULDER, RIGHT_HIP, RIGHT_SHOULDER};
        let sigma = self.options.sigma_upright;
        if sigma.is_nan() || sigma <= 0.0 {
            return 0.0;
        }
        let model = self.model;
        let pose = Pose::from_slice(x);
        let heads = model.rest_heads(&pose.shape);
        let g = model.skinning(&pose, &heads);
        let at = |i: usize| model.landmark_points[i].map(|p| model.point(p, &pose.shape, &heads, &g));
        let (Some(ls), Some(rs), Some(lh), Some(rh)) =
            (at(LEFT_SHOULDER), at(RIGHT_SHOULDER), at(LEFT_HIP), at(RIGHT_HIP))
        else {
            return 0.0;
        };
        let torso = 0.5 * (ls + rs) - 0.5 * (lh + rh);
        let length = torso.length();
        if length > 1e-9 && length.is_finite() {
            torso.z / length / sigma
        } else {
            0.0
        }
    }
}

impl LeastSquaresProblem<f64, Dyn, Dyn> for Problem<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, x: &DVector<f64>) {
        self.params.copy_from(x);
    }

    fn params(&self) -> DVector<f64> {
        self.params.clone()
    }

    fn residuals(&self) -> Option<DVector<f64>> {
        let mut out = Vec::with_capacity(self.residual_count);
        self.residuals_of(self.params.as_slice(), &mut out);
        Some(DVector::from_vec(out))
    }

    fn jacobian(&self) -> Option<DMatrix<f64>> {
        Some(match self.options.jacobian {
            JacobianKind::Analytic => self.jacobian_at(self.params.as_slice()),
            JacobianKind::ForwardDifference => self.difference_jacobian_at(self.params.as_slice()),
        })
    }
}

/// How the fitter computes the Jacobian of its residuals.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum JacobianKind {
    /// Analytic in the pose parameters, forward differences in the four shape sliders.
    #[default]
    Analytic,
    /// Forward differences in every parameter (one residual evaluation per parameter, about 4x the cost). Its
    /// silhouette rows are off by up to ±7 % where a step of 1e-6 moves a projected vertex by a few f32 ulps of a
    /// pixel coordinate.
    ForwardDifference,
}

/// Parameters whose derivatives are analytic: scale, translation, global rotation and the joint rotations (the
/// shape sliders after them are differenced).
const POSE_PARAMS: usize = 7 + JOINT_PARAMS;

/// The right Jacobian of the rotation exponential: `Exp(v + d) ≈ Exp(v) Exp(J_r(v) d)`.
fn right_jacobian(v: DVec3) -> DMat3 {
    let theta2 = v.length_squared();
    let k = skew(v);
    let (a, b) = if theta2 < 1e-8 {
        (0.5 - theta2 / 24.0, 1.0 / 6.0 - theta2 / 120.0)
    } else {
        let theta = theta2.sqrt();
        ((1.0 - theta.cos()) / theta2, (theta - theta.sin()) / (theta2 * theta))
    };
    DMat3::IDENTITY - a * k + b * (k * k)
}

fn skew(v: DVec3) -> DMat3 {
    DMat3::from_cols(DVec3::new(0.0, v.z, -v.y), DVec3::new(-v.z, 0.0, v.x), DVec3::new(v.y, -v.x, 0.0))
}

/// What the derivatives of every model point share at one pose: the world axes of every rotation parameter and
/// the joint centres.
struct Frames {
    /// Per joint of [`JOINTS`]: its world centre and the world axis of each of its parameters.
    joints: Vec<(DVec3, [DVec3; 3])>,
    /// World axes of the global rotation's parameters.
    global: [DVec3; 3],
    scale: f64,
    translation: DVec3,
}

impl Frames {
    fn new(model: &BodyModel, pose: &Pose, heads: &[DVec3], g: &[DAffine3]) -> Self {
        let rg = DMat3::from_quat(DQuat::from_scaled_axis(pose.global)) * right_jacobian(pose.global);
        let s = if pose.scale.abs() > 1e-12 { pose.scale } else { 1e-12 };
        let mut joints = Vec::with_capacity(JOINTS.len());
        let mut k = 0;
        for (j, (_, dof)) in JOINTS.iter().enumerate() {
            let b = model.joint_bones[j];
            let world = g[b].matrix3 * (1.0 / s);
            let centre = g[b].transform_point3(heads[b]);
            let mut axes = [DVec3::ZERO; 3];
            if *dof == 3 {
                let v = DVec3::new(pose.joints[k], pose.joints[k + 1], pose.joints[k + 2]);
                let m = world * right_jacobian(v);
                axes = [m.x_axis, m.y_axis, m.z_axis];
            } else {
                axes[0] = world * model.flex_axes[j];
            }
            joints.push((centre, axes));
            k += dof;
        }
        Self { joints, global: [rg.x_axis, rg.y_axis, rg.z_axis], scale: s, translation: pose.translation }
    }

    /// Derivatives of the posed point `p` with respect to the first [`POSE_PARAMS`] parameters, given per joint the
    /// skinning-weighted sum of the point's bone positions that joint moves and the sum of those weights.
    fn point_derivatives(&self, p: DVec3, moved: &[(DVec3, f64)], out: &mut [DVec3; POSE_PARAMS]) {
        let rel = p - self.translation;
        out[0] = rel / self.scale;
        out[1] = DVec3::X;
        out[2] = DVec3::Y;
        out[3] = DVec3::Z;
        for a in 0..3 {
            out[4 + a] = self.global[a].cross(rel);
        }
        let mut k = 7;
        for (j, (_, dof)) in JOINTS.iter().enumerate() {
            let (sum, weight) = moved[j];
            let arm = sum - weight * self.joints[j].0;
            for a in 0..*dof {
                out[k + a] = self.joints[j].1[a].cross(arm);
            }
            k += dof;
        }
    }
}

impl Problem<'_> {
    /// A model point and its derivatives (see [`Frames::point_derivatives`]).
    #[allow(clippy::too_many_arguments)]
    fn point_with_derivatives(
        &self,
        point: ModelPoint,
        shape: &[f64; super::model::SHAPE_COUNT],
        heads: &[DVec3],
        g: &[DAffine3],
        frames: &Frames,
        moved: &mut [(DVec3, f64)],
        out: &mut [DVec3; POSE_PARAMS],
    ) -> DVec3 {
        let model = self.model;
        moved.iter_mut().for_each(|m| *m = (DVec3::ZERO, 0.0));
        let p = match point {
            ModelPoint::Joint(b) => {
                let p = g[b].transform_point3(heads[b]);
                for &j in &model.moved_by[b] {
                    moved[j] = (p, 1.0);
                }
                p
            }
            ModelPoint::Vertex(v) => {
                let rest = model.rest_vertex(v, shape);
                let mut p = DVec3::ZERO;
                for &(b, w) in model.rig.weights.get(v as usize).map(|l| l.as_slice()).unwrap_or(&[]) {
                    let (b, w) = (b as usize, w as f64);
                    let q = g[b].transform_point3(rest);
                    p += w * q;
                    for &j in &model.moved_by[b] {
                        moved[j].0 += w * q;
                        moved[j].1 += w;
                    }
                }
                p
            }
        };
        frames.point_derivatives(p, moved, out);
        p
    }

    /// Forward-difference columns `d residuals / d x[j]` at `x0` for the parameters `js` (in parallel), `base`
    /// being the residuals at `x0`. Step `1e-6 max(|x_j|, 1)`, a tenth of it for parameter 0.
    fn difference_columns(&self, x0: &[f64], base: &[f64], js: std::ops::Range<usize>) -> Vec<Vec<f64>> {
        use rayon::prelude::*;
        js.into_par_iter()
            .map(|j| {
                let h = 1e-6 * x0[j].abs().max(1.0) * if j == 0 { 0.1 } else { 1.0 };
                let mut x = x0.to_vec();
                x[j] += h;
                let mut r = Vec::with_capacity(base.len());
                self.residuals_of(&x, &mut r);
                r.iter().zip(base).map(|(a, b)| (a - b) / h).collect()
            })
            .collect()
    }

    /// The Jacobian of [`Problem::residuals_of`] at `x` by forward differences in every parameter.
    fn difference_jacobian_at(&self, x0: &[f64]) -> DMatrix<f64> {
        let mut base = Vec::with_capacity(self.residual_count);
        self.residuals_of(x0, &mut base);
        let m = base.len();
        let columns = self.difference_columns(x0, &base, 0..x0.len());
        DMatrix::from_fn(m, x0.len(), |i, j| columns[j][i])
    }

    /// The Jacobian of [`Problem::residuals_of`] at `x`: analytic in the pose parameters (the chain of rotations
    /// about the joint centres, the silhouette distance's bilinear gradient), forward differences in the four
    /// shape sliders (they move the rest mesh and the joint centres together).
    fn jacobian_at(&self, x0: &[f64]) -> DMatrix<f64> {
        let mut base = Vec::with_capacity(self.residual_count);
        self.residuals_of(x0, &mut base);
        let m = base.len();
        let mut jac = DMatrix::zeros(m, PARAM_COUNT);
        let shape_columns = self.difference_columns(x0, &base, POSE_PARAMS..PARAM_COUNT);
        for (c, column) in shape_columns.iter().enumerate() {
            for (i, v) in column.iter().enumerate() {
                jac[(i, POSE_PARAMS + c)] = *v;
            }
        }
        let pose = Pose::from_slice(x0);
        let model = self.model;
        let heads = model.rest_heads(&pose.shape);
        let g = model.skinning(&pose, &heads);
        let frames = Frames::new(model, &pose, &heads, &g);
        let o = &self.options;
        let mut moved = vec![(DVec3::ZERO, 0.0); JOINTS.len()];
        let mut d = [DVec3::ZERO; POSE_PARAMS];
        // Landmarks: x, y, and depth about the weighted mean depth.
        let wsum: f64 = self.terms.iter().map(|t| t.weight).sum::<f64>().max(1e-9);
        let mut dz_mean = [0.0; POSE_PARAMS];
        let mut dz = vec![[0.0; POSE_PARAMS]; self.terms.len()];
        for (t, term) in self.terms.iter().enumerate() {
            self.point_with_derivatives(term.point, &pose.shape, &heads, &g, &frames, &mut moved, &mut d);
            let w = term.weight.sqrt();
            for (p, dp) in d.iter().enumerate() {
                jac[(3 * t, p)] = w * dp.x / o.sigma_2d;
                jac[(3 * t + 1, p)] = w * dp.y / o.sigma_2d;
                dz[t][p] = dp.z;
                dz_mean[p] += term.weight * dp.z / wsum;
            }
        }
        for (t, term) in self.terms.iter().enumerate() {
            let w = term.weight.sqrt();
            for p in 0..POSE_PARAMS {
                jac[(3 * t + 2, p)] = w * (dz[t][p] - dz_mean[p]) / o.sigma_depth;
            }
        }
        // Silhouette: d(distance)/d(pixel) times d(pixel)/d(cube) (= R/2, which cancels the pixel size).
        let res = self.target.resolution;
        let lm = self.target.landmarks;
        let mut row = 3 * self.terms.len();
        // Beyond the frame: the slope of the nearest edge's inside distance, where the point is inside.
        let half = res as f64 * 0.5;
        for &b in &self.beyond {
            let p = self.point_with_derivatives(b, &pose.shape, &heads, &g, &frames, &mut moved, &mut d);
            let (u, w) = to_pixel(p, res);
            let inside = [u - lm.frame_min.x, w - lm.frame_min.y, lm.frame_max.x - u, lm.frame_max.y - w];
            let (edge, nearest) =
                inside.iter().enumerate().fold((0, f32::INFINITY), |a, (i, &v)| if v < a.1 { (i, v) } else { a });
            if nearest > 0.0 {
                // d(inside)/d(cube) per edge; the pixel size 1 / half cancels the pixels per cube unit.
                let slope = |dp: DVec3| match edge {
                    0 => dp.x,
                    1 => -dp.y,
                    2 => -dp.x,
                    _ => dp.y,
                } * half * (2.0 / res as f64);
                for (k, dp) in d.iter().enumerate() {
                    jac[(row, k)] = slope(*dp) / o.sigma_2d;
                }
            }
            row += 1;
        }
        for &v in &model.samples {
            let p = self.point_with_derivatives(
                ModelPoint::Vertex(v),
                &pose.shape,
                &heads,
                &g,
                &frames,
                &mut moved,
                &mut d,
            );
            let (u, w) = to_pixel(p, res);
            let inside_photo = u >= lm.frame_min.x && w >= lm.frame_min.y && u <= lm.frame_max.x && w <= lm.frame_max.y;
            if inside_photo {
                let (dist, (gx, gy)) = self.target.outside.distance_and_gradient_at(u, w);
                if dist.is_finite() {
                    for (k, dp) in d.iter().enumerate() {
                        jac[(row, k)] = (gx as f64 * dp.x - gy as f64 * dp.y) / o.sigma_silhouette;
                    }
                }
            }
            row += 1;
        }
        // Priors and limits (the shape rows are differenced above).
        let mut k = 0;
        for (j, (_, dof)) in JOINTS.iter().enumerate() {
            let (sigma, (lo, hi)) = JOINT_PRIOR[j];
            let v = &x0[7 + k..7 + k + dof];
            for a in 0..*dof {
                jac[(row, 7 + k + a)] = 1.0 / sigma;
                row += 1;
            }
            if *dof == 3 {
                let angle = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                if angle > hi && angle > 0.0 {
                    for a in 0..3 {
                        jac[(row, 7 + k + a)] = LIMIT_WEIGHT * v[a] / angle;
                    }
                }
            } else if v[0] < lo {
                jac[(row, 7 + k)] = -LIMIT_WEIGHT;
            } else if v[0] > hi {
                jac[(row, 7 + k)] = LIMIT_WEIGHT;
            }
            row += 1;
            k += dof;
        }
        row += 2 * super::model::SHAPE_COUNT;
        jac[(row, 4)] = 1.0 / 0.5;
        jac[(row + 1, 6)] = 1.0 / 0.5;
        jac[(row + 2, 3)] = 1.0 / 0.2;
        // Upright torso: central differences of its one smooth row.
        for p in 0..POSE_PARAMS {
            let h = 1e-6 * x0[p].abs().max(1.0) * if p == 0 { 0.1 } else { 1.0 };
            let (mut xp, mut xm) = (x0.to_vec(), x0.to_vec());
            xp[p] += h;
            xm[p] -= h;
            jac[(row + 3, p)] = (self.upright(&xp) - self.upright(&xm)) / (2.0 * h);
        }
        // The anchor's rows, one per parameter (the shape columns are differenced above).
        if let Some((_, spread)) = &self.anchor {
            for p in 0..POSE_PARAMS {
                jac[(row + 4 + p, p)] = 1.0 / spread[p];
            }
        }
        // Residuals that were replaced for being non-finite have no slope.
        for (i, r) in base.iter().enumerate() {
            if r.abs() >= 1e6 {
                for p in 0..POSE_PARAMS {
                    jac[(i, p)] = 0.0;
                }
            }
        }
        if jac.iter().any(|v| !v.is_finite()) {
            jac.iter_mut().for_each(|v| {
                if !v.is_finite() {
                    *v = 0.0;
                }
            });
        }
        jac
    }
}

/// A starting pose for a still photo: rest pose, neutral shape, scaled and placed so the model's shoulders and
/// hips (or whatever of them is visible, else the nose) land on the landmarks.
pub fn initial_pose(model: &BodyModel, target: &FitTarget<'_>, options: &FitOptions) -> Pose {
    let lm = target.landmarks;
    let res = target.resolution;
    let usable = |i: usize| lm.landmarks[i].visibility >= options.min_visibility && lm.in_frame(i, 0.0);
    let rest = Pose::rest(1.0, DVec3::ZERO);
    let heads = model.rest_heads(&rest.shape);
    let g = model.skinning(&rest, &heads);
    let model_at = |i: usize| model.landmark_points[i].map(|p| model.point(p, &rest.shape, &heads, &g));
    let photo_at = |i: usize| to_cube(lm.landmarks[i].pixel, res);
    // Scale from the longest visible pair among shoulders, hips and the nose.
    let candidates = [11usize, 12, 23, 24, 0];
    let visible: Vec<usize> = candidates.iter().copied().filter(|&i| usable(i) && model_at(i).is_some()).collect();
    let mut scale = 1.8 / model.rest_height;
    let mut best = 0.0;
    for (a, &i) in visible.iter().enumerate() {
        for &j in &visible[a + 1..] {
            let (mi, mj) = (model_at(i).unwrap_or_default(), model_at(j).unwrap_or_default());
            let dm = DVec2::new(mi.x - mj.x, mi.y - mj.y).length();
            let dp = photo_at(i).distance(photo_at(j));
            if dm > best && dm > 1e-3 && dp > 1e-3 {
                best = dm;
                scale = dp / dm;
            }
        }
    }
    let scale = scale.clamp(0.2 / model.rest_height, 8.0 / model.rest_height);
    // Translation: the visible candidates' centroid onto the photo's.
    let mut translation = DVec3::ZERO;
    if !visible.is_empty() {
        let n = visible.len() as f64;
        let m: DVec3 = visible.iter().map(|&i| model_at(i).unwrap_or_default()).sum::<DVec3>() / n;
        let p: DVec2 = visible.iter().map(|&i| photo_at(i)).sum::<DVec2>() / n;
        translation = DVec3::new(p.x - scale * m.x, p.y - scale * m.y, 0.0);
    }
    Pose::rest(scale, translation)
}

/// Fits the body to `target`, starting from `start` (the previous frame's pose on live input) or from
/// [`initial_pose`]. Never returns non-finite parameters: a solver failure returns the start.
pub fn fit_body(model: &BodyModel, target: &FitTarget<'_>, start: Option<&Pose>, options: &FitOptions) -> BodyFit {
    let lm = target.landmarks;
    let res = target.resolution;
    let half = res as f64 * 0.5;
    // World-landmark depth scale: cube units per metre, from the 2-D landmarks against the world x, y.
    let usable: Vec<usize> = (0..LANDMARK_COUNT)
        .filter(|&i| model_has(model, i) && lm.landmarks[i].visibility >= options.min_visibility && lm.in_frame(i, 0.0))
        .collect();
    let kappa = world_scale(lm, &usable, res);
    let mut terms: Vec<Term> = usable
        .iter()
        .filter_map(|&i| {
            let point = model.landmark_points[i]?;
            let l = &lm.landmarks[i];
            let depth = match kappa {
                Some(k) => k * lm.world[i].z as f64,
                None => l.depth as f64 / half,
            };
            Some(Term { point, xy: to_cube(l.pixel, res), depth, weight: l.visibility as f64 })
        })
        .collect();
    let initial = initial_pose(model, target, options);
    let (start, warm) = match start {
        Some(p) if p.is_finite() => (*p, true),
        _ => (initial, false),
    };
    // The hanging legs' length from the photo alone (the starting pose's scale on a cold fit): taken from a warm
    // start's scale, each fit moved the next one's targets, and a still person's fits alternated between two poses
    // (the astronaut's frames repeated: costs 40 and 58 in turn, `--geometry body-placed` flickering from the side).
    terms.extend(hanging_legs(model, &usable, &terms, initial.scale));
    // Depths relative to the weighted mean of the used landmarks.
    let wsum: f64 = terms.iter().map(|t| t.weight).sum::<f64>().max(1e-9);
    let dmean = terms.iter().map(|t| t.weight * t.depth).sum::<f64>() / wsum;
    for t in &mut terms {
        t.depth -= dmean;
    }
    let used: Vec<(usize, f64)> = usable.iter().map(|&i| (i, lm.landmarks[i].visibility as f64)).collect();
    // Landmarks beyond an edge that cuts the person (beyond an edge the person does not reach, a landmark is
    // just a wrong guess).
    let beyond = (0..LANDMARK_COUNT)
        .filter(|&i| {
            let p = lm.landmarks[i].pixel;
            let past = [p.x < lm.frame_min.x, p.y < lm.frame_min.y, p.x > lm.frame_max.x, p.y > lm.frame_max.y];
            p.is_finite() && past.iter().zip(&target.cut_edges).any(|(&a, &b)| a && b)
        })
        .filter_map(|i| model.landmark_points[i])
        .collect();
    let mut problem = Problem {
        model,
        target,
        terms,
        beyond,
        options: options.clone(),
        params: DVector::from_row_slice(&start.to_vec()),
        residual_count: 0,
        anchor: (warm && options.warm_anchor > 0.0)
            .then(|| (start.to_vec(), anchor_step(&start).map(|d| d * options.warm_anchor))),
    };
    let mut r = Vec::new();
    problem.residuals_of(&start.to_vec(), &mut r);
    problem.residual_count = r.len();
    let start_cost = 0.5 * r.iter().map(|v| v * v).sum::<f64>();
    let (problem, report) = LevenbergMarquardt::new()
        .with_patience(options.patience.max(1))
        .with_stepbound(options.stepbound)
        .with_ftol(options.tolerance)
        .with_xtol(options.tolerance)
        .minimize(problem);
    let pose = Pose::from_slice(problem.params.as_slice());
    let cost = report.objective_function;
    if warm && cost.is_finite() && start_cost - cost <= options.warm_hold * start_cost {
        BodyFit { pose: start, used, cost: start_cost, evaluations: report.number_of_evaluations }
    } else if pose.is_finite() && cost.is_finite() && cost <= start_cost {
        BodyFit { pose, used, cost, evaluations: report.number_of_evaluations }
    } else {
        tracing::warn!("body fit did not converge ({:?}); keeping the starting pose", report.termination);
        BodyFit { pose: start, used, cost: start_cost, evaluations: report.number_of_evaluations }
    }
}

/// Weight (as a landmark visibility) of the rest-pose knee and ankle of a leg the network does not see.
pub const HANGING_WEIGHT: f64 = 0.1;

/// Weak targets for the knee and ankle of each leg whose hip is used (`usable[k]` is landmark index of `terms[k]`)
/// but whose knee is not: where the rest pose (legs hanging straight) puts them from that hip at `scale`. Without
/// them a leg the photo does not show follows the pelvis: a person bent at the waist got legs sticking out behind.
fn hanging_legs(model: &BodyModel, usable: &[usize], terms: &[Term], scale: f64) -> Vec<Term> {
    use super::pose::index::{LEFT_ANKLE, LEFT_HIP, LEFT_KNEE, RIGHT_ANKLE, RIGHT_HIP, RIGHT_KNEE};
    let rest = Pose::rest(scale, DVec3::ZERO);
    let heads = model.rest_heads(&rest.shape);
    let g = model.skinning(&rest, &heads);
    let at = |i: usize| model.landmark_points[i].map(|p| model.point(p, &rest.shape, &heads, &g));
    let mut out = Vec::new();
    for (hip, knee, ankle) in [(LEFT_HIP, LEFT_KNEE, LEFT_ANKLE), (RIGHT_HIP, RIGHT_KNEE, RIGHT_ANKLE)] {
        let Some(k) = usable.iter().position(|&i| i == hip) else { continue };
        if usable.contains(&knee) {
            continue;
        }
        let (Some(h), Some(term)) = (at(hip), terms.get(k)) else { continue };
        for i in [knee, ankle] {
            let (Some(m), Some(point)) = (at(i), model.landmark_points[i]) else { continue };
            let offset = m - h;
            out.push(Term {
                point,
                xy: term.xy + DVec2::new(offset.x, offset.y),
                depth: term.depth + offset.z,
                weight: HANGING_WEIGHT,
            });
        }
    }
    out
}

fn model_has(model: &BodyModel, i: usize) -> bool {
    model.landmark_points.get(i).is_some_and(|p| p.is_some())
}

/// Cube units per metre: least squares of the used landmarks' 2-D offsets against their world x, y offsets
/// (about the means). `None` with fewer than three landmarks or a degenerate spread.
pub fn world_scale(lm: &PoseLandmarks, used: &[usize], resolution: usize) -> Option<f64> {
    if used.len() < 3 {
        return None;
    }
    let n = used.len() as f64;
    let p: Vec<DVec2> = used.iter().map(|&i| to_cube(lm.landmarks[i].pixel, resolution)).collect();
    let w: Vec<DVec2> = used.iter().map(|&i| DVec2::new(lm.world[i].x as f64, lm.world[i].y as f64)).collect();
    let (pm, wm) = (p.iter().sum::<DVec2>() / n, w.iter().sum::<DVec2>() / n);
    let num: f64 = p.iter().zip(&w).map(|(a, b)| (*a - pm).dot(*b - wm)).sum();
    let den: f64 = w.iter().map(|b| (*b - wm).length_squared()).sum();
    let k = num / den;
    (den > 1e-6 && k.is_finite() && k > 0.0).then_some(k)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::pose::{Landmark, PoseRegion};
    use crate::buffer::Image;

    /// Landmarks at the model points of `pose` in a `res`² view (visibility 1, world = cube coordinates).
    fn landmarks_of(model: &BodyModel, pose: &Pose, res: usize) -> PoseLandmarks {
        let heads = model.rest_heads(&pose.shape);
        let g = model.skinning(pose, &heads);
        let half = res as f32 * 0.5;
        let points: Vec<Option<DVec3>> =
            model.landmark_points.iter().map(|p| p.map(|p| model.point(p, &pose.shape, &heads, &g))).collect();
        PoseLandmarks {
            landmarks: points
                .iter()
                .map(|p| match p {
                    Some(p) => Landmark {
                        pixel: Vec2::new((p.x as f32 + 1.0) * half, (1.0 - p.y as f32) * half),
                        depth: p.z as f32 * half,
                        visibility: 1.0,
                        presence: 1.0,
                    },
                    None => Landmark { pixel: Vec2::splat(half), depth: 0.0, visibility: 0.0, presence: 0.0 },
                })
                .collect(),
            world: points.iter().map(|p| p.unwrap_or_default().as_vec3()).collect(),
            score: 1.0,
            region: PoseRegion { centre: Vec2::splat(half), side: res as f32 },
            next_region: None,
            frame_min: Vec2::ZERO,
            frame_max: Vec2::splat(res as f32),
        }
    }

    #[test]
    fn a_leg_the_network_does_not_see_hangs_from_its_hip() {
        // From the landmarks of the rest pose (scale s, anywhere), with the left knee and ankle not used: the weak
        // targets for them are exactly where the rest pose has them, x, y and depth; a leg whose knee is used gets
        // none, nor one whose hip is not.
        let model = BodyModel::shared().expect("body model data (bash scripts/setup.d/synth.sh)");
        let res = 256;
        let s = 1.5 / model.rest_height;
        let rest = Pose::rest(s, DVec3::new(0.1, -0.2, 0.05));
        let lm = landmarks_of(model, &rest, res);
        let terms_of = |usable: &[usize]| -> Vec<Term> {
            usable
                .iter()
                .map(|&i| Term {
                    point: model.landmark_points[i].unwrap(),
                    xy: to_cube(lm.landmarks[i].pixel, res),
                    depth: lm.world[i].z as f64,
                    weight: 1.0,
                })
                .collect()
        };
        let all: Vec<usize> = (0..LANDMARK_COUNT).filter(|&i| model_has(model, i)).collect();
        let (lk, la) = (super::super::pose::index::LEFT_KNEE, super::super::pose::index::LEFT_ANKLE);
        let usable: Vec<usize> = all.iter().copied().filter(|&i| i != lk && i != la).collect();
        let hanging = hanging_legs(model, &usable, &terms_of(&usable), s);
        assert_eq!(hanging.len(), 2);
        for (t, i) in hanging.iter().zip([lk, la]) {
            assert_eq!(t.point, model.landmark_points[i].unwrap());
            assert!((t.xy - to_cube(lm.landmarks[i].pixel, res)).length() < 1e-5, "{i}: {:?}", t.xy);
            assert!((t.depth - lm.world[i].z as f64).abs() < 1e-5);
            assert_eq!(t.weight, HANGING_WEIGHT);
        }
        assert!(hanging_legs(model, &all, &terms_of(&all), s).is_empty());
        let no_hip: Vec<usize> = usable.iter().copied().filter(|&i| i != super::super::pose::index::LEFT_HIP).collect();
        assert!(hanging_legs(model, &no_hip, &terms_of(&no_hip), s).is_empty());
    }

    #[test]
    fn the_upright_prior_is_the_torsos_lean_in_depth() {
        // A body pitched by t about the camera's x axis: the unit hip-to-shoulder vector u of the unpitched body
        // turns to (ux, uy cos t - uz sin t, uy sin t + uz cos t), so the row is (uy sin t + uz cos t) / sigma.
        use crate::body::pose::index::{LEFT_HIP, LEFT_SHOULDER, RIGHT_HIP, RIGHT_SHOULDER};
        let model = BodyModel::shared().expect("body model data (bash scripts/setup.d/synth.sh)");
        let res = 256;
        let pose = Pose::rest(1.6 / model.rest_height, DVec3::new(0.02, -0.05, 0.1));
        let lm = landmarks_of(model, &pose, res);
        let mask = Image::new(res, res, 1.0);
        let target = FitTarget::new(&lm, &mask);
        let heads = model.rest_heads(&pose.shape);
        let g = model.skinning(&pose, &heads);
        let at = |i: usize| model.point(model.landmark_points[i].unwrap(), &pose.shape, &heads, &g);
        let u = (0.5 * (at(LEFT_SHOULDER) + at(RIGHT_SHOULDER)) - 0.5 * (at(LEFT_HIP) + at(RIGHT_HIP))).normalize();
        let mut options = FitOptions::default();
        let problem = |options: &FitOptions| Problem {
            model,
            target: &target,
            terms: Vec::new(),
            beyond: Vec::new(),
            options: options.clone(),
            params: DVector::from_row_slice(&pose.to_vec()),
            residual_count: 0,
            anchor: None,
        };
        for t in [-0.4f64, 0.0, 0.3] {
            let pitched = Pose { global: DVec3::new(t, 0.0, 0.0), ..pose };
            let want = (u.y * t.sin() + u.z * t.cos()) / options.sigma_upright;
            let got = problem(&options).upright(&pitched.to_vec());
            assert!((got - want).abs() < 1e-9, "pitch {t}: {got} vs {want}");
        }
        // Off, and a NaN pose: no residual.
        let nan = Pose { scale: f64::NAN, ..pose };
        assert_eq!(problem(&options).upright(&nan.to_vec()), 0.0);
        options.sigma_upright = 0.0;
        assert_eq!(problem(&options).upright(&Pose { global: DVec3::X, ..pose }.to_vec()), 0.0);
    }

    #[test]
    fn the_analytic_jacobian_matches_central_differences() {
        let model = BodyModel::shared().expect("body model data (bash scripts/setup.d/synth.sh)");
        let res = 256;
        let mut truth = Pose::rest(1.6 / model.rest_height, DVec3::new(0.02, -0.05, 0.0));
        truth.joints.iter_mut().enumerate().for_each(|(i, v)| *v = 0.25 * ((i as f64 * 1.7).sin()));
        truth.global = DVec3::new(0.1, 0.4, -0.05);
        let lm = landmarks_of(model, &truth, res);
        // A mask narrower than the body so that part of it lies outside and the silhouette rows have slopes.
        let mask = Image::from_fn(res, res, |c, _| if (96..160).contains(&c) { 1.0 } else { 0.0 });
        let target = FitTarget::new(&lm, &mask);
        let mut at = truth;
        at.joints.iter_mut().enumerate().for_each(|(i, v)| *v += 0.1 * ((i as f64 * 0.9).cos()));
        at.global += DVec3::new(0.05, -0.2, 0.03);
        at.translation += DVec3::new(0.03, 0.02, 0.1);
        at.scale *= 1.05;
        at.shape = [0.4, 0.6, 0.55, 0.3];
        let mut problem = Problem {
            model,
            target: &target,
            terms: Vec::new(),
            options: FitOptions::default(),
            params: DVector::from_row_slice(&at.to_vec()),
            beyond: Vec::new(),
            residual_count: 0,
            // A warm fit's rows toward the previous pose: linear, exact to rounding like the priors.
            anchor: Some((truth.to_vec(), anchor_step(&truth))),
        };
        problem.terms = (0..LANDMARK_COUNT)
            .filter_map(|i| {
                let point = model.landmark_points[i]?;
                Some(Term {
                    point,
                    xy: to_cube(lm.landmarks[i].pixel, res),
                    depth: lm.world[i].z as f64,
                    weight: 0.5 + 0.5 * (i % 2) as f64,
                })
            })
            .collect();
        // Points the photo's frame cuts off but the model puts inside it (their rows measure how far inside the
        // frame they are, from the nearest edge): the eyes (nearest the top), the wrists (the sides), the ankles
        // (the bottom).
        problem.beyond = [2usize, 5, 15, 16, 27, 28].iter().filter_map(|&i| model.landmark_points[i]).collect();
        let rest = Pose { joints: [0.0; JOINT_PARAMS], global: DVec3::ZERO, ..at };
        // Past the joint limits: an upper arm turned by 2.8 rad (limit 2.6), an elbow bent backward (limit -0.1).
        let mut limits = at;
        limits.joints[9..12].copy_from_slice(&[1.2, -2.0, 1.6]);
        limits.joints[15] = -0.3;
        for x0 in [at.to_vec(), rest.to_vec(), limits.to_vec()] {
            let mut r = Vec::new();
            problem.residuals_of(&x0, &mut r);
            problem.residual_count = r.len();
            let jac = problem.jacobian_at(&x0);
            let first_silhouette = 3 * problem.terms.len() + problem.beyond.len();
            let silhouette_rows = first_silhouette..first_silhouette + model.samples.len();
            let beyond_rows = 3 * problem.terms.len()..first_silhouette;
            assert!(beyond_rows.clone().all(|i| r[i] > 0.0), "the frame's rows are active");
            assert!(silhouette_rows.clone().any(|i| r[i] > 0.0), "some samples lie outside the mask");
            for p in 0..POSE_PARAMS {
                let h = 1e-5;
                let (mut xp, mut xm) = (x0, x0);
                xp[p] += h;
                xm[p] -= h;
                let (mut rp, mut rm) = (Vec::new(), Vec::new());
                problem.residuals_of(&xp, &mut rp);
                problem.residuals_of(&xm, &mut rm);
                let fd: Vec<f64> = rp.iter().zip(&rm).map(|(a, b)| (a - b) / (2.0 * h)).collect();
                // Landmark and prior rows: smooth, exact to rounding.
                let smooth = |i: &usize| !silhouette_rows.contains(i) && !beyond_rows.contains(i);
                let (mut err, mut norm) = (0.0f64, 0.0f64);
                for i in (0..r.len()).filter(smooth) {
                    err = err.max((jac[(i, p)] - fd[i]).abs());
                    norm = norm.max(fd[i].abs());
                }
                assert!(
                    err <= 1e-4 * norm.max(1.0),
                    "parameter {p}: landmark/prior rows differ by {err} (scale {norm})"
                );
                // Frame rows: smooth but through f32 pixels: one ulp of a pixel coordinate (1.5e-5 at 128-256) over
                // the step 2e-3 is 0.01 in these rows' units (1 / (128 px * sigma_2d)).
                let h = 1e-3;
                let (mut xp, mut xm) = (x0, x0);
                xp[p] += h;
                xm[p] -= h;
                problem.residuals_of(&xp, &mut rp);
                problem.residuals_of(&xm, &mut rm);
                for i in beyond_rows.clone() {
                    let fd = (rp[i] - rm[i]) / (2.0 * h);
                    assert!(
                        (jac[(i, p)] - fd).abs() <= 0.02 + 1e-3 * fd.abs(),
                        "parameter {p}, frame row {i}: {} vs {fd}",
                        jac[(i, p)]
                    );
                }
                // Silhouette rows: the bilinear distance has kinks between pixels and is evaluated in f32, so compare
                // the column as a whole.
                // A step of 1e-4 (0.013 pixels) keeps the f32 rounding of the distance (about 1e-6 pixels) out of it.
                let h = 1e-4;
                let (mut xp, mut xm) = (x0, x0);
                xp[p] += h;
                xm[p] -= h;
                problem.residuals_of(&xp, &mut rp);
                problem.residuals_of(&xm, &mut rm);
                let (mut e2, mut n2) = (0.0, 0.0);
                for i in silhouette_rows.clone() {
                    let fd = (rp[i] - rm[i]) / (2.0 * h);
                    e2 += (jac[(i, p)] - fd).powi(2);
                    n2 += fd.powi(2);
                }
                assert!(
                    e2.sqrt() <= 0.05 * n2.sqrt() + 1e-3,
                    "parameter {p}: silhouette rows differ by {} of {}",
                    e2.sqrt(),
                    n2.sqrt()
                );
            }
        }
    }
}
