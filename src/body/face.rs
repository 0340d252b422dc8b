//! Faces from the face mesh: MediaPipe's face landmark network (468 points of the face with their relative
//! depths, trained on real faces) shapes the front of the face in the body-placed geometry.
//!
//! Why: the silhouette-inflation prior draws a face as part of a smooth dome (the head's outline inflated), so from
//! the side a real person's face is flat, without a nose or eye sockets. The pose network's face landmarks (eyes,
//! ears, nose, mouth) say where the face is but not its relief; the face mesh does. It runs on a square crop of the
//! face, rotated so the eyes are level: first found from the pose landmarks, then, as MediaPipe tracks a face, again
//! from the first mesh's own box ([`FaceEstimator::estimate`]).
//!
//! How the relief goes in ([`with_face_relief`]): inside the face's outline (the mesh's 36 face-oval points) the
//! front surface becomes the plane through the old front surface at the outline plus the mesh's depth above the
//! plane through its own outline, faded in over [`FEATHER`] of the face's width from the outline, so the face keeps
//! the head's place and tilt and takes the mesh's shape. Skipped (the geometry unchanged) when the mesh is not sure
//! of a face ([`MIN_FACE_SCORE`]), when the face is small ([`MIN_FACE_WIDTH`]: under about 6 % of the view's side
//! its relief is a few pixels), turned away from the camera by more than [`MAX_FACE_YAW`] (the mesh's hidden half
//! folds behind the nose), or when its outline leaves the person's mask.
//!
//! The model: `face_landmark.onnx`, converted from the `mediapipe` wheel's `face_landmark.tflite` (Apache-2.0) by
//! `scripts/tflite_to_onnx.py`, installed by `scripts/setup.d/live.sh`. Input `[1, 192, 192, 3]` sRGB in `[0, 1]`;
//! outputs 468 x (x, y, z) in input pixels (z: + away from the camera, about x's scale) and a face-presence logit.

use std::path::{Path, PathBuf};

use glam::{DMat3, DVec3, Vec2, Vec3};
use ort::session::Session;

use super::pose::{network_value, sigmoid, PoseLandmarks};
use super::BodyError;
use crate::buffer::{supersampled, RgbImage};
use crate::geometry::inflate::InflatedSurfaces;
use crate::neural::RuntimeOptions;

/// The model's file name under `.tools/models`.
pub const MODEL_FILE: &str = "face_landmark.onnx";
/// The network's input side in pixels.
pub const INPUT_SIZE: usize = 192;
/// Points of the face mesh.
pub const POINT_COUNT: usize = 468;
/// Lowest face-presence probability taken for a face.
pub const MIN_FACE_SCORE: f32 = 0.5;
/// MediaPipe's face crop: the landmarks' box, squared on its long side, scaled by this.
pub const CROP_SCALE: f32 = 1.5;
/// Smallest face (width between the outline's left and right ends, source-view pixels at 512²; scaled with the
/// view) whose relief is applied.
pub const MIN_FACE_WIDTH: f32 = 32.0;
/// Largest turn of the face from the camera (radians, from the mesh's cheek depths) whose relief is applied. A
/// turned face's relief is drawn over the plane through its outline, which the turn tilts, and the hidden cheek
/// folds behind the nose: the Nexuiz dev players' faces, turned 0.30–0.45 rad, lost 0.02–0.15 dB of whole-frame
/// PSNR to the relief, while the UFO: AI dev faces it gains on are turned 0.02–0.16 rad (docs/geometry.md,
/// "Body-placed inflation").
pub const MAX_FACE_YAW: f32 = 0.25;
/// Width of the fade from the old surface at the face's outline to the mesh's relief, as a fraction of the face's
/// width.
pub const FEATHER: f32 = 0.15;
/// Smallest fraction of the face outline's points in or next to the person's mask (within [`OUTLINE_SLACK`]) for
/// the relief to be applied: a face the mask does not hold is not this person's.
pub const MIN_OUTLINE_IN_MASK: f32 = 0.9;
/// How far outside the mask an outline point still counts as on the person, as a fraction of the face's width: the
/// jaw's points lie on the face's own outline, and a segmentation a pixel or two tight puts them outside (Obama's
/// portraits in `face_recognition`'s test images: 4-6 of 36 points 1-3 px out).
pub const OUTLINE_SLACK: f32 = 0.08;

/// The face oval of MediaPipe's canonical face mesh, in order around the face (`FACEMESH_FACE_OVAL` of the
/// `mediapipe` package, Apache-2.0).
pub const FACE_OVAL: [usize; 36] = [
    10, 338, 297, 332, 284, 251, 389, 356, 454, 323, 361, 288, 397, 365, 379, 378, 400, 377, 152, 148, 176, 149, 150,
    136, 172, 58, 132, 93, 234, 127, 162, 21, 54, 103, 67, 109,
];
/// The outer corner of the eye on the image's left for a face looking at the camera (the person's right eye).
const EYE_OUTER_IMAGE_LEFT: usize = 33;
/// The outer corner of the eye on the image's right.
const EYE_OUTER_IMAGE_RIGHT: usize = 263;
/// The outline's point at the image-left cheek.
const CHEEK_IMAGE_LEFT: usize = 234;
/// The outline's point at the image-right cheek.
const CHEEK_IMAGE_RIGHT: usize = 454;

/// A square region of the photo, rotated by `angle`, fed to the network.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaceRegion {
    /// Centre (continuous pixel coordinates, pixel centres at `+0.5`).
    pub centre: Vec2,
    /// Side in photo pixels.
    pub side: f32,
    /// Rotation of the crop's x axis from the photo's (radians, y down: positive turns x toward +y).
    pub angle: f32,
}

impl FaceRegion {
    /// Network input coordinates (0..192, pixel centres at `+0.5`) to photo pixels.
    pub fn to_photo(&self, q: Vec2) -> Vec2 {
        let d = (q / INPUT_SIZE as f32 - Vec2::splat(0.5)) * self.side;
        self.centre + Vec2::from_angle(self.angle).rotate(d)
    }

    /// The first region, from the pose network's face landmarks: level with the eyes, centred a little below
    /// them, as wide as the larger of the ear distance and 2.6 eye-to-mouth distances (a face's height), scaled
    /// by [`CROP_SCALE`]. `None` when the face landmarks are not usable (a face seen from behind, coincident points).
    pub fn from_pose(pose: &PoseLandmarks) -> Option<Self> {
        let p = |i: usize| pose.landmarks.get(i).map(|l| l.pixel);
        // MediaPipe pose: 2 the person's left eye, 5 the right eye, 7/8 the ears, 9/10 the mouth's corners.
        // Which label is on which side does not matter here (a read turned to face the camera swaps them).
        let (eye_a, eye_b) = (p(2)?, p(5)?);
        let (ear_a, ear_b) = (p(7)?, p(8)?);
        let mouth = (p(9)? + p(10)?) * 0.5;
        let eyes = (eye_a + eye_b) * 0.5;
        let across = if eye_a.x >= eye_b.x { eye_a - eye_b } else { eye_b - eye_a };
        if across.length() <= 0.0 || !across.is_finite() {
            return None;
        }
        let angle = across.y.atan2(across.x);
        let down = mouth - eyes;
        let size = ear_a.distance(ear_b).max(2.6 * down.length());
        let side = CROP_SCALE * size;
        let centre = eyes + 0.4 * down;
        (side.is_finite() && side > 4.0 && centre.is_finite()).then_some(Self { centre, side, angle })
    }

    /// MediaPipe's tracking region from a face mesh: level with the eyes' outer corners, the points' box in
    /// that frame squared on its long side and scaled by [`CROP_SCALE`]. `None` for a degenerate mesh.
    pub fn from_mesh(mesh: &FaceMesh) -> Option<Self> {
        let across = mesh.points[EYE_OUTER_IMAGE_RIGHT].truncate() - mesh.points[EYE_OUTER_IMAGE_LEFT].truncate();
        if across.length() <= 0.0 || !across.is_finite() {
            return None;
        }
        let angle = across.y.atan2(across.x);
        let unrotate = Vec2::from_angle(-angle);
        let (mut lo, mut hi) = (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY));
        for p in &mesh.points {
            let q = unrotate.rotate(p.truncate());
            lo = lo.min(q);
            hi = hi.max(q);
        }
        let side = CROP_SCALE * (hi - lo).max_element();
        let centre = Vec2::from_angle(angle).rotate((lo + hi) * 0.5);
        (side.is_finite() && side > 4.0 && centre.is_finite()).then_some(Self { centre, side, angle })
    }
}

/// A face mesh in source-view pixels.
#[derive(Clone, Debug, PartialEq)]
pub struct FaceMesh {
    /// The 468 points: x, y in pixels (pixel centres at `+0.5`), z the depth in the same pixels, **+ toward the
    /// camera**, relative to the mesh's own middle.
    pub points: Vec<Vec3>,
    /// Face-presence probability.
    pub score: f32,
    /// The region the mesh came from.
    pub region: FaceRegion,
    /// How far the mesh moved between the read on the pose's region and the read on the first mesh's own region
    /// ([`FaceEstimator::estimate`]): RMS distance of the points in the image over the face's width; NaN with one
    /// read. A face the network is sure of lands in the same place from both crops.
    pub drift: f32,
}

impl FaceMesh {
    /// Decodes the network's raw output (`POINT_COUNT` x (x, y, z) in input pixels, z + away from the camera) and
    /// presence logit for `region`. `None` when the output has the wrong length or holds a non-finite value.
    pub fn decode(raw: &[f32], logit: f32, region: FaceRegion) -> Option<Self> {
        if raw.len() != 3 * POINT_COUNT || raw.iter().any(|v| !v.is_finite()) || logit.is_nan() {
            return None;
        }
        let scale = region.side / INPUT_SIZE as f32;
        let points = raw
            .chunks_exact(3)
            .map(|p| {
                let xy = region.to_photo(Vec2::new(p[0], p[1]));
                Vec3::new(xy.x, xy.y, -p[2] * scale)
            })
            .collect();
        let score = sigmoid(logit);
        Some(Self { points, score, region, drift: f32::NAN })
    }

    /// Width of the face: distance between the outline's cheek points (pixels).
    pub fn width(&self) -> f32 {
        self.points[CHEEK_IMAGE_LEFT].truncate().distance(self.points[CHEEK_IMAGE_RIGHT].truncate())
    }

    /// How far the face is turned from the camera (radians, 0 facing it), from the depths of the two cheek
    /// points: a turned face has one cheek nearer than the other.
    pub fn yaw(&self) -> f32 {
        let (l, r) = (self.points[CHEEK_IMAGE_LEFT], self.points[CHEEK_IMAGE_RIGHT]);
        (r.z - l.z).abs().atan2(l.truncate().distance(r.truncate()))
    }

    /// The distance between the eyes' midpoint of the mesh (outer corners) and of the pose landmarks (2, 5) over
    /// the face's width: where the two networks put the face apart. NaN without the pose's eyes.
    pub fn pose_offset(&self, pose: &PoseLandmarks) -> f32 {
        let (Some(a), Some(b)) = (pose.landmarks.get(2), pose.landmarks.get(5)) else { return f32::NAN };
        let mesh_eyes = (self.points[EYE_OUTER_IMAGE_LEFT] + self.points[EYE_OUTER_IMAGE_RIGHT]).truncate() * 0.5;
        mesh_eyes.distance((a.pixel + b.pixel) * 0.5) / self.width()
    }
}

/// The face model: `explicit`, else `R2HUMAN_FACE_MODEL`, else `.tools/models/face_landmark.onnx` (installed by
/// `scripts/setup.d/live.sh`).
pub fn model_path(explicit: Option<&Path>) -> Result<PathBuf, BodyError> {
    super::installed_model(explicit, "R2HUMAN_FACE_MODEL", MODEL_FILE, "face landmark model", "")
}

/// The network's input for `region` of `rgb` (linear RGB): `[192, 192, 3]` sRGB in `[0, 1]`, black outside the
/// image, box-filtered when the region is larger than the input ([`crate::buffer::supersampled`], the pose
/// network's rule for its taps).
pub fn network_input(rgb: &RgbImage, region: FaceRegion) -> Vec<f32> {
    let taps = ((region.side / INPUT_SIZE as f32).ceil() as usize).clamp(1, 4);
    let cells = supersampled(rgb, INPUT_SIZE, taps, |q| region.to_photo(q));
    cells.iter().flat_map(|v| v.to_array()).map(network_value).collect()
}

/// MediaPipe's face landmark network in an ONNX Runtime session.
pub struct FaceEstimator {
    session: Session,
    path: PathBuf,
}

impl std::fmt::Debug for FaceEstimator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FaceEstimator").field("path", &self.path).finish()
    }
}

impl FaceEstimator {
    /// Loads the model (see [`model_path`]).
    pub fn load(model: Option<&Path>, options: &RuntimeOptions) -> Result<Self, BodyError> {
        let path = model_path(model)?;
        let (session, _) =
            crate::neural::create_session(&path, "face landmark model", options).map_err(BodyError::ModelLoad)?;
        let outputs: Vec<String> = session.outputs().iter().map(|o| o.name().to_string()).collect();
        for needed in ["conv2d_21", "conv2d_31"] {
            if !outputs.iter().any(|o| o == needed) {
                return Err(BodyError::Model(format!(
                    "`{}` is not MediaPipe's face landmark model (no output `{needed}`; outputs {outputs:?}); \
                     reinstall it with `bash scripts/setup.d/live.sh`",
                    path.display()
                )));
            }
        }
        Ok(Self { session, path })
    }

    /// The model file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Runs the network once on `region` of `rgb`.
    fn run(&mut self, rgb: &RgbImage, region: FaceRegion) -> Result<Option<FaceMesh>, BodyError> {
        let input = network_input(rgb, region);
        let shape = (1, INPUT_SIZE, INPUT_SIZE, 3);
        let outputs = ["conv2d_21", "conv2d_31"];
        let mut out = super::run_image_network(&mut self.session, &self.path, shape, &input, &outputs)?.into_iter();
        let (raw, logit) = (out.next().unwrap_or_default(), out.next().and_then(|l| l.first().copied()));
        let logit = logit.unwrap_or(f32::NEG_INFINITY);
        Ok(FaceMesh::decode(&raw, logit, region).filter(|m| m.score >= MIN_FACE_SCORE))
    }

    /// The face mesh of the person whose pose landmarks are `pose` in `rgb` (linear RGB, the pose's pixels): one
    /// run on the region the pose gives ([`FaceRegion::from_pose`]), one more on the region that mesh gives
    /// ([`FaceRegion::from_mesh`]; the first mesh when that one finds no face). `None` when no face is found.
    pub fn estimate(&mut self, rgb: &RgbImage, pose: &PoseLandmarks) -> Result<Option<FaceMesh>, BodyError> {
        let Some(region) = FaceRegion::from_pose(pose) else { return Ok(None) };
        let Some(first) = self.run(rgb, region)? else { return Ok(None) };
        let Some(next) = FaceRegion::from_mesh(&first) else { return Ok(Some(first)) };
        Ok(Some(match self.run(rgb, next)? {
            Some(mut second) => {
                let sum: f32 = first
                    .points
                    .iter()
                    .zip(&second.points)
                    .map(|(a, b)| a.truncate().distance_squared(b.truncate()))
                    .sum();
                second.drift = (sum / POINT_COUNT as f32).sqrt() / second.width();
                second
            }
            None => first,
        }))
    }
}

/// Why [`with_face_relief`] left the surfaces as they were.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum NoRelief {
    /// The face is smaller than [`MIN_FACE_WIDTH`] (pixels, at this view's size).
    Small(f32),
    /// The face is turned from the camera by more than [`MAX_FACE_YAW`] (radians).
    Turned(f32),
    /// Under [`MIN_OUTLINE_IN_MASK`] of the outline's points lie in the person's mask.
    OutsideMask(f32),
    /// The mesh is degenerate (its outline spans no area, or a plane through it cannot be fitted).
    Degenerate,
}

/// Least-squares plane `z = a x + b y + c` through `points` (x, y, z); `None` when they do not span a plane.
fn fit_plane(points: impl Iterator<Item = DVec3>) -> Option<DVec3> {
    let (mut ata, mut atz) = (DMat3::ZERO, DVec3::ZERO);
    for p in points {
        let row = DVec3::new(p.x, p.y, 1.0);
        ata += DMat3::from_cols(row * row.x, row * row.y, row * row.z);
        atz += row * p.z;
    }
    let det = ata.determinant();
    (det.abs() > 1e-9 && det.is_finite()).then(|| ata.inverse() * atz).filter(|s| s.is_finite())
}

/// Distance from `p` to the closed polygon `outline` and whether `p` lies inside it (even-odd rule).
fn inside_and_distance(p: Vec2, outline: &[Vec2]) -> (bool, f32) {
    let mut inside = false;
    let mut best = f32::INFINITY;
    for (k, &a) in outline.iter().enumerate() {
        let b = outline[(k + 1) % outline.len()];
        if (a.y > p.y) != (b.y > p.y) && p.x < a.x + (p.y - a.y) / (b.y - a.y) * (b.x - a.x) {
            inside = !inside;
        }
        let ab = b - a;
        let t = if ab.length_squared() > 0.0 { ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
        best = best.min(p.distance(a + t * ab));
    }
    (inside, best)
}

/// `surfaces` with the front of the face shaped by `mesh` (module docs); the surfaces as they were, and why, when
/// the mesh is skipped. Only columns inside the surfaces' mask change; every changed front stays at least two depth
/// samples of a 512-sample column in front of its back.
pub fn with_face_relief(mut surfaces: InflatedSurfaces, mesh: &FaceMesh) -> (InflatedSurfaces, Option<NoRelief>) {
    let (w, h) = (surfaces.front.width, surfaces.front.height);
    if mesh.points.len() != POINT_COUNT
        || (surfaces.back.width, surfaces.back.height) != (w, h)
        || (surfaces.mask.width, surfaces.mask.height) != (w, h)
        || w == 0
    {
        return (surfaces, Some(NoRelief::Degenerate));
    }
    let half = w as f32 * 0.5;
    let width = mesh.width();
    let min_width = MIN_FACE_WIDTH * w as f32 / 512.0;
    if width.is_nan() || width < min_width {
        return (surfaces, Some(NoRelief::Small(width)));
    }
    let yaw = mesh.yaw();
    if yaw.is_nan() || yaw > MAX_FACE_YAW {
        return (surfaces, Some(NoRelief::Turned(yaw)));
    }
    let outline: Vec<Vec2> = FACE_OVAL.iter().map(|&i| mesh.points[i].truncate()).collect();
    let mask_at = |c: i64, r: i64| {
        (0..w as i64).contains(&c) && (0..h as i64).contains(&r) && *surfaces.mask.get(c as usize, r as usize) > 0.5
    };
    let in_mask = |p: Vec2| mask_at(p.x.floor() as i64, p.y.floor() as i64);
    // At most 32 px: the search is a disc around each of the 36 points.
    let slack = ((OUTLINE_SLACK * width).ceil() as i64).clamp(0, 32);
    let near_mask = |p: Vec2| {
        let (c, r) = (p.x.floor() as i64, p.y.floor() as i64);
        (-slack..=slack)
            .any(|dr| (-slack..=slack).any(|dc| dc * dc + dr * dr <= slack * slack && mask_at(c + dc, r + dr)))
    };
    let inside_share = outline.iter().filter(|&&p| near_mask(p)).count() as f32 / outline.len() as f32;
    tracing::debug!("face mesh outline near the mask: {inside_share:.3}");
    if inside_share < MIN_OUTLINE_IN_MASK {
        return (surfaces, Some(NoRelief::OutsideMask(inside_share)));
    }
    // The planes through the old front surface and through the mesh's depths along the outline (cube units).
    let front_at = |p: Vec2| {
        let (c, r) = ((p.x.floor() as usize).min(w - 1), (p.y.floor() as usize).min(h - 1));
        *surfaces.front.get(c, r)
    };
    let rim_front = fit_plane(
        outline.iter().filter(|&&p| in_mask(p)).map(|&p| DVec3::new(p.x as f64, p.y as f64, front_at(p) as f64)),
    );
    let rim_mesh = fit_plane(FACE_OVAL.iter().map(|&i| {
        let p = mesh.points[i];
        DVec3::new(p.x as f64, p.y as f64, (p.z / half) as f64)
    }));
    let (Some(rim_front), Some(rim_mesh)) = (rim_front, rim_mesh) else {
        return (surfaces, Some(NoRelief::Degenerate));
    };
    let plane = |s: DVec3, p: Vec2| (s.x * p.x as f64 + s.y * p.y as f64 + s.z) as f32;
    // The mesh's depth at any pixel inside it: linear over its Delaunay triangles.
    use spade::{DelaunayTriangulation, HasPosition, Point2, Triangulation};
    struct MeshPoint {
        at: Point2<f64>,
        depth: f64,
    }
    impl HasPosition for MeshPoint {
        type Scalar = f64;
        fn position(&self) -> Point2<f64> {
            self.at
        }
    }
    let mut triangulation = DelaunayTriangulation::<MeshPoint>::new();
    for p in &mesh.points {
        let at = Point2::new(p.x as f64, p.y as f64);
        if triangulation.insert(MeshPoint { at, depth: (p.z / half) as f64 }).is_err() {
            return (surfaces, Some(NoRelief::Degenerate));
        }
    }
    let (mut lo, mut hi) = (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY));
    for p in &outline {
        lo = lo.min(*p);
        hi = hi.max(*p);
    }
    let (c0, c1) = (lo.x.floor().max(0.0) as usize, (hi.x.ceil().max(0.0) as usize).min(w));
    let (r0, r1) = (lo.y.floor().max(0.0) as usize, (hi.y.ceil().max(0.0) as usize).min(h));
    let bw = c1.saturating_sub(c0);
    // The mesh's depth at the pixel centres of the outline's box: linear over each Delaunay triangle (barycentric
    // weights from edge functions; a centre on a shared edge takes the first triangle's value, the same there).
    let mut depth = vec![f32::NAN; bw * r1.saturating_sub(r0)];
    for face in triangulation.inner_faces() {
        let [a, b, c] =
            face.vertices().map(|v| (Vec2::new(v.data().at.x as f32, v.data().at.y as f32), v.data().depth as f32));
        let area = (b.0 - a.0).perp_dot(c.0 - a.0);
        if area.abs() < 1e-9 {
            continue;
        }
        let (tlo, thi) = (a.0.min(b.0).min(c.0), a.0.max(b.0).max(c.0));
        let col_lo = ((tlo.x - 0.5).ceil() as i64).max(c0 as i64);
        let col_hi = ((thi.x - 0.5).floor() as i64).min(c1 as i64 - 1);
        let row_lo = ((tlo.y - 0.5).ceil() as i64).max(r0 as i64);
        let row_hi = ((thi.y - 0.5).floor() as i64).min(r1 as i64 - 1);
        for r in row_lo..=row_hi {
            for col in col_lo..=col_hi {
                let p = Vec2::new(col as f32 + 0.5, r as f32 + 0.5);
                let wa = (b.0 - p).perp_dot(c.0 - p) / area;
                let wb = (c.0 - p).perp_dot(a.0 - p) / area;
                let wc = 1.0 - wa - wb;
                if wa < -1e-5 || wb < -1e-5 || wc < -1e-5 {
                    continue;
                }
                let k = (r as usize - r0) * bw + (col as usize - c0);
                if depth[k].is_nan() {
                    depth[k] = wa * a.1 + wb * b.1 + wc * c.1;
                }
            }
        }
    }
    let feather = FEATHER * width;
    let min_thickness = 2.0 * 2.0 / 512.0;
    for r in r0..r1 {
        for c in c0..c1 {
            let i = r * w + c;
            let d = depth[(r - r0) * bw + (c - c0)];
            if surfaces.mask.data[i] <= 0.5 || !d.is_finite() {
                continue;
            }
            let p = Vec2::new(c as f32 + 0.5, r as f32 + 0.5);
            let (inside, distance) = inside_and_distance(p, &outline);
            if !inside {
                continue;
            }
            let target = plane(rim_front, p) + (d - plane(rim_mesh, p));
            let t = (distance / feather).clamp(0.0, 1.0);
            let weight = t * t * (3.0 - 2.0 * t);
            let old = surfaces.front.data[i];
            let new = (old + weight * (target - old)).max(surfaces.back.data[i] + min_thickness);
            if new.is_finite() {
                surfaces.front.data[i] = new;
            }
        }
    }
    (surfaces, None)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::buffer::Image;

    /// A synthetic face mesh: points on a grid over a disc of radius `radius` about `centre`, the outline points
    /// on its rim, depth `depth(p)` (pixels, + toward the camera).
    fn mesh(centre: Vec2, radius: f32, depth: impl Fn(Vec2) -> f32) -> FaceMesh {
        let mut points = vec![Vec3::ZERO; POINT_COUNT];
        let is_outline = |i: usize| FACE_OVAL.contains(&i);
        for (k, &i) in FACE_OVAL.iter().enumerate() {
            let a = std::f32::consts::TAU * k as f32 / FACE_OVAL.len() as f32;
            // Start at the top, go clockwise on screen (x right, y down) like the real oval.
            let p = centre + radius * Vec2::new(a.sin(), -a.cos());
            points[i] = p.extend(depth(p));
        }
        // Cheek points sit on the outline already (234 and 454 are in FACE_OVAL); the rest fill the disc.
        let inner: Vec<usize> = (0..POINT_COUNT).filter(|&i| !is_outline(i)).collect();
        let n = inner.len();
        for (k, &i) in inner.iter().enumerate() {
            // A sunflower spiral inside 0.95 of the radius: distinct points, even cover.
            let rr = 0.95 * radius * ((k as f32 + 0.5) / n as f32).sqrt();
            let a = k as f32 * 2.399_963;
            let p = centre + rr * Vec2::new(a.cos(), a.sin());
            points[i] = p.extend(depth(p));
        }
        FaceMesh { points, score: 1.0, region: FaceRegion { centre, side: 3.0 * radius, angle: 0.0 }, drift: 0.0 }
    }

    fn flat(w: usize, front: f32, back: f32) -> InflatedSurfaces {
        InflatedSurfaces { front: Image::new(w, w, front), back: Image::new(w, w, back), mask: Image::new(w, w, 1.0) }
    }

    #[test]
    fn a_crop_maps_to_the_photo_and_back() {
        let region = FaceRegion { centre: Vec2::new(200.0, 150.0), side: 96.0, angle: 0.3 };
        // The input's centre is the region's centre; its x axis is turned by the angle; its side is the region's.
        assert!(region.to_photo(Vec2::splat(96.0)).distance(region.centre) < 1e-4);
        let right = region.to_photo(Vec2::new(192.0, 96.0)) - region.centre;
        assert!((right - 48.0 * Vec2::new(0.3f32.cos(), 0.3f32.sin())).length() < 1e-3);
        // Its inverse, by definition: undo the turn, then the scale and the centre.
        let to_input = |p: Vec2| {
            let d = Vec2::from_angle(-region.angle).rotate(p - region.centre);
            (d / region.side + Vec2::splat(0.5)) * INPUT_SIZE as f32
        };
        for q in [Vec2::new(0.0, 0.0), Vec2::new(12.5, 170.0), Vec2::new(191.0, 3.0)] {
            assert!(to_input(region.to_photo(q)).distance(q) < 1e-3);
        }
    }

    #[test]
    fn decoding_scales_depth_like_x_and_turns_it_toward_the_camera() {
        let region = FaceRegion { centre: Vec2::new(100.0, 100.0), side: 384.0, angle: 0.0 };
        let mut raw = vec![96.0f32; 3 * POINT_COUNT];
        raw[0] = 0.0; // first point at the crop's left edge, depth 96 (away) -> -192 photo px (toward: negative)
        raw[1] = 96.0;
        raw[2] = 96.0;
        let m = FaceMesh::decode(&raw, 0.0, region).expect("decodes");
        assert!((m.score - 0.5).abs() < 1e-6);
        assert!(m.points[0].truncate().distance(Vec2::new(-92.0, 100.0)) < 1e-3);
        assert!((m.points[0].z + 192.0).abs() < 1e-3);
        assert!(FaceMesh::decode(&raw[1..], 0.0, region).is_none());
        raw[5] = f32::NAN;
        assert!(FaceMesh::decode(&raw, 0.0, region).is_none());
    }

    #[test]
    fn the_tracking_region_is_the_meshs_box_squared_and_scaled() {
        let m = mesh(Vec2::new(64.0, 80.0), 20.0, |_| 0.0);
        let region = FaceRegion::from_mesh(&m).expect("region");
        assert!(region.centre.distance(Vec2::new(64.0, 80.0)) < 0.5);
        assert!((region.side - CROP_SCALE * 40.0).abs() < 1.0, "{}", region.side);
    }

    #[test]
    fn a_flat_face_mesh_leaves_a_flat_front_as_it_was() {
        let s = flat(128, 0.2, -0.2);
        let (out, why) = with_face_relief(s.clone(), &mesh(Vec2::new(64.0, 64.0), 30.0, |_| 5.0));
        assert_eq!(why, None);
        for (a, b) in out.front.data.iter().zip(&s.front.data) {
            assert!((a - b).abs() < 1e-5);
        }
    }

    #[test]
    fn the_relief_is_the_meshs_depth_above_its_outline_on_the_old_rim() {
        // A cone nose: depth 12 px at the centre falling to 0 at the rim; the old front a tilted plane
        // z = 0.2 + 0.001 (x - 64). Well inside the fade the new front is the plane plus the cone (in cube units,
        // 64 px per unit at 128²); outside the outline nothing changes.
        let centre = Vec2::new(64.0, 64.0);
        let radius = 30.0;
        let cone = |p: Vec2| 12.0 * (1.0 - p.distance(centre) / radius).max(0.0);
        let mut s = flat(128, 0.0, -0.5);
        for r in 0..128 {
            for c in 0..128 {
                s.front.set(c, r, 0.2 + 0.001 * (c as f32 + 0.5 - 64.0));
            }
        }
        let (out, why) = with_face_relief(s.clone(), &mesh(centre, radius, cone));
        assert_eq!(why, None);
        for (c, r) in [(64usize, 64usize), (60, 70), (70, 58)] {
            let p = Vec2::new(c as f32 + 0.5, r as f32 + 0.5);
            let expected = 0.2 + 0.001 * (p.x - 64.0) + cone(p) / 64.0;
            // Linear interpolation over the spiral's triangles: within a pixel of depth of the cone.
            assert!(
                (out.front.get(c, r) - expected).abs() < 1.0 / 64.0,
                "({c}, {r}): {} vs {expected}",
                out.front.get(c, r)
            );
        }
        for (c, r) in [(10usize, 10usize), (64, 100), (100, 64)] {
            assert_eq!(out.front.get(c, r), s.front.get(c, r));
        }
        assert_eq!(out.back, s.back);
        assert!(out.front.data.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn a_deep_socket_never_pushes_the_front_behind_the_back() {
        let centre = Vec2::new(64.0, 64.0);
        let (out, why) =
            with_face_relief(flat(128, 0.01, 0.0), &mesh(centre, 30.0, |p| -40.0 * (1.0 - p.distance(centre) / 30.0)));
        assert_eq!(why, None);
        let min = 2.0 * 2.0 / 512.0;
        assert!(out.front.data.iter().zip(&out.back.data).all(|(f, b)| *f >= *b + min - 1e-6));
        // The socket's middle went as far back as it may.
        assert!((out.front.get(64, 64) - min).abs() < 1e-6, "{}", out.front.get(64, 64));
    }

    #[test]
    fn small_turned_outside_and_degenerate_faces_are_skipped() {
        let centre = Vec2::new(64.0, 64.0);
        let s = flat(128, 0.2, -0.2);
        // Small: 2 x 6 px wide at 128² is under 32 px at 512² (8 px here).
        let (out, why) = with_face_relief(s.clone(), &mesh(centre, 3.0, |_| 0.0));
        assert!(matches!(why, Some(NoRelief::Small(_))), "{why:?}");
        assert_eq!(out, s);
        // Turned: the image-right cheek 14 px nearer than the left over a 60 px width (yaw atan(14/60) = 0.23
        // rad is under the limit of 0.25; 17 px, atan(17/60) = 0.28 rad, is over it).
        let tilted = |k: f32| move |p: Vec2| k * (p.x - 34.0) / 60.0;
        assert_eq!(with_face_relief(s.clone(), &mesh(centre, 30.0, tilted(14.0))).1, None);
        assert!(matches!(with_face_relief(s.clone(), &mesh(centre, 30.0, tilted(17.0))).1, Some(NoRelief::Turned(_))));
        // Outside the mask: the mask covers the left half only.
        let mut half = s.clone();
        half.mask = Image::from_fn(128, 128, |c, _| if c < 64 { 1.0 } else { 0.0 });
        let (out, why) = with_face_relief(half.clone(), &mesh(centre, 30.0, |_| 0.0));
        assert!(matches!(why, Some(NoRelief::OutsideMask(_))), "{why:?}");
        assert_eq!(out, half);
        // A mask two pixels tighter than the outline (the jaw on the face's own edge): still the person's face.
        let mut tight = s.clone();
        tight.mask = Image::from_fn(128, 128, |c, r| {
            let d = Vec2::new(c as f32 + 0.5, r as f32 + 0.5).distance(centre);
            if d < 28.0 || r < 64 {
                1.0
            } else {
                0.0
            }
        });
        assert_eq!(with_face_relief(tight, &mesh(centre, 30.0, |_| 0.0)).1, None);
        // Degenerate: every point at one place; NaN depths.
        let mut m = mesh(centre, 30.0, |_| 0.0);
        m.points.iter_mut().for_each(|p| *p = Vec3::new(64.0, 64.0, 0.0));
        assert!(with_face_relief(s.clone(), &m).1.is_some());
        let mut m = mesh(centre, 30.0, |_| f32::NAN);
        m.points[0].x = f32::NAN;
        let (out, _) = with_face_relief(s.clone(), &m);
        assert!(out.front.data.iter().all(|v| v.is_finite()));
    }
}
