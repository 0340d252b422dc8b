//! A plausibility check that looks at rendered views the way a person would, for photos without ground truth:
//! the project's pose network reads every view, and what it reads is compared with what the yaw-0 view (the input
//! seen again) predicts for that yaw. Three checks per view:
//!
//! - **a person in the predicted pose** ([`ViewCheck::pose_error`]): the pose network ([`crate::body::pose`]) finds
//!   a person (presence score at least [`MIN_PERSON_SCORE`]) whose body landmarks (shoulders, elbows, wrists, hips,
//!   knees, ankles: those the yaw-0 view shows) lie on the rows where the yaw-0 view has them: an orbit about the
//!   vertical axis moves points sideways only. The sideways position is not compared: it needs the landmarks'
//!   depth, and the network's depth is too rough for that (on ground-truth renders of 12 synthetic people,
//!   predicting it put the landmarks off by more than a shoulder width at yaw 60–90 on several). The
//!   error is the RMS row distance in 3-D shoulder widths, with left and right read either way (the network often
//!   swaps them seen from behind); at most [`MAX_POSE_ERROR`];
//! - **a head as deep as a head** ([`ViewCheck::head_width`]): on the rows between the eyes and the mouth (an
//!   orbit about the vertical axis keeps every row where it is), the width of the silhouette's run through the
//!   head (through the nose the network finds in the view) over its width at yaw 0, median over the rows. A head
//!   seen from above is close to an ellipse `D/W` times as deep as it is wide; turned by `phi` from the camera at
//!   yaw 0, its width at yaw `y` over its width at yaw 0 is `sqrt(cos²(y-phi) + r² sin²(y-phi)) / sqrt(cos²(phi) +
//!   r² sin²(phi))`. [`head_band`] is that ratio's range over `r` in [`HEAD_DEPTH_RATIO`] and `phi` within
//!   ±[`HEAD_TURN`] degrees of the face's direction read from the yaw-0 view's landmarks ([`Reference::head_turn`];
//!   an ellipse is the same turned by 180°, so a face read as looking away costs nothing), widened by
//!   [`HEAD_TOLERANCE`]. A face squashed flat in profile reads under it, a head stretched into an egg front to
//!   back over it;
//! - **one face** ([`ViewCheck::back_likeness`]): in the view from behind (yaw [`BACK_YAW`]), the head from the
//!   forehead to the chin must not look like the face: a rotation by 180° about the vertical axis maps column `c`
//!   to `width - 1 - c`, so a face painted or modelled on the back of the head shows there as the yaw-0 face
//!   mirrored. The normalised cross-correlation of the luminance of the two (on the yaw-0 head's pixels, where
//!   both views cover) is at most [`MAX_BACK_LIKENESS`].
//!
//! The thresholds were set on ground-truth renders of synthetic people, and the test cases it must fail are made
//! from their meshes (`cargo test --release --lib eval::plausible`): the head squashed to half its depth, the head
//! replaced by an egg twice as deep as it is wide, and the face mirrored onto the back of the head.

use std::ops::Range;

use glam::{Vec2, Vec3};

use crate::body::pose::{index, PhotoFrame, PoseEstimator, PoseLandmarks};
use crate::body::BodyError;
use crate::buffer::{GrayImage, Image, RgbImage, RgbaImage};
use crate::geometry::camera::Camera;

/// The pose network's presence score from which a view counts as showing a person.
pub const MIN_PERSON_SCORE: f32 = 0.5;

/// The largest accepted RMS distance between the landmarks found in a view and those predicted from the yaw-0
/// view, in 3-D shoulder widths ([`ViewCheck::pose_error`]).
pub const MAX_POSE_ERROR: f32 = 1.2;

/// The range of a head's depth over its width (seen from above, at the rows between the eyes and the mouth) that
/// [`head_band`] allows.
pub const HEAD_DEPTH_RATIO: (f32, f32) = (0.9, 1.5);

/// How far (degrees) the head may be turned from the camera at yaw 0 in [`head_band`].
pub const HEAD_TURN: f32 = 35.0;

/// The relative slack around the head's modelled width range in [`head_band`] (silhouette rounding, hair, a hand
/// near the face).
pub const HEAD_TOLERANCE: f32 = 0.1;

/// The largest accepted likeness of the back of the head to the mirrored face ([`ViewCheck::back_likeness`]).
pub const MAX_BACK_LIKENESS: f32 = 0.65;

/// The yaw (degrees) of the view from behind, where the back of the head is compared with the face.
pub const BACK_YAW: f32 = 180.0;

/// The landmarks whose positions are compared: shoulders, elbows, wrists, hips, knees, ankles.
const BODY_POINTS: [usize; 12] = [
    index::LEFT_SHOULDER,
    index::RIGHT_SHOULDER,
    index::LEFT_ELBOW,
    index::RIGHT_ELBOW,
    index::LEFT_WRIST,
    index::RIGHT_WRIST,
    index::LEFT_HIP,
    index::RIGHT_HIP,
    index::LEFT_KNEE,
    index::RIGHT_KNEE,
    index::LEFT_ANKLE,
    index::RIGHT_ANKLE,
];

/// MediaPipe's eye centres.
const EYES: [usize; 2] = [2, 5];
/// MediaPipe's mouth corners.
const MOUTH: [usize; 2] = [9, 10];

/// The visibility from which a landmark of the yaw-0 view is used.
const MIN_VISIBILITY: f32 = 0.5;

/// The variance floor (linear luminance squared) of [`ncc`]: a featureless patch correlates with nothing.
const LIKENESS_FLOOR: f32 = 1e-4;

/// The fewest pixel pairs the back of the head is compared on.
const MIN_LIKENESS_PIXELS: usize = 20;

/// What the yaw-0 view tells about the person: the pose network's read and where the head is.
#[derive(Clone, Debug)]
pub struct Reference {
    /// The pose network's read of the yaw-0 view.
    pub read: PoseLandmarks,
    /// The view's side in pixels (views are square).
    pub size: usize,
    /// The head's rows and frontal width; `None` when the eyes, mouth or nose were not found or no silhouette
    /// runs through the nose.
    pub head: Option<HeadRows>,
    /// Which way the face points at yaw 0 (degrees from the camera toward +x, the yaw at which a camera faces it),
    /// from the network's image landmarks ([`face_direction`]); `None` when those are degenerate.
    pub head_turn: Option<f32>,
    /// Where the photo lies in the views (`None`: the whole view), given to the pose network so that a photo cut
    /// at the bottom (a portrait) is read as one ([`crate::body::pose::cut_at_bottom`]).
    pub frame: Option<PhotoFrame>,
    /// The yaw-0 view itself (premultiplied linear RGBA).
    front: RgbaImage,
}

/// The head in the yaw-0 view.
#[derive(Clone, Debug, PartialEq)]
pub struct HeadRows {
    /// The rows from the eyes to the mouth.
    pub face: Range<usize>,
    /// The rows from the forehead to the chin (the face rows widened by their own height above and half of it
    /// below).
    pub likeness: Range<usize>,
    /// The median width (pixels) of the silhouette's run through the nose over [`HeadRows::face`].
    pub width: f32,
    /// The nose's column.
    pub nose_x: f32,
}

/// What the check measured in one view.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewCheck {
    /// The view's yaw (degrees).
    pub yaw: f32,
    /// The pose network's presence score (0 when it found nobody).
    pub person: f32,
    /// RMS distance of the body landmarks from their rows in the yaw-0 view, in 3-D shoulder widths (left and
    /// right read either way); `None` without a read of the view or with fewer than three landmarks to compare.
    pub pose_error: Option<f32>,
    /// The face's direction at yaw 0 (degrees) the head band is centred on: the average over the views in
    /// [`check`], [`Reference::head_turn`] in [`check_view`].
    pub head_turn: Option<f32>,
    /// The head's width over its width at yaw 0; `None` when it could not be measured.
    pub head_width: Option<f32>,
    /// The likeness of the back of the head to the mirrored face (yaw [`BACK_YAW`] only; `None` elsewhere or when
    /// too few pixels compare).
    pub back_likeness: Option<f32>,
}

impl ViewCheck {
    /// Why this view fails, one phrase per failure (empty: it passes). An unmeasured head or pose is not a
    /// failure by itself: a view without a person already fails.
    pub fn failures(&self) -> Vec<String> {
        let mut out = Vec::new();
        let yaw = self.yaw;
        if self.person.is_nan() || self.person < MIN_PERSON_SCORE {
            out.push(format!("no person at yaw {yaw} (score {:.2})", self.person));
        }
        if let Some(e) = self.pose_error.filter(|e| e.is_nan() || *e > MAX_POSE_ERROR) {
            out.push(format!("pose off at yaw {yaw} ({e:.2} shoulder widths)"));
        }
        if let Some(w) = self.head_width {
            let (lo, hi) = head_band(yaw, self.head_turn.unwrap_or(0.0));
            if w < lo || !w.is_finite() {
                out.push(format!("head squashed at yaw {yaw} (width {w:.2} of frontal, under {lo:.2})"));
            } else if w > hi {
                out.push(format!("head stretched at yaw {yaw} (width {w:.2} of frontal, over {hi:.2})"));
            }
        }
        if let Some(l) = self.back_likeness.filter(|l| l.is_nan() || *l > MAX_BACK_LIKENESS) {
            out.push(format!("a face on the back of the head (likeness {l:.2})"));
        }
        out
    }

    /// True when nothing fails.
    pub fn passes(&self) -> bool {
        self.failures().is_empty()
    }
}

/// What the check saw in one method's views of one photo.
#[derive(Clone, Debug, PartialEq)]
pub struct Plausibility {
    /// Whether the pose network found a person in the yaw-0 view (without one nothing can be predicted).
    pub reference: bool,
    /// Every view's measurements.
    pub views: Vec<ViewCheck>,
}

impl Plausibility {
    /// Why the views fail, one phrase per failure (empty: they pass).
    pub fn failures(&self) -> Vec<String> {
        let mut out = Vec::new();
        if !self.reference {
            out.push("no person at yaw 0 to predict the views from".to_string());
        }
        out.extend(self.views.iter().flat_map(ViewCheck::failures));
        out
    }

    /// True when nothing fails.
    pub fn passes(&self) -> bool {
        self.failures().is_empty()
    }

    /// How many views pass, of how many.
    pub fn passing_views(&self) -> (usize, usize) {
        (self.views.iter().filter(|v| v.passes()).count(), self.views.len())
    }
}

/// The width of a head `r` times as deep as it is wide, turned `phi` degrees from the camera at yaw 0, seen at
/// `yaw` (degrees), over its width at yaw 0 (orthographic views of an ellipse).
pub fn modelled_head_width(r: f32, phi: f32, yaw: f32) -> f32 {
    let width = |a: f32| {
        let (s, c) = a.to_radians().sin_cos();
        (c * c + r * r * s * s).sqrt()
    };
    width(yaw - phi) / width(-phi)
}

/// The accepted range of [`ViewCheck::head_width`] at `yaw` (degrees): the range of [`modelled_head_width`] over
/// depth ratios in [`HEAD_DEPTH_RATIO`] and turns within ±[`HEAD_TURN`], the lower end divided and the upper end
/// multiplied by `1 +` [`HEAD_TOLERANCE`].
pub fn head_band(yaw: f32, turn: f32) -> (f32, f32) {
    const STEPS: usize = 24;
    let (mut lo, mut hi) = (f32::INFINITY, 0.0f32);
    for i in 0..=STEPS {
        let r = HEAD_DEPTH_RATIO.0 + (HEAD_DEPTH_RATIO.1 - HEAD_DEPTH_RATIO.0) * i as f32 / STEPS as f32;
        for j in 0..=STEPS {
            let phi = turn - HEAD_TURN + 2.0 * HEAD_TURN * j as f32 / STEPS as f32;
            let w = modelled_head_width(r, phi, yaw);
            lo = lo.min(w);
            hi = hi.max(w);
        }
    }
    (lo / (1.0 + HEAD_TOLERANCE), hi * (1.0 + HEAD_TOLERANCE))
}

/// The colour and mask (alpha above 0.5) of a rendered view (premultiplied linear RGBA over black), as the pose
/// network takes them.
fn network_inputs(view: &RgbaImage) -> (RgbImage, GrayImage) {
    let rgb = Image::from_fn(view.width, view.height, |c, r| view.data[r * view.width + c].truncate());
    let mask = Image::from_fn(view.width, view.height, |c, r| (view.data[r * view.width + c].w > 0.5) as u8 as f32);
    (rgb, mask)
}

/// The columns `[left, right]` of the run of `mask` (row-major, `width` wide) in row `row` that contains column
/// `x`, or of the run nearest to it within `reach` pixels; `None` when there is none.
fn run_at(mask: &[bool], width: usize, row: usize, x: f32, reach: usize) -> Option<(usize, usize)> {
    let line = mask.get(row * width..(row + 1) * width)?;
    if !x.is_finite() || width == 0 {
        return None;
    }
    let x0 = (x.floor().max(0.0) as usize).min(width - 1);
    let start =
        (0..=reach).flat_map(|d| [x0.checked_sub(d), Some(x0 + d)]).flatten().find(|&c| c < width && line[c])?;
    let left = (0..=start).rev().take_while(|&c| line[c]).last().unwrap_or(start);
    let right = (start..width).take_while(|&c| line[c]).last().unwrap_or(start);
    Some((left, right))
}

/// The median over `rows` of the width of [`run_at`] through column `x` (rows without a run are left out); `None`
/// when no row has one.
fn median_run_width(mask: &[bool], width: usize, rows: Range<usize>, x: f32, reach: usize) -> Option<f32> {
    let mut widths: Vec<usize> =
        rows.filter_map(|r| run_at(mask, width, r, x, reach).map(|(a, b)| b - a + 1)).collect();
    if widths.is_empty() {
        return None;
    }
    widths.sort_unstable();
    Some(widths[widths.len() / 2] as f32)
}

/// The mask (alpha above 0.5) of a view, row-major.
fn mask_of(view: &RgbaImage) -> Vec<bool> {
    view.data.iter().map(|p| p.w > 0.5).collect()
}

/// The mean row of two landmarks of `read`; `None` when not finite.
fn mean_row(read: &PoseLandmarks, ids: [usize; 2]) -> Option<f32> {
    let y = ids.iter().map(|&i| read.landmarks.get(i).map(|l| l.pixel.y)).sum::<Option<f32>>()? / 2.0;
    y.is_finite().then_some(y)
}

/// `lo..hi` (pixel rows, `lo` floored and `hi` ceiled, at least one row) clipped to `height`.
fn rows(lo: f32, hi: f32, height: usize) -> Option<Range<usize>> {
    let range = (lo.floor().max(0.0) as usize).min(height)..((hi.ceil().max(0.0) as usize) + 1).min(height);
    (!range.is_empty()).then_some(range)
}

/// Where the head is in the yaw-0 view (`mask`, `width` wide) according to `read`.
fn head_rows(read: &PoseLandmarks, mask: &[bool], width: usize) -> Option<HeadRows> {
    let height = mask.len() / width.max(1);
    let (eyes, mouth) = (mean_row(read, EYES)?, mean_row(read, MOUTH)?);
    let (top, bottom) = (eyes.min(mouth), eyes.max(mouth));
    let span = (bottom - top).max(1.0);
    let face = rows(top, bottom, height)?;
    let likeness = rows(top - span, bottom + 0.5 * span, height)?;
    let nose_x = read.landmarks.get(index::NOSE)?.pixel.x;
    let widths = median_run_width(mask, width, face.clone(), nose_x, (span as usize).max(2))?;
    (widths > 0.0).then_some(HeadRows { face, likeness, width: widths, nose_x })
}

/// How far the nose lies in front of the line between the ears over half the distance between them (a head seen
/// from above: about 0.10 m over 0.075 m).
const NOSE_OVER_HALF_EARS: f32 = 1.3;

/// Which way the face of `read` points (degrees from +z toward +x), from the image landmarks: the nose's offset
/// from the ears' midpoint is `b sin(phi)`, the person's left ear's offset from the right one `2a cos(phi)`, with
/// `b / a =` [`NOSE_OVER_HALF_EARS`]; `None` when that is degenerate.
fn face_direction(read: &PoseLandmarks) -> Option<f32> {
    let x = |i: usize| read.landmarks.get(i).map(|l| l.pixel.x).filter(|x| x.is_finite());
    let (nose, left, right) = (x(index::NOSE)?, x(index::LEFT_EAR)?, x(index::RIGHT_EAR)?);
    let (along, across) = (nose - 0.5 * (left + right), 0.5 * NOSE_OVER_HALF_EARS * (left - right));
    (along.hypot(across) > 1e-3).then(|| along.atan2(across).to_degrees())
}

impl Reference {
    /// Reads the yaw-0 view `front` (premultiplied linear RGBA, square; the photo within `frame`, `None`: all of
    /// it) with `pose`; `None` when the network finds no person in it.
    pub fn read(
        pose: &mut PoseEstimator,
        front: &RgbaImage,
        frame: Option<PhotoFrame>,
    ) -> Result<Option<Self>, BodyError> {
        let (rgb, mask) = network_inputs(front);
        let Some(read) = pose.estimate(&rgb, &mask, frame)?.filter(|r| r.score >= MIN_PERSON_SCORE) else {
            return Ok(None);
        };
        let head = head_rows(&read, &mask_of(front), front.width);
        let head_turn = face_direction(&read);
        Ok(Some(Self { read, size: front.width, head, head_turn, frame, front: front.clone() }))
    }

    /// Where landmark `i` of the yaw-0 view projects in the view at `yaw` (degrees), the hips at the body
    /// cube's depth 0.
    fn predicted(&self, i: usize, camera: &Camera) -> Option<Vec2> {
        let p = camera.project(self.read.cube(i, self.size))?;
        let v = Vec2::new(p.x, p.y);
        v.is_finite().then_some(v)
    }

    /// The 3-D shoulder width of the yaw-0 view's read, in pixels.
    fn shoulder_width(&self) -> f32 {
        let l = &self.read.landmarks;
        let p = |i: usize| Vec3::new(l[i].pixel.x, l[i].pixel.y, l[i].depth);
        p(index::LEFT_SHOULDER).distance(p(index::RIGHT_SHOULDER))
    }

    /// The RMS row distance (in 3-D shoulder widths) of `found`'s body landmarks from the rows of the yaw-0
    /// view's (those it shows, visibility at least 0.5); `None` with fewer than three landmarks.
    fn pose_error(&self, found: &PoseLandmarks) -> Option<f32> {
        let scale = self.shoulder_width();
        if scale.is_nan() || scale <= 1.0 {
            return None;
        }
        let rows: Vec<f32> = BODY_POINTS
            .iter()
            .filter(|&&i| self.read.landmarks[i].visibility >= MIN_VISIBILITY && self.read.in_frame(i, 0.0))
            .filter_map(|&i| Some(found.landmarks.get(i)?.pixel.y - self.read.landmarks[i].pixel.y))
            .filter(|d| d.is_finite())
            .collect();
        if rows.len() < 3 {
            return None;
        }
        Some((rows.iter().map(|d| d * d).sum::<f32>() / rows.len() as f32).sqrt() / scale)
    }

    /// The head's width in `mask` (a view at `yaw` degrees, `width` wide) through the column `nose_x` over its
    /// width at yaw 0.
    fn head_width(&self, mask: &[bool], width: usize, nose_x: f32) -> Option<f32> {
        let head = self.head.as_ref()?;
        let reach = (0.5 * head.width) as usize;
        let w = median_run_width(mask, width, head.face.clone(), nose_x, reach)?;
        Some(w / head.width)
    }

    /// The likeness of the back of the head in `back` (the view at [`BACK_YAW`]) to the mirrored face of the
    /// yaw-0 view: [`ncc`] of the luminance on the yaw-0 head's pixels over [`HeadRows::likeness`] (the run
    /// through the nose in each row) against the mirrored pixels of `back`, where both are covered.
    fn back_likeness(&self, back: &RgbaImage) -> Option<f32> {
        let head = self.head.as_ref()?;
        let (w, front) = (self.front.width, &self.front);
        if back.width != w || back.height != front.height {
            return None;
        }
        let mask = mask_of(front);
        let reach = (0.5 * head.width) as usize;
        let luminance = |p: glam::Vec4| crate::buffer::luminance(p.truncate());
        let mut pairs = Vec::new();
        for r in head.likeness.clone() {
            let Some((left, right)) = run_at(&mask, w, r, head.nose_x, reach) else { continue };
            for c in left..=right {
                let (f, b) = (front.data[r * w + c], back.data[r * w + (w - 1 - c)]);
                if f.w > 0.5 && b.w > 0.5 {
                    pairs.push((luminance(f), luminance(b)));
                }
            }
        }
        (pairs.len() >= MIN_LIKENESS_PIXELS).then(|| ncc(&pairs))
    }
}

/// Normalised cross-correlation of the pairs' two values, each variance floored at [`LIKENESS_FLOOR`] (a
/// featureless side correlates with nothing); 0 without pairs.
fn ncc(pairs: &[(f32, f32)]) -> f32 {
    if pairs.is_empty() {
        return 0.0;
    }
    let n = pairs.len() as f32;
    let (ma, mb) = pairs.iter().fold((0.0, 0.0), |(a, b), p| (a + p.0 / n, b + p.1 / n));
    let (mut cov, mut va, mut vb) = (0.0, 0.0, 0.0);
    for &(a, b) in pairs {
        cov += (a - ma) * (b - mb) / n;
        va += (a - ma) * (a - ma) / n;
        vb += (b - mb) * (b - mb) / n;
    }
    let v = cov / ((va + LIKENESS_FLOOR) * (vb + LIKENESS_FLOOR)).sqrt();
    if v.is_finite() {
        v
    } else {
        0.0
    }
}

/// Checks one view (`yaw` in degrees, premultiplied linear RGBA of the reference's size) against `reference`.
pub fn check_view(
    pose: &mut PoseEstimator,
    reference: &Reference,
    yaw: f32,
    view: &RgbaImage,
) -> Result<ViewCheck, BodyError> {
    Ok(measure(pose, reference, yaw, view)?.0)
}

/// [`check_view`], and which way the face points in the view's own frame ([`face_direction`]; `None` without a
/// read).
fn measure(
    pose: &mut PoseEstimator,
    reference: &Reference,
    yaw: f32,
    view: &RgbaImage,
) -> Result<(ViewCheck, Option<f32>), BodyError> {
    let (rgb, mask) = network_inputs(view);
    let read = pose.estimate(&rgb, &mask, reference.frame)?;
    let camera = Camera::orbit(yaw, 0.0, view.width, view.height);
    let person = read.as_ref().map_or(0.0, |r| r.score);
    let pose_error = read.as_ref().and_then(|found| {
        match (reference.pose_error(found), reference.pose_error(&found.mirrored_in_depth())) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    });
    let nose_x = read
        .as_ref()
        .map(|r| r.landmarks[index::NOSE].pixel.x)
        .filter(|x| x.is_finite())
        .or_else(|| reference.predicted(index::NOSE, &camera).map(|p| p.x));
    let head_width = nose_x.and_then(|x| reference.head_width(&mask_of(view), view.width, x));
    let back_likeness =
        if (yaw.rem_euclid(360.0) - BACK_YAW).abs() < 0.5 { reference.back_likeness(view) } else { None };
    let face = read.as_ref().filter(|r| r.score >= MIN_PERSON_SCORE).and_then(face_direction);
    Ok((ViewCheck { yaw, person, pose_error, head_width, head_turn: reference.head_turn, back_likeness }, face))
}

/// The views within this many degrees of facing the face whose reads of the face's direction [`check`] averages.
pub const FACE_SEEN: f32 = 60.0;

/// The mean of directions (degrees) taken modulo 180° (a head's outline is the same turned by 180°), in
/// `(-90, 90]`; `None` without directions or when they cancel out.
fn axial_mean(directions: impl Iterator<Item = f32>) -> Option<f32> {
    let (s, c) = directions.fold((0.0f32, 0.0f32), |(s, c), d| {
        let (ds, dc) = (2.0 * d.to_radians()).sin_cos();
        (s + ds, c + dc)
    });
    (s.hypot(c) > 1e-3).then(|| 0.5 * s.atan2(c).to_degrees())
}

/// Runs the check on one method's views (`(yaw in degrees, premultiplied linear RGBA)`, square, one of them at
/// yaw 0, which every view is predicted from; the photo within `frame`, `None`: all of the view) with the pose
/// network `pose`. The head's band is centred on the
/// face's direction averaged over the views that see the face (within [`FACE_SEEN`] of facing it), else the
/// yaw-0 view's.
pub fn check(
    pose: &mut PoseEstimator,
    views: &[(f32, &RgbaImage)],
    frame: Option<PhotoFrame>,
) -> Result<Plausibility, BodyError> {
    let Some(&(_, front)) =
        views.iter().find(|(yaw, _)| yaw.rem_euclid(360.0).min(360.0 - yaw.rem_euclid(360.0)) < 0.5)
    else {
        return Ok(Plausibility { reference: false, views: Vec::new() });
    };
    let Some(reference) = Reference::read(pose, front, frame)? else {
        return Ok(Plausibility { reference: false, views: Vec::new() });
    };
    let mut measured = Vec::with_capacity(views.len());
    for &(yaw, view) in views {
        measured.push(measure(pose, &reference, yaw, view)?);
    }
    // The face's direction from every view that sees the face (the view's yaw plus the direction read in it), a
    // steadier estimate than the yaw-0 view's alone.
    let seen = measured.iter().filter_map(|(v, face)| face.filter(|f| f.abs() <= FACE_SEEN).map(|f| v.yaw + f));
    let turn = axial_mean(seen).or(reference.head_turn);
    let views = measured.into_iter().map(|(v, _)| ViewCheck { head_turn: turn, ..v }).collect();
    Ok(Plausibility { reference: true, views })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::ground_truth::render_ground_truth;
    use crate::io::mesh_io::TexturedMesh;
    use crate::synth::framing::Framing;

    /// Rows of `#` (set) and `.` as a mask.
    fn mask(rows: &[&str]) -> (Vec<bool>, usize) {
        (rows.iter().flat_map(|r| r.chars().map(|c| c == '#')).collect(), rows[0].len())
    }

    #[test]
    fn runs_are_measured_through_the_column_or_the_nearest_within_reach() {
        let (m, w) = mask(&["..###...##", "#########."]);
        assert_eq!(run_at(&m, w, 0, 3.5, 0), Some((2, 4)));
        assert_eq!(run_at(&m, w, 0, 1.2, 0), None, "column 1 is empty and nothing is in reach");
        assert_eq!(run_at(&m, w, 0, 1.2, 1), Some((2, 4)));
        assert_eq!(run_at(&m, w, 0, 9.9, 0), Some((8, 9)));
        assert_eq!(run_at(&m, w, 1, 0.0, 0), Some((0, 8)));
        assert_eq!(run_at(&m, w, 2, 0.0, 0), None, "no such row");
        assert_eq!(run_at(&m, w, 0, f32::NAN, 3), None);
        assert_eq!(median_run_width(&m, w, 0..2, 3.0, 0), Some(9.0), "median of 3 and 9: the upper");
        assert_eq!(median_run_width(&m, w, 0..0, 3.0, 0), None);
    }

    #[test]
    fn the_head_band_follows_an_ellipse_turned_within_the_limits() {
        assert!((modelled_head_width(1.3, 0.0, 90.0) - 1.3).abs() < 1e-5);
        assert!((modelled_head_width(1.3, 20.0, 180.0) - 1.0).abs() < 1e-5, "from behind: the same width");
        let (lo, hi) = head_band(0.0, 0.0);
        assert!(lo < 1.0 && hi > 1.0);
        let (lo, hi) = head_band(90.0, 0.0);
        let tol = 1.0 + HEAD_TOLERANCE;
        assert!((hi - HEAD_DEPTH_RATIO.1 * tol).abs() < 1e-3, "deepest head facing the camera: {hi}");
        assert!(lo < 1.0 / tol + 1e-3, "a round head turned: {lo}");
        assert!(lo * tol > 0.5 && hi < 2.0, "a head half as deep or twice as deep is outside ({lo}, {hi})");
    }

    #[test]
    fn likeness_is_one_for_a_copy_and_zero_for_a_featureless_side() {
        let a: Vec<(f32, f32)> = (0..50).map(|i| ((i % 7) as f32 * 0.1, (i % 7) as f32 * 0.1)).collect();
        assert!(ncc(&a) > 0.95, "{}", ncc(&a));
        let flat: Vec<(f32, f32)> = (0..50).map(|i| ((i % 7) as f32 * 0.1, 0.4)).collect();
        assert!(ncc(&flat).abs() < 1e-6);
        let inverted: Vec<(f32, f32)> = a.iter().map(|&(x, y)| (x, 1.0 - y)).collect();
        assert!(ncc(&inverted) < -0.9);
        assert_eq!(ncc(&[]), 0.0);
    }

    #[test]
    fn failures_name_what_is_wrong() {
        let ok = ViewCheck {
            yaw: 90.0,
            person: 0.9,
            pose_error: Some(0.2),
            head_turn: Some(0.0),
            head_width: Some(1.3),
            back_likeness: None,
        };
        assert!(ok.passes(), "{:?}", ok.failures());
        let bad = ViewCheck {
            yaw: 90.0,
            person: 0.1,
            pose_error: Some(2.0),
            head_turn: None,
            head_width: Some(0.6),
            back_likeness: Some(0.9),
        };
        assert_eq!(bad.failures().len(), 4, "{:?}", bad.failures());
        let egg = ViewCheck { head_width: Some(2.4), ..ok.clone() };
        assert!(egg.failures()[0].starts_with("head stretched"), "{:?}", egg.failures());
        let nan = ViewCheck { person: f32::NAN, head_width: Some(f32::NAN), ..ok.clone() };
        assert_eq!(nan.failures().len(), 2, "{:?}", nan.failures());
        let none = Plausibility { reference: false, views: vec![ok.clone()] };
        assert!(!none.passes());
        let all = Plausibility { reference: true, views: vec![ok, egg] };
        assert_eq!(all.passing_views(), (1, 2));
    }

    /// The installed pose network, or `None` after a line saying the test is skipped without it.
    fn pose_network() -> Option<PoseEstimator> {
        let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(".tools/models/pose_landmark_full.onnx");
        if !file.is_file() {
            eprintln!("skipped: {} is not installed (bash scripts/setup.d/live.sh)", file.display());
            return None;
        }
        Some(PoseEstimator::load(Some(&file), &Default::default()).expect("pose model"))
    }

    /// The views' side in pixels (that of `eval --photos`).
    const SIZE: usize = 512;

    /// The yaws the ground truth is checked at: those of `eval --photos` and the other side.
    const YAWS: [f32; 9] = [0.0, 30.0, 60.0, 90.0, 135.0, 180.0, 225.0, 270.0, 315.0];

    /// The head of a synthetic subject: the vertices from [`CHIN_BELOW_EYES`] below the eyes up, within a radius
    /// of the head bone's joint (the top of the neck) horizontally (hair and hats included), the way the face
    /// points (from the neck to the eyes' midpoint, seen from above), and the bounding box of the body's own head
    /// vertices (no garment) in the head's frame (across, up, forward).
    struct Head {
        vertices: Vec<bool>,
        centre: Vec3,
        /// Unit vectors across the face, up, and forward.
        frame: [Vec3; 3],
        half: Vec3,
    }

    /// How far from the neck's axis (body-cube units, about metres) a vertex above the neck counts as the head's
    /// (hair included, raised arms mostly not).
    const HEAD_RADIUS: f32 = 0.16;

    /// The same with long hair hanging behind the head.
    const HAIR_RADIUS: f32 = 0.3;

    /// How far below the eyes (body-cube units) the head's vertices reach: the chin and the top of the neck (the
    /// head bone starts at the mouth's height).
    const CHIN_BELOW_EYES: f32 = 0.09;

    impl Head {
        fn of(mesh: &TexturedMesh, body_end: usize, neck: Vec3, eyes: Vec3, radius: f32) -> Self {
            let p = &mesh.mesh.positions;
            let forward = Vec3::new(eyes.x - neck.x, 0.0, eyes.z - neck.z).try_normalize().unwrap_or(Vec3::Z);
            let frame = [Vec3::Y.cross(forward), Vec3::Y, forward];
            let vertices: Vec<bool> = p
                .iter()
                .map(|v| v.y > eyes.y - CHIN_BELOW_EYES && Vec2::new(v.x - neck.x, v.z - neck.z).length() < radius)
                .collect();
            let local = |v: Vec3| Vec3::new(v.dot(frame[0]), v.dot(frame[1]), v.dot(frame[2]));
            let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
            for (v, _) in p.iter().zip(&vertices).take(body_end).filter(|(_, h)| **h) {
                lo = lo.min(local(*v));
                hi = hi.max(local(*v));
            }
            let c = 0.5 * (lo + hi);
            Head { vertices, centre: c.x * frame[0] + c.y * frame[1] + c.z * frame[2], frame, half: 0.5 * (hi - lo) }
        }

        /// `p` in the head's frame about its centre.
        fn local(&self, p: Vec3) -> Vec3 {
            let d = p - self.centre;
            Vec3::new(d.dot(self.frame[0]), d.dot(self.frame[1]), d.dot(self.frame[2]))
        }

        /// A point of the head's frame about its centre in the body cube.
        fn world(&self, l: Vec3) -> Vec3 {
            self.centre + l.x * self.frame[0] + l.y * self.frame[1] + l.z * self.frame[2]
        }
    }

    /// The subject with its head squashed front to back to `depth` of its depth about its centre (a squashed
    /// profile).
    fn squashed(mut mesh: TexturedMesh, head: &Head, depth: f32) -> TexturedMesh {
        for (p, _) in mesh.mesh.positions.iter_mut().zip(&head.vertices).filter(|(_, h)| **h) {
            let l = head.local(*p);
            *p = head.world(Vec3::new(l.x, l.y, depth * l.z));
        }
        mesh.mesh.compute_normals();
        mesh
    }

    /// The subject with its head replaced by an egg: every head vertex moved along its ray from the head's centre
    /// onto an ellipsoid as wide and as high as the head and `depth` times as deep (front to back) as it is wide,
    /// keeping its texture coordinates (the face is painted onto the egg).
    fn egg(mut mesh: TexturedMesh, head: &Head, depth: f32) -> TexturedMesh {
        let axes = Vec3::new(head.half.x, head.half.y, depth * head.half.x).max(Vec3::splat(1e-3));
        for (p, _) in mesh.mesh.positions.iter_mut().zip(&head.vertices).filter(|(_, h)| **h) {
            let l = head.local(*p);
            let k = (l / axes).length();
            if k > 1e-6 {
                *p = head.world(l / k);
            }
        }
        mesh.mesh.compute_normals();
        mesh
    }

    /// The subject with a face on the back of its head: the head's triangles behind its centre are dropped and
    /// those in front of it are copied mirrored front to back about the centre (a two-faced head, the face seen
    /// from behind as from the front).
    fn doubled_face(mut mesh: TexturedMesh, head: &Head) -> TexturedMesh {
        let m = &mut mesh.mesh;
        let in_head = |t: &[u32; 3]| t.iter().all(|&i| head.vertices[i as usize]);
        let mut copy = vec![u32::MAX; m.positions.len()];
        let (mut triangles, mut materials) = (Vec::new(), Vec::new());
        let several = !mesh.triangle_materials.is_empty();
        for (k, t) in m.triangles.clone().iter().enumerate() {
            let material = mesh.triangle_materials.get(k).copied().unwrap_or(0);
            if !in_head(t) {
                triangles.push(*t);
                materials.push(material);
                continue;
            }
            let front = t.iter().map(|&i| head.local(m.positions[i as usize]).z).sum::<f32>();
            if front < 0.0 {
                continue;
            }
            triangles.push(*t);
            materials.push(material);
            let mut mirrored = [0u32; 3];
            for (slot, &i) in mirrored.iter_mut().zip(t) {
                let i = i as usize;
                if copy[i] == u32::MAX {
                    copy[i] = m.positions.len() as u32;
                    let l = head.local(m.positions[i]);
                    m.positions.push(head.world(Vec3::new(l.x, l.y, -l.z)));
                    if !m.uvs.is_empty() {
                        m.uvs.push(m.uvs[i]);
                    }
                    if !m.colors.is_empty() {
                        m.colors.push(m.colors[i]);
                    }
                }
                *slot = copy[i];
            }
            triangles.push([mirrored[0], mirrored[2], mirrored[1]]);
            materials.push(material);
        }
        m.triangles = triangles;
        m.compute_normals();
        if several {
            mesh.triangle_materials = materials;
        }
        mesh
    }

    /// The ground truth of `mesh` at `yaw`, [`SIZE`] px.
    fn view(mesh: &TexturedMesh, yaw: f32) -> RgbaImage {
        render_ground_truth(mesh, &Camera::orbit(yaw, 0.0, SIZE, SIZE)).to_linear_rgba()
    }

    /// One line of measurements, for setting the thresholds (printed with `--nocapture`).
    fn line(case: &str, seed: u64, v: &ViewCheck) -> String {
        let f = |x: Option<f32>| x.map_or("-".to_string(), |x| format!("{x:.3}"));
        format!(
            "PLAUS\t{case}\t{seed}\t{}\t{:.3}\t{}\t{}\t{}\t{}\t{}",
            v.yaw,
            v.person,
            f(v.pose_error),
            f(v.head_turn),
            f(v.head_width),
            f(v.back_likeness),
            v.passes()
        )
    }

    /// The least share (%) of the squashed, egg and doubled views the check must fail.
    const BAD_CAUGHT: [usize; 3] = [60, 30, 75];

    /// How many synthetic people (seeds from 0) the check is measured on; `PLAUS_SEEDS` overrides.
    const SEEDS: u64 = 24;

    #[test]
    fn ground_truth_passes_and_squashed_egg_or_doubled_heads_fail() {
        let Some(mut pose) = pose_network() else { return };
        let rig = &crate::synth::SynthAssets::shared().expect("synthetic assets").rig;
        let head_bone = rig.index["head"];
        let seeds: u64 = std::env::var("PLAUS_SEEDS").ok().and_then(|s| s.parse().ok()).unwrap_or(SEEDS);
        let sheet_dir = std::env::var_os("PLAUS_SHEETS").map(std::path::PathBuf::from);
        // (passing views, views) per case.
        let (mut truth, mut bad) = ((0, 0), [(0, 0); 3]);
        for seed in 0..seeds {
            let subject = crate::synth::generate_subject(seed, Framing::Full).expect("synthetic subject");
            let eyes = 0.5 * (subject.joints[rig.index["eye.L"]] + subject.joints[rig.index["eye.R"]]);
            let neck = subject.joints[head_bone];
            let body_end = subject.garments.iter().map(|g| g.vertices.start).min().unwrap_or(usize::MAX);
            let head = Head::of(&subject.mesh, body_end, neck, eyes, HEAD_RADIUS);
            // With the hair that hangs behind the head, which would hide a face there.
            let facing_camera =
                Head::of(&subject.mesh, body_end, neck, Vec3::new(neck.x, eyes.y, neck.z + 1.0), HAIR_RADIUS);
            let face_yaw = head.frame[2].x.atan2(head.frame[2].z).to_degrees();
            let profiles = vec![face_yaw + 90.0, face_yaw - 90.0];
            let ymax = subject.mesh.mesh.positions.iter().fold(f32::MIN, |m, p| m.max(p.y));
            eprintln!(
                "PLAUSDBG\t{seed}\tneck {:?} eyes {:?} centre {:?} half {:?} count {} ymax {ymax}",
                subject.joints[head_bone],
                eyes,
                head.centre,
                head.half,
                head.vertices.iter().filter(|h| **h).count()
            );
            let truth_views: Vec<(f32, RgbaImage)> = YAWS.iter().map(|&y| (y, view(&subject.mesh, y))).collect();
            let refs: Vec<(f32, &RgbaImage)> = truth_views.iter().map(|(y, v)| (*y, v)).collect();
            let checked = check(&mut pose, &refs, None).expect("pose network runs");
            if !checked.reference {
                eprintln!("PLAUS\tno-reference\t{seed}");
            }
            for v in &checked.views {
                eprintln!("{}", line("truth", seed, v));
            }
            truth.0 += checked.views.iter().filter(|v| v.passes()).count();
            truth.1 += YAWS.len();
            let cases = [
                ("squashed", squashed(subject.mesh.clone(), &head, 0.5), profiles.clone()),
                ("egg", egg(subject.mesh.clone(), &head, 2.0), profiles),
                // Mirrored about the camera's depth axis, as the renderer draws the back of a photo: the front
                // image mirrored.
                ("doubled", doubled_face(subject.mesh.clone(), &facing_camera), vec![BACK_YAW]),
            ];
            for (k, (name, mesh, shown)) in cases.iter().enumerate() {
                // Checked like a method's views in `eval --photos`: the bad mesh's own yaw-0 view is the
                // reference; counted are the views that show the defect (`shown`).
                let mut bad_views: Vec<(f32, RgbaImage)> = YAWS.iter().map(|&y| (y, view(mesh, y))).collect();
                bad_views.extend(shown.iter().filter(|y| !YAWS.contains(y)).map(|&y| (y, view(mesh, y))));
                let refs: Vec<(f32, &RgbaImage)> = bad_views.iter().map(|(y, v)| (*y, v)).collect();
                let checked = check(&mut pose, &refs, None).expect("pose network runs");
                if !checked.reference {
                    eprintln!("PLAUS\t{name}\t{seed}\tno reference");
                }
                for &yaw in shown {
                    let v = checked.views.iter().find(|v| v.yaw == yaw);
                    if let Some(v) = v {
                        eprintln!("{}", line(name, seed, v));
                    }
                    bad[k].0 += (checked.reference && v.is_some_and(ViewCheck::passes)) as usize;
                    bad[k].1 += 1;
                    if let (Some(dir), Some((_, img))) = (&sheet_dir, bad_views.iter().find(|(y, _)| *y == yaw)) {
                        let file = dir.join(format!("{name}_{seed}_{yaw:.0}.png"));
                        crate::io::image_io::save_rgba_png(&file, img).expect("writes the sheet");
                    }
                }
            }
        }
        eprintln!("ground truth: {} of {} views pass", truth.0, truth.1);
        for (name, (pass, n)) in ["squashed", "egg", "doubled"].iter().zip(bad) {
            eprintln!("{name}: {} of {n} views fail", n - pass);
        }
        if std::env::var_os("PLAUS_MEASURE").is_none() {
            assert!(truth.0 * 100 >= 95 * truth.1, "{} of {} ground-truth views pass", truth.0, truth.1);
            // What the check catches on seeds 0-47 (docs/evaluation.md), less a margin: not every bad view.
            for ((name, (pass, n)), least) in ["squashed", "egg", "doubled"].iter().zip(bad).zip(BAD_CAUGHT) {
                assert!((n - pass) * 100 >= least * n, "{name}: {} of {n} bad views fail, under {least} %", n - pass);
            }
        }
    }
}
