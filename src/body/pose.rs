//! Pose landmarks from a photo: the MediaPipe Pose landmark "full" network (BlazePose GHUM 3D, from the PyPI
//! wheel `mediapipe` 0.10.21, Apache-2.0, converted to ONNX by `scripts/setup.d/live.sh`) run through ONNX
//! Runtime.
//!
//! # What the network expects and returns (checked against the converted model and the photos)
//! - Input `[1, 3, 256, 256]`: RGB, sRGB-encoded in `[0, 1]`, of a square, upright region around the person
//!   (MediaPipe's region of interest; outside the photo the region is black).
//! - `Identity` `[1, 195]`: 39 points x (x, y, z, visibility, presence) in input pixels; `z` is depth in the
//!   same units as `x`, relative to the middle of the hips, smaller = nearer the camera; visibility and presence
//!   are logits (a sigmoid gives the probability). Points 0..33 are the pose landmarks ([`NAMES`]), 33 and 34
//!   the auxiliary points MediaPipe uses to place the next region (hip centre, and a point whose distance from
//!   it is half the body's extent).
//! - `Identity_1` `[1, 1]`: the pose presence score, already a probability.
//! - `Identity_4` `[1, 117]`: 39 x (x, y, z) world landmarks in metres, origin at the hip centre, x right, y down,
//!   z away from the camera (axes of the input region).
//!
//! # The region
//! First the mask's bounding box, squared and enlarged by [`MASK_MARGIN`] around its centre (the person detector's
//! box in MediaPipe is about 1.25 times the person). When the network finds a pose there, it runs once more on
//! the region MediaPipe's tracker derives from the auxiliary points (centre = hip centre, side = 1.5 x 2 x
//! their distance), which is how the network was trained to see people. Live frames are read the same way, each
//! from its own mask: MediaPipe's tracking (one run on the region the previous frame's points give) made the
//! region, and the fitted body with it, wander on a still person ([`crate::body::prior::BodyEstimator::estimate`]).
//!
//! Landmarks come back in the photo's continuous pixel coordinates (pixel centres at `+0.5`), and depths in the
//! same pixels with **+ toward the camera** (the body cube's convention); [`PoseLandmarks::transformed`] maps
//! them into the normalised source view and [`PoseLandmarks::cube`] into body-cube coordinates.

use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};
use ort::session::Session;

use super::BodyError;
use crate::buffer::{bilinear_cell, linear_to_srgb, sample_bilinear_cell, GrayImage, RgbImage};
use crate::neural::RuntimeOptions;

/// Number of pose landmarks.
pub const LANDMARK_COUNT: usize = 33;
/// Points the network outputs (landmarks + auxiliary points).
const NETWORK_POINTS: usize = 39;
/// Network input side.
pub const INPUT_SIZE: usize = 256;
/// Side of the first region relative to the mask's larger bounding-box side.
pub const MASK_MARGIN: f32 = 1.25;
/// MediaPipe's region scale around the auxiliary points (`pose_landmarks_to_roi`: 1.5).
pub const AUX_SCALE: f32 = 1.5;
/// Pose presence below which the network is taken to have found no person.
pub const MIN_POSE_SCORE: f32 = 0.5;
/// How far above a cut photo's bottom edge (fraction of its height) a visible foot means a folded body
/// ([`PoseLandmarks::legs_above_cut`]). The folded Grace Hopper portrait has its ankles 19 % above the edge.
pub const FOLD_MARGIN: f32 = 0.1;
/// File name of the model under `.tools/models/`.
pub const MODEL_FILE: &str = "pose_landmark_full.onnx";

/// Landmark names, in the network's order (MediaPipe's topology; "left" is the person's left).
pub const NAMES: [&str; LANDMARK_COUNT] = [
    "nose",
    "left eye (inner)",
    "left eye",
    "left eye (outer)",
    "right eye (inner)",
    "right eye",
    "right eye (outer)",
    "left ear",
    "right ear",
    "mouth (left)",
    "mouth (right)",
    "left shoulder",
    "right shoulder",
    "left elbow",
    "right elbow",
    "left wrist",
    "right wrist",
    "left pinky",
    "right pinky",
    "left index",
    "right index",
    "left thumb",
    "right thumb",
    "left hip",
    "right hip",
    "left knee",
    "right knee",
    "left ankle",
    "right ankle",
    "left heel",
    "right heel",
    "left foot index",
    "right foot index",
];

/// The left/right pairs of [`NAMES`] (left, right).
const MIRROR_PAIRS: [(usize, usize); 16] = [
    (1, 4),
    (2, 5),
    (3, 6),
    (7, 8),
    (9, 10),
    (11, 12),
    (13, 14),
    (15, 16),
    (17, 18),
    (19, 20),
    (21, 22),
    (23, 24),
    (25, 26),
    (27, 28),
    (29, 30),
    (31, 32),
];

/// Landmark indices used by the fitter.
pub mod index {
    /// Nose.
    pub const NOSE: usize = 0;
    /// Left ear.
    pub const LEFT_EAR: usize = 7;
    /// Right ear.
    pub const RIGHT_EAR: usize = 8;
    /// Left shoulder.
    pub const LEFT_SHOULDER: usize = 11;
    /// Right shoulder.
    pub const RIGHT_SHOULDER: usize = 12;
    /// Left elbow.
    pub const LEFT_ELBOW: usize = 13;
    /// Right elbow.
    pub const RIGHT_ELBOW: usize = 14;
    /// Left wrist.
    pub const LEFT_WRIST: usize = 15;
    /// Right wrist.
    pub const RIGHT_WRIST: usize = 16;
    /// Left hip.
    pub const LEFT_HIP: usize = 23;
    /// Right hip.
    pub const RIGHT_HIP: usize = 24;
    /// Left knee.
    pub const LEFT_KNEE: usize = 25;
    /// Right knee.
    pub const RIGHT_KNEE: usize = 26;
    /// Left ankle.
    pub const LEFT_ANKLE: usize = 27;
    /// Right ankle.
    pub const RIGHT_ANKLE: usize = 28;
    /// Left foot index (toe).
    pub const LEFT_FOOT: usize = 31;
    /// Right foot index (toe).
    pub const RIGHT_FOOT: usize = 32;
}

/// Pairs of landmarks drawn as the skeleton (for pictures and checks).
pub const SKELETON: [(usize, usize); 16] = [
    (11, 12),
    (11, 13),
    (13, 15),
    (12, 14),
    (14, 16),
    (11, 23),
    (12, 24),
    (23, 24),
    (23, 25),
    (25, 27),
    (24, 26),
    (26, 28),
    (27, 31),
    (28, 32),
    (0, 7),
    (0, 8),
];

/// A square, upright region of the photo fed to the network: centre and side in photo pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseRegion {
    /// Centre (continuous pixel coordinates).
    pub centre: Vec2,
    /// Side length in photo pixels.
    pub side: f32,
}

impl PoseRegion {
    /// Photo pixels per network input pixel.
    pub fn scale(&self) -> f32 {
        self.side / INPUT_SIZE as f32
    }

    /// Network input coordinates (0..256) to photo pixels.
    pub fn to_photo(&self, p: Vec2) -> Vec2 {
        self.centre + (p - Vec2::splat(0.5 * INPUT_SIZE as f32)) * self.scale()
    }

    /// The first region: the bounding box of `mask >= 0.5`, squared and enlarged by [`MASK_MARGIN`]. `None` for
    /// an empty mask.
    pub fn from_mask(mask: &GrayImage) -> Option<Self> {
        let (mut c0, mut r0, mut c1, mut r1) = (usize::MAX, usize::MAX, 0usize, 0usize);
        for (k, &m) in mask.data.iter().enumerate() {
            if m >= 0.5 {
                let (c, r) = (k % mask.width, k / mask.width);
                c0 = c0.min(c);
                r0 = r0.min(r);
                c1 = c1.max(c + 1);
                r1 = r1.max(r + 1);
            }
        }
        if c0 == usize::MAX {
            return None;
        }
        let centre = Vec2::new((c0 + c1) as f32, (r0 + r1) as f32) * 0.5;
        let side = MASK_MARGIN * ((c1 - c0).max(r1 - r0) as f32);
        Some(Self { centre, side })
    }

    /// MediaPipe's tracking region from the two auxiliary points (photo pixels): centred on the first, side
    /// [`AUX_SCALE`] x 2 x their distance. `None` when the points are not finite or coincide.
    pub fn from_auxiliary(centre: Vec2, scale_point: Vec2) -> Option<Self> {
        let side = AUX_SCALE * 2.0 * centre.distance(scale_point);
        (centre.is_finite() && side.is_finite() && side > 1.0).then_some(Self { centre, side })
    }
}

/// One pose landmark in photo pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Landmark {
    /// Position (continuous pixel coordinates, `+0.5` = first pixel centre).
    pub pixel: Vec2,
    /// Depth relative to the hip centre in the same pixels, **+ toward the camera**.
    pub depth: f32,
    /// Probability that the point is visible (in the photo and not occluded).
    pub visibility: f32,
    /// Probability that the point is in the photo's frame (occluded or not).
    pub presence: f32,
}

/// The 33 landmarks of one person, their world landmarks, and where they were found.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseLandmarks {
    /// Image landmarks, [`NAMES`] order.
    pub landmarks: Vec<Landmark>,
    /// World landmarks in metres, origin at the hip centre, x right, **y up, z toward the camera** (the body
    /// cube's axes; the network's are y down, z away).
    pub world: Vec<Vec3>,
    /// The network's pose presence score in `[0, 1]`.
    pub score: f32,
    /// The region the landmarks came from.
    pub region: PoseRegion,
    /// MediaPipe's tracking region for the next frame (from the auxiliary points).
    pub next_region: Option<PoseRegion>,
    /// Top-left corner of the photo in these pixels (a landmark outside the frame is outside the photo).
    pub frame_min: Vec2,
    /// Bottom-right corner of the photo in these pixels.
    pub frame_max: Vec2,
}

/// Where the photo lies in the image the network runs on: `(min, max)` corners in pixels. A photo normalised into
/// the source view covers only part of it ([`crate::pipeline::input::NormalisedInput::frame`]); the rest is black
/// padding, not a place where the body ends.
pub type PhotoFrame = (Vec2, Vec2);

pub(super) fn sigmoid(v: f32) -> f32 {
    1.0 / (1.0 + (-v.clamp(-60.0, 60.0)).exp())
}

/// One linear colour channel as MediaPipe's networks (pose, face mesh) read it: sRGB in `[0, 1]`, 0 when not finite.
pub(super) fn network_value(linear: f32) -> f32 {
    let x = linear_to_srgb(linear);
    if x.is_finite() {
        x.clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// The world landmarks (`Identity_4`, 39 x 3 values, metres, y down, z away from the camera) as
/// [`PoseLandmarks::world`] holds them: the first [`LANDMARK_COUNT`], y up and z toward the camera; a non-finite
/// point becomes the origin. `None` when there are too few values.
pub fn decode_world(world: &[f32]) -> Option<Vec<Vec3>> {
    if world.len() < NETWORK_POINTS * 3 {
        return None;
    }
    Some(
        (0..LANDMARK_COUNT)
            .map(|i| {
                let w = Vec3::new(world[i * 3], -world[i * 3 + 1], -world[i * 3 + 2]);
                if w.is_finite() {
                    w
                } else {
                    Vec3::ZERO
                }
            })
            .collect(),
    )
}

impl PoseLandmarks {
    /// Decodes the network's raw outputs (`raw`: 39 x 5 values, `world`: 39 x 3, `score`: pose presence) for
    /// `region` of a `frame`-sized image. Non-finite values become invisible points at the region's centre.
    pub fn decode(raw: &[f32], world: &[f32], score: f32, region: PoseRegion, frame: PhotoFrame) -> Option<Self> {
        if raw.len() < NETWORK_POINTS * 5 || world.len() < NETWORK_POINTS * 3 {
            return None;
        }
        let point = |i: usize| -> (Vec2, f32, f32, f32) {
            let v = &raw[i * 5..i * 5 + 5];
            let p = Vec2::new(v[0], v[1]);
            if p.is_finite() && v[2].is_finite() && v[3].is_finite() && v[4].is_finite() {
                (region.to_photo(p), -v[2] * region.scale(), sigmoid(v[3]), sigmoid(v[4]))
            } else {
                (region.centre, 0.0, 0.0, 0.0)
            }
        };
        let landmarks: Vec<Landmark> = (0..LANDMARK_COUNT)
            .map(|i| {
                let (pixel, depth, visibility, presence) = point(i);
                Landmark { pixel, depth, visibility, presence }
            })
            .collect();
        let world = decode_world(world)?;
        let next_region = PoseRegion::from_auxiliary(point(33).0, point(34).0);
        let score = if score.is_finite() { score.clamp(0.0, 1.0) } else { 0.0 };
        Some(Self { landmarks, world, score, region, next_region, frame_min: frame.0, frame_max: frame.1 })
    }

    /// The region to look again in. MediaPipe's tracking region ([`PoseLandmarks::next_region`]) when the whole
    /// person is in the photo. When the photo cuts the person at the bottom (`cut`: a head-and-shoulders or
    /// half-body photo) the network, given a region the visible part fills, explains it as a small whole body
    /// (hips at the chest, legs over the arms); the region is then the larger of the tracking region and the one
    /// the head and shoulders imply for a whole adult body ([`PoseLandmarks::body_region`]), so the hidden part
    /// of the body falls outside the photo, where the network sees black and reports it absent.
    pub fn refined_region(&self, cut: bool) -> Option<PoseRegion> {
        let body = if cut { self.body_region() } else { None };
        match (self.next_region, body) {
            (Some(a), Some(b)) => Some(if b.side > a.side { b } else { a }),
            (a, b) => a.or(b),
        }
    }

    /// The region a whole adult body would need, from the shoulders and the nose (the landmarks a portrait shows
    /// reliably): body height `H = max(4.2 x shoulder width, 6 x nose-to-shoulder-centre distance)`, hip centre
    /// `0.3 H` below the shoulder centre, side `1.5 H` (MediaPipe's margin). `None` when the shoulders or the nose
    /// are not visible.
    pub fn body_region(&self) -> Option<PoseRegion> {
        use index::{LEFT_SHOULDER, NOSE, RIGHT_SHOULDER};
        let l = &self.landmarks;
        if [NOSE, LEFT_SHOULDER, RIGHT_SHOULDER].iter().any(|&i| l[i].visibility < 0.5) {
            return None;
        }
        let shoulders = 0.5 * (l[LEFT_SHOULDER].pixel + l[RIGHT_SHOULDER].pixel);
        let width = l[LEFT_SHOULDER].pixel.distance(l[RIGHT_SHOULDER].pixel);
        let height = (4.2 * width).max(6.0 * l[NOSE].pixel.distance(shoulders));
        let centre = shoulders + Vec2::new(0.0, 0.3 * height);
        let side = 1.5 * height;
        (centre.is_finite() && side.is_finite() && side > 1.0).then_some(PoseRegion { centre, side })
    }

    /// Whether the network places a foot (ankle, heel or toe) inside the photo's frame more than `margin` (a
    /// fraction of the frame's height) above its bottom edge, seen or hidden. In a photo whose mask runs off the
    /// bottom edge this means the network folded a whole body into the visible part (a full body standing on the
    /// edge has its feet there; a body the photo cuts has them below it). Hidden feet count: a folded body often
    /// hides them behind the visible part (measured on an upper-body synthetic crop: the whole body inside the
    /// head, feet at visibility 0.1–0.35).
    pub fn legs_above_cut(&self, margin: f32) -> bool {
        let limit = self.frame_max.y - margin * (self.frame_max.y - self.frame_min.y);
        (index::LEFT_ANKLE..LANDMARK_COUNT).any(|i| self.in_frame(i, 0.0) && self.landmarks[i].pixel.y < limit)
    }

    /// Which way the torso faces according to the world landmarks: the component toward the camera of the unit
    /// normal `(left − right) × (shoulders − hips)` (both shoulders and both hips; `1` faces the camera, `-1` faces
    /// away, about 0 in profile). `None` when the torso's landmarks are not finite or degenerate.
    pub fn facing(&self) -> Option<f32> {
        use index::{LEFT_HIP, LEFT_SHOULDER, RIGHT_HIP, RIGHT_SHOULDER};
        let w = |i: usize| self.world.get(i).copied().filter(|v| v.is_finite());
        let (ls, rs, lh, rh) = (w(LEFT_SHOULDER)?, w(RIGHT_SHOULDER)?, w(LEFT_HIP)?, w(RIGHT_HIP)?);
        let normal = ((ls - rs) + (lh - rh)).cross((ls + rs) - (lh + rh));
        let length = normal.length();
        (length > 1e-6 && length.is_finite()).then(|| normal.z / length)
    }

    /// The same landmarks seen from the other side of the depth axis: every depth (image and world) negated and
    /// left and right swapped, so the 2-D positions stay where they are while the person turns to face the other
    /// way (front <-> back).
    pub fn mirrored_in_depth(&self) -> Self {
        let mut out = self.clone();
        for (l, r) in MIRROR_PAIRS {
            out.landmarks.swap(l, r);
            out.world.swap(l, r);
        }
        out.landmarks.iter_mut().for_each(|l| l.depth = -l.depth);
        out.world.iter_mut().for_each(|w| w.z = -w.z);
        out
    }

    /// Landmarks found in the left-right mirror image of a `width`-pixel-wide picture (pixel `x -> width - x`),
    /// read back as landmarks of the picture itself: positions, the frame and the regions mirrored, world x
    /// negated, left and right swapped (the mirror image's left arm is the picture's right arm); depths,
    /// visibility and presence unchanged. Twice is the identity (up to the rounding of `width - x`).
    pub fn mirrored_left_right(&self, width: f32) -> Self {
        let mut out = self.clone();
        for (l, r) in MIRROR_PAIRS {
            out.landmarks.swap(l, r);
            out.world.swap(l, r);
        }
        out.landmarks.iter_mut().for_each(|l| l.pixel.x = width - l.pixel.x);
        out.world.iter_mut().for_each(|w| w.x = -w.x);
        let mirror = |r: PoseRegion| PoseRegion { centre: Vec2::new(width - r.centre.x, r.centre.y), ..r };
        out.next_region = self.next_region.map(mirror);
        out.region =
            PoseRegion { centre: Vec2::new(width - self.region.centre.x, self.region.centre.y), ..self.region };
        out.frame_min.x = width - self.frame_max.x;
        out.frame_max.x = width - self.frame_min.x;
        out
    }

    /// Whether landmark `i` lies inside the photo's frame (shrunk by `margin` pixels).
    pub fn in_frame(&self, i: usize, margin: f32) -> bool {
        let p = self.landmarks[i].pixel;
        p.x >= self.frame_min.x + margin
            && p.y >= self.frame_min.y + margin
            && p.x <= self.frame_max.x - margin
            && p.y <= self.frame_max.y - margin
    }

    /// The landmarks in another pixel grid: `p' = scale * p + offset` (positions, depths, the frame and the
    /// regions). With a [`crate::pipeline::input::NormaliseTransform`]'s scale and offset this maps photo
    /// landmarks into the normalised source view.
    pub fn transformed(&self, scale: f32, offset: Vec2) -> Self {
        let map = |p: Vec2| p * scale + offset;
        let region = |r: PoseRegion| PoseRegion { centre: map(r.centre), side: r.side * scale };
        Self {
            landmarks: self
                .landmarks
                .iter()
                .map(|l| Landmark { pixel: map(l.pixel), depth: l.depth * scale, ..*l })
                .collect(),
            world: self.world.clone(),
            score: self.score,
            region: region(self.region),
            next_region: self.next_region.map(region),
            frame_min: map(self.frame_min),
            frame_max: map(self.frame_max),
        }
    }

    /// Landmark `i` in body-cube coordinates of a `resolution`² source view (see [`crate::geometry::camera`]:
    /// pixel centre `x = (col + 0.5) / (R/2) - 1`, `y = 1 - (row + 0.5) / (R/2)`): x, y from the pixel, z the
    /// depth relative to the hip centre (cube units, + toward the camera).
    pub fn cube(&self, i: usize, resolution: usize) -> Vec3 {
        let half = resolution as f32 * 0.5;
        let l = &self.landmarks[i];
        Vec3::new(l.pixel.x / half - 1.0, 1.0 - l.pixel.y / half, l.depth / half)
    }
}

/// The network's input for `region` of `rgb` (linear RGB): `[3, 256, 256]` sRGB in `[0, 1]`, black outside the
/// image, box-filtered when the region is larger than the input (so a large photo is not aliased).
pub fn network_input(rgb: &RgbImage, region: PoseRegion) -> Vec<f32> {
    use rayon::prelude::*;
    let s = INPUT_SIZE;
    let scale = region.scale();
    let taps = (scale.ceil() as usize).clamp(1, 4);
    // The region is an axis-aligned square, so a tap's photo x depends on its column only and its y on its row
    // only: each bilinear cell is worked out once (`sample_bilinear` per tap gives the same bits;
    // `tests::network_input_is_the_box_filter_of_bilinear_samples`).
    let tap = |k: usize| (k / taps) as f32 + ((k % taps) as f32 + 0.5) / taps as f32;
    let photo = |q: Vec2| region.to_photo(q);
    let xs: Vec<Option<(i64, f32)>> = (0..s * taps).map(|k| bilinear_cell(photo(Vec2::new(tap(k), 0.0)).x)).collect();
    let ys: Vec<Option<(i64, f32)>> = (0..s * taps).map(|k| bilinear_cell(photo(Vec2::new(0.0, tap(k))).y)).collect();
    // Rows in parallel (each pixel on its own: the same values in any order), as RGB triples, then planar.
    let mut rgb_rows = vec![[0.0f32; 3]; s * s];
    rgb_rows.par_chunks_mut(s).enumerate().for_each(|(r, row)| {
        for (c, out) in row.iter_mut().enumerate() {
            let mut acc = Vec3::ZERO;
            for y in &ys[r * taps..(r + 1) * taps] {
                for x in &xs[c * taps..(c + 1) * taps] {
                    acc += match (x, y) {
                        (Some(x), Some(y)) => sample_bilinear_cell(rgb, *x, *y, Vec3::ZERO),
                        _ => Vec3::ZERO,
                    };
                }
            }
            let v = acc / (taps * taps) as f32;
            for ch in 0..3 {
                out[ch] = network_value(v[ch]);
            }
        }
    });
    let mut out = vec![0.0f32; 3 * s * s];
    for (k, v) in rgb_rows.iter().enumerate() {
        for ch in 0..3 {
            out[ch * s * s + k] = v[ch];
        }
    }
    out
}

/// Smallest width of a straight bottom edge of the mask that [`cut_frame`] takes for a cut, as a fraction of the
/// mask's height: the two thighs of a photo cut at mid-thigh span about 0.2 of it, the shoes of a standing person
/// well under 0.1.
pub const CUT_EDGE_WIDTH: f32 = 0.15;

/// The photo's `frame` with its bottom edge raised to the mask's bottom row when that row is a straight cut: at
/// least [`CUT_EDGE_WIDTH`] of the mask's height wide and at least 0.8 of the row two above it (a person's own
/// outline rounds off toward the bottom; a person cropped out of a larger picture, or standing behind a table, ends
/// in a straight line). Below such an edge the body continues, out of sight, exactly as below a photo's own edge.
/// `frame` unchanged otherwise (and for an empty mask).
pub fn cut_frame(mask: &GrayImage, frame: PhotoFrame) -> PhotoFrame {
    let count = |r: usize| mask.rows().nth(r).map_or(0, |row| row.iter().filter(|&&m| m >= 0.5).count());
    let rows: Vec<usize> = (0..mask.height).filter(|&r| count(r) > 0).collect();
    let (Some(&top), Some(&bottom)) = (rows.first(), rows.last()) else { return frame };
    let height = (bottom + 1 - top) as f32;
    let edge = count(bottom) as f32;
    let above = if bottom >= top + 2 { count(bottom - 2) as f32 } else { f32::INFINITY };
    let straight = edge >= CUT_EDGE_WIDTH * height && edge >= 0.8 * above;
    let edge_y = (bottom + 1) as f32;
    if straight && edge_y < frame.1.y {
        (frame.0, Vec2::new(frame.1.x, edge_y))
    } else {
        frame
    }
}

/// Whether the person's mask touches the bottom edge of the photo's `frame` (the photo cuts the body there).
pub fn cut_at_bottom(mask: &GrayImage, frame: PhotoFrame) -> bool {
    let row = (frame.1.y.floor() as i64 - 1).clamp(0, mask.height as i64 - 1) as usize;
    mask.height > 0 && mask.rows().nth(row).is_some_and(|r| r.iter().filter(|&&m| m >= 0.5).count() >= 2)
}

/// The pose model: `explicit`, else `R2HUMAN_POSE_MODEL`, else `.tools/models/pose_landmark_full.onnx` in the
/// project (installed by `scripts/setup.d/live.sh`).
pub fn model_path(explicit: Option<&Path>) -> Result<PathBuf, BodyError> {
    super::installed_model(explicit, "R2HUMAN_POSE_MODEL", MODEL_FILE, "pose model", ", or use --geometry inflate")
}

/// The MediaPipe pose landmark network in an ONNX Runtime session.
pub struct PoseEstimator {
    session: Session,
    path: PathBuf,
    /// The network's last outputs by the photo and region of their input ([`RUN_CACHE`] entries, newest last): the
    /// body prior reads one photo up to three times (uncut and cut frames, each with its region refinements), and
    /// those reads share network inputs. The input tensor is a function of the photo's pixels and the region only
    /// ([`network_input`]), so a hit returns what the same input gave and caching changes no result; it also skips
    /// building the input again (about 7 ms at 512², a box filter of up to 16 bilinear taps per input pixel).
    runs: Vec<CachedRun>,
    /// Session runs so far (cache hits not counted).
    network_runs: u64,
}

/// One network run: what its input was made of and its raw outputs (landmarks, score, world landmarks).
struct CachedRun {
    key: RunKey,
    raw: Vec<f32>,
    score: f32,
    world: Vec<f32>,
}

/// What a network input is made of: the photo ([`PhotoFingerprint`]) and the region's exact bits.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
struct RunKey {
    photo: PhotoFingerprint,
    region: [u32; 3],
}

/// A photo's size and a 64-bit hash of its pixels' bits: two photos with the same fingerprint give the same
/// network input for any region (a chance collision between the few photos one cache sees, 2^-64 per pair, is
/// the only way for them not to).
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
struct PhotoFingerprint {
    width: usize,
    height: usize,
    hash: u64,
}

impl PhotoFingerprint {
    /// The fingerprint of `rgb` (about 1 ms at 512²).
    fn of(rgb: &RgbImage) -> Self {
        use std::hash::Hasher;
        let mut hasher = std::collections::hash_map::DefaultHasher::new();
        let mut bytes = Vec::with_capacity(12 * 1024);
        for chunk in rgb.data.chunks(1024) {
            bytes.clear();
            for v in chunk {
                for x in v.to_array() {
                    bytes.extend_from_slice(&x.to_bits().to_le_bytes());
                }
            }
            hasher.write(&bytes);
        }
        Self { width: rgb.width, height: rgb.height, hash: hasher.finish() }
    }
}

/// How many runs [`PoseEstimator`] keeps (one photo's reads need at most eight; each entry holds a 256² input).
const RUN_CACHE: usize = 8;

impl PoseEstimator {
    /// Loads the model (see [`model_path`]) on the execution provider of `options`.
    pub fn load(model: Option<&Path>, options: &RuntimeOptions) -> Result<Self, BodyError> {
        let path = model_path(model)?;
        let (session, _) =
            crate::neural::create_session(&path, "pose landmark model", options).map_err(BodyError::ModelLoad)?;
        let outputs: Vec<String> = session.outputs().iter().map(|o| o.name().to_string()).collect();
        for needed in ["Identity", "Identity_1", "Identity_4"] {
            if !outputs.iter().any(|o| o == needed) {
                return Err(BodyError::Model(format!(
                    "`{}` is not the MediaPipe pose landmark model (no output `{needed}`; outputs {outputs:?}); \
                     reinstall it with `bash scripts/setup.d/live.sh`",
                    path.display()
                )));
            }
        }
        Ok(Self { session, path, runs: Vec::new(), network_runs: 0 })
    }

    /// The model file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// How many times the network has run (a read whose input it has seen among the last few is answered from
    /// them and does not count).
    pub fn network_runs(&self) -> u64 {
        self.network_runs
    }

    /// Forgets the cached runs: the next reads run the network (a caller that times one photo's read calls this
    /// first, so a photo read before does not make it look free; [`crate::body::prior::BodyEstimator::estimate`]
    /// does).
    pub fn forget_runs(&mut self) {
        self.runs.clear();
    }

    /// Runs the network once on `region` of `rgb` (linear RGB; the photo lies in `frame` of it; `photo` its
    /// fingerprint, worked out once for all of a read's runs); `None` when it finds no pose there.
    fn run(
        &mut self,
        rgb: &RgbImage,
        photo: PhotoFingerprint,
        region: PoseRegion,
        frame: PhotoFrame,
    ) -> Result<Option<PoseLandmarks>, BodyError> {
        let key =
            RunKey { photo, region: [region.centre.x.to_bits(), region.centre.y.to_bits(), region.side.to_bits()] };
        let cached = self.runs.iter().position(|r| r.key == key);
        let (raw, score, world) = match cached {
            Some(i) => {
                let hit = self.runs.remove(i);
                let out = (hit.raw.clone(), hit.score, hit.world.clone());
                self.runs.push(hit);
                out
            }
            None => {
                let (raw, score, world) = self.run_network(&network_input(rgb, region))?;
                self.network_runs += 1;
                if self.runs.len() == RUN_CACHE {
                    self.runs.remove(0);
                }
                self.runs.push(CachedRun { key, raw: raw.clone(), score, world: world.clone() });
                (raw, score, world)
            }
        };
        let seen = if cached.is_some() { " (cached)" } else { "" };
        tracing::debug!("pose network: score {score:.3} in region {region:?}{seen}");
        if score.is_nan() || score < MIN_POSE_SCORE {
            return Ok(None);
        }
        Ok(PoseLandmarks::decode(&raw, &world, score, region, frame))
    }

    /// One session run on a network input: raw landmarks, pose score and world landmarks.
    fn run_network(&mut self, input: &[f32]) -> Result<(Vec<f32>, f32, Vec<f32>), BodyError> {
        let shape = (1, 3, INPUT_SIZE, INPUT_SIZE);
        let outputs = ["Identity", "Identity_1", "Identity_4"];
        let mut out = super::run_image_network(&mut self.session, &self.path, shape, input, &outputs)?.into_iter();
        let (raw, score, world) = (out.next(), out.next(), out.next());
        let score = score.and_then(|s| s.first().copied()).unwrap_or(0.0);
        Ok((raw.unwrap_or_default(), score, world.unwrap_or_default()))
    }

    /// One run of the network on `region` of `rgb` (linear RGB; the photo lies in `frame` of it, the whole image
    /// when `None`), as [`PoseEstimator::estimate`] makes each of its runs; `None` when it finds no pose there. A
    /// caller that knows the region the same person's last read came from, in a frame that follows the person,
    /// reads again there in one run instead of `estimate`'s two or more.
    pub fn read_in(
        &mut self,
        rgb: &RgbImage,
        region: PoseRegion,
        frame: Option<PhotoFrame>,
    ) -> Result<Option<PoseLandmarks>, BodyError> {
        let frame = frame.unwrap_or((Vec2::ZERO, Vec2::new(rgb.width as f32, rgb.height as f32)));
        self.run(rgb, PhotoFingerprint::of(rgb), region, frame)
    }

    /// One run of the network, as MediaPipe tracks a person across video frames: on `region` (the previous frame's
    /// [`PoseLandmarks::next_region`]) when given and still holding most of the mask's box, else on the mask's
    /// region. `None` when the mask is empty or no pose is found. The person model reads the torso's orientation
    /// this way on every frame (one run instead of [`PoseEstimator::estimate`]'s two or more).
    pub fn track(
        &mut self,
        rgb: &RgbImage,
        mask: &GrayImage,
        region: Option<PoseRegion>,
    ) -> Result<Option<PoseLandmarks>, BodyError> {
        same_size(rgb, mask)?;
        let Some(from_mask) = PoseRegion::from_mask(mask) else { return Ok(None) };
        // The tracked region holds the person while the mask's box centre lies inside it and it is not much smaller
        // than the box.
        let holds = |r: &PoseRegion| {
            let d = (r.centre - from_mask.centre).abs();
            d.max_element() < 0.25 * r.side && r.side > 0.6 * from_mask.side && r.side < 2.5 * from_mask.side
        };
        self.read_in(rgb, region.filter(holds).unwrap_or(from_mask), None)
    }

    /// Landmarks of the person in `rgb` (linear RGB) whose mask is `mask` (same size, `[0, 1]`; the photo lies in
    /// `frame` of the image, the whole image when `None`): one run on the mask's region, then one on the region
    /// that run gives ([`PoseLandmarks::refined_region`]). `None` when the mask is empty or no pose is found.
    pub fn estimate(
        &mut self,
        rgb: &RgbImage,
        mask: &GrayImage,
        frame: Option<PhotoFrame>,
    ) -> Result<Option<PoseLandmarks>, BodyError> {
        same_size(rgb, mask)?;
        self.estimate_on(rgb, PhotoFingerprint::of(rgb), mask, frame)
    }

    /// [`PoseEstimator::estimate`] of the photo whose fingerprint is `photo` (sizes checked by the caller).
    fn estimate_on(
        &mut self,
        rgb: &RgbImage,
        photo: PhotoFingerprint,
        mask: &GrayImage,
        frame: Option<PhotoFrame>,
    ) -> Result<Option<PoseLandmarks>, BodyError> {
        let frame = frame.unwrap_or((Vec2::ZERO, Vec2::new(rgb.width as f32, rgb.height as f32)));
        let Some(region) = PoseRegion::from_mask(mask) else { return Ok(None) };
        let cut = cut_at_bottom(mask, frame);
        // A photo that cuts the person may show too little of the body for the network to find it in the mask's
        // region: look again in regions two and three times as large that extend below the photo (the body
        // continues there), keeping the top of the person at the same place.
        let grown = |grow: f32| {
            let top = region.centre.y - 0.5 * region.side;
            let side = region.side * grow;
            PoseRegion { centre: Vec2::new(region.centre.x, top + 0.5 * side), side }
        };
        let mut first = self.run(rgb, photo, region, frame)?;
        for grow in [2.0f32, 3.0] {
            if first.is_some() || !cut {
                break;
            }
            first = self.run(rgb, photo, grown(grow), frame)?;
        }
        let Some(first) = first else { return Ok(None) };
        let found = self.refine(rgb, photo, first, cut, frame)?;
        // A photo cut at the bottom cannot show the feet well above its bottom edge: the network folded a small
        // whole body into the visible part (legs over the coat). Look again in the larger regions, where the
        // hidden part of the body falls outside the photo, and keep the first answer that is not folded.
        if cut && found.legs_above_cut(FOLD_MARGIN) {
            for grow in [2.0f32, 3.0] {
                if let Some(again) = self.run(rgb, photo, grown(grow), frame)? {
                    let again = self.refine(rgb, photo, again, cut, frame)?;
                    if !again.legs_above_cut(FOLD_MARGIN) {
                        tracing::debug!("pose: folded body in the mask's region; region grown x{grow} instead");
                        return Ok(Some(again));
                    }
                }
            }
        }
        Ok(Some(found))
    }

    /// One more run on the region `first` gives ([`PoseLandmarks::refined_region`]); `first` when that finds
    /// nothing.
    fn refine(
        &mut self,
        rgb: &RgbImage,
        photo: PhotoFingerprint,
        first: PoseLandmarks,
        cut: bool,
        frame: PhotoFrame,
    ) -> Result<PoseLandmarks, BodyError> {
        Ok(match first.refined_region(cut) {
            Some(next) => self.run(rgb, photo, next, frame)?.unwrap_or(first),
            None => first,
        })
    }
}

/// An error unless `rgb` and `mask` have the same size (the reads take the mask's pixels as the photo's).
fn same_size(rgb: &RgbImage, mask: &GrayImage) -> Result<(), BodyError> {
    if (rgb.width, rgb.height) != (mask.width, mask.height) {
        return Err(BodyError::Model(format!(
            "image is {}x{} but mask is {}x{}",
            rgb.width, rgb.height, mask.width, mask.height
        )));
    }
    Ok(())
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::buffer::Image;

    #[test]
    fn region_from_mask_is_a_square_around_the_box() {
        let mask =
            Image::from_fn(100, 80, |c, r| if (20..40).contains(&c) && (10..70).contains(&r) { 1.0 } else { 0.0 });
        let r = PoseRegion::from_mask(&mask).unwrap();
        assert_eq!(r.centre, Vec2::new(30.0, 40.0));
        assert!((r.side - 1.25 * 60.0).abs() < 1e-5);
        assert!(PoseRegion::from_mask(&Image::new(4, 4, 0.2)).is_none());
        // Input pixel centre 128 maps to the region centre; the edges to +-side/2.
        assert!((r.to_photo(Vec2::splat(128.0)) - r.centre).length() < 1e-5);
        assert!((r.to_photo(Vec2::ZERO) - (r.centre - Vec2::splat(r.side / 2.0))).length() < 1e-4);
        let aux = PoseRegion::from_auxiliary(Vec2::new(10.0, 10.0), Vec2::new(10.0, 30.0)).unwrap();
        assert_eq!(aux.centre, Vec2::new(10.0, 10.0));
        assert!((aux.side - 60.0).abs() < 1e-5);
        assert!(PoseRegion::from_auxiliary(Vec2::ONE, Vec2::ONE).is_none());
        assert!(PoseRegion::from_auxiliary(Vec2::NAN, Vec2::ONE).is_none());
    }

    #[test]
    fn decode_maps_network_units_to_photo_pixels() {
        let region = PoseRegion { centre: Vec2::new(200.0, 300.0), side: 512.0 };
        let mut raw = vec![0.0f32; 39 * 5];
        let mut world = vec![0.0f32; 39 * 3];
        // Landmark 0 at input (64, 192), z = -10 (nearer), visibility logit 0 -> 0.5, presence logit 2.
        raw[..5].copy_from_slice(&[64.0, 192.0, -10.0, 0.0, 2.0]);
        world[..3].copy_from_slice(&[0.1, -0.5, -0.2]);
        // Auxiliary points 33 (centre) and 34 (scale).
        raw[33 * 5..33 * 5 + 2].copy_from_slice(&[128.0, 128.0]);
        raw[34 * 5..34 * 5 + 2].copy_from_slice(&[128.0, 64.0]);
        raw[5] = f32::NAN;
        let frame = (Vec2::ZERO, Vec2::new(400.0, 600.0));
        let p = PoseLandmarks::decode(&raw, &world, 0.9, region, frame).unwrap();
        let l = p.landmarks[0];
        // Scale 2 photo pixels per input pixel.
        assert!((l.pixel - Vec2::new(200.0 - 128.0, 300.0 + 128.0)).length() < 1e-4);
        assert!((l.depth - 20.0).abs() < 1e-5, "nearer the camera is +z");
        assert!((l.visibility - 0.5).abs() < 1e-6);
        assert!((l.presence - 1.0 / (1.0 + (-2.0f32).exp())).abs() < 1e-6);
        assert_eq!(p.world[0], Vec3::new(0.1, 0.5, 0.2));
        // A NaN landmark is invisible, at the region centre.
        assert_eq!(p.landmarks[1].visibility, 0.0);
        assert_eq!(p.landmarks[1].pixel, region.centre);
        let next = p.next_region.unwrap();
        assert_eq!(next.centre, Vec2::new(200.0, 300.0));
        assert!((next.side - 1.5 * 2.0 * 128.0).abs() < 1e-3);
        assert!(p.in_frame(0, 0.0));
        assert!(PoseLandmarks::decode(&raw[..10], &world, 0.9, region, frame).is_none());
        // Into a source view at half scale, offset (10, 20); cube coordinates of a 512 view.
        let s = p.transformed(0.5, Vec2::new(10.0, 20.0));
        assert!((s.landmarks[0].pixel - Vec2::new(46.0, 234.0)).length() < 1e-4);
        assert!((s.landmarks[0].depth - 10.0).abs() < 1e-5);
        assert_eq!(s.frame_max, Vec2::new(210.0, 320.0));
        let c = s.cube(0, 512);
        assert!((c - Vec3::new(46.0 / 256.0 - 1.0, 1.0 - 234.0 / 256.0, 10.0 / 256.0)).length() < 1e-6);
        assert!(s.in_frame(0, 0.0) && !s.in_frame(0, 40.0));
        assert_eq!(s.next_region.unwrap().centre, Vec2::new(110.0, 170.0));
        // A mask touching the frame's bottom row is cut there; one ending above it is not.
        let mask = Image::from_fn(8, 8, |_, r| if r < 6 { 1.0 } else { 0.0 });
        assert!(cut_at_bottom(&mask, (Vec2::ZERO, Vec2::new(8.0, 6.0))));
        assert!(!cut_at_bottom(&mask, (Vec2::ZERO, Vec2::new(8.0, 8.0))));
    }

    /// Landmarks of a torso (shoulders at y 0.5, hips at 0, half width 0.2 and 0.1, metres) turned by `yaw`
    /// radians about the vertical (0: facing the camera, +z), every other landmark at the hip centre; pixels and
    /// image depths follow the world x and z (100 pixels per metre).
    pub(crate) fn torso(yaw: f32) -> PoseLandmarks {
        let turn = glam::Quat::from_rotation_y(yaw);
        let mut world = vec![Vec3::ZERO; LANDMARK_COUNT];
        world[index::LEFT_SHOULDER] = turn * Vec3::new(0.2, 0.5, 0.0);
        world[index::RIGHT_SHOULDER] = turn * Vec3::new(-0.2, 0.5, 0.0);
        world[index::LEFT_HIP] = turn * Vec3::new(0.1, 0.0, 0.0);
        world[index::RIGHT_HIP] = turn * Vec3::new(-0.1, 0.0, 0.0);
        world[index::NOSE] = turn * Vec3::new(0.0, 0.7, 0.1);
        let landmarks = world
            .iter()
            .enumerate()
            .map(|(i, w)| Landmark {
                pixel: Vec2::new(256.0 + 100.0 * w.x, 256.0 - 100.0 * w.y),
                depth: 100.0 * w.z,
                visibility: i as f32 / LANDMARK_COUNT as f32,
                presence: 1.0,
            })
            .collect();
        let region = PoseRegion { centre: Vec2::splat(256.0), side: 512.0 };
        PoseLandmarks {
            landmarks,
            world,
            score: 1.0,
            region,
            next_region: None,
            frame_min: Vec2::ZERO,
            frame_max: Vec2::splat(512.0),
        }
    }

    #[test]
    fn facing_and_mirroring_in_depth() {
        // The torso's normal toward the camera is cos(yaw): 1 facing it, -1 facing away, 0 in profile.
        for (yaw, expected) in
            [(0.0f32, 1.0f32), (std::f32::consts::PI, -1.0), (1.0, 1.0f32.cos()), (2.5, 2.5f32.cos())]
        {
            let f = torso(yaw).facing().unwrap();
            assert!((f - expected).abs() < 1e-5, "yaw {yaw}: {f} vs {expected}");
        }
        assert!(torso(std::f32::consts::FRAC_PI_2).facing().unwrap().abs() < 1e-5);
        // Mirrored in depth, a torso turned by yaw faces as one turned by pi - yaw, with the same 2-D positions
        // under the other side's names and negated depths; twice is the identity.
        let back = torso(2.5);
        let m = back.mirrored_in_depth();
        assert!((m.facing().unwrap() - (std::f32::consts::PI - 2.5).cos()).abs() < 1e-5);
        let (l, r) = (index::LEFT_SHOULDER, index::RIGHT_SHOULDER);
        assert_eq!(m.landmarks[l].pixel, back.landmarks[r].pixel);
        assert_eq!(m.landmarks[l].visibility, back.landmarks[r].visibility);
        assert_eq!(m.landmarks[l].depth, -back.landmarks[r].depth);
        assert_eq!(m.world[l], back.world[r] * Vec3::new(1.0, 1.0, -1.0));
        assert_eq!(m.landmarks[index::NOSE].pixel, back.landmarks[index::NOSE].pixel);
        assert_eq!(m.mirrored_in_depth(), back);
        // Not finite or degenerate: no facing.
        let mut bad = torso(0.0);
        bad.world[index::LEFT_HIP].x = f32::NAN;
        assert_eq!(bad.facing(), None);
        let mut flat = torso(0.0);
        flat.world.iter_mut().for_each(|w| *w = Vec3::ZERO);
        assert_eq!(flat.facing(), None);
    }

    #[test]
    fn mirroring_left_right_reads_a_mirror_image_back() {
        // The mirror image of a torso turned by yaw is a torso turned by -yaw: its landmarks, brought back, are the
        // torso's own (positions, depths, world points), each side's visibility moving with its name; twice is the
        // identity; the frame and the regions are mirrored about the picture's width.
        for yaw in [0.0f32, 1.0, -0.4, 2.5] {
            let (wanted, seen) = (torso(yaw), torso(-yaw));
            let back = seen.mirrored_left_right(512.0);
            for i in 0..LANDMARK_COUNT {
                let (a, b) = (back.landmarks[i], wanted.landmarks[i]);
                assert!(a.pixel.distance(b.pixel) < 1e-3 && (a.depth - b.depth).abs() < 1e-3, "yaw {yaw}, {i}");
                assert!(back.world[i].distance(wanted.world[i]) < 1e-6, "yaw {yaw}, {i}");
            }
            let (l, r) = (index::LEFT_SHOULDER, index::RIGHT_SHOULDER);
            assert_eq!(back.landmarks[l].visibility, seen.landmarks[r].visibility);
            assert!((back.facing().unwrap() - wanted.facing().unwrap()).abs() < 1e-5);
            let twice = back.mirrored_left_right(512.0);
            assert_eq!(twice.world, seen.world);
            for (a, b) in twice.landmarks.iter().zip(&seen.landmarks) {
                assert!(a.pixel.distance(b.pixel) < 1e-3 && a.depth == b.depth && a.visibility == b.visibility);
            }
        }
        let mut l = torso(0.0);
        l.frame_min = Vec2::new(10.0, 20.0);
        l.frame_max = Vec2::new(300.0, 400.0);
        l.next_region = Some(PoseRegion { centre: Vec2::new(100.0, 50.0), side: 30.0 });
        let m = l.mirrored_left_right(512.0);
        assert_eq!((m.frame_min, m.frame_max), (Vec2::new(212.0, 20.0), Vec2::new(502.0, 400.0)));
        assert_eq!(m.next_region, Some(PoseRegion { centre: Vec2::new(412.0, 50.0), side: 30.0 }));
        assert_eq!(m.region.centre, Vec2::splat(256.0));
    }

    #[test]
    fn a_straight_bottom_edge_of_the_mask_is_a_cut() {
        let frame = (Vec2::ZERO, Vec2::new(40.0, 40.0));
        // A torso 20 rows high, cut straight 14 wide at row 29: the frame ends there.
        let torso =
            Image::from_fn(40, 40, |c, r| if (10..30).contains(&r) && (13..27).contains(&c) { 1.0 } else { 0.0 });
        assert_eq!(cut_frame(&torso, frame), (Vec2::ZERO, Vec2::new(40.0, 30.0)));
        // Two narrow feet at the bottom of a tall body: not a cut.
        let standing = Image::from_fn(40, 40, |c, r| {
            let body = (2..34).contains(&r) && (17..23).contains(&c);
            let feet = (34..37).contains(&r) && (c == 15 || c == 24);
            if body || feet {
                1.0
            } else {
                0.0
            }
        });
        assert_eq!(cut_frame(&standing, frame), frame);
        // A rounded bottom (a disc): not a cut.
        let disc = Image::from_fn(40, 40, |c, r| {
            let (x, y) = (c as f32 - 20.0, r as f32 - 20.0);
            if x * x + y * y <= 100.0 {
                1.0
            } else {
                0.0
            }
        });
        assert_eq!(cut_frame(&disc, frame), frame);
        // The frame's own edge below the mask stays when the mask reaches it; an empty mask changes nothing.
        let touching = Image::from_fn(40, 40, |c, r| if r >= 10 && (13..27).contains(&c) { 1.0 } else { 0.0 });
        assert_eq!(cut_frame(&touching, frame), frame);
        assert_eq!(cut_frame(&Image::new(40, 40, 0.0), frame), frame);
    }

    #[test]
    fn feet_well_above_a_cut_edge_mean_a_folded_body() {
        let region = PoseRegion { centre: Vec2::splat(50.0), side: 100.0 };
        let frame = (Vec2::ZERO, Vec2::new(100.0, 100.0));
        let raw = vec![0.0f32; 39 * 5];
        let mut p = PoseLandmarks::decode(&raw, &[0.0; 39 * 3], 0.9, region, frame).unwrap();
        let put = |p: &mut PoseLandmarks, y: f32, visibility: f32| {
            for l in &mut p.landmarks[index::LEFT_ANKLE..] {
                *l = Landmark { pixel: Vec2::new(50.0, y), depth: 0.0, visibility, presence: 1.0 };
            }
        };
        // Feet 20 % above the bottom edge: folded, seen or not (a folded body often has them hidden behind the
        // visible part: an upper-body crop with the whole tiny body inside the head). 5 %: a full body standing on
        // the edge. Below the edge: nothing to say.
        put(&mut p, 80.0, 0.9);
        assert!(p.legs_above_cut(FOLD_MARGIN));
        put(&mut p, 95.0, 0.9);
        assert!(!p.legs_above_cut(FOLD_MARGIN));
        put(&mut p, 130.0, 0.9);
        assert!(!p.legs_above_cut(FOLD_MARGIN));
        put(&mut p, 80.0, 0.2);
        assert!(p.legs_above_cut(FOLD_MARGIN));
        put(&mut p, 130.0, 0.2);
        assert!(!p.legs_above_cut(FOLD_MARGIN));
    }

    #[test]
    fn network_input_is_srgb_and_black_outside() {
        let rgb = Image::new(64, 64, Vec3::new(0.214, 0.0, 1.0)); // linear 0.214 ~ sRGB 0.5
        let region = PoseRegion { centre: Vec2::new(32.0, 32.0), side: 128.0 };
        let x = network_input(&rgb, region);
        let s = INPUT_SIZE;
        let at = |ch: usize, r: usize, c: usize| x[ch * s * s + r * s + c];
        assert!((at(0, 128, 128) - 0.5).abs() < 0.01);
        assert!((at(2, 128, 128) - 1.0).abs() < 1e-5);
        assert_eq!(at(0, 2, 2), 0.0, "outside the photo is black");
        assert!(x.iter().all(|v| v.is_finite() && (0.0..=1.0).contains(v)));
    }

    /// The network input, per pixel, from `sample_bilinear` at each tap: the definition `network_input` computes
    /// with its taps' cells worked out once per row and column.
    fn network_input_by_definition(rgb: &RgbImage, region: PoseRegion) -> Vec<f32> {
        let s = INPUT_SIZE;
        let taps = (region.scale().ceil() as usize).clamp(1, 4);
        let cells = crate::buffer::supersampled(rgb, s, taps, |q| region.to_photo(q));
        let mut out = vec![0.0f32; 3 * s * s];
        for (k, v) in cells.iter().enumerate() {
            for ch in 0..3 {
                out[ch * s * s + k] = network_value(v[ch]);
            }
        }
        out
    }

    #[test]
    fn network_input_is_the_box_filter_of_bilinear_samples() {
        let rgb = Image::from_fn(97, 61, |c, r| {
            let t = (c * 31 + r * 17) as f32;
            Vec3::new((t * 0.013).sin().abs(), (t * 0.007).cos().abs(), ((c ^ r) % 7) as f32 / 6.0)
        });
        let regions = [
            PoseRegion { centre: Vec2::new(48.5, 30.5), side: 61.0 }, // smaller than the input: one tap
            PoseRegion { centre: Vec2::new(40.3, 55.7), side: 700.9 }, // larger: 3 x 3 taps, mostly outside
            PoseRegion { centre: Vec2::new(-20.0, 10.0), side: 1500.0 }, // 4 x 4 taps, centre outside the photo
            PoseRegion { centre: Vec2::new(30.0, 30.0), side: f32::NAN }, // degenerate: black
        ];
        for region in regions {
            let fast = network_input(&rgb, region);
            let reference = network_input_by_definition(&rgb, region);
            let same = fast.iter().zip(&reference).all(|(a, b)| a.to_bits() == b.to_bits());
            assert!(same, "region {region:?}: not bit-identical to the definition");
        }
    }
}
