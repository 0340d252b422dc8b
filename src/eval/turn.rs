//! `r2human eval --turn`: a person turning once in front of a fixed camera ([`crate::synth::turn`]), played frame
//! by frame through the live frame path ([`FramePath::prepare`], as `view --video` prepares a frame), and scored at
//! every frame on the views the camera cannot see (divergent, at least 90 degrees from it) and the close ones (at
//! most 45 degrees), against the ground truth of that moment.
//!
//! Each frame's ground truth is the person of that frame carried into the frame path's own normalisation (the
//! similarity [`crate::pipeline::input::NormaliseTransform`] it found for the frame, so the figures measure the
//! geometry and the colours, not a re-cropping), then centred in depth like every geometry. Methods:
//!
//! - `frame-path`: the geometric renderer on what [`FramePath`] prepared (what a live source shows today);
//! - `model`: the same preparation rewritten by the person model kept across the clip's frames ([`PersonModel`]:
//!   the hull's depths and the kept colours of the back, its yaw tracked from the frames alone; the clip's true
//!   turn is only compared with it, in `turn_model.csv`);
//! - `oracle`: the geometric renderer on the same frame's normalised input with the true geometry (the frame's
//!   ground-truth FOF, [`PreparedInput::from_fof`]): the ceiling of any geometry.
//!
//! Outputs in `--out`: `turn.csv` (one row per clip, frame, method and view group), `turn_model.csv` (the model's
//! tracking per frame), `turn.md` (per clip and over every clip: the first frame, the last one — the person has
//! turned once and faces the camera again — and the mean over the turn), `turn_divergent_psnr.png` (divergent
//! whole-frame PSNR over the frames, mean over clips) and `sheets/<clip>.png` (contact sheets: six moments of the
//! clip; rows: the camera's frame, then at yaw 180 and yaw 90 the ground truth, the frame path, the model and the
//! oracle).

use std::path::PathBuf;
use std::time::Instant;

use glam::Vec3;
use serde::Serialize;

use super::ground_truth::render_ground_truth;
use super::runner::{mean, score, write_chart, Acc, MeanScores, Prediction};
use super::EvalError;
use crate::buffer::{GrayImage, RgbImage};
use crate::geometry::camera::Camera;
use crate::geometry::fof::Fof;
use crate::io::mesh_io::TexturedMesh;
use crate::io::npy::write_atomic;
use crate::pipeline::frame::FramePath;
use crate::pipeline::input::NormaliseTransform;
use crate::pipeline::person_model::PersonModel;
use crate::pipeline::warp::OcclusionFill;
use crate::pipeline::{PrepareOptions, PreparedInput, StageTimings, ViewRenderer};
use crate::synth::turn::{TurnOptions, TurningClip};
use crate::synth::{self, SubjectParams, SynthAssets};

/// Options of [`run_turn_eval`] (`r2human eval --turn`).
#[derive(Clone, Debug, PartialEq)]
pub struct TurnEvalOptions {
    /// Synthetic subjects (`--subjects`), the seeds of `r2human eval` (full body).
    pub subjects: usize,
    /// Seed (`--seed`).
    pub seed: u64,
    /// Scans turned rigidly (`--scan`).
    pub scans: Vec<PathBuf>,
    /// How the scans are turned upright and toward the camera.
    pub scan_orientation: synth::scan::ScanOrientation,
    /// Output folder.
    pub out: PathBuf,
    /// Image side of the camera's frames and of the views.
    pub size: usize,
    /// The turn (`--turn-frames`, `--hold-frames`, `--arm-swing`).
    pub turn: TurnOptions,
    /// View yaws in degrees (pitch 0) relative to the camera.
    pub yaws: Vec<f32>,
    /// Texture side of the synthetic subjects.
    pub texture_size: usize,
    /// What happens halfway through the turn (`--event`): nothing, a cut to another subject, or the top taken off.
    pub event: EventChoice,
    /// Where the person model reads the body's orientation (`--model-body`).
    pub model_body: ModelBody,
    /// Degrees either side of the body's yaw the model's colours refine it (`--model-colour-refine`).
    pub model_colour_refine: i32,
}

/// Where the person model of `eval --turn` reads the body's orientation (`--model-body`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum ModelBody {
    /// The world landmarks of the live segmenter's pose read of each frame (MediaPipe's pose model on the square
    /// around the person, [`crate::capture::Segmenter::body_world`]): what a live camera source hands the model.
    #[default]
    Segmenter,
    /// A read of its own with the back image's pose network on MediaPipe's tracking region
    /// ([`crate::body::pose::PoseEstimator::track`]): one more network run a frame.
    Own,
    /// No body read: the yaw from the colours alone.
    Colour,
    /// The true turn of each frame (the clip's ground truth): not a source a camera has, but what the model gives
    /// with perfect tracking, the ceiling of every way of reading the yaw.
    Truth,
}

impl ModelBody {
    /// Its name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            ModelBody::Segmenter => "segmenter",
            ModelBody::Own => "own",
            ModelBody::Colour => "colour",
            ModelBody::Truth => "truth",
        }
    }
}

/// The event of the clips ([`crate::synth::turn::TurnEvent`]), at frame `turn_frames / 2`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum EventChoice {
    /// The person turns once.
    #[default]
    None,
    /// Halfway through the turn another synthetic subject (one outside the evaluated set) takes their place.
    Cut,
    /// Halfway through the turn the person's top (top or dress, and sleeves) is off.
    TakeOff,
}

impl EventChoice {
    /// Its name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            EventChoice::None => "none",
            EventChoice::Cut => "cut",
            EventChoice::TakeOff => "take-off",
        }
    }
}

impl Default for TurnEvalOptions {
    fn default() -> Self {
        Self {
            subjects: 3,
            seed: 0,
            scans: Vec::new(),
            scan_orientation: Default::default(),
            out: PathBuf::from("eval-turn"),
            size: 512,
            turn: TurnOptions::default(),
            yaws: vec![20.0, 45.0, 90.0, 135.0, 180.0, 225.0, 270.0, 315.0],
            texture_size: 1024,
            event: EventChoice::None,
            model_body: ModelBody::Segmenter,
            model_colour_refine: crate::pipeline::person_model::COLOUR_REFINE_DEGREES,
        }
    }
}

/// The methods scored at every frame.
pub const TURN_METHODS: [&str; 3] = ["frame-path", "model", "oracle"];

/// The view groups: close (at most 45 degrees from the camera), divergent (at least 90).
pub const GROUPS: [&str; 2] = ["close", "divergent"];

/// One method on one view group at one frame of one clip.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TurnRow {
    /// The clip: `subject_XXXX` or a scan's file stem.
    pub clip: String,
    /// Frame index.
    pub frame: usize,
    /// How far the person has turned (degrees, [`TurnOptions::yaw`]).
    pub turn: f32,
    /// Whether the person has turned once and faces the camera again.
    pub turned: bool,
    /// Method ([`TURN_METHODS`]).
    pub method: String,
    /// View group ([`GROUPS`]).
    pub group: String,
    /// The means over the group's views (whole-frame PSNR `psnr_frame`: sRGB on black, the paper's Table 2
    /// convention).
    #[serde(flatten)]
    pub scores: MeanScores,
    /// Milliseconds the method took to prepare the frame (the frame path's `prepare`; the oracle's FOF and mesh).
    pub ms_prepare: f32,
    /// Views averaged.
    pub views: usize,
}

/// What the person model did on one frame of one clip, beside the clip's truth.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ModelTrackRow {
    /// The clip.
    pub clip: String,
    /// Frame index.
    pub frame: usize,
    /// How far the person has truly turned (degrees, the clip's ground truth: reported, never used by the model).
    pub turn: f32,
    /// The yaw the model tracked (degrees, since it last started).
    pub yaw: f32,
    /// The tracked yaw minus the true turn since the model last started, wrapped to `[-180, 180)`.
    pub yaw_error: f32,
    /// The body's reading (degrees, the model's frame) minus the true turn, wrapped; empty when the pose network read
    /// no torso.
    pub body_error: Option<f32>,
    /// The turn since the frame before read from the image (degrees, [`crate::pipeline::person_model::ModelFrame`]'s
    /// `image_turn_degrees`) minus the true one; empty when none was read.
    pub image_turn_error: Option<f32>,
    /// Whether the body's reading moved the yaw.
    pub body_used: bool,
    /// Whether the whole model restarted on this frame.
    pub restarted: bool,
    /// Bands reset on this frame.
    pub reset_bands: usize,
    /// Mean hull weight over the silhouette.
    pub hull_weight: f32,
    /// Milliseconds the model's update took (with the pose read).
    pub ms: f32,
    /// The frame's colour difference with the model averaged over the bands holding colour, and its largest band
    /// ([`crate::pipeline::person_model::ModelFrame::band_error_roots`]; NaN where no band holds colour).
    pub band_error: (f32, f32),
    /// Milliseconds of it the pose network's read took.
    pub pose_ms: f32,
}

/// What [`run_turn_eval`] produced.
#[derive(Clone, Debug, Default)]
pub struct TurnReport {
    /// Every frame's rows.
    pub rows: Vec<TurnRow>,
    /// The person model's tracking, per clip and frame.
    pub tracking: Vec<ModelTrackRow>,
    /// Clips (or frames) that failed, with the reason.
    pub failed: Vec<(String, String)>,
}

impl TurnReport {
    /// The mean of `value` over the rows of `method` and `group` that `keep` selects (NaN when none).
    pub fn mean_of(
        &self,
        method: &str,
        group: &str,
        keep: impl Fn(&TurnRow) -> bool,
        value: fn(&TurnRow) -> f32,
    ) -> f32 {
        let v: Vec<f32> =
            self.rows.iter().filter(|r| r.method == method && r.group == group && keep(r)).map(value).collect();
        mean(&v)
    }
}

/// `p` of the camera's body cube in the normalised source view that `t` maps the camera's `size`² frame to
/// (pixel `q = scale p + offset` in both; depth scaled alike).
pub fn to_normalised(p: Vec3, t: &NormaliseTransform, size: usize) -> Vec3 {
    let (s, r) = (t.scale, size as f32);
    Vec3::new(s * p.x + s - 1.0 + 2.0 * t.offset.x / r, s * p.y + 1.0 - s - 2.0 * t.offset.y / r, s * p.z)
}

/// The camera's frame of `mesh`: linear RGB (0 off the person) and the true mask.
fn camera_frame(mesh: &TexturedMesh, size: usize) -> (RgbImage, GrayImage) {
    let gt = render_ground_truth(mesh, &Camera::source(size));
    (gt.to_linear_rgba().map(|p| p.truncate()), gt.mask_image())
}

/// The contact sheet's images of one moment (a column): the camera's frame, then at yaw 180 and 90 the ground
/// truth, the frame path and the oracle.
type SheetColumn = Vec<RgbImage>;

/// Yaws of the contact sheets' rows.
const SHEET_YAWS: [f32; 2] = [180.0, 90.0];

/// Columns (moments) of a contact sheet.
const SHEET_COLUMNS: usize = 6;

/// Plays one clip through the frame path and the person model and scores every frame; pushes the rows and the
/// model's tracking into `report` and returns the contact sheet's columns. A frame the frame path refuses is
/// reported in `report.failed` and skipped.
fn eval_clip(
    name: &str,
    clip: &TurningClip,
    assets: Option<&SynthAssets>,
    opts: &TurnEvalOptions,
    prepare: &PrepareOptions,
    report: &mut TurnReport,
) -> Result<Vec<SheetColumn>, EvalError> {
    let TurnReport { rows, tracking, failed } = report;
    let r = opts.size;
    let n = clip.frames();
    let mut path = FramePath::new(prepare.clone());
    let pose = if opts.model_body == ModelBody::Own { prepare.back_pose.clone() } else { None };
    let mut model = PersonModel::new().with_pose(pose).with_colour_refine(opts.model_colour_refine);
    // The live segmenter, read on each camera frame for its pose model's world landmarks only (the true mask
    // is the frame path's); without it installed, the yaw comes from the colours.
    let mut segmenter = match opts.model_body {
        ModelBody::Segmenter => {
            match crate::capture::onnx::OnnxSegmenter::load(None, crate::capture::onnx::DEFAULT_INPUT_SIZE) {
                Ok(s) if s.kind() == crate::capture::onnx::SegmentationModel::MediapipePose => Some(s),
                Ok(_) => {
                    tracing::warn!(
                        "eval --turn: the segmentation model is not the pose model; the model's yaw from the colours"
                    );
                    None
                }
                Err(e) => {
                    tracing::warn!("eval --turn: no segmentation model ({e}); the model's yaw from the colours");
                    None
                }
            }
        }
        _ => None,
    };
    // The true turn when the model last started (the tracked yaw counts from there).
    let mut turn_at_start = clip.options.yaw(0);
    let sheet_frames: Vec<usize> = (0..SHEET_COLUMNS).map(|k| k * (n - 1) / (SHEET_COLUMNS - 1)).collect();
    let mut sheet = Vec::new();
    for i in 0..n {
        let mesh = clip.frame(assets, i)?;
        let (rgb, mask) = camera_frame(&mesh, r);
        let t = Instant::now();
        let prepared = match path.prepare(&rgb, &mask) {
            Ok(p) => p,
            Err(e) => {
                failed.push((format!("{name} frame {i}"), e.to_string()));
                continue;
            }
        };
        let ms_frame = t.elapsed().as_secs_f32() * 1e3;
        let mut modelled = prepared.clone();
        let step = match segmenter.as_mut() {
            Some(seg) => {
                use crate::capture::Segmenter;
                let frame = crate::capture::Frame {
                    index: i as u64,
                    timestamp: std::time::Duration::ZERO,
                    rgb: rgb.clone(),
                    alpha: None,
                };
                let world = match seg.segment(&frame) {
                    Ok(_) => seg.body_world(),
                    Err(e) => {
                        tracing::debug!("{name} frame {i}: the segmenter failed: {e}");
                        None
                    }
                };
                model.update_with_world(&mut modelled, world)
            }
            None if opts.model_body == ModelBody::Truth => {
                // Since the model (re)started; on its first frame (or a restart) that is 0.
                let since = if model.frames() == 0 { 0.0 } else { clip.options.yaw(i) - turn_at_start };
                model.update_with_yaw(&mut modelled, since)
            }
            None => model.update(&mut modelled),
        };
        if step.restarted || model.frames() == 1 {
            turn_at_start = clip.options.yaw(i);
        }
        let truth_turn = clip.options.yaw(i) - turn_at_start;
        let wrapped = |d: f32| (d + 180.0).rem_euclid(360.0) - 180.0;
        tracking.push(ModelTrackRow {
            clip: name.to_string(),
            frame: i,
            turn: clip.options.yaw(i),
            yaw: step.yaw_degrees,
            yaw_error: wrapped(step.yaw_degrees - truth_turn),
            body_error: step.body_yaw_degrees.map(|b| wrapped(b - truth_turn)),
            image_turn_error: step
                .image_turn_degrees
                .map(|t| wrapped(t - (clip.options.yaw(i) - clip.options.yaw(i.saturating_sub(1))))),
            body_used: step.body_used,
            restarted: step.restarted,
            reset_bands: step.reset_bands.len(),
            hull_weight: step.hull_weight,
            ms: step.ms,
            pose_ms: step.pose_ms,
            band_error: {
                let held: Vec<f32> = step.band_error_roots.iter().copied().filter(|e| !e.is_nan()).collect();
                let mean = held.iter().sum::<f32>() / held.len() as f32;
                (mean, held.iter().copied().fold(f32::NAN, f32::max))
            },
        });
        // The ground truth of this moment in the frame path's normalisation, centred in depth.
        let transform = prepared.normalised.transform;
        let mut truth = mesh.clone();
        truth.mesh.positions.iter_mut().for_each(|p| *p = to_normalised(*p, &transform, r));
        synth::normalize::centre_depth(&mut truth.mesh);
        // The oracle: the same normalised input with the true geometry.
        let t = Instant::now();
        let fof =
            Fof::from_mesh(&truth.mesh, r, prepare.fof_order).map_err(|e| EvalError::stage("ground-truth FOF", e))?;
        let oracle = PreparedInput::from_fof(prepared.normalised.clone(), fof, prepare, StageTimings::default())
            .map_err(|e| EvalError::stage("oracle geometry", e))?;
        let ms_oracle = t.elapsed().as_secs_f32() * 1e3;
        let inputs = [(&prepared, ms_frame), (&modelled, ms_frame + step.ms), (&oracle, ms_oracle)];
        let mut renderers: Vec<ViewRenderer<'_>> =
            inputs.iter().map(|(p, _)| ViewRenderer::new(p, OcclusionFill::default(), false)).collect();
        let mut acc: [[Acc; 2]; TURN_METHODS.len()] = Default::default();
        let in_sheet = sheet_frames.contains(&i);
        let mut column: SheetColumn = Vec::new();
        if in_sheet {
            column.push(crate::io::image_io::over_background(
                &crate::buffer::RgbaImage::from_fn(r, r, |c, row| rgb.get(c, row).extend(*mask.get(c, row))),
                Vec3::ZERO,
            ));
        }
        let mut sheet_views: Vec<(f32, Vec<RgbImage>)> = Vec::new();
        for &yaw in &opts.yaws {
            let cam = Camera::orbit(yaw, 0.0, r, r);
            let angle = cam.angle_from_source().to_degrees();
            let group = match angle {
                a if a <= 45.0 + 1e-3 => 0,
                a if a >= 90.0 - 1e-3 => 1,
                _ => continue,
            };
            let gt = render_ground_truth(&truth, &cam);
            let mut views = vec![over_black(&gt.to_linear_rgba())];
            for (m, renderer) in renderers.iter_mut().enumerate() {
                let t = Instant::now();
                let person = renderer.render_person(&cam).map_err(|e| EvalError::stage("rendering", e))?;
                let ms = t.elapsed().as_secs_f32() * 1e3;
                let pred = Prediction::of_person(person, &inputs[m].0.mesh, &cam);
                views.push(over_black(pred.rgba()));
                score(&gt, &pred, &mut acc[m][group], ms);
            }
            if in_sheet && SHEET_YAWS.contains(&yaw) {
                sheet_views.push((yaw, views));
            }
        }
        if in_sheet {
            for yaw in SHEET_YAWS {
                if let Some((_, v)) = sheet_views.iter_mut().find(|(y, _)| *y == yaw) {
                    column.append(v);
                }
            }
            sheet.push(column);
        }
        for (m, method) in TURN_METHODS.iter().enumerate() {
            for (g, group) in GROUPS.iter().enumerate() {
                let a = &acc[m][g];
                if a.psnr_frame.is_empty() {
                    continue;
                }
                rows.push(TurnRow {
                    clip: name.to_string(),
                    frame: i,
                    turn: clip.options.yaw(i),
                    turned: clip.options.turned(i),
                    method: method.to_string(),
                    group: group.to_string(),
                    scores: a.means(),
                    ms_prepare: inputs[m].1,
                    views: a.psnr_frame.len(),
                });
            }
        }
        tracing::info!("{name}: frame {}/{n} scored", i + 1);
    }
    Ok(sheet)
}

/// A premultiplied person layer over black.
fn over_black(img: &crate::buffer::RgbaImage) -> RgbImage {
    crate::io::image_io::over_background(img, Vec3::ZERO)
}

/// Runs the turning-clip evaluation and writes its outputs into `opts.out` (see the module docs). `back_pose`: the
/// pose network the frame path's back image reads the face with (the live default's fill), when it loaded.
pub fn run_turn_eval(
    opts: &TurnEvalOptions,
    back_pose: Option<crate::pipeline::SharedPose>,
) -> Result<TurnReport, EvalError> {
    if opts.subjects == 0 && opts.scans.is_empty() {
        return Err(EvalError::InvalidOptions("nothing to turn: give --subjects N or --scan FILE".into()));
    }
    if !(32..=2048).contains(&opts.size) {
        return Err(EvalError::InvalidOptions(format!("--size {} must be within 32..=2048", opts.size)));
    }
    opts.turn.validate()?;
    let sheets_dir = opts.out.join("sheets");
    std::fs::create_dir_all(&sheets_dir).map_err(|e| EvalError::io(&sheets_dir, e))?;
    let prepare = PrepareOptions { resolution: opts.size, depth_samples: opts.size, back_pose, ..Default::default() };
    let mut report = TurnReport::default();
    let assets = if opts.subjects > 0 { Some(SynthAssets::shared()?) } else { None };
    let clips = clips_of(opts, assets);
    for (name, clip) in clips {
        let r = clip.and_then(|(clip, synthetic)| {
            let a = if synthetic { assets } else { None };
            let sheet = eval_clip(&name, &clip, a, opts, &prepare, &mut report)?;
            write_sheet(&sheets_dir.join(format!("{name}.png")), &sheet, opts.size)
        });
        if let Err(e) = r {
            report.failed.push((name, e.to_string()));
        }
    }
    if report.rows.is_empty() {
        let first = report.failed.first().map(|f| format!("{}: {}", f.0, f.1)).unwrap_or_default();
        return Err(EvalError::AllFailed(first));
    }
    write_turn_reports(opts, &report)?;
    Ok(report)
}

/// The clips `opts` asks for, named (`subject_XXXX` with the eval's seeds, then each scan's file stem), each made
/// or with why it could not be.
fn clips_of(opts: &TurnEvalOptions, assets: Option<&SynthAssets>) -> Vec<(String, ClipToPlay)> {
    let mut clips: Vec<(String, ClipToPlay)> = Vec::new();
    for i in 0..opts.subjects {
        let seed = super::dataset::subject_seed(opts.seed, i);
        let at = opts.turn.turn_frames / 2;
        let clip = assets.map_or_else(
            || Err(EvalError::InvalidOptions("no synthetic-subject data".into())),
            |a| {
                let make = |seed| TurningClip::synthetic(a, &SubjectParams::sample(seed), opts.texture_size, opts.turn);
                let clip = make(seed).and_then(|c| match opts.event {
                    EventChoice::None => Ok(c),
                    // The other person is a subject outside the evaluated set.
                    EventChoice::Cut => c.cut_to(make(super::dataset::subject_seed(opts.seed, opts.subjects + i))?, at),
                    EventChoice::TakeOff => c.take_off_top(at),
                });
                clip.map(|c| (c, true)).map_err(EvalError::from)
            },
        );
        clips.push((format!("subject_{i:04}"), clip));
    }
    for scan in &opts.scans {
        let stem = scan.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "scan".into());
        let clip = match opts.event {
            EventChoice::None => synth::scan::load_scan_with(scan, &opts.scan_orientation)
                .and_then(|s| TurningClip::scan(s.mesh, opts.turn))
                .map(|c| (c, false))
                .map_err(EvalError::from),
            event => Err(EvalError::InvalidOptions(format!(
                "--event {} needs synthetic subjects (a scan has no rig and no second person)",
                event.name()
            ))),
        };
        clips.push((stem, clip));
    }
    clips
}

/// `r2human dataset --turn`: writes each clip `opts` asks for as a folder of frames a live source can play
/// (`r2human view --video DIR/subject_0000 --fps 16`): `frame_NNNN.png` (8-bit sRGB, straight alpha = the true
/// mask, the camera's `size`² frame) and `clip.json` (the clip's turn, arm swing and seed, and per frame the turn
/// in degrees and whether the person has turned once).
pub fn write_turn_clips(opts: &TurnEvalOptions) -> Result<TurnClipsWritten, EvalError> {
    if opts.subjects == 0 && opts.scans.is_empty() {
        return Err(EvalError::InvalidOptions("nothing to turn: give --subjects N or --scan FILE".into()));
    }
    opts.turn.validate()?;
    let assets = if opts.subjects > 0 { Some(SynthAssets::shared()?) } else { None };
    let (mut written, mut failed) = (Vec::new(), Vec::new());
    for (k, (name, clip)) in clips_of(opts, assets).into_iter().enumerate() {
        let dir = opts.out.join(&name);
        let r = clip.and_then(|(clip, synthetic)| {
            std::fs::create_dir_all(&dir).map_err(|e| EvalError::io(&dir, e))?;
            let a = if synthetic { assets } else { None };
            let mut frames = Vec::new();
            for i in 0..clip.frames() {
                let mesh = clip.frame(a, i)?;
                let gt = render_ground_truth(&mesh, &Camera::source(opts.size));
                let path = dir.join(format!("frame_{i:04}.png"));
                let mut bytes = Vec::new();
                image::DynamicImage::ImageRgba8(gt.to_srgba8())
                    .write_to(&mut std::io::Cursor::new(&mut bytes), image::ImageFormat::Png)
                    .map_err(|e| EvalError::io(&path, std::io::Error::other(e)))?;
                write_atomic(&path, &bytes).map_err(|e| EvalError::io(&path, e))?;
                frames.push(serde_json::json!({"turn_deg": clip.options.yaw(i), "turned": clip.options.turned(i)}));
            }
            let seed = (k < opts.subjects).then(|| super::dataset::subject_seed(opts.seed, k));
            let meta = serde_json::json!({
                "format": "r2human-turn-clip", "version": 1, "size": opts.size, "seed": seed,
                "turn_frames": opts.turn.turn_frames, "hold_frames": opts.turn.hold_frames,
                "arm_swing_deg": opts.turn.arm_swing, "event": opts.event.name(),
                "event_frame": clip.event.as_ref().map(|e| e.at()), "frames": frames,
            });
            let path = dir.join("clip.json");
            let text =
                serde_json::to_string_pretty(&meta).map_err(|e| EvalError::io(&path, std::io::Error::other(e)))?;
            write_atomic(&path, text.as_bytes()).map_err(|e| EvalError::io(&path, e))
        });
        match r {
            Ok(()) => written.push(dir),
            Err(e) => failed.push((name, e.to_string())),
        }
    }
    Ok(TurnClipsWritten { written, failed })
}

/// What [`write_turn_clips`] wrote.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TurnClipsWritten {
    /// The clips' folders.
    pub written: Vec<PathBuf>,
    /// The clips that failed, with the reason.
    pub failed: Vec<(String, String)>,
}

/// A clip made (and whether it is synthetic, re-posed with the synthetic assets) or why it could not be.
type ClipToPlay = Result<(TurningClip, bool), EvalError>;

/// Writes a contact sheet whose columns are `columns` (transposed into rows of images).
fn write_sheet(path: &std::path::Path, columns: &[SheetColumn], size: usize) -> Result<(), EvalError> {
    let rows = columns.iter().map(Vec::len).max().unwrap_or(0);
    let blank = RgbImage::new(size, size, Vec3::ZERO);
    let blank = &blank;
    let frames: Vec<RgbImage> = (0..rows)
        .flat_map(|row| columns.iter().map(move |c| c.get(row).cloned().unwrap_or_else(|| blank.clone())))
        .collect();
    let thumb = (size / 2).max(16);
    crate::io::sequence::write_contact_sheet(path, &frames, columns.len().max(1), thumb)
        .map_err(|e| EvalError::io(path, std::io::Error::other(e)))
}

/// The summary of `turn.md`: per clip and over every clip, per method and group, the first frame, the last one and
/// the mean over the turn.
fn summary_markdown(opts: &TurnEvalOptions, rep: &TurnReport) -> String {
    let mut clips: Vec<&str> = Vec::new();
    for r in &rep.rows {
        if !clips.contains(&r.clip.as_str()) {
            clips.push(&r.clip);
        }
    }
    let last = opts.turn.frames() - 1;
    let mut md = format!(
        "# r2human eval --turn\n\n{} clip(s): {} frame(s) each ({} turning once, then {} facing the camera again; \
         arms swinging {} degrees), {}x{} views at yaws {:?} relative to the camera (pitch 0). Close = at most 45 \
         degrees from the camera, divergent = at least 90. PSNR frame: whole frame, sRGB on black (the paper's \
         Table 2 convention). `frame-path`: the live frame path; `model`: the same frames through the person model kept across them \
         (`pipeline::person_model`); `oracle`: the same frames with the true geometry.\n\n\
         | clip | method | group | PSNR frame: first | last | mean | mask IoU: first | last | mean |\n\
         |---|---|---|---|---|---|---|---|---|\n",
        clips.len(),
        opts.turn.frames(),
        opts.turn.turn_frames,
        opts.turn.hold_frames,
        opts.turn.arm_swing,
        opts.size,
        opts.size,
        opts.yaws,
    );
    let psnr: fn(&TurnRow) -> f32 = |r| r.scores.psnr_frame;
    let iou: fn(&TurnRow) -> f32 = |r| r.scores.mask_iou;
    let all = "all clips";
    for clip in clips.iter().copied().chain(std::iter::once(all)) {
        for method in TURN_METHODS {
            for group in GROUPS {
                let of = |frame: Option<usize>, value| {
                    rep.mean_of(
                        method,
                        group,
                        |r| (clip == all || r.clip == clip) && frame.is_none_or(|f| r.frame == f),
                        value,
                    )
                };
                let cells = [
                    of(Some(0), psnr),
                    of(Some(last), psnr),
                    of(None, psnr),
                    of(Some(0), iou),
                    of(Some(last), iou),
                    of(None, iou),
                ];
                if cells.iter().all(|v| v.is_nan()) {
                    continue;
                }
                md.push_str(&format!("| {clip} | {method} | {group} |"));
                for (k, v) in cells.iter().enumerate() {
                    md.push_str(&if k < 3 { format!(" {v:.2} |") } else { format!(" {v:.3} |") });
                }
                md.push('\n');
            }
        }
    }
    if opts.event != EventChoice::None {
        md.push_str(&event_markdown(opts, rep));
    }
    md.push_str(&tracking_markdown(opts, rep));
    md.push_str(
        "\n![Divergent whole-frame PSNR over the turn](turn_divergent_psnr.png)\n\nContact sheets (`sheets/`): six \
         moments of each clip; rows: the camera's frame, then at yaw 180 the ground truth, the frame path, the \
         model and the oracle, then the same at yaw 90.\n",
    );
    if !rep.failed.is_empty() {
        md.push_str("\n## Failed\n\n");
        for (n, e) in &rep.failed {
            md.push_str(&format!("- {n}: {e}\n"));
        }
    }
    md
}

/// The person model's own figures: the tracked yaw's error against the true turn (the truth is only compared
/// with, never given to the model), its restarts and band resets, and its cost per frame.
fn tracking_markdown(opts: &TurnEvalOptions, rep: &TurnReport) -> String {
    let t = &rep.tracking;
    if t.is_empty() {
        return String::new();
    }
    let abs_error = |keep: &dyn Fn(&ModelTrackRow) -> bool| {
        let v: Vec<f32> = t.iter().filter(|r| keep(r)).map(|r| r.yaw_error.abs()).collect();
        mean(&v)
    };
    let median_of = |mut v: Vec<f32>| {
        v.retain(|x| x.is_finite());
        v.sort_by(f32::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f32::NAN)
    };
    let p95_of = |mut v: Vec<f32>| {
        v.retain(|x| x.is_finite());
        v.sort_by(f32::total_cmp);
        v.get((v.len() * 95 / 100).min(v.len().saturating_sub(1))).copied().unwrap_or(f32::NAN)
    };
    let median_error = median_of(t.iter().map(|r| r.yaw_error.abs()).collect());
    let p95_error = p95_of(t.iter().map(|r| r.yaw_error.abs()).collect());
    let max_error = t.iter().map(|r| r.yaw_error.abs()).fold(0.0f32, f32::max);
    let body_median = median_of(t.iter().filter_map(|r| r.body_error).map(f32::abs).collect());
    let body_frames = t.iter().filter(|r| r.body_used).count();
    let without_pose = median_of(t.iter().map(|r| r.ms - r.pose_ms).collect());
    let pose_median = median_of(t.iter().map(|r| r.pose_ms).collect());
    let last_turning = opts.turn.turn_frames.saturating_sub(1);
    let last = opts.turn.frames() - 1;
    let mut ms: Vec<f32> = t.iter().map(|r| r.ms).filter(|v| v.is_finite()).collect();
    ms.sort_by(f32::total_cmp);
    let median = ms.get(ms.len() / 2).copied().unwrap_or(f32::NAN);
    let p95 = ms.get((ms.len() * 95 / 100).min(ms.len().saturating_sub(1))).copied().unwrap_or(f32::NAN);
    let restarts: Vec<String> =
        t.iter().filter(|r| r.restarted).map(|r| format!("{} frame {}", r.clip, r.frame)).collect();
    let band_resets = t.iter().filter(|r| !r.restarted && r.reset_bands > 0).count();
    let source = if opts.model_body == ModelBody::Truth {
        "from the clip's true turn (perfect tracking: the ceiling of every way of reading the yaw, not a camera's)"
            .to_string()
    } else if opts.model_body != ModelBody::Colour {
        let read = match opts.model_body {
            ModelBody::Segmenter => "the live segmenter's pose read of each frame",
            _ => "one read of its own a frame",
        };
        let image: Vec<f32> = t.iter().filter_map(|r| r.image_turn_error).map(f32::abs).collect();
        let (image_frames, image_median) = (image.len(), median_of(image));
        format!(
            "from the body (the pose network's torso, {read}; {body_frames} of {} frames moved by it; \
             the reading alone {body_median:.1} degrees median |error|) and the turn between frames read from the \
             image ({} frames; {:.1} degrees median |error| per frame), refined by the colours within {} degrees",
            t.len(),
            image_frames,
            image_median,
            opts.model_colour_refine
        )
    } else {
        "from the frames' colours alone".to_string()
    };
    format!(
        "\nThe person model (`model` rows): yaw tracked {source}; its error against the true turn: {median_error:.1} \
         degrees median |error| over every frame ({p95_error:.1} p95, {max_error:.1} largest), mean over clips of \
         |error| {:.1} over every frame, {:.1} at the last turning frame ({}), {:.1} at the last frame; restarts: {}; \
         frames with bands reset: {}; update {:.1} ms median, {:.1} ms p95 per frame, of which the pose read \
         {pose_median:.1} ms median ({without_pose:.1} ms median without it; release build, this machine, {}x{}; \
         `turn_model.csv` has every frame).\n",
        abs_error(&|_| true),
        abs_error(&|r| r.frame == last_turning),
        last_turning,
        abs_error(&|r| r.frame == last),
        if restarts.is_empty() { "none".to_string() } else { restarts.join(", ") },
        band_resets,
        median,
        p95,
        opts.size,
        opts.size,
    )
}

/// Frames a second holds in the clips' time line (the clips are made to be played at 16 frames a second).
pub const CLIP_FPS: usize = 16;

/// The table around the event (`--event`): over every clip, per method and group, the frame before it, the frame
/// of it and one second after it ([`CLIP_FPS`] frames).
fn event_markdown(opts: &TurnEvalOptions, rep: &TurnReport) -> String {
    let at = opts.turn.turn_frames / 2;
    let frames = [at.saturating_sub(1), at, at + CLIP_FPS];
    let mut md = format!(
        "\nAround the event (`--event {}` at frame {at}), over every clip: the frame before it, the frame of it and \
         one second later ({CLIP_FPS} frames at {CLIP_FPS} frames a second; `-` past the clip's end), each scored \
         against that moment's ground truth.\n\n| method | group | PSNR frame: frame {} | {} | {} | mask IoU: frame {} | {} | {} |\n\
         |---|---|---|---|---|---|---|---|\n",
        opts.event.name(),
        frames[0],
        frames[1],
        frames[2],
        frames[0],
        frames[1],
        frames[2],
    );
    for method in TURN_METHODS {
        for group in GROUPS {
            md.push_str(&format!("| {method} | {group} |"));
            for value in [(|r: &TurnRow| r.scores.psnr_frame) as fn(&TurnRow) -> f32, |r| r.scores.mask_iou] {
                for f in frames {
                    let v = rep.mean_of(method, group, |r| r.frame == f, value);
                    md.push_str(&match v {
                        v if v.is_nan() => " - |".to_string(),
                        v if v > 1.0 => format!(" {v:.2} |"),
                        v => format!(" {v:.3} |"),
                    });
                }
            }
            md.push('\n');
        }
    }
    md
}

/// Writes `turn.csv`, `turn.md` and `turn_divergent_psnr.png`.
fn write_turn_reports(opts: &TurnEvalOptions, rep: &TurnReport) -> Result<(), EvalError> {
    let mut csv = String::from(
        "clip,frame,turn_deg,turned,method,group,psnr_frame,psnr,psnr_overlap,ssim_frame,mask_iou,depth_l1,ms_prepare,views\n",
    );
    for r in &rep.rows {
        csv.push_str(&format!(
            "\"{}\",{},{:.1},{},{},{},{:.3},{:.3},{:.3},{:.4},{:.4},{:.4},{:.1},{}\n",
            r.clip.replace('"', "\"\""),
            r.frame,
            r.turn,
            r.turned,
            r.method,
            r.group,
            r.scores.psnr_frame,
            r.scores.psnr,
            r.scores.psnr_overlap,
            r.scores.ssim_frame,
            r.scores.mask_iou,
            r.scores.depth_l1,
            r.ms_prepare,
            r.views
        ));
    }
    let p = opts.out.join("turn.csv");
    write_atomic(&p, csv.as_bytes()).map_err(|e| EvalError::io(&p, e))?;
    let mut track = String::from("clip,frame,turn_deg,yaw_deg,yaw_error_deg,body_error_deg,image_turn_error_deg,body_used,restarted,reset_bands,hull_weight,ms,pose_ms,band_error_mean,band_error_max\n");
    for r in &rep.tracking {
        let fields = [
            format!("\"{}\"", r.clip.replace('"', "\"\"")),
            r.frame.to_string(),
            format!("{:.1}", r.turn),
            format!("{:.2}", r.yaw),
            format!("{:.2}", r.yaw_error),
            r.body_error.map_or(String::new(), |e| format!("{e:.2}")),
            r.image_turn_error.map_or(String::new(), |e| format!("{e:.2}")),
            r.body_used.to_string(),
            r.restarted.to_string(),
            r.reset_bands.to_string(),
            format!("{:.3}", r.hull_weight),
            format!("{:.2}", r.ms),
            format!("{:.2}", r.pose_ms),
            format!("{:.4}", r.band_error.0),
            format!("{:.4}", r.band_error.1),
        ];
        track.push_str(&fields.join(","));
        track.push('\n');
    }
    let p = opts.out.join("turn_model.csv");
    write_atomic(&p, track.as_bytes()).map_err(|e| EvalError::io(&p, e))?;
    let p = opts.out.join("turn.md");
    write_atomic(&p, summary_markdown(opts, rep).as_bytes()).map_err(|e| EvalError::io(&p, e))?;
    plot_turn(&opts.out.join("turn_divergent_psnr.png"), opts, rep)
}

/// Divergent whole-frame PSNR over the frames: per method the mean over clips (thick) and each clip (thin).
fn plot_turn(path: &std::path::Path, opts: &TurnEvalOptions, rep: &TurnReport) -> Result<(), EvalError> {
    use plotters::prelude::*;
    let n = opts.turn.frames();
    let per_frame = |method: &str, clip: Option<&str>| -> Vec<(f32, f32)> {
        (0..n)
            .map(|f| {
                let v = rep.mean_of(
                    method,
                    "divergent",
                    |r| r.frame == f && clip.is_none_or(|c| r.clip == c),
                    |r| r.scores.psnr_frame,
                );
                (f as f32, v)
            })
            .filter(|p| p.1.is_finite())
            .collect()
    };
    let mut clips: Vec<&str> = Vec::new();
    for r in &rep.rows {
        if !clips.contains(&r.clip.as_str()) {
            clips.push(&r.clip);
        }
    }
    let values: Vec<f32> = rep
        .rows
        .iter()
        .filter(|r| r.group == "divergent")
        .map(|r| r.scores.psnr_frame)
        .filter(|v| v.is_finite())
        .collect();
    let (lo, hi) = values.iter().fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    let (lo, hi) = if lo <= hi { (lo.floor() - 1.0, hi.ceil() + 1.0) } else { (0.0, 40.0) };
    write_chart(path, (900, 500), |root| {
        let perr = |e: String| EvalError::io(path, std::io::Error::other(e));
        let mut chart = ChartBuilder::on(root)
            .caption("Divergent views over the turn (whole-frame PSNR)", ("sans-serif", 22))
            .margin(15)
            .x_label_area_size(40)
            .y_label_area_size(50)
            .build_cartesian_2d(0f32..(n.max(2) - 1) as f32, lo..hi)
            .map_err(|e| perr(e.to_string()))?;
        chart
            .configure_mesh()
            .x_desc(format!("frame (a whole turn over frames 0-{}, then facing the camera)", opts.turn.turn_frames))
            .y_desc("PSNR frame (dB)")
            .draw()
            .map_err(|e| perr(e.to_string()))?;
        let colours = [RGBColor(60, 180, 60), MAGENTA, BLUE, RED];
        for (m, method) in TURN_METHODS.iter().enumerate() {
            let c = colours[m % colours.len()];
            for clip in &clips {
                chart
                    .draw_series(LineSeries::new(per_frame(method, Some(clip)), c.mix(0.3).stroke_width(1)))
                    .map_err(|e| perr(e.to_string()))?;
            }
            chart
                .draw_series(LineSeries::new(per_frame(method, None), c.stroke_width(3)))
                .map_err(|e| perr(e.to_string()))?
                .label(format!("{method} (mean of {} clips; thin: each clip)", clips.len()))
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], c.stroke_width(3)));
        }
        let t = opts.turn.turn_frames as f32;
        chart
            .draw_series(LineSeries::new([(t, lo), (t, hi)], BLACK.mix(0.5).stroke_width(1)))
            .map_err(|e| perr(e.to_string()))?;
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .position(SeriesLabelPosition::LowerRight)
            .draw()
            .map_err(|e| perr(e.to_string()))?;
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec2;

    #[test]
    fn a_small_turn_is_played_scored_and_written() {
        let dir = tempfile::tempdir().unwrap();
        let opts = TurnEvalOptions {
            subjects: 1,
            out: dir.path().to_path_buf(),
            size: 64,
            turn: TurnOptions { turn_frames: 4, hold_frames: 1, arm_swing: 10.0 },
            yaws: vec![20.0, 90.0, 180.0],
            texture_size: 32,
            ..Default::default()
        };
        let rep = run_turn_eval(&opts, None).unwrap();
        assert!(rep.failed.is_empty(), "{:?}", rep.failed);
        // Every frame, both methods, both groups; every score finite.
        assert_eq!(rep.rows.len(), 5 * 3 * 2);
        assert!(rep.rows.iter().all(|r| r.scores.psnr_frame.is_finite() && (0.0..=1.0).contains(&r.scores.mask_iou)));
        // True geometry draws the unseen side's silhouette better than the frame path's guess.
        let iou = |m: &str| rep.mean_of(m, "divergent", |_| true, |r| r.scores.mask_iou);
        assert!(iou("oracle") > iou("frame-path") + 0.05, "{} vs {}", iou("oracle"), iou("frame-path"));
        for f in ["turn.csv", "turn.md", "turn_divergent_psnr.png", "sheets/subject_0000.png"] {
            assert!(dir.path().join(f).is_file(), "{f}");
        }
        let csv = std::fs::read_to_string(dir.path().join("turn.csv")).unwrap();
        assert_eq!(csv.lines().count(), 1 + 30);
        // Nothing to turn, or a turn out of range, is a sentence, not a panic.
        assert!(run_turn_eval(&TurnEvalOptions { subjects: 0, ..opts.clone() }, None).is_err());
        let bad = TurnEvalOptions { turn: TurnOptions { turn_frames: 2, ..opts.turn }, ..opts.clone() };
        assert!(run_turn_eval(&bad, None).is_err());
    }

    #[test]
    fn the_normalised_frame_is_the_pixel_similarity_in_cube_units() {
        // Pixel q = s p + o in a 200-pixel frame; cube x = 2 p / 200 - 1, y = 1 - 2 p / 200.
        let t = NormaliseTransform { scale: 1.5, offset: Vec2::new(-20.0, 10.0) };
        for p in [Vec2::new(30.0, 70.0), Vec2::new(100.0, 100.0), Vec2::new(0.0, 200.0)] {
            let cube = |q: Vec2| Vec2::new(2.0 * q.x / 200.0 - 1.0, 1.0 - 2.0 * q.y / 200.0);
            let (a, b) = (cube(p), cube(t.forward(p)));
            let got = to_normalised(a.extend(0.3), &t, 200);
            assert!((got.truncate() - b).length() < 1e-5, "{got:?} {b:?}");
            assert!((got.z - 0.45).abs() < 1e-6);
        }
    }
}
