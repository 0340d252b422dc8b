//! Desktop mirror: both eye images side by side in a window while the session runs.
//!
//! The window (winit) is driven from the display loop with non-blocking event pumping, and presented through a
//! [`Swapchain`] ([`SwapchainOptions::MIRROR`]) on the device the OpenXR runtime chose: the eyes' float images
//! (`crate::xr::swapchain::EyeSwapchain`) are blitted side by side into the window's image on the GPU.
//! Presentation never blocks the display loop: the present mode is IMMEDIATE or MAILBOX when offered, and an image
//! that cannot be acquired at once is skipped. Closing the window only closes the mirror, not the session. `E` in the
//! window asks the session to export the person ([`Mirror::take_export_key`]).

use std::ffi::c_char;
use std::sync::Arc;
use std::time::{Duration, Instant};

use ash::vk;
use raw_window_handle::{HasDisplayHandle, HasWindowHandle};
use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::WindowEvent;
use winit::event_loop::{ActiveEventLoop, EventLoop};
use winit::keyboard::Key;
use winit::platform::pump_events::EventLoopExtPumpEvents;
use winit::window::{Window, WindowId};

use crate::gpu::present::{self, Acquired, Swapchain, SwapchainOptions};
use crate::gpu::resources::Image2d;
use crate::gpu::{CommandSlot, Context, GpuError};

#[derive(Default)]
struct MirrorApp {
    size: PhysicalSize<u32>,
    window: Option<Window>,
    closed: bool,
    resized: bool,
    error: Option<String>,
    /// `E` was pressed since the last [`Mirror::take_export_key`].
    export_key: bool,
}

impl ApplicationHandler for MirrorApp {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.window.is_none() && self.error.is_none() {
            let attrs = Window::default_attributes().with_title("r2human XR mirror").with_inner_size(self.size);
            match event_loop.create_window(attrs) {
                Ok(w) => self.window = Some(w),
                Err(e) => self.error = Some(e.to_string()),
            }
        }
    }

    fn window_event(&mut self, _event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => self.closed = true,
            WindowEvent::Resized(_) => self.resized = true,
            WindowEvent::KeyboardInput { event, .. } if event.state.is_pressed() && !event.repeat => {
                if let Key::Character(c) = &event.logical_key {
                    self.export_key |= c.as_str().eq_ignore_ascii_case("e");
                }
            }
            _ => {}
        }
    }
}

/// The mirror's event loop, created before the Vulkan instance (which needs its surface extensions).
pub struct MirrorEventLoop {
    event_loop: EventLoop<()>,
    app: MirrorApp,
}

impl MirrorEventLoop {
    /// Opens the display connection for a `width x height` mirror window. Fails (with the reason) when there is
    /// no display.
    pub fn new(width: u32, height: u32) -> Result<Self, GpuError> {
        let mut builder = EventLoop::builder();
        // The display loop is not necessarily the process's main thread.
        #[cfg(target_os = "linux")]
        {
            use winit::platform::wayland::EventLoopBuilderExtWayland;
            use winit::platform::x11::EventLoopBuilderExtX11;
            EventLoopBuilderExtX11::with_any_thread(&mut builder, true);
            EventLoopBuilderExtWayland::with_any_thread(&mut builder, true);
        }
        // winit panics (instead of failing) when libxkbcommon-x11 is missing: turn that into an error too.
        let built = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| builder.build()));
        let event_loop = match built {
            Ok(Ok(l)) => l,
            Ok(Err(e)) => return Err(GpuError::Surface(format!("no display for the mirror window: {e}"))),
            Err(_) => {
                return Err(GpuError::Surface(
                    "the windowing library failed to start (is libxkbcommon-x11-0 installed?)".into(),
                ));
            }
        };
        Ok(Self { event_loop, app: MirrorApp { size: PhysicalSize::new(width, height), ..Default::default() } })
    }

    /// The Vulkan instance extensions a surface on this display needs.
    pub fn required_instance_extensions(&self) -> Result<Vec<*const c_char>, GpuError> {
        let display = self.event_loop.display_handle().map_err(|e| GpuError::Surface(e.to_string()))?;
        ash_window::enumerate_required_extensions(display.as_raw())
            .map(|e| e.to_vec())
            .map_err(|e| GpuError::Surface(format!("no Vulkan surface support for this display: {e}")))
    }

    fn pump(&mut self) {
        let _ = self.event_loop.pump_app_events(Some(Duration::ZERO), &mut self.app);
    }
}

/// The mirror window and its swapchain.
pub struct Mirror {
    // Declared before `lp`: the swapchain's surface goes before the window.
    swapchain: Swapchain,
    commands: CommandSlot,
    lp: MirrorEventLoop,
    /// Images presented so far.
    pub presented: u64,
}

/// Device extensions the mirror needs.
pub const DEVICE_EXTENSIONS: [&std::ffi::CStr; 1] = [ash::khr::swapchain::NAME];

impl Mirror {
    /// Opens the window (sized by the event loop) and its swapchain on `ctx`, which must have been created with the
    /// loop's instance extensions and [`DEVICE_EXTENSIONS`]; it presents on queue 0 (the OpenXR session's).
    pub fn new(mut lp: MirrorEventLoop, ctx: &Arc<Context>) -> Result<Self, GpuError> {
        let deadline = Instant::now() + Duration::from_secs(5);
        while lp.app.window.is_none() {
            lp.pump();
            if let Some(e) = &lp.app.error {
                return Err(GpuError::Surface(format!("cannot open the mirror window: {e}")));
            }
            if Instant::now() > deadline {
                return Err(GpuError::Surface("the mirror window did not open within 5 s".into()));
            }
        }
        let swapchain = {
            let window = lp.app.window.as_ref().ok_or_else(|| GpuError::Surface("no mirror window".into()))?;
            let display = window.display_handle().map_err(|e| GpuError::Surface(e.to_string()))?;
            let handle = window.window_handle().map_err(|e| GpuError::Surface(e.to_string()))?;
            let size = window.inner_size();
            Swapchain::for_window(
                ctx,
                display.as_raw(),
                handle.as_raw(),
                SwapchainOptions::MIRROR,
                size.width.max(1),
                size.height.max(1),
            )?
        };
        lp.app.resized = false;
        Ok(Self { swapchain, commands: CommandSlot::new(ctx)?, lp, presented: 0 })
    }

    /// Handles window events; `false` once the user closed the window.
    pub fn pump(&mut self) -> bool {
        self.lp.pump();
        !self.lp.app.closed
    }

    /// Whether `E` (export the person) was pressed in the window since the last call.
    pub fn take_export_key(&mut self) -> bool {
        std::mem::take(&mut self.lp.app.export_key)
    }

    fn recreate(&mut self) -> Result<(), GpuError> {
        let size = self.lp.app.window.as_ref().map(|w| w.inner_size()).unwrap_or(PhysicalSize::new(1, 1));
        // Minimised (`false`): keep the old swapchain (or none) until the window has a size again.
        self.swapchain.recreate(size.width, size.height)?;
        self.lp.app.resized = false;
        Ok(())
    }

    /// Shows the eye images side by side (each scaled to its part of the window). `eyes` are the float images of
    /// the eyes, in TRANSFER_SRC_OPTIMAL and written by earlier submissions on queue 0. Skips the frame instead of
    /// waiting when no window image is free.
    pub fn present(&mut self, eyes: &[&Image2d]) -> Result<(), GpuError> {
        if self.lp.app.closed || eyes.is_empty() {
            return Ok(());
        }
        if self.lp.app.resized || !self.swapchain.is_ready() {
            self.recreate()?;
            if !self.swapchain.is_ready() {
                return Ok(());
            }
        }
        // The previous present's commands must be done before the buffer is re-recorded; it has had a whole
        // display frame to run.
        self.commands.wait()?;
        let (index, image, ready, rendered) = match self.swapchain.acquire(0)? {
            Acquired::Image { index, image, ready, rendered, suboptimal } => {
                self.lp.app.resized |= suboptimal;
                (index, image, ready, rendered)
            }
            Acquired::NotReady => return Ok(()),
            Acquired::OutOfDate => {
                self.lp.app.resized = true;
                return Ok(());
            }
        };
        let layers = vk::ImageSubresourceLayers {
            aspect_mask: vk::ImageAspectFlags::COLOR,
            mip_level: 0,
            base_array_layer: 0,
            layer_count: 1,
        };
        let n = eyes.len() as u32;
        let extent = self.swapchain.extent;
        let (ww, wh) = (extent.width, extent.height);
        let blits: Vec<(vk::Image, vk::ImageBlit)> = eyes
            .iter()
            .enumerate()
            .map(|(i, e)| {
                let i = i as u32;
                let src = vk::Offset3D { x: e.extent.width as i32, y: e.extent.height as i32, z: 1 };
                let blit = vk::ImageBlit {
                    src_subresource: layers,
                    src_offsets: [vk::Offset3D::default(), src],
                    dst_subresource: layers,
                    dst_offsets: [
                        vk::Offset3D { x: (ww * i / n) as i32, y: 0, z: 0 },
                        vk::Offset3D { x: (ww * (i + 1) / n) as i32, y: wh as i32, z: 1 },
                    ],
                };
                (e.image, blit)
            })
            .collect();
        // The eye images were written by the upload's copy (an earlier submission on this queue).
        let eyes_written = vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
            .dst_access_mask(vk::AccessFlags::TRANSFER_READ);
        let cmd = self.commands.begin()?;
        let ctx = Arc::clone(self.swapchain.context());
        let device = ctx.device();
        // SAFETY: `cmd` is recording (`begin`); the image was acquired (its semaphore is waited on by the
        // submission); the eye images are valid and in TRANSFER_SRC_OPTIMAL.
        unsafe {
            device.cmd_pipeline_barrier(
                cmd,
                vk::PipelineStageFlags::TRANSFER,
                vk::PipelineStageFlags::TRANSFER,
                vk::DependencyFlags::empty(),
                &[eyes_written],
                &[],
                &[present::to_transfer_dst(image)],
            );
            let black = vk::ClearColorValue { float32: [0.0, 0.0, 0.0, 1.0] };
            let range = crate::gpu::resources::subresource(vk::ImageAspectFlags::COLOR);
            device.cmd_clear_color_image(cmd, image, vk::ImageLayout::TRANSFER_DST_OPTIMAL, &black, &[range]);
            let after_clear = vk::MemoryBarrier::default()
                .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
                .dst_access_mask(vk::AccessFlags::TRANSFER_WRITE);
            device.cmd_pipeline_barrier(
                cmd,
                vk::PipelineStageFlags::TRANSFER,
                vk::PipelineStageFlags::TRANSFER,
                vk::DependencyFlags::empty(),
                &[after_clear],
                &[],
                &[],
            );
            for (src, blit) in &blits {
                device.cmd_blit_image(
                    cmd,
                    *src,
                    vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                    image,
                    vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                    std::slice::from_ref(blit),
                    vk::Filter::NEAREST,
                );
            }
            present::record_to_present(device, cmd, image);
        }
        let mut waited = Duration::ZERO;
        self.commands.submit(
            SwapchainOptions::MIRROR.queue,
            Some((ready, vk::PipelineStageFlags::TRANSFER)),
            Some(rendered),
            &mut waited,
        )?;
        if self.swapchain.present(index)? {
            self.lp.app.resized = true;
        }
        self.presented += 1;
        Ok(())
    }

    /// Waits for the mirror's GPU work and destroys its Vulkan objects and the window.
    pub fn destroy(self) {
        let Self { swapchain, commands, mut lp, .. } = self;
        drop(commands);
        drop(swapchain);
        lp.app.window = None;
        lp.pump();
    }
}
