//! The Vulkan side of the OpenXR client: the instance and device created through XR_KHR_vulkan_enable2 (so the
//! runtime can add what it needs), wrapped as a [`gpu::Context`] for the renderer, and one swapchain per eye filled
//! on the GPU ([`EyeUploader`]): the renderer's float result is copied into a float image and blitted into the
//! swapchain image, which converts it to the swapchain's 8-bit format (sRGB encoding included) in hardware.
//!
//! Colour: eye images are linear, premultiplied RGBA. For `*_SRGB` swapchain formats the blit encodes sRGB (the
//! compositor decodes it back to linear when it samples); for `*_UNORM` formats the runtime takes the values as
//! linear, so the blit quantises them directly. [`SwapchainFormat::decode`] reads read-back bytes the same way.

use std::ffi::{c_char, CStr};
use std::sync::{Arc, Mutex, MutexGuard};

use ash::vk::{self, Handle};
use glam::Vec4;
use openxr as xr;

use super::diag::{vulkan_callback, DiagnosticLog};
use super::{VkContext, XrContext, XrError};
use crate::buffer::{linear_to_srgb, srgb_to_linear, RgbaImage};
use crate::gpu::{self, resources::subresource, resources::Buffer, resources::Image2d};

/// The Vulkan version r2human asks for (the renderer's; lavapipe and every desktop driver offer it).
const VK_TARGET_VERSION: u32 = vk::make_api_version(0, 1, 2, 0);

/// The format of the per-eye float images the renderer's output is copied into (its `vec4` layout).
pub const LINEAR_FORMAT: vk::Format = vk::Format::R32G32B32A32_SFLOAT;

/// A swapchain colour format r2human can fill.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SwapchainFormat {
    /// The Vulkan format.
    pub vk: vk::Format,
    /// Bytes are sRGB-encoded (the `*_SRGB` formats).
    pub srgb: bool,
    /// Byte order B, G, R, A instead of R, G, B, A.
    pub bgra: bool,
}

impl SwapchainFormat {
    /// The formats r2human can fill, in order of preference (sRGB first: 8-bit linear bands visibly in the darks).
    pub const PREFERRED: [SwapchainFormat; 4] = [
        SwapchainFormat { vk: vk::Format::R8G8B8A8_SRGB, srgb: true, bgra: false },
        SwapchainFormat { vk: vk::Format::B8G8R8A8_SRGB, srgb: true, bgra: true },
        SwapchainFormat { vk: vk::Format::R8G8B8A8_UNORM, srgb: false, bgra: false },
        SwapchainFormat { vk: vk::Format::B8G8R8A8_UNORM, srgb: false, bgra: true },
    ];

    /// The most preferred of [`SwapchainFormat::PREFERRED`] among the runtime's `offered` formats (raw VkFormat
    /// values, as `xrEnumerateSwapchainFormats` returns them), or `None`.
    pub fn choose(offered: &[u32]) -> Option<Self> {
        Self::choose_where(offered, |_| true)
    }

    /// As [`SwapchainFormat::choose`], among the formats for which `usable` holds (e.g. the device can blit into
    /// them).
    pub fn choose_where(offered: &[u32], usable: impl Fn(vk::Format) -> bool) -> Option<Self> {
        Self::PREFERRED.into_iter().find(|f| offered.contains(&(f.vk.as_raw() as u32)) && usable(f.vk))
    }

    /// Encodes one linear premultiplied RGBA pixel into the 4 bytes of this format.
    #[inline]
    pub fn encode(&self, px: Vec4) -> [u8; 4] {
        let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
        let a = if px.w.is_nan() { 0.0 } else { px.w.clamp(0.0, 1.0) };
        let channel = |v: f32| {
            // Premultiplied colour cannot exceed alpha; NaN reads as 0.
            let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, a) };
            if self.srgb {
                q(linear_to_srgb(v))
            } else {
                q(v)
            }
        };
        let (r, g, b) = (channel(px.x), channel(px.y), channel(px.z));
        if self.bgra {
            [b, g, r, q(a)]
        } else {
            [r, g, b, q(a)]
        }
    }

    /// Decodes 4 bytes of this format back to linear premultiplied RGBA (inverse of [`SwapchainFormat::encode`]
    /// up to quantisation).
    #[inline]
    pub fn decode(&self, bytes: [u8; 4]) -> Vec4 {
        let [c0, c1, c2, a] = bytes;
        let (r, g, b) = if self.bgra { (c2, c1, c0) } else { (c0, c1, c2) };
        let lin = |v: u8| {
            let v = v as f32 / 255.0;
            if self.srgb {
                srgb_to_linear(v)
            } else {
                v
            }
        };
        Vec4::new(lin(r), lin(g), lin(b), a as f32 / 255.0)
    }

    /// Decodes `width x height` pixels of this format into an image.
    pub fn decode_image(&self, bytes: &[u8], width: usize, height: usize) -> RgbaImage {
        RgbaImage::from_fn(width, height, |c, r| {
            let i = (r * width + c) * 4;
            self.decode([bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]])
        })
    }
}

/// The Vulkan instance, device and queue the OpenXR runtime asked for (XR_KHR_vulkan_enable2), and the renderer's
/// [`gpu::Context`] wrapped around them.
///
/// Everything created on the device (swapchains, renderers, buffers) must be dropped before this.
pub struct VulkanContext {
    /// The Vulkan loader.
    pub entry: ash::Entry,
    /// The instance created through `xrCreateVulkanInstanceKHR`.
    pub instance: ash::Instance,
    /// The physical device the runtime chose (`xrGetVulkanGraphicsDevice2KHR`).
    pub physical_device: vk::PhysicalDevice,
    /// The device created through `xrCreateVulkanDeviceKHR`.
    pub device: ash::Device,
    /// Family of [`VulkanContext::queue`] (graphics and compute).
    pub queue_family_index: u32,
    /// The queue given to the OpenXR session (index 0 of the family).
    pub queue: vk::Queue,
    /// Name of the physical device (e.g. "llvmpipe (LLVM 19...)").
    pub device_name: String,
    /// Vulkan validation warnings and errors (VK_EXT_debug_utils), when the extension is available.
    pub validation: Arc<DiagnosticLog>,
    /// Command pool for the display thread's command buffers (uploads, mirror).
    pub command_pool: vk::CommandPool,
    /// The renderer's view of this device: queue 1 of the family when the device has two queues there (the
    /// render thread then never contends with the OpenXR session's queue), else the session's queue.
    pub gpu: Arc<gpu::Context>,
    /// Serialises the session queue when the renderer does not share it (see [`VulkanContext::lock_queue`]).
    own_queue_lock: Mutex<()>,
    debug: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
}

impl VulkanContext {
    /// Creates the Vulkan instance and device for `system` through the runtime (XR_KHR_vulkan_enable2 must be
    /// enabled on `xr_instance`). Enables VK_EXT_debug_utils when present so validation output is captured.
    pub fn new(xr_instance: &xr::Instance, system: xr::SystemId) -> Result<Self, XrError> {
        Self::with_extensions(xr_instance, system, &[], &[])
    }

    /// As [`VulkanContext::new`], additionally enabling the given instance and device extensions (e.g. the
    /// surface and swapchain extensions of the desktop mirror window).
    pub fn with_extensions(
        xr_instance: &xr::Instance,
        system: xr::SystemId,
        instance_extensions: &[*const c_char],
        device_extensions: &[&CStr],
    ) -> Result<Self, XrError> {
        let reqs = xr_instance.graphics_requirements::<xr::Vulkan>(system).xr("xrGetVulkanGraphicsRequirements2KHR")?;
        let target = xr::Version::new(1, 2, 0);
        if target < reqs.min_api_version_supported || target.major() > reqs.max_api_version_supported.major() {
            return Err(XrError::Unsupported(format!(
                "the runtime needs Vulkan {} to {}, r2human uses 1.2",
                reqs.min_api_version_supported, reqs.max_api_version_supported
            )));
        }
        // SAFETY: loads the system Vulkan loader, which implements the Vulkan ABI.
        let entry = unsafe { ash::Entry::load() }.map_err(|e| XrError::VulkanLoader(e.to_string()))?;
        // SAFETY: plain enumeration on a loaded entry.
        let available = unsafe { entry.enumerate_instance_extension_properties(None) }
            .vk("vkEnumerateInstanceExtensionProperties")?;
        let has_debug_utils =
            available.iter().any(|e| e.extension_name_as_c_str().is_ok_and(|n| n == ash::ext::debug_utils::NAME));
        let mut extensions: Vec<*const c_char> = instance_extensions.to_vec();
        if has_debug_utils {
            extensions.push(ash::ext::debug_utils::NAME.as_ptr());
        }
        let app_name = c"r2human";
        let app_info = vk::ApplicationInfo::default()
            .application_name(app_name)
            .application_version(1)
            .engine_name(app_name)
            .api_version(VK_TARGET_VERSION);
        let create_info =
            vk::InstanceCreateInfo::default().application_info(&app_info).enabled_extension_names(&extensions);

        // SAFETY: the transmute only changes the handle parameter type of vkGetInstanceProcAddr from ash's u64
        // handle to OpenXR's pointer-sized handle: identical ABI on 64-bit targets.
        let gipa: xr::sys::platform::VkGetInstanceProcAddr =
            unsafe { std::mem::transmute(entry.static_fn().get_instance_proc_addr) };
        // SAFETY: valid system, loader entry and create info (pointers live until the call returns).
        let raw_instance =
            unsafe { xr_instance.create_vulkan_instance(system, gipa, &create_info as *const _ as *const _) }
                .xr("xrCreateVulkanInstanceKHR")?
                .map_err(|r| XrError::Vulkan {
                    call: "vkCreateInstance (via OpenXR)",
                    result: vk::Result::from_raw(r),
                })?;
        // SAFETY: the runtime created a valid instance with this loader.
        let instance = unsafe { ash::Instance::load(entry.static_fn(), vk::Instance::from_raw(raw_instance as u64)) };

        let validation = DiagnosticLog::new();
        let debug = if has_debug_utils {
            let loader = ash::ext::debug_utils::Instance::new(&entry, &instance);
            let info = vk::DebugUtilsMessengerCreateInfoEXT::default()
                .message_severity(
                    vk::DebugUtilsMessageSeverityFlagsEXT::WARNING | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
                )
                .message_type(
                    vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                        | vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                        | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
                )
                .pfn_user_callback(Some(vulkan_callback))
                .user_data(Arc::as_ptr(&validation) as *mut _);
            // SAFETY: valid instance; the user data outlives the messenger (both owned by self).
            match unsafe { loader.create_debug_utils_messenger(&info, None) } {
                Ok(m) => Some((loader, m)),
                Err(e) => {
                    tracing::warn!("vkCreateDebugUtilsMessengerEXT failed: {e}; Vulkan validation is not captured");
                    None
                }
            }
        } else {
            None
        };

        // From here on, failures must destroy the instance: build the rest in a closure.
        let rest = || -> Result<(vk::PhysicalDevice, ash::Device, u32, u32, String), XrError> {
            // SAFETY: the instance came from xrCreateVulkanInstanceKHR for this system.
            let physical_device = vk::PhysicalDevice::from_raw(
                unsafe { xr_instance.vulkan_graphics_device(system, instance.handle().as_raw() as _) }
                    .xr("xrGetVulkanGraphicsDevice2KHR")? as u64,
            );
            // SAFETY: valid physical device of this instance.
            let props = unsafe { instance.get_physical_device_properties(physical_device) };
            let device_name =
                props.device_name_as_c_str().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
            if props.api_version < VK_TARGET_VERSION {
                return Err(XrError::Unsupported(format!("Vulkan device {device_name} does not support Vulkan 1.2")));
            }
            // SAFETY: as above.
            let families = unsafe { instance.get_physical_device_queue_family_properties(physical_device) };
            let (queue_family_index, family) = families
                .iter()
                .enumerate()
                .find(|(_, f)| f.queue_flags.contains(vk::QueueFlags::GRAPHICS | vk::QueueFlags::COMPUTE))
                .ok_or_else(|| {
                    XrError::Unsupported(format!("Vulkan device {device_name} has no graphics+compute queue"))
                })?;
            let queue_count = family.queue_count.clamp(1, 2);
            let priorities = [1.0f32; 2];
            let queues = [vk::DeviceQueueCreateInfo::default()
                .queue_family_index(queue_family_index as u32)
                .queue_priorities(&priorities[..queue_count as usize])];
            let device_ext_ptrs: Vec<*const c_char> = device_extensions.iter().map(|e| e.as_ptr()).collect();
            let device_info =
                vk::DeviceCreateInfo::default().queue_create_infos(&queues).enabled_extension_names(&device_ext_ptrs);
            // SAFETY: valid physical device chosen by the runtime; pointers live until the call returns.
            let raw_device = unsafe {
                xr_instance.create_vulkan_device(
                    system,
                    gipa,
                    physical_device.as_raw() as _,
                    &device_info as *const _ as *const _,
                )
            }
            .xr("xrCreateVulkanDeviceKHR")?
            .map_err(|r| XrError::Vulkan { call: "vkCreateDevice (via OpenXR)", result: vk::Result::from_raw(r) })?;
            // SAFETY: the runtime created a valid device on this instance.
            let device = unsafe { ash::Device::load(instance.fp_v1_0(), vk::Device::from_raw(raw_device as u64)) };
            Ok((physical_device, device, queue_family_index as u32, queue_count, device_name))
        };
        let (physical_device, device, queue_family_index, queue_count, device_name) = match rest() {
            Ok(v) => v,
            Err(e) => {
                // SAFETY: nothing else was created on this instance.
                unsafe {
                    if let Some((loader, m)) = &debug {
                        loader.destroy_debug_utils_messenger(*m, None);
                    }
                    instance.destroy_instance(None);
                }
                return Err(e);
            }
        };
        // SAFETY: the handles belong together and outlive the context: it is dropped (with everything created from
        // it) before `Self::drop` destroys the device.
        let gpu = unsafe {
            gpu::Context::from_existing(
                entry.clone(),
                instance.clone(),
                physical_device,
                device.clone(),
                queue_family_index,
                queue_count - 1,
            )
        };
        let gpu = match gpu {
            Ok(g) => Arc::new(g),
            Err(e) => {
                // SAFETY: nothing was created on the device yet.
                unsafe {
                    device.destroy_device(None);
                    if let Some((loader, m)) = &debug {
                        loader.destroy_debug_utils_messenger(*m, None);
                    }
                    instance.destroy_instance(None);
                }
                return Err(XrError::Unsupported(format!("the OpenXR device cannot run the renderer: {e}")));
            }
        };
        // SAFETY: valid device; queue 0 of the family exists (at least one was requested).
        let queue = unsafe { device.get_device_queue(queue_family_index, 0) };
        let pool_info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(queue_family_index)
            .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER);
        let mut ctx = Self {
            entry,
            instance,
            physical_device,
            device,
            queue_family_index,
            queue,
            device_name,
            validation,
            command_pool: vk::CommandPool::null(),
            gpu,
            own_queue_lock: Mutex::new(()),
            debug,
        };
        // SAFETY: valid device; on failure `ctx`'s Drop cleans up (null pool is skipped).
        ctx.command_pool = unsafe { ctx.device.create_command_pool(&pool_info, None) }.vk("vkCreateCommandPool")?;
        Ok(ctx)
    }

    /// Does the renderer submit to the OpenXR session's queue (a device with one queue in the family)?
    pub fn renderer_shares_queue(&self) -> bool {
        self.gpu.queue() == self.queue
    }

    /// Locks the OpenXR session's queue: hold it around every call that may use it — own submissions and presents,
    /// and the OpenXR calls the runtime may submit from (`xrBeginFrame`, `xrEndFrame`, `xrAcquireSwapchainImage`,
    /// `xrReleaseSwapchainImage`). It is the renderer's queue lock when the renderer shares the queue.
    pub fn lock_queue(&self) -> MutexGuard<'_, ()> {
        if self.renderer_shares_queue() {
            self.gpu.lock_queue()
        } else {
            self.own_queue_lock.lock().unwrap_or_else(|p| p.into_inner())
        }
    }

    /// [`VulkanContext::lock_queue`], adding the time spent waiting for the lock to `waited`.
    pub fn lock_queue_timed(&self, waited: &mut std::time::Duration) -> MutexGuard<'_, ()> {
        let t = std::time::Instant::now();
        let guard = self.lock_queue();
        *waited += t.elapsed();
        guard
    }

    /// Does the device support `features` for `format` with optimal tiling?
    pub fn format_supports(&self, format: vk::Format, features: vk::FormatFeatureFlags) -> bool {
        // SAFETY: valid physical device.
        let props = unsafe { self.instance.get_physical_device_format_properties(self.physical_device, format) };
        props.optimal_tiling_features.contains(features)
    }
}

impl Drop for VulkanContext {
    fn drop(&mut self) {
        // SAFETY: the owner has dropped every object created on this device; wait for the queues first.
        unsafe {
            {
                let _q = self.lock_queue();
                let _g = (!self.renderer_shares_queue()).then(|| self.gpu.lock_queue());
                let _ = self.device.device_wait_idle();
            }
            if self.command_pool != vk::CommandPool::null() {
                self.device.destroy_command_pool(self.command_pool, None);
            }
            self.device.destroy_device(None);
            if let Some((loader, m)) = &self.debug {
                loader.destroy_debug_utils_messenger(*m, None);
            }
            self.instance.destroy_instance(None);
        }
    }
}

/// One eye's swapchain, the float image the renderer's result is copied into (also the mirror's source), and an
/// optional readback buffer (tests).
pub struct EyeSwapchain {
    /// The OpenXR swapchain.
    pub handle: xr::Swapchain<xr::Vulkan>,
    /// Its Vulkan images (owned by the runtime).
    pub images: Vec<vk::Image>,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// The colour format.
    pub format: SwapchainFormat,
    /// The last eye image in linear float ([`LINEAR_FORMAT`]); in TRANSFER_SRC_OPTIMAL after the first upload.
    pub linear: Image2d,
    readback: Option<Buffer>,
    released_once: bool,
}

impl EyeSwapchain {
    /// Creates a `width x height` swapchain of `format` for one eye. `readback` adds TRANSFER_SRC usage and a
    /// readback buffer so [`EyeUploader`] can read the image back from the swapchain.
    pub fn new(
        ctx: &VulkanContext,
        session: &xr::Session<xr::Vulkan>,
        format: SwapchainFormat,
        width: u32,
        height: u32,
        readback: bool,
    ) -> Result<Self, XrError> {
        if !ctx.format_supports(LINEAR_FORMAT, vk::FormatFeatureFlags::BLIT_SRC | vk::FormatFeatureFlags::TRANSFER_DST)
        {
            return Err(XrError::Unsupported(format!(
                "Vulkan device {} cannot blit from {LINEAR_FORMAT:?} images",
                ctx.device_name
            )));
        }
        let mut usage = xr::SwapchainUsageFlags::COLOR_ATTACHMENT
            | xr::SwapchainUsageFlags::TRANSFER_DST
            | xr::SwapchainUsageFlags::SAMPLED;
        if readback {
            usage |= xr::SwapchainUsageFlags::TRANSFER_SRC;
        }
        let handle = session
            .create_swapchain(&xr::SwapchainCreateInfo {
                create_flags: xr::SwapchainCreateFlags::EMPTY,
                usage_flags: usage,
                format: format.vk.as_raw() as u32,
                sample_count: 1,
                width,
                height,
                face_count: 1,
                array_size: 1,
                mip_count: 1,
            })
            .xr("xrCreateSwapchain")?;
        let images =
            handle.enumerate_images().xr("xrEnumerateSwapchainImages")?.into_iter().map(vk::Image::from_raw).collect();
        let gpu_err = |e: gpu::GpuError| XrError::Unsupported(format!("eye image buffers: {e}"));
        let linear = Image2d::new(
            &ctx.gpu,
            vk::Extent2D { width, height },
            LINEAR_FORMAT,
            // SAMPLED only because the image comes with a view (gpu::resources::Image2d); it is used by transfers.
            vk::ImageUsageFlags::TRANSFER_DST | vk::ImageUsageFlags::TRANSFER_SRC | vk::ImageUsageFlags::SAMPLED,
            vk::ImageAspectFlags::COLOR,
        )
        .map_err(gpu_err)?;
        let readback = if readback {
            let bytes = u64::from(width) * u64::from(height) * 4;
            Some(Buffer::new(&ctx.gpu, bytes, vk::BufferUsageFlags::TRANSFER_DST).map_err(gpu_err)?)
        } else {
            None
        };
        Ok(Self { handle, images, width, height, format, linear, readback, released_once: false })
    }

    /// Has an image been released at least once (so a projection layer may reference this swapchain)?
    pub fn has_content(&self) -> bool {
        self.released_once
    }

    /// The last read-back image (valid once the upload that wrote it has finished; see [`EyeUploader`]).
    fn read_back(&self) -> Option<RgbaImage> {
        let rb = self.readback.as_ref()?;
        let n = self.width as usize * self.height as usize * 4;
        let bytes = rb.bytes().get(..n)?;
        Some(self.format.decode_image(bytes, self.width as usize, self.height as usize))
    }
}

/// Records one image barrier between two pipeline stages.
///
/// # Safety
/// `cmd` is in the recording state and `barrier` names a valid image of `device`.
unsafe fn image_barrier(
    device: &ash::Device,
    cmd: vk::CommandBuffer,
    (src, dst): (vk::PipelineStageFlags, vk::PipelineStageFlags),
    barrier: vk::ImageMemoryBarrier<'_>,
) {
    // SAFETY: as the caller guarantees.
    unsafe { device.cmd_pipeline_barrier(cmd, src, dst, vk::DependencyFlags::empty(), &[], &[], &[barrier]) };
}

/// Fills the eye swapchains from the renderer's result buffers with one GPU submission per frame: buffer -> float
/// image copy, blit into the acquired swapchain image (format conversion), optional readback. Runs on the display
/// thread; it waits only for its own previous submission, which has long finished by the time a new frame exists.
pub struct EyeUploader {
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
    submitted: bool,
    capture_pending: bool,
}

impl EyeUploader {
    /// Allocates the command buffer and fence.
    pub fn new(ctx: &VulkanContext) -> Result<Self, XrError> {
        let alloc = vk::CommandBufferAllocateInfo::default()
            .command_pool(ctx.command_pool)
            .level(vk::CommandBufferLevel::PRIMARY)
            .command_buffer_count(1);
        // SAFETY: valid device and pool (the pool is only used from the display thread).
        let cmd = unsafe { ctx.device.allocate_command_buffers(&alloc) }.vk("vkAllocateCommandBuffers")?[0];
        // SAFETY: valid device.
        let fence = match unsafe { ctx.device.create_fence(&vk::FenceCreateInfo::default(), None) } {
            Ok(f) => f,
            Err(e) => {
                // SAFETY: never submitted.
                unsafe { ctx.device.free_command_buffers(ctx.command_pool, &[cmd]) };
                return Err(XrError::Vulkan { call: "vkCreateFence", result: e });
            }
        };
        Ok(Self { cmd, fence, submitted: false, capture_pending: false })
    }

    /// Copies `sources[i]` (the renderer's result for eye `i`, `vec4` per pixel of the eye's size) into the next
    /// image of each eye's swapchain, and with `capture` also back out into the eye's readback buffer. Returns the
    /// fence that signals when the GPU has finished reading `sources`. Time spent waiting for the queue lock is
    /// added to `waited`.
    pub fn upload(
        &mut self,
        ctx: &VulkanContext,
        eyes: &mut [EyeSwapchain],
        sources: &[vk::Buffer],
        capture: bool,
        waited: &mut std::time::Duration,
    ) -> Result<vk::Fence, XrError> {
        if sources.len() != eyes.len() {
            return Err(XrError::Render(format!("{} eye images for {} swapchains", sources.len(), eyes.len())));
        }
        self.wait(ctx)?;
        let mut indices = Vec::with_capacity(eyes.len());
        for eye in eyes.iter_mut() {
            let index = {
                let _q = ctx.lock_queue_timed(waited);
                eye.handle.acquire_image().xr("xrAcquireSwapchainImage")?
            };
            eye.handle.wait_image(xr::Duration::INFINITE).xr("xrWaitSwapchainImage")?;
            indices.push(index as usize);
        }
        let device = &ctx.device;
        let range = subresource(vk::ImageAspectFlags::COLOR);
        let layers = vk::ImageSubresourceLayers {
            aspect_mask: vk::ImageAspectFlags::COLOR,
            mip_level: 0,
            base_array_layer: 0,
            layer_count: 1,
        };
        let barrier = |image, old, new, src_access, dst_access| {
            vk::ImageMemoryBarrier::default()
                .old_layout(old)
                .new_layout(new)
                .src_access_mask(src_access)
                .dst_access_mask(dst_access)
                .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                .image(image)
                .subresource_range(range)
        };
        let capture = capture && eyes.iter().all(|e| e.readback.is_some());
        // SAFETY: the command buffer is idle (fence waited), every handle is valid, each swapchain image is ours
        // between xrWaitSwapchainImage and xrReleaseSwapchainImage, and the source buffers were finished by the
        // render thread (it waited on its own fence before publishing them).
        unsafe {
            device.reset_fences(&[self.fence]).vk("vkResetFences")?;
            device.reset_command_buffer(self.cmd, vk::CommandBufferResetFlags::empty()).vk("vkResetCommandBuffer")?;
            let begin = vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
            device.begin_command_buffer(self.cmd, &begin).vk("vkBeginCommandBuffer")?;
            for ((eye, &index), &source) in eyes.iter().zip(&indices).zip(sources) {
                let target = eye.images[index];
                let linear = eye.linear.image;
                let extent = vk::Extent3D { width: eye.width, height: eye.height, depth: 1 };
                // Both images are overwritten whole: discard the old contents. Earlier reads of the float image
                // (blits, the mirror) finish first.
                device.cmd_pipeline_barrier(
                    self.cmd,
                    vk::PipelineStageFlags::TRANSFER,
                    vk::PipelineStageFlags::TRANSFER,
                    vk::DependencyFlags::empty(),
                    &[],
                    &[],
                    &[
                        barrier(
                            linear,
                            vk::ImageLayout::UNDEFINED,
                            vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                            vk::AccessFlags::TRANSFER_READ,
                            vk::AccessFlags::TRANSFER_WRITE,
                        ),
                        barrier(
                            target,
                            vk::ImageLayout::UNDEFINED,
                            vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                            vk::AccessFlags::empty(),
                            vk::AccessFlags::TRANSFER_WRITE,
                        ),
                    ],
                );
                let copy = vk::BufferImageCopy {
                    buffer_offset: 0,
                    buffer_row_length: 0,
                    buffer_image_height: 0,
                    image_subresource: layers,
                    image_offset: vk::Offset3D::default(),
                    image_extent: extent,
                };
                device.cmd_copy_buffer_to_image(
                    self.cmd,
                    source,
                    linear,
                    vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                    &[copy],
                );
                image_barrier(
                    device,
                    self.cmd,
                    (vk::PipelineStageFlags::TRANSFER, vk::PipelineStageFlags::TRANSFER),
                    barrier(
                        linear,
                        vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                        vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                        vk::AccessFlags::TRANSFER_WRITE,
                        vk::AccessFlags::TRANSFER_READ,
                    ),
                );
                let corner = vk::Offset3D { x: eye.width as i32, y: eye.height as i32, z: 1 };
                let blit = vk::ImageBlit {
                    src_subresource: layers,
                    src_offsets: [vk::Offset3D::default(), corner],
                    dst_subresource: layers,
                    dst_offsets: [vk::Offset3D::default(), corner],
                };
                device.cmd_blit_image(
                    self.cmd,
                    linear,
                    vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                    target,
                    vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                    &[blit],
                    vk::Filter::NEAREST,
                );
                let mut last_layout = vk::ImageLayout::TRANSFER_DST_OPTIMAL;
                if let (true, Some(rb)) = (capture, &eye.readback) {
                    image_barrier(
                        device,
                        self.cmd,
                        (vk::PipelineStageFlags::TRANSFER, vk::PipelineStageFlags::TRANSFER),
                        barrier(
                            target,
                            vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                            vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                            vk::AccessFlags::TRANSFER_WRITE,
                            vk::AccessFlags::TRANSFER_READ,
                        ),
                    );
                    device.cmd_copy_image_to_buffer(
                        self.cmd,
                        target,
                        vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                        rb.buffer,
                        &[copy],
                    );
                    let host = vk::BufferMemoryBarrier::default()
                        .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
                        .dst_access_mask(vk::AccessFlags::HOST_READ)
                        .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                        .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                        .buffer(rb.buffer)
                        .offset(0)
                        .size(vk::WHOLE_SIZE);
                    device.cmd_pipeline_barrier(
                        self.cmd,
                        vk::PipelineStageFlags::TRANSFER,
                        vk::PipelineStageFlags::HOST,
                        vk::DependencyFlags::empty(),
                        &[],
                        &[host],
                        &[],
                    );
                    last_layout = vk::ImageLayout::TRANSFER_SRC_OPTIMAL;
                }
                // XR_KHR_vulkan_enable: a released colour image must be in COLOR_ATTACHMENT_OPTIMAL.
                image_barrier(
                    device,
                    self.cmd,
                    (vk::PipelineStageFlags::TRANSFER, vk::PipelineStageFlags::ALL_COMMANDS),
                    barrier(
                        target,
                        last_layout,
                        vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL,
                        vk::AccessFlags::TRANSFER_WRITE | vk::AccessFlags::TRANSFER_READ,
                        vk::AccessFlags::COLOR_ATTACHMENT_READ | vk::AccessFlags::SHADER_READ,
                    ),
                );
            }
            device.end_command_buffer(self.cmd).vk("vkEndCommandBuffer")?;
            let cmds = [self.cmd];
            let submit = vk::SubmitInfo::default().command_buffers(&cmds);
            let _q = ctx.lock_queue_timed(waited);
            device.queue_submit(ctx.queue, &[submit], self.fence).vk("vkQueueSubmit")?;
        }
        self.submitted = true;
        // A read-back not collected yet stays valid: its buffers are only rewritten by uploads with `capture`.
        self.capture_pending |= capture;
        for eye in eyes.iter_mut() {
            let _q = ctx.lock_queue_timed(waited);
            eye.handle.release_image().xr("xrReleaseSwapchainImage")?;
            eye.released_once = true;
        }
        Ok(self.fence)
    }

    /// The read-back eye images of the last upload with `capture`, once the GPU has finished it (never blocks;
    /// `None` while it runs or when there is nothing new).
    pub fn take_captures(&mut self, ctx: &VulkanContext, eyes: &[EyeSwapchain]) -> Option<Vec<RgbaImage>> {
        if !self.capture_pending {
            return None;
        }
        // SAFETY: our own fence.
        if !unsafe { ctx.device.get_fence_status(self.fence) }.unwrap_or(false) {
            return None;
        }
        self.capture_pending = false;
        eyes.iter().map(EyeSwapchain::read_back).collect()
    }

    /// Waits for the last upload (before re-recording, and at the end of the session).
    pub fn wait(&mut self, ctx: &VulkanContext) -> Result<(), XrError> {
        if self.submitted {
            // SAFETY: our own fence, submitted once since its last reset.
            unsafe { ctx.device.wait_for_fences(&[self.fence], true, u64::MAX) }.vk("vkWaitForFences")?;
        }
        Ok(())
    }

    /// Frees the command buffer and fence (after the device is idle).
    pub fn destroy(self, ctx: &VulkanContext) {
        // SAFETY: the caller waited for the device; nothing uses these objects any more.
        unsafe {
            ctx.device.destroy_fence(self.fence, None);
            ctx.device.free_command_buffers(ctx.command_pool, &[self.cmd]);
        }
    }
}

/// The name of a Vulkan format for messages ("R8G8B8A8_SRGB"), or its number.
pub fn format_name(raw: u32) -> String {
    let f = vk::Format::from_raw(raw as i32);
    let name = format!("{f:?}");
    if name.chars().all(|c| c.is_ascii_digit()) {
        format!("VkFormat({raw})")
    } else {
        name
    }
}

/// A `CStr` view of a fixed-size C string array (for Vulkan property names).
pub fn c_array_str(chars: &[c_char]) -> String {
    let bytes: Vec<u8> = chars.iter().take_while(|&&c| c != 0).map(|&c| c as u8).collect();
    CStr::from_bytes_until_nul(&[bytes.as_slice(), &[0]].concat())
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chooses_srgb_first_and_none_when_nothing_fits() {
        let offered = [vk::Format::B8G8R8A8_UNORM.as_raw() as u32, vk::Format::B8G8R8A8_SRGB.as_raw() as u32];
        let f = SwapchainFormat::choose(&offered).unwrap();
        assert_eq!(f.vk, vk::Format::B8G8R8A8_SRGB);
        assert!(f.srgb && f.bgra);
        let only_unorm = [vk::Format::R8G8B8A8_UNORM.as_raw() as u32];
        assert!(!SwapchainFormat::choose(&only_unorm).unwrap().srgb);
        assert!(SwapchainFormat::choose(&[vk::Format::R16G16B16A16_SFLOAT.as_raw() as u32]).is_none());
    }

    #[test]
    fn encode_matches_closed_form_and_round_trips() {
        let srgb = SwapchainFormat::PREFERRED[0];
        let bgra_unorm = SwapchainFormat::PREFERRED[3];
        // Linear 0.5 grey, opaque: sRGB byte round(255 * 0.7354) = 188; UNORM byte 128.
        assert_eq!(srgb.encode(Vec4::new(0.5, 0.5, 0.5, 1.0)), [188, 188, 188, 255]);
        assert_eq!(bgra_unorm.encode(Vec4::new(1.0, 0.5, 0.0, 1.0)), [0, 128, 255, 255]);
        // Premultiplied colour above alpha is clamped to alpha; NaN becomes 0; alpha NaN becomes transparent.
        assert_eq!(bgra_unorm.encode(Vec4::new(0.9, f32::NAN, 0.1, 0.5)), [26, 0, 128, 128]);
        assert_eq!(srgb.encode(Vec4::new(1.0, 1.0, 1.0, f32::NAN)), [0, 0, 0, 0]);
        for f in SwapchainFormat::PREFERRED {
            for &v in &[0.0f32, 0.01, 0.2, 0.5, 0.99, 1.0] {
                let px = Vec4::new(v, v * 0.5, v * 0.25, 1.0);
                let back = f.decode(f.encode(px));
                let tol = if f.srgb { 0.01 } else { 0.5 / 255.0 + 1e-6 };
                assert!((back - px).abs().max_element() <= tol, "{f:?} {px} -> {back}");
            }
        }
    }

    #[test]
    fn image_encoding_is_row_major_top_first() {
        let f = SwapchainFormat::PREFERRED[2];
        let img = RgbaImage::from_fn(2, 2, |c, r| Vec4::new(c as f32, r as f32, 0.0, 1.0));
        let bytes: Vec<u8> = img.data.iter().flat_map(|p| f.encode(*p)).collect();
        assert_eq!(bytes, vec![0, 0, 0, 255, 255, 0, 0, 255, 0, 255, 0, 255, 255, 255, 0, 255]);
        assert_eq!(f.decode_image(&bytes, 2, 2), img);
    }

    #[test]
    fn format_names_are_readable() {
        assert_eq!(format_name(vk::Format::R8G8B8A8_SRGB.as_raw() as u32), "R8G8B8A8_SRGB");
        assert_eq!(c_array_str(&[b'a' as c_char, b'b' as c_char, 0, b'c' as c_char]), "ab");
    }
}
