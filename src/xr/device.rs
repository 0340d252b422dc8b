//! The Vulkan device the OpenXR runtime asks for: [`create_device`] builds the one [`gpu::Context`] type through
//! `XR_KHR_vulkan_enable2` ([`RuntimeDevice`] is the [`gpu::DeviceFactory`] that makes the runtime create the
//! instance and device). The session submits to queue [`SESSION_QUEUE`]; the renderer to the context's last
//! queue, a second queue of the family when the device has one (then it never contends with the session).

use std::ffi::{c_char, CStr};
use std::sync::Arc;

use ash::vk::{self, Handle};
use openxr as xr;

use super::{XrContext, XrError};
use crate::gpu::{self, GpuError};

/// The queue index the OpenXR session is created with (and its swapchain copies and the mirror submit to).
pub const SESSION_QUEUE: usize = 0;

/// Makes the OpenXR runtime create the Vulkan instance and device for `system` (see [`gpu::DeviceFactory`]).
pub struct RuntimeDevice<'a> {
    /// An instance with `XR_KHR_vulkan_enable2` enabled.
    pub instance: &'a xr::Instance,
    /// The headset's system.
    pub system: xr::SystemId,
}

/// `vkGetInstanceProcAddr` of `entry` as OpenXR's function-pointer type.
fn instance_proc_addr(entry: &ash::Entry) -> xr::sys::platform::VkGetInstanceProcAddr {
    // SAFETY: the transmute only changes the handle parameter type of vkGetInstanceProcAddr from ash's u64 handle
    // to OpenXR's pointer-sized handle: identical ABI on 64-bit targets.
    unsafe { std::mem::transmute(entry.static_fn().get_instance_proc_addr) }
}

impl gpu::DeviceFactory for RuntimeDevice<'_> {
    type Error = XrError;

    fn create_instance(&self, entry: &ash::Entry, info: &vk::InstanceCreateInfo<'_>) -> Result<vk::Instance, XrError> {
        // SAFETY: valid system, loader entry and create info (pointers live until the call returns).
        let raw = unsafe {
            self.instance.create_vulkan_instance(self.system, instance_proc_addr(entry), info as *const _ as *const _)
        }
        .xr("xrCreateVulkanInstanceKHR")?
        .map_err(|r| GpuError::vk("create the instance (through OpenXR)")(vk::Result::from_raw(r)))?;
        Ok(vk::Instance::from_raw(raw as u64))
    }

    fn physical_device(&self, instance: &ash::Instance) -> Result<vk::PhysicalDevice, XrError> {
        // SAFETY: the instance came from xrCreateVulkanInstanceKHR for this system.
        let raw = unsafe { self.instance.vulkan_graphics_device(self.system, instance.handle().as_raw() as _) }
            .xr("xrGetVulkanGraphicsDevice2KHR")?;
        Ok(vk::PhysicalDevice::from_raw(raw as u64))
    }

    fn create_device(
        &self,
        entry: &ash::Entry,
        _instance: &ash::Instance,
        physical_device: vk::PhysicalDevice,
        info: &vk::DeviceCreateInfo<'_>,
    ) -> Result<vk::Device, XrError> {
        // SAFETY: valid physical device chosen by the runtime; pointers live until the call returns.
        let raw = unsafe {
            self.instance.create_vulkan_device(
                self.system,
                instance_proc_addr(entry),
                physical_device.as_raw() as _,
                info as *const _ as *const _,
            )
        }
        .xr("xrCreateVulkanDeviceKHR")?
        .map_err(|r| GpuError::vk("create the device (through OpenXR)")(vk::Result::from_raw(r)))?;
        Ok(vk::Device::from_raw(raw as u64))
    }
}

/// Creates the Vulkan instance and device for `system` through the runtime (`XR_KHR_vulkan_enable2` must be
/// enabled on `xr_instance`), with the given extra instance and device extensions (e.g. the desktop mirror
/// window's surface and swapchain extensions) and up to two queues. `VK_EXT_debug_utils` is enabled when present,
/// so validation output is captured in [`gpu::Context::validation`].
pub fn create_device(
    xr_instance: &xr::Instance,
    system: xr::SystemId,
    instance_extensions: &[*const c_char],
    device_extensions: &[&CStr],
) -> Result<Arc<gpu::Context>, XrError> {
    let reqs = xr_instance.graphics_requirements::<xr::Vulkan>(system).xr("xrGetVulkanGraphicsRequirements2KHR")?;
    let target = xr::Version::new(1, 2, 0);
    if target < reqs.min_api_version_supported || target.major() > reqs.max_api_version_supported.major() {
        return Err(XrError::Unsupported(format!(
            "the runtime needs Vulkan {} to {}, r2human uses 1.2",
            reqs.min_api_version_supported, reqs.max_api_version_supported
        )));
    }
    let factory = RuntimeDevice { instance: xr_instance, system };
    gpu::Context::through(&factory, instance_extensions, device_extensions, 2).map(Arc::new)
}

/// Does the renderer submit to the OpenXR session's queue (a device with one queue in the family)?
pub fn renderer_shares_queue(ctx: &gpu::Context) -> bool {
    ctx.queue_count() == 1
}
