//! A person model kept across the frames of a live source: what the camera has seen stays.
//!
//! One frame shows one side of a person; the frame path ([`super::frame`]) guesses the thickness from the
//! silhouette and the back's colours from the front. A live person turns, and every frame is a measured view of
//! the same person. [`PersonModel`] keeps, in the person's own frame (the frame that turns with them about the
//! vertical axis through their torso):
//!
//! - **the shape the silhouettes have shown** ([`HULL_SIDE`]² cells on each of [`HULL_SLICES`] horizontal
//!   slices): a visual hull carved by every frame's silhouette. Under the orthographic source camera and a turn
//!   about the vertical axis, each row of the silhouette constrains one horizontal slice of the person, so each
//!   cell keeps the signed distance (inside positive) of its projection to that row's silhouette, and the hull is
//!   the second smallest over the frames (one stray frame does not carve). The field is continuous, so the surface
//!   is found between cells.
//! - **the colour of every surface seen** ([`MAP_ANGLES`] x [`MAP_ROWS`] texels of a cylinder about the same
//!   axis), each texel with a confidence: how squarely the camera saw it (the front's normal), capped at
//!   [`MAP_MAX_WEIGHT`] so that newer views outweigh old ones.
//!
//! **The person's orientation comes from the body**: each frame's world landmarks of a pose read give the torso's
//! yaw — the live segmenter's, handed on with the mask ([`PersonModel::update_with_world`]), else a read of the
//! model's own ([`PersonModel::with_pose`], [`crate::body::pose::PoseEstimator::track`] on MediaPipe's tracking
//! region) — ([`body_yaw`]: the normal of shoulders and hips). The network confuses a person's front and back away from profile (the same image read with depths negated and sides swapped: yaw
//! `pi - m` instead of `m`), so both readings go into a filter over yaw and turning speed (`YawFilter`) that
//! counts them alike: the branch is decided by the motion (a person turning on would have to reverse at profile to
//! follow the mirror branch), which the image itself measures: the turn since the frame before, read from how the
//! front's textured points moved against their depths (`turn_between`), weighs the filter's turning speeds. The
//! first reading is taken to face the camera. Never from any ground truth ([`PersonModel::update_with_yaw`], the
//! true yaw, is for evaluation only).
//! The colours can refine the filter's yaw within [`COLOUR_REFINE_DEGREES`] (0 by default: on the turning clips
//! 4 or 10 degrees changed nothing measurable). Without a pose network or a torso read, the yaw is tracked from
//! the colours alone: each candidate turn around the constant-velocity prediction scored by how well the frame's
//! colours fit the kept colours where the model holds them (a parabola through the best three); a person of one
//! flat colour then gives no match and the yaw follows the prediction.
//!
//! **Rendering with it** ([`PersonModel::update`] rewrites a [`PreparedInput`] of the frame path): inside the
//! current frame's silhouette (the current frame always decides where the person is), the front and back depths
//! become the hull's where its slice has been seen from enough directions ([`coverage_weight`]), blended with the
//! frame's own guess before, and only where the hull holds the pixel: where a measured slice's hull misses a pixel
//! well inside the silhouette (a limb that moved), the frame keeps its own depths ([`AGREE_RAMP`]); the back image (what the renderer draws on every surface the camera does not see)
//! takes the kept colour where the model holds it, else today's fill. What the camera sees keeps the camera's
//! colours.
//!
//! **Forgetting**: per horizontal band of the body ([`BANDS`]), the colours the frame shows are compared with the
//! kept ones at the tracked yaw; a band whose mean difference exceeds
//! [`RESET_COLOUR_ERROR`] on [`RESET_STRIKES`] frames in a row is reset (hull, colours and the directions seen); when
//! half the bands holding colour reset at once, or the mean over the bands (of the colours' square roots, about as
//! the eye weighs them) jumps above [`RESTART_JUMP`] times its usual value and [`RESTART_COLOUR_ERROR`], with
//! three quarters of the bands each jumping ([`RESTART_BAND_JUMP`]), as long (another person, a cut), the whole
//! model restarts from this frame. A band that disagrees once keeps what it holds (nothing of that frame is
//! carved or kept there) until the next frame decides. A turn keeps the colours in step with the tracked yaw and
//! does not reset.
//!
//! Memory is fixed at construction ([`PersonModel::memory_bytes`]): 6.3 MB whatever the length of the source.

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::back::BackImage;
use super::PreparedInput;
use crate::buffer::{luminance, GrayImage, RgbImage};
use crate::geometry::inflate::InflatedSurfaces;
use crate::geometry::surface_mesh::{mesh_from_surfaces, source_gbuffer};

/// Cells across each horizontal slice of the hull (both horizontal axes).
pub const HULL_SIDE: usize = 64;

/// Horizontal slices of the hull over the model's height (body-cube y from 1 down to -1).
pub const HULL_SLICES: usize = 128;

/// Half the side of a slice in model units (the body cube of the frame the model started on, centred on the
/// person's vertical axis): a person turning within a circle of this radius is held.
pub const HULL_HALF: f32 = 1.0;

/// Tolerance added to every carving distance (model units, about 2 pixels at 512²): a yaw tracked a degree off
/// does not carve the person's edge. (0.02 was tried with the body's yaw: no gain at the turn's end, 0.1 dB less
/// over it.)
pub const CARVE_MARGIN: f32 = 0.008;

/// Texels around the colour cylinder.
pub const MAP_ANGLES: usize = 256;

/// Texels along the colour cylinder's height (body-cube y from 1 down to -1).
pub const MAP_ROWS: usize = 512;

/// Largest confidence a colour texel accumulates: a new view squarely seen takes at least a third of it.
pub const MAP_MAX_WEIGHT: f32 = 2.0;

/// Confidence from which a kept colour is drawn in full (below it, blended with today's fill).
pub const MAP_FULL_WEIGHT: f32 = 0.8;

/// Horizontal bands of the body that are forgotten on their own.
pub const BANDS: usize = 8;

/// Directions (yaw modulo 180 degrees: a silhouette and its mirror say the same) a slice's coverage counts.
pub const YAW_BINS: usize = 12;

/// Degrees either side of the predicted yaw the tracker tries, one degree apart.
pub const SEARCH_DEGREES: i32 = 16;

/// Degrees either side of the body's yaw the colours refine it ([`PersonModel::with_colour_refine`]; 0: the body's
/// yaw alone).
pub const COLOUR_REFINE_DEGREES: i32 = 0;

/// Cells of the body's yaw filter around the turn (`YawFilter`; 5 degrees each).
pub const YAW_CELLS: usize = 72;

/// Turning speeds the yaw filter holds, in cells a frame either side of standing still (up to 25 degrees a frame).
pub const YAW_SPEEDS: i32 = 5;

/// The body reading's spread (degrees) in the yaw filter.
pub const BODY_SIGMA_DEGREES: f32 = 20.0;

/// Likelihood of a reading that is neither branch (a glitch of the network), against 1 at a branch.
pub const BODY_OUTLIER: f32 = 0.2;

/// Chance the turning speed stays from one frame to the next (else it changes by one step, 5 degrees a frame).
pub const KEEP_SPEED: f32 = 0.8;

/// Chance the yaw drifts by a cell either way beyond the speed, per frame.
pub const YAW_DRIFT: f32 = 0.15;

/// Largest turning speed the prediction keeps (degrees per frame).
pub const MAX_TURN_DEGREES: f32 = 25.0;

/// Mean absolute colour difference (linear RGB, averaged over the channels) between a band of the frame and the
/// model above which the band counts as changed.
pub const RESET_COLOUR_ERROR: f32 = 0.16;

/// The colour difference of the square roots of linear RGB ([`ModelFrame::band_error_roots`]) averaged over the
/// bands holding colour: the floor under which the whole person never counts as changed. The whole person counts as changed above it and above [`RESTART_JUMP`] times what the person's
/// frames have differed by so far. On the turning synthetic people (`eval --turn`, seed 0, frames without an
/// event) the mean stays under 0.042; on the textured column of the tests it climbs to 0.09 over a turn as the
/// yaw runs ahead; a cut to another person gave 0.12–0.39 on the two frames after it, 4 to 12 times the frames
/// before.
pub const RESTART_COLOUR_ERROR: f32 = 0.05;

/// How many times the person's usual difference ([`RESTART_COLOUR_ERROR`]) the mean over the bands must exceed for
/// the whole person to count as changed: a cut jumps, a turn drifts (2.5 restarted the textured column's turn).
pub const RESTART_JUMP: f32 = 3.0;

/// How many times a band's usual difference its difference must exceed to count as jumped; the whole person counts
/// as changed only when three quarters of the bands holding colour jumped (on the cuts of `eval --turn` every band
/// but one jumped 2 to 90 times its value before).
pub const RESTART_BAND_JUMP: f32 = 2.0;

/// The new frame's weight in the person's usual difference (an exponential average over the unchanged frames).
pub const RESTART_BASELINE_WEIGHT: f32 = 0.2;

/// How far (degrees) the tracked yaw must have turned since the hull was last carved and the colours last kept for
/// a frame to carve and keep again at once: a frame from the direction of the last adds little to either (the
/// hull is carved by the second smallest over frames, the colours are the camera's own where it looks), and the
/// two are 7–8 ms of a 512² update.
pub const REFRESH_DEGREES: f32 = 2.5;

/// Frames after which the hull is carved and the colours kept again even without a turn (a moved arm, a new
/// expression).
pub const REFRESH_EVERY: u64 = 4;

/// Frames in a row a band must count as changed before it is reset.
pub const RESET_STRIKES: u8 = 2;

/// Most pixels the tracker reads per frame.
const MAX_TRACK_POINTS: usize = 1500;

/// The turn between two frames read from the image (`turn_between`): the standard deviation (degrees) of its
/// weight on the yaw filter's turning speeds, about a speed cell.
pub const FLOW_SIGMA_DEGREES: f32 = 10.0;

/// The weight of a turning speed the image's turn does not support (a reading can be wrong: an arm's swing taken for
/// the turn), as [`BODY_OUTLIER`] is for the body.
pub const FLOW_OUTLIER: f32 = 0.2;

/// Tracked pixels a frame's turn is read from at most ([`turn_between`]): those with the most texture.
const FLOW_POINTS: usize = 300;

/// Texels either side around the colour cylinder the tracker's coarse step averages (8 degrees).
const COARSE_BLUR: usize = 6;

/// Colour samples a band needs before its difference counts.
const MIN_BAND_SAMPLES: usize = 24;

/// Step between the pixels the tracker and the forgetting read (source pixels at 512², scaled with the size).
const TRACK_STEP_512: usize = 4;

/// Step between the rays cast through the hull (source pixels at 512², scaled with the size); the depths between
/// them are interpolated.
const RAY_STEP_512: usize = 4;

/// Rays (of the grid [`PersonModel::blend_depths`] casts) over which the hull's weight rises from a ray that
/// missed it inside the silhouette to full.
pub const AGREE_RAMP: f32 = 2.0;

/// The frame's surfaces with the hull's depths blended in ([`PersonModel::blend_depths`]).
struct Blended {
    surfaces: InflatedSurfaces,
    /// Mean over the silhouette of how far the hull replaced the frame's own depths.
    hull_weight: f32,
    /// Per pixel, how far what the model holds applies there (0..1): 1 where the slice is not measured yet or the
    /// hull covers the pixel, 0 where a measured slice's hull misses it (the person there no longer matches the
    /// other frames: a limb that moved). Colours are kept and drawn from the model only as far.
    hold: Vec<f32>,
}

/// A chamfer distance (1 along the grid, sqrt 2 diagonally) from the cells holding 0, in place over a `w` x `h`
/// grid of infinities and zeros.
fn chamfer(d: &mut [f32], w: usize, h: usize) {
    const DIAG: f32 = std::f32::consts::SQRT_2;
    for r in 0..h {
        for c in 0..w {
            let mut v = d[r * w + c];
            if c > 0 {
                v = v.min(d[r * w + c - 1] + 1.0);
            }
            if r > 0 {
                v = v.min(d[(r - 1) * w + c] + 1.0);
                if c > 0 {
                    v = v.min(d[(r - 1) * w + c - 1] + DIAG);
                }
                if c + 1 < w {
                    v = v.min(d[(r - 1) * w + c + 1] + DIAG);
                }
            }
            d[r * w + c] = v;
        }
    }
    for r in (0..h).rev() {
        for c in (0..w).rev() {
            let mut v = d[r * w + c];
            if c + 1 < w {
                v = v.min(d[r * w + c + 1] + 1.0);
            }
            if r + 1 < h {
                v = v.min(d[(r + 1) * w + c] + 1.0);
                if c + 1 < w {
                    v = v.min(d[(r + 1) * w + c + 1] + DIAG);
                }
                if c > 0 {
                    v = v.min(d[(r + 1) * w + c - 1] + DIAG);
                }
            }
            d[r * w + c] = v;
        }
    }
}

/// One frame's placement of the model: how the current normalised frame relates to the model's coordinates.
#[derive(Clone, Copy, Debug)]
struct Placement {
    /// Source side in pixels.
    size: f32,
    /// Current scale over the model's reference scale.
    k: f32,
    /// Column of the person's vertical axis in the current frame (continuous source pixels).
    axis: f32,
    /// Current row = `k (1 - Y) size / 2 + row_offset` for model height `Y`.
    row_offset: f32,
    /// Yaw (radians): the person has turned this far from the model's frame.
    yaw: f32,
    /// Where the photo lies in the source view (rows and columns outside are unknown).
    frame: (Vec2, Vec2),
}

impl Placement {
    /// Source pixels per model unit.
    fn px(&self) -> f32 {
        self.k * self.size * 0.5
    }

    /// The current (continuous) row of model height `y`.
    fn row(&self, y: f32) -> f32 {
        self.k * (1.0 - y) * self.size * 0.5 + self.row_offset
    }

    /// The model height of current (continuous) row `q`.
    fn height(&self, q: f32) -> f32 {
        1.0 - 2.0 * (q - self.row_offset) / (self.k * self.size)
    }

    /// The turn by the yaw, its sine and cosine taken once (for the per-pixel loops).
    fn turn(&self) -> Turn {
        let (s, c) = self.yaw.sin_cos();
        Turn { s, c }
    }

    /// Camera-aligned `x` about the axis of model `(u, w)`.
    fn camera_x(self, u: f32, w: f32) -> f32 {
        let (s, c) = self.yaw.sin_cos();
        c * u + s * w
    }
}

/// The usual difference `baseline` (`None`: none yet) after a frame that differed by `value`: the exponential
/// average with the new frame's weight [`RESTART_BASELINE_WEIGHT`], or `value` itself to start.
fn usual_difference(baseline: Option<f32>, value: f32) -> f32 {
    let w = RESTART_BASELINE_WEIGHT;
    baseline.map_or(value, |b| (1.0 - w) * b + w * value)
}

/// A frame's colour difference with the model per band at the tracked yaw ([`ModelFrame::band_error`],
/// [`ModelFrame::band_error_roots`]).
#[derive(Clone, Copy, Debug)]
struct BandErrors {
    linear: [f32; BANDS],
    roots: [f32; BANDS],
}

/// The time each step of an update took, for the log (at trace level: `R2HUMAN_LOG=r2human::pipeline::person_model=trace`).
struct StageClock {
    last: std::time::Instant,
    laps: Vec<(&'static str, f32)>,
}

impl StageClock {
    fn start() -> Self {
        Self { last: std::time::Instant::now(), laps: Vec::new() }
    }

    /// Ends the step `name`.
    fn lap(&mut self, name: &'static str) {
        let now = std::time::Instant::now();
        self.laps.push((name, (now - self.last).as_secs_f32() * 1e3));
        self.last = now;
    }

    fn log(&self) {
        if tracing::enabled!(tracing::Level::TRACE) {
            let laps: Vec<String> = self.laps.iter().map(|(n, ms)| format!("{n} {ms:.1}")).collect();
            tracing::trace!("person model steps (ms): {}", laps.join(", "));
        }
    }
}

/// The turn of a [`Placement`]'s yaw: its sine and cosine.
#[derive(Clone, Copy, Debug)]
struct Turn {
    s: f32,
    c: f32,
}

impl Turn {
    /// Model `(u, w)` (horizontal, depth) of camera-aligned `(x, z)` about the axis.
    #[inline]
    fn model_of(self, x: f32, z: f32) -> (f32, f32) {
        (self.c * x - self.s * z, self.s * x + self.c * z)
    }
}

/// The model's reference: the normalisation of the frame it started on.
#[derive(Clone, Copy, Debug)]
struct Reference {
    scale: f32,
    offset_y: f32,
    /// The person's axis in photo pixels (smoothed over frames).
    axis_photo: f32,
}

/// What one [`PersonModel::update`] did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ModelFrame {
    /// The tracked yaw (degrees): how far the person has turned since the model started.
    pub yaw_degrees: f32,
    /// Whether the yaw came from matching the kept colours (else from the prediction).
    pub tracked: bool,
    /// The body's yaw this frame read (degrees, in the model's frame, of its two branches the one nearer the
    /// tracked yaw), when the pose network found the torso.
    pub body_yaw_degrees: Option<f32>,
    /// Whether a body reading went into the yaw (`YawFilter`).
    pub body_used: bool,
    /// The turn between the frame before and this one read from the image (degrees, `turn_between`), when it
    /// could be read.
    pub image_turn_degrees: Option<f32>,
    /// Milliseconds the pose network's read took (inside `ms`).
    pub pose_ms: f32,
    /// Bands reset on this frame (0 = the top band).
    pub reset_bands: Vec<usize>,
    /// Whether the whole model restarted on this frame.
    pub restarted: bool,
    /// Per band, the mean colour difference between the frame and the model (linear RGB; NaN where too few samples).
    pub band_error: [f32; BANDS],
    /// The same of the square roots of linear RGB, about as the eye weighs differences (a dark garment changed for
    /// another differs as much as a light one): the whole person's test ([`RESTART_COLOUR_ERROR`]).
    pub band_error_roots: [f32; BANDS],
    /// Mean over the current silhouette's slices of how far the hull replaced the frame's own depths (0..1).
    pub hull_weight: f32,
    /// Fraction of the back image's pixels that took the kept colours.
    pub back_from_model: f32,
    /// Milliseconds the update took.
    pub ms: f32,
}

impl ModelFrame {
    /// What the forgetting did, in words (for the log).
    pub fn describe(&self) -> String {
        if self.restarted {
            "restarted (most of the person changed)".to_string()
        } else if self.reset_bands.is_empty() {
            "kept".to_string()
        } else {
            format!("forgot bands {:?} (0 = the top)", self.reset_bands)
        }
    }
}

/// The person model (see the module docs).
#[derive(Clone, Debug)]
pub struct PersonModel {
    /// Per slice, per cell: the two smallest carving distances (model units; infinity = not carved).
    hull: Vec<[f32; 2]>,
    /// Per slice, how far from the axis its hull reaches ([`slice_radii`]): made again whenever the hull changes,
    /// read by every ray.
    radii: Vec<f32>,
    /// Per slice, the directions seen (bit per [`YAW_BINS`] bin).
    seen: Vec<u16>,
    /// Per texel: linear RGB and the confidence.
    map: Vec<[f32; 4]>,
    reference: Option<Reference>,
    yaw: f32,
    velocity: f32,
    strikes: [u8; BANDS],
    /// Frames in a row the mean over the bands has counted as changed.
    whole_strikes: u8,
    /// The mean over the bands on the frames that counted as unchanged, averaged over time
    /// ([`RESTART_BASELINE_WEIGHT`]); `None` before the first.
    whole_baseline: Option<f32>,
    /// The same per band, over the frames its difference did not jump ([`RESTART_BAND_JUMP`]).
    band_baseline: [Option<f32>; BANDS],
    /// The yaw and frame number the hull was last carved and the colours kept at (`None`: at the next frame).
    last_refresh: Option<(f32, u64)>,
    frames: u64,
    /// The pose network the body's orientation is read with on every frame ([`PersonModel::with_pose`]).
    pose: Option<super::SharedPose>,
    /// MediaPipe's tracking region the last read gave (normalised source pixels).
    pose_region: Option<crate::body::pose::PoseRegion>,
    /// The body's yaw (radians, [`body_yaw`]'s convention) when the model's yaw was 0: model yaw = body yaw - this.
    body_offset: Option<f32>,
    /// The yaw filter over the body's readings (from the first reading on).
    filter: Option<YawFilter>,
    /// The frame before (its brightness, placement and own axis), which the turn between frames is read against.
    previous: Option<PreviousFrame>,
    /// Degrees either side of the body's yaw the colours refine it.
    colour_refine: i32,
}

impl Default for PersonModel {
    fn default() -> Self {
        Self::new()
    }
}

impl PersonModel {
    /// An empty model.
    pub fn new() -> Self {
        let hull = vec![[f32::INFINITY; 2]; HULL_SLICES * HULL_SIDE * HULL_SIDE];
        Self {
            radii: slice_radii(&hull),
            hull,
            seen: vec![0; HULL_SLICES],
            map: vec![[0.0; 4]; MAP_ANGLES * MAP_ROWS],
            reference: None,
            yaw: 0.0,
            velocity: 0.0,
            strikes: [0; BANDS],
            whole_strikes: 0,
            whole_baseline: None,
            band_baseline: [None; BANDS],
            last_refresh: None,
            frames: 0,
            pose: None,
            pose_region: None,
            body_offset: None,
            filter: None,
            previous: None,
            colour_refine: COLOUR_REFINE_DEGREES,
        }
    }

    /// The model reading the person's orientation from the body on every frame with `pose` (one run of the pose
    /// network, [`crate::body::pose::PoseEstimator::track`]); without it (`None`) the yaw comes from the colours
    /// alone.
    pub fn with_pose(mut self, pose: Option<super::SharedPose>) -> Self {
        self.pose = pose;
        self
    }

    /// The model refining the body's yaw by at most `degrees` either side with the colours (0: the body's yaw
    /// alone; [`COLOUR_REFINE_DEGREES`] by default). Without a body reading the colours search
    /// [`SEARCH_DEGREES`] either side of the prediction.
    pub fn with_colour_refine(mut self, degrees: i32) -> Self {
        self.colour_refine = degrees.clamp(0, SEARCH_DEGREES);
        self
    }

    /// Bytes the model holds: fixed, and the frame before's brightness (it does not grow with the frames).
    pub fn memory_bytes(&self) -> usize {
        std::mem::size_of_val(self.hull.as_slice())
            + std::mem::size_of_val(self.seen.as_slice())
            + std::mem::size_of_val(self.map.as_slice())
            + YAW_CELLS * YawFilter::SPEEDS * std::mem::size_of::<f32>()
            + self.previous.as_ref().map_or(0, |p| std::mem::size_of_val(p.brightness.data.as_slice()))
    }

    /// Frames the model has taken since it (re)started.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// Forgets everything (a new shot, a new source size).
    pub fn reset(&mut self) {
        self.hull.iter_mut().for_each(|c| *c = [f32::INFINITY; 2]);
        self.radii = slice_radii(&self.hull);
        self.seen.iter_mut().for_each(|s| *s = 0);
        self.map.iter_mut().for_each(|t| *t = [0.0; 4]);
        self.reference = None;
        self.yaw = 0.0;
        self.velocity = 0.0;
        self.strikes = [0; BANDS];
        self.whole_strikes = 0;
        self.whole_baseline = None;
        self.band_baseline = [None; BANDS];
        self.last_refresh = None;
        self.frames = 0;
        self.pose_region = None;
        self.body_offset = None;
        self.filter = None;
        self.previous = None;
    }

    /// The yaw the model tracked last (degrees).
    pub fn yaw_degrees(&self) -> f32 {
        self.yaw.to_degrees()
    }

    /// How far the hull decides the depth of slice `j` (0: the frame's own guess; 1: the hull), from the directions
    /// it has been seen from.
    fn slice_weight(&self, j: usize) -> f32 {
        coverage_weight(self.seen.get(j).map_or(0, |s| s.count_ones()) as usize)
    }

    /// Takes one prepared frame of the frame path and rewrites it with what the model holds (see the module docs):
    /// its one-shell surfaces, mesh and source view, its back image and the back's side image. A frame without
    /// one-shell surfaces, or without a person, passes unchanged.
    ///
    /// With a pose network ([`PersonModel::with_pose`]) the body's orientation is read on this frame first (one run
    /// of the network, counted in [`ModelFrame::ms`] and [`ModelFrame::pose_ms`]).
    pub fn update(&mut self, prepared: &mut PreparedInput) -> ModelFrame {
        let started = std::time::Instant::now();
        let body = if prepared.surfaces.is_some() { self.read_body(prepared) } else { None };
        let pose_ms = started.elapsed().as_secs_f32() * 1e3;
        self.update_from(prepared, Orientation::Body(body), started, pose_ms)
    }

    /// [`PersonModel::update`] with the body's world landmarks already read on this frame (the pose network's,
    /// [`crate::body::pose::PoseLandmarks::world`], e.g. by the segmenter), or `None` (the yaw from the colours).
    pub fn update_with_world(&mut self, prepared: &mut PreparedInput, world: Option<&[Vec3]>) -> ModelFrame {
        self.update_from(prepared, Orientation::Body(world.and_then(body_yaw)), std::time::Instant::now(), 0.0)
    }

    /// [`PersonModel::update`] with the person's yaw known (degrees, turned since the model (re)started; a
    /// restart on this frame starts again at 0): an evaluation's ground truth, which shows what the model gives with
    /// perfect tracking (`eval --turn --model-body truth`). No body is read; the colours are compared at that yaw only
    /// (for forgetting).
    pub fn update_with_yaw(&mut self, prepared: &mut PreparedInput, yaw_degrees: f32) -> ModelFrame {
        self.update_from(prepared, Orientation::Known(yaw_degrees.to_radians()), std::time::Instant::now(), 0.0)
    }

    /// The update with what this frame says of the person's orientation.
    fn update_from(
        &mut self,
        prepared: &mut PreparedInput,
        orientation: Orientation,
        started: std::time::Instant,
        pose_ms: f32,
    ) -> ModelFrame {
        let (body, known) = match orientation {
            Orientation::Body(body) => (body, None),
            Orientation::Known(yaw) => (None, Some(yaw)),
        };
        let mut out = ModelFrame {
            band_error: [f32::NAN; BANDS],
            band_error_roots: [f32::NAN; BANDS],
            pose_ms,
            ..Default::default()
        };
        let mut stage = StageClock::start();
        let Some(guess) = prepared.surfaces.clone() else { return out };
        let size = prepared.normalised.mask.width;
        let mask = &prepared.normalised.mask;
        if size < 8
            || mask.height != size
            || guess.mask.data.len() != size * size
            || guess.front.data.len() != size * size
            || guess.back.data.len() != size * size
            || prepared.normalised.rgb.data.len() != size * size
        {
            return out;
        }
        let transform = prepared.normalised.transform;
        if !(transform.scale.is_finite() && transform.scale > 0.0 && transform.offset.is_finite()) {
            return out;
        }
        let Some(axis) = axis_column(&guess.mask) else { return out };
        // The axis in photo pixels, smoothed; a new model takes this frame's normalisation as its reference.
        let axis_photo = (axis - transform.offset.x) / transform.scale;
        let reference = match self.reference {
            Some(mut r) => {
                r.axis_photo = 0.5 * r.axis_photo + 0.5 * axis_photo;
                r
            }
            None => Reference { scale: transform.scale, offset_y: transform.offset.y, axis_photo },
        };
        self.reference = Some(reference);
        let k = transform.scale / reference.scale;
        let mut place = Placement {
            size: size as f32,
            k,
            axis: reference.axis_photo * transform.scale + transform.offset.x,
            row_offset: transform.offset.y - k * reference.offset_y,
            yaw: self.yaw + self.velocity,
            frame: prepared.normalised.frame,
        };
        let step = |at_512: usize| (at_512 * size).div_ceil(512).max(1);
        if self.body_offset.is_none() {
            // The first reading: the person is taken to face the camera (the front/back call is the network's
            // weak cue), and the model's yaw so far is kept.
            self.body_offset = body.map(|m| wrap_pi(front_branch(m) - self.yaw));
            self.filter = self.body_offset.map(|_| YawFilter::at(self.yaw));
        }
        // Track the yaw: the body's readings through the yaw filter, refined by the kept colours (without a reading,
        // the colours around the prediction); read each band's difference at it.
        // This frame's brightness: read against the frame before's, then kept for the next.
        let this_brightness = brightness(&prepared.normalised.rgb);
        if self.frames > 0 {
            let mut points = track_points(prepared, &guess, &place, step(TRACK_STEP_512));
            self.hull_depths(&mut points, &place);
            if let Some(yaw) = known {
                place.yaw = yaw;
                out.body_used = true;
            } else if let (Some(filter), Some(offset)) = (self.filter.as_mut(), self.body_offset) {
                // Both readings the image allows go into the filter, with the turn the image shows since the
                // frame before; its most likely yaw is the frame's.
                let reading = body.map(|m| (wrap_pi(m - offset), wrap_pi(std::f32::consts::PI - m - offset)));
                let turned =
                    self.previous.as_ref().and_then(|p| turn_between(p, &this_brightness, &points, &place, axis));
                out.image_turn_degrees = turned.map(f32::to_degrees);
                let yaw = filter.step(reading, turned);
                out.body_yaw_degrees = reading.map(|(a, b)| {
                    let (a, b) = (yaw + wrap_pi(a - yaw), yaw + wrap_pi(b - yaw));
                    if (a - yaw).abs() <= (b - yaw).abs() { a } else { b }.to_degrees()
                });
                out.body_used = reading.is_some();
                place.yaw = yaw;
            }
            let search = match known {
                Some(_) => 0,
                None if out.body_used => self.colour_refine,
                None => SEARCH_DEGREES,
            };
            let coarse = self.track(&points, &place, -search..=search, COARSE_BLUR);
            let fine = coarse
                .filter(|_| search > 0)
                .and_then(|(yaw, _)| self.track(&points, &Placement { yaw, ..place }, -2..=2, 0))
                .filter(|(yaw, _)| (yaw - place.yaw).abs() <= (search as f32).to_radians());
            match fine.or(coarse) {
                Some((yaw, errors)) => {
                    out.tracked = search > 0;
                    out.band_error = errors.linear;
                    out.band_error_roots = errors.roots;
                    place.yaw = if search > 0 { yaw } else { place.yaw };
                }
                None if !out.body_used => self.velocity *= 0.8,
                None => {}
            }
            if out.body_used || out.tracked {
                let limit = MAX_TURN_DEGREES.to_radians();
                self.velocity = if out.body_used {
                    place.yaw - self.yaw
                } else {
                    0.5 * self.velocity + 0.5 * (place.yaw - self.yaw)
                }
                .clamp(-limit, limit);
            }
        }
        stage.lap("track");
        self.forget(&mut out, &mut place, transform, axis_photo);
        if out.restarted {
            self.body_offset = body.map(front_branch);
            self.filter = self.body_offset.map(|_| YawFilter::at(0.0));
        }
        self.yaw = place.yaw;
        // A band that disagrees with the model but is not reset yet keeps what it holds: nothing of this frame is
        // carved or kept there until the next frame says whether it changed.
        let suspect: [bool; BANDS] = std::array::from_fn(|b| self.strikes[b] > 0);
        // Carve with this frame's silhouette and keep its colours when it shows the person from a new direction, else
        // every few frames ([`REFRESH_DEGREES`], [`REFRESH_EVERY`]).
        let refresh = self.last_refresh.is_none_or(|(yaw, frame)| {
            (place.yaw - yaw).abs() >= REFRESH_DEGREES.to_radians() || self.frames >= frame + REFRESH_EVERY
        });
        if refresh {
            let profiles = RowProfiles::of(&guess.mask, &place);
            self.carve(&profiles, &place, &suspect);
            let bin = yaw_bin(place.yaw);
            for j in 0..HULL_SLICES {
                let q = place.row(slice_height(j));
                if !suspect[band_of(slice_height(j))] && q >= place.frame.0.y && q <= place.frame.1.y {
                    self.seen[j] |= 1 << bin;
                }
            }
            self.last_refresh = Some((place.yaw, self.frames));
        }
        stage.lap("carve");
        // Depths: the hull's where it has been seen from enough directions, else the frame's own.
        let Blended { surfaces, hull_weight, hold } = self.blend_depths(&guess, &place, step(RAY_STEP_512));
        out.hull_weight = hull_weight;
        stage.lap("depths");
        let centred = crate::body::placed::centred(surfaces.clone());
        // The mesh beside the colours: keep what this frame sees, then draw the back from the model.
        let (mesh, (gbuffer, back_from_model)) = rayon::join(
            || mesh_from_surfaces(&centred, super::frame::FRAME_MESH_STEP),
            || {
                let gbuffer = source_gbuffer(&centred);
                if refresh {
                    self.keep_colours(prepared, &surfaces, &gbuffer.normal, &hold, &place, &suspect);
                }
                let back = self.back_from_model(prepared, &surfaces, &hold, &place);
                (gbuffer, back)
            },
        );
        out.back_from_model = back_from_model;
        stage.lap("source view, colours kept, back image | mesh");
        if let Ok(mesh) = mesh {
            prepared.mesh = mesh;
            prepared.source_gbuffer = gbuffer;
            prepared.surfaces = Some(centred);
            // The encoder's FOF and the coarse mesh, if any, no longer match the geometry: drop them (the FOF is
            // encoded on demand, the coarse mesh made by `frame::finish_meshes`).
            prepared.fof = None;
            prepared.coarse = None;
        }
        self.previous = Some(PreviousFrame { brightness: this_brightness, place, axis });
        self.frames += 1;
        stage.log();
        out.yaw_degrees = self.yaw.to_degrees();
        out.ms = started.elapsed().as_secs_f32() * 1e3;
        prepared.timings.0.push(("person model", started.elapsed()));
        out
    }

    /// The body's yaw ([`body_yaw`]) from one read of the pose network on the normalised frame, when the model has
    /// one and it finds a torso; keeps the tracking region for the next read.
    fn read_body(&mut self, prepared: &PreparedInput) -> Option<f32> {
        let net = self.pose.as_ref()?;
        let read = {
            let mut net = net.0.lock().ok()?;
            net.track(&prepared.normalised.rgb, &prepared.normalised.mask, self.pose_region)
        };
        match read {
            Ok(Some(landmarks)) => {
                self.pose_region = landmarks.next_region;
                body_yaw(&landmarks.world)
            }
            Ok(None) => {
                self.pose_region = None;
                None
            }
            Err(e) => {
                tracing::debug!("person model: pose read failed: {e}");
                self.pose_region = None;
                None
            }
        }
    }

    /// The forgetting step: bands whose colours disagree for [`RESET_STRIKES`] frames are reset; most of the
    /// bands holding colour at once restart the model on this frame.
    fn forget(
        &mut self,
        out: &mut ModelFrame,
        place: &mut Placement,
        transform: super::input::NormaliseTransform,
        axis_photo: f32,
    ) {
        let mut holding = 0;
        let mut changed = Vec::new();
        for b in 0..BANDS {
            let e = out.band_error[b];
            if e.is_nan() {
                self.strikes[b] = 0;
                continue;
            }
            holding += 1;
            if e > RESET_COLOUR_ERROR {
                self.strikes[b] = self.strikes[b].saturating_add(1);
                if self.strikes[b] >= RESET_STRIKES {
                    changed.push(b);
                }
            } else {
                self.strikes[b] = 0;
            }
        }
        let errors: Vec<f32> = out.band_error_roots.iter().copied().filter(|e| !e.is_nan()).collect();
        let whole = errors.iter().sum::<f32>() / errors.len().max(1) as f32;
        // Changed: well above what this person's frames have differed by so far (a textured garment a few degrees
        // off the tracked yaw differs a lot all the time), and above a floor; before the first unchanged frame there
        // is no usual difference: the bands' own threshold. And broadly: most bands jumped (a top taken off changes
        // the torso's bands and leaves the legs', which then stay; their bands are reset one by one).
        let limit = self.whole_baseline.map_or(RESET_COLOUR_ERROR, |b| RESTART_COLOUR_ERROR.max(RESTART_JUMP * b));
        let mut jumped = 0;
        for (b, &e) in out.band_error_roots.iter().enumerate().filter(|(_, e)| !e.is_nan()) {
            let base = self.band_baseline[b];
            let jump = base.is_none_or(|base| e > RESTART_BAND_JUMP * base);
            jumped += usize::from(jump);
            // A jump does not move the usual difference (the first value starts it).
            if !jump || base.is_none() {
                self.band_baseline[b] = Some(usual_difference(base, e));
            }
        }
        let broadly = 4 * jumped >= 3 * errors.len();
        let changed_whole = holding > 0 && whole > limit && broadly;
        self.whole_strikes = if changed_whole { self.whole_strikes + 1 } else { 0 };
        if holding > 0 && !changed_whole {
            self.whole_baseline = Some(usual_difference(self.whole_baseline, whole));
        }
        if self.whole_strikes > 0 && self.whole_strikes < RESET_STRIKES {
            // The whole person may have changed: every band waits for the next frame.
            self.strikes.iter_mut().for_each(|s| *s = (*s).max(1));
        }
        if changed.is_empty() && self.whole_strikes < RESET_STRIKES {
            return;
        }
        if 2 * changed.len() >= holding || self.whole_strikes >= RESET_STRIKES {
            // Another person (or the same one changed everywhere): start again from this frame.
            self.reset();
            self.reference = Some(Reference { scale: transform.scale, offset_y: transform.offset.y, axis_photo });
            place.k = 1.0;
            place.row_offset = 0.0;
            place.yaw = 0.0;
            place.axis = axis_photo * transform.scale + transform.offset.x;
            out.restarted = true;
            out.reset_bands = (0..BANDS).collect();
            return;
        }
        for &b in &changed {
            self.reset_band(b);
            self.strikes[b] = 0;
        }
        out.reset_bands = changed;
    }

    /// Forgets band `b`: its hull slices, their directions, its colour rows and its usual difference.
    fn reset_band(&mut self, b: usize) {
        self.band_baseline[b] = None;
        self.last_refresh = None;
        let cells = HULL_SIDE * HULL_SIDE;
        for j in (0..HULL_SLICES).filter(|&j| band_of(slice_height(j)) == b) {
            self.hull[j * cells..(j + 1) * cells].iter_mut().for_each(|c| *c = [f32::INFINITY; 2]);
            self.seen[j] = 0;
        }
        self.radii = slice_radii(&self.hull);
        for row in (0..MAP_ROWS).filter(|&r| band_of(map_height(r)) == b) {
            self.map[row * MAP_ANGLES..(row + 1) * MAP_ANGLES].iter_mut().for_each(|t| *t = [0.0; 4]);
        }
    }

    /// Moves each tracked point's depth (the frame's guess) toward the hull's front at the predicted yaw, as far
    /// as its slice is measured ([`PersonModel::slice_weight`]): the angle a point has about the axis depends on
    /// its depth, and the guess is only a guess.
    fn hull_depths(&self, points: &mut [TrackPoint], place: &Placement) {
        let radii = &self.radii;
        points.par_iter_mut().for_each(|p| {
            let Some(j) = slice_of(p.y) else { return };
            let weight = self.slice_weight(j);
            if weight <= 0.0 {
                return;
            }
            if let Some((front, _)) = self.ray(j, p.x, place, radii[j]) {
                p.z = weight * front + (1.0 - weight) * p.z;
            }
        });
    }

    /// The yaw that fits `points` best to the kept colours among the candidates `range` (whole degrees) around
    /// `place.yaw`, refined by a parabola, with each band's mean difference there; `None` when the model holds too
    /// few of the points' colours. With `blur` (texels either side around the cylinder) the points' blurred colours
    /// are matched to the kept colours averaged as wide: the coarse step, which a striped garment's period does not
    /// fool.
    fn track(
        &self,
        points: &[TrackPoint],
        place: &Placement,
        range: std::ops::RangeInclusive<i32>,
        blur: usize,
    ) -> Option<(f32, BandErrors)> {
        if points.is_empty() {
            return None;
        }
        let first = *range.start();
        let candidates: Vec<(f32, usize, BandErrors)> = range
            .into_par_iter()
            .map(|d| {
                let yaw = place.yaw + (d as f32).to_radians();
                let p = Placement { yaw, ..*place }.turn();
                let (mut sum, mut n) = (0.0f32, 0usize);
                let (mut band_sum, mut band_n) = ([0.0f32; BANDS], [0usize; BANDS]);
                let mut band_root_sum = [0.0f32; BANDS];
                for pt in points {
                    let (u, w) = p.model_of(pt.x, pt.z);
                    let Some(kept) = self.colour_at(u, w, pt.y, blur) else { continue };
                    let seen = if blur > 0 { pt.blurred } else { pt.rgb };
                    let e = (seen - kept).abs().element_sum() / 3.0;
                    sum += e;
                    n += 1;
                    band_sum[pt.band] += e;
                    let root = |v: Vec3| v.max(Vec3::ZERO).powf(0.5);
                    band_root_sum[pt.band] += (root(seen) - root(kept)).abs().element_sum() / 3.0;
                    band_n[pt.band] += 1;
                }
                let mean = if n > 0 { sum / n as f32 } else { f32::INFINITY };
                let (mut band, mut roots) = ([f32::NAN; BANDS], [f32::NAN; BANDS]);
                for b in 0..BANDS {
                    if band_n[b] >= MIN_BAND_SAMPLES {
                        band[b] = band_sum[b] / band_n[b] as f32;
                        roots[b] = band_root_sum[b] / band_n[b] as f32;
                    }
                }
                (mean, n, BandErrors { linear: band, roots })
            })
            .collect();
        let most = candidates.iter().map(|c| c.1).max().unwrap_or(0);
        if most < (points.len() / 8).max(MIN_BAND_SAMPLES) {
            return None;
        }
        // Among candidates matching at least half as many points as the best-covered one.
        let score = |i: usize| {
            let c = &candidates[i];
            if 2 * c.1 >= most {
                c.0
            } else {
                f32::INFINITY
            }
        };
        let best = (0..candidates.len()).min_by(|&a, &b| score(a).total_cmp(&score(b)))?;
        if !score(best).is_finite() {
            return None;
        }
        let mut offset = (best as i32 + first) as f32;
        if best > 0 && best + 1 < candidates.len() {
            let (a, b, c) = (score(best - 1), score(best), score(best + 1));
            let denom = a - 2.0 * b + c;
            if a.is_finite() && c.is_finite() && denom > 1e-9 {
                offset += (0.5 * (a - c) / denom).clamp(-0.5, 0.5);
            }
        }
        Some((place.yaw + offset.to_radians(), candidates[best].2))
    }

    /// The kept colour at model `(u, w)` and height `y`: the mean of the texels held with at least half the full
    /// confidence among `blur` texels either side around the cylinder; `None` where none is.
    fn colour_at(&self, u: f32, w: f32, y: f32, blur: usize) -> Option<Vec3> {
        let centre = texel_index(u, w, y)?;
        let (row, col) = (centre / MAP_ANGLES, centre % MAP_ANGLES);
        let (mut sum, mut n) = (Vec3::ZERO, 0.0f32);
        for k in 0..=2 * blur {
            let c = (col + MAP_ANGLES + k - blur) % MAP_ANGLES;
            let t = &self.map[row * MAP_ANGLES + c];
            if t[3] >= MAP_FULL_WEIGHT * 0.5 {
                sum += Vec3::new(t[0], t[1], t[2]);
                n += 1.0;
            }
        }
        (n > 0.0).then(|| sum / n)
    }

    /// The colour texel at model `(u, w)` and height `y`.
    fn texel(&self, u: f32, w: f32, y: f32) -> Option<&[f32; 4]> {
        self.map.get(texel_index(u, w, y)?)
    }

    /// Carves every slice the current frame shows with its silhouette rows (not those of `suspect` bands).
    fn carve(&mut self, profiles: &RowProfiles, place: &Placement, suspect: &[bool; BANDS]) {
        let cells = HULL_SIDE * HULL_SIDE;
        // The camera-aligned x of every cell (the same on every slice).
        let xs: Vec<f32> = (0..cells)
            .map(|i| {
                let (u, w) = (cell_centre(i % HULL_SIDE), cell_centre(i / HULL_SIDE));
                place.camera_x(u, w)
            })
            .collect();
        let px = place.px();
        self.hull.par_chunks_mut(cells).enumerate().for_each(|(j, slice)| {
            if suspect[band_of(slice_height(j))] {
                return;
            }
            let q = place.row(slice_height(j));
            let Some(row) = profiles.row(q) else { return };
            for (cell, &x) in slice.iter_mut().zip(&xs) {
                let d = row.at(place.axis + x * px) / px + CARVE_MARGIN;
                if d < cell[0] {
                    cell[1] = cell[0];
                    cell[0] = d;
                } else if d < cell[1] {
                    cell[1] = d;
                }
            }
        });
        self.radii = slice_radii(&self.hull);
    }

    /// The hull's field on slice `j` at model `(u, w)` (bilinear; outside the slice: empty).
    fn field(&self, j: usize, u: f32, w: f32) -> f32 {
        let n = HULL_SIDE as f32;
        let (fx, fz) = ((u + HULL_HALF) / (2.0 * HULL_HALF) * n - 0.5, (w + HULL_HALF) / (2.0 * HULL_HALF) * n - 0.5);
        if !(fx >= 0.0 && fz >= 0.0 && fx <= n - 1.0 && fz <= n - 1.0) {
            return -1.0;
        }
        let (c0, r0) = (fx as usize, fz as usize);
        let (c1, r1) = ((c0 + 1).min(HULL_SIDE - 1), (r0 + 1).min(HULL_SIDE - 1));
        let (tx, tz) = (fx - c0 as f32, fz - r0 as f32);
        let base = j * HULL_SIDE * HULL_SIDE;
        let v = |c: usize, r: usize| self.hull[base + r * HULL_SIDE + c][1].clamp(-1.0, 1.0);
        let top = v(c0, r0) * (1.0 - tx) + v(c1, r0) * tx;
        let bottom = v(c0, r1) * (1.0 - tx) + v(c1, r1) * tx;
        top * (1.0 - tz) + bottom * tz
    }

    /// The hull's front and back (camera-aligned z about the axis, model units) along the ray at camera-aligned
    /// `x` through slice `j`; `None` when the ray misses it.
    /// `radius`: how far from the axis the slice's hull reaches ([`slice_radii`]); the ray is
    /// marched only within it.
    fn ray(&self, j: usize, x: f32, place: &Placement, radius: f32) -> Option<(f32, f32)> {
        if x.is_nan() || radius.is_nan() || x.abs() >= radius {
            return None;
        }
        let reach = (radius * radius - x * x).sqrt();
        let step = 2.0 * HULL_HALF / HULL_SIDE as f32;
        let steps = (2.0 * reach / step).ceil() as usize;
        let turn = place.turn();
        let at = |z: f32| {
            let (u, w) = turn.model_of(x, z);
            self.field(j, u, w)
        };
        let crossing = |from: f32, dir: f32| -> Option<f32> {
            let mut prev = at(from);
            if prev > 0.0 {
                return Some(from);
            }
            for s in 1..=steps {
                let z = from + dir * s as f32 * step;
                let v = at(z);
                if v > 0.0 {
                    let t = prev / (prev - v);
                    return Some(z - dir * step * (1.0 - t));
                }
                prev = v;
            }
            None
        };
        let front = crossing(reach, -1.0)?;
        let back = crossing(-reach, 1.0)?;
        (front >= back).then_some((front, back))
    }

    /// The frame's surfaces with the hull's depths blended in, the mean weight over the silhouette, and per pixel
    /// how far the model holds it ([`Blended::hold`]).
    ///
    /// The weight is the slice's ([`PersonModel::slice_weight`]) times how far the pixel lies inside the part of the
    /// current silhouette the hull covers: a ray through a measured slice that misses the hull is where the
    /// person no longer matches what the other frames carved (an arm that has moved, a yaw off), and there the
    /// frame keeps its own depths, fading to the hull's over [`AGREE_RAMP`] rays. The frame's own depths are
    /// shifted by the median difference to the hull's where both hold, so that the two join without a step.
    fn blend_depths(&self, guess: &InflatedSurfaces, place: &Placement, step: usize) -> Blended {
        let size = guess.mask.width;
        let mut out = guess.clone();
        let (gw, gh) = (size.div_ceil(step), size.div_ceil(step));
        let px = place.px();
        let radii = &self.radii;
        // A hull cell in pixels: the hull's outline falls up to about that far inside the silhouette's on a row.
        let rim = (px * 2.0 * HULL_HALF / HULL_SIDE as f32).ceil().max(1.0) as usize;
        // Rays on a coarse grid of pixel centres, over the rows and columns that hold the person: `Some(None)` a
        // measured ray that missed the hull deeper inside the silhouette than its rim, `None` no ray (outside, or
        // the slice not measured) or a miss at the rim.
        let grid: Vec<Option<Option<(f32, f32)>>> = (0..gw * gh)
            .into_par_iter()
            .map(|i| {
                let (c, r) = ((i % gw) * step, (i / gw) * step);
                let near = (r.saturating_sub(step)..(r + step + 1).min(size)).any(|rr| {
                    (c.saturating_sub(step)..(c + step + 1).min(size)).any(|cc| guess.mask.data[rr * size + cc] > 0.5)
                });
                if !near {
                    return None;
                }
                let q = r as f32 + 0.5;
                let j = slice_of(place.height(q))?;
                if self.slice_weight(j) <= 0.0 {
                    return None;
                }
                let x = (c as f32 + 0.5 - place.axis) / px;
                let row = &guess.mask.data[r.min(size - 1) * size..(r.min(size - 1) + 1) * size];
                let inside = (0..=rim).all(|d| {
                    c.checked_sub(d).is_some_and(|cc| row[cc] > 0.5) && row.get(c + d).is_some_and(|&m| m > 0.5)
                });
                match self.ray(j, x, place, radii[j]) {
                    Some((f, b)) => Some(Some((f * place.k, b * place.k))),
                    None if inside => Some(None),
                    None => None,
                }
            })
            .collect();
        // Per ray, how far it lies inside the hull's cover: 1 at AGREE_RAMP rays or more from a ray that missed,
        // falling to 0 at the miss (a chamfer distance over the grid).
        let mut reach = vec![f32::INFINITY; gw * gh];
        for (k, g) in grid.iter().enumerate() {
            if matches!(g, Some(None)) {
                reach[k] = 0.0;
            }
        }
        chamfer(&mut reach, gw, gh);
        let agree_grid: Vec<f32> = reach.iter().map(|&d| (d / AGREE_RAMP).clamp(0.0, 1.0)).collect();
        // The frame's depths joined to the hull's: the median of their difference where both are sure.
        let mut shifts: Vec<f32> = Vec::new();
        for gr in 0..gh {
            for gc in 0..gw {
                let k = gr * gw + gc;
                let (c, r) = (gc * step, gr * step);
                if let (Some(Some((hf, hb))), true) = (grid[k], agree_grid[k] >= 1.0) {
                    let i = r * size + c;
                    if r < size && c < size && guess.mask.data[i] > 0.5 {
                        shifts.push(0.5 * (hf + hb) - 0.5 * (guess.front.data[i] + guess.back.data[i]));
                    }
                }
            }
        }
        let shift = if shifts.len() >= 8 {
            let mid = shifts.len() / 2;
            *shifts.select_nth_unstable_by(mid, f32::total_cmp).1
        } else {
            0.0
        };
        let shift = if shift.is_finite() { shift } else { 0.0 };
        let mut hold = vec![0.0f32; size * size];
        let (weight_sum, count) = out
            .front
            .data
            .par_chunks_mut(size)
            .zip(out.back.data.par_chunks_mut(size))
            .zip(hold.par_chunks_mut(size))
            .enumerate()
            .map(|(r, ((front_row, back_row), hold_row))| {
                let q = r as f32 + 0.5;
                let slice = slice_of(place.height(q)).map_or(0.0, |j| self.slice_weight(j));
                let (mut weight_sum, mut count) = (0.0f32, 0usize);
                for c in 0..size {
                    let i = r * size + c;
                    if guess.mask.data[i] <= 0.5 {
                        continue;
                    }
                    count += 1;
                    hold_row[c] = 1.0;
                    if slice <= 0.0 {
                        continue;
                    }
                    // The frame's own depths, joined to the hull's.
                    let (gf, gb) = (guess.front.data[i] + shift, guess.back.data[i] + shift);
                    front_row[c] = gf.clamp(-1.0, 1.0);
                    back_row[c] = gb.clamp(-1.0, 1.0).min(front_row[c]);
                    // Bilinear between the coarse rays, over the ones that hit.
                    let (gx, gy) = (c as f32 / step as f32, r as f32 / step as f32);
                    let (x0, y0) = (gx.floor() as usize, gy.floor() as usize);
                    let (tx, ty) = (gx - x0 as f32, gy - y0 as f32);
                    let (mut f, mut b, mut a, mut wsum, mut all) = (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
                    for (dx, dy, wt) in [
                        (0, 0, (1.0 - tx) * (1.0 - ty)),
                        (1, 0, tx * (1.0 - ty)),
                        (0, 1, (1.0 - tx) * ty),
                        (1, 1, tx * ty),
                    ] {
                        let (xx, yy) = (x0 + dx, y0 + dy);
                        if xx >= gw || yy >= gh || wt <= 0.0 {
                            continue;
                        }
                        let k = yy * gw + xx;
                        match grid[k] {
                            Some(Some((hf, hb))) => {
                                f += wt * hf;
                                b += wt * hb;
                                a += wt * agree_grid[k];
                                wsum += wt;
                                all += wt;
                            }
                            Some(None) => all += wt,
                            None => {}
                        }
                    }
                    // Rays that missed around this pixel count as disagreeing.
                    let here = if all > 0.0 { (a / all).clamp(0.0, 1.0) } else { 1.0 };
                    hold_row[c] = 1.0 - slice * (1.0 - here);
                    if wsum < 1e-3 {
                        continue;
                    }
                    let (hf, hb) = (f / wsum, b / wsum);
                    if !(hf.is_finite() && hb.is_finite()) {
                        continue;
                    }
                    let weight = slice * here;
                    weight_sum += weight;
                    let front = weight * hf + (1.0 - weight) * gf;
                    let back = weight * hb + (1.0 - weight) * gb;
                    front_row[c] = front.clamp(-1.0, 1.0);
                    back_row[c] = back.clamp(-1.0, 1.0).min(front_row[c]);
                }
                (weight_sum, count)
            })
            .reduce(|| (0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
        Blended { surfaces: out, hull_weight: if count > 0 { weight_sum / count as f32 } else { 0.0 }, hold }
    }

    /// Keeps the colours this frame shows on its front (depths `surfaces`, about the axis; source-view normals
    /// `normals`), each with the confidence of how squarely the camera saw it, as far as the model holds the
    /// pixel (`hold`, [`Blended::hold`]: not where a limb has moved off the hull); `suspect` bands keep what they
    /// hold.
    fn keep_colours(
        &mut self,
        prepared: &PreparedInput,
        surfaces: &InflatedSurfaces,
        normals: &[Vec3],
        hold: &[f32],
        place: &Placement,
        suspect: &[bool; BANDS],
    ) {
        let size = surfaces.mask.width;
        let mask = &prepared.normalised.mask;
        let rgb = &prepared.normalised.rgb;
        let px = place.px();
        let turn = place.turn();
        // A pixel row's colours go to one row of texels: the rows of texels are kept in parallel, each from the
        // pixel rows that fall on it.
        let mut rows_of: Vec<Vec<usize>> = vec![Vec::new(); MAP_ROWS];
        for r in 1..size.saturating_sub(1) {
            let y = place.height(r as f32 + 0.5);
            let t = (1.0 - y) * 0.5 * MAP_ROWS as f32;
            if !suspect[band_of(y)] && t.is_finite() && t >= 0.0 && t < MAP_ROWS as f32 {
                rows_of[t as usize].push(r);
            }
        }
        self.map.par_chunks_mut(MAP_ANGLES).zip(rows_of.par_iter()).for_each(|(texels, rows)| {
            for &r in rows {
                let y = place.height(r as f32 + 0.5);
                for c in 1..size - 1 {
                    let i = r * size + c;
                    // Inside, away from the outline (the rim's colours are the background's as much as the
                    // person's).
                    if mask.data[i] < 0.99 || [i - 1, i + 1, i - size, i + size].iter().any(|&n| mask.data[n] < 0.99) {
                        continue;
                    }
                    let nz = normals.get(i).map_or(0.0, |n| n.z);
                    let confidence = nz * nz * hold.get(i).copied().unwrap_or(0.0);
                    if confidence.is_nan() || confidence <= 0.25 {
                        continue;
                    }
                    let x = (c as f32 + 0.5 - place.axis) / px;
                    let z = surfaces.front.data[i] / place.k;
                    let (u, w) = turn.model_of(x, z);
                    let Some(t) = texel_index(u, w, y) else { continue };
                    let colour = rgb.data[i] / mask.data[i].max(1e-3);
                    if !colour.is_finite() {
                        continue;
                    }
                    let texel = &mut texels[t % MAP_ANGLES];
                    let total = texel[3] + confidence;
                    for ch in 0..3 {
                        texel[ch] = (texel[ch] * texel[3] + colour[ch] * confidence) / total;
                    }
                    texel[3] = total.min(MAP_MAX_WEIGHT);
                }
            }
        });
    }

    /// Draws the back image from the kept colours at the back surface (depths `surfaces`, about the axis) where
    /// the model holds them, over today's fill (or the photo itself when there is none); rewrites the back's side
    /// image to match; as far as the model holds the pixel (`hold`, [`Blended::hold`]). Returns the fraction of the
    /// silhouette's pixels that took the model's colours.
    fn back_from_model(
        &self,
        prepared: &mut PreparedInput,
        surfaces: &InflatedSurfaces,
        hold: &[f32],
        place: &Placement,
    ) -> f32 {
        let size = surfaces.mask.width;
        let px = place.px();
        let turn = place.turn();
        let mask = &prepared.normalised.mask;
        let had_back = prepared.back.is_some();
        let mut back = match prepared.back.take() {
            Some(b) => b,
            None => BackImage { rgb: prepared.normalised.rgb.clone(), head: GrayImage::new(size, size, 0.0) },
        };
        if back.rgb.data.len() != size * size || back.head.data.len() != size * size || mask.data.len() != size * size {
            prepared.back = had_back.then_some(back);
            return 0.0;
        }
        let (taken, inside) = back
            .rgb
            .data
            .par_chunks_mut(size)
            .zip(back.head.data.par_chunks_mut(size))
            .enumerate()
            .map(|(r, (rgb, head))| {
                let y = place.height(r as f32 + 0.5);
                let (mut taken, mut inside) = (0usize, 0usize);
                for c in 0..size {
                    let i = r * size + c;
                    let m = mask.data[i];
                    if m <= 0.0 {
                        continue;
                    }
                    inside += 1;
                    let x = (c as f32 + 0.5 - place.axis) / px;
                    let z = surfaces.back.data[i] / place.k;
                    let (u, w) = turn.model_of(x, z);
                    let Some(t) = self.texel(u, w, y) else { continue };
                    let a = (t[3] / MAP_FULL_WEIGHT).clamp(0.0, 1.0) * hold.get(i).copied().unwrap_or(0.0);
                    if a <= 0.0 {
                        continue;
                    }
                    let kept = Vec3::new(t[0], t[1], t[2]) * m;
                    rgb[c] = rgb[c] * (1.0 - a) + kept * a;
                    head[c] *= 1.0 - a;
                    taken += 1;
                }
                (taken, inside)
            })
            .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
        if taken > 0 {
            // On the frame path's grid for side images (a blur of 4 px at 512² loses nothing twice as coarse).
            let mask = &prepared.normalised.mask;
            let side = super::warp::SideImages::with_back_side(&back.rgb, None, mask, super::frame::FRAME_SIDE_FACTOR);
            prepared.side.back = Some(side.rgb);
        }
        // Untouched, a frame without a back image keeps none.
        prepared.back = (had_back || taken > 0).then_some(back);
        if inside > 0 {
            taken as f32 / inside as f32
        } else {
            0.0
        }
    }
}

/// Per slice of `hull`, how far from the axis its hull can reach (model units): past the farthest cell inside it by
/// the field's interpolation (a cell's diagonal); 0 for a slice carved away.
fn slice_radii(hull: &[[f32; 2]]) -> Vec<f32> {
    let cells = HULL_SIDE * HULL_SIDE;
    let diagonal = 2.0 * HULL_HALF / HULL_SIDE as f32 * std::f32::consts::SQRT_2;
    hull.par_chunks(cells)
        .map(|slice| {
            let mut far = f32::NEG_INFINITY;
            for (i, cell) in slice.iter().enumerate() {
                if cell[1] > 0.0 {
                    let (u, w) = (cell_centre(i % HULL_SIDE), cell_centre(i / HULL_SIDE));
                    far = far.max(u * u + w * w);
                }
            }
            if far.is_finite() {
                far.sqrt() + diagonal
            } else {
                0.0
            }
        })
        .collect()
}

/// What a frame says of the person's orientation ([`PersonModel::update_from`]).
#[derive(Clone, Copy, Debug)]
enum Orientation {
    /// The body's yaw read on this frame (radians, [`body_yaw`]), if any: through the yaw filter.
    Body(Option<f32>),
    /// The yaw known (radians, since the model (re)started).
    Known(f32),
}

/// A filter over the person's yaw from the body's readings: a probability over [`YAW_CELLS`] yaws around the turn
/// and `2 YAW_SPEEDS + 1` turning speeds. Each frame it moves every yaw by its speed (plus a drift of a cell, and
/// the speed changing by a step now and then), then weighs each yaw by the reading: both branches the image
/// allows (the turn and its front/back mirror, which the pose network confuses away from profile) count the same,
/// so the branch is decided by the motion (a person turning on keeps turning: the mirror branch would need the
/// speed to reverse where the two branches cross, at profile). Its yaw is the most likely cell, refined between
/// its neighbours, unwrapped next to the last.
#[derive(Clone, Debug)]
struct YawFilter {
    /// Per yaw cell, per speed: the probability.
    p: Vec<f32>,
    /// The last yaw (radians, unwrapped).
    yaw: f32,
}

impl YawFilter {
    const SPEEDS: usize = 2 * YAW_SPEEDS as usize + 1;

    /// A filter sure of `yaw` (radians), every speed alike.
    fn at(yaw: f32) -> Self {
        let mut p = vec![0.0; YAW_CELLS * Self::SPEEDS];
        let cell = Self::cell_of(yaw);
        p[cell * Self::SPEEDS..(cell + 1) * Self::SPEEDS].iter_mut().for_each(|v| *v = 1.0 / Self::SPEEDS as f32);
        Self { p, yaw }
    }

    fn cell_of(yaw: f32) -> usize {
        let c = (yaw.rem_euclid(std::f32::consts::TAU) / std::f32::consts::TAU * YAW_CELLS as f32).round();
        if c.is_finite() {
            (c as usize) % YAW_CELLS
        } else {
            0
        }
    }

    /// One frame: the motion, then the reading's two branches `(a, b)` (radians), if any. Returns the yaw.
    fn step(&mut self, reading: Option<(f32, f32)>, turned: Option<f32>) -> f32 {
        let (n, s) = (YAW_CELLS, Self::SPEEDS);
        let mut moved = vec![0.0f32; n * s];
        for y in 0..n {
            for v in 0..s {
                let speed = v as i64 - YAW_SPEEDS as i64;
                let to = (y as i64 + speed).rem_euclid(n as i64) as usize;
                let mass = self.p[y * s + v];
                // Drift a cell either way.
                moved[to * s + v] += (1.0 - 2.0 * YAW_DRIFT) * mass;
                moved[((to + 1) % n) * s + v] += YAW_DRIFT * mass;
                moved[((to + n - 1) % n) * s + v] += YAW_DRIFT * mass;
            }
        }
        let change = 0.5 * (1.0 - KEEP_SPEED);
        for y in 0..n {
            let row = &moved[y * s..(y + 1) * s];
            for v in 0..s {
                let slower = if v > 0 { row[v - 1] } else { row[v] };
                let faster = if v + 1 < s { row[v + 1] } else { row[v] };
                self.p[y * s + v] = KEEP_SPEED * row[v] + change * (slower + faster);
            }
        }
        if let Some(turned) = turned.filter(|t| t.is_finite()) {
            // The speed is this frame's turn: each speed weighed by the image's, whatever the yaw (the image's turn
            // is the same on either branch of the body's reading, so it tells them apart where they cross).
            let spread = 2.0 * FLOW_SIGMA_DEGREES.to_radians().powi(2);
            let cell = std::f32::consts::TAU / n as f32;
            let weights: Vec<f32> = (0..s)
                .map(|v| {
                    let speed = (v as f32 - YAW_SPEEDS as f32) * cell;
                    FLOW_OUTLIER + (-(speed - turned).powi(2) / spread).exp()
                })
                .collect();
            for y in 0..n {
                self.p[y * s..(y + 1) * s].iter_mut().zip(&weights).for_each(|(p, w)| *p *= w);
            }
        }
        if let Some((a, b)) = reading.filter(|(a, b)| a.is_finite() && b.is_finite()) {
            let spread = 2.0 * BODY_SIGMA_DEGREES.to_radians().powi(2);
            for y in 0..n {
                let at = y as f32 * std::f32::consts::TAU / n as f32;
                let near = |r: f32| (-wrap_pi(at - r).powi(2) / spread).exp();
                let weight = BODY_OUTLIER + near(a) + near(b);
                self.p[y * s..(y + 1) * s].iter_mut().for_each(|v| *v *= weight);
            }
        }
        let total: f32 = self.p.iter().sum();
        if !(total.is_finite() && total > 0.0) {
            *self = Self::at(self.yaw);
            return self.yaw;
        }
        self.p.iter_mut().for_each(|v| *v /= total);
        let marginal: Vec<f32> = (0..n).map(|y| self.p[y * s..(y + 1) * s].iter().sum()).collect();
        let best = (0..n).max_by(|&a, &b| marginal[a].total_cmp(&marginal[b])).unwrap_or(0);
        let (mut offset, mut weight) = (0.0f32, 0.0f32);
        for d in -2i64..=2 {
            let m = marginal[(best as i64 + d).rem_euclid(n as i64) as usize];
            offset += d as f32 * m;
            weight += m;
        }
        let cell = best as f32 + if weight > 0.0 { offset / weight } else { 0.0 };
        let yaw = cell * std::f32::consts::TAU / n as f32;
        self.yaw += wrap_pi(yaw - self.yaw);
        self.yaw
    }
}

/// The torso's yaw (radians) from the pose network's world landmarks (x right, y up, z toward the camera): the
/// angle about the vertical of the torso's normal `(left - right) x (shoulders - hips)` (both shoulders and both
/// hips), 0 facing the camera, positive turned toward the image's right (the model's convention: the front's
/// centre moves to `x = sin(yaw)`). `None` when the landmarks are missing, not finite, or the normal is nearly
/// vertical.
pub fn body_yaw(world: &[Vec3]) -> Option<f32> {
    use crate::body::pose::index::{LEFT_HIP, LEFT_SHOULDER, RIGHT_HIP, RIGHT_SHOULDER};
    let w = |i: usize| world.get(i).copied().filter(|v| v.is_finite());
    let (ls, rs, lh, rh) = (w(LEFT_SHOULDER)?, w(RIGHT_SHOULDER)?, w(LEFT_HIP)?, w(RIGHT_HIP)?);
    let normal = ((ls - rs) + (lh - rh)).cross((ls + rs) - (lh + rh));
    let horizontal = (normal.x * normal.x + normal.z * normal.z).sqrt();
    (horizontal.is_finite() && horizontal > 0.3 * normal.length() && horizontal > 1e-6)
        .then(|| normal.x.atan2(normal.z))
}

/// `a` wrapped to `[-pi, pi)`.
fn wrap_pi(a: f32) -> f32 {
    use std::f32::consts::{PI, TAU};
    (a + PI).rem_euclid(TAU) - PI
}

/// The reading of yaw `m` (radians) that faces the camera: `m` itself within 90 degrees of the camera, else its
/// front/back mirror `pi - m` (the pose network's depth-mirrored read: same image, sides swapped).
fn front_branch(m: f32) -> f32 {
    if wrap_pi(m).abs() <= std::f32::consts::FRAC_PI_2 {
        wrap_pi(m)
    } else {
        wrap_pi(std::f32::consts::PI - m)
    }
}

/// How far the hull decides a slice's depths once it has been seen from `bins` of the [`YAW_BINS`] directions: 0
/// up to a quarter of them, 1 from three quarters on, smooth between (a slice seen only from the front and its
/// mirror says nothing about its depth; seen from most directions, its thickness is measured).
pub fn coverage_weight(bins: usize) -> f32 {
    let t = ((bins as f32 / YAW_BINS as f32 - 0.25) / 0.5).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// The [`YAW_BINS`] bin of `yaw` (radians) modulo half a turn.
fn yaw_bin(yaw: f32) -> usize {
    let t = yaw.rem_euclid(std::f32::consts::PI) / std::f32::consts::PI;
    ((t * YAW_BINS as f32) as usize).min(YAW_BINS - 1)
}

/// Model height of slice `j`'s centre.
fn slice_height(j: usize) -> f32 {
    1.0 - (j as f32 + 0.5) * 2.0 / HULL_SLICES as f32
}

/// The slice holding model height `y`.
fn slice_of(y: f32) -> Option<usize> {
    let f = (1.0 - y) * 0.5 * HULL_SLICES as f32;
    (f.is_finite() && f >= 0.0 && f < HULL_SLICES as f32).then_some(f as usize)
}

/// Model height of colour row `r`'s centre.
fn map_height(r: usize) -> f32 {
    1.0 - (r as f32 + 0.5) * 2.0 / MAP_ROWS as f32
}

/// The band of model height `y` (0 at the top).
fn band_of(y: f32) -> usize {
    (((1.0 - y) * 0.5 * BANDS as f32).max(0.0) as usize).min(BANDS - 1)
}

/// Centre of hull cell `i` along one horizontal axis (model units).
fn cell_centre(i: usize) -> f32 {
    -HULL_HALF + (i as f32 + 0.5) * 2.0 * HULL_HALF / HULL_SIDE as f32
}

/// The colour texel of model `(u, w)` and height `y`: the angle about the axis (0 = the model's front) and the
/// height.
fn texel_index(u: f32, w: f32, y: f32) -> Option<usize> {
    let row = (1.0 - y) * 0.5 * MAP_ROWS as f32;
    if !(row.is_finite() && row >= 0.0 && row < MAP_ROWS as f32 && u.is_finite() && w.is_finite()) {
        return None;
    }
    let a = fast_atan2(u, w) / std::f32::consts::TAU + 0.5;
    let col = ((a * MAP_ANGLES as f32) as usize) % MAP_ANGLES;
    Some(row as usize * MAP_ANGLES + col)
}

/// `y.atan2(x)` to within 0.0015 radians (a fifth of a colour texel), several times cheaper: the angle is taken
/// for every pixel of every frame. 0 for a zero vector.
fn fast_atan2(y: f32, x: f32) -> f32 {
    use std::f32::consts::{FRAC_PI_2, PI};
    let (ax, ay) = (x.abs(), y.abs());
    let (lo, hi) = (ax.min(ay), ax.max(ay));
    if hi <= 0.0 || !(x.is_finite() && y.is_finite()) {
        return 0.0;
    }
    let t = lo / hi;
    let t2 = t * t;
    // A minimax polynomial for atan on [0, 1].
    let mut a = t * (0.999_866 + t2 * (-0.330_299_5 + t2 * (0.180_141 + t2 * (-0.085_133 + t2 * 0.020_835_1))));
    if ay > ax {
        a = FRAC_PI_2 - a;
    }
    if x < 0.0 {
        a = PI - a;
    }
    if y < 0.0 {
        -a
    } else {
        a
    }
}

/// The column of the person's vertical axis: the median column of the silhouette's torso rows (from 30 % to 55 %
/// of its height from the top), where arms and feet weigh least. `None` for an empty mask.
fn axis_column(mask: &GrayImage) -> Option<f32> {
    let (w, h) = (mask.width, mask.height);
    let rows: Vec<usize> = (0..h).filter(|&r| mask.data[r * w..(r + 1) * w].iter().any(|&m| m > 0.5)).collect();
    let (top, bottom) = (*rows.first()?, *rows.last()?);
    let span = (bottom - top + 1) as f32;
    let (lo, hi) = (top + (0.30 * span) as usize, top + (0.55 * span) as usize);
    let mut histogram = vec![0usize; w];
    for r in lo..=hi.min(h - 1) {
        for (c, &m) in mask.data[r * w..(r + 1) * w].iter().enumerate() {
            if m > 0.5 {
                histogram[c] += 1;
            }
        }
    }
    let total: usize = histogram.iter().sum();
    if total == 0 {
        return None;
    }
    let mut seen = 0;
    for (c, &n) in histogram.iter().enumerate() {
        seen += n;
        if 2 * seen >= total {
            return Some(c as f32 + 0.5);
        }
    }
    None
}

/// A pixel the tracker reads: camera-aligned `x` and front depth `z` about the axis and model height `y` (model
/// units), its colour (sharp and blurred) and its band.
#[derive(Clone, Copy, Debug)]
struct TrackPoint {
    /// Its pixel (column, row) in the normalised frame.
    pixel: (usize, usize),
    x: f32,
    y: f32,
    z: f32,
    rgb: Vec3,
    /// The colours around it, averaged.
    blurred: Vec3,
    band: usize,
}

/// The pixels the tracker reads: every `step`-th pixel well inside the silhouette whose front (the frame's own
/// guess) faces the camera.
fn track_points(prepared: &PreparedInput, guess: &InflatedSurfaces, place: &Placement, step: usize) -> Vec<TrackPoint> {
    let size = guess.mask.width;
    let mask = &prepared.normalised.mask;
    let px = place.px();
    let mut points = Vec::new();
    let margin = 2 * step;
    for r in (margin..size.saturating_sub(margin)).step_by(step) {
        for c in (margin..size.saturating_sub(margin)).step_by(step) {
            let i = r * size + c;
            let inner = [i, i - margin, i + margin, i - margin * size, i + margin * size];
            if inner.iter().any(|&n| mask.data[n] < 0.99 || guess.mask.data[n] <= 0.5) {
                continue;
            }
            // The front's slope from the neighbours `margin` away: keep what faces the camera.
            let (dx, dy) = (
                (guess.front.data[i + margin] - guess.front.data[i - margin]) * size as f32 / (4.0 * margin as f32),
                (guess.front.data[i - margin * size] - guess.front.data[i + margin * size]) * size as f32
                    / (4.0 * margin as f32),
            );
            let nz = 1.0 / (1.0 + dx * dx + dy * dy).sqrt();
            if nz.is_nan() || nz <= 0.6 {
                continue;
            }
            let rgb = prepared.normalised.rgb.data[i] / mask.data[i].max(1e-3);
            let y = place.height(r as f32 + 0.5);
            if !rgb.is_finite() || !(-1.0..=1.0).contains(&y) {
                continue;
            }
            let x = (c as f32 + 0.5 - place.axis) / px;
            // The colours around it (a box of five by five samples `step` apart, inside the silhouette).
            let (mut blurred, mut n) = (Vec3::ZERO, 0.0f32);
            for dr in -2i64..=2 {
                for dc in -2i64..=2 {
                    let (rr, cc) = (r as i64 + dr * step as i64, c as i64 + dc * step as i64);
                    if rr < 0 || cc < 0 || rr >= size as i64 || cc >= size as i64 {
                        continue;
                    }
                    let k = rr as usize * size + cc as usize;
                    if mask.data[k] >= 0.99 {
                        blurred += prepared.normalised.rgb.data[k] / mask.data[k];
                        n += 1.0;
                    }
                }
            }
            let blurred = if n > 0.0 { blurred / n } else { rgb };
            let z = guess.front.data[i] / place.k;
            points.push(TrackPoint { pixel: (c, r), x, y, z, rgb, blurred, band: band_of(y) });
        }
    }
    // At most MAX_TRACK_POINTS, spread over the silhouette.
    let every = points.len().div_ceil(MAX_TRACK_POINTS).max(1);
    points.into_iter().step_by(every).collect()
}

/// What the turn between two frames is read against: the frame before's brightness ([`brightness`]) and placement.
#[derive(Clone, Debug)]
struct PreviousFrame {
    brightness: GrayImage,
    place: Placement,
    /// The frame's own axis column ([`axis_column`], not smoothed over frames).
    axis: f32,
}

/// The brightness ([`luminance`]) a turn between frames is read on: one channel instead of three.
fn brightness(rgb: &RgbImage) -> GrayImage {
    let data = rgb.data.par_iter().map(|&v| luminance(v)).collect();
    GrayImage { width: rgb.width, height: rgb.height, data }
}

/// The person's turn (radians) between the frame before and this one, read from the image: under a turn about the
/// vertical axis a point of the front moves sideways by its depth times the turn (`x = u cos + w sin`, so
/// `dx/dyaw = z`). Each tracked pixel with texture across the row is found again in the frame before (a patch of
/// 5 x 5 brightness samples compared along the row of the same model height, a sideways
/// move of up to 0.5 rad times the deepest point's depth, refined by a parabola); the moves against the points'
/// depths (the hull's where it is measured, else the frame's guess) are fitted by `dx = turn z` (least squares,
/// then again without the points more than 3 median deviations off it). Positions are taken about each frame's own
/// axis (`axis`, the current one; the placement's follows it smoothly, a frame late on a person moving sideways,
/// which read as a turn). `None` with too few textured points or a
/// turn past 0.5 rad (29 degrees) a frame.
///
/// The pose network reads the torso's yaw from one image and confuses front and back; this reads how far and which
/// way the person turned, on either side of them: the two together decide the branch.
fn turn_between(
    previous: &PreviousFrame,
    brightness: &GrayImage,
    points: &[TrackPoint],
    place: &Placement,
    axis: f32,
) -> Option<f32> {
    let before = &previous.brightness;
    let size = brightness.width;
    if (before.width, before.height) != (size, brightness.height) || points.is_empty() {
        return None;
    }
    // A pixel of either frame (same size), `None` outside.
    let at = |img: &GrayImage, c: i64, r: i64| -> Option<f32> {
        (c >= 0 && r >= 0 && (c as usize) < size && (r as usize) < img.height)
            .then(|| img.data[r as usize * size + c as usize])
    };
    let now = |c: i64, r: i64| at(brightness, c, r);
    let spacing = (size / 256).max(1) as i64;
    let reach = 2 * spacing;
    // The patch's 5 x 5 samples, `spacing` apart, about its pixel.
    let offsets: Vec<(i64, i64)> = (0..25).map(|k| (((k % 5) - 2) * spacing, ((k / 5) - 2) * spacing)).collect();
    // Texture across the row: the patch's sideways differences.
    let texture = |c: usize, r: usize| -> f32 {
        let (c, r) = (c as i64, r as i64);
        let mut sum = 0.0;
        for dr in [-reach, 0, reach] {
            match (now(c - reach, r + dr), now(c + reach, r + dr)) {
                (Some(a), Some(b)) => sum += (a - b).abs(),
                _ => return 0.0,
            }
        }
        sum
    };
    let mut ranked: Vec<(f32, usize)> =
        points.iter().enumerate().map(|(k, p)| (texture(p.pixel.0, p.pixel.1), k)).collect();
    ranked.sort_by(|a, b| b.0.total_cmp(&a.0));
    ranked.truncate(FLOW_POINTS);
    ranked.retain(|&(t, _)| t > 0.02);
    let deepest = points.iter().map(|p| p.z).fold(0.0f32, f32::max);
    let before_px = previous.place.px();
    // Moves tried in steps of the patch's sample spacing (a pixel at 256², two at 512²; the parabola refines
    // between them), up to 0.5 rad times the deepest point's depth.
    let steps = (0.5 * deepest * before_px / spacing as f32).ceil() as i64 + 1;
    if ranked.len() < 24 || steps < 2 || steps * spacing > size as i64 / 4 {
        return None;
    }
    let moves: Vec<(f32, f32)> = ranked
        .par_iter()
        .filter_map(|&(_, k)| {
            let p = &points[k];
            let (c, r) = (p.pixel.0 as i64, p.pixel.1 as i64);
            let mut patch = [0.0f32; 25];
            for (v, &(dc, dr)) in patch.iter_mut().zip(&offsets) {
                *v = now(c + dc, r + dr)?;
            }
            // Where the point would be in the frame before had it not moved.
            // Pixel indices: the continuous position less the half pixel to the centre, rounded; the rounding is
            // added back to the move.
            let row = (previous.place.row(p.y) - 0.5).round() as i64;
            // About each frame's own axis: a person who moves sideways (or a camera that pans) does not turn.
            let x = p.x + (place.axis - axis) / place.px();
            let expected = previous.axis + x * before_px - 0.5;
            let column = expected.round() as i64;
            let rounding = expected - column as f32;
            let costs: Vec<f32> = (-steps..=steps)
                .map(|step| {
                    let d = step * spacing;
                    let mut cost = 0.0;
                    for (&v, &(dc, dr)) in patch.iter().zip(&offsets) {
                        match at(before, column - d + dc, row + dr) {
                            Some(b) => cost += (v - b).abs(),
                            None => return f32::INFINITY,
                        }
                    }
                    cost
                })
                .collect();
            let best = (0..costs.len()).min_by(|&a, &b| costs[a].total_cmp(&costs[b]))?;
            let finite: Vec<f32> = costs.iter().copied().filter(|c| c.is_finite()).collect();
            let mean = finite.iter().sum::<f32>() / finite.len().max(1) as f32;
            // A clear minimum inside the range.
            if best == 0 || best + 1 == costs.len() || costs[best] >= 0.6 * mean || costs[best].is_nan() {
                return None;
            }
            let (a, b, cc) = (costs[best - 1], costs[best], costs[best + 1]);
            let denom = a - 2.0 * b + cc;
            let sub = if denom > 1e-9 { (0.5 * (a - cc) / denom).clamp(-0.5, 0.5) } else { 0.0 };
            let shift_px = (best as f32 - steps as f32 + sub) * spacing as f32 + rounding;
            Some((p.z, shift_px / before_px))
        })
        .collect();
    if moves.len() < 24 {
        return None;
    }
    // The slope through the origin: the positions are about each frame's own axis, and the points' depths span too
    // little of the cross-section to fit a sideways shift beside the turn (tried: a line with a shift read the turn
    // 6-14 degrees off, median over the clips' frames, against 1-6 without).
    let fit = |pts: &[(f32, f32)]| -> Option<f32> {
        let (szd, szz) = pts.iter().fold((0.0, 0.0), |(a, b), &(z, d)| (a + z * d, b + z * z));
        (szz > 0.0).then(|| szd / szz)
    };
    let turn = fit(&moves)?;
    let mut residuals: Vec<f32> = moves.iter().map(|&(z, d)| (d - turn * z).abs()).collect();
    let mid = residuals.len() / 2;
    let spread = *residuals.select_nth_unstable_by(mid, f32::total_cmp).1;
    let limit = 3.0 * spread.max(0.5 / before_px);
    let kept: Vec<(f32, f32)> = moves.iter().copied().filter(|&(z, d)| (d - turn * z).abs() <= limit).collect();
    if kept.len() < 24 {
        return None;
    }
    let turn = fit(&kept)?;
    (turn.is_finite() && turn.abs() <= 0.5).then_some(turn)
}

/// Per row of a silhouette, the signed distance along the row (source pixels, inside positive) from each pixel
/// centre to the row's outline; rows and columns outside the photo are unknown.
struct RowProfiles {
    size: usize,
    distance: Vec<f32>,
    frame: (Vec2, Vec2),
}

/// One row of [`RowProfiles`], read at continuous columns.
struct RowAt<'a> {
    a: &'a [f32],
    b: &'a [f32],
    t: f32,
    frame: (f32, f32),
}

impl RowAt<'_> {
    /// The signed distance at continuous column `q`: interpolated between pixel centres; past the image's edge
    /// the distance goes on falling (outside), and past the photo's edge it is unknown (infinite: no carving).
    fn at(&self, q: f32) -> f32 {
        if !q.is_finite() || q < self.frame.0 || q > self.frame.1 {
            return f32::INFINITY;
        }
        let n = self.a.len();
        let x = q - 0.5;
        let value = |row: &[f32], i: usize| row[i];
        let sample = |row: &[f32]| {
            if x <= 0.0 {
                value(row, 0).min(0.0) + x
            } else if x >= (n - 1) as f32 {
                value(row, n - 1).min(0.0) - (x - (n - 1) as f32)
            } else {
                let i = x as usize;
                let t = x - i as f32;
                value(row, i) * (1.0 - t) + value(row, i + 1) * t
            }
        };
        sample(self.a) * (1.0 - self.t) + sample(self.b) * self.t
    }
}

impl RowProfiles {
    /// The profiles of `mask` (above 0.5 is the person).
    fn of(mask: &GrayImage, place: &Placement) -> Self {
        let (w, h) = (mask.width, mask.height);
        let mut distance = vec![0.0f32; w * h];
        distance.par_chunks_mut(w.max(1)).enumerate().for_each(|(r, out)| {
            let row = &mask.data[r * w..(r + 1) * w];
            let inside = |c: usize| row[c] > 0.5;
            // Distance to the nearest pixel of the other kind, left then right; the image's edges count as
            // outside one pixel beyond.
            let far = (2 * w) as f32;
            let (mut last_in, mut last_out) = (f32::NEG_INFINITY, -1.0f32);
            for (c, o) in out.iter_mut().enumerate() {
                if inside(c) {
                    last_in = c as f32;
                    *o = c as f32 - last_out;
                } else {
                    last_out = c as f32;
                    *o = if last_in.is_finite() { c as f32 - last_in } else { far };
                }
            }
            let (mut next_in, mut next_out) = (f32::INFINITY, w as f32);
            for c in (0..w).rev() {
                if inside(c) {
                    next_in = c as f32;
                    out[c] = (out[c].min(next_out - c as f32)) - 0.5;
                } else {
                    next_out = c as f32;
                    let d = if next_in.is_finite() { next_in - c as f32 } else { far };
                    out[c] = -(out[c].min(d) - 0.5);
                }
            }
        });
        Self { size: w.min(h), distance, frame: place.frame }
    }

    /// The row at continuous row `q` (interpolated between the two nearest); above or below the image but inside
    /// the photo, a row with nobody; outside the photo, `None` (unknown).
    fn row(&self, q: f32) -> Option<RowAt<'_>> {
        if !q.is_finite() || q < self.frame.0.y || q > self.frame.1.y || self.size == 0 {
            return None;
        }
        let n = self.size;
        let y = (q - 0.5).clamp(0.0, (n - 1) as f32);
        if q < 0.0 || q > n as f32 {
            // Beyond the normalised view: nobody there (the view holds the whole person).
            return None;
        }
        let r0 = y as usize;
        let r1 = (r0 + 1).min(n - 1);
        let frame = (self.frame.0.x, self.frame.1.x);
        Some(RowAt {
            a: &self.distance[r0 * n..(r0 + 1) * n],
            b: &self.distance[r1 * n..(r1 + 1) * n],
            t: y - r0 as f32,
            frame,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::buffer::RgbImage;
    use crate::pipeline::frame::FramePath;
    use crate::pipeline::PrepareOptions;

    /// Semi-axes (body-cube units) of the test person: an elliptic column, wide across and thin in depth.
    const A: f32 = 0.3;
    const B: f32 = 0.15;

    /// The colour of the column's surface at angle `phi` about its axis and height `y`; `other` is another person.
    fn pattern(phi: f32, y: f32, other: bool) -> Vec3 {
        if other {
            Vec3::new(0.15 + 0.1 * (2.0 * phi).sin(), 0.7, 0.2 + 0.1 * (6.0 * y).cos())
        } else {
            Vec3::new(
                0.5 + 0.35 * (3.0 * phi).sin(),
                0.5 + 0.35 * (5.0 * phi + 2.0 * y).cos(),
                0.45 + 0.3 * (phi + 6.0 * y).sin(),
            )
        }
    }

    /// A `size`² orthographic frame of the column turned by `yaw` (radians; the model's convention), with a head
    /// (a narrower column on top) so that the silhouette has a torso band: linear RGB and the mask.
    fn frame(size: usize, yaw: f32, other: bool) -> (RgbImage, GrayImage) {
        frame_with(size, yaw, |phi, y| pattern(phi, y, other))
    }

    /// [`frame`] with the column's colours `pattern(angle about the axis, height)`.
    fn frame_with(size: usize, yaw: f32, pattern: impl Fn(f32, f32) -> Vec3) -> (RgbImage, GrayImage) {
        let mut rgb = RgbImage::new(size, size, Vec3::ZERO);
        let mut mask = GrayImage::new(size, size, 0.0);
        let (s, c) = yaw.sin_cos();
        for r in 0..size {
            let y = 1.0 - 2.0 * (r as f32 + 0.5) / size as f32;
            let scale = if y > 0.55 { 0.45 } else { 1.0 };
            if !(-0.85..=0.8).contains(&y) {
                continue;
            }
            let (a, b) = (A * scale, B * scale);
            for col in 0..size {
                let x = 2.0 * (col as f32 + 0.5) / size as f32 - 1.0;
                // u = c x - s z, w = s x + c z on the ellipse u²/a² + w²/b² = 1: a quadratic in z.
                let qa = s * s / (a * a) + c * c / (b * b);
                let qb = 2.0 * (-c * x * s / (a * a) + s * x * c / (b * b));
                let qc = c * c * x * x / (a * a) + s * s * x * x / (b * b) - 1.0;
                let disc = qb * qb - 4.0 * qa * qc;
                if disc < 0.0 {
                    continue;
                }
                let z = (-qb + disc.sqrt()) / (2.0 * qa);
                let (u, w) = (c * x - s * z, s * x + c * z);
                let phi = (u / a).atan2(w / b);
                rgb.set(col, r, pattern(phi, y));
                mask.set(col, r, 1.0);
            }
        }
        (rgb, mask)
    }

    /// The normalised front-back thickness at the silhouette's centre column, mid-torso.
    fn centre_thickness(p: &PreparedInput) -> f32 {
        let s = p.surfaces.as_ref().expect("one-shell surfaces");
        let size = s.mask.width;
        let axis = axis_column(&s.mask).expect("a person") as usize;
        let r = (0..size).filter(|&r| s.mask.data[r * size + axis] > 0.5).nth(size / 6).expect("rows");
        let i = r * size + axis;
        s.front.data[i] - s.back.data[i]
    }

    const SIZE: usize = 128;

    fn path() -> FramePath {
        FramePath::new(PrepareOptions { resolution: SIZE, depth_samples: SIZE, ..Default::default() })
    }

    /// Plays a turn of `steps` frames of `degrees` each; returns the last frame's prepared input before and after
    /// the model, the model and every frame's [`ModelFrame`].
    fn turn(model: &mut PersonModel, steps: usize, degrees: f32) -> (PreparedInput, PreparedInput, Vec<ModelFrame>) {
        let mut path = path();
        let mut frames = Vec::new();
        let mut last = None;
        for i in 0..=steps {
            let (rgb, mask) = frame(SIZE, (i as f32 * degrees).to_radians(), false);
            let prepared = path.prepare(&rgb, &mask).expect("a frame");
            let mut modelled = prepared.clone();
            frames.push(model.update(&mut modelled));
            last = Some((prepared, modelled));
        }
        let (a, b) = last.expect("frames");
        (a, b, frames)
    }

    /// A turn of the column with the yaw from the colours alone (no body read). That tracker runs ahead of the
    /// turn by up to about 20 degrees mid-turn on this thin column (its first frames keep colours at the frame's
    /// guessed depths, before the hull is measured), then pulls back toward the truth as the front it kept first
    /// comes round again; where it ends within that pull-back varies by several degrees with any change to the
    /// depths it reads (5.6 to 8.7 degrees over the variants tried). The bounds say what the tracker does: it never
    /// loses the turn, and it ends closer than its worst.
    #[test]
    fn a_turn_measures_the_thickness_the_frame_guesses() {
        let mut model = PersonModel::new();
        let (guess, modelled, frames) = turn(&mut model, 36, 10.0);
        let off =
            |i: usize, f: &ModelFrame| ((f.yaw_degrees - 10.0 * i as f32 + 180.0).rem_euclid(360.0) - 180.0).abs();
        let worst = frames.iter().enumerate().map(|(i, f)| off(i, f)).fold(0.0f32, f32::max);
        assert!(worst < 25.0, "the colours' yaw {worst} degrees off at worst over the turn");
        let last = frames.last().unwrap();
        let error = off(frames.len() - 1, last);
        assert!(
            error < 10.0 && error < worst,
            "tracked {} degrees after a turn of 360 (worst {worst})",
            last.yaw_degrees
        );
        assert!(frames.iter().skip(1).all(|f| f.tracked), "every frame after the first is tracked");
        // Facing the camera again, the true thickness at the centre is 2 B (normalised like the frame).
        let truth = 2.0 * B * guess.normalised.transform.scale;
        let (before, after) = (centre_thickness(&guess), centre_thickness(&modelled));
        assert!((after - truth).abs() < 0.2 * truth, "model {after} vs truth {truth} (frame's guess {before})");
        assert!((after - truth).abs() * 2.0 < (before - truth).abs(), "model {after} guess {before} truth {truth}");
        assert!(last.hull_weight > 0.8, "{}", last.hull_weight);
        // The back image comes from the model, and nothing reset on a turn.
        assert!(last.back_from_model > 0.5, "{}", last.back_from_model);
        assert!(frames.iter().all(|f| !f.restarted && f.reset_bands.is_empty()), "a turn reset the model");
        // Memory is what the model was made with and the frame before's brightness.
        let frame_brightness = SIZE * SIZE * std::mem::size_of::<f32>();
        assert_eq!(model.memory_bytes(), PersonModel::new().memory_bytes() + frame_brightness);
    }

    /// World landmarks (the pose network's axes: x right, y up, z toward the camera) of a torso turned by `yaw`
    /// (radians, the model's convention); `mirrored`: the network's front/back swap (depths negated, sides swapped).
    fn torso(yaw: f32, mirrored: bool) -> Vec<Vec3> {
        use crate::body::pose::index::{LEFT_HIP, LEFT_SHOULDER, RIGHT_HIP, RIGHT_SHOULDER};
        let (s, c) = yaw.sin_cos();
        let turned = |x: f32, y: f32| Vec3::new(c * x, y, -s * x);
        let mut w = vec![Vec3::ZERO; crate::body::pose::LANDMARK_COUNT];
        w[LEFT_SHOULDER] = turned(0.2, 0.5);
        w[RIGHT_SHOULDER] = turned(-0.2, 0.5);
        w[LEFT_HIP] = turned(0.1, 0.0);
        w[RIGHT_HIP] = turned(-0.1, 0.0);
        if mirrored {
            w.swap(LEFT_SHOULDER, RIGHT_SHOULDER);
            w.swap(LEFT_HIP, RIGHT_HIP);
            w.iter_mut().for_each(|p| p.z = -p.z);
        }
        w
    }

    #[test]
    fn the_body_yaw_is_the_turn_and_its_mirror_the_other_branch() {
        for k in -17..=17 {
            let yaw = (k as f32 * 10.0).to_radians();
            let read = body_yaw(&torso(yaw, false)).expect("a torso");
            assert!(wrap_pi(read - yaw).abs() < 1e-4, "{yaw} read {read}");
            let mirrored = body_yaw(&torso(yaw, true)).expect("a torso");
            assert!(wrap_pi(mirrored - (std::f32::consts::PI - yaw)).abs() < 1e-4, "{yaw} mirrored {mirrored}");
        }
        assert_eq!(body_yaw(&[]), None);
        assert_eq!(body_yaw(&vec![Vec3::NAN; 33]), None);
    }

    /// A turn of the column read by a body whose front/back call flips on every third frame and lags by
    /// `lag` of each reading (the pose network's behaviour on the synthetic people): the tracked yaw stays within
    /// 12 degrees of the truth over the whole turn, the thickness is measured and nothing resets.
    #[test]
    fn the_body_keeps_the_yaw_over_a_whole_turn() {
        let mut model = PersonModel::new();
        let mut path = path();
        let mut worst = 0.0f32;
        let mut last = None;
        for i in 0..=36 {
            let yaw = (i as f32 * 10.0).to_radians();
            let (rgb, mask) = frame(SIZE, yaw, false);
            let mut p = path.prepare(&rgb, &mask).expect("a frame");
            // The reading: a little off, and swapped front/back on every third frame.
            let read = yaw + 0.08 * (i as f32 * 1.7).sin();
            let f = model.update_with_world(&mut p, Some(&torso(read, i % 3 == 2)));
            assert!(!f.restarted && f.reset_bands.is_empty(), "frame {i}: {}", f.describe());
            let error = (f.yaw_degrees - i as f32 * 10.0 + 180.0).rem_euclid(360.0) - 180.0;
            worst = worst.max(error.abs());
            last = Some((p, f));
        }
        assert!(worst < 12.0, "tracked yaw {worst} degrees off at worst");
        let (p, f) = last.expect("frames");
        assert!(f.body_used && f.hull_weight > 0.8, "{f:?}");
        let truth = 2.0 * B * p.normalised.transform.scale;
        let thickness = centre_thickness(&p);
        assert!((thickness - truth).abs() < 0.2 * truth, "model {thickness} vs truth {truth}");
    }

    /// The turn read from the image between frames is the column's turn, whichever way it turns, and with
    /// body readings that always take the mirror branch (front and back swapped: `180° − yaw`) the model still
    /// follows the turn: the image's turn says which way the person went where the two branches cross.
    #[test]
    fn the_image_turn_is_the_turn_and_keeps_the_branch() {
        for degrees in [6.0f32, -6.0] {
            let mut model = PersonModel::new();
            let mut path = path();
            let (mut errors, mut worst_yaw) = (Vec::new(), 0.0f32);
            for i in 0..=60 {
                let yaw = (i as f32 * degrees).to_radians();
                let (rgb, mask) = frame(SIZE, yaw, false);
                let mut p = path.prepare(&rgb, &mask).expect("a frame");
                let f = model.update_with_world(&mut p, Some(&torso(yaw, i > 0)));
                if let Some(t) = f.image_turn_degrees {
                    errors.push((t - degrees).abs());
                }
                if i > 0 {
                    let error = (f.yaw_degrees - i as f32 * degrees + 180.0).rem_euclid(360.0) - 180.0;
                    worst_yaw = worst_yaw.max(error.abs());
                }
            }
            assert!(errors.len() >= 50, "{degrees}: the turn read on {} of 60 frames", errors.len());
            errors.sort_by(f32::total_cmp);
            let median = errors[errors.len() / 2];
            assert!(median < 1.0, "{degrees}: the image's turn {median} degrees off (median)");
            assert!(worst_yaw < 20.0, "{degrees}: the tracked yaw {worst_yaw} degrees off at worst");
        }
    }

    /// The colour of the test's arm: 0.2 (RGB distance) from every colour of the column's `pattern`, so that a
    /// texel near it holds the arm and not the column's own colours (the pattern passes within 0.01 of
    /// `(0.8, 0.3, 0.3)`).
    const ARM: Vec3 = Vec3::new(0.5, 0.5, 0.95);

    /// A limb the hull never saw (an arm out to the side on the last frame of a turn) keeps the frame's own depths
    /// and is not painted into the kept colours, while the torso takes the hull's: the hull there was carved by
    /// frames without the arm, and its depths would flatten it onto the torso.
    #[test]
    fn a_limb_the_hull_never_saw_keeps_the_frames_own_depths() {
        let mut model = PersonModel::new();
        let _ = turn(&mut model, 36, 10.0);
        let (mut rgb, mut mask) = frame(SIZE, 0.0, false);
        for r in 0..SIZE {
            let y = 1.0 - 2.0 * (r as f32 + 0.5) / SIZE as f32;
            for col in 0..SIZE {
                let x = 2.0 * (col as f32 + 0.5) / SIZE as f32 - 1.0;
                if (0.05..=0.2).contains(&y) && (A - 0.02..=A + 0.25).contains(&x) {
                    rgb.set(col, r, ARM);
                    mask.set(col, r, 1.0);
                }
            }
        }
        let prepared = path().prepare(&rgb, &mask).expect("a frame");
        let mut modelled = prepared.clone();
        let step = model.update(&mut modelled);
        assert!(step.hull_weight > 0.5 && !step.restarted, "{step:?}");
        let (g, m) = (prepared.surfaces.as_ref().unwrap(), modelled.surfaces.as_ref().unwrap());
        let n = &prepared.normalised;
        let t = n.transform;
        // The arm's pixels clear of the torso (camera x beyond the column's edge by 0.04).
        let clear = |i: usize| {
            let col = ((i % SIZE) as f32 + 0.5 - t.offset.x) / t.scale;
            2.0 * col / SIZE as f32 - 1.0 > A + 0.04
        };
        let arm: Vec<usize> = (0..n.mask.data.len())
            .filter(|&i| n.mask.data[i] >= 0.99 && (n.rgb.data[i] - ARM).abs().max_element() < 0.02 && clear(i))
            .collect();
        assert!(arm.len() > 40, "{} arm pixels", arm.len());
        // Every arm pixel, the ones next to the torso too, keeps about the frame's own thickness.
        let worst = arm
            .iter()
            .map(|&i| ((m.front.data[i] - m.back.data[i]) - (g.front.data[i] - g.back.data[i])).abs())
            .fold(0.0f32, f32::max);
        let guess_mean = arm.iter().map(|&i| g.front.data[i] - g.back.data[i]).sum::<f32>() / arm.len() as f32;
        assert!(worst < 0.25 * guess_mean.max(0.02), "arm thickness off by {worst} (the frame's {guess_mean})");
        // No band was held back by the forgetting (which keeps nothing of a frame in a band it doubts): what kept
        // the arm out is the hull.
        assert!(model.strikes.iter().all(|&s| s == 0), "bands held back {:?}: {step:?}", model.strikes);
        // The arm's colour went into no texel.
        let painted = model.map.iter().filter(|t| t[3] > 0.0 && (Vec3::new(t[0], t[1], t[2]) - ARM).length() < 0.1);
        assert_eq!(painted.count(), 0, "the arm's colour was kept");
    }

    #[test]
    fn a_cut_to_another_person_restarts_the_model() {
        let mut model = PersonModel::new();
        let _ = turn(&mut model, 12, 10.0);
        let mut path = path();
        let mut restarted_at = None;
        for i in 0..6 {
            let (rgb, mask) = frame(SIZE, (i as f32 * 10.0).to_radians(), true);
            let mut p = path.prepare(&rgb, &mask).expect("a frame");
            // The other person faces the camera and turns: the body's reading is as plausible as before.
            let f = model.update_with_world(&mut p, Some(&torso((i as f32 * 10.0).to_radians(), false)));
            if f.restarted && restarted_at.is_none() {
                restarted_at = Some(i);
            }
        }
        let at = restarted_at.expect("the model restarted after the cut");
        assert!(at < RESET_STRIKES as usize + 1, "restarted {at} frames after the cut");
    }

    /// Two people in dark clothes differ little in linear RGB (navy against brown: 0.045 mean, under a third of the
    /// bands' threshold) but as much as any two garments to the eye: the whole person's test reads square roots and a jump
    /// over what the person's own frames differed by. A turn of the dark person alone never restarts.
    #[test]
    fn a_cut_between_two_people_in_dark_clothes_restarts_the_model() {
        let navy = |phi: f32, y: f32| {
            Vec3::new(0.02, 0.03, 0.08) * (1.0 + 0.3 * (3.0 * phi).sin()) + Vec3::splat(0.01 * (6.0 * y).cos())
        };
        let brown = |phi: f32, y: f32| {
            Vec3::new(0.08, 0.04, 0.02) * (1.0 + 0.3 * (2.0 * phi).cos()) + Vec3::splat(0.01 * (5.0 * y).sin())
        };
        let linear_gap = (0..64)
            .map(|k| {
                let (phi, y) = (k as f32 * 0.1, (k % 8) as f32 * 0.2 - 0.8);
                (navy(phi, y) - brown(phi, y)).abs().element_sum() / 3.0
            })
            .sum::<f32>()
            / 64.0;
        assert!(linear_gap < RESET_COLOUR_ERROR / 3.0, "the two garments differ by {linear_gap} in linear RGB");
        let mut model = PersonModel::new();
        let mut path = path();
        let mut restarted_at = None;
        for i in 0..30 {
            let yaw = (i as f32 * 10.0).to_radians();
            let (rgb, mask) = if i < 24 { frame_with(SIZE, yaw, navy) } else { frame_with(SIZE, yaw, brown) };
            let mut p = path.prepare(&rgb, &mask).expect("a frame");
            let f = model.update_with_world(&mut p, Some(&torso(yaw, false)));
            if f.restarted {
                assert!(i >= 24, "frame {i}: the turn of one person restarted the model");
                restarted_at = restarted_at.or(Some(i));
            }
        }
        let at = restarted_at.expect("the model restarted after the cut");
        assert!(at < 24 + RESET_STRIKES as usize + 1, "restarted {} frames after the cut", at - 24);
    }

    /// What the export action writes from a live source with the model on (`view`'s E key, `xr`'s export: the
    /// prepared frame the eyes show) is the accumulated person: the model's mesh, and on the surfaces facing away
    /// the back colours the turn showed — truer to the column's back than the frame's front, which the frame path's
    /// export puts there without a back image.
    #[test]
    fn the_export_writes_the_accumulated_person() {
        use crate::pipeline::export::{person_mesh, ExportOptions};
        let mut model = PersonModel::new();
        let (guess, modelled, _) = turn(&mut model, 36, 10.0);
        let opts = ExportOptions::default();
        let mask = &modelled.normalised.mask;
        let (exported, report) = person_mesh(&modelled, mask, &opts).expect("the model's person exports");
        let res = mask.width;
        assert_eq!(report.texture, (2 * res as u32, res as u32), "the photo and the kept back as textures");
        assert!(report.back_triangles > 0, "{report:?}");
        assert_eq!(report.source_triangles, modelled.mesh.triangle_count());
        assert!(!exported.mesh.positions.is_empty());
        let (_, plain) = person_mesh(&guess, &guess.normalised.mask, &opts).expect("the frame exports");
        assert_eq!(plain.texture, (res as u32, res as u32), "the frame alone has no back image here");
        // The column's true back colour at each pixel of the torso, against the kept back and the frame's front.
        let back = modelled.back.as_ref().expect("a back image from the model");
        let t = modelled.normalised.transform;
        let (mut kept, mut front, mut n) = (0.0f32, 0.0f32, 0usize);
        for row in 0..res {
            for col in 0..res {
                let i = row * res + col;
                if mask.data[i] < 0.99 {
                    continue;
                }
                let photo = t.inverse(Vec2::new(col as f32 + 0.5, row as f32 + 0.5));
                let (x, y) = (2.0 * photo.x / SIZE as f32 - 1.0, 1.0 - 2.0 * photo.y / SIZE as f32);
                if !(-0.8..=0.5).contains(&y) || x.abs() > 0.8 * A {
                    continue;
                }
                let z_back = -B * (1.0 - x * x / (A * A)).max(0.0).sqrt();
                let truth = pattern((x / A).atan2(z_back / B), y, false);
                let m = mask.data[i];
                kept += (back.rgb.data[i] / m - truth).abs().element_sum() / 3.0;
                front += (modelled.normalised.rgb.data[i] / m - truth).abs().element_sum() / 3.0;
                n += 1;
            }
        }
        assert!(n > 200, "{n} torso pixels");
        let (kept, front) = (kept / n as f32, front / n as f32);
        assert!(kept < 0.6 * front, "kept back {kept} against the front's {front} (mean |difference|)");
    }

    #[test]
    fn the_fast_angle_is_the_angle() {
        for k in 0..2000 {
            let a = k as f32 * 0.0131 - 13.0;
            let (r, s) = (0.3 + (k % 7) as f32, a.sin());
            let (y, x) = (r * s, r * a.cos());
            let d = (fast_atan2(y, x) - y.atan2(x) + 3.0 * std::f32::consts::PI).rem_euclid(std::f32::consts::TAU)
                - std::f32::consts::PI;
            assert!(d.abs() < 0.0015, "{y} {x}: {d}");
        }
        assert_eq!(fast_atan2(0.0, 0.0), 0.0);
        assert_eq!(fast_atan2(f32::NAN, 1.0), 0.0);
    }

    #[test]
    fn no_nan_at_extreme_views_and_no_panic_on_odd_input() {
        let mut model = PersonModel::new();
        let (_, modelled, _) = turn(&mut model, 20, 18.0);
        let mut renderer =
            crate::pipeline::ViewRenderer::new(&modelled, crate::pipeline::warp::OcclusionFill::default(), false);
        for (yaw, pitch) in [(90.0, 0.0), (180.0, 0.0), (270.0, 89.0), (45.0, -89.0), (135.0, 60.0)] {
            let cam = crate::geometry::Camera::orbit(yaw, pitch, 64, 64);
            let img = renderer.render_person(&cam).expect("a view");
            assert!(img.data.iter().all(|p| p.is_finite()), "yaw {yaw} pitch {pitch}");
        }
        assert!(modelled.mesh.positions.iter().all(|p| p.is_finite()));
        // A frame without surfaces, an empty mask and a frame of another size pass without a panic.
        let mut still = modelled.clone();
        still.surfaces = None;
        assert_eq!(model.update(&mut still).ms, 0.0);
        let mut empty = modelled.clone();
        if let Some(s) = empty.surfaces.as_mut() {
            s.mask.data.iter_mut().for_each(|m| *m = 0.0);
        }
        let _ = model.update(&mut empty);
        let mut other = path();
        let (rgb, mask) = frame(48, 0.3, false);
        let mut small = other.prepare(&rgb, &mask).expect("a frame");
        let _ = model.update(&mut small);
        assert!(small.surfaces.as_ref().unwrap().front.data.iter().all(|v| v.is_finite()));
    }
}
