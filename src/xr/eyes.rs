//! The eyes on the Vulkan renderer ([`GpuEyes`]) or, on a software Vulkan device, on the CPU reference
//! ([`CpuEyes`]). On the Vulkan renderer: one [`gpu::Renderer`] per eye (so spatial fusion follows each eye's own view
//! sequence) on the device the OpenXR runtime chose, fed with the person's mesh and source view once per input
//! frame ([`Scene`], from a [`SceneFeed`]), rendering each eye's perspective camera on the GPU through the person
//! renderer of every path ([`GpuView`] under a per-eye [`NeuralPolicy`]).
//!
//! Where the renderers run: on the OpenXR session's device, on a second queue of its queue family when there is
//! one (the results are then copied GPU to GPU). A device with a single queue (lavapipe, many GPUs' graphics
//! family) executes submissions in order, so the runtime's per-frame work in `xrEndFrame` would wait behind a
//! whole eye render; there the renderers get their own device ([`GpuEyes::new`] with a separate `render`
//! context) and each finished eye image is handed over through a host-visible staging buffer on the session's
//! device, written by the render thread (one copy of the eye image per render, never in the display loop).
//!
//! The panorama is locked to the room, not to the person: the renderer looks it up in body-cube directions, so it
//! is uploaded turned by the placement's yaw (and uploaded again when a controller turns the person).

use std::sync::Arc;
use std::time::{Duration, Instant};

use ash::vk;
use glam::Vec4;
use rayon::prelude::*;

use super::pacing::{timed, EyeError, EyeRenderer, EyeRequest};
use super::placement::Placement;
use crate::capture::stats::{DurationHistogram, StageStats};
use crate::compose::{Mode, RenderedFrame};
use crate::geometry::Camera;
use crate::gpu::{self, resources::Buffer, GpuView, Renderer};
use crate::io::environment::Environment;
use crate::pipeline::warp::OcclusionFill;
use crate::pipeline::{CpuView, NeuralCounters, NeuralPolicy, Scene};

/// Where new scenes come from: a still photo (one scene) or a live source (a new scene per completed frame).
/// Polled by the render thread before every request; must never block.
pub trait SceneFeed: Send {
    /// The newest scene if one completed since the last call.
    fn poll(&mut self) -> Option<Arc<Scene>>;
    /// Messages for the user since the last call (a source that ended, a corrupt frame).
    fn take_messages(&mut self) -> Vec<String> {
        Vec::new()
    }
    /// Whether the source's newest frame holds no person: the eyes then show none (the scene stays for when the
    /// person comes back).
    fn person_absent(&self) -> bool {
        false
    }
}

/// A feed with one scene (a still photo).
pub struct StaticScene(Option<Arc<Scene>>);

impl StaticScene {
    /// A feed that yields `scene` once.
    pub fn new(scene: Scene) -> Self {
        Self(Some(Arc::new(scene)))
    }
}

impl SceneFeed for StaticScene {
    fn poll(&mut self) -> Option<Arc<Scene>> {
        self.0.take()
    }
}

/// What the neural renderer did for the eyes of a session.
#[derive(Clone, Debug, Default)]
pub struct NeuralEyeStats {
    /// Over both eyes: eye images drawn by the decoder (reused layers included), decoder runs, reused layers
    /// (same pose, same input), fallbacks (eye images the neural renderer failed on, drawn geometrically).
    pub counters: NeuralCounters,
    /// Per decoder run: GPU raster + flow/Z-map including the read-back into host memory (a histogram: fixed
    /// memory however long the session runs).
    pub gpu_inputs: DurationHistogram,
    /// Per decoder run: colour lookup, feature sampling and the decoder on ONNX Runtime (a histogram).
    pub decoder: DurationHistogram,
}

impl NeuralEyeStats {
    /// One line for the session report; `None` when no eye was meant to be neural.
    pub fn summary(&self) -> Option<String> {
        let c = self.counters;
        if c.views + c.fallbacks == 0 {
            return None;
        }
        let ms = |h: &DurationHistogram| h.median().as_secs_f64() * 1e3;
        Some(format!(
            "neural (decoder on ONNX Runtime through host memory: GPU raster + flow read back, decoded on the host, \
             uploaded for compositing): {} eye images, {} decoder runs (median GPU inputs {:.1} ms, lookup + \
             decoder {:.1} ms), {} reused, {} geometric fallbacks",
            c.views,
            c.decoder_runs,
            ms(&self.gpu_inputs),
            ms(&self.decoder),
            c.reused,
            c.fallbacks
        ))
    }
}

/// The per-eye Vulkan renderers and their inputs. See the module docs.
pub struct GpuEyes {
    renderers: Vec<Renderer>,
    /// Per-eye staging buffers on the session's device when the renderers run on their own device.
    staging: Option<Vec<Buffer>>,
    feed: Box<dyn SceneFeed>,
    /// The scene on the GPU (kept for the neural decoder's colour lookup and features).
    scene: Option<Arc<Scene>>,
    /// Scenes uploaded so far (identifies the scene of a cached neural layer).
    scene_count: u64,
    /// Per eye: the person-renderer policy (its neural layer, fallbacks and counters).
    policies: Vec<NeuralPolicy>,
    /// Neural eye renders, decoder runs, fallbacks and host times.
    pub neural_stats: NeuralEyeStats,
    mode: Mode,
    environment: Option<Environment>,
    /// Yaw of the panorama as loaded (radians).
    base_yaw: f32,
    /// Placement yaw the panorama was last uploaded for.
    uploaded_for_yaw: Option<f32>,
}

impl std::fmt::Debug for GpuEyes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuEyes").field("eyes", &self.renderers.len()).field("mode", &self.mode).finish()
    }
}

impl GpuEyes {
    /// One renderer per eye of the given sizes on `render`, for a session on `session` (the same context, or a
    /// separate device: then each result is staged in host-visible memory of the session's device). VR needs the
    /// panorama (`environment`); AR ignores it.
    pub fn new(
        session: Arc<gpu::Context>,
        render: Arc<gpu::Context>,
        sizes: &[(usize, usize)],
        mode: Mode,
        environment: Option<Environment>,
        feed: Box<dyn SceneFeed>,
    ) -> Result<Self, gpu::GpuError> {
        needs_panorama(mode, environment.as_ref())?;
        let mut renderers = Vec::with_capacity(sizes.len());
        for &(w, h) in sizes {
            let mut r = Renderer::new(render.clone(), w, h)?;
            r.set_fill(OcclusionFill::default());
            r.set_fusion(true);
            renderers.push(r);
        }
        let base_yaw = environment.as_ref().map_or(0.0, |e| e.yaw);
        let staging = if Arc::ptr_eq(&session, &render) { None } else { Some(staging_buffers(&session, sizes)?) };
        Ok(Self {
            renderers,
            staging,
            feed,
            scene: None,
            scene_count: 0,
            policies: vec![NeuralPolicy::default(); sizes.len()],
            neural_stats: NeuralEyeStats::default(),
            mode,
            environment: if mode == Mode::Vr { environment } else { None },
            base_yaw,
            uploaded_for_yaw: None,
        })
    }

    /// The panorama yaw that keeps it locked to the room for a person turned by `placement_yaw`: the renderer
    /// looks up body-cube directions `R_y(-placement_yaw) d`, and a panorama of yaw `y` is looked up along
    /// `R_y(y) d` (see `io::environment::direction_to_uv`), so `base + placement_yaw` gives `R_y(base) d`, the
    /// room-locked lookup.
    pub fn room_locked_yaw(base_yaw: f32, placement_yaw: f32) -> f32 {
        base_yaw + placement_yaw
    }

    fn upload_scene(&mut self, scene: &Scene) -> Result<(), gpu::GpuError> {
        for r in &mut self.renderers {
            r.set_scene(&scene.source())?;
        }
        Ok(())
    }
}

impl EyeRenderer for GpuEyes {
    fn refresh(&mut self, placement: &Placement) -> Result<bool, EyeError> {
        let mut uploaded = false;
        if let Some(scene) = self.feed.poll() {
            self.upload_scene(&scene)
                .map_err(|source| EyeError::Gpu { what: "uploading the person to the GPU".into(), source })?;
            self.scene = Some(scene);
            self.scene_count += 1;
            uploaded = true;
        }
        if let Some(env) = &mut self.environment {
            if self.uploaded_for_yaw != Some(placement.yaw) {
                env.yaw = Self::room_locked_yaw(self.base_yaw, placement.yaw);
                for r in &mut self.renderers {
                    r.set_environment(env)
                        .map_err(|source| EyeError::Gpu { what: "uploading the panorama to the GPU".into(), source })?;
                }
                self.uploaded_for_yaw = Some(placement.yaw);
            }
        }
        Ok(uploaded)
    }

    fn has_content(&self) -> bool {
        self.scene.is_some()
    }

    fn render_eye(&mut self, eye: &EyeRequest) -> Result<vk::Buffer, EyeError> {
        let mode = self.mode;
        let gpu = |source| EyeError::Gpu { what: format!("eye {}", eye.eye), source };
        let r = self.renderers.get_mut(eye.eye).ok_or(EyeError::NoRenderer(eye.eye))?;
        let camera = (eye.body_camera.width, eye.body_camera.height);
        if r.size() != camera {
            return Err(EyeError::SizeMismatch { eye: eye.eye, camera, renderer: r.size() });
        }
        // One policy per renderer (made together in `new`).
        let policy = self.policies.get_mut(eye.eye).ok_or(EyeError::NoRenderer(eye.eye))?;
        match self.scene.as_ref().filter(|_| !self.feed.person_absent()) {
            Some(scene) => {
                let before = policy.counters();
                let mut view = GpuView { renderer: &mut *r, mode, target: None };
                policy
                    .draw(&mut view, scene.source(), scene.neural(), self.scene_count, &eye.body_camera)
                    .map_err(gpu)?;
                let drawn = policy.counters().since(before);
                if drawn.decoder_runs > 0 {
                    let times = policy.last_times();
                    self.neural_stats.gpu_inputs.record(times.gpu_inputs);
                    self.neural_stats.decoder.record(times.decoder);
                }
                self.neural_stats.counters += drawn;
            }
            // The person has left (the scene stays for their return): the panorama or an empty layer, with fusion
            // restarted so no trace of the last person lingers.
            None if self.scene.is_some() => {
                let (w, h) = r.size();
                let nobody = crate::buffer::RgbaImage::new(w, h, Vec4::ZERO);
                r.set_fusion(false);
                let drawn = r.render_frame_from_person(Some(&nobody), &eye.body_camera, mode, None);
                r.set_fusion(true);
                drawn.map_err(gpu)?;
            }
            None => r.render_frame(&eye.body_camera, mode, None).map_err(gpu)?,
        }
        match self.staging.as_mut().and_then(|s| s.get_mut(eye.eye)) {
            // Separate device: hand the result over through the session device's host-visible buffer. Safe to
            // rewrite: the display loop reported its copy out of it finished before this render started (`copied`).
            Some(buffer) => {
                let data: Vec<Vec4> = match r.read_output(mode) {
                    RenderedFrame::Vr(img) => img.data.iter().map(|c| c.extend(1.0)).collect(),
                    RenderedFrame::Ar(img) => img.data,
                };
                buffer.write(&data);
                Ok(buffer.buffer)
            }
            None => Ok(r.output_buffer()),
        }
    }

    fn take_messages(&mut self) -> Vec<String> {
        self.feed.take_messages()
    }
}

/// Result buffer sets of the CPU eyes: the next pair is drawn into one while the display loop's copy out of the
/// other waits for its frame ([`EyeRenderer::buffer_sets`]).
pub const CPU_EYE_BUFFER_SETS: usize = 2;

/// One eye of [`CpuEyeViews`]: its view sequence and its finished image.
struct CpuEye {
    view: CpuView,
    size: (usize, usize),
    /// The finished eye as the result buffer holds it (linear RGBA, row-major), kept from render to render.
    pixels: Vec<Vec4>,
}

/// What drawing one eye measured, merged into [`CpuEyeViews`]' statistics in eye order once all eyes are drawn.
#[derive(Default)]
struct EyeRecord {
    stages: Vec<(&'static str, Duration)>,
    neural: NeuralCounters,
    decoder: Option<Duration>,
}

/// The CPU eyes without device memory: one [`CpuView`] per eye (so spatial fusion follows each eye's own view
/// sequence) and each eye's finished image, composited over the room-locked panorama in VR or as the premultiplied
/// layer in AR. [`CpuEyes`] writes these images into the session's device memory; the pieces are public so the
/// two ways of drawing a pair can be compared without a headset (`examples/xr_eye_pairs.rs`).
pub struct CpuEyeViews {
    eyes: Vec<CpuEye>,
    mode: Mode,
    environment: Option<Environment>,
    /// Neural eye renders, decoder runs, fallbacks and host times.
    pub neural_stats: NeuralEyeStats,
    /// Each eye render's stages (the view's own, the composite, and in [`CpuEyes`] the write into device memory):
    /// medians over the last [`EYE_STAGE_WINDOW`] eyes. With both eyes drawn at once a stage's time is its wall
    /// time while the other eye is drawn beside it.
    pub stages: StageStats,
}

impl std::fmt::Debug for CpuEyeViews {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CpuEyeViews").field("eyes", &self.eyes.len()).field("mode", &self.mode).finish()
    }
}

impl CpuEyeViews {
    /// One view sequence per eye of the given sizes. VR needs the panorama (`environment`); AR ignores it.
    pub fn new(sizes: &[(usize, usize)], mode: Mode, environment: Option<Environment>) -> Result<Self, gpu::GpuError> {
        needs_panorama(mode, environment.as_ref())?;
        Ok(Self {
            eyes: sizes
                .iter()
                .map(|&size| CpuEye { view: CpuView::new(OcclusionFill::default(), true), size, pixels: Vec::new() })
                .collect(),
            mode,
            environment: if mode == Mode::Vr { environment } else { None },
            neural_stats: NeuralEyeStats::default(),
            stages: StageStats::new(EYE_STAGE_WINDOW),
        })
    }

    /// Turns the panorama (VR) to `yaw` radians; nothing in AR.
    pub fn set_panorama_yaw(&mut self, yaw: f32) {
        if let Some(env) = &mut self.environment {
            env.yaw = yaw;
        }
    }

    /// Draws eye `eye` for `camera` (its size): the person of `scene` (the scene and a number that changes with it,
    /// for the neural layer's reuse), or nobody when `None`, composited for the mode.
    pub fn draw_eye(&mut self, scene: Option<(&Scene, u64)>, eye: usize, camera: &Camera) -> Result<(), EyeError> {
        let (mode, environment) = (self.mode, self.environment.as_ref());
        let one = self.eyes.get_mut(eye).ok_or(EyeError::NoRenderer(eye))?;
        let record = draw_cpu_eye(one, eye, scene, mode, environment, camera)?;
        self.record(record);
        Ok(())
    }

    /// Draws the first `cameras.len()` eyes at the same time, each eye's work on its own worker of the current
    /// rayon pool (the eyes' own parallel stages spread over the pool as each finishes), with the same pixels as
    /// [`CpuEyeViews::draw_eye`] for each eye in turn (each eye keeps its own view sequence, and the stages are
    /// deterministic). A neural scene's eyes are drawn one after the other: its decoder runs one view at a time
    /// under its lock anyway, and a worker that waited for the lock inside the other eye's parallel work could
    /// deadlock.
    pub fn draw_eyes(&mut self, scene: Option<(&Scene, u64)>, cameras: &[Camera]) -> Result<(), EyeError> {
        if cameras.len() > self.eyes.len() {
            return Err(EyeError::NoRenderer(self.eyes.len()));
        }
        if scene.is_some_and(|(s, _)| s.neural.is_some()) {
            for (eye, camera) in cameras.iter().enumerate() {
                self.draw_eye(scene, eye, camera)?;
            }
            return Ok(());
        }
        let (mode, environment) = (self.mode, self.environment.as_ref());
        let records: Vec<Result<EyeRecord, EyeError>> = self
            .eyes
            .par_iter_mut()
            .zip(cameras.par_iter())
            .enumerate()
            .map(|(eye, (one, camera))| draw_cpu_eye(one, eye, scene, mode, environment, camera))
            .collect();
        for record in records {
            self.record(record?);
        }
        Ok(())
    }

    /// Eye `eye`'s finished image (linear RGBA, row-major, of its size; empty before its first draw).
    pub fn pixels(&self, eye: usize) -> Option<&[Vec4]> {
        self.eyes.get(eye).map(|e| e.pixels.as_slice())
    }

    fn record(&mut self, record: EyeRecord) {
        for (name, d) in record.stages {
            self.stages.record(name, d);
        }
        if let Some(d) = record.decoder {
            self.neural_stats.decoder.record(d);
        }
        self.neural_stats.counters += record.neural;
    }
}

/// Draws one eye into its `pixels` (see [`CpuEyeViews::draw_eye`]); `index` names it in errors.
fn draw_cpu_eye(
    eye: &mut CpuEye,
    index: usize,
    scene: Option<(&Scene, u64)>,
    mode: Mode,
    environment: Option<&Environment>,
    camera: &Camera,
) -> Result<EyeRecord, EyeError> {
    if eye.size != (camera.width, camera.height) {
        return Err(EyeError::SizeMismatch { eye: index, camera: (camera.width, camera.height), renderer: eye.size });
    }
    let mut record = EyeRecord::default();
    let view = &mut eye.view;
    let person = match scene {
        Some((scene, number)) => {
            let before = view.neural_counters();
            let t = Instant::now();
            let (person, _) = view
                .draw(scene.source(), scene.neural(), number, camera)
                .map_err(|source| EyeError::Cpu { eye: index, source })?;
            record.neural = view.neural_counters().since(before);
            record.decoder = (record.neural.decoder_runs > 0).then(|| t.elapsed());
            record.stages.extend(view.timings.0.iter().copied());
            person
        }
        None => crate::buffer::RgbaImage::new(eye.size.0, eye.size.1, Vec4::ZERO),
    };
    let t = Instant::now();
    match (mode, environment) {
        (Mode::Vr, Some(env)) => {
            crate::compose::compose_vr_rgba_into(&person, env, camera, &mut eye.pixels);
            record.stages.push(("compose (panorama)", t.elapsed()));
        }
        _ => {
            crate::compose::compose_ar_into(&person, &mut eye.pixels);
            record.stages.push(("compose (AR layer)", t.elapsed()));
        }
    }
    Ok(record)
}

/// The eyes on the CPU reference ([`CpuEyeViews`]), for a session whose only Vulkan device is a software
/// rasteriser: there the Vulkan passes share the CPU's cores with the rasteriser's own overhead and run several
/// times slower than the reference. Both eyes of a request are drawn at the same time
/// ([`CpuEyeViews::draw_eyes`]); each finished eye image is written into a host-visible buffer on the session's
/// device: one upload per eye render, which the display loop copies into the swapchain image as it copies a
/// Vulkan eye.
pub struct CpuEyes {
    /// The eyes' views, images and statistics.
    pub views: CpuEyeViews,
    /// Host-visible result buffers: [`CPU_EYE_BUFFER_SETS`] sets of one per eye.
    staging: Vec<Vec<Buffer>>,
    feed: Box<dyn SceneFeed>,
    scene: Option<Arc<Scene>>,
    scene_count: u64,
    base_yaw: f32,
}

/// Eye renders over which [`CpuEyeViews::stages`] keeps its medians.
pub const EYE_STAGE_WINDOW: usize = 512;

impl std::fmt::Debug for CpuEyes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CpuEyes").field("views", &self.views).finish()
    }
}

impl CpuEyes {
    /// One CPU view sequence per eye of the given sizes, staging into host-visible buffers of `session`. VR needs
    /// the panorama (`environment`); AR ignores it.
    pub fn new(
        session: Arc<gpu::Context>,
        sizes: &[(usize, usize)],
        mode: Mode,
        environment: Option<Environment>,
        feed: Box<dyn SceneFeed>,
    ) -> Result<Self, gpu::GpuError> {
        let base_yaw = environment.as_ref().map_or(0.0, |e| e.yaw);
        let views = CpuEyeViews::new(sizes, mode, environment)?;
        let staging =
            (0..CPU_EYE_BUFFER_SETS).map(|_| staging_buffers(&session, sizes)).collect::<Result<Vec<_>, _>>()?;
        Ok(Self { views, staging, feed, scene: None, scene_count: 0, base_yaw })
    }

    /// Writes eye `eye`'s finished image into its result buffer of set `set`.
    fn stage(&mut self, eye: usize, set: usize) -> Result<vk::Buffer, EyeError> {
        let buffer = self.staging.get_mut(set).and_then(|s| s.get_mut(eye)).ok_or(EyeError::NoRenderer(eye))?;
        let pixels = self.views.pixels(eye).ok_or(EyeError::NoRenderer(eye))?;
        // Safe to rewrite: the display loop never took this set's frame, or reported its copy finished (`copied`).
        let t = Instant::now();
        buffer.write(pixels);
        self.views.stages.record("write to device memory", t.elapsed());
        Ok(buffer.buffer)
    }
}

impl EyeRenderer for CpuEyes {
    fn refresh(&mut self, placement: &Placement) -> Result<bool, EyeError> {
        let mut uploaded = false;
        if let Some(scene) = self.feed.poll() {
            self.scene = Some(scene);
            self.scene_count += 1;
            uploaded = true;
        }
        // The panorama is looked up on the CPU: turning it is setting its yaw.
        self.views.set_panorama_yaw(GpuEyes::room_locked_yaw(self.base_yaw, placement.yaw));
        Ok(uploaded)
    }

    fn has_content(&self) -> bool {
        self.scene.is_some()
    }

    fn render_eye(&mut self, eye: &EyeRequest) -> Result<vk::Buffer, EyeError> {
        let person = shown(self.scene.as_deref(), &*self.feed, self.scene_count);
        self.views.draw_eye(person, eye.eye, &eye.body_camera)?;
        self.stage(eye.eye, eye.set)
    }

    /// Both eyes at once ([`CpuEyeViews::draw_eyes`]); each eye's time is the pair's wall time (drawing and the
    /// writes into device memory) divided by the number of eyes, so the eye times of a request still add up to its
    /// wall time.
    fn render_eyes(&mut self, eyes: &[EyeRequest]) -> Result<Vec<(vk::Buffer, Duration)>, EyeError> {
        // The pair is drawn as one when the eyes are 0, 1, … in order (as `render_request` asks them).
        if eyes.iter().enumerate().any(|(k, e)| e.eye != k) {
            return eyes.iter().map(|e| timed(|| self.render_eye(e))).collect();
        }
        let start = Instant::now();
        let cameras: Vec<Camera> = eyes.iter().map(|e| e.body_camera).collect();
        let person = shown(self.scene.as_deref(), &*self.feed, self.scene_count);
        self.views.draw_eyes(person, &cameras)?;
        let buffers = eyes.iter().map(|e| self.stage(e.eye, e.set)).collect::<Result<Vec<_>, _>>()?;
        let share = start.elapsed() / eyes.len().max(1) as u32;
        Ok(buffers.into_iter().map(|b| (b, share)).collect())
    }

    fn buffer_sets(&self) -> usize {
        CPU_EYE_BUFFER_SETS
    }

    fn take_messages(&mut self) -> Vec<String> {
        self.feed.take_messages()
    }
}

/// VR shows the person in a panorama: an error without one.
/// The person the CPU eyes draw: the feed's last scene with its number, or nobody when the person has left (the
/// scene stays for their return).
fn shown<'a>(scene: Option<&'a Scene>, feed: &dyn SceneFeed, number: u64) -> Option<(&'a Scene, u64)> {
    scene.filter(|_| !feed.person_absent()).map(|s| (s, number))
}

fn needs_panorama(mode: Mode, environment: Option<&Environment>) -> Result<(), gpu::GpuError> {
    match (mode, environment) {
        (Mode::Vr, None) => Err(gpu::GpuError::Invalid("VR needs a panorama to show around the person".into())),
        _ => Ok(()),
    }
}

/// One host-visible buffer per eye on the session's device, of the eye's size in `vec4`s: where a finished eye is
/// handed to the display loop's copy.
fn staging_buffers(session: &Arc<gpu::Context>, sizes: &[(usize, usize)]) -> Result<Vec<Buffer>, gpu::GpuError> {
    sizes.iter().map(|&(w, h)| Buffer::new(session, (w * h * 16) as u64, vk::BufferUsageFlags::TRANSFER_SRC)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::environment::direction_to_uv;
    use glam::{Quat, Vec3};
    use std::time::Duration;

    #[test]
    fn the_panorama_stays_locked_to_the_room_when_the_person_turns() {
        // A stage direction d seen through a body camera is looked up as R_y(-placement_yaw) d with the uploaded
        // yaw; it must land where the room-locked lookup of d with the base yaw lands.
        for &(base, turn) in &[(0.0f32, 0.0f32), (0.3, 1.2), (-2.0, 0.7), (1.0, -3.0)] {
            for d in [Vec3::new(0.3, 0.2, -0.9), Vec3::new(-0.8, -0.1, 0.4), Vec3::X] {
                let d = d.normalize();
                let body = Quat::from_rotation_y(-turn) * d;
                let got = direction_to_uv(body, GpuEyes::room_locked_yaw(base, turn));
                let want = direction_to_uv(d, base);
                let du = (got.0 - want.0).abs();
                assert!(du.min(1.0 - du) < 1e-5 && (got.1 - want.1).abs() < 1e-5, "{base} {turn} {d}: {got:?}");
            }
        }
    }

    #[test]
    fn neural_eye_times_are_summarised_by_their_medians() {
        let mut stats = NeuralEyeStats::default();
        assert_eq!(stats.summary(), None);
        stats.counters.views = 3;
        stats.counters.decoder_runs = 3;
        for ms in [4, 1, 2] {
            stats.gpu_inputs.record(Duration::from_millis(ms));
            stats.decoder.record(Duration::from_millis(10 * ms));
        }
        let line = stats.summary().unwrap();
        assert!(line.contains("median GPU inputs 2.0 ms, lookup + decoder 20.0 ms"), "{line}");
        assert_eq!((stats.gpu_inputs.count(), stats.decoder.count()), (3, 3));
    }

    #[test]
    fn a_static_scene_is_polled_once() {
        use crate::buffer::{GrayImage, RgbImage};
        use crate::geometry::raster::GBuffer;
        use crate::geometry::{Camera, TriMesh};
        let scene = Scene {
            mesh: TriMesh::cuboid(Vec3::splat(-0.5), Vec3::splat(0.5)),
            mesh_closed: true,
            coarse: None,
            rgb: RgbImage::new(4, 4, Vec3::ONE),
            mask: GrayImage::new(4, 4, 1.0),
            gbuffer: GBuffer::new(4, 4),
            camera: Camera::source(4),
            back: None,
            side: None,
            neural: None,
        };
        let mut feed = StaticScene::new(scene);
        assert!(feed.poll().is_some());
        assert!(feed.poll().is_none());
        assert!(feed.take_messages().is_empty());
    }

    /// A lit box seen from its source camera: a small scene whose warp, fusion and composite all do work.
    fn box_scene() -> Scene {
        use crate::buffer::{GrayImage, RgbImage};
        use crate::geometry::raster::{rasterize_into, GBuffer};
        use crate::geometry::{Camera, TriMesh};
        let n = 32;
        let mesh = TriMesh::cuboid(Vec3::new(-0.4, -0.6, -0.3), Vec3::new(0.4, 0.6, 0.3));
        let camera = Camera::source(n);
        let mut gbuffer = GBuffer::new(n, n);
        rasterize_into(&mut gbuffer, &mesh, &camera);
        Scene {
            mesh,
            mesh_closed: true,
            coarse: None,
            rgb: RgbImage::from_fn(n, n, |c, r| Vec3::new(c as f32 / n as f32, r as f32 / n as f32, 0.3)),
            mask: GrayImage::new(n, n, 1.0),
            gbuffer,
            camera,
            back: None,
            side: None,
            neural: None,
        }
    }

    #[test]
    fn both_eyes_at_once_draw_the_pixels_of_one_after_the_other() {
        use crate::geometry::{Camera, Fov};
        let scene = box_scene();
        let (w, h) = (40, 36);
        let fov = Fov::symmetric(1.2, w as f32 / h as f32);
        // A head moving a little from frame to frame (spatial fusion carries each eye's last view), then a frame
        // without the person.
        let cameras = |frame: usize| -> Vec<Camera> {
            let turn = Quat::from_rotation_y(0.05 * frame as f32);
            [-0.032f32, 0.032]
                .iter()
                .map(|&x| Camera::perspective(turn * Vec3::new(x, 0.1, 2.2), turn, fov, 0.05, w, h))
                .collect()
        };
        for mode in [Mode::Vr, Mode::Ar] {
            let env = (mode == Mode::Vr).then(Environment::default_embedded);
            let mut one_by_one = CpuEyeViews::new(&[(w, h); 2], mode, env.clone()).unwrap();
            let mut at_once = CpuEyeViews::new(&[(w, h); 2], mode, env).unwrap();
            for frame in 0..4 {
                let person = (frame < 3).then_some((&scene, 1));
                let cams = cameras(frame);
                for (eye, camera) in cams.iter().enumerate() {
                    one_by_one.draw_eye(person, eye, camera).unwrap();
                }
                at_once.draw_eyes(person, &cams).unwrap();
                for eye in 0..2 {
                    let bytes = |v: &CpuEyeViews| -> Vec<u32> {
                        v.pixels(eye).unwrap().iter().flat_map(|p| p.to_array().map(f32::to_bits)).collect()
                    };
                    let (a, b) = (bytes(&one_by_one), bytes(&at_once));
                    assert_eq!(a.len(), w * h * 4);
                    assert!(a == b, "{mode:?} frame {frame} eye {eye}: the pair differs");
                }
                // Something was drawn: the person covers part of the eye while present.
                let covered = at_once.pixels(0).unwrap().iter().filter(|p| p.w > 0.5 && mode == Mode::Ar).count();
                assert_eq!(covered > 0, mode == Mode::Ar && frame < 3, "{mode:?} frame {frame}");
            }
            assert_eq!(one_by_one.stages.summary().len(), at_once.stages.summary().len());
        }
        // Wrong sizes and too many cameras are errors, not panics.
        let mut eyes = CpuEyeViews::new(&[(w, h); 2], Mode::Ar, None).unwrap();
        let small = Camera::perspective(Vec3::Z, Quat::IDENTITY, fov, 0.05, 8, 8);
        assert!(matches!(eyes.draw_eyes(Some((&scene, 1)), &[small]), Err(EyeError::SizeMismatch { eye: 0, .. })));
        assert!(matches!(eyes.draw_eyes(None, &cameras(0).repeat(2)), Err(EyeError::NoRenderer(2))));
    }
}
