//! Fitting the body model ([`super::model`]) to a photo's pose landmarks under the orthographic source camera.
//!
//! Least squares over the [`Pose`] parameters, solved with Levenberg–Marquardt (the `levenberg-marquardt`
//! crate over nalgebra; forward-difference Jacobian):
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
//! - **Prior**: every joint rotation is pulled toward the rest pose, the shape toward the neutral body, the hip
//!   centre toward depth 0; joint limits (hinge penalties) keep elbows and knees bending one way and every joint
//!   inside a plausible range, so a bad landmark cannot give an impossible body.
//!
//! Live input warm-starts from the previous frame's [`Pose`] ([`fit_body`] with `start`).

use glam::{DVec2, DVec3, Vec2};
use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{storage::Owned, DMatrix, DVector, Dyn};

use super::distance::DistanceField;
use super::model::{BodyModel, ModelPoint, Pose, JOINTS};
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
    /// Residual evaluations the solver may spend, per parameter (the crate's `patience`).
    pub patience: usize,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            min_visibility: 0.5,
            sigma_2d: 0.012,
            sigma_depth: 0.03,
            sigma_silhouette: 0.02,
            sigma_shape: 0.35,
            patience: 12,
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
        for r in out.iter_mut() {
            if !r.is_finite() {
                *r = 1e6;
            }
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
        use rayon::prelude::*;
        let x0: Vec<f64> = self.params.as_slice().to_vec();
        let mut base = Vec::with_capacity(self.residual_count);
        self.residuals_of(&x0, &mut base);
        let m = base.len();
        let columns: Vec<Vec<f64>> = (0..x0.len())
            .into_par_iter()
            .map(|j| {
                let h = 1e-6 * x0[j].abs().max(1.0) * if j == 0 { 0.1 } else { 1.0 };
                let mut x = x0.clone();
                x[j] += h;
                let mut r = Vec::with_capacity(m);
                self.residuals_of(&x, &mut r);
                r.iter().zip(&base).map(|(a, b)| (a - b) / h).collect()
            })
            .collect();
        Some(DMatrix::from_fn(m, x0.len(), |i, j| columns[j][i]))
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
    // Depths relative to the weighted mean of the used landmarks.
    let wsum: f64 = terms.iter().map(|t| t.weight).sum::<f64>().max(1e-9);
    let dmean = terms.iter().map(|t| t.weight * t.depth).sum::<f64>() / wsum;
    for t in &mut terms {
        t.depth -= dmean;
    }
    let start = match start {
        Some(p) if p.is_finite() => *p,
        _ => initial_pose(model, target, options),
    };
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
    };
    let mut r = Vec::new();
    problem.residuals_of(&start.to_vec(), &mut r);
    problem.residual_count = r.len();
    let start_cost = 0.5 * r.iter().map(|v| v * v).sum::<f64>();
    let (problem, report) = LevenbergMarquardt::new().with_patience(options.patience.max(1)).minimize(problem);
    let pose = Pose::from_slice(problem.params.as_slice());
    if pose.is_finite() && report.objective_function.is_finite() && report.objective_function <= start_cost {
        BodyFit { pose, used, cost: report.objective_function, evaluations: report.number_of_evaluations }
    } else {
        tracing::warn!("body fit did not converge ({:?}); keeping the starting pose", report.termination);
        BodyFit { pose: start, used, cost: start_cost, evaluations: report.number_of_evaluations }
    }
}

fn model_has(model: &BodyModel, i: usize) -> bool {
    model.landmark_points.get(i).is_some_and(|p| p.is_some())
}

/// Cube units per metre: least squares of the used landmarks' 2-D offsets against their world x, y offsets
/// (about the means). `None` with fewer than three landmarks or a degenerate spread.
fn world_scale(lm: &PoseLandmarks, used: &[usize], resolution: usize) -> Option<f64> {
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
