//! The live per-frame pipeline: a capture thread reads the source, a worker thread runs
//! segment -> smoothing -> per-frame processing (geometry, encoder) once per new frame, and the display loop reads
//! the latest completed frame without ever waiting.
//!
//! - Frames are never queued: the capture thread writes into a one-slot mailbox; a frame still waiting there when
//!   the next one arrives is dropped (counted in [`LiveStats::dropped`]). So the worker always starts on the
//!   newest frame and latency stays bounded when the pipeline is slower than the camera.
//! - Completed frames are published as `Arc`s in a slot the worker holds only for a pointer swap ("double
//!   buffered"): the display reads it with `try_lock` through a [`LatestReader`], falling back to the frame it
//!   already has, so it never blocks.
//! - Masks are smoothed over time ([`MaskSmoother`]), with a reset on large change.
//! - File sources are paced to their frame rate (as a camera would deliver them); cameras pace themselves.
//! - Errors from the source or a stage become messages ([`LivePipeline::messages`]); recoverable ones never stop
//!   the session, and the display keeps the last good frame.
//!
//! Offline rendering ([`render_video`]) runs the same stages sequentially, one output PNG per input frame.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::buffer::{GrayImage, RgbaImage};
use crate::capture::smooth::MaskSmoother;
use crate::capture::stats::{DurationHistogram, StageStats, StageSummary};
use crate::capture::{CaptureError, Frame, FrameSource, SegmentMethod, Segmenter, SourceEvent, SourceFactory};
use crate::geometry::Camera;
use crate::pipeline::frame::{mask_iou, FramePath, PlacementRefresh};
use crate::pipeline::input::{normalise, NormalisedInput};
use crate::pipeline::person_model::PersonModel;
use crate::pipeline::warp::OcclusionFill;
use crate::pipeline::{NeuralInput, PipelineError, PrepareOptions, PreparedInput, SharedNeural, ViewRenderer};

/// Errors of the live loop and offline video rendering.
#[derive(Debug, thiserror::Error)]
pub enum LiveError {
    /// The source could not be opened, or segmentation could not be set up.
    #[error(transparent)]
    Capture(#[from] CaptureError),
    /// A per-frame stage failed on one frame (the frame is skipped).
    #[error("frame {index}: {source}")]
    Stage {
        /// Frame index in the source.
        index: u64,
        /// The stage's error.
        #[source]
        source: PipelineError,
    },
    /// An output file could not be written.
    #[error("cannot write `{path}`: {reason}")]
    Output {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// A frame's PNG could not be written.
    #[error("cannot write `{path}`: {source}")]
    WriteFrame {
        /// The file.
        path: PathBuf,
        /// Why.
        source: crate::io::image_io::IoError,
    },
    /// The source produced no usable frame at all.
    #[error("no frame of `{0}` could be processed; see the messages above")]
    NothingRendered(String),
    /// A pipeline thread could not be started.
    #[error("cannot start the live pipeline: {0}")]
    Thread(String),
}

/// Turns a segmented frame into the per-frame product the views are rendered from (normalised input, geometry,
/// encoder features). Runs on the worker thread, once per new frame.
pub trait FrameProcessor: Send + 'static {
    /// What the views need.
    type Output: Send + Sync + 'static;
    /// Processes one frame with its (smoothed) mask; records its own stage timings in `stats`.
    fn process(
        &mut self,
        frame: &Frame,
        mask: &GrayImage,
        stats: &mut StageStats,
    ) -> Result<Self::Output, PipelineError>;

    /// Forgets what earlier frames left behind (temporal smoothing): the next frame starts a new shot, e.g. a photo
    /// of another size in a folder.
    fn reset(&mut self) {}

    /// The person's world landmarks the segmenter read on the frame [`FrameProcessor::process`] gets next
    /// ([`crate::capture::Segmenter::body_world`]), before it is called; `None` when it read none. Ignored by
    /// default.
    fn body(&mut self, _world: Option<&[glam::Vec3]>) {}
}

/// The processor available on every build: normalisation of the person into the body cube (stage "normalise").
#[derive(Clone, Debug)]
pub struct NormaliseProcessor {
    /// Source resolution (512 in the paper).
    pub resolution: usize,
}

impl FrameProcessor for NormaliseProcessor {
    type Output = NormalisedInput;

    fn process(
        &mut self,
        frame: &Frame,
        mask: &GrayImage,
        stats: &mut StageStats,
    ) -> Result<NormalisedInput, PipelineError> {
        Ok(stats.time("normalise", || normalise(&frame.rgb, mask, self.resolution))?)
    }
}

/// The per-frame stages of the core pipeline: the frame path ([`FramePath`]: normalise -> one-shell geometry ->
/// smoothing over time -> mesh and source view straight from the depth maps; the back image's face at its own
/// rate). Stage names in the statistics are the frame path's.
pub struct PrepareProcessor {
    path: FramePath,
    /// The person kept across frames ([`PrepareOptions::person_model`]).
    model: Option<Box<PersonModel>>,
    /// The segmenter's world landmarks of the next frame ([`FrameProcessor::body`]).
    body: Option<Vec<glam::Vec3>>,
    /// Whether the segmenter has handed landmarks on: from then on the model reads no body of its own.
    segmenter_reads_body: bool,
}

impl PrepareProcessor {
    /// A processor preparing frames with `options` ([`FramePath::new`]: frames' geometry, warm-started body fit;
    /// then the person model unless `options.person_model` is off).
    pub fn new(options: PrepareOptions) -> Self {
        // The model reads the body's orientation with the back image's pose network when it is loaded.
        let model = options.person_model.then(|| Box::new(PersonModel::new().with_pose(options.back_pose.clone())));
        // With the model, a frame is meshed once, after the model has changed its surfaces.
        let path = if model.is_some() { FramePath::new(options).without_meshes() } else { FramePath::new(options) };
        Self { path, model, body: None, segmenter_reads_body: false }
    }

    /// The options frames are prepared with.
    pub fn options(&self) -> &PrepareOptions {
        self.path.options()
    }
}

impl FrameProcessor for PrepareProcessor {
    type Output = PreparedInput;

    fn process(
        &mut self,
        frame: &Frame,
        mask: &GrayImage,
        stats: &mut StageStats,
    ) -> Result<PreparedInput, PipelineError> {
        let mut prepared = self.path.prepare(&frame.rgb, mask)?;
        let body = self.body.take();
        if let Some(model) = self.model.as_mut() {
            // The segmenter's pose read when it gives one (no second run of the pose network), else the model's own.
            let step = if self.segmenter_reads_body {
                model.update_with_world(&mut prepared, body.as_deref())
            } else {
                model.update(&mut prepared)
            };
            if step.restarted || !step.reset_bands.is_empty() {
                tracing::info!("frame {}: person model {}", frame.index, step.describe());
            }
            crate::pipeline::frame::finish_meshes(&mut prepared, self.path.options())?;
        }
        for (name, d) in &prepared.timings.0 {
            stats.record(name, *d);
        }
        Ok(prepared)
    }

    fn reset(&mut self) {
        self.path.reset();
        if let Some(model) = self.model.as_mut() {
            model.reset();
        }
    }

    fn body(&mut self, world: Option<&[glam::Vec3]>) {
        self.segmenter_reads_body |= world.is_some();
        self.body = world.map(<[glam::Vec3]>::to_vec);
    }
}

/// One completed live frame for the views: the prepared input and, with the neural renderer, the encoder's
/// features of it (computed once, on the worker thread).
#[derive(Clone, Debug)]
pub struct LiveFrame {
    /// Normalised input, geometry, mesh and source view.
    pub input: PreparedInput,
    /// The encoder's output for `input` (`None`: geometric renderer, or the encoder failed on this frame).
    pub neural: Option<NeuralInput>,
}

/// Frames one run of the encoder serves at most on a live source ([`EncodeProcessor`]): every other frame reuses
/// the features of the frame before, while the person's silhouette stays within [`FEATURES_KEEP_IOU`] of the one
/// they were made on. On the CPU the encoder costs about as much as the rest of a frame's geometry.
pub const ENCODE_EVERY: u64 = 2;

/// Mask IoU (normalised frame) with the frame the kept features were made on below which the encoder runs again.
pub const FEATURES_KEEP_IOU: f32 = 0.97;

/// [`PrepareProcessor`] followed by the neural encoder (stage "encoder") on the worker thread, at most every
/// [`ENCODE_EVERY`] frames while the person holds still (the decoder then draws the new frame's geometry and colours
/// with the features of the frame before). Without a neural renderer it only prepares. An encoder failure is a
/// message and the frame is still shown, drawn by the geometric renderer.
pub struct EncodeProcessor {
    prepare: PrepareProcessor,
    neural: Option<SharedNeural>,
    encodes: Arc<AtomicU64>,
    /// The last features, the normalised mask they were made on and the frames they have served.
    kept: Option<(NeuralInput, GrayImage, u64)>,
}

impl EncodeProcessor {
    /// A processor preparing with `options` and encoding with `neural` (give the worker its own instance, see
    /// [`crate::app::neural::NeuralAvailability::second_instance`], so the display's decoder never waits for it).
    pub fn new(options: PrepareOptions, neural: Option<SharedNeural>) -> Self {
        Self { prepare: PrepareProcessor::new(options), neural, encodes: Arc::new(AtomicU64::new(0)), kept: None }
    }

    /// This processor making every body placement on the frame it is due on
    /// ([`PlacementRefresh::Inline`]): for sources drawn frame by frame, where the same frames give the same
    /// output.
    pub fn refreshing_inline(mut self) -> Self {
        self.prepare.path.set_refresh(PlacementRefresh::Inline);
        self
    }

    /// A counter of encoder runs (shared: read it while the worker runs).
    pub fn encode_counter(&self) -> Arc<AtomicU64> {
        Arc::clone(&self.encodes)
    }
}

impl FrameProcessor for EncodeProcessor {
    type Output = LiveFrame;

    fn process(&mut self, frame: &Frame, mask: &GrayImage, stats: &mut StageStats) -> Result<LiveFrame, PipelineError> {
        let input = self.prepare.process(frame, mask, stats)?;
        let Some(shared) = &self.neural else { return Ok(LiveFrame { input, neural: None }) };
        if let Some((features, made_on, served)) = self.kept.as_mut() {
            if *served < ENCODE_EVERY && mask_iou(made_on, &input.normalised.mask) >= FEATURES_KEEP_IOU {
                *served += 1;
                return Ok(LiveFrame { neural: Some(features.clone()), input });
            }
        }
        let t = Instant::now();
        let encoded = shared.lock().unwrap_or_else(|p| p.into_inner()).encode(&input);
        stats.record("encoder", t.elapsed());
        self.encodes.fetch_add(1, Ordering::Relaxed);
        match encoded {
            Ok(n) => {
                self.kept = Some((n.clone(), input.normalised.mask.clone(), 1));
                Ok(LiveFrame { input, neural: Some(n) })
            }
            Err(e) => {
                self.kept = None;
                tracing::warn!("frame {}: the neural encoder failed, drawing it geometrically: {e}", frame.index);
                Ok(LiveFrame { input, neural: None })
            }
        }
    }
    fn reset(&mut self) {
        self.prepare.reset();
        self.kept = None;
    }

    fn body(&mut self, world: Option<&[glam::Vec3]>) {
        self.prepare.body(world);
    }
}

/// Options of the live loop.
#[derive(Clone, Debug)]
pub struct LiveOptions {
    /// How frames are segmented.
    pub segment: SegmentMethod,
    /// Weight of the new mask in the temporal EMA (1 = no smoothing).
    pub mask_alpha: f32,
    /// IoU with the smoothed mask below which smoothing restarts (a cut, a person entering).
    pub mask_reset_iou: f32,
    /// Pace file sources to their nominal frame rate (`false`: read as fast as possible, still dropping).
    pub pace: bool,
    /// Samples per stage for the medians.
    pub stats_window: usize,
    /// Messages kept for display.
    pub max_messages: usize,
    /// How much lower the segment and frame threads (and the threads they start: their thread pool, ONNX
    /// Runtime's) are scheduled than the rest of the process, as a nice increment: when the display's own work
    /// and a frame both want the cores, the display goes first. 0 (the default) leaves them alike; `xr` lowers them
    /// ([`crate::app::xr_session`]).
    pub worker_nice: i32,
}

impl Default for LiveOptions {
    fn default() -> Self {
        Self {
            segment: SegmentMethod::Auto,
            mask_alpha: 0.6,
            mask_reset_iou: 0.6,
            pace: true,
            stats_window: 120,
            max_messages: 8,
            worker_nice: 0,
        }
    }
}

/// One completed frame: what the display renders views from until the next one.
#[derive(Debug)]
pub struct Completed<T> {
    /// Index of the source frame.
    pub frame_index: u64,
    /// Its timestamp in the source.
    pub timestamp: Duration,
    /// The smoothed mask used (frame size).
    pub mask: GrayImage,
    /// The processor's output.
    pub output: T,
    /// Time from the frame's arrival to its completion.
    pub latency: Duration,
    /// Completion sequence number (1, 2, …).
    pub sequence: u64,
}

/// Counters and stage medians of a live session.
#[derive(Clone, Debug, Default)]
pub struct LiveStats {
    /// Frames read from the source.
    pub read: u64,
    /// Frames dropped because the worker was busy.
    pub dropped: u64,
    /// Frames fully processed.
    pub completed: u64,
    /// Errors reported (source and stages).
    pub errors: u64,
    /// Frames whose segmentation found no person (not processed, not errors).
    pub no_person: u64,
    /// Per-stage medians ("segment", "smooth", processor stages, "frame" = arrival to completion).
    pub stages: Vec<StageSummary>,
    /// Completed frames per second over the window.
    pub throughput_fps: f64,
    /// Frames per second arriving from the source.
    pub source_fps: f64,
    /// Median time from a frame's arrival to its completion, over every completed frame.
    pub latency_p50: Duration,
    /// 95th percentile of the same.
    pub latency_p95: Duration,
}

impl LiveStats {
    /// One line for a session report: `live: 600 frames read, 352 completed (17.4 per second), 248 dropped, 0
    /// without a person, 0 errors; latency (arrival -> completion) p50 124 ms, p95 193 ms` (the rate over the
    /// statistics window, the latency over every completed frame).
    pub fn report_line(&self) -> String {
        format!(
            "live: {} frames read, {} completed ({:.1} per second), {} dropped, {} without a person, {} errors; \
             latency (arrival -> completion) p50 {:.0} ms, p95 {:.0} ms",
            self.read,
            self.completed,
            self.throughput_fps,
            self.dropped,
            self.no_person,
            self.errors,
            self.latency_p50.as_secs_f64() * 1e3,
            self.latency_p95.as_secs_f64() * 1e3
        )
    }

    /// A one-line overlay: `segment 210.0 ms · normalise 8.1 ms · frame 230.2 ms · 4.2/30.0 fps · 12 dropped`.
    pub fn overlay_line(&self) -> String {
        let mut parts: Vec<String> =
            self.stages.iter().map(|s| format!("{} {:.1} ms", s.name, s.median_ms())).collect();
        parts.push(format!("{:.1}/{:.1} fps", self.throughput_fps, self.source_fps));
        parts.push(format!("{} dropped", self.dropped));
        parts.join(" · ")
    }
}

/// A one-value slot published by one thread and read without blocking by another.
pub struct LatestSlot<T> {
    slot: Mutex<Option<Arc<T>>>,
}

impl<T> Default for LatestSlot<T> {
    fn default() -> Self {
        Self { slot: Mutex::new(None) }
    }
}

impl<T> LatestSlot<T> {
    /// Replaces the value (the lock is held only for the pointer swap).
    pub fn publish(&self, value: Arc<T>) {
        let old = self.slot.lock().unwrap_or_else(|p| p.into_inner()).replace(value);
        // The previous value (possibly a whole prepared frame) is freed outside the lock.
        drop(old);
    }

    /// The current value, or `None` when empty or momentarily locked by the publisher.
    pub fn try_get(&self) -> Option<Arc<T>> {
        match self.slot.try_lock() {
            Ok(g) => g.clone(),
            Err(std::sync::TryLockError::Poisoned(p)) => p.into_inner().clone(),
            Err(std::sync::TryLockError::WouldBlock) => None,
        }
    }
}

/// The display side's view of a [`LatestSlot`]: keeps the frame it has, swaps to a newer one when available.
pub struct LatestReader<T> {
    slot: Arc<LatestSlot<T>>,
    current: Option<Arc<T>>,
}

impl<T> LatestReader<T> {
    /// The newest value if the slot could be read now, else the one held; never blocks.
    pub fn get(&mut self) -> Option<&Arc<T>> {
        if let Some(v) = self.slot.try_get() {
            self.current = Some(v);
        }
        self.current.as_ref()
    }
}

struct Shared<T> {
    mailbox: Mutex<Option<(Frame, Instant)>>,
    wake: Condvar,
    /// The newest segmented frame, waiting for the processing thread (one slot, as the mailbox).
    segmented: Mutex<Option<Segmented>>,
    segmented_wake: Condvar,
    latest: Arc<LatestSlot<Completed<T>>>,
    stats: Mutex<StageStats>,
    arrivals: Mutex<StageStats>,
    /// Arrival -> completion of every completed frame.
    latency: Mutex<DurationHistogram>,
    messages: Mutex<Vec<String>>,
    max_messages: usize,
    read: AtomicU64,
    dropped: AtomicU64,
    completed: AtomicU64,
    errors: AtomicU64,
    /// Frames whose segmentation found no person.
    no_person: AtomicU64,
    /// The newest segmented frame held no person (cleared by the next frame that holds one).
    absent: AtomicBool,
    stop: AtomicBool,
    source_done: AtomicBool,
    segmenter_done: AtomicBool,
    worker_done: AtomicBool,
}

/// A frame segmented by the first worker thread, waiting for the second.
struct Segmented {
    frame: Frame,
    arrived: Instant,
    mask: GrayImage,
    /// The person's world landmarks the segmenter read ([`crate::capture::Segmenter::body_world`]).
    body: Option<Vec<glam::Vec3>>,
    /// The frame starts a new shot (another size): the processor forgets earlier frames first.
    new_shot: bool,
    stats: StageStats,
}

impl<T> Shared<T> {
    fn report(&self, message: String) {
        tracing::warn!("{message}");
        self.errors.fetch_add(1, Ordering::Relaxed);
        let mut m = self.messages.lock().unwrap_or_else(|p| p.into_inner());
        if m.len() == self.max_messages.max(1) {
            m.remove(0);
        }
        m.push(message);
    }
}

/// A running live session (capture thread + worker thread). Dropping it stops both.
pub struct LivePipeline<T: Send + Sync + 'static> {
    shared: Arc<Shared<T>>,
    description: String,
    live: bool,
    threads: Vec<JoinHandle<()>>,
}

impl<T: Send + Sync + 'static> LivePipeline<T> {
    /// Opens the source (on the capture thread, returning its open error here) and starts both threads.
    pub fn start<P>(factory: SourceFactory, processor: P, options: LiveOptions) -> Result<Self, LiveError>
    where
        P: FrameProcessor<Output = T>,
    {
        let shared = Arc::new(Shared {
            mailbox: Mutex::new(None),
            wake: Condvar::new(),
            segmented: Mutex::new(None),
            segmented_wake: Condvar::new(),
            latest: Arc::new(LatestSlot::default()),
            stats: Mutex::new(StageStats::new(options.stats_window)),
            arrivals: Mutex::new(StageStats::new(options.stats_window)),
            latency: Mutex::new(DurationHistogram::default()),
            messages: Mutex::new(Vec::new()),
            max_messages: options.max_messages,
            read: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
            completed: AtomicU64::new(0),
            errors: AtomicU64::new(0),
            no_person: AtomicU64::new(0),
            absent: AtomicBool::new(false),
            stop: AtomicBool::new(false),
            source_done: AtomicBool::new(false),
            segmenter_done: AtomicBool::new(false),
            worker_done: AtomicBool::new(false),
        });
        let (opened_tx, opened_rx) = mpsc::channel::<Result<(String, bool), CaptureError>>();
        let cap_shared = Arc::clone(&shared);
        let pace = options.pace;
        let capture = spawn("r2human-capture", move || match factory() {
            Ok(mut source) => {
                let _ = opened_tx.send(Ok((source.describe(), source.is_live())));
                capture_loop(source.as_mut(), &cap_shared, pace);
            }
            Err(e) => {
                cap_shared.source_done.store(true, Ordering::SeqCst);
                let _ = opened_tx.send(Err(e));
            }
        })?;
        let (description, live) = match opened_rx.recv() {
            Ok(Ok(d)) => d,
            Ok(Err(e)) => {
                let _ = capture.join();
                return Err(e.into());
            }
            Err(_) => {
                let _ = capture.join();
                return Err(LiveError::Thread("the capture thread ended while opening the source".into()));
            }
        };
        let seg_shared = Arc::clone(&shared);
        let seg_options = options.clone();
        let nice = options.worker_nice;
        let segmenter = spawn("r2human-segment", move || {
            // Before the segmenter is built, so that ONNX Runtime's threads inherit it.
            lower_this_threads_priority(nice);
            segment_loop(&seg_shared, &seg_options);
            seg_shared.segmenter_done.store(true, Ordering::SeqCst);
            seg_shared.segmented_wake.notify_all();
        })?;
        let work_shared = Arc::clone(&shared);
        let worker = spawn("r2human-frame", move || {
            lower_this_threads_priority(nice);
            // A pool of its own, started from this thread so its workers share its priority; the frame's parallel
            // stages run there instead of in the global pool the display may draw with.
            match rayon::ThreadPoolBuilder::new().thread_name(|i| format!("r2human-frame-{i}")).build() {
                Ok(pool) => pool.install(|| process_loop(&work_shared, processor)),
                Err(e) => {
                    tracing::debug!("no thread pool of its own for the frame path ({e}); it shares the global one");
                    process_loop(&work_shared, processor)
                }
            }
            work_shared.worker_done.store(true, Ordering::SeqCst);
        })?;
        Ok(Self { shared, description, live, threads: vec![capture, segmenter, worker] })
    }

    /// The source's description.
    pub fn describe(&self) -> &str {
        &self.description
    }

    /// Is the source real-time (a camera, the live synthetic source), one that never ends by itself?
    pub fn is_live(&self) -> bool {
        self.live
    }

    /// A non-blocking reader of the latest completed frame, for the display loop.
    pub fn reader(&self) -> LatestReader<Completed<T>> {
        LatestReader { slot: Arc::clone(&self.shared.latest), current: None }
    }

    /// Counters and stage medians (takes two short locks; call it at most a few times per second).
    pub fn stats(&self) -> LiveStats {
        let s = self.shared.stats.lock().unwrap_or_else(|p| p.into_inner());
        let arrivals = self.shared.arrivals.lock().unwrap_or_else(|p| p.into_inner());
        let latency = self.shared.latency.lock().unwrap_or_else(|p| p.into_inner());
        LiveStats {
            read: self.shared.read.load(Ordering::Relaxed),
            dropped: self.shared.dropped.load(Ordering::Relaxed),
            completed: self.shared.completed.load(Ordering::Relaxed),
            errors: self.shared.errors.load(Ordering::Relaxed),
            no_person: self.shared.no_person.load(Ordering::Relaxed),
            stages: s.summary(),
            throughput_fps: s.throughput_fps(),
            source_fps: arrivals.throughput_fps(),
            latency_p50: latency.quantile(0.5),
            latency_p95: latency.quantile(0.95),
        }
    }

    /// Whether the newest segmented frame holds no person (an empty room, a blank wall, a dark frame, the person
    /// gone). The display then shows no person ([`LiveStats::no_person`] counts such frames); the latest
    /// completed frame stays readable for when the person comes back.
    pub fn person_absent(&self) -> bool {
        self.shared.absent.load(Ordering::SeqCst)
    }

    /// Recent messages (oldest first): corrupt frames, a lost camera, segmentation failures.
    pub fn messages(&self) -> Vec<String> {
        self.shared.messages.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// True once the source has ended and the worker has finished the last frame.
    pub fn is_finished(&self) -> bool {
        self.shared.worker_done.load(Ordering::SeqCst)
    }

    /// Blocks until the source ends and the last frame is processed, or `timeout` passes; returns
    /// [`Self::is_finished`]. For tests and offline use (a display loop polls `is_finished`).
    pub fn wait(&self, timeout: Duration) -> bool {
        let t = Instant::now();
        while !self.is_finished() && t.elapsed() < timeout {
            std::thread::sleep(Duration::from_millis(2));
        }
        self.is_finished()
    }

    /// Stops both threads and waits for them, returning the final statistics.
    pub fn stop(mut self) -> LiveStats {
        self.shutdown();
        self.stats()
    }

    fn shutdown(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        self.shared.wake.notify_all();
        self.shared.segmented_wake.notify_all();
        for t in self.threads.drain(..) {
            // A camera read can block for one frame period; the join waits for it.
            let _ = t.join();
        }
    }
}

impl<T: Send + Sync + 'static> Drop for LivePipeline<T> {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// Lowers the calling thread's scheduling priority by `by` nice steps (Linux keeps a nice value per thread, and
/// threads started later from this one inherit it); nothing for `by <= 0`, or where the system refuses (a debug
/// message).
fn lower_this_threads_priority(by: i32) {
    if by <= 0 {
        return;
    }
    #[cfg(target_os = "linux")]
    {
        // SAFETY: `gettid` and `getpriority`/`setpriority` on this thread's own id only read and set its scheduling
        // attributes; errno is cleared first because -1 is a valid priority.
        let refused = unsafe {
            let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
            *libc::__errno_location() = 0;
            let now = libc::getpriority(libc::PRIO_PROCESS, tid);
            *libc::__errno_location() != 0 || libc::setpriority(libc::PRIO_PROCESS, tid, (now + by).min(19)) != 0
        };
        if refused {
            tracing::debug!("could not lower the live worker's priority: {}", std::io::Error::last_os_error());
        }
    }
}

/// Starts a named pipeline thread.
fn spawn(name: &str, f: impl FnOnce() + Send + 'static) -> Result<JoinHandle<()>, LiveError> {
    std::thread::Builder::new().name(name.into()).spawn(f).map_err(|e| LiveError::Thread(e.to_string()))
}

fn capture_loop<T>(source: &mut dyn FrameSource, shared: &Shared<T>, pace: bool) {
    let start = Instant::now();
    let paced = pace && !source.is_live();
    let mut first_ts: Option<Duration> = None;
    while !shared.stop.load(Ordering::SeqCst) {
        match source.next_frame() {
            Ok(SourceEvent::Frame(frame)) => {
                if paced {
                    let t0 = *first_ts.get_or_insert(frame.timestamp);
                    let due = frame.timestamp.saturating_sub(t0);
                    let now = start.elapsed();
                    if due > now {
                        std::thread::sleep(due - now);
                    }
                }
                let arrived = Instant::now();
                shared.read.fetch_add(1, Ordering::Relaxed);
                shared.arrivals.lock().unwrap_or_else(|p| p.into_inner()).complete_frame(arrived);
                let mut slot = shared.mailbox.lock().unwrap_or_else(|p| p.into_inner());
                if let Some((old, _)) = slot.replace((frame, arrived)) {
                    tracing::trace!("dropped frame {}", old.index);
                    shared.dropped.fetch_add(1, Ordering::Relaxed);
                }
                drop(slot);
                shared.wake.notify_one();
            }
            Ok(SourceEvent::End) => break,
            Err(e) if e.is_recoverable() => shared.report(e.to_string()),
            Err(e) => {
                shared.report(e.to_string());
                break;
            }
        }
    }
    shared.source_done.store(true, Ordering::SeqCst);
    shared.wake.notify_all();
}

/// The first worker thread: segments the newest frame and smooths its mask, then hands it to the processing thread,
/// so frame n+1 is segmented while frame n's geometry is built. It segments only once the processing thread has
/// taken the frame before: a frame segmented ahead of that would wait and be replaced, its segmentation wasted on
/// cores the processing needs. (Waiting further, for the processing's usual time less its own, to take a newer
/// frame: latency p50 124 -> 121 ms, completed frames 17.4 -> 13.2 a second; not kept.)
fn segment_loop<T>(shared: &Shared<T>, options: &LiveOptions) {
    let mut segmenter: Option<Box<dyn Segmenter>> = None;
    let mut smoother = MaskSmoother::new(options.mask_alpha, options.mask_reset_iou);
    let mut last_size = None;
    loop {
        {
            let mut slot = shared.segmented.lock().unwrap_or_else(|p| p.into_inner());
            while slot.is_some() {
                if shared.stop.load(Ordering::SeqCst) {
                    return;
                }
                slot = shared
                    .segmented_wake
                    .wait_timeout(slot, Duration::from_millis(50))
                    .unwrap_or_else(|p| p.into_inner())
                    .0;
            }
        }
        let Some((frame, arrived)) = take_next(&shared.mailbox, &shared.wake, &shared.stop, &shared.source_done) else {
            return;
        };
        if segmenter.is_none() {
            match options.segment.build(Some(&frame)) {
                Ok(s) => segmenter = Some(s),
                Err(e) => {
                    // Without a segmenter nothing can be shown: say so once per frame, keep the session.
                    shared.report(format!("{e}"));
                    continue;
                }
            }
        }
        let Some(seg) = segmenter.as_mut() else { continue };
        let size = (frame.width(), frame.height());
        let new_shot = last_size.replace(size).is_some_and(|s| s != size);
        if new_shot {
            // A frame of another size (a folder of photos) is a new shot: no smoothing across it.
            smoother.reset();
        }
        let mut local = StageStats::new(1);
        let mask = local.time("segment", || seg.segment(&frame));
        let mask = match mask {
            Ok(m) => m,
            Err(e) => {
                shared.report(format!("frame {}: {e}", frame.index));
                continue;
            }
        };
        let mask = local.time("smooth", || smoother.update(&mask));
        if !holds_a_person(&mask) {
            // No person: nothing to build. The display shows none until a frame holds one again.
            shared.no_person.fetch_add(1, Ordering::Relaxed);
            shared.absent.store(true, Ordering::SeqCst);
            smoother.reset();
            merge_stats(shared, &local, None);
            continue;
        }
        let body = seg.body_world().map(<[glam::Vec3]>::to_vec);
        let item = Segmented { frame, arrived, mask, body, new_shot, stats: local };
        let mut slot = shared.segmented.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(old) = slot.replace(item) {
            tracing::trace!("dropped segmented frame {}", old.frame.index);
            shared.dropped.fetch_add(1, Ordering::Relaxed);
        }
        drop(slot);
        shared.segmented_wake.notify_all();
    }
}

/// The value waiting in the one-slot `slot`, waiting on `wake` (rechecking every 50 ms) until there is one; `None`
/// once `stop` is set, or once the producer is `done` and the slot is empty.
fn take_next<V>(slot: &Mutex<Option<V>>, wake: &Condvar, stop: &AtomicBool, done: &AtomicBool) -> Option<V> {
    let mut slot = slot.lock().unwrap_or_else(|p| p.into_inner());
    loop {
        if stop.load(Ordering::SeqCst) {
            return None;
        }
        if let Some(v) = slot.take() {
            return Some(v);
        }
        if done.load(Ordering::SeqCst) {
            return None;
        }
        slot = wake.wait_timeout(slot, Duration::from_millis(50)).unwrap_or_else(|p| p.into_inner()).0;
    }
}

/// The fewest mask pixels (a fraction of the frame) a frame needs to hold a person: the normalisation's own floor
/// ([`crate::pipeline::input::MIN_COVERAGE`]), below which a frame could not be prepared anyway.
fn holds_a_person(mask: &GrayImage) -> bool {
    let count = mask.data.iter().filter(|&&v| v >= 0.5).count();
    !mask.data.is_empty() && count as f32 >= crate::pipeline::input::MIN_COVERAGE * mask.data.len() as f32
}

/// The second worker thread: builds the newest segmented frame ([`FrameProcessor::process`]) and publishes it.
fn process_loop<P: FrameProcessor>(shared: &Shared<P::Output>, mut processor: P) {
    let mut sequence = 0u64;
    loop {
        let next = take_next(&shared.segmented, &shared.segmented_wake, &shared.stop, &shared.segmenter_done);
        let Some(Segmented { frame, arrived, mask, body, new_shot, stats: mut local }) = next else { return };
        // The segmenter waits for the slot to empty.
        shared.segmented_wake.notify_all();
        if new_shot {
            processor.reset();
        }
        processor.body(body.as_deref());
        // The whole of the frame's processing, every stage of it: what a per-frame addition (the person model)
        // costs is this median with it against without it.
        let started = Instant::now();
        let output = processor.process(&frame, &mask, &mut local);
        local.record("processing", started.elapsed());
        let output = match output {
            Ok(o) => o,
            Err(source) => {
                shared.report(LiveError::Stage { index: frame.index, source }.to_string());
                merge_stats(shared, &local, None);
                continue;
            }
        };
        sequence += 1;
        let latency = arrived.elapsed();
        let done = Completed { frame_index: frame.index, timestamp: frame.timestamp, mask, output, latency, sequence };
        shared.latest.publish(Arc::new(done));
        shared.completed.fetch_add(1, Ordering::Relaxed);
        shared.absent.store(false, Ordering::SeqCst);
        shared.latency.lock().unwrap_or_else(|p| p.into_inner()).record(latency);
        local.record("frame", latency);
        merge_stats(shared, &local, Some(Instant::now()));
    }
}

fn merge_stats<T>(shared: &Shared<T>, local: &StageStats, completed_at: Option<Instant>) {
    let mut s = shared.stats.lock().unwrap_or_else(|p| p.into_inner());
    for st in local.summary() {
        s.record(&st.name, st.median);
    }
    if let Some(t) = completed_at {
        s.complete_frame(t);
    }
}

/// What happened to one input frame in [`render_video`].
#[derive(Clone, Debug, PartialEq)]
pub struct FrameOutcome {
    /// Position in the source (`u64::MAX` for a source error not tied to a frame).
    pub index: u64,
    /// The source's name for it (a folder's file name), when it has one.
    pub name: Option<String>,
    /// Width and height, when the frame was read.
    pub size: Option<(usize, usize)>,
    /// The PNG written, or why the frame was skipped.
    pub result: Result<PathBuf, String>,
    /// Which segmentation made its mask ("alpha", "onnx", "clean-plate"), when it got one.
    pub segmented_by: Option<&'static str>,
    /// Its size differs from the frame before it, so it was processed on its own (no temporal smoothing across).
    pub new_size: bool,
}

impl std::fmt::Display for FrameOutcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.index == u64::MAX {
            write!(f, "source")?;
        } else {
            write!(f, "frame {}", self.index)?;
        }
        match (&self.name, self.size) {
            (Some(n), Some((w, h))) => write!(f, " ({n}, {w}x{h})")?,
            (Some(n), None) => write!(f, " ({n})")?,
            (None, Some((w, h))) => write!(f, " ({w}x{h})")?,
            (None, None) => {}
        }
        match &self.result {
            Ok(path) => {
                write!(f, ": wrote {}", path.display())?;
                if let Some(s) = self.segmented_by {
                    write!(f, ", mask from {s}")?;
                }
                if self.new_size {
                    write!(f, ", a new size: processed on its own")?;
                }
                Ok(())
            }
            Err(reason) => write!(f, ": skipped: {reason}"),
        }
    }
}

/// What [`render_video`] did.
#[derive(Clone, Debug, Default)]
pub struct RenderReport {
    /// Files written, in frame order.
    pub written: Vec<PathBuf>,
    /// Frames skipped, with the reason.
    pub skipped: Vec<(u64, String)>,
    /// Every frame in source order: written or skipped, and how.
    pub frames: Vec<FrameOutcome>,
    /// Per-stage medians over the whole run ("segment", "smooth", processor stages, "render", "write").
    pub stages: Vec<StageSummary>,
}

/// Renders every frame of `source` into `out_dir/frame_NNNNN.png` (`NNNNN` = source frame index), sequentially
/// and without dropping: segment (`method`), smooth masks like the live loop, `processor`, then `render` (one
/// premultiplied RGBA image per frame; the CLI passes its view camera and renderer here). A frame that fails is
/// reported on `on_message` and skipped; the run fails only if the source cannot be read at all or no frame at all
/// could be rendered.
pub fn render_video<P: FrameProcessor>(
    source: &mut dyn FrameSource,
    method: &SegmentMethod,
    options: &LiveOptions,
    processor: &mut P,
    mut render: impl FnMut(&Completed<P::Output>) -> Result<RgbaImage, PipelineError>,
    out_dir: &Path,
    mut on_message: impl FnMut(&str),
) -> Result<RenderReport, LiveError> {
    std::fs::create_dir_all(out_dir).map_err(|e| LiveError::Output { path: out_dir.into(), reason: e.to_string() })?;
    let mut report = RenderReport::default();
    let mut stats = StageStats::new(100_000);
    let mut segmenter: Option<Box<dyn Segmenter>> = None;
    let mut smoother = MaskSmoother::new(options.mask_alpha, options.mask_reset_iou);
    let mut sequence = 0;
    let mut last_size = None;
    let mut skip = |report: &mut RenderReport, outcome: FrameOutcome, reason: String| {
        on_message(&reason);
        report.skipped.push((outcome.index, reason.clone()));
        report.frames.push(FrameOutcome { result: Err(reason), ..outcome });
    };
    loop {
        let frame = match source.next_frame() {
            Ok(SourceEvent::Frame(f)) => f,
            Ok(SourceEvent::End) => break,
            Err(e) => {
                let index = match &e {
                    CaptureError::CorruptFrame { index, .. } | CaptureError::CorruptImage { index, .. } => *index,
                    _ => u64::MAX,
                };
                let name = source.frame_name(index);
                let outcome = FrameOutcome {
                    index,
                    name,
                    size: None,
                    result: Err(String::new()),
                    segmented_by: None,
                    new_size: false,
                };
                let recoverable = e.is_recoverable();
                skip(&mut report, outcome, e.to_string());
                if recoverable {
                    continue;
                }
                break;
            }
        };
        let started = Instant::now();
        let size = (frame.width(), frame.height());
        let new_size = last_size.replace(size).is_some_and(|s| s != size);
        let mut outcome = FrameOutcome {
            index: frame.index,
            name: source.frame_name(frame.index),
            size: Some(size),
            result: Err(String::new()),
            segmented_by: None,
            new_size,
        };
        if new_size {
            // A photo of another size in a folder is a new shot: no temporal smoothing across it.
            smoother.reset();
            processor.reset();
        }
        if segmenter.is_none() {
            segmenter = Some(method.build(Some(&frame))?);
        }
        let Some(seg) = segmenter.as_mut() else { break };
        let mask = match stats.time("segment", || seg.segment(&frame)) {
            Ok(m) => m,
            Err(e) => {
                skip(&mut report, outcome, format!("frame {}: {e}", frame.index));
                continue;
            }
        };
        outcome.segmented_by = Some(seg.name());
        let mask = stats.time("smooth", || smoother.update(&mask));
        if !holds_a_person(&mask) {
            smoother.reset();
            skip(&mut report, outcome, format!("frame {}: no person in this frame", frame.index));
            continue;
        }
        processor.body(seg.body_world());
        let output = match processor.process(&frame, &mask, &mut stats) {
            Ok(o) => o,
            Err(source) => {
                skip(&mut report, outcome, LiveError::Stage { index: frame.index, source }.to_string());
                continue;
            }
        };
        sequence += 1;
        let done = Completed {
            frame_index: frame.index,
            timestamp: frame.timestamp,
            mask,
            output,
            latency: started.elapsed(),
            sequence,
        };
        let image = match stats.time("render", || render(&done)) {
            Ok(i) => i,
            Err(source) => {
                skip(&mut report, outcome, LiveError::Stage { index: frame.index, source }.to_string());
                continue;
            }
        };
        let path = out_dir.join(format!("frame_{:05}.png", frame.index));
        stats
            .time("write", || crate::io::image_io::save_rgba_png(&path, &image))
            .map_err(|source| LiveError::WriteFrame { path: path.clone(), source })?;
        stats.record("frame", started.elapsed());
        report.written.push(path.clone());
        report.frames.push(FrameOutcome { result: Ok(path), ..outcome });
    }
    report.stages = stats.summary();
    if report.written.is_empty() {
        return Err(LiveError::NothingRendered(source.describe()));
    }
    Ok(report)
}

/// `r2human render --video PATH ... --out OUTDIR`: every frame through the core pipeline and, with `neural`, the
/// encoder once per frame ([`EncodeProcessor`]), rendered for `camera` ([`ViewRenderer::render_person`] with the
/// neural decoder or the geometric renderer; premultiplied RGBA, no fusion between frames), one PNG per input frame
/// in `out_dir`. See [`render_video`]. Returns the report and the number of views the neural decoder failed on
/// (drawn by the geometric renderer instead).
#[allow(clippy::too_many_arguments)]
pub fn render_video_views(
    source: &mut dyn FrameSource,
    method: &SegmentMethod,
    options: &LiveOptions,
    prepare: &PrepareOptions,
    camera: &Camera,
    fill: OcclusionFill,
    neural: Option<&SharedNeural>,
    out_dir: &Path,
    on_message: impl FnMut(&str),
) -> Result<(RenderReport, usize), LiveError> {
    let mut processor = EncodeProcessor::new(prepare.clone(), neural.cloned()).refreshing_inline();
    let mut fallbacks = 0;
    let render = |done: &Completed<LiveFrame>| {
        let frame = &done.output;
        let mut view = match (neural, &frame.neural) {
            (Some(shared), Some(encoded)) => {
                ViewRenderer::with_neural(&frame.input, fill, false, Arc::clone(shared), encoded.clone())
            }
            _ => ViewRenderer::new(&frame.input, fill, false),
        };
        let person = view.render_person(camera);
        fallbacks += view.neural_fallbacks();
        person
    };
    let report = render_video(source, method, options, &mut processor, render, out_dir, on_message)?;
    Ok((report, fallbacks))
}

/// The normalised source view as an RGBA image (premultiplied): the renderer `render_video` uses when no view
/// renderer is given (it shows exactly what the geometry stage receives).
pub fn normalised_rgba(input: &NormalisedInput) -> RgbaImage {
    RgbaImage {
        width: input.rgb.width,
        height: input.rgb.height,
        data: input.rgb.data.iter().zip(&input.mask.data).map(|(c, &m)| c.extend(m.clamp(0.0, 1.0))).collect(),
    }
}

/// `--video PATH` for the CLI: a factory for [`LivePipeline::start`] (folder, image or video file).
pub fn video_source(path: &Path, fps: f32) -> SourceFactory {
    let path = path.to_path_buf();
    Box::new(move || crate::capture::open_video_path(&path, fps))
}

/// `--camera N` for the CLI: a factory for [`LivePipeline::start`].
pub fn camera_source(request: crate::capture::CameraRequest) -> SourceFactory {
    Box::new(move || crate::capture::CameraSource::open(&request).map(|c| Box::new(c) as Box<dyn FrameSource>))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(target_os = "linux")]
    fn this_threads_nice() -> i32 {
        // SAFETY: reads this thread's own scheduling priority.
        unsafe { libc::getpriority(libc::PRIO_PROCESS, libc::syscall(libc::SYS_gettid) as libc::id_t) }
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn a_lowered_worker_and_the_threads_it_starts_run_lower_and_the_rest_does_not() {
        let before = this_threads_nice();
        let (worker, child) = std::thread::spawn(|| {
            lower_this_threads_priority(3);
            let child = std::thread::spawn(this_threads_nice).join().expect("child thread");
            (this_threads_nice(), child)
        })
        .join()
        .expect("worker thread");
        let expected = (before + 3).min(19);
        assert_eq!(worker, expected, "the worker itself");
        assert_eq!(child, expected, "a thread it started (its pool, ONNX Runtime's)");
        assert_eq!(this_threads_nice(), before, "the calling thread is untouched");
        // Nothing to do without an increment.
        let same = std::thread::spawn(|| {
            lower_this_threads_priority(0);
            this_threads_nice()
        })
        .join()
        .expect("thread");
        assert_eq!(same, before);
    }

    #[test]
    fn with_the_person_model_a_frame_is_meshed_once_from_the_models_surfaces() {
        use crate::geometry::surface_mesh::mesh_from_surfaces;
        use crate::pipeline::{frame::FRAME_MESH_STEP, GeometryMode};
        // A striped ellipse moving sideways, as frames of a source with no alpha.
        let (w, h) = (96, 128);
        let frame = |index: u64| {
            let centre = 48.0 + index as f32;
            let inside = |c: usize, r: usize| {
                let (x, y) = ((c as f32 + 0.5 - centre) / 22.0, (r as f32 + 0.5 - 64.0) / 52.0);
                x * x + y * y <= 1.0
            };
            let mut rgb = crate::buffer::RgbImage::new(w, h, glam::Vec3::splat(0.2));
            let mut mask = GrayImage::new(w, h, 0.0);
            for r in 0..h {
                for c in 0..w {
                    if inside(c, r) {
                        rgb.data[r * w + c] = glam::Vec3::new(0.8, 0.3 + 0.4 * ((c / 4) % 2) as f32, 0.1);
                        mask.data[r * w + c] = 1.0;
                    }
                }
            }
            (Frame { index, timestamp: Duration::from_millis(33 * index), rgb, alpha: None }, mask)
        };
        let options = |person_model: bool| PrepareOptions {
            resolution: 128,
            depth_samples: 128,
            geometry: GeometryMode::Inflate,
            coarse_views: true,
            person_model,
            ..PrepareOptions::default()
        };
        let (mut with, mut without) = (PrepareProcessor::new(options(true)), PrepareProcessor::new(options(false)));
        let (mut stats, mut other) = (StageStats::new(8), StageStats::new(8));
        for index in 0..4 {
            let (f, mask) = frame(index);
            let a = with.process(&f, &mask, &mut stats).expect("frame with the model");
            let b = without.process(&f, &mask, &mut other).expect("frame without it");
            for (p, what) in [(&a, "with the model"), (&b, "without")] {
                let surfaces = p.surfaces.as_ref().expect("one-shell surfaces");
                // The mesh and the coarse mesh are the frame's final surfaces', whoever changed them last.
                let mesh = mesh_from_surfaces(surfaces, FRAME_MESH_STEP).expect("mesh");
                assert_eq!(p.mesh.positions, mesh.positions, "frame {index} {what}: mesh");
                let coarse = p.coarse.as_ref().expect("a coarse mesh for coarse views");
                let expected = mesh_from_surfaces(surfaces, 2 * FRAME_MESH_STEP).expect("coarse mesh");
                assert_eq!(coarse.mesh.positions, expected.positions, "frame {index} {what}: coarse");
                assert_eq!(p.source_gbuffer.width, 128, "frame {index} {what}: source view");
                assert!(p.source_gbuffer.depth.iter().all(|d| !d.is_nan()), "frame {index} {what}: NaN depth");
            }
        }
        // With the model the frame path meshes nothing (the model meshes its surfaces; the coarse mesh follows).
        let runs =
            |stats: &StageStats, name: &str| stats.summary().into_iter().find(|s| s.name == name).map(|s| s.total);
        assert_eq!(runs(&stats, "mesh (depth maps)"), None);
        assert_eq!(runs(&stats, "source view (depth maps)"), None);
        assert_eq!(runs(&stats, "coarse mesh (depth maps)"), Some(4));
        assert_eq!(runs(&other, "mesh (depth maps)"), Some(4));
    }

    #[test]
    fn latest_reader_never_waits_for_the_publisher() {
        let slot = Arc::new(LatestSlot::<u32>::default());
        let mut reader = LatestReader { slot: Arc::clone(&slot), current: None };
        assert!(reader.get().is_none());
        slot.publish(Arc::new(1));
        assert_eq!(**reader.get().unwrap(), 1);
        slot.publish(Arc::new(2));
        // While the publisher holds the slot, the reader returns what it has at once (this would deadlock if it
        // waited for the lock).
        let guard = slot.slot.lock().unwrap();
        assert!(slot.try_get().is_none());
        assert_eq!(**reader.get().unwrap(), 1);
        drop(guard);
        assert_eq!(**reader.get().unwrap(), 2);
    }

    #[test]
    fn overlay_line_lists_stages_and_rates() {
        let stats = LiveStats {
            read: 10,
            dropped: 3,
            completed: 7,
            errors: 0,
            stages: vec![StageSummary {
                name: "segment".into(),
                median: Duration::from_millis(12),
                samples: 7,
                total: 7,
            }],
            throughput_fps: 7.5,
            source_fps: 30.0,
            ..Default::default()
        };
        assert_eq!(stats.overlay_line(), "segment 12.0 ms · 7.5/30.0 fps · 3 dropped");
    }
}
