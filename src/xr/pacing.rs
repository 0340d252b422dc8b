//! Frame pacing: the display loop never waits on the person renderer.
//!
//! The display loop posts a [`RenderRequest`] every frame (the latest predicted eye poses; an older request not
//! yet started is simply replaced) and picks up the newest finished [`RenderedFrame`] whenever there is one. The
//! render thread renders both eyes for the newest request it finds. A frame whose image is not new re-submits the
//! previous image with the eye poses it was rendered for, so the compositor reprojects it to the current head pose.
//! [`PacingStats`] measures what the viewer gets: the share of frames that showed a fresh render and the
//! motion-to-photon latency of the person layer (pose sampling to predicted display time).

use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use glam::{Quat, Vec3};

use super::gfx::SwapchainFormat;
use super::placement::Placement;
use crate::buffer::RgbaImage;
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
}

/// Renders one eye's final image: linear, premultiplied RGBA of the camera's size (opaque in VR, the person as
/// an alpha layer in AR). Implemented by the app layer on top of the per-view pipeline.
pub trait EyeImageRenderer: Send {
    /// Renders `eye`; the error text ends up in the session report.
    fn render_eye(&mut self, eye: &EyeRequest) -> Result<RgbaImage, String>;
}

impl<F: FnMut(&EyeRequest) -> Result<RgbaImage, String> + Send> EyeImageRenderer for F {
    fn render_eye(&mut self, eye: &EyeRequest) -> Result<RgbaImage, String> {
        self(eye)
    }
}

/// Both eyes rendered for one request, already encoded for the swapchain.
#[derive(Debug)]
pub struct RenderedFrame {
    /// The request this answers.
    pub request: RenderRequest,
    /// Per-eye cameras used (body-cube coordinates).
    pub cameras: Vec<Camera>,
    /// Per-eye pixels in the swapchain format, top row first.
    pub encoded: Vec<Vec<u8>>,
    /// Per-eye render time.
    pub eye_times: Vec<Duration>,
}

#[derive(Default)]
struct Slots {
    pending: Option<RenderRequest>,
    shutdown: bool,
    latest: Option<Arc<RenderedFrame>>,
    error: Option<String>,
    eye_times: Vec<Duration>,
}

/// The mailbox between the display loop and the render thread.
#[derive(Default)]
pub struct RenderMailbox {
    slots: Mutex<Slots>,
    wake: Condvar,
}

impl RenderMailbox {
    /// A new mailbox.
    pub fn new() -> Arc<Self> {
        Arc::new(Self::default())
    }

    /// Posts the newest request, replacing one the render thread has not picked up yet. Never blocks on rendering.
    pub fn request(&self, request: RenderRequest) {
        if let Ok(mut s) = self.slots.lock() {
            s.pending = Some(request);
        }
        self.wake.notify_one();
    }

    /// The newest finished frame, if any.
    pub fn latest(&self) -> Option<Arc<RenderedFrame>> {
        self.slots.lock().ok().and_then(|s| s.latest.clone())
    }

    /// The render thread's error, if it stopped on one.
    pub fn error(&self) -> Option<String> {
        self.slots.lock().ok().and_then(|s| s.error.clone())
    }

    /// Every per-eye render time so far.
    pub fn eye_times(&self) -> Vec<Duration> {
        self.slots.lock().map(|s| s.eye_times.clone()).unwrap_or_default()
    }

    /// Asks the render thread to stop after its current render.
    pub fn shutdown(&self) {
        if let Ok(mut s) = self.slots.lock() {
            s.shutdown = true;
        }
        self.wake.notify_all();
    }

    /// The render thread's body: renders the newest request until [`RenderMailbox::shutdown`].
    pub fn run_render_loop(&self, renderer: &mut dyn EyeImageRenderer, format: SwapchainFormat) {
        loop {
            let request = {
                let Ok(mut s) = self.slots.lock() else { return };
                loop {
                    if s.shutdown {
                        return;
                    }
                    if let Some(r) = s.pending.take() {
                        break r;
                    }
                    s = match self.wake.wait(s) {
                        Ok(s) => s,
                        Err(_) => return,
                    };
                }
            };
            match render_request(renderer, &request, format) {
                Ok(frame) => {
                    if let Ok(mut s) = self.slots.lock() {
                        s.eye_times.extend_from_slice(&frame.eye_times);
                        s.latest = Some(Arc::new(frame));
                    }
                }
                Err(e) => {
                    if let Ok(mut s) = self.slots.lock() {
                        s.error = Some(e);
                    }
                    return;
                }
            }
        }
    }
}

/// Renders and encodes both eyes of one request.
pub fn render_request(
    renderer: &mut dyn EyeImageRenderer,
    request: &RenderRequest,
    format: SwapchainFormat,
) -> Result<RenderedFrame, String> {
    let mut cameras = Vec::with_capacity(request.views.len());
    let mut encoded = Vec::with_capacity(request.views.len());
    let mut eye_times = Vec::with_capacity(request.views.len());
    for (eye, (view, &(w, h))) in request.views.iter().zip(&request.sizes).enumerate() {
        let body_camera = request.placement.eye_camera(view.position, view.orientation, view.fov, w, h);
        let stage_camera = Placement::stage_camera(view.position, view.orientation, view.fov, w, h);
        let start = Instant::now();
        let img = renderer.render_eye(&EyeRequest { eye, body_camera, stage_camera })?;
        if img.width != w || img.height != h {
            return Err(format!("eye {eye}: renderer returned {}x{}, expected {w}x{h}", img.width, img.height));
        }
        eye_times.push(start.elapsed());
        encoded.push(format.encode_image(&img));
        cameras.push(body_camera);
    }
    Ok(RenderedFrame { request: request.clone(), cameras, encoded, eye_times })
}

/// Per-frame pacing measurements of the person layer.
#[derive(Clone, Debug, Default)]
pub struct PacingStats {
    /// Frames submitted with the person layer.
    pub person_frames: u64,
    /// Of those, frames that showed an image not shown before.
    pub fresh_frames: u64,
    /// Motion-to-photon latency per person frame (pose sampling to predicted display), nanoseconds.
    pub latencies_ns: Vec<i64>,
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
            self.latencies_ns.push(display_time.saturating_sub(t));
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

    /// Median motion-to-photon latency in milliseconds, if measured.
    pub fn median_latency_ms(&self) -> Option<f64> {
        median_i64(&self.latencies_ns).map(|ns| ns / 1e6)
    }
}

/// Median of a list (mean of the middle two for even lengths); `None` when empty.
pub fn median_i64(values: &[i64]) -> Option<f64> {
    let mut v = values.to_vec();
    v.sort_unstable();
    let n = v.len();
    match n {
        0 => None,
        _ if n % 2 == 1 => Some(v[n / 2] as f64),
        _ => Some((v[n / 2 - 1] as f64 + v[n / 2] as f64) / 2.0),
    }
}

/// Median of durations in milliseconds; `None` when empty.
pub fn median_ms(values: &[Duration]) -> Option<f64> {
    let ns: Vec<i64> = values.iter().map(|d| d.as_nanos().min(i64::MAX as u128) as i64).collect();
    median_i64(&ns).map(|m| m / 1e6)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec4;

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

    #[test]
    fn medians_and_shares_are_closed_form() {
        assert_eq!(median_i64(&[]), None);
        assert_eq!(median_i64(&[5, 1, 3]), Some(3.0));
        assert_eq!(median_i64(&[4, 1, 3, 2]), Some(2.5));
        assert_eq!(median_ms(&[Duration::from_millis(3), Duration::from_millis(1)]), Some(2.0));
        let mut s = PacingStats::default();
        assert_eq!(s.fresh_share(), 0.0);
        s.record(true, 50_000_000, Some(10_000_000));
        s.record(false, 100_000_000, Some(10_000_000));
        s.record(false, 150_000_000, None);
        s.record(true, 200_000_000, Some(170_000_000));
        assert!((s.fresh_share() - 0.5).abs() < 1e-12);
        assert_eq!(s.median_latency_ms(), Some(40.0));
    }

    #[test]
    fn render_request_uses_the_placement_and_checks_sizes() {
        let req = request(1);
        let mut seen = Vec::new();
        let mut r = |e: &EyeRequest| -> Result<RgbaImage, String> {
            seen.push((e.eye, e.body_camera.position(), e.stage_camera.position()));
            Ok(RgbaImage::new(e.body_camera.width, e.body_camera.height, Vec4::new(0.25, 0.5, 1.0, 1.0)))
        };
        let frame = render_request(&mut r, &req, SwapchainFormat::PREFERRED[2]).unwrap();
        assert_eq!(frame.encoded.len(), 2);
        assert_eq!(frame.encoded[0].len(), 8 * 6 * 4);
        assert_eq!(&frame.encoded[1][..4], &[64, 128, 255, 255]);
        // Eye 0 at (0, 1.6, 0) in the room is at (0, 0.7, 1.75) in body units for the default placement.
        assert!((seen[0].1 - Vec3::new(0.0, 0.7, 1.75)).length() < 1e-5);
        assert!((seen[1].2 - Vec3::new(0.06, 1.6, 0.0)).length() < 1e-6);
        let mut wrong = |_: &EyeRequest| -> Result<RgbaImage, String> { Ok(RgbaImage::new(2, 2, Vec4::ZERO)) };
        assert!(render_request(&mut wrong, &req, SwapchainFormat::PREFERRED[0]).unwrap_err().contains("expected 8x6"));
    }

    #[test]
    fn the_render_thread_renders_the_newest_request_and_never_blocks_the_poster() {
        let mailbox = RenderMailbox::new();
        let gate = Arc::new((Mutex::new(false), Condvar::new()));
        std::thread::scope(|scope| {
            let m = mailbox.clone();
            let g = gate.clone();
            scope.spawn(move || {
                // A renderer that blocks until the test opens the gate (a slow decoder).
                let mut r = move |e: &EyeRequest| -> Result<RgbaImage, String> {
                    let (lock, cv) = &*g;
                    let mut open = lock.lock().unwrap();
                    while !*open {
                        open = cv.wait(open).unwrap();
                    }
                    Ok(RgbaImage::new(e.body_camera.width, e.body_camera.height, Vec4::ONE))
                };
                m.run_render_loop(&mut r, SwapchainFormat::PREFERRED[0]);
            });
            // Posting many requests while the renderer is stuck returns immediately.
            let t = Instant::now();
            for seq in 1..=50 {
                mailbox.request(request(seq));
            }
            assert!(t.elapsed() < Duration::from_millis(500));
            assert!(mailbox.latest().is_none());
            {
                let (lock, cv) = &*gate;
                *lock.lock().unwrap() = true;
                cv.notify_all();
            }
            // The thread renders what it picked up first, then only the newest pending request (50).
            let deadline = Instant::now() + Duration::from_secs(10);
            while mailbox.latest().is_none_or(|f| f.request.seq != 50) {
                assert!(Instant::now() < deadline, "render thread never rendered the newest request");
                std::thread::sleep(Duration::from_millis(1));
            }
            assert!(mailbox.eye_times().len() <= 4, "at most two requests rendered");
            mailbox.shutdown();
        });
    }

    #[test]
    fn a_render_error_stops_the_thread_and_is_reported() {
        let mailbox = RenderMailbox::new();
        mailbox.request(request(1));
        let mut r = |_: &EyeRequest| -> Result<RgbaImage, String> { Err("decoder exploded".into()) };
        mailbox.run_render_loop(&mut r, SwapchainFormat::PREFERRED[0]);
        assert_eq!(mailbox.error().as_deref(), Some("decoder exploded"));
        assert!(mailbox.latest().is_none());
    }
}
