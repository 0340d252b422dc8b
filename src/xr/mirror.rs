//! Desktop mirror: both eye images side by side in a window while the session runs.
//!
//! The window (winit) is driven from the display loop with non-blocking event pumping, and presented through a
//! Vulkan surface on the device the OpenXR runtime chose: the eyes' float images (see [`super::gfx::EyeSwapchain`])
//! are blitted side by side into the window's image on the GPU. Presentation never blocks the display loop: the
//! present mode is IMMEDIATE or MAILBOX when offered, and an image that cannot be acquired at once is skipped.
//! Closing the window only closes the mirror, not the session.

use std::ffi::c_char;
use std::time::{Duration, Instant};

use ash::vk;
use raw_window_handle::{HasDisplayHandle, HasWindowHandle};
use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::WindowEvent;
use winit::event_loop::{ActiveEventLoop, EventLoop};
use winit::platform::pump_events::EventLoopExtPumpEvents;
use winit::window::{Window, WindowId};

use super::gfx::VulkanContext;
use super::{VkContext, XrError};
use crate::gpu::resources::{subresource, Image2d};

#[derive(Default)]
struct MirrorApp {
    size: PhysicalSize<u32>,
    window: Option<Window>,
    closed: bool,
    resized: bool,
    error: Option<String>,
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
    pub fn new(width: u32, height: u32) -> Result<Self, String> {
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
            Ok(Err(e)) => return Err(format!("no display for the mirror window: {e}")),
            Err(_) => {
                return Err("the windowing library failed to start (is libxkbcommon-x11-0 installed?)".into());
            }
        };
        Ok(Self { event_loop, app: MirrorApp { size: PhysicalSize::new(width, height), ..Default::default() } })
    }

    /// The Vulkan instance extensions a surface on this display needs.
    pub fn required_instance_extensions(&self) -> Result<Vec<*const c_char>, String> {
        let display = self.event_loop.display_handle().map_err(|e| e.to_string())?;
        ash_window::enumerate_required_extensions(display.as_raw())
            .map(|e| e.to_vec())
            .map_err(|e| format!("no Vulkan surface support for this display: {e}"))
    }

    fn pump(&mut self) {
        let _ = self.event_loop.pump_app_events(Some(Duration::ZERO), &mut self.app);
    }
}

/// The mirror window and its Vulkan swapchain.
pub struct Mirror {
    lp: MirrorEventLoop,
    surface_fn: ash::khr::surface::Instance,
    swapchain_fn: ash::khr::swapchain::Device,
    surface: vk::SurfaceKHR,
    swapchain: vk::SwapchainKHR,
    images: Vec<vk::Image>,
    format: vk::SurfaceFormatKHR,
    extent: vk::Extent2D,
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
    acquired: vk::Semaphore,
    rendered: Vec<vk::Semaphore>,
    /// Images presented so far.
    pub presented: u64,
}

/// Device extensions the mirror needs.
pub const DEVICE_EXTENSIONS: [&std::ffi::CStr; 1] = [ash::khr::swapchain::NAME];

impl Mirror {
    /// Opens the window (sized by the event loop) and its swapchain on `ctx`, which must have been created with the
    /// loop's instance extensions and [`DEVICE_EXTENSIONS`].
    pub fn new(mut lp: MirrorEventLoop, ctx: &VulkanContext) -> Result<Self, XrError> {
        let deadline = Instant::now() + Duration::from_secs(5);
        while lp.app.window.is_none() {
            lp.pump();
            if let Some(e) = &lp.app.error {
                return Err(XrError::Unsupported(format!("cannot open the mirror window: {e}")));
            }
            if Instant::now() > deadline {
                return Err(XrError::Unsupported("the mirror window did not open within 5 s".into()));
            }
        }
        let surface = {
            let window = lp.app.window.as_ref().ok_or_else(|| XrError::Unsupported("no mirror window".into()))?;
            let display = window.display_handle().map_err(|e| XrError::Unsupported(e.to_string()))?;
            let handle = window.window_handle().map_err(|e| XrError::Unsupported(e.to_string()))?;
            // SAFETY: the window outlives the surface (both owned by `Mirror`, the surface destroyed first).
            unsafe { ash_window::create_surface(&ctx.entry, &ctx.instance, display.as_raw(), handle.as_raw(), None) }
                .vk("vkCreate*SurfaceKHR")?
        };
        let surface_fn = ash::khr::surface::Instance::new(&ctx.entry, &ctx.instance);
        // SAFETY: valid physical device, family and surface.
        let supported = unsafe {
            surface_fn.get_physical_device_surface_support(ctx.physical_device, ctx.queue_family_index, surface)
        }
        .unwrap_or(false);
        if !supported {
            // SAFETY: nothing uses the surface yet.
            unsafe { surface_fn.destroy_surface(surface, None) };
            return Err(XrError::Unsupported("the OpenXR device's queue cannot present to the mirror window".into()));
        }
        let swapchain_fn = ash::khr::swapchain::Device::new(&ctx.instance, &ctx.device);
        let alloc = vk::CommandBufferAllocateInfo::default()
            .command_pool(ctx.command_pool)
            .level(vk::CommandBufferLevel::PRIMARY)
            .command_buffer_count(1);
        // SAFETY: valid device and pool; all objects are destroyed in `destroy`.
        let (cmd, fence, acquired) = unsafe {
            (
                ctx.device.allocate_command_buffers(&alloc).vk("vkAllocateCommandBuffers")?[0],
                ctx.device
                    .create_fence(&vk::FenceCreateInfo::default().flags(vk::FenceCreateFlags::SIGNALED), None)
                    .vk("vkCreateFence")?,
                ctx.device.create_semaphore(&vk::SemaphoreCreateInfo::default(), None).vk("vkCreateSemaphore")?,
            )
        };
        let mut mirror = Self {
            lp,
            surface_fn,
            swapchain_fn,
            surface,
            swapchain: vk::SwapchainKHR::null(),
            images: Vec::new(),
            format: vk::SurfaceFormatKHR::default(),
            extent: vk::Extent2D::default(),
            cmd,
            fence,
            acquired,
            rendered: Vec::new(),
            presented: 0,
        };
        mirror.recreate_swapchain(ctx)?;
        Ok(mirror)
    }

    /// Handles window events; `false` once the user closed the window.
    pub fn pump(&mut self) -> bool {
        self.lp.pump();
        !self.lp.app.closed
    }

    fn recreate_swapchain(&mut self, ctx: &VulkanContext) -> Result<(), XrError> {
        // SAFETY: the surface is valid; waiting for our fence makes the old swapchain's images unused by us.
        unsafe {
            ctx.device.wait_for_fences(&[self.fence], true, u64::MAX).vk("vkWaitForFences")?;
            let caps = self
                .surface_fn
                .get_physical_device_surface_capabilities(ctx.physical_device, self.surface)
                .vk("vkGetPhysicalDeviceSurfaceCapabilitiesKHR")?;
            let formats = self
                .surface_fn
                .get_physical_device_surface_formats(ctx.physical_device, self.surface)
                .vk("vkGetPhysicalDeviceSurfaceFormatsKHR")?;
            let modes = self
                .surface_fn
                .get_physical_device_surface_present_modes(ctx.physical_device, self.surface)
                .vk("vkGetPhysicalDeviceSurfacePresentModesKHR")?;
            let wanted = [
                vk::Format::B8G8R8A8_SRGB,
                vk::Format::R8G8B8A8_SRGB,
                vk::Format::B8G8R8A8_UNORM,
                vk::Format::R8G8B8A8_UNORM,
            ];
            let format = wanted
                .iter()
                .filter(|w| ctx.format_supports(**w, vk::FormatFeatureFlags::BLIT_DST))
                .find_map(|w| formats.iter().find(|f| f.format == *w).copied())
                .ok_or_else(|| {
                    XrError::Unsupported("the mirror window offers no 8-bit RGBA format to blit to".into())
                })?;
            let mode = [vk::PresentModeKHR::IMMEDIATE, vk::PresentModeKHR::MAILBOX]
                .into_iter()
                .find(|m| modes.contains(m))
                .unwrap_or(vk::PresentModeKHR::FIFO);
            let size = self.lp.app.window.as_ref().map(|w| w.inner_size()).unwrap_or(PhysicalSize::new(1, 1));
            let extent = if caps.current_extent.width != u32::MAX {
                caps.current_extent
            } else {
                vk::Extent2D {
                    width: size.width.clamp(caps.min_image_extent.width, caps.max_image_extent.width.max(1)),
                    height: size.height.clamp(caps.min_image_extent.height, caps.max_image_extent.height.max(1)),
                }
            };
            if extent.width == 0 || extent.height == 0 {
                return Ok(()); // minimised: keep the old swapchain (or none) until it has a size again
            }
            let mut count = caps.min_image_count + 1;
            if caps.max_image_count > 0 {
                count = count.min(caps.max_image_count);
            }
            let old = self.swapchain;
            let info = vk::SwapchainCreateInfoKHR::default()
                .surface(self.surface)
                .min_image_count(count)
                .image_format(format.format)
                .image_color_space(format.color_space)
                .image_extent(extent)
                .image_array_layers(1)
                .image_usage(vk::ImageUsageFlags::TRANSFER_DST)
                .image_sharing_mode(vk::SharingMode::EXCLUSIVE)
                .pre_transform(caps.current_transform)
                .composite_alpha(vk::CompositeAlphaFlagsKHR::OPAQUE)
                .present_mode(mode)
                .clipped(true)
                .old_swapchain(old);
            let swapchain = self.swapchain_fn.create_swapchain(&info, None).vk("vkCreateSwapchainKHR")?;
            if old != vk::SwapchainKHR::null() {
                let _q = ctx.lock_queue();
                let _ = ctx.device.queue_wait_idle(ctx.queue);
                self.swapchain_fn.destroy_swapchain(old, None);
            }
            for s in self.rendered.drain(..) {
                ctx.device.destroy_semaphore(s, None);
            }
            self.swapchain = swapchain;
            self.images = self.swapchain_fn.get_swapchain_images(swapchain).vk("vkGetSwapchainImagesKHR")?;
            for _ in 0..self.images.len() {
                let s =
                    ctx.device.create_semaphore(&vk::SemaphoreCreateInfo::default(), None).vk("vkCreateSemaphore")?;
                self.rendered.push(s);
            }
            self.format = format;
            self.extent = extent;
        }
        self.lp.app.resized = false;
        Ok(())
    }

    /// Shows the eye images side by side (each scaled to its half of the window). `eyes` are the float images of
    /// the eyes, in TRANSFER_SRC_OPTIMAL and written by earlier submissions on the session queue. Skips the frame
    /// instead of waiting when no window image is free.
    pub fn present(&mut self, ctx: &VulkanContext, eyes: &[&Image2d]) -> Result<(), XrError> {
        if self.lp.app.closed || eyes.is_empty() {
            return Ok(());
        }
        if self.lp.app.resized || self.swapchain == vk::SwapchainKHR::null() {
            self.recreate_swapchain(ctx)?;
            if self.swapchain == vk::SwapchainKHR::null() {
                return Ok(());
            }
        }
        // SAFETY: our own fence; the previous present's commands must be done before the buffer is re-recorded.
        // It has had a whole display frame to run.
        unsafe { ctx.device.wait_for_fences(&[self.fence], true, u64::MAX).vk("vkWaitForFences")? };
        // SAFETY: swapchain valid; timeout 0 never blocks.
        let acquire =
            unsafe { self.swapchain_fn.acquire_next_image(self.swapchain, 0, self.acquired, vk::Fence::null()) };
        let index = match acquire {
            Ok((i, suboptimal)) => {
                self.lp.app.resized |= suboptimal;
                i as usize
            }
            Err(vk::Result::NOT_READY) | Err(vk::Result::TIMEOUT) => return Ok(()),
            Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => {
                self.lp.app.resized = true;
                return Ok(());
            }
            Err(e) => return Err(XrError::Vulkan { call: "vkAcquireNextImageKHR", result: e }),
        };
        let image = self.images[index];
        let range = subresource(vk::ImageAspectFlags::COLOR);
        let layers = vk::ImageSubresourceLayers {
            aspect_mask: vk::ImageAspectFlags::COLOR,
            mip_level: 0,
            base_array_layer: 0,
            layer_count: 1,
        };
        let n = eyes.len() as u32;
        let (ww, wh) = (self.extent.width, self.extent.height);
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
        let to_dst = vk::ImageMemoryBarrier::default()
            .old_layout(vk::ImageLayout::UNDEFINED)
            .new_layout(vk::ImageLayout::TRANSFER_DST_OPTIMAL)
            .src_access_mask(vk::AccessFlags::empty())
            .dst_access_mask(vk::AccessFlags::TRANSFER_WRITE)
            .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .image(image)
            .subresource_range(range);
        let to_present = vk::ImageMemoryBarrier::default()
            .old_layout(vk::ImageLayout::TRANSFER_DST_OPTIMAL)
            .new_layout(vk::ImageLayout::PRESENT_SRC_KHR)
            .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
            .dst_access_mask(vk::AccessFlags::empty())
            .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .image(image)
            .subresource_range(range);
        // The eye images were written by the upload's copy (an earlier submission on this queue).
        let eyes_written = vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
            .dst_access_mask(vk::AccessFlags::TRANSFER_READ);
        let device = &ctx.device;
        // SAFETY: the command buffer is idle (fence waited); the image was acquired (its semaphore is waited on).
        unsafe {
            device.reset_fences(&[self.fence]).vk("vkResetFences")?;
            device.reset_command_buffer(self.cmd, vk::CommandBufferResetFlags::empty()).vk("vkResetCommandBuffer")?;
            let begin = vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
            device.begin_command_buffer(self.cmd, &begin).vk("vkBeginCommandBuffer")?;
            device.cmd_pipeline_barrier(
                self.cmd,
                vk::PipelineStageFlags::TRANSFER,
                vk::PipelineStageFlags::TRANSFER,
                vk::DependencyFlags::empty(),
                &[eyes_written],
                &[],
                &[to_dst],
            );
            let black = vk::ClearColorValue { float32: [0.0, 0.0, 0.0, 1.0] };
            device.cmd_clear_color_image(self.cmd, image, vk::ImageLayout::TRANSFER_DST_OPTIMAL, &black, &[range]);
            let after_clear = vk::MemoryBarrier::default()
                .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
                .dst_access_mask(vk::AccessFlags::TRANSFER_WRITE);
            device.cmd_pipeline_barrier(
                self.cmd,
                vk::PipelineStageFlags::TRANSFER,
                vk::PipelineStageFlags::TRANSFER,
                vk::DependencyFlags::empty(),
                &[after_clear],
                &[],
                &[],
            );
            for (src, blit) in &blits {
                device.cmd_blit_image(
                    self.cmd,
                    *src,
                    vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                    image,
                    vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                    std::slice::from_ref(blit),
                    vk::Filter::NEAREST,
                );
            }
            device.cmd_pipeline_barrier(
                self.cmd,
                vk::PipelineStageFlags::TRANSFER,
                vk::PipelineStageFlags::BOTTOM_OF_PIPE,
                vk::DependencyFlags::empty(),
                &[],
                &[],
                &[to_present],
            );
            device.end_command_buffer(self.cmd).vk("vkEndCommandBuffer")?;
            let waits = [self.acquired];
            let stages = [vk::PipelineStageFlags::TRANSFER];
            let signals = [self.rendered[index]];
            let cmds = [self.cmd];
            let submit = vk::SubmitInfo::default()
                .wait_semaphores(&waits)
                .wait_dst_stage_mask(&stages)
                .command_buffers(&cmds)
                .signal_semaphores(&signals);
            let _q = ctx.lock_queue();
            device.queue_submit(ctx.queue, &[submit], self.fence).vk("vkQueueSubmit")?;
            let swapchains = [self.swapchain];
            let indices = [index as u32];
            let present =
                vk::PresentInfoKHR::default().wait_semaphores(&signals).swapchains(&swapchains).image_indices(&indices);
            match self.swapchain_fn.queue_present(ctx.queue, &present) {
                Ok(suboptimal) => self.lp.app.resized |= suboptimal,
                Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => self.lp.app.resized = true,
                Err(e) => return Err(XrError::Vulkan { call: "vkQueuePresentKHR", result: e }),
            }
        }
        self.presented += 1;
        Ok(())
    }

    /// Waits for the mirror's GPU work and destroys its Vulkan objects and the window.
    pub fn destroy(mut self, ctx: &VulkanContext) {
        // SAFETY: after the queue is idle nothing uses these objects.
        unsafe {
            {
                let _q = ctx.lock_queue();
                let _ = ctx.device.queue_wait_idle(ctx.queue);
            }
            let _ = ctx.device.wait_for_fences(&[self.fence], true, u64::MAX);
            for s in self.rendered.drain(..) {
                ctx.device.destroy_semaphore(s, None);
            }
            ctx.device.destroy_semaphore(self.acquired, None);
            ctx.device.destroy_fence(self.fence, None);
            ctx.device.free_command_buffers(ctx.command_pool, &[self.cmd]);
            if self.swapchain != vk::SwapchainKHR::null() {
                self.swapchain_fn.destroy_swapchain(self.swapchain, None);
            }
            self.surface_fn.destroy_surface(self.surface, None);
        }
        self.lp.app.window = None;
        self.lp.pump();
    }
}
