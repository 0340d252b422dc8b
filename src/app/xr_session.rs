//! `r2human xr`: the person from one photo — or from a live source, frame by frame — in a headset, rendered per
//! eye on the GPU, either standing in a 360-degree panorama (VR) or as an alpha layer over the room (AR); and
//! `r2human xr --check`.
//!
//! The OpenXR session, the per-eye Vulkan renderers, frame pacing and placement live in [`crate::xr`]; this module
//! prepares the input (once for a photo; per frame on the live pipeline's worker thread for `--video`/`--camera`)
//! and hands it to the session as [`Scene`]s.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::{bail, Context, Result};

use crate::app::live::{
    camera_source, video_source, Completed, EncodeProcessor, LatestReader, LiveFrame, LiveOptions, LivePipeline,
    LiveStats,
};
use crate::app::neural::{load_interactive, NeuralAvailability, NeuralSetup};
use crate::buffer::GrayImage;
use crate::capture::{CameraRequest, SegmentMethod, SourceFactory};
use crate::compose::Mode;
use crate::io::environment::Environment;
use crate::pipeline::export::{numbered_path, person_glb, ExportOptions};
use crate::pipeline::{PrepareOptions, PreparedInput, Scene, SceneNeural, SharedNeural};
use crate::xr::{ExportFailure, ExportHook, PersonExporter, SceneFeed, SessionConfig, SessionReport, StaticScene};

/// Where the person comes from.
#[derive(Clone, Debug)]
pub enum XrInput {
    /// A photo (PNG/JPEG); its alpha channel is the mask unless `mask` is given.
    Image {
        /// The photo.
        path: PathBuf,
        /// Person mask (white = person), same size as the image; wins over `segment`.
        mask: Option<PathBuf>,
        /// Person segmentation of the photo without `mask` ([`crate::capture::segment::segment_photo`]).
        segment: SegmentMethod,
    },
    /// A video file or a folder of frames, played at `fps` (frame folders) through the live pipeline.
    Video {
        /// The file or folder.
        path: PathBuf,
        /// Frame rate of a folder of frames.
        fps: f32,
        /// Person segmentation.
        segment: SegmentMethod,
    },
    /// A camera through the live pipeline.
    Camera {
        /// Which camera and format.
        request: CameraRequest,
        /// Person segmentation.
        segment: SegmentMethod,
    },
}

/// Options of `r2human xr`.
#[derive(Clone, Debug)]
pub struct XrOptions {
    /// The person.
    pub input: XrInput,
    /// Panorama for VR (equirectangular PNG/JPEG or .hdr); the embedded one when `None`.
    pub env: Option<PathBuf>,
    /// VR or AR.
    pub mode: Mode,
    /// Stop after this many frames showing the person (`None`: until the runtime ends the session).
    pub frames: Option<u64>,
    /// Largest eye image side in pixels (a software Vulkan device cannot fill full headset resolution).
    pub eye_size: u32,
    /// Stop after this long (`None`: no limit).
    pub duration: Option<Duration>,
    /// Show the eye images in a desktop window while the session runs.
    pub mirror: bool,
    /// `--renderer`, `--models`, `--ep` (the default loads none: geometric).
    pub neural: NeuralSetup,
    /// Which engine renders the eyes (auto: the CPU reference on a software Vulkan device, the Vulkan passes on a
    /// GPU).
    pub backend: crate::app::Backend,
    /// Folder the export action writes the person to (`r2human-person-NNNNN.glb`).
    pub export_dir: PathBuf,
    /// How the export action writes the person (height, decimation; the fill is the eyes').
    pub export: ExportOptions,
    /// Also export when this many frames have shown the person (`--export-at-frame`).
    pub export_at_frames: Vec<u64>,
    /// Live sources keep a person model across the frames ([`PrepareOptions::person_model`]).
    pub person_model: bool,
    /// Source resolution live frames are prepared at (`None`: [`live_frame_resolution`] of the eye size).
    pub live_resolution: Option<usize>,
}

impl Default for XrOptions {
    fn default() -> Self {
        Self {
            input: XrInput::Image { path: PathBuf::new(), mask: None, segment: SegmentMethod::Auto },
            env: None,
            mode: Mode::Vr,
            frames: None,
            eye_size: 384,
            duration: None,
            mirror: true,
            neural: NeuralSetup::default(),
            backend: crate::app::Backend::Auto,
            export_dir: PathBuf::from("."),
            export: ExportOptions::default(),
            export_at_frames: Vec::new(),
            person_model: false,
            live_resolution: None,
        }
    }
}

/// The person the eyes show, as the export action writes it: a photo's reconstruction and person mask, or the
/// live frame the eyes last received (its smoothed mask).
#[derive(Clone)]
enum ShownPerson {
    Photo(Arc<(PreparedInput, GrayImage)>),
    Live(Arc<Completed<LiveFrame>>),
}

impl ShownPerson {
    fn parts(&self) -> (&PreparedInput, &GrayImage) {
        match self {
            ShownPerson::Photo(p) => (&p.0, &p.1),
            ShownPerson::Live(c) => (&c.output.input, &c.mask),
        }
    }
}

/// Where the feed leaves the person it last handed to the eyes, for the exporter.
type ShownSlot = Arc<Mutex<Option<ShownPerson>>>;

/// The export action of `r2human xr`: the person the eyes show, written as glTF like view's `E` key
/// ([`person_glb`] into [`numbered_path`]).
struct GltfExporter {
    shown: ShownSlot,
    dir: PathBuf,
    options: ExportOptions,
}

impl PersonExporter for GltfExporter {
    fn export(&self, frame: u64) -> Result<PathBuf, ExportFailure> {
        let shown = self.shown.lock().unwrap_or_else(|p| p.into_inner()).clone();
        let shown = shown.ok_or(ExportFailure::NothingShown)?;
        let (input, mask) = shown.parts();
        let path = numbered_path(&self.dir, frame);
        match person_glb(&path, input, mask, &self.options) {
            Ok(_) => Ok(path),
            Err(source) => Err(ExportFailure::Write { path, source }),
        }
    }
}

/// A live source as a scene feed: the newest completed frame of a [`LivePipeline`] (read without blocking), its
/// messages passed on, one message when the source changes resolution, and one when it ends (the session keeps
/// showing the last person).
pub struct LiveFeed {
    pipeline: LivePipeline<LiveFrame>,
    reader: LatestReader<Completed<LiveFrame>>,
    /// The decoder the eyes use (the worker encodes with its own instance).
    decoder: Option<SharedNeural>,
    last_sequence: u64,
    errors_seen: u64,
    ended_reported: bool,
    /// Frame size (width, height) of the last new frame, and messages about changes not yet taken.
    frame_size: Option<(usize, usize)>,
    pending: Vec<String>,
    /// The frame last handed to the eyes (for the export action).
    shown: ShownSlot,
    /// Where the pipeline's counters are left when the feed is dropped (the session's end), for the report.
    final_stats: Arc<Mutex<Option<LiveStats>>>,
}

impl Drop for LiveFeed {
    fn drop(&mut self) {
        *self.final_stats.lock().unwrap_or_else(|p| p.into_inner()) = Some(self.pipeline.stats());
    }
}

/// How much lower the live pipeline's workers are scheduled than the eyes in a headset
/// ([`LiveOptions::worker_nice`]): when both want the cores, the next eye pair goes first, so head motion keeps
/// reaching the person layer while the person's frames come less often (docs/xr.md has the measured trade).
pub const XR_LIVE_WORKER_NICE: i32 = 5;

impl LiveFeed {
    /// Starts the live pipeline (capture and worker threads) on `factory`'s source with `segment`; with a neural
    /// renderer in `neural`, the worker also runs the encoder once per new frame (on a second instance of the
    /// models) and the eyes are drawn by the decoder.
    pub fn start(
        factory: SourceFactory,
        segment: SegmentMethod,
        prepare: PrepareOptions,
        neural: &NeuralAvailability,
    ) -> Result<Self> {
        let options = LiveOptions { segment, worker_nice: XR_LIVE_WORKER_NICE, ..Default::default() };
        let worker = neural.second_instance().context("loading the neural models for the live worker")?;
        let pipeline = LivePipeline::start(factory, EncodeProcessor::new(prepare, worker), options)?;
        tracing::info!("live input: {}", pipeline.describe());
        let reader = pipeline.reader();
        Ok(Self {
            pipeline,
            reader,
            decoder: neural.renderer.clone(),
            last_sequence: 0,
            errors_seen: 0,
            ended_reported: false,
            frame_size: None,
            pending: Vec::new(),
            shown: ShownSlot::default(),
            final_stats: Arc::default(),
        })
    }
}

impl LiveFeed {
    /// This feed, leaving the frame it hands to the eyes in `shown` (for the export action).
    fn sharing_shown(mut self, shown: &ShownSlot) -> Self {
        self.shown = Arc::clone(shown);
        self
    }

    /// This feed, leaving the pipeline's counters in `stats` when it is dropped.
    fn reporting_to(mut self, stats: &Arc<Mutex<Option<LiveStats>>>) -> Self {
        self.final_stats = Arc::clone(stats);
        self
    }
}

impl SceneFeed for LiveFeed {
    fn poll(&mut self) -> Option<Arc<Scene>> {
        let done = self.reader.get()?;
        if done.sequence == self.last_sequence {
            return None;
        }
        self.last_sequence = done.sequence;
        let size = (done.mask.width, done.mask.height);
        if let Some(old) = self.frame_size.filter(|&old| old != size) {
            self.pending.push(format!(
                "the source `{}` changed resolution from {}x{} to {}x{}",
                self.pipeline.describe(),
                old.0,
                old.1,
                size.0,
                size.1
            ));
        }
        self.frame_size = Some(size);
        *self.shown.lock().unwrap_or_else(|p| p.into_inner()) = Some(ShownPerson::Live(Arc::clone(done)));
        let neural = match (&self.decoder, &done.output.neural) {
            (Some(renderer), Some(encoded)) => {
                Some(SceneNeural { renderer: Arc::clone(renderer), encoded: encoded.clone() })
            }
            _ => None,
        };
        Some(Arc::new(Scene::from_prepared(&done.output.input, neural)))
    }

    fn person_absent(&self) -> bool {
        self.pipeline.person_absent()
    }

    fn take_messages(&mut self) -> Vec<String> {
        let stats = self.pipeline.stats();
        let mut out = std::mem::take(&mut self.pending);
        if stats.errors > self.errors_seen {
            let new = (stats.errors - self.errors_seen) as usize;
            let recent = self.pipeline.messages();
            out.extend(recent.iter().skip(recent.len().saturating_sub(new)).cloned());
            self.errors_seen = stats.errors;
        }
        if !self.ended_reported && self.pipeline.is_finished() {
            self.ended_reported = true;
            out.push(format!(
                "the source `{}` ended after {} frames; the session goes on with the last person",
                self.pipeline.describe(),
                stats.read
            ));
        }
        out
    }
}

/// What an `xr` run did: the session's report and, for a live source, the live pipeline's counters.
#[derive(Debug)]
pub struct XrRunReport {
    /// The OpenXR session's report.
    pub session: SessionReport,
    /// The live pipeline's counters, latency quantiles and stage medians (`None` for a photo).
    pub live: Option<LiveStats>,
}

impl std::fmt::Display for XrRunReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.session)?;
        if let Some(live) = &self.live {
            write!(f, "\n{}", live.report_line())?;
        }
        Ok(())
    }
}

/// Prepares the input (or starts the live source) and runs one OpenXR session; returns what it did.
pub fn run_xr_session(opts: &XrOptions) -> Result<XrRunReport> {
    if !(16..=4096).contains(&opts.eye_size) {
        bail!("eye size {} is out of range: use 16 to 4096 pixels", opts.eye_size);
    }
    if opts.frames == Some(0) {
        bail!("--frames 0 shows nothing: give at least 1, or leave it out to run until the headset session ends");
    }
    opts.export.validate()?;
    check_live_resolution(opts.live_resolution)?;
    if let Some(0) = opts.export_at_frames.iter().copied().min() {
        bail!("--export-at-frame 0 is before the person is shown: give 1 or more");
    }
    let live = !matches!(opts.input, XrInput::Image { .. });
    let neural = load_interactive(&opts.neural, live)?;
    let shown = ShownSlot::default();
    let live_stats: Arc<Mutex<Option<LiveStats>>> = Arc::default();
    let feed: Box<dyn SceneFeed> = match &opts.input {
        XrInput::Image { path, mask, segment } => {
            let person = crate::capture::segment::segment_photo(path, mask.as_deref(), segment)?;
            // A photo pays for the back image once (the pose network finds the face); live frames do not.
            let back_pose =
                crate::pipeline::load_back_pose(crate::pipeline::warp::OcclusionFill::default(), &opts.neural.options);
            // The geometry `render` draws (`--geometry auto`), prepared once.
            let auto = crate::pipeline::auto_still_options(opts.neural.models.as_deref(), &opts.neural.options)?;
            let prepared = PreparedInput::prepare(
                &person.photo.rgb,
                &person.mask,
                &PrepareOptions { back_pose, coarse_views: true, ..auto },
            )
            .with_context(|| format!("preparing {}", path.display()))?;
            // The encoder runs once for a photo; the eyes run only the decoder.
            let eye_neural = match &neural.renderer {
                Some(shared) => {
                    let encoded = shared.lock().unwrap_or_else(|p| p.into_inner()).encode(&prepared);
                    match encoded {
                        Ok(encoded) => Some(SceneNeural { renderer: Arc::clone(shared), encoded }),
                        Err(e) => {
                            tracing::warn!("the neural encoder failed on this photo; the eyes are geometric: {e}");
                            None
                        }
                    }
                }
                None => None,
            };
            let scene = Scene::from_prepared(&prepared, eye_neural);
            *shown.lock().unwrap_or_else(|p| p.into_inner()) =
                Some(ShownPerson::Photo(Arc::new((prepared, person.mask))));
            Box::new(StaticScene::new(scene))
        }
        XrInput::Video { path, fps, segment } => {
            if !(*fps > 0.0 && fps.is_finite()) {
                bail!("--fps {fps} must be a positive number of frames per second");
            }
            let frames = frame_options(opts)?;
            let feed = LiveFeed::start(video_source(path, *fps), segment.clone(), frames, &neural)
                .with_context(|| format!("opening {}", path.display()))?;
            Box::new(feed.sharing_shown(&shown).reporting_to(&live_stats))
        }
        XrInput::Camera { request, segment } => {
            let feed = LiveFeed::start(camera_source(request.clone()), segment.clone(), frame_options(opts)?, &neural)
                .with_context(|| format!("opening camera {}", request.index))?;
            Box::new(feed.sharing_shown(&shown).reporting_to(&live_stats))
        }
    };
    let environment = match (opts.mode, &opts.env) {
        (Mode::Ar, _) => None,
        (Mode::Vr, Some(p)) => Some(Environment::load(p)?),
        (Mode::Vr, None) => Some(Environment::default_embedded()),
    };
    let config = SessionConfig {
        mode: opts.mode,
        max_person_frames: opts.frames,
        max_duration: opts.duration,
        eye_max_side: opts.eye_size,
        capture: false,
        mirror: opts.mirror,
        export: Some(ExportHook(Arc::new(GltfExporter {
            shown,
            dir: opts.export_dir.clone(),
            options: opts.export.clone(),
        }))),
        export_at_frames: opts.export_at_frames.clone(),
        backend: opts.backend,
    };
    let report = crate::xr::run_session(&config, feed, environment)?;
    if let crate::xr::EndReason::RenderFailed(e) = &report.end {
        bail!("the person renderer failed during the XR session: {e}");
    }
    let live = live_stats.lock().unwrap_or_else(|p| p.into_inner()).take();
    Ok(XrRunReport { session: report, live })
}

/// The options the session's live frames are prepared with ([`crate::pipeline::auto_frame_options`]) at
/// `--live-resolution` or [`live_frame_resolution`], with the coarse mesh the eyes draw when their pixels are that
/// large.
fn frame_options(opts: &XrOptions) -> Result<PrepareOptions> {
    // `--live-resolution` was checked with the other options (`run_xr_session`).
    let suited = live_frame_resolution(opts.eye_size);
    let resolution = opts.live_resolution.unwrap_or(suited);
    tracing::info!(
        "live frames are prepared at {resolution}x{resolution} ({suited} holds what eyes of at most {} pixels show of \
         the person at the default distance; --live-resolution changes it)",
        opts.eye_size
    );
    let frames = crate::pipeline::auto_frame_options(opts.neural.models.as_deref(), resolution, &opts.neural.options)?;
    Ok(PrepareOptions { coarse_views: true, person_model: opts.person_model, ..frames })
}

/// An error saying the range when `--live-resolution` is outside 64 to the still photos' resolution.
fn check_live_resolution(resolution: Option<usize>) -> Result<()> {
    match resolution {
        Some(r) if !(LIVE_RESOLUTION_STEP..=crate::geometry::SOURCE_RESOLUTION).contains(&r) => bail!(
            "--live-resolution {r} is out of range: use {LIVE_RESOLUTION_STEP} to {} pixels",
            crate::geometry::SOURCE_RESOLUTION
        ),
        _ => Ok(()),
    }
}

/// Live frame resolutions are multiples of this many pixels (and at least this many).
pub const LIVE_RESOLUTION_STEP: usize = 64;

/// The smallest resolution (a multiple of [`LIVE_RESOLUTION_STEP`] from 256, at most the still photos'
/// [`crate::geometry::SOURCE_RESOLUTION`]) at which a live frame holds every detail an eye whose largest side is
/// `eye_side` pixels can show of the person at the default placement distance
/// ([`crate::xr::placement::DEFAULT_DISTANCE`]): one source pixel of the 2 m body cube no larger than one eye pixel
/// there, for a 90° field of view over that side (headsets' are wider, so their pixels are larger). A live frame
/// costs about the square of its resolution (`bench-live --resolution`), and what the eye cannot show only takes
/// the cores the eyes draw with; nearer than the default distance the person gets softer (docs/xr.md).
pub fn live_frame_resolution(eye_side: u32) -> usize {
    // Eye pixel at distance D over a 90° field of view: D * 2 * tan(45°) / side metres; source pixel: 2 m / res.
    let needed = eye_side as f32 / crate::xr::placement::DEFAULT_DISTANCE;
    let steps = (needed / LIVE_RESOLUTION_STEP as f32).ceil().max(0.0) as usize;
    (steps * LIVE_RESOLUTION_STEP).clamp(4 * LIVE_RESOLUTION_STEP, crate::geometry::SOURCE_RESOLUTION)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_options_are_refused_with_a_sentence() {
        let image = |p: &str| XrInput::Image { path: p.into(), mask: None, segment: SegmentMethod::Auto };
        let opts = XrOptions { input: image("missing.png"), eye_size: 8, ..Default::default() };
        assert!(run_xr_session(&opts).unwrap_err().to_string().contains("eye size 8"));
        let opts = XrOptions { input: image("missing.png"), frames: Some(0), ..Default::default() };
        assert!(run_xr_session(&opts).unwrap_err().to_string().contains("--frames 0"));
        let opts = XrOptions { input: image("/nonexistent/person.png"), ..Default::default() };
        assert!(run_xr_session(&opts).is_err());
        let video = XrInput::Video { path: "/nonexistent/frames".into(), fps: 10.0, segment: SegmentMethod::Alpha };
        let err = run_xr_session(&XrOptions { input: video, ..Default::default() }).unwrap_err();
        assert!(format!("{err:#}").contains("/nonexistent/frames"), "{err:#}");
        let opts = XrOptions { input: image("missing.png"), export_at_frames: vec![5, 0], ..Default::default() };
        assert!(run_xr_session(&opts).unwrap_err().to_string().contains("--export-at-frame 0"));
        let export = ExportOptions { height_m: 9.0, ..Default::default() };
        let opts = XrOptions { input: image("missing.png"), export, ..Default::default() };
        assert!(run_xr_session(&opts).unwrap_err().to_string().contains("height of 9 m"));
        let video = XrInput::Video { path: "x".into(), fps: 0.0, segment: SegmentMethod::Alpha };
        assert!(run_xr_session(&XrOptions { input: video, ..Default::default() })
            .unwrap_err()
            .to_string()
            .contains("--fps"));
        let opts = XrOptions { input: image("missing.png"), live_resolution: Some(8), ..Default::default() };
        assert!(run_xr_session(&opts).unwrap_err().to_string().contains("--live-resolution 8"));
    }

    #[test]
    fn live_frames_hold_what_the_eye_shows_at_the_default_distance() {
        // An eye pixel of a 90° view over `side` pixels at 1.75 m: 3.5 / side metres; a source pixel: 2 / res.
        let eye_pixel = |side: u32| 2.0 * crate::xr::placement::DEFAULT_DISTANCE / side as f32;
        for side in [16, 64, 200, 342, 384, 512, 700, 768, 900, 1024, 2048, 4096] {
            let res = live_frame_resolution(side);
            assert_eq!(res % LIVE_RESOLUTION_STEP, 0, "eye {side}: {res}");
            assert!((256..=crate::geometry::SOURCE_RESOLUTION).contains(&res), "eye {side}: {res}");
            // Fine enough, unless capped at the stills' resolution...
            assert!(2.0 / res as f32 <= eye_pixel(side) || res == crate::geometry::SOURCE_RESOLUTION, "eye {side}");
            // ...and no finer than it needs to be, unless at the floor.
            let coarser = res - LIVE_RESOLUTION_STEP;
            assert!(2.0 / coarser as f32 > eye_pixel(side) || res == 256, "eye {side}: {res}");
        }
        assert_eq!(live_frame_resolution(384), 256);
        assert_eq!(live_frame_resolution(768), 448);
        assert_eq!(live_frame_resolution(2048), crate::geometry::SOURCE_RESOLUTION);
    }
}
