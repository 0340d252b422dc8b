//! The desktop mirror: `r2human view`. A winit window shows the person from an orbit camera, rendered by the
//! Vulkan per-view passes or by the CPU reference (then only presented through Vulkan).
//!
//! Controls: drag with the left button to orbit, wheel to zoom, `V`/`A` switch VR/AR, `G`/`N` geometric/neural
//! (neural only when a decoder is available), `S` writes a screenshot (atomic PNG). The window title shows the
//! mode and the frame time (median of the last frames). `--frames N` renders N frames and exits.
//!
//! Faults: a resized or minimised window recreates the swapchain (nothing is drawn while minimised); a lost
//! device or surface ends the loop with an error that says so.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context as _};
use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{Key, NamedKey};
use winit::raw_window_handle::{HasDisplayHandle, HasWindowHandle};
use winit::window::{Window, WindowId};

use crate::compose::Mode;
use crate::geometry::Camera;
use crate::gpu::{Context, GpuError, PresentTarget, Renderer};
use crate::io::environment::Environment;
use crate::io::image_io;
use crate::io::sequence::Frame;
use crate::pipeline::{PrepareOptions, PreparedInput};
use crate::window::{Acquired, Swapchain};

/// Which engine computes the person.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Backend {
    /// The CPU reference pipeline (the window still presents through Vulkan).
    Cpu,
    /// The Vulkan per-view passes.
    #[default]
    Vulkan,
}

/// Geometric warp or neural decoder.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Shading {
    /// The geometric warp of the photo (no model needed).
    #[default]
    Geometric,
    /// The neural decoder (only when a model is available).
    Neural,
}

/// Options of [`run_view`].
#[derive(Clone, Debug)]
pub struct ViewOptions {
    /// Photo of a person (PNG/JPEG); its alpha channel is the person mask unless `mask` is given.
    pub image: PathBuf,
    /// Person mask (white = person), same size as the image.
    pub mask: Option<PathBuf>,
    /// Panorama behind the person in VR (default: the embedded one).
    pub env: Option<PathBuf>,
    /// Start in VR or AR.
    pub mode: Mode,
    /// Engine for the person.
    pub backend: Backend,
    /// Render this many frames, then exit (`None`: until the window is closed).
    pub frames: Option<u64>,
    /// Initial window size (square), pixels.
    pub size: u32,
    /// Folder for `S` screenshots.
    pub screenshot_dir: PathBuf,
    /// Write the last frame to this PNG when the loop ends (for tests and scripted runs).
    pub screenshot_on_exit: Option<PathBuf>,
    /// Source (FOF grid) resolution of the prepared input; 512 like the reference.
    pub resolution: usize,
}

impl Default for ViewOptions {
    fn default() -> Self {
        Self {
            image: PathBuf::new(),
            mask: None,
            env: None,
            mode: Mode::Vr,
            backend: Backend::Vulkan,
            frames: None,
            size: 512,
            screenshot_dir: PathBuf::from("."),
            screenshot_on_exit: None,
            resolution: crate::geometry::SOURCE_RESOLUTION,
        }
    }
}

/// What a finished loop reports.
#[derive(Clone, Debug, Default)]
pub struct ViewStats {
    /// Frames presented.
    pub frames: u64,
    /// Median frame time (render + present) over the presented frames.
    pub median_frame: Duration,
    /// Screenshots written.
    pub screenshots: Vec<PathBuf>,
    /// Validation-layer errors + warnings seen (0 unless validation is on).
    pub validation_messages: u32,
    /// The Vulkan device that ran the window.
    pub device: String,
}

/// Orbit camera state driven by the mouse.
#[derive(Clone, Copy, Debug)]
pub struct Orbit {
    /// Degrees about the vertical axis (0 = the photo's viewpoint).
    pub yaw: f32,
    /// Degrees, positive looks down; kept within (-89, 89).
    pub pitch: f32,
    /// Magnification (1 = the body cube fills the height).
    pub zoom: f32,
}

impl Default for Orbit {
    fn default() -> Self {
        Self { yaw: 0.0, pitch: 0.0, zoom: 1.0 }
    }
}

impl Orbit {
    /// Degrees of orbit per pixel of drag.
    pub const DEGREES_PER_PIXEL: f32 = 0.4;

    /// Applies a drag of `(dx, dy)` pixels (right drag turns the person to show its left side, down drag looks
    /// from above).
    pub fn drag(&mut self, dx: f32, dy: f32) {
        if dx.is_finite() && dy.is_finite() {
            self.yaw = (self.yaw - dx * Self::DEGREES_PER_PIXEL).rem_euclid(360.0);
            self.pitch = (self.pitch + dy * Self::DEGREES_PER_PIXEL).clamp(-89.0, 89.0);
        }
    }

    /// Applies `steps` wheel notches (positive zooms in), bounded to [0.5, 4].
    pub fn wheel(&mut self, steps: f32) {
        if steps.is_finite() {
            self.zoom = (self.zoom * 1.1f32.powf(steps)).clamp(0.5, 4.0);
        }
    }

    /// The orthographic orbit camera for a `width x height` view.
    pub fn camera(&self, width: usize, height: usize) -> Camera {
        Camera::orthographic(Camera::orbit_rotation(self.yaw, self.pitch), 1.0 / self.zoom, width, height)
    }
}

/// The person engine behind the window.
pub trait PersonEngine {
    /// Is the neural decoder available?
    fn has_neural(&self) -> bool {
        false
    }

    /// Renders the frame for `camera` and presents it into `target` through `renderer` (whose size is the
    /// camera's). Returns the rendered frame when `want_frame` is set (screenshots).
    fn frame(
        &mut self,
        renderer: &mut Renderer,
        camera: &Camera,
        mode: Mode,
        shading: Shading,
        target: PresentTarget,
        want_frame: bool,
    ) -> anyhow::Result<Option<Frame>>;

    /// Uploads whatever the engine keeps on the GPU into a (new) renderer, e.g. after a resize.
    fn attach(&mut self, renderer: &mut Renderer) -> anyhow::Result<()>;
}

/// Opens the mirror window for a photo and runs until closed (or for `opts.frames` frames).
pub fn run_view(opts: ViewOptions) -> anyhow::Result<()> {
    run_view_with_stats(opts).map(|_| ())
}

/// [`run_view`], returning what the loop measured (frames, median frame time, screenshots, validation).
pub fn run_view_with_stats(opts: ViewOptions) -> anyhow::Result<ViewStats> {
    if !(64..=1024).contains(&opts.resolution) {
        bail!("source resolution {} is out of range: use 64 to 1024 (512 is the reference's)", opts.resolution);
    }
    let env = match (&opts.env, opts.mode) {
        (Some(p), _) => Environment::load(p).with_context(|| format!("cannot use the panorama {}", p.display()))?,
        (None, _) => Environment::default_embedded(),
    };
    let (photo, mask) = image_io::load_person(&opts.image, opts.mask.as_deref())?;
    tracing::info!("preparing the input (segmentation mask, geometry, mesh)");
    let prepare =
        PrepareOptions { resolution: opts.resolution, depth_samples: opts.resolution, ..PrepareOptions::default() };
    let input = PreparedInput::prepare(&photo.rgb, &mask, &prepare)?;
    let mut engine = engines::build(&input, &env, opts.backend);
    let stats = run_window(&mut *engine, &opts)?;
    tracing::info!("view: {} frames, median {:.2} ms", stats.frames, stats.median_frame.as_secs_f64() * 1e3);
    Ok(stats)
}

/// Runs the window loop with any engine (see [`run_view`]).
pub fn run_window(engine: &mut dyn PersonEngine, opts: &ViewOptions) -> anyhow::Result<ViewStats> {
    if opts.size < 16 || opts.size > 4096 {
        bail!("window size {} is out of range: use 16 to 4096 pixels", opts.size);
    }
    let mut builder = EventLoop::builder();
    #[cfg(all(unix, not(target_os = "macos"), not(target_os = "android")))]
    {
        // Tests run the loop off the main thread.
        use winit::platform::x11::EventLoopBuilderExtX11;
        builder.with_any_thread(true);
    }
    let event_loop = builder.build().map_err(|e| {
        anyhow!("cannot open a window ({e}); is a display available (DISPLAY / WAYLAND_DISPLAY)? Use `r2human render` for offline output")
    })?;
    event_loop.set_control_flow(ControlFlow::Poll);
    let mut app = App {
        engine,
        opts,
        mode: opts.mode,
        shading: Shading::Geometric,
        orbit: Orbit::default(),
        gfx: None,
        window: None,
        drag: None,
        cursor: (0.0, 0.0),
        frame_times: Vec::new(),
        last_title: Instant::now(),
        presented: 0,
        screenshot_requested: false,
        resized: false,
        error: None,
        stats: ViewStats::default(),
    };
    event_loop.run_app(&mut app).map_err(|e| anyhow!("the window event loop failed: {e}"))?;
    if let Some(e) = app.error {
        return Err(e);
    }
    let mut times = app.frame_times.clone();
    times.sort();
    app.stats.median_frame = times.get(times.len() / 2).copied().unwrap_or_default();
    app.stats.frames = app.presented;
    Ok(app.stats)
}

struct Graphics {
    ctx: Arc<Context>,
    swapchain: Swapchain,
    renderer: Renderer,
}

struct App<'a> {
    engine: &'a mut dyn PersonEngine,
    opts: &'a ViewOptions,
    mode: Mode,
    shading: Shading,
    orbit: Orbit,
    // Declared before `window`: the swapchain's surface must go before the window.
    gfx: Option<Graphics>,
    window: Option<Window>,
    drag: Option<(f64, f64)>,
    cursor: (f64, f64),
    frame_times: Vec<Duration>,
    last_title: Instant,
    presented: u64,
    screenshot_requested: bool,
    resized: bool,
    error: Option<anyhow::Error>,
    stats: ViewStats,
}

impl App<'_> {
    fn fail(&mut self, event_loop: &ActiveEventLoop, e: anyhow::Error) {
        if self.error.is_none() {
            self.error = Some(e);
        }
        event_loop.exit();
    }

    fn create(&mut self, event_loop: &ActiveEventLoop) -> anyhow::Result<()> {
        let attrs = Window::default_attributes()
            .with_title("r2human")
            .with_inner_size(PhysicalSize::new(self.opts.size, self.opts.size));
        let window = event_loop.create_window(attrs).map_err(|e| anyhow!("cannot create the window: {e}"))?;
        let display = window.display_handle().map_err(|e| anyhow!("no display handle: {e}"))?.as_raw();
        let handle = window.window_handle().map_err(|e| anyhow!("no window handle: {e}"))?.as_raw();
        let (ctx, surface) = Context::with_surface(display, handle, None)?;
        let ctx = Arc::new(ctx);
        let size = window.inner_size();
        let swapchain = Swapchain::new(&ctx, surface, size.width.max(1), size.height.max(1))?;
        let mut renderer =
            Renderer::new(ctx.clone(), swapchain.extent.width as usize, swapchain.extent.height as usize)?;
        self.engine.attach(&mut renderer)?;
        tracing::info!("view: {} on {}", swapchain.extent.width, ctx.device_name());
        self.gfx = Some(Graphics { ctx, swapchain, renderer });
        self.window = Some(window);
        Ok(())
    }

    /// Recreates the swapchain (and the renderer when the size changed). `false` while minimised.
    fn recreate(&mut self) -> anyhow::Result<bool> {
        let (Some(gfx), Some(window)) = (self.gfx.as_mut(), self.window.as_ref()) else { return Ok(false) };
        let size = window.inner_size();
        if size.width == 0 || size.height == 0 {
            return Ok(false);
        }
        if !gfx.swapchain.recreate(size.width, size.height)? {
            return Ok(false);
        }
        let extent = gfx.swapchain.extent;
        if gfx.renderer.size() != (extent.width as usize, extent.height as usize) {
            gfx.renderer = Renderer::new(gfx.ctx.clone(), extent.width as usize, extent.height as usize)?;
            self.engine.attach(&mut gfx.renderer)?;
        }
        Ok(true)
    }

    fn redraw(&mut self) -> anyhow::Result<()> {
        if self.resized {
            self.resized = false;
            if !self.recreate()? {
                return Ok(());
            }
        }
        let Some(gfx) = self.gfx.as_mut() else { return Ok(()) };
        let start = Instant::now();
        let acquired = gfx.swapchain.acquire()?;
        let Acquired::Image { index, image, ready, rendered } = acquired else {
            self.resized = true;
            return Ok(());
        };
        let (w, h) = gfx.renderer.size();
        let camera = self.orbit.camera(w, h);
        let last = self.opts.frames.is_some_and(|n| self.presented + 1 >= n);
        let want = self.screenshot_requested || (last && self.opts.screenshot_on_exit.is_some());
        let target = PresentTarget { image, wait: ready, signal: rendered, bgra: gfx.swapchain.is_bgra() };
        let frame = self.engine.frame(&mut gfx.renderer, &camera, self.mode, self.shading, target, want)?;
        if gfx.swapchain.present(index)? {
            self.resized = true;
        }
        self.presented += 1;
        self.frame_times.push(start.elapsed());
        if let Some(frame) = frame {
            if self.screenshot_requested {
                self.screenshot_requested = false;
                let path = self.opts.screenshot_dir.join(format!("r2human-{:05}.png", self.presented));
                save_frame(&path, &frame)?;
                self.stats.screenshots.push(path);
            }
            if last {
                if let Some(path) = &self.opts.screenshot_on_exit {
                    save_frame(path, &frame)?;
                    self.stats.screenshots.push(path.clone());
                }
            }
        }
        self.update_title();
        Ok(())
    }

    fn update_title(&mut self) {
        if self.last_title.elapsed() < Duration::from_millis(250) && self.presented > 1 {
            return;
        }
        self.last_title = Instant::now();
        let recent = &self.frame_times[self.frame_times.len().saturating_sub(30)..];
        let mut sorted = recent.to_vec();
        sorted.sort();
        let median = sorted.get(sorted.len() / 2).copied().unwrap_or_default();
        let ms = median.as_secs_f64() * 1e3;
        let title = format!(
            "r2human | {} | {} | {:?} | {ms:.1} ms/frame ({:.0} fps) | drag: orbit, wheel: zoom, V/A, G/N, S: screenshot",
            match self.mode {
                Mode::Vr => "VR",
                Mode::Ar => "AR",
            },
            match self.shading {
                Shading::Geometric => "geometric",
                Shading::Neural => "neural",
            },
            self.opts.backend,
            if ms > 0.0 { 1e3 / ms } else { 0.0 },
        );
        if let Some(w) = &self.window {
            w.set_title(&title);
        }
    }

    fn key(&mut self, key: &Key) {
        let Key::Character(c) = key else { return };
        match c.to_lowercase().as_str() {
            "v" => self.mode = Mode::Vr,
            "a" => self.mode = Mode::Ar,
            "g" => self.shading = Shading::Geometric,
            "n" => {
                if self.engine.has_neural() {
                    self.shading = Shading::Neural;
                } else {
                    tracing::warn!("no neural decoder is available: staying with the geometric warp");
                }
            }
            "s" => self.screenshot_requested = true,
            _ => {}
        }
    }
}

fn save_frame(path: &std::path::Path, frame: &Frame) -> anyhow::Result<()> {
    match frame {
        Frame::Vr(img) => image_io::save_rgb_png(path, img)?,
        Frame::Ar(img) => image_io::save_rgba_png(path, img)?,
    }
    tracing::info!("screenshot: {}", path.display());
    Ok(())
}

impl ApplicationHandler for App<'_> {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.window.is_none() {
            if let Err(e) = self.create(event_loop) {
                self.fail(event_loop, e);
            }
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(_) => self.resized = true,
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.redraw() {
                    let e = match e.downcast::<GpuError>() {
                        Ok(GpuError::DeviceLost) => anyhow!("the Vulkan device was lost; the mirror window closed"),
                        Ok(GpuError::Surface(s)) => anyhow!("the window surface was lost ({s}); the mirror closed"),
                        Ok(other) => anyhow::Error::new(other),
                        Err(e) => e,
                    };
                    self.fail(event_loop, e);
                    return;
                }
                if self.opts.frames.is_some_and(|n| self.presented >= n) {
                    event_loop.exit();
                }
            }
            WindowEvent::MouseInput { state, button: MouseButton::Left, .. } => {
                self.drag = (state == ElementState::Pressed).then_some(self.cursor);
            }
            WindowEvent::CursorMoved { position, .. } => {
                self.cursor = (position.x, position.y);
                if let Some((x0, y0)) = self.drag {
                    self.orbit.drag((position.x - x0) as f32, (position.y - y0) as f32);
                    self.drag = Some(self.cursor);
                }
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let steps = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y,
                    MouseScrollDelta::PixelDelta(p) => (p.y / 40.0) as f32,
                };
                self.orbit.wheel(steps);
            }
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Pressed => {
                if event.logical_key == Key::Named(NamedKey::Escape) {
                    event_loop.exit();
                } else {
                    self.key(&event.logical_key);
                }
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, _event_loop: &ActiveEventLoop) {
        if let Some(w) = &self.window {
            w.request_redraw();
        }
    }

    fn exiting(&mut self, _event_loop: &ActiveEventLoop) {
        if let Some(gfx) = &self.gfx {
            let log = gfx.ctx.validation();
            self.stats.validation_messages = log.errors() + log.warnings();
            for m in log.messages() {
                tracing::warn!("validation: {m}");
            }
            self.stats.device = gfx.ctx.device_name().to_string();
        }
        // Drop the GPU objects before the window (the surface refers to it).
        self.gfx = None;
    }
}

/// The engines: the CPU reference pipeline or the Vulkan passes, both over one prepared input.
mod engines {
    use super::*;
    use crate::pipeline::warp::OcclusionFill;
    use crate::pipeline::{PreparedInput, ViewRenderer};

    /// Builds the engine for a prepared input.
    pub fn build<'a>(input: &'a PreparedInput, env: &'a Environment, backend: Backend) -> Box<dyn PersonEngine + 'a> {
        match backend {
            Backend::Cpu => Box::new(CpuEngine { view: ViewRenderer::new(input, OcclusionFill::default(), true), env }),
            Backend::Vulkan => Box::new(VulkanEngine { input, env }),
        }
    }

    /// The CPU reference renders; Vulkan only presents.
    struct CpuEngine<'a> {
        view: ViewRenderer<'a>,
        env: &'a Environment,
    }

    impl PersonEngine for CpuEngine<'_> {
        fn frame(
            &mut self,
            renderer: &mut Renderer,
            camera: &Camera,
            mode: Mode,
            _shading: Shading,
            target: PresentTarget,
            want_frame: bool,
        ) -> anyhow::Result<Option<Frame>> {
            let frame = self.view.render_frame(camera, mode, self.env)?;
            renderer.present_frame(&frame, target)?;
            Ok(want_frame.then_some(frame))
        }

        fn attach(&mut self, _renderer: &mut Renderer) -> anyhow::Result<()> {
            Ok(())
        }
    }

    /// Every per-view stage on the GPU; the input is uploaded once per renderer.
    struct VulkanEngine<'a> {
        input: &'a PreparedInput,
        env: &'a Environment,
    }

    impl PersonEngine for VulkanEngine<'_> {
        fn frame(
            &mut self,
            renderer: &mut Renderer,
            camera: &Camera,
            mode: Mode,
            _shading: Shading,
            target: PresentTarget,
            want_frame: bool,
        ) -> anyhow::Result<Option<Frame>> {
            renderer.render_frame(camera, mode, Some(target))?;
            Ok(want_frame.then(|| renderer.read_output(mode)))
        }

        fn attach(&mut self, renderer: &mut Renderer) -> anyhow::Result<()> {
            let input = self.input;
            renderer.set_mesh(&input.mesh)?;
            renderer.set_source_parts(
                &input.normalised.rgb,
                &input.normalised.mask,
                &input.source_gbuffer,
                &input.source_camera,
            )?;
            renderer.set_environment(self.env)?;
            renderer.set_fill(OcclusionFill::default());
            renderer.set_fusion(true);
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orbit_drag_and_wheel_stay_bounded() {
        let mut o = Orbit::default();
        o.drag(100.0, 0.0);
        assert!((o.yaw - (360.0 - 40.0)).abs() < 1e-4);
        o.drag(0.0, 1e6);
        assert_eq!(o.pitch, 89.0);
        o.drag(f32::NAN, 3.0);
        assert_eq!(o.pitch, 89.0);
        for _ in 0..100 {
            o.wheel(1.0);
        }
        assert_eq!(o.zoom, 4.0);
        o.wheel(-1000.0);
        assert_eq!(o.zoom, 0.5);
        let cam = o.camera(64, 32);
        assert_eq!((cam.width, cam.height), (64, 32));
        assert!(cam.view_from_world.is_finite());
    }
}
