//! Desktop window presentation: a Vulkan swapchain on a winit window's surface (ash-window creates the surface).
//!
//! The renderer writes its output into swapchain images by a buffer-to-image copy, so the swapchain needs only
//! `TRANSFER_DST` usage and an 8-bit UNORM format (the renderer encodes sRGB itself). Out-of-date and suboptimal
//! swapchains (resize, minimise) are reported to the caller, which recreates; a lost surface or device is an
//! error the caller turns into a clean exit.

use std::sync::Arc;

use ash::vk;

use crate::gpu::{Context, GpuError};

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
    },
    /// The swapchain no longer matches the surface: recreate it.
    OutOfDate,
}

/// A swapchain and its synchronisation objects.
pub struct Swapchain {
    ctx: Arc<Context>,
    surface_loader: ash::khr::surface::Instance,
    loader: ash::khr::swapchain::Device,
    surface: vk::SurfaceKHR,
    swapchain: vk::SwapchainKHR,
    images: Vec<vk::Image>,
    /// Pixel format of the images (`B8G8R8A8_UNORM` or `R8G8B8A8_UNORM`).
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
    /// Creates a swapchain for `surface` (created with the context by [`Context::with_surface`]) of about
    /// `width x height` pixels (the surface's current extent wins when it dictates one). Takes ownership of the
    /// surface.
    pub fn new(ctx: &Arc<Context>, surface: vk::SurfaceKHR, width: u32, height: u32) -> Result<Self, GpuError> {
        let surface_loader = ash::khr::surface::Instance::new(ctx.entry(), ctx.instance());
        let loader = ash::khr::swapchain::Device::new(ctx.instance(), ctx.device());
        let sem = |ctx: &Context| unsafe { ctx.device().create_semaphore(&vk::SemaphoreCreateInfo::default(), None) };
        let acquire_semaphore = match sem(ctx) {
            Ok(s) => s,
            Err(e) => {
                unsafe { surface_loader.destroy_surface(surface, None) };
                return Err(GpuError::vk("create a semaphore")(e));
            }
        };
        let mut sc = Self {
            ctx: ctx.clone(),
            surface_loader,
            loader,
            surface,
            swapchain: vk::SwapchainKHR::null(),
            images: Vec::new(),
            format: vk::Format::B8G8R8A8_UNORM,
            extent: vk::Extent2D { width, height },
            acquire_semaphore,
            render_semaphores: Vec::new(),
        };
        sc.recreate(width, height)?;
        Ok(sc)
    }

    /// Does the image format store blue first (the renderer then packs BGRA)?
    pub fn is_bgra(&self) -> bool {
        matches!(self.format, vk::Format::B8G8R8A8_UNORM | vk::Format::B8G8R8A8_SRGB)
    }

    /// (Re)creates the swapchain for the window's current size. Returns `false` when the surface has zero area
    /// (minimised): nothing can be presented until it is restored.
    pub fn recreate(&mut self, width: u32, height: u32) -> Result<bool, GpuError> {
        self.ctx.wait_idle()?;
        let pd = self.ctx.physical_device();
        let caps = unsafe { self.surface_loader.get_physical_device_surface_capabilities(pd, self.surface) }
            .map_err(GpuError::vk("query the surface"))?;
        let extent = if caps.current_extent.width != u32::MAX {
            caps.current_extent
        } else {
            vk::Extent2D {
                width: width.clamp(caps.min_image_extent.width, caps.max_image_extent.width),
                height: height.clamp(caps.min_image_extent.height, caps.max_image_extent.height),
            }
        };
        if extent.width == 0 || extent.height == 0 {
            return Ok(false);
        }
        if !caps.supported_usage_flags.contains(vk::ImageUsageFlags::TRANSFER_DST) {
            return Err(GpuError::Surface("the window surface cannot be written by transfers".into()));
        }
        let formats = unsafe { self.surface_loader.get_physical_device_surface_formats(pd, self.surface) }
            .map_err(GpuError::vk("query surface formats"))?;
        let chosen = [vk::Format::B8G8R8A8_UNORM, vk::Format::R8G8B8A8_UNORM]
            .into_iter()
            .find_map(|f| formats.iter().find(|s| s.format == f).copied())
            .ok_or_else(|| GpuError::Surface("the window offers no 8-bit RGBA/BGRA UNORM format".into()))?;
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
            .present_mode(vk::PresentModeKHR::FIFO)
            .clipped(true)
            .old_swapchain(old);
        let swapchain =
            unsafe { self.loader.create_swapchain(&info, None) }.map_err(GpuError::vk("create the swapchain"))?;
        if old != vk::SwapchainKHR::null() {
            unsafe { self.loader.destroy_swapchain(old, None) };
        }
        self.swapchain = swapchain;
        self.images =
            unsafe { self.loader.get_swapchain_images(swapchain) }.map_err(GpuError::vk("get the swapchain images"))?;
        self.format = chosen.format;
        self.extent = extent;
        // One "rendered" semaphore per image: a semaphore a pending present still waits on is never re-signalled.
        let device = self.ctx.device();
        for s in self.render_semaphores.drain(..) {
            unsafe { device.destroy_semaphore(s, None) };
        }
        for _ in 0..self.images.len() {
            let s = unsafe { device.create_semaphore(&vk::SemaphoreCreateInfo::default(), None) }
                .map_err(GpuError::vk("create a semaphore"))?;
            self.render_semaphores.push(s);
        }
        Ok(true)
    }

    /// Acquires the next image (waits for one to be free).
    pub fn acquire(&mut self) -> Result<Acquired, GpuError> {
        let r = unsafe {
            self.loader.acquire_next_image(self.swapchain, u64::MAX, self.acquire_semaphore, vk::Fence::null())
        };
        match r {
            Ok((index, _suboptimal)) => Ok(Acquired::Image {
                index,
                image: self.images[index as usize],
                ready: self.acquire_semaphore,
                rendered: self.render_semaphores[index as usize],
            }),
            Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => Ok(Acquired::OutOfDate),
            Err(e) => Err(GpuError::vk("acquire a swapchain image")(e)),
        }
    }

    /// Presents image `index` after `rendered` is signalled. Returns `true` when the swapchain should be
    /// recreated (out of date or suboptimal).
    pub fn present(&mut self, index: u32) -> Result<bool, GpuError> {
        let waits = [self.render_semaphores[index as usize]];
        let swapchains = [self.swapchain];
        let indices = [index];
        let info =
            vk::PresentInfoKHR::default().wait_semaphores(&waits).swapchains(&swapchains).image_indices(&indices);
        // The queue may be shared with another thread (see `Context::lock_queue`).
        let presented = {
            let _queue = self.ctx.lock_queue();
            unsafe { self.loader.queue_present(self.ctx.queue(), &info) }
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
        let _ = self.ctx.wait_idle();
        let device = self.ctx.device();
        // SAFETY: the device is idle; these objects belong to this swapchain.
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
