//! Frame pacing: the display loop never waits on the person renderer.
//!
//! The display loop posts a [`RenderRequest`] every frame (the latest predicted eye poses; an older request not
//! yet started is simply replaced) and picks up the newest finished [`RenderedEyes`] whenever there is one. The
//! render thread renders both eyes for the newest request it finds, on the GPU: a finished frame is a set of
//! device buffers, which the display loop copies into the swapchain images with one small GPU submission (no
//! pixels pass through the CPU). The render thread must not overwrite those buffers before that copy has run: the
//! display loop marks the frame it copies ([`RenderMailbox::take_newer`]) and reports the copy finished
//! ([`RenderMailbox::copied`]), and the render thread draws into a buffer set only when no copy may still read it
//! (with two sets, the next pair is drawn while the last one's copy waits) — the display loop never waits for the
//! render thread.
//!
//! A frame whose image is not new re-submits the previous image with the eye poses it was rendered for, so the
//! compositor reprojects it to the current head pose. [`PacingStats`] measures what the viewer gets: the share of
//! frames that showed a fresh render and the motion-to-photon latency of the person layer (pose sampling to
//! predicted display time).

use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use ash::vk;
use glam::{Quat, Vec3};

use super::placement::Placement;
use crate::capture::stats::DurationHistogram;
use crate::geometry::camera::{Camera, Fov};

/// One eye's pose and field of view in the reference space (metres), as `XrView` gives them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EyeView {
    /// Eye position.
    pub position: Vec3,
    /// Eye orientation (looks down its local -z).
    pub orientation: Quat,
    /// Field of view.
    pub fov: Fov,
}

/// What the render thread is asked to render: both eyes for one set of predicted poses.
#[derive(Clone, Debug)]
pub struct RenderRequest {
    /// Increasing request number.
    pub seq: u64,
    /// Per-eye poses and fields of view in the reference space.
    pub views: Vec<EyeView>,
    /// Where the person stands.
    pub placement: Placement,
    /// Per-eye image size `(width, height)` (the swapchain size).
    pub sizes: Vec<(usize, usize)>,
    /// When the head pose used was sampled, in OpenXR time (ns), if the runtime can convert clocks.
    pub sampled_at: Option<i64>,
}

/// One eye to render, in both coordinate frames the renderer may need.
#[derive(Clone, Copy, Debug)]
pub struct EyeRequest {
    /// Eye index (0 left, 1 right).
    pub eye: usize,
    /// The eye camera in body-cube coordinates (for the person).
    pub body_camera: Camera,
    /// The same eye in reference-space coordinates (for a room-locked panorama).
    pub stage_camera: Camera,
    /// Which of the renderer's result buffer sets to write (below [`EyeRenderer::buffer_sets`]): the display loop
    /// may still be copying out of the others.
    pub set: usize,
}

/// Why the render thread could not render the eyes (it stops; the session ends with this sentence).
#[derive(Debug, thiserror::Error)]
pub enum EyeError {
    /// A GPU call failed (`what`: the step, e.g. "uploading the person to the GPU" or "eye 0").
    #[error("{what}: {source}")]
    Gpu {
        /// The step that failed.
        what: String,
        /// The GPU's error.
        #[source]
        source: crate::gpu::GpuError,
    },
    /// The CPU reference failed on an eye (a non-finite view).
    #[error("eye {eye} on the CPU: {source}")]
    Cpu {
        /// Eye index.
        eye: usize,
        /// The pipeline's error.
        #[source]
        source: crate::pipeline::PipelineError,
    },
    /// The session asked for an eye the renderer does not have.
    #[error("eye {0} has no renderer (the session has fewer eyes)")]
    NoRenderer(usize),
    /// The eye's camera does not match its renderer's size.
    #[error("eye {eye}: camera of {}x{} for a renderer of {}x{}", .camera.0, .camera.1, .renderer.0, .renderer.1)]
    SizeMismatch {
        /// Eye index.
        eye: usize,
        /// The camera's (width, height).
        camera: (usize, usize),
        /// The renderer's (width, height).
        renderer: (usize, usize),
    },
}

/// The render thread's side of the eye renderer (implemented on the Vulkan renderer by
/// [`super::eyes::GpuEyes`], on the CPU reference by [`super::eyes::CpuEyes`]).
pub trait EyeRenderer: Send {
    /// Takes new content (a new input frame, a panorama turned with the placement) without blocking; called
    /// before every request. Returns whether something was uploaded.
    fn refresh(&mut self, placement: &Placement) -> Result<bool, EyeError>;
    /// Is there anything to render yet (a live source may not have produced its first frame)?
    fn has_content(&self) -> bool;
    /// Renders one eye; returns the device buffer holding the result (`vec4` linear RGBA per pixel, row-major,
    /// of the eye camera's size), valid until the next call for that eye.
    fn render_eye(&mut self, eye: &EyeRequest) -> Result<vk::Buffer, EyeError>;
    /// Renders the eyes of one request (eye indices `0..n` in order); returns each eye's result buffer (as
    /// [`EyeRenderer::render_eye`]) and its render time. By default one eye after the other, each timed alone; a
    /// renderer that draws them together says how it splits the time (the CPU eyes: the pair's wall time divided
    /// among the eyes).
    fn render_eyes(&mut self, eyes: &[EyeRequest]) -> Result<Vec<(vk::Buffer, Duration)>, EyeError> {
        eyes.iter().map(|e| timed(|| self.render_eye(e))).collect()
    }
    /// How many sets of result buffers the renderer keeps ([`EyeRequest::set`]). With one, the next pair waits
    /// until the display loop has copied the last one; with two, it is drawn while that copy waits for its frame.
    fn buffer_sets(&self) -> usize {
        1
    }
    /// Messages for the user since the last call (a live source that ended, a corrupt frame).
    fn take_messages(&mut self) -> Vec<String>;
}

/// Both eyes rendered for one request.
#[derive(Debug)]
pub struct RenderedEyes {
    /// The request this answers.
    pub request: RenderRequest,
    /// Per-eye cameras used (body-cube coordinates).
    pub cameras: Vec<Camera>,
    /// Per-eye result buffers on the device (see [`EyeRenderer::render_eye`]).
    pub outputs: Vec<vk::Buffer>,
    /// Per-eye render time.
    pub eye_times: Vec<Duration>,
}

#[derive(Default)]
struct Slots {
    pending: Option<RenderRequest>,
    shutdown: bool,
    latest: Option<Arc<RenderedEyes>>,
    /// The newest frame the display loop took to copy ([`RenderMailbox::take_newer`]).
    taken: Option<u64>,
    /// The newest frame whose copy has finished ([`RenderMailbox::copied`]).
    copied: Option<u64>,
    error: Option<String>,
    /// Every per-eye render time, in fixed memory (sessions run for hours).
    eye_times: DurationHistogram,
    uploads: u64,
    messages: Vec<String>,
}

/// The mailbox between the display loop and the render thread.
#[derive(Default)]
pub struct RenderMailbox {
    slots: Mutex<Slots>,
    wake: Condvar,
}

/// How many user messages a session keeps (the newest are dropped beyond this).
const KEPT_MESSAGES: usize = 32;

impl RenderMailbox {
    /// A new mailbox.
    pub fn new() -> Arc<Self> {
        Arc::new(Self::default())
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Slots> {
        self.slots.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Posts the newest request, replacing one the render thread has not picked up yet. Never blocks on rendering.
    pub fn request(&self, request: RenderRequest) {
        self.lock().pending = Some(request);
        self.wake.notify_all();
    }

    /// The newest finished frame, if any.
    pub fn latest(&self) -> Option<Arc<RenderedEyes>> {
        self.lock().latest.clone()
    }

    /// The newest finished frame when it is newer than `seen`, marked as taken: the render thread does not write
    /// its buffers again until [`RenderMailbox::copied`] reports the copy out of them.
    pub fn take_newer(&self, seen: Option<u64>) -> Option<Arc<RenderedEyes>> {
        let mut s = self.lock();
        let frame = s.latest.clone().filter(|f| Some(f.request.seq) != seen)?;
        s.taken = Some(frame.request.seq);
        Some(frame)
    }

    /// The display loop's copy of frame `seq` out of the result buffers has finished (it waited for it): the
    /// render thread may write them again without touching the copy's fence, which the display loop reuses.
    pub fn copied(&self, seq: u64) {
        self.lock().copied = Some(seq);
        self.wake.notify_all();
    }

    /// The render thread's error, if it stopped on one.
    pub fn error(&self) -> Option<String> {
        self.lock().error.clone()
    }

    /// Every per-eye render time so far (a histogram: fixed memory however long the session).
    pub fn eye_times(&self) -> DurationHistogram {
        self.lock().eye_times.clone()
    }

    /// How many times new content was uploaded to the renderer.
    pub fn uploads(&self) -> u64 {
        self.lock().uploads
    }

    /// Messages for the user so far (at most 32).
    pub fn messages(&self) -> Vec<String> {
        self.lock().messages.clone()
    }

    /// Asks the render thread to stop after its current render.
    pub fn shutdown(&self) {
        self.lock().shutdown = true;
        self.wake.notify_all();
    }

    fn record_messages(&self, messages: Vec<String>) {
        if messages.is_empty() {
            return;
        }
        let mut s = self.lock();
        for m in messages {
            tracing::warn!("{m}");
            if s.messages.len() < KEPT_MESSAGES {
                s.messages.push(m);
            }
        }
    }

    /// The render thread's body: renders the newest request until [`RenderMailbox::shutdown`].
    pub fn run_render_loop(&self, renderer: &mut dyn EyeRenderer) {
        let sets = renderer.buffer_sets().max(1);
        // Published frames whose buffer set the display loop may still read, oldest first: (frame, set).
        let mut in_flight: std::collections::VecDeque<(u64, usize)> = std::collections::VecDeque::new();
        loop {
            let (request, set) = {
                let mut s = self.lock();
                loop {
                    if s.shutdown {
                        return;
                    }
                    let free = if in_flight.len() < sets {
                        (0..sets).find(|k| in_flight.iter().all(|&(_, used)| used != *k))
                    } else {
                        in_flight.front().filter(|&&(frame, _)| set_released(&s, frame)).map(|&(_, set)| set)
                    };
                    if let (Some(set), true) = (free, s.pending.is_some()) {
                        if in_flight.len() >= sets {
                            in_flight.pop_front();
                        }
                        break (s.pending.take().expect("checked above"), set);
                    }
                    s = self.wake.wait(s).unwrap_or_else(|p| p.into_inner());
                }
            };
            let result = (|| -> Result<Option<RenderedEyes>, EyeError> {
                if renderer.refresh(&request.placement)? {
                    self.lock().uploads += 1;
                }
                self.record_messages(renderer.take_messages());
                if !renderer.has_content() {
                    return Ok(None);
                }
                render_request(renderer, &request, set).map(Some)
            })();
            match result {
                Ok(Some(frame)) => {
                    in_flight.push_back((frame.request.seq, set));
                    let mut s = self.lock();
                    for &t in &frame.eye_times {
                        s.eye_times.record(t);
                    }
                    s.latest = Some(Arc::new(frame));
                }
                Ok(None) => {}
                Err(e) => {
                    self.lock().error = Some(e.to_string());
                    return;
                }
            }
        }
    }
}

/// Whether the buffers of published `frame` may be written again:
/// - a copy of it (or of a later frame: copies run in submission order) reported finished ([`RenderMailbox::copied`]):
///   yes;
/// - while it is the newest frame and not copied: not yet (the display loop will take it);
/// - after a newer one: yes unless the display loop took it and has not reported its copy finished.
fn set_released(s: &Slots, frame: u64) -> bool {
    if s.copied.is_some_and(|c| c >= frame) {
        return true;
    }
    let newest = s.latest.as_ref().is_some_and(|l| l.request.seq == frame);
    !newest && s.taken != Some(frame)
}

/// Renders both eyes of one request into the renderer's buffer set `set` ([`EyeRenderer::render_eyes`]).
pub fn render_request(
    renderer: &mut dyn EyeRenderer,
    request: &RenderRequest,
    set: usize,
) -> Result<RenderedEyes, EyeError> {
    let eyes: Vec<EyeRequest> = request
        .views
        .iter()
        .zip(&request.sizes)
        .enumerate()
        .map(|(eye, (view, &(w, h)))| EyeRequest {
            eye,
            body_camera: request.placement.eye_camera(view.position, view.orientation, view.fov, w, h),
            stage_camera: Placement::stage_camera(view.position, view.orientation, view.fov, w, h),
            set,
        })
        .collect();
    let (outputs, eye_times) = renderer.render_eyes(&eyes)?.into_iter().unzip();
    Ok(RenderedEyes {
        request: request.clone(),
        cameras: eyes.iter().map(|e| e.body_camera).collect(),
        outputs,
        eye_times,
    })
}

/// Runs `f` and returns its result with how long it took.
pub(crate) fn timed<T, E>(f: impl FnOnce() -> Result<T, E>) -> Result<(T, Duration), E> {
    let start = Instant::now();
    let out = f()?;
    Ok((out, start.elapsed()))
}

/// Per-frame pacing measurements of the person layer.
#[derive(Clone, Debug, Default)]
pub struct PacingStats {
    /// Frames submitted with the person layer.
    pub person_frames: u64,
    /// Of those, frames that showed an image not shown before.
    pub fresh_frames: u64,
    /// Motion-to-photon latency per person frame (pose sampling to predicted display; negative values count as
    /// zero), in fixed memory.
    pub latencies: DurationHistogram,
}

impl PacingStats {
    /// Records one submitted person frame displayed at `display_time` (OpenXR ns) showing an image whose poses
    /// were sampled at `sampled_at`.
    pub fn record(&mut self, fresh: bool, display_time: i64, sampled_at: Option<i64>) {
        self.person_frames += 1;
        if fresh {
            self.fresh_frames += 1;
        }
        if let Some(t) = sampled_at {
            let ns = display_time.saturating_sub(t).max(0) as u64;
            self.latencies.record(Duration::from_nanos(ns));
        }
    }

    /// Share of person frames that showed a fresh render, in [0, 1] (0 when there were none).
    pub fn fresh_share(&self) -> f64 {
        if self.person_frames == 0 {
            0.0
        } else {
            self.fresh_frames as f64 / self.person_frames as f64
        }
    }

    /// Median motion-to-photon latency in milliseconds (to within 50 µs), if measured.
    pub fn median_latency_ms(&self) -> Option<f64> {
        (self.latencies.count() > 0).then(|| self.latencies.median().as_secs_f64() * 1e3)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ash::vk::Handle;

    fn request(seq: u64) -> RenderRequest {
        let view =
            EyeView { position: Vec3::new(0.0, 1.6, 0.0), orientation: Quat::IDENTITY, fov: Fov::symmetric(1.5, 1.0) };
        RenderRequest {
            seq,
            views: vec![view, EyeView { position: Vec3::new(0.06, 1.6, 0.0), ..view }],
            placement: Placement::in_front_of(Vec3::new(0.0, 1.6, 0.0), Quat::IDENTITY, 0.0, 1.75),
            sizes: vec![(8, 6), (8, 6)],
            sampled_at: Some(1_000),
        }
    }

    /// A fake eye renderer: blocks while `gate` is closed (a slow GPU), records what it was asked.
    #[derive(Default)]
    struct Fake {
        gate: Option<Arc<(Mutex<bool>, Condvar)>>,
        content: bool,
        fail: bool,
        seen: Arc<Mutex<Vec<(usize, Vec3, Vec3)>>>,
        messages: Vec<String>,
        /// Buffer sets it keeps (0 = the default, one).
        sets: usize,
        /// The set each eye render was asked to write.
        used_sets: Arc<Mutex<Vec<usize>>>,
    }

    impl EyeRenderer for Fake {
        fn refresh(&mut self, _placement: &Placement) -> Result<bool, EyeError> {
            let first = !self.content;
            self.content = true;
            if first {
                self.messages.push("first content".into());
            }
            Ok(first)
        }
        fn has_content(&self) -> bool {
            self.content
        }
        fn render_eye(&mut self, e: &EyeRequest) -> Result<vk::Buffer, EyeError> {
            if self.fail {
                return Err(EyeError::SizeMismatch { eye: e.eye, camera: (8, 8), renderer: (4, 4) });
            }
            if let Some(g) = &self.gate {
                let (lock, cv) = &**g;
                let mut open = lock.lock().unwrap();
                while !*open {
                    open = cv.wait(open).unwrap();
                }
            }
            self.seen.lock().unwrap().push((e.eye, e.body_camera.position(), e.stage_camera.position()));
            self.used_sets.lock().unwrap().push(e.set);
            Ok(vk::Buffer::from_raw(100 + e.eye as u64))
        }
        fn take_messages(&mut self) -> Vec<String> {
            std::mem::take(&mut self.messages)
        }
        fn buffer_sets(&self) -> usize {
            self.sets.max(1)
        }
    }

    #[test]
    fn fresh_shares_and_latencies_are_closed_form() {
        let mut s = PacingStats::default();
        assert_eq!(s.fresh_share(), 0.0);
        s.record(true, 50_000_000, Some(10_000_000));
        s.record(false, 100_000_000, Some(10_000_000));
        s.record(false, 150_000_000, None);
        s.record(true, 200_000_000, Some(170_000_000));
        assert!((s.fresh_share() - 0.5).abs() < 1e-12);
        // Latencies 40, 90 and 30 ms: the median 40 ms, to within the histogram's 50 µs bins.
        let m = s.median_latency_ms().unwrap();
        assert!((m - 40.0).abs() <= 0.05, "{m}");
    }

    #[test]
    fn render_request_uses_the_placement_for_each_eye() {
        let req = request(1);
        let mut r = Fake { content: true, ..Default::default() };
        let frame = render_request(&mut r, &req, 0).unwrap();
        assert_eq!(frame.outputs, vec![vk::Buffer::from_raw(100), vk::Buffer::from_raw(101)]);
        assert_eq!((frame.cameras[0].width, frame.cameras[0].height), (8, 6));
        let seen = r.seen.lock().unwrap();
        // Eye 0 at (0, 1.6, 0) in the room is at (0, 0.7, 1.75) in body units for the default placement.
        assert!((seen[0].1 - Vec3::new(0.0, 0.7, 1.75)).length() < 1e-5);
        assert!((seen[1].2 - Vec3::new(0.06, 1.6, 0.0)).length() < 1e-6);
    }

    #[test]
    fn the_render_thread_renders_the_newest_request_and_waits_for_the_copy() {
        let mailbox = RenderMailbox::new();
        let gate = Arc::new((Mutex::new(false), Condvar::new()));
        let fake = Fake { gate: Some(gate.clone()), ..Default::default() };
        std::thread::scope(|scope| {
            let m = mailbox.clone();
            scope.spawn(move || {
                let mut fake = fake;
                m.run_render_loop(&mut fake);
            });
            // Posting many requests while the renderer is stuck does not wait for it: posted from another thread,
            // all 50 return while the gate is still closed (a blocking `request` would never return, so the wait is
            // bounded instead of timing the calls, which a loaded machine could fail).
            let (posted, all_posted) = std::sync::mpsc::channel();
            let poster = mailbox.clone();
            scope.spawn(move || {
                for seq in 1..=50 {
                    poster.request(request(seq));
                }
                let _ = posted.send(());
            });
            let open_gate = || {
                let (lock, cv) = &*gate;
                *lock.lock().unwrap() = true;
                cv.notify_all();
            };
            if all_posted.recv_timeout(Duration::from_secs(30)).is_err() {
                // Let the stuck threads finish so the scope can end and the failure is reported, not a hang.
                open_gate();
                mailbox.shutdown();
                panic!("request blocked while the render thread was stuck");
            }
            assert!(mailbox.latest().is_none());
            open_gate();
            let wait_for = |seq: u64| {
                let deadline = Instant::now() + Duration::from_secs(10);
                while mailbox.latest().is_none_or(|f| f.request.seq != seq) {
                    assert!(Instant::now() < deadline, "render thread never rendered request {seq}");
                    std::thread::sleep(Duration::from_millis(1));
                }
            };
            // The first request picked up (whichever it was) is rendered; the thread then holds the newest pending
            // request (50) until the display loop hands back the copy of the first.
            let deadline = Instant::now() + Duration::from_secs(10);
            while mailbox.latest().is_none() {
                assert!(Instant::now() < deadline, "nothing rendered");
                std::thread::sleep(Duration::from_millis(1));
            }
            let first = mailbox.latest().unwrap().request.seq;
            if first != 50 {
                std::thread::sleep(Duration::from_millis(50));
                assert_eq!(mailbox.latest().unwrap().request.seq, first, "rendered over a frame still being copied");
                // The display loop takes the first frame: still not drawn over until its copy is reported finished.
                assert_eq!(mailbox.take_newer(None).map(|f| f.request.seq), Some(first));
                std::thread::sleep(Duration::from_millis(50));
                assert_eq!(mailbox.latest().unwrap().request.seq, first, "rendered over a frame being copied");
                mailbox.copied(first);
                wait_for(50);
            }
            assert!(mailbox.eye_times().count() <= 4, "at most two requests rendered");
            assert_eq!(mailbox.uploads(), 1);
            assert_eq!(mailbox.messages(), vec!["first content".to_string()]);
            mailbox.shutdown();
        });
    }

    #[test]
    fn a_render_error_stops_the_thread_and_is_reported() {
        let mailbox = RenderMailbox::new();
        mailbox.request(request(1));
        let mut r = Fake { fail: true, ..Default::default() };
        let m = mailbox.clone();
        let t = std::thread::spawn(move || m.run_render_loop(&mut r));
        t.join().unwrap();
        assert_eq!(mailbox.error().as_deref(), Some("eye 0: camera of 8x8 for a renderer of 4x4"));
        assert!(mailbox.latest().is_none());
    }

    #[test]
    fn with_two_buffer_sets_the_next_pair_is_drawn_while_the_last_waits_for_its_copy() {
        let mailbox = RenderMailbox::new();
        let used = Arc::new(Mutex::new(Vec::new()));
        let mut r = Fake { sets: 2, used_sets: used.clone(), ..Default::default() };
        let rendered = |seq: u64| {
            let deadline = Instant::now() + Duration::from_secs(10);
            while mailbox.latest().is_none_or(|f| f.request.seq != seq) {
                assert!(Instant::now() < deadline, "request {seq} was not rendered");
                std::thread::sleep(Duration::from_millis(1));
            }
        };
        std::thread::scope(|scope| {
            let m = mailbox.clone();
            scope.spawn(move || m.run_render_loop(&mut r));
            // Two pairs without any copy: one per set.
            mailbox.request(request(1));
            rendered(1);
            mailbox.request(request(2));
            rendered(2);
            // The display loop takes frame 2 (not 1, which it never saw): frame 1's set is free at once.
            assert_eq!(mailbox.take_newer(Some(1)).map(|f| f.request.seq), Some(2));
            assert!(mailbox.take_newer(Some(2)).is_none(), "a frame already taken is not new");
            mailbox.request(request(3));
            rendered(3);
            // Frame 2 was taken and its copy not reported finished: its set stays untouched.
            mailbox.request(request(4));
            std::thread::sleep(Duration::from_millis(50));
            assert_eq!(mailbox.latest().unwrap().request.seq, 3, "drew over a frame being copied");
            mailbox.copied(2);
            rendered(4);
            mailbox.shutdown();
        });
        assert_eq!(*used.lock().unwrap(), vec![0, 0, 1, 1, 0, 0, 1, 1]);
    }
}
