//! The Vulkan device: instance, physical device, logical device and one graphics+compute queue, created
//! headless, for a window surface, or wrapped around handles another component created (the OpenXR client
//! creates its instance and device through `XR_KHR_vulkan_enable2`).

use std::ffi::{c_char, c_void, CStr, CString};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Mutex, MutexGuard};

use ash::vk;
use raw_window_handle::{RawDisplayHandle, RawWindowHandle};

use super::GpuError;

/// Environment variable that turns on the Khronos validation layer and the debug messenger (`1`).
pub const VALIDATION_ENV: &str = "R2HUMAN_VULKAN_VALIDATION";

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

/// Options for [`Context::new`].
#[derive(Clone, Debug, Default)]
pub struct ContextOptions {
    /// Enable the validation layer and count its messages. `None` reads [`VALIDATION_ENV`].
    pub validation: Option<bool>,
    /// A window surface will be created for this display (adds the surface instance extensions and the
    /// swapchain device extension).
    pub display: Option<RawDisplayHandle>,
}

/// Validation-layer messages seen by the debug messenger, counted by severity.
#[derive(Debug, Default)]
pub struct ValidationLog {
    errors: AtomicU32,
    warnings: AtomicU32,
    messages: Mutex<Vec<String>>,
}

impl ValidationLog {
    /// Number of error messages so far.
    pub fn errors(&self) -> u32 {
        self.errors.load(Ordering::SeqCst)
    }

    /// Number of warning messages so far.
    pub fn warnings(&self) -> u32 {
        self.warnings.load(Ordering::SeqCst)
    }

    /// The first error and warning messages (at most 32), for test failures.
    pub fn messages(&self) -> Vec<String> {
        self.messages.lock().map(|m| m.clone()).unwrap_or_default()
    }

    fn record(&self, error: bool, text: String) {
        if error {
            self.errors.fetch_add(1, Ordering::SeqCst);
        } else {
            self.warnings.fetch_add(1, Ordering::SeqCst);
        }
        if let Ok(mut m) = self.messages.lock() {
            if m.len() < 32 {
                m.push(text);
            }
        }
    }
}

unsafe extern "system" fn debug_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut c_void,
) -> vk::Bool32 {
    // SAFETY: the loader passes valid callback data for the duration of the call; `user` is the
    // `ValidationLog` boxed in the Context, which outlives the messenger.
    let text = unsafe {
        if data.is_null() || (*data).p_message.is_null() {
            String::from("(no message)")
        } else {
            CStr::from_ptr((*data).p_message).to_string_lossy().into_owned()
        }
    };
    let error = severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR);
    let warning = severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::WARNING);
    if error || warning {
        tracing::warn!(target: "vulkan", "{text}");
        if !user.is_null() {
            unsafe { (*(user as *const ValidationLog)).record(error, text) };
        }
    } else {
        tracing::debug!(target: "vulkan", "{text}");
    }
    vk::FALSE
}

/// A Vulkan device with one queue that does graphics, compute and transfer (and presents, when created for
/// a surface). Everything the renderer allocates comes from here.
pub struct Context {
    entry: ash::Entry,
    instance: ash::Instance,
    physical_device: vk::PhysicalDevice,
    device: ash::Device,
    queue: vk::Queue,
    queue_family: u32,
    memory_properties: vk::PhysicalDeviceMemoryProperties,
    device_name: String,
    debug: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    log: Box<ValidationLog>,
    owned: bool,
    /// Serialises submissions when the queue is shared between threads (an OpenXR frame loop and a render
    /// thread): Vulkan requires external synchronisation of `vkQueueSubmit`/`vkQueueWaitIdle` on one queue.
    queue_lock: Mutex<()>,
}

impl std::fmt::Debug for Context {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Context").field("device", &self.device_name).field("owned", &self.owned).finish()
    }
}

fn validation_requested(opt: Option<bool>) -> bool {
    opt.unwrap_or_else(|| std::env::var(VALIDATION_ENV).map(|v| v == "1").unwrap_or(false))
}

fn debug_info(log: &ValidationLog) -> vk::DebugUtilsMessengerCreateInfoEXT<'static> {
    vk::DebugUtilsMessengerCreateInfoEXT::default()
        .message_severity(
            vk::DebugUtilsMessageSeverityFlagsEXT::ERROR
                | vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
                | vk::DebugUtilsMessageSeverityFlagsEXT::INFO,
        )
        .message_type(
            vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
        )
        .pfn_user_callback(Some(debug_callback))
        .user_data(log as *const ValidationLog as *mut c_void)
}

impl Context {
    /// A headless device (no window): offscreen rendering for tests, batch renders and benchmarks.
    pub fn headless() -> Result<Self, GpuError> {
        Self::new(&ContextOptions::default())
    }

    /// Creates an instance and a device. Any Vulkan 1.2+ device is accepted (discrete preferred, then
    /// integrated, virtual, CPU — lavapipe included).
    pub fn new(options: &ContextOptions) -> Result<Self, GpuError> {
        Self::create(options, None).map(|(ctx, _)| ctx)
    }

    /// Creates an instance, a surface for `window` and a device whose queue can present to that surface.
    pub fn with_surface(
        display: RawDisplayHandle,
        window: RawWindowHandle,
        validation: Option<bool>,
    ) -> Result<(Self, vk::SurfaceKHR), GpuError> {
        let options = ContextOptions { validation, display: Some(display) };
        let (ctx, surface) = Self::create(&options, Some((display, window)))?;
        surface.map(|s| (ctx, s)).ok_or_else(|| GpuError::Surface("no surface was created".into()))
    }

    fn create(
        options: &ContextOptions,
        window: Option<(RawDisplayHandle, RawWindowHandle)>,
    ) -> Result<(Self, Option<vk::SurfaceKHR>), GpuError> {
        // SAFETY: loading the system Vulkan loader; failure is reported, not assumed.
        let entry = unsafe { ash::Entry::load() }.map_err(|e| GpuError::NoVulkan(e.to_string()))?;
        let version = unsafe { entry.try_enumerate_instance_version() }.map_err(GpuError::vk("query version"))?;
        let version = version.unwrap_or(vk::API_VERSION_1_0);
        if vk::api_version_major(version) == 1 && vk::api_version_minor(version) < 2 {
            return Err(GpuError::NoDevice(format!(
                "the Vulkan loader offers version 1.{} but 1.2 is required",
                vk::api_version_minor(version)
            )));
        }
        let validation = validation_requested(options.validation);
        let log = Box::new(ValidationLog::default());
        let mut layers: Vec<*const c_char> = Vec::new();
        let mut extensions: Vec<*const c_char> = Vec::new();
        if validation {
            let available = unsafe { entry.enumerate_instance_layer_properties() }
                .map_err(GpuError::vk("enumerate instance layers"))?;
            if !available.iter().any(|l| l.layer_name_as_c_str().is_ok_and(|n| n == VALIDATION_LAYER)) {
                return Err(GpuError::ValidationUnavailable);
            }
            layers.push(VALIDATION_LAYER.as_ptr());
            extensions.push(ash::ext::debug_utils::NAME.as_ptr());
        }
        if let Some(display) = options.display {
            let required = ash_window::enumerate_required_extensions(display)
                .map_err(|e| GpuError::Surface(format!("this window system has no Vulkan surface support ({e})")))?;
            extensions.extend_from_slice(required);
        }
        let app_name = CString::new("r2human").unwrap_or_default();
        let app = vk::ApplicationInfo::default()
            .application_name(&app_name)
            .engine_name(&app_name)
            .api_version(vk::API_VERSION_1_2);
        let mut messenger_info = debug_info(&log);
        let mut info = vk::InstanceCreateInfo::default()
            .application_info(&app)
            .enabled_layer_names(&layers)
            .enabled_extension_names(&extensions);
        if validation {
            info = info.push_next(&mut messenger_info);
        }
        let instance = unsafe { entry.create_instance(&info, None) }.map_err(|e| match e {
            // The loader found no driver (ICD) at all.
            vk::Result::ERROR_INCOMPATIBLE_DRIVER => GpuError::NoDevice("no Vulkan driver (ICD) is installed".into()),
            e => GpuError::vk("create the instance")(e),
        })?;
        // From here on, failures must destroy what was created: build a partial context step by step.
        let debug = if validation {
            let loader = ash::ext::debug_utils::Instance::new(&entry, &instance);
            match unsafe { loader.create_debug_utils_messenger(&debug_info(&log), None) } {
                Ok(m) => Some((loader, m)),
                Err(e) => {
                    unsafe { instance.destroy_instance(None) };
                    return Err(GpuError::vk("create the debug messenger")(e));
                }
            }
        } else {
            None
        };
        let destroy_instance = |debug: &Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>| unsafe {
            if let Some((loader, m)) = debug {
                loader.destroy_debug_utils_messenger(*m, None);
            }
            instance.destroy_instance(None);
        };
        let surface = match window {
            Some((display, handle)) => {
                match unsafe { ash_window::create_surface(&entry, &instance, display, handle, None) } {
                    Ok(s) => Some(s),
                    Err(e) => {
                        destroy_instance(&debug);
                        return Err(GpuError::Surface(format!("cannot create a window surface ({e})")));
                    }
                }
            }
            None => None,
        };
        let surface_loader = ash::khr::surface::Instance::new(&entry, &instance);
        let picked = pick_device(&instance, surface.map(|s| (&surface_loader, s)));
        let (physical_device, queue_family) = match picked {
            Ok(p) => p,
            Err(e) => {
                if let Some(s) = surface {
                    unsafe { surface_loader.destroy_surface(s, None) };
                }
                destroy_instance(&debug);
                return Err(e);
            }
        };
        let priorities = [1.0f32];
        let queue_info =
            [vk::DeviceQueueCreateInfo::default().queue_family_index(queue_family).queue_priorities(&priorities)];
        let mut device_extensions: Vec<*const c_char> = Vec::new();
        if surface.is_some() {
            device_extensions.push(ash::khr::swapchain::NAME.as_ptr());
        }
        let device_info =
            vk::DeviceCreateInfo::default().queue_create_infos(&queue_info).enabled_extension_names(&device_extensions);
        let device = match unsafe { instance.create_device(physical_device, &device_info, None) } {
            Ok(d) => d,
            Err(e) => {
                if let Some(s) = surface {
                    unsafe { surface_loader.destroy_surface(s, None) };
                }
                destroy_instance(&debug);
                return Err(GpuError::vk("create the device")(e));
            }
        };
        let queue = unsafe { device.get_device_queue(queue_family, 0) };
        let memory_properties = unsafe { instance.get_physical_device_memory_properties(physical_device) };
        let props = unsafe { instance.get_physical_device_properties(physical_device) };
        let device_name = props.device_name_as_c_str().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        tracing::info!("Vulkan device: {device_name}");
        Ok((
            Self {
                entry,
                instance,
                physical_device,
                device,
                queue,
                queue_family,
                memory_properties,
                device_name,
                debug,
                log,
                owned: true,
                queue_lock: Mutex::new(()),
            },
            surface,
        ))
    }

    /// Wraps an instance and device created elsewhere (e.g. by OpenXR's `XR_KHR_vulkan_enable2`). The
    /// context does not destroy them when dropped; the queue family must support graphics and compute.
    ///
    /// # Safety
    /// The handles must be valid, belong together, and outlive the context and everything created from it.
    pub unsafe fn from_existing(
        entry: ash::Entry,
        instance: ash::Instance,
        physical_device: vk::PhysicalDevice,
        device: ash::Device,
        queue_family: u32,
        queue_index: u32,
    ) -> Result<Self, GpuError> {
        let families = unsafe { instance.get_physical_device_queue_family_properties(physical_device) };
        let family = families
            .get(queue_family as usize)
            .ok_or_else(|| GpuError::NoDevice(format!("queue family {queue_family} does not exist on this device")))?;
        if !family.queue_flags.contains(vk::QueueFlags::GRAPHICS | vk::QueueFlags::COMPUTE) {
            return Err(GpuError::NoDevice(format!("queue family {queue_family} lacks graphics or compute")));
        }
        let queue = unsafe { device.get_device_queue(queue_family, queue_index) };
        let memory_properties = unsafe { instance.get_physical_device_memory_properties(physical_device) };
        let props = unsafe { instance.get_physical_device_properties(physical_device) };
        let device_name = props.device_name_as_c_str().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        Ok(Self {
            entry,
            instance,
            physical_device,
            device,
            queue,
            queue_family,
            memory_properties,
            device_name,
            debug: None,
            log: Box::new(ValidationLog::default()),
            owned: false,
            queue_lock: Mutex::new(()),
        })
    }

    /// The Vulkan loader entry points.
    pub fn entry(&self) -> &ash::Entry {
        &self.entry
    }

    /// The instance.
    pub fn instance(&self) -> &ash::Instance {
        &self.instance
    }

    /// The physical device.
    pub fn physical_device(&self) -> vk::PhysicalDevice {
        self.physical_device
    }

    /// The logical device.
    pub fn device(&self) -> &ash::Device {
        &self.device
    }

    /// The graphics + compute (+ present) queue.
    pub fn queue(&self) -> vk::Queue {
        self.queue
    }

    /// The queue's family index.
    pub fn queue_family(&self) -> u32 {
        self.queue_family
    }

    /// The device's name (e.g. `llvmpipe (LLVM 15.0.6, 256 bits)`).
    pub fn device_name(&self) -> &str {
        &self.device_name
    }

    /// Whether the device is a software rasteriser running on the CPU (lavapipe/llvmpipe: Vulkan device type
    /// `CPU`), where the Vulkan passes run on the same cores as the CPU reference and are slower than it.
    pub fn is_software(&self) -> bool {
        let props = unsafe { self.instance.get_physical_device_properties(self.physical_device) };
        props.device_type == vk::PhysicalDeviceType::CPU
    }

    /// Validation messages counted so far (always zero when validation is off).
    pub fn validation(&self) -> &ValidationLog {
        &self.log
    }

    /// Is the validation layer on?
    pub fn validation_enabled(&self) -> bool {
        self.debug.is_some()
    }

    /// A memory type index with all of `flags` among those allowed by `type_bits`.
    pub(crate) fn memory_type(&self, type_bits: u32, flags: vk::MemoryPropertyFlags) -> Option<u32> {
        (0..self.memory_properties.memory_type_count).find(|&i| {
            type_bits & (1 << i) != 0 && self.memory_properties.memory_types[i as usize].property_flags.contains(flags)
        })
    }

    /// Waits until the device is idle (used before destroying resources).
    pub fn wait_idle(&self) -> Result<(), GpuError> {
        let _queue = self.lock_queue();
        unsafe { self.device.device_wait_idle() }.map_err(GpuError::vk("wait for the device"))
    }

    /// Locks the queue for a submission, present or wait from outside the renderer (the renderer takes the same
    /// lock around its own submissions), so several threads can share the queue. Hold it only for the call.
    pub fn lock_queue(&self) -> MutexGuard<'_, ()> {
        self.queue_lock.lock().unwrap_or_else(|p| p.into_inner())
    }
}

impl Drop for Context {
    fn drop(&mut self) {
        if !self.owned {
            return;
        }
        // SAFETY: everything created from this context holds an Arc to it, so nothing uses the device now.
        unsafe {
            let _ = self.device.device_wait_idle();
            self.device.destroy_device(None);
            if let Some((loader, messenger)) = self.debug.take() {
                loader.destroy_debug_utils_messenger(messenger, None);
            }
            self.instance.destroy_instance(None);
        }
    }
}

fn pick_device(
    instance: &ash::Instance,
    surface: Option<(&ash::khr::surface::Instance, vk::SurfaceKHR)>,
) -> Result<(vk::PhysicalDevice, u32), GpuError> {
    let devices = unsafe { instance.enumerate_physical_devices() }.map_err(GpuError::vk("list the devices"))?;
    let mut best: Option<(u32, vk::PhysicalDevice, u32)> = None;
    let mut rejected = Vec::new();
    for pd in devices {
        let props = unsafe { instance.get_physical_device_properties(pd) };
        let name = props.device_name_as_c_str().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        if vk::api_version_major(props.api_version) == 1 && vk::api_version_minor(props.api_version) < 2 {
            rejected.push(format!("{name} (Vulkan 1.{} < 1.2)", vk::api_version_minor(props.api_version)));
            continue;
        }
        let families = unsafe { instance.get_physical_device_queue_family_properties(pd) };
        let family = families.iter().enumerate().find_map(|(i, f)| {
            let ok = f.queue_flags.contains(vk::QueueFlags::GRAPHICS | vk::QueueFlags::COMPUTE);
            let present = match surface {
                Some((loader, s)) => unsafe {
                    loader.get_physical_device_surface_support(pd, i as u32, s).unwrap_or(false)
                },
                None => true,
            };
            (ok && present).then_some(i as u32)
        });
        let Some(family) = family else {
            rejected.push(format!("{name} (no graphics+compute queue that can present)"));
            continue;
        };
        let rank = match props.device_type {
            vk::PhysicalDeviceType::DISCRETE_GPU => 4,
            vk::PhysicalDeviceType::INTEGRATED_GPU => 3,
            vk::PhysicalDeviceType::VIRTUAL_GPU => 2,
            vk::PhysicalDeviceType::CPU => 1,
            _ => 0,
        };
        if best.is_none_or(|(r, _, _)| rank > r) {
            best = Some((rank, pd, family));
        }
    }
    best.map(|(_, pd, f)| (pd, f)).ok_or_else(|| {
        GpuError::NoDevice(if rejected.is_empty() {
            "no Vulkan device was found".to_string()
        } else {
            format!("no usable Vulkan device: {}", rejected.join(", "))
        })
    })
}
