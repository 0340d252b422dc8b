//! Presentation to a window: a Vulkan swapchain on a window surface, serving both the `view` window (the
//! renderer copies its encoded output into the image: [`crate::gpu::Renderer`] with a [`super::PresentTarget`])
//! and the XR desktop mirror (the eye images are blitted into it: `crate::window::mirror`), and the two layout
//! transitions every present needs ([`to_transfer_dst`], [`to_present`]).
//!
//! The images are written by transfers only (`TRANSFER_DST` usage). Out-of-date and suboptimal swapchains
//! (resize, minimise) are reported to the caller, which recreates; a lost surface or device is an error the
//! caller turns into a clean exit.

use std::sync::Arc;

use ash::vk;
use raw_window_handle::{RawDisplayHandle, RawWindowHandle};

use super::resources::{color_barrier, record_image_barrier};
use super::{Context, GpuError};

/// How a swapchain is made and presented.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SwapchainOptions {
    /// Acceptable image formats, most preferred first.
    pub formats: &'static [vk::Format],
    /// Format features the device must offer for a format to be chosen (e.g. `BLIT_DST`).
    pub format_features: vk::FormatFeatureFlags,
    /// Present modes in order of preference; FIFO (always offered) when none is.
    pub present_modes: &'static [vk::PresentModeKHR],
    /// The context's queue that presents (see [`Context::queue_at`]).
    pub queue: usize,
}

impl SwapchainOptions {
    /// The `view` window: 8-bit UNORM images (the renderer encodes sRGB itself), FIFO, the renderer's queue.
    pub const WINDOW: Self = Self {
        formats: &[vk::Format::B8G8R8A8_UNORM, vk::Format::R8G8B8A8_UNORM],
        format_features: vk::FormatFeatureFlags::empty(),
        present_modes: &[vk::PresentModeKHR::FIFO],
        queue: Context::RENDER_QUEUE,
    };

    /// The XR desktop mirror: sRGB first (the blit from the linear float eye images encodes it), blittable,
    /// never blocking the display loop (IMMEDIATE or MAILBOX when offered), on the OpenXR session's queue 0.
    pub const MIRROR: Self = Self {
        formats: &[
            vk::Format::B8G8R8A8_SRGB,
            vk::Format::R8G8B8A8_SRGB,
            vk::Format::B8G8R8A8_UNORM,
            vk::Format::R8G8B8A8_UNORM,
        ],
        format_features: vk::FormatFeatureFlags::BLIT_DST,
        present_modes: &[vk::PresentModeKHR::IMMEDIATE, vk::PresentModeKHR::MAILBOX],
        queue: 0,
    };
}

/// Result of acquiring a swapchain image.
#[derive(Clone, Copy, Debug)]
pub enum Acquired {
    /// Render into this image, then present it.
    Image {
        /// Swapchain image index.
        index: u32,
        /// The image.
        image: vk::Image,
        /// Signalled when the image may be written.
        ready: vk::Semaphore,
        /// To be signalled when rendering is done; present waits on it.
        rendered: vk::Semaphore,
        /// The swapchain still works but no longer matches the surface exactly: recreate it soon.
        suboptimal: bool,
    },
    /// No image was free within the timeout: skip this frame.
    NotReady,
    /// The swapchain no longer matches the surface: recreate it.
    OutOfDate,
}

/// A swapchain on a window surface and its synchronisation objects.
pub struct Swapchain {
    ctx: Arc<Context>,
    options: SwapchainOptions,
    surface_loader: ash::khr::surface::Instance,
    loader: ash::khr::swapchain::Device,
    surface: vk::SurfaceKHR,
    swapchain: vk::SwapchainKHR,
    images: Vec<vk::Image>,
    /// Pixel format of the images (one of [`SwapchainOptions::formats`]).
    pub format: vk::Format,
    /// Size of the images.
    pub extent: vk::Extent2D,
    acquire_semaphore: vk::Semaphore,
    render_semaphores: Vec<vk::Semaphore>,
}

impl std::fmt::Debug for Swapchain {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Swapchain").field("format", &self.format).field("extent", &self.extent).finish()
    }
}

impl Swapchain {
    /// Creates a [`SwapchainOptions::WINDOW`] swapchain for `surface` (created with the context by
    /// [`Context::with_surface`]) of about `width x height` pixels (the surface's current extent wins when it
    /// dictates one). Takes ownership of the surface.
    pub fn new(ctx: &Arc<Context>, surface: vk::SurfaceKHR, width: u32, height: u32) -> Result<Self, GpuError> {
        Self::with_options(ctx, surface, SwapchainOptions::WINDOW, width, height)
    }

    /// Creates a surface for a window on `ctx` (whose instance has the display's surface extensions and whose
    /// device has `VK_KHR_swapchain`) and a swapchain on it. The window must outlive the swapchain.
    pub fn for_window(
        ctx: &Arc<Context>,
        display: RawDisplayHandle,
        window: RawWindowHandle,
        options: SwapchainOptions,
        width: u32,
        height: u32,
    ) -> Result<Self, GpuError> {
        // SAFETY: the caller's window handles are valid and the window outlives the surface (destroyed on drop).
        let surface = unsafe { ash_window::create_surface(ctx.entry(), ctx.instance(), display, window, None) }
            .map_err(|e| GpuError::Surface(format!("cannot create a window surface ({e})")))?;
        let surface_loader = ash::khr::surface::Instance::new(ctx.entry(), ctx.instance());
        // SAFETY: valid physical device, queue family and surface.
        let supported = unsafe {
            surface_loader.get_physical_device_surface_support(ctx.physical_device(), ctx.queue_family(), surface)
        }
        .unwrap_or(false);
        if !supported {
            // SAFETY: nothing uses the surface yet.
            unsafe { surface_loader.destroy_surface(surface, None) };
            return Err(GpuError::Surface("the device's queue cannot present to this window".into()));
        }
        Self::with_options(ctx, surface, options, width, height)
    }

    /// Creates a swapchain made as `options` say for `surface` (taking ownership of it).
    pub fn with_options(
        ctx: &Arc<Context>,
        surface: vk::SurfaceKHR,
        options: SwapchainOptions,
        width: u32,
        height: u32,
    ) -> Result<Self, GpuError> {
        let surface_loader = ash::khr::surface::Instance::new(ctx.entry(), ctx.instance());
        let loader = ash::khr::swapchain::Device::new(ctx.instance(), ctx.device());
        // SAFETY: valid device.
        let acquire_semaphore =
            match unsafe { ctx.device().create_semaphore(&vk::SemaphoreCreateInfo::default(), None) } {
                Ok(s) => s,
                Err(e) => {
                    // SAFETY: nothing uses the surface yet.
                    unsafe { surface_loader.destroy_surface(surface, None) };
                    return Err(GpuError::vk("create a semaphore")(e));
                }
            };
        let mut sc = Self {
            ctx: ctx.clone(),
            options,
            surface_loader,
            loader,
            surface,
            swapchain: vk::SwapchainKHR::null(),
            images: Vec::new(),
            format: options.formats.first().copied().unwrap_or(vk::Format::B8G8R8A8_UNORM),
            extent: vk::Extent2D { width, height },
            acquire_semaphore,
            render_semaphores: Vec::new(),
        };
        sc.recreate(width, height)?;
        Ok(sc)
    }

    /// The context the swapchain presents with.
    pub fn context(&self) -> &Arc<Context> {
        &self.ctx
    }

    /// Does the image format store blue first (the renderer then packs BGRA)?
    pub fn is_bgra(&self) -> bool {
        matches!(self.format, vk::Format::B8G8R8A8_UNORM | vk::Format::B8G8R8A8_SRGB)
    }

    /// Is there a swapchain to present to (`false` until a surface with an area has been seen)?
    pub fn is_ready(&self) -> bool {
        self.swapchain != vk::SwapchainKHR::null()
    }

    /// (Re)creates the swapchain for the window's current size (`width x height` when the surface does not
    /// dictate its extent). Returns `false` when the surface has zero area (minimised): nothing can be presented
    /// until it is restored, and the old swapchain (if any) stays.
    pub fn recreate(&mut self, width: u32, height: u32) -> Result<bool, GpuError> {
        // The present queue idle: no submission still writes or presents an image of the old swapchain.
        self.ctx.wait_queue_idle(self.options.queue)?;
        let pd = self.ctx.physical_device();
        // SAFETY: valid physical device and surface.
        let caps = unsafe { self.surface_loader.get_physical_device_surface_capabilities(pd, self.surface) }
            .map_err(GpuError::vk("query the surface"))?;
        let extent = if caps.current_extent.width != u32::MAX {
            caps.current_extent
        } else {
            vk::Extent2D {
                width: width.clamp(caps.min_image_extent.width, caps.max_image_extent.width.max(1)),
                height: height.clamp(caps.min_image_extent.height, caps.max_image_extent.height.max(1)),
            }
        };
        if extent.width == 0 || extent.height == 0 {
            return Ok(false);
        }
        if !caps.supported_usage_flags.contains(vk::ImageUsageFlags::TRANSFER_DST) {
            return Err(GpuError::Surface("the window surface cannot be written by transfers".into()));
        }
        // SAFETY: as above.
        let formats = unsafe { self.surface_loader.get_physical_device_surface_formats(pd, self.surface) }
            .map_err(GpuError::vk("query surface formats"))?;
        // SAFETY: as above.
        let modes = unsafe { self.surface_loader.get_physical_device_surface_present_modes(pd, self.surface) }
            .map_err(GpuError::vk("query present modes"))?;
        let chosen = self
            .options
            .formats
            .iter()
            .filter(|&&f| self.ctx.format_supports(f, self.options.format_features))
            .find_map(|&f| formats.iter().find(|s| s.format == f).copied())
            .ok_or_else(|| {
                GpuError::Surface(format!("the window offers none of the formats {:?}", self.options.formats))
            })?;
        let mode =
            self.options.present_modes.iter().copied().find(|m| modes.contains(m)).unwrap_or(vk::PresentModeKHR::FIFO);
        let image_count = if caps.max_image_count == 0 {
            caps.min_image_count + 1
        } else {
            (caps.min_image_count + 1).min(caps.max_image_count)
        };
        let composite = if caps.supported_composite_alpha.contains(vk::CompositeAlphaFlagsKHR::OPAQUE) {
            vk::CompositeAlphaFlagsKHR::OPAQUE
        } else {
            vk::CompositeAlphaFlagsKHR::INHERIT
        };
        let old = self.swapchain;
        let info = vk::SwapchainCreateInfoKHR::default()
            .surface(self.surface)
            .min_image_count(image_count)
            .image_format(chosen.format)
            .image_color_space(chosen.color_space)
            .image_extent(extent)
            .image_array_layers(1)
            .image_usage(vk::ImageUsageFlags::TRANSFER_DST)
            .image_sharing_mode(vk::SharingMode::EXCLUSIVE)
            .pre_transform(caps.current_transform)
            .composite_alpha(composite)
            .present_mode(mode)
            .clipped(true)
            .old_swapchain(old);
        // SAFETY: valid create info; the old swapchain is retired by this call and unused (queue idle above).
        let swapchain =
            unsafe { self.loader.create_swapchain(&info, None) }.map_err(GpuError::vk("create the swapchain"))?;
        if old != vk::SwapchainKHR::null() {
            // SAFETY: retired and idle.
            unsafe { self.loader.destroy_swapchain(old, None) };
        }
        self.swapchain = swapchain;
        // SAFETY: valid swapchain.
        self.images =
            unsafe { self.loader.get_swapchain_images(swapchain) }.map_err(GpuError::vk("get the swapchain images"))?;
        self.format = chosen.format;
        self.extent = extent;
        // One "rendered" semaphore per image: a semaphore a pending present still waits on is never re-signalled.
        let device = self.ctx.device();
        for s in self.render_semaphores.drain(..) {
            // SAFETY: the queue is idle, so no present waits on it.
            unsafe { device.destroy_semaphore(s, None) };
        }
        for _ in 0..self.images.len() {
            // SAFETY: valid device.
            let s = unsafe { device.create_semaphore(&vk::SemaphoreCreateInfo::default(), None) }
                .map_err(GpuError::vk("create a semaphore"))?;
            self.render_semaphores.push(s);
        }
        Ok(true)
    }

    /// Acquires the next image, waiting at most `timeout_ns` for one to be free (`u64::MAX`: until one is; 0:
    /// never blocks, [`Acquired::NotReady`] when none is free).
    pub fn acquire(&mut self, timeout_ns: u64) -> Result<Acquired, GpuError> {
        // SAFETY: valid swapchain and semaphore (unsignalled: every acquire that signals it is waited on by the
        // submission that follows).
        let r = unsafe {
            self.loader.acquire_next_image(self.swapchain, timeout_ns, self.acquire_semaphore, vk::Fence::null())
        };
        match r {
            Ok((index, suboptimal)) => Ok(Acquired::Image {
                index,
                image: self.images[index as usize],
                ready: self.acquire_semaphore,
                rendered: self.render_semaphores[index as usize],
                suboptimal,
            }),
            Err(vk::Result::NOT_READY | vk::Result::TIMEOUT) => Ok(Acquired::NotReady),
            Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => Ok(Acquired::OutOfDate),
            Err(e) => Err(GpuError::vk("acquire a swapchain image")(e)),
        }
    }

    /// Presents image `index` after its `rendered` semaphore is signalled. Returns `true` when the swapchain
    /// should be recreated (out of date or suboptimal).
    pub fn present(&mut self, index: u32) -> Result<bool, GpuError> {
        let waits = [self.render_semaphores[index as usize]];
        let swapchains = [self.swapchain];
        let indices = [index];
        let info =
            vk::PresentInfoKHR::default().wait_semaphores(&waits).swapchains(&swapchains).image_indices(&indices);
        // The queue may be shared with another thread (see `Context::lock_queue_at`).
        let presented = {
            let _queue = self.ctx.lock_queue_at(self.options.queue);
            // SAFETY: the image was acquired and its rendering submitted (signalling `waits`); the queue is locked.
            unsafe { self.loader.queue_present(self.ctx.queue_at(self.options.queue), &info) }
        };
        match presented {
            Ok(suboptimal) => Ok(suboptimal),
            Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => Ok(true),
            Err(e) => Err(GpuError::vk("present")(e)),
        }
    }
}

impl Drop for Swapchain {
    fn drop(&mut self) {
        let _ = self.ctx.wait_queue_idle(self.options.queue);
        let device = self.ctx.device();
        // SAFETY: the present queue is idle; these objects belong to this swapchain.
        unsafe {
            for s in self.render_semaphores.drain(..) {
                device.destroy_semaphore(s, None);
            }
            device.destroy_semaphore(self.acquire_semaphore, None);
            if self.swapchain != vk::SwapchainKHR::null() {
                self.loader.destroy_swapchain(self.swapchain, None);
            }
            self.surface_loader.destroy_surface(self.surface, None);
        }
    }
}

/// The barrier that makes an acquired swapchain `image` a transfer destination (its old contents discarded).
pub fn to_transfer_dst(image: vk::Image) -> vk::ImageMemoryBarrier<'static> {
    color_barrier(
        image,
        (vk::ImageLayout::UNDEFINED, vk::ImageLayout::TRANSFER_DST_OPTIMAL),
        (vk::AccessFlags::empty(), vk::AccessFlags::TRANSFER_WRITE),
    )
}

/// The barrier that hands a swapchain `image` written by transfers to the presentation engine.
pub fn to_present(image: vk::Image) -> vk::ImageMemoryBarrier<'static> {
    color_barrier(
        image,
        (vk::ImageLayout::TRANSFER_DST_OPTIMAL, vk::ImageLayout::PRESENT_SRC_KHR),
        (vk::AccessFlags::TRANSFER_WRITE, vk::AccessFlags::empty()),
    )
}

/// Records the [`to_present`] barrier of `image` (after the transfers that wrote it) into `cb`.
///
/// # Safety
/// `cb` is recording and `image` is a valid swapchain image of `device` in `TRANSFER_DST_OPTIMAL`.
pub unsafe fn record_to_present(device: &ash::Device, cb: vk::CommandBuffer, image: vk::Image) {
    let stages = (vk::PipelineStageFlags::TRANSFER, vk::PipelineStageFlags::BOTTOM_OF_PIPE);
    // SAFETY: as the caller guarantees.
    unsafe { record_image_barrier(device, cb, stages, to_present(image)) };
}
