//! The Vulkan device: instance, physical device, logical device and one or two graphics+compute queues of one
//! family, created headless, for a window surface, or through another component that must create the instance and
//! device itself ([`DeviceFactory`]: the OpenXR client creates them through `XR_KHR_vulkan_enable2`). Every path
//! shares one validation log ([`ValidationLog`]), one lock per queue ([`Context::lock_queue`]) and one error type
//! ([`GpuError`]).

use std::ffi::{c_char, c_void, CStr};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

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

/// How many validation messages a [`ValidationLog`] keeps verbatim (the counts keep going).
pub const KEPT_MESSAGES: usize = 64;

/// Validation-layer messages seen by the debug messenger, counted by severity (one log per Vulkan instance; the
/// OpenXR client feeds the core validation layer's reports into one of its own).
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

    /// Number of warnings and errors so far.
    pub fn count(&self) -> u32 {
        self.errors() + self.warnings()
    }

    /// The first error and warning messages (at most [`KEPT_MESSAGES`]), for reports and test failures.
    pub fn messages(&self) -> Vec<String> {
        self.messages.lock().map(|m| m.clone()).unwrap_or_default()
    }

    /// Records one message (an error when `error`, else a warning).
    pub fn record(&self, error: bool, text: String) {
        if error {
            self.errors.fetch_add(1, Ordering::SeqCst);
        } else {
            self.warnings.fetch_add(1, Ordering::SeqCst);
        }
        if let Ok(mut m) = self.messages.lock() {
            if m.len() < KEPT_MESSAGES {
                m.push(text);
            }
        }
    }
}

/// The Vulkan debug-utils callback: records validation warnings and errors into the [`ValidationLog`] in
/// `user_data`.
///
/// # Safety
/// Called by the loader only: `data` is null or valid for the call, `user_data` is null or the `ValidationLog`
/// registered with the messenger (alive while the messenger is).
unsafe extern "system" fn debug_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut c_void,
) -> vk::Bool32 {
    // SAFETY: the loader passes valid callback data for the duration of the call; `user` is the
    // `ValidationLog` held (in an Arc) by the Context, which outlives the messenger.
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
        if error {
            tracing::error!(target: "vulkan", "{text}");
        } else {
            tracing::warn!(target: "vulkan", "{text}");
        }
        if !user.is_null() {
            // SAFETY: `user` is the context's `Arc<ValidationLog>`, alive as long as the messenger (see above).
            unsafe { (*(user as *const ValidationLog)).record(error, text) };
        }
    } else {
        tracing::debug!(target: "vulkan", "{text}");
    }
    vk::FALSE
}

/// The Vulkan version r2human asks for (lavapipe and every desktop driver offer it).
pub const API_VERSION: u32 = vk::API_VERSION_1_2;

/// One queue of the context's family and the lock that serialises its use.
struct Queue {
    handle: vk::Queue,
    lock: Mutex<()>,
}

/// A messenger and the loader functions that destroy it.
type Messenger = (ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT);

/// A Vulkan device with one or two queues of one family that does graphics, compute and transfer (and presents,
/// when created for a surface). Everything the renderer allocates comes from here. The renderer submits to the
/// last queue ([`Context::queue`]); a device created through a [`DeviceFactory`] with two queues leaves queue 0 to
/// the component that asked for it (the OpenXR session).
pub struct Context {
    entry: ash::Entry,
    instance: ash::Instance,
    physical_device: vk::PhysicalDevice,
    device: ash::Device,
    /// The family's queues in index order. Vulkan requires external synchronisation of `vkQueueSubmit`,
    /// `vkQueuePresentKHR` and `vkQueueWaitIdle` on one queue: each has its lock, so an OpenXR frame loop and a
    /// render thread can share the device.
    queues: Vec<Queue>,
    queue_family: u32,
    memory_properties: vk::PhysicalDeviceMemoryProperties,
    device_name: String,
    debug: Option<Messenger>,
    log: Arc<ValidationLog>,
}

impl std::fmt::Debug for Context {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Context").field("device", &self.device_name).field("queues", &self.queues.len()).finish()
    }
}

/// Creates the instance and the device on behalf of a component that must own their creation (OpenXR's
/// `XR_KHR_vulkan_enable2`: the runtime adds the extensions it needs and chooses the physical device). The
/// [`Context`] built by [`Context::through`] owns and destroys both.
pub trait DeviceFactory {
    /// The factory's error; GPU errors of the steps the context does itself convert into it.
    type Error: From<GpuError>;
    /// Creates the instance for `info` with `entry`'s loader.
    fn create_instance(
        &self,
        entry: &ash::Entry,
        info: &vk::InstanceCreateInfo<'_>,
    ) -> Result<vk::Instance, Self::Error>;
    /// The physical device to use on `instance`.
    fn physical_device(&self, instance: &ash::Instance) -> Result<vk::PhysicalDevice, Self::Error>;
    /// Creates the device for `info` on `physical_device`.
    fn create_device(
        &self,
        entry: &ash::Entry,
        instance: &ash::Instance,
        physical_device: vk::PhysicalDevice,
        info: &vk::DeviceCreateInfo<'_>,
    ) -> Result<vk::Device, Self::Error>;
}

fn validation_requested(opt: Option<bool>) -> bool {
    opt.unwrap_or_else(|| std::env::var(VALIDATION_ENV).map(|v| v == "1").unwrap_or(false))
}

fn debug_info(log: &Arc<ValidationLog>) -> vk::DebugUtilsMessengerCreateInfoEXT<'static> {
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
        .user_data(Arc::as_ptr(log) as *mut c_void)
}

/// Destroys a messenger (if any) and the instance.
///
/// # Safety
/// Nothing else created on `instance` is alive.
unsafe fn destroy_instance(instance: &ash::Instance, debug: &Option<Messenger>) {
    // SAFETY: as the caller guarantees.
    unsafe {
        if let Some((loader, m)) = debug {
            loader.destroy_debug_utils_messenger(*m, None);
        }
        instance.destroy_instance(None);
    }
}

/// Loads the system's Vulkan loader.
pub(crate) fn load_entry() -> Result<ash::Entry, GpuError> {
    // SAFETY: loading the system Vulkan loader, which implements the Vulkan ABI; failure is reported.
    unsafe { ash::Entry::load() }.map_err(|e| GpuError::NoVulkan(e.to_string()))
}

/// The application info of r2human's instances (Vulkan 1.2).
pub(crate) fn application_info(name: &CStr) -> vk::ApplicationInfo<'_> {
    vk::ApplicationInfo::default()
        .application_name(name)
        .application_version(1)
        .engine_name(name)
        .api_version(API_VERSION)
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
        let entry = load_entry()?;
        // SAFETY: plain query on a loaded entry.
        let version = unsafe { entry.try_enumerate_instance_version() }.map_err(GpuError::vk("query version"))?;
        let version = version.unwrap_or(vk::API_VERSION_1_0);
        if vk::api_version_major(version) == 1 && vk::api_version_minor(version) < 2 {
            return Err(GpuError::NoDevice(format!(
                "the Vulkan loader offers version 1.{} but 1.2 is required",
                vk::api_version_minor(version)
            )));
        }
        let validation = validation_requested(options.validation);
        let log = Arc::new(ValidationLog::default());
        let mut layers: Vec<*const c_char> = Vec::new();
        let mut extensions: Vec<*const c_char> = Vec::new();
        if validation {
            // SAFETY: plain enumeration on a loaded entry.
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
        let app = application_info(c"r2human");
        let mut messenger_info = debug_info(&log);
        let mut info = vk::InstanceCreateInfo::default()
            .application_info(&app)
            .enabled_layer_names(&layers)
            .enabled_extension_names(&extensions);
        if validation {
            info = info.push_next(&mut messenger_info);
        }
        // SAFETY: valid create info; every pointer in it lives until the call returns.
        let instance = unsafe { entry.create_instance(&info, None) }.map_err(|e| match e {
            // The loader found no driver (ICD) at all.
            vk::Result::ERROR_INCOMPATIBLE_DRIVER => GpuError::NoDevice("no Vulkan driver (ICD) is installed".into()),
            e => GpuError::vk("create the instance")(e),
        })?;
        // From here on, failures must destroy what was created: build a partial context step by step.
        let debug = if validation {
            let loader = ash::ext::debug_utils::Instance::new(&entry, &instance);
            // SAFETY: valid instance; the log outlives the messenger (both end up in the context).
            match unsafe { loader.create_debug_utils_messenger(&debug_info(&log), None) } {
                Ok(m) => Some((loader, m)),
                Err(e) => {
                    // SAFETY: nothing else was created on the instance.
                    unsafe { instance.destroy_instance(None) };
                    return Err(GpuError::vk("create the debug messenger")(e));
                }
            }
        } else {
            None
        };
        let surface = match window {
            Some((display, handle)) => {
                // SAFETY: the caller's window handles are valid; the surface is destroyed before the instance.
                match unsafe { ash_window::create_surface(&entry, &instance, display, handle, None) } {
                    Ok(s) => Some(s),
                    Err(e) => {
                        // SAFETY: nothing else was created on the instance.
                        unsafe { destroy_instance(&instance, &debug) };
                        return Err(GpuError::Surface(format!("cannot create a window surface ({e})")));
                    }
                }
            }
            None => None,
        };
        let surface_loader = ash::khr::surface::Instance::new(&entry, &instance);
        let fail = |e: GpuError| {
            // SAFETY: only the surface (if any) was created on the instance.
            unsafe {
                if let Some(s) = surface {
                    surface_loader.destroy_surface(s, None);
                }
                destroy_instance(&instance, &debug);
            }
            e
        };
        let (physical_device, queue_family) =
            pick_device(&instance, surface.map(|s| (&surface_loader, s))).map_err(fail)?;
        let priorities = [1.0f32];
        let queue_info =
            [vk::DeviceQueueCreateInfo::default().queue_family_index(queue_family).queue_priorities(&priorities)];
        let mut device_extensions: Vec<*const c_char> = Vec::new();
        if surface.is_some() {
            device_extensions.push(ash::khr::swapchain::NAME.as_ptr());
        }
        let device_info =
            vk::DeviceCreateInfo::default().queue_create_infos(&queue_info).enabled_extension_names(&device_extensions);
        // SAFETY: valid physical device and create info.
        let device = unsafe { instance.create_device(physical_device, &device_info, None) }
            .map_err(|e| fail(GpuError::vk("create the device")(e)))?;
        let ctx = Self::assemble(entry, instance, physical_device, device, queue_family, 1, debug, log);
        Ok((ctx, surface))
    }

    /// Creates the instance and the device through `factory` (see [`DeviceFactory`]) with `instance_extensions`
    /// and `device_extensions` (e.g. a mirror window's surface and swapchain extensions) and up to `max_queues`
    /// queues of the first graphics+compute family. `VK_EXT_debug_utils` is enabled when the loader offers it,
    /// so the messages of a validation layer switched on from outside (`VK_INSTANCE_LAYERS`) are counted in
    /// [`Context::validation`].
    pub fn through<F: DeviceFactory>(
        factory: &F,
        instance_extensions: &[*const c_char],
        device_extensions: &[&CStr],
        max_queues: u32,
    ) -> Result<Self, F::Error> {
        let entry = load_entry()?;
        // SAFETY: plain enumeration on a loaded entry.
        let available = unsafe { entry.enumerate_instance_extension_properties(None) }
            .map_err(GpuError::vk("list the instance extensions"))?;
        let has_debug_utils =
            available.iter().any(|e| e.extension_name_as_c_str().is_ok_and(|n| n == ash::ext::debug_utils::NAME));
        let mut extensions: Vec<*const c_char> = instance_extensions.to_vec();
        if has_debug_utils {
            extensions.push(ash::ext::debug_utils::NAME.as_ptr());
        }
        let app = application_info(c"r2human");
        let info = vk::InstanceCreateInfo::default().application_info(&app).enabled_extension_names(&extensions);
        let raw = factory.create_instance(&entry, &info)?;
        // SAFETY: the factory created a valid instance with this loader.
        let instance = unsafe { ash::Instance::load(entry.static_fn(), raw) };
        let log = Arc::new(ValidationLog::default());
        let debug = if has_debug_utils {
            let loader = ash::ext::debug_utils::Instance::new(&entry, &instance);
            // SAFETY: valid instance; the log outlives the messenger (both end up in the context).
            match unsafe { loader.create_debug_utils_messenger(&debug_info(&log), None) } {
                Ok(m) => Some((loader, m)),
                Err(e) => {
                    tracing::warn!("vkCreateDebugUtilsMessengerEXT failed: {e}; Vulkan validation is not captured");
                    None
                }
            }
        } else {
            None
        };
        let rest = || -> Result<(vk::PhysicalDevice, vk::Device, u32, u32), F::Error> {
            let physical_device = factory.physical_device(&instance)?;
            // SAFETY: valid physical device of this instance.
            let props = unsafe { instance.get_physical_device_properties(physical_device) };
            let name = props.device_name_as_c_str().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            if props.api_version < API_VERSION {
                return Err(GpuError::NoDevice(format!("Vulkan device {name} does not support Vulkan 1.2")).into());
            }
            // SAFETY: as above.
            let families = unsafe { instance.get_physical_device_queue_family_properties(physical_device) };
            let (family, props) = families
                .iter()
                .enumerate()
                .find(|(_, f)| f.queue_flags.contains(vk::QueueFlags::GRAPHICS | vk::QueueFlags::COMPUTE))
                .ok_or_else(|| GpuError::NoDevice(format!("Vulkan device {name} has no graphics+compute queue")))?;
            let count = props.queue_count.clamp(1, max_queues.max(1));
            let priorities = [1.0f32; 2];
            let queues = [vk::DeviceQueueCreateInfo::default()
                .queue_family_index(family as u32)
                .queue_priorities(&priorities[..count.min(2) as usize])];
            let device_extensions: Vec<*const c_char> = device_extensions.iter().map(|e| e.as_ptr()).collect();
            let info =
                vk::DeviceCreateInfo::default().queue_create_infos(&queues).enabled_extension_names(&device_extensions);
            let device = factory.create_device(&entry, &instance, physical_device, &info)?;
            Ok((physical_device, device, family as u32, count.min(2)))
        };
        match rest() {
            Ok((physical_device, raw_device, family, count)) => {
                // SAFETY: the factory created a valid device on this instance.
                let device = unsafe { ash::Device::load(instance.fp_v1_0(), raw_device) };
                Ok(Self::assemble(entry, instance, physical_device, device, family, count, debug, log))
            }
            Err(e) => {
                // SAFETY: nothing else was created on this instance.
                unsafe { destroy_instance(&instance, &debug) };
                Err(e)
            }
        }
    }

    /// The context around a created device with `queue_count` queues of `queue_family`.
    #[allow(clippy::too_many_arguments)]
    fn assemble(
        entry: ash::Entry,
        instance: ash::Instance,
        physical_device: vk::PhysicalDevice,
        device: ash::Device,
        queue_family: u32,
        queue_count: u32,
        debug: Option<Messenger>,
        log: Arc<ValidationLog>,
    ) -> Self {
        let queues = (0..queue_count.max(1))
            // SAFETY: the device was created with `queue_count` queues of this family.
            .map(|i| Queue { handle: unsafe { device.get_device_queue(queue_family, i) }, lock: Mutex::new(()) })
            .collect();
        // SAFETY: valid physical device of this instance.
        let memory_properties = unsafe { instance.get_physical_device_memory_properties(physical_device) };
        // SAFETY: as above.
        let props = unsafe { instance.get_physical_device_properties(physical_device) };
        let device_name = props.device_name_as_c_str().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        tracing::info!("Vulkan device: {device_name}");
        Self {
            entry,
            instance,
            physical_device,
            device,
            queues,
            queue_family,
            memory_properties,
            device_name,
            debug,
            log,
        }
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

    /// Index of the renderer's queue for [`Context::queue_at`] and [`Context::lock_queue_at`]: the family's last
    /// queue (an index past the end means the last one).
    pub const RENDER_QUEUE: usize = usize::MAX;

    /// The renderer's queue (graphics + compute, + present for a surface context): the family's last queue.
    pub fn queue(&self) -> vk::Queue {
        self.queue_at(Self::RENDER_QUEUE)
    }

    /// Queue `index` of the family (the last one for an index past the end).
    pub fn queue_at(&self, index: usize) -> vk::Queue {
        self.queues[index.min(self.queues.len() - 1)].handle
    }

    /// How many queues of the family the device has (1 or 2).
    pub fn queue_count(&self) -> usize {
        self.queues.len()
    }

    /// The queues' family index.
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
        // SAFETY: valid physical device of this instance.
        let props = unsafe { self.instance.get_physical_device_properties(self.physical_device) };
        props.device_type == vk::PhysicalDeviceType::CPU
    }

    /// Does the device support `features` for `format` with optimal tiling?
    pub fn format_supports(&self, format: vk::Format, features: vk::FormatFeatureFlags) -> bool {
        // SAFETY: valid physical device of this instance.
        let props = unsafe { self.instance.get_physical_device_format_properties(self.physical_device, format) };
        props.optimal_tiling_features.contains(features)
    }

    /// Validation messages counted so far (always zero when validation is off).
    pub fn validation(&self) -> &ValidationLog {
        &self.log
    }

    /// Is the debug messenger on (the validation layer's messages are counted)?
    pub fn validation_enabled(&self) -> bool {
        self.debug.is_some()
    }

    /// A memory type index with all of `flags` among those allowed by `type_bits`.
    pub(crate) fn memory_type(&self, type_bits: u32, flags: vk::MemoryPropertyFlags) -> Option<u32> {
        (0..self.memory_properties.memory_type_count).find(|&i| {
            type_bits & (1 << i) != 0 && self.memory_properties.memory_types[i as usize].property_flags.contains(flags)
        })
    }

    /// Waits until the device is idle (used before destroying resources); holds every queue's lock meanwhile.
    pub fn wait_idle(&self) -> Result<(), GpuError> {
        let _queues: Vec<MutexGuard<'_, ()>> = (0..self.queues.len()).map(|i| self.lock_queue_at(i)).collect();
        // SAFETY: every queue is locked, as vkDeviceWaitIdle requires.
        unsafe { self.device.device_wait_idle() }.map_err(GpuError::vk("wait for the device"))
    }

    /// Waits until queue `index` is idle (holding its lock).
    pub fn wait_queue_idle(&self, index: usize) -> Result<(), GpuError> {
        let _queue = self.lock_queue_at(index);
        // SAFETY: the queue is locked.
        unsafe { self.device.queue_wait_idle(self.queue_at(index)) }.map_err(GpuError::vk("wait for the queue"))
    }

    /// Locks the renderer's queue for a submission, present or wait from outside the renderer (the renderer takes
    /// the same lock around its own submissions), so several threads can share the queue. Hold it only for the
    /// call.
    pub fn lock_queue(&self) -> MutexGuard<'_, ()> {
        self.lock_queue_at(Self::RENDER_QUEUE)
    }

    /// Locks queue `index` (see [`Context::queue_at`]); hold it around every call that may use that queue,
    /// including the OpenXR calls a runtime may submit from.
    pub fn lock_queue_at(&self, index: usize) -> MutexGuard<'_, ()> {
        self.queues[index.min(self.queues.len() - 1)].lock.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// [`Context::lock_queue_at`], adding the time spent waiting for the lock to `waited`.
    pub fn lock_queue_timed(&self, index: usize, waited: &mut std::time::Duration) -> MutexGuard<'_, ()> {
        let start = std::time::Instant::now();
        let guard = self.lock_queue_at(index);
        *waited += start.elapsed();
        guard
    }
}

impl Drop for Context {
    fn drop(&mut self) {
        let _ = self.wait_idle();
        // SAFETY: everything created from this context holds an Arc to it, so nothing uses the device now.
        unsafe {
            self.device.destroy_device(None);
            destroy_instance(&self.instance, &self.debug);
        }
    }
}

fn pick_device(
    instance: &ash::Instance,
    surface: Option<(&ash::khr::surface::Instance, vk::SurfaceKHR)>,
) -> Result<(vk::PhysicalDevice, u32), GpuError> {
    // SAFETY: `instance` is borrowed for the call, so it is alive (the caller destroys it only after this returns);
    // a read-only query.
    let devices = unsafe { instance.enumerate_physical_devices() }.map_err(GpuError::vk("list the devices"))?;
    let mut best: Option<(u32, vk::PhysicalDevice, u32)> = None;
    let mut rejected = Vec::new();
    for pd in devices {
        // SAFETY: `pd` was just enumerated from this live instance; a read-only query.
        let props = unsafe { instance.get_physical_device_properties(pd) };
        let name = props.device_name_as_c_str().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        if vk::api_version_major(props.api_version) == 1 && vk::api_version_minor(props.api_version) < 2 {
            rejected.push(format!("{name} (Vulkan 1.{} < 1.2)", vk::api_version_minor(props.api_version)));
            continue;
        }
        // SAFETY: the same physical device of the same live instance; a read-only query.
        let families = unsafe { instance.get_physical_device_queue_family_properties(pd) };
        let family = families.iter().enumerate().find_map(|(i, f)| {
            let ok = f.queue_flags.contains(vk::QueueFlags::GRAPHICS | vk::QueueFlags::COMPUTE);
            let present = match surface {
                // SAFETY: `pd`, queue family `i` and the surface `s` all belong to this live instance (the surface is
                // destroyed only after the device is chosen and the context dropped).
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
