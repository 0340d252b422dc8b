//! The Vulkan devices of this machine, GPU or software (`r2human doctor`), without creating a device.

use ash::vk;

use super::context::{application_info, load_entry};
use super::GpuError;

/// One Vulkan physical device.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DeviceSummary {
    /// Its name (`NVIDIA GeForce RTX 4090`, `llvmpipe (LLVM 15.0.6, 256 bits)`).
    pub name: String,
    /// Its kind: `discrete GPU`, `integrated GPU`, `virtual GPU`, `software (CPU)` or `other`.
    pub kind: &'static str,
    /// A software rasteriser on the CPU (lavapipe): `--backend auto` uses the CPU reference there.
    pub software: bool,
    /// The Vulkan version it offers (`1.3.255`).
    pub api_version: String,
    /// Whether it offers Vulkan 1.2, which r2human needs.
    pub usable: bool,
}

/// Lists the Vulkan devices the loader offers, in its order. Errors when there is no Vulkan loader or no driver.
pub fn list_devices() -> Result<Vec<DeviceSummary>, GpuError> {
    let entry = load_entry()?;
    let app = application_info(c"r2human doctor");
    let info = vk::InstanceCreateInfo::default().application_info(&app);
    // SAFETY: a valid create info whose pointers live until the call returns.
    let instance = unsafe { entry.create_instance(&info, None) }.map_err(|e| match e {
        vk::Result::ERROR_INCOMPATIBLE_DRIVER => GpuError::NoDevice("no Vulkan driver (ICD) is installed".into()),
        e => GpuError::vk("create the instance")(e),
    })?;
    // SAFETY: `instance` is alive until it is destroyed below; read-only queries.
    let listed = unsafe { instance.enumerate_physical_devices() }.map(|devices| {
        devices
            .into_iter()
            .map(|pd| {
                // SAFETY: `pd` was just enumerated from this live instance; a read-only query.
                let props = unsafe { instance.get_physical_device_properties(pd) };
                let v = props.api_version;
                let kind = match props.device_type {
                    vk::PhysicalDeviceType::DISCRETE_GPU => "discrete GPU",
                    vk::PhysicalDeviceType::INTEGRATED_GPU => "integrated GPU",
                    vk::PhysicalDeviceType::VIRTUAL_GPU => "virtual GPU",
                    vk::PhysicalDeviceType::CPU => "software (CPU)",
                    _ => "other",
                };
                DeviceSummary {
                    name: props.device_name_as_c_str().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default(),
                    kind,
                    software: props.device_type == vk::PhysicalDeviceType::CPU,
                    api_version: format!(
                        "{}.{}.{}",
                        vk::api_version_major(v),
                        vk::api_version_minor(v),
                        vk::api_version_patch(v)
                    ),
                    usable: vk::api_version_major(v) > 1 || vk::api_version_minor(v) >= 2,
                }
            })
            .collect::<Vec<_>>()
    });
    // SAFETY: nothing else was created on the instance, and no handle of it is used after this.
    unsafe { instance.destroy_instance(None) };
    listed.map_err(GpuError::vk("list the devices"))
}
