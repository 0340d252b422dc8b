//! The Vulkan side of the OpenXR client: the instance and device created through XR_KHR_vulkan_enable2 (so the
//! runtime can add what it needs), and one swapchain per eye fed from a host-visible staging buffer.
//!
//! The raw handles stay public on [`VulkanContext`] and [`EyeSwapchain`] so a GPU renderer built from existing ash
//! handles can render straight into the swapchain images instead of going through the staging copy.
//!
//! Colour: eye images are linear, premultiplied RGBA. For `*_SRGB` swapchain formats the bytes written are
//! sRGB-encoded (the hardware decodes them back to linear when the compositor samples); for `*_UNORM` formats the
//! runtime takes the values as linear, so the bytes are the linear values quantised directly.

use std::ffi::{c_char, CStr};
use std::sync::Arc;

use ash::vk::{self, Handle};
use glam::Vec4;
use openxr as xr;

use super::diag::{vulkan_callback, DiagnosticLog};
use super::{VkContext, XrContext, XrError};
use crate::buffer::{linear_to_srgb, srgb_to_linear, RgbaImage};

/// The Vulkan version r2human asks for (lavapipe and every desktop driver offer it).
const VK_TARGET_VERSION: u32 = vk::make_api_version(0, 1, 1, 0);

/// A swapchain colour format r2human can write from the CPU.
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
        Self::PREFERRED.into_iter().find(|f| offered.contains(&(f.vk.as_raw() as u32)))
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

    /// Encodes a whole image (row 0 first, as Vulkan buffer-to-image copies expect).
    pub fn encode_image(&self, img: &RgbaImage) -> Vec<u8> {
        let mut out = Vec::with_capacity(img.data.len() * 4);
        for px in &img.data {
            out.extend_from_slice(&self.encode(*px));
        }
        out
    }

    /// Decodes `width x height` pixels of this format into an image.
    pub fn decode_image(&self, bytes: &[u8], width: usize, height: usize) -> RgbaImage {
        RgbaImage::from_fn(width, height, |c, r| {
            let i = (r * width + c) * 4;
            self.decode([bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]])
        })
    }
}

/// The Vulkan instance, device and queue the OpenXR runtime asked for (XR_KHR_vulkan_enable2).
///
/// Field order is drop order irrelevant: [`Drop`] destroys in the right order. Everything created on the device
/// (swapchains, buffers) must be dropped before this.
pub struct VulkanContext {
    /// The Vulkan loader.
    pub entry: ash::Entry,
    /// The instance created through `xrCreateVulkanInstanceKHR`.
    pub instance: ash::Instance,
    /// The physical device the runtime chose (`xrGetVulkanGraphicsDevice2KHR`).
    pub physical_device: vk::PhysicalDevice,
    /// The device created through `xrCreateVulkanDeviceKHR`.
    pub device: ash::Device,
    /// Family of [`VulkanContext::queue`] (graphics-capable).
    pub queue_family_index: u32,
    /// The queue shared with the OpenXR runtime; only the display thread submits to it.
    pub queue: vk::Queue,
    /// Name of the physical device (e.g. "llvmpipe (LLVM 19...)").
    pub device_name: String,
    /// Vulkan validation warnings and errors (VK_EXT_debug_utils), when the extension is available.
    pub validation: Arc<DiagnosticLog>,
    /// Command pool for the per-eye upload command buffers.
    pub command_pool: vk::CommandPool,
    memory_properties: vk::PhysicalDeviceMemoryProperties,
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
        let target = xr::Version::new(1, 1, 0);
        if target < reqs.min_api_version_supported || target.major() > reqs.max_api_version_supported.major() {
            return Err(XrError::Unsupported(format!(
                "the runtime needs Vulkan {} to {}, r2human uses 1.1",
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
        let rest = || -> Result<(vk::PhysicalDevice, ash::Device, u32, String), XrError> {
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
                return Err(XrError::Unsupported(format!("Vulkan device {device_name} does not support Vulkan 1.1")));
            }
            // SAFETY: as above.
            let families = unsafe { instance.get_physical_device_queue_family_properties(physical_device) };
            let queue_family_index = families
                .iter()
                .position(|f| f.queue_flags.contains(vk::QueueFlags::GRAPHICS))
                .ok_or_else(|| XrError::Unsupported(format!("Vulkan device {device_name} has no graphics queue")))?
                as u32;
            let priorities = [1.0f32];
            let queues = [vk::DeviceQueueCreateInfo::default()
                .queue_family_index(queue_family_index)
                .queue_priorities(&priorities)];
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
            Ok((physical_device, device, queue_family_index, device_name))
        };
        let (physical_device, device, queue_family_index, device_name) = match rest() {
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
        // SAFETY: valid device; queue 0 of the family exists (one was requested).
        let queue = unsafe { device.get_device_queue(queue_family_index, 0) };
        // SAFETY: valid physical device.
        let memory_properties = unsafe { instance.get_physical_device_memory_properties(physical_device) };
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
            memory_properties,
            debug,
        };
        // SAFETY: valid device; on failure `ctx`'s Drop cleans up (null pool is skipped).
        ctx.command_pool = unsafe { ctx.device.create_command_pool(&pool_info, None) }.vk("vkCreateCommandPool")?;
        Ok(ctx)
    }

    /// Allocates a host-visible, host-coherent buffer of `size` bytes, persistently mapped.
    pub fn host_buffer(&self, size: u64, usage: vk::BufferUsageFlags) -> Result<HostBuffer, XrError> {
        let info = vk::BufferCreateInfo::default().size(size).usage(usage).sharing_mode(vk::SharingMode::EXCLUSIVE);
        // SAFETY: valid device and create info; every object is destroyed on the error paths below.
        unsafe {
            let buffer = self.device.create_buffer(&info, None).vk("vkCreateBuffer")?;
            let reqs = self.device.get_buffer_memory_requirements(buffer);
            let wanted = vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT;
            let Some(type_index) = (0..self.memory_properties.memory_type_count).find(|&i| {
                reqs.memory_type_bits & (1 << i) != 0
                    && self.memory_properties.memory_types[i as usize].property_flags.contains(wanted)
            }) else {
                self.device.destroy_buffer(buffer, None);
                return Err(XrError::Unsupported("no host-visible coherent memory for staging buffers".into()));
            };
            let alloc = vk::MemoryAllocateInfo::default().allocation_size(reqs.size).memory_type_index(type_index);
            let memory = match self.device.allocate_memory(&alloc, None) {
                Ok(m) => m,
                Err(e) => {
                    self.device.destroy_buffer(buffer, None);
                    return Err(XrError::Vulkan { call: "vkAllocateMemory", result: e });
                }
            };
            let mapped = self
                .device
                .bind_buffer_memory(buffer, memory, 0)
                .and_then(|_| self.device.map_memory(memory, 0, vk::WHOLE_SIZE, vk::MemoryMapFlags::empty()));
            match mapped {
                Ok(ptr) => Ok(HostBuffer { buffer, memory, ptr: ptr as *mut u8, size: size as usize }),
                Err(e) => {
                    self.device.destroy_buffer(buffer, None);
                    self.device.free_memory(memory, None);
                    Err(XrError::Vulkan { call: "vkMapMemory", result: e })
                }
            }
        }
    }
}

impl Drop for VulkanContext {
    fn drop(&mut self) {
        // SAFETY: the owner has dropped every object created on this device; wait for the queue first.
        unsafe {
            let _ = self.device.device_wait_idle();
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

/// A persistently mapped host-visible buffer. Destroy it with [`HostBuffer::destroy`] before the device.
pub struct HostBuffer {
    /// The buffer.
    pub buffer: vk::Buffer,
    /// Its memory (host visible and coherent).
    pub memory: vk::DeviceMemory,
    ptr: *mut u8,
    size: usize,
}

// SAFETY: the mapping is plain memory; access is serialised by the owner (one thread at a time).
unsafe impl Send for HostBuffer {}

impl HostBuffer {
    /// The mapped bytes.
    pub fn bytes_mut(&mut self) -> &mut [u8] {
        // SAFETY: `ptr` maps `size` bytes for the lifetime of the buffer; `&mut self` makes the access exclusive.
        unsafe { std::slice::from_raw_parts_mut(self.ptr, self.size) }
    }

    /// The mapped bytes, read-only.
    pub fn bytes(&self) -> &[u8] {
        // SAFETY: as in `bytes_mut`.
        unsafe { std::slice::from_raw_parts(self.ptr, self.size) }
    }

    /// Frees the buffer and its memory.
    ///
    /// # Safety
    /// No submitted GPU work may still use the buffer.
    pub unsafe fn destroy(&mut self, device: &ash::Device) {
        // SAFETY: caller guarantees the GPU is done with it.
        unsafe {
            device.destroy_buffer(self.buffer, None);
            device.free_memory(self.memory, None);
        }
        self.buffer = vk::Buffer::null();
        self.memory = vk::DeviceMemory::null();
        self.size = 0;
    }
}

/// One eye's swapchain with its staging and (optional) readback buffers, command buffer and fence.
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
    staging: HostBuffer,
    readback: Option<HostBuffer>,
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
    released_once: bool,
}

impl EyeSwapchain {
    /// Creates a `width x height` swapchain of `format` for one eye. `readback` adds TRANSFER_SRC usage and a
    /// readback buffer so [`EyeSwapchain::upload`] can read the image back from the swapchain.
    pub fn new(
        ctx: &VulkanContext,
        session: &xr::Session<xr::Vulkan>,
        format: SwapchainFormat,
        width: u32,
        height: u32,
        readback: bool,
    ) -> Result<Self, XrError> {
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
        let size = width as u64 * height as u64 * 4;
        let mut staging = ctx.host_buffer(size, vk::BufferUsageFlags::TRANSFER_SRC)?;
        let readback_buf = if readback {
            match ctx.host_buffer(size, vk::BufferUsageFlags::TRANSFER_DST) {
                Ok(b) => Some(b),
                Err(e) => {
                    // SAFETY: never used by the GPU.
                    unsafe { staging.destroy(&ctx.device) };
                    return Err(e);
                }
            }
        } else {
            None
        };
        let alloc = vk::CommandBufferAllocateInfo::default()
            .command_pool(ctx.command_pool)
            .level(vk::CommandBufferLevel::PRIMARY)
            .command_buffer_count(1);
        // SAFETY: valid device and pool (the pool is only used from the display thread).
        let cmd = unsafe { ctx.device.allocate_command_buffers(&alloc) }.vk("vkAllocateCommandBuffers")?[0];
        let fence_info = vk::FenceCreateInfo::default().flags(vk::FenceCreateFlags::SIGNALED);
        // SAFETY: valid device.
        let fence = unsafe { ctx.device.create_fence(&fence_info, None) }.vk("vkCreateFence")?;
        Ok(Self {
            handle,
            images,
            width,
            height,
            format,
            staging,
            readback: readback_buf,
            cmd,
            fence,
            released_once: false,
        })
    }

    /// Has an image been released at least once (so a projection layer may reference this swapchain)?
    pub fn has_content(&self) -> bool {
        self.released_once
    }

    /// Acquires the next image, copies `pixels` (already encoded in [`EyeSwapchain::format`], `width*height*4`
    /// bytes, top row first) through the staging buffer into it and releases it. With `read_back`, the image is
    /// copied back out of the swapchain after the upload and returned (needs `readback` at creation).
    pub fn upload(&mut self, ctx: &VulkanContext, pixels: &[u8], read_back: bool) -> Result<Option<Vec<u8>>, XrError> {
        if pixels.len() != self.staging.size {
            return Err(XrError::Render(format!(
                "eye image has {} bytes, the {}x{} swapchain needs {}",
                pixels.len(),
                self.width,
                self.height,
                self.staging.size
            )));
        }
        let device = &ctx.device;
        // SAFETY: the fence belongs to this device; waiting makes the staging buffer and command buffer free.
        unsafe {
            device.wait_for_fences(&[self.fence], true, u64::MAX).vk("vkWaitForFences")?;
        }
        let index = self.handle.acquire_image().xr("xrAcquireSwapchainImage")? as usize;
        self.handle.wait_image(xr::Duration::INFINITE).xr("xrWaitSwapchainImage")?;
        self.staging.bytes_mut().copy_from_slice(pixels);
        let image = self.images[index];
        let read_back = read_back && self.readback.is_some();
        let range = vk::ImageSubresourceRange {
            aspect_mask: vk::ImageAspectFlags::COLOR,
            base_mip_level: 0,
            level_count: 1,
            base_array_layer: 0,
            layer_count: 1,
        };
        let layers = vk::ImageSubresourceLayers {
            aspect_mask: vk::ImageAspectFlags::COLOR,
            mip_level: 0,
            base_array_layer: 0,
            layer_count: 1,
        };
        let region = vk::BufferImageCopy {
            buffer_offset: 0,
            buffer_row_length: 0,
            buffer_image_height: 0,
            image_subresource: layers,
            image_offset: vk::Offset3D::default(),
            image_extent: vk::Extent3D { width: self.width, height: self.height, depth: 1 },
        };
        let barrier = |old, new, src_access, dst_access| {
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
        // SAFETY: the command buffer is idle (fence waited), every handle is valid, and the image is ours between
        // xrWaitSwapchainImage and xrReleaseSwapchainImage.
        unsafe {
            device.reset_fences(&[self.fence]).vk("vkResetFences")?;
            device.reset_command_buffer(self.cmd, vk::CommandBufferResetFlags::empty()).vk("vkResetCommandBuffer")?;
            let begin = vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
            device.begin_command_buffer(self.cmd, &begin).vk("vkBeginCommandBuffer")?;
            // The whole image is overwritten: discard the old contents (UNDEFINED -> TRANSFER_DST).
            device.cmd_pipeline_barrier(
                self.cmd,
                vk::PipelineStageFlags::TOP_OF_PIPE,
                vk::PipelineStageFlags::TRANSFER,
                vk::DependencyFlags::empty(),
                &[],
                &[],
                &[barrier(
                    vk::ImageLayout::UNDEFINED,
                    vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                    vk::AccessFlags::empty(),
                    vk::AccessFlags::TRANSFER_WRITE,
                )],
            );
            device.cmd_copy_buffer_to_image(
                self.cmd,
                self.staging.buffer,
                image,
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                &[region],
            );
            let mut last_layout = vk::ImageLayout::TRANSFER_DST_OPTIMAL;
            if let (true, Some(rb)) = (read_back, &self.readback) {
                device.cmd_pipeline_barrier(
                    self.cmd,
                    vk::PipelineStageFlags::TRANSFER,
                    vk::PipelineStageFlags::TRANSFER,
                    vk::DependencyFlags::empty(),
                    &[],
                    &[],
                    &[barrier(
                        vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                        vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                        vk::AccessFlags::TRANSFER_WRITE,
                        vk::AccessFlags::TRANSFER_READ,
                    )],
                );
                device.cmd_copy_image_to_buffer(
                    self.cmd,
                    image,
                    vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                    rb.buffer,
                    &[region],
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
            device.cmd_pipeline_barrier(
                self.cmd,
                vk::PipelineStageFlags::TRANSFER,
                vk::PipelineStageFlags::ALL_COMMANDS,
                vk::DependencyFlags::empty(),
                &[],
                &[],
                &[barrier(
                    last_layout,
                    vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL,
                    vk::AccessFlags::TRANSFER_WRITE | vk::AccessFlags::TRANSFER_READ,
                    vk::AccessFlags::COLOR_ATTACHMENT_READ | vk::AccessFlags::SHADER_READ,
                )],
            );
            device.end_command_buffer(self.cmd).vk("vkEndCommandBuffer")?;
            let cmds = [self.cmd];
            let submit = vk::SubmitInfo::default().command_buffers(&cmds);
            device.queue_submit(ctx.queue, &[submit], self.fence).vk("vkQueueSubmit")?;
        }
        let out = if read_back {
            // SAFETY: waiting on our own fence; afterwards the readback buffer holds the copied image.
            unsafe { device.wait_for_fences(&[self.fence], true, u64::MAX).vk("vkWaitForFences")? };
            self.readback.as_ref().map(|rb| rb.bytes().to_vec())
        } else {
            None
        };
        self.handle.release_image().xr("xrReleaseSwapchainImage")?;
        self.released_once = true;
        Ok(out)
    }

    /// Waits for this eye's GPU work and frees the Vulkan objects (the OpenXR swapchain is dropped with `self`).
    pub fn destroy(mut self, ctx: &VulkanContext) {
        // SAFETY: waiting for our fence means the GPU no longer uses the buffers or the command buffer.
        unsafe {
            let _ = ctx.device.wait_for_fences(&[self.fence], true, u64::MAX);
            ctx.device.destroy_fence(self.fence, None);
            ctx.device.free_command_buffers(ctx.command_pool, &[self.cmd]);
            self.staging.destroy(&ctx.device);
            if let Some(rb) = &mut self.readback {
                rb.destroy(&ctx.device);
            }
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
        let bytes = f.encode_image(&img);
        assert_eq!(bytes, vec![0, 0, 0, 255, 255, 0, 0, 255, 0, 255, 0, 255, 255, 255, 0, 255]);
        assert_eq!(f.decode_image(&bytes, 2, 2), img);
    }

    #[test]
    fn format_names_are_readable() {
        assert_eq!(format_name(vk::Format::R8G8B8A8_SRGB.as_raw() as u32), "R8G8B8A8_SRGB");
        assert_eq!(c_array_str(&[b'a' as c_char, b'b' as c_char, 0, b'c' as c_char]), "ab");
    }
}
