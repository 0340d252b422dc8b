//! Validation-message capture: debug-utils messengers for OpenXR (XR_EXT_debug_utils, which the core validation
//! layer reports through) and Vulkan (VK_EXT_debug_utils, which the Khronos validation layer reports through).
//! Warnings and errors are logged with `tracing` and kept, so a run can report "validation said nothing".

use std::ffi::{c_void, CStr};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use ash::vk;
use openxr as xr;
use xr::sys::Handle as _;

/// How many messages are kept verbatim (the count keeps going).
const KEPT_MESSAGES: usize = 64;

/// Collected validation warnings and errors of one API (OpenXR or Vulkan).
#[derive(Debug, Default)]
pub struct DiagnosticLog {
    count: AtomicUsize,
    messages: Mutex<Vec<String>>,
}

impl DiagnosticLog {
    /// A new, empty log.
    pub fn new() -> Arc<Self> {
        Arc::new(Self::default())
    }

    /// Records one message.
    pub fn push(&self, message: String) {
        self.count.fetch_add(1, Ordering::Relaxed);
        if let Ok(mut kept) = self.messages.lock() {
            if kept.len() < KEPT_MESSAGES {
                kept.push(message);
            }
        }
    }

    /// Number of warnings and errors seen.
    pub fn count(&self) -> usize {
        self.count.load(Ordering::Relaxed)
    }

    /// The first messages (at most 64).
    pub fn messages(&self) -> Vec<String> {
        self.messages.lock().map(|m| m.clone()).unwrap_or_default()
    }
}

/// Reads a possibly-null C string from a callback.
///
/// # Safety
/// `ptr` is null or points to a NUL-terminated string valid for the duration of the call.
unsafe fn c_str(ptr: *const std::ffi::c_char) -> String {
    if ptr.is_null() {
        String::new()
    } else {
        // SAFETY: non-null and NUL-terminated by the caller's contract.
        unsafe { CStr::from_ptr(ptr) }.to_string_lossy().into_owned()
    }
}

/// The Vulkan debug-utils callback: records warnings and errors into the [`DiagnosticLog`] in `user_data`.
pub(crate) unsafe extern "system" fn vulkan_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user_data: *mut c_void,
) -> vk::Bool32 {
    if data.is_null() || user_data.is_null() {
        return vk::FALSE;
    }
    // SAFETY: the loader passes valid callback data; user_data is the Arc<DiagnosticLog> pointer registered in
    // `VulkanContext`, which outlives the messenger.
    let (text, log) = unsafe { (c_str((*data).p_message), &*(user_data as *const DiagnosticLog)) };
    if severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR) {
        tracing::error!(target: "vulkan", "{text}");
    } else {
        tracing::warn!(target: "vulkan", "{text}");
    }
    log.push(text);
    vk::FALSE
}

/// The OpenXR debug-utils callback: records warnings and errors into the [`DiagnosticLog`] in `user_data`.
unsafe extern "system" fn openxr_callback(
    severity: xr::sys::DebugUtilsMessageSeverityFlagsEXT,
    _types: xr::sys::DebugUtilsMessageTypeFlagsEXT,
    data: *const xr::sys::DebugUtilsMessengerCallbackDataEXT,
    user_data: *mut c_void,
) -> xr::sys::Bool32 {
    if data.is_null() || user_data.is_null() {
        return xr::sys::FALSE;
    }
    // SAFETY: as in `vulkan_callback`; the log outlives the messenger (see `XrMessenger`).
    let (function, text, log) =
        unsafe { (c_str((*data).function_name), c_str((*data).message), &*(user_data as *const DiagnosticLog)) };
    let line = format!("{function}: {text}");
    if severity.contains(xr::sys::DebugUtilsMessageSeverityFlagsEXT::ERROR) {
        tracing::error!(target: "openxr", "{line}");
    } else {
        tracing::warn!(target: "openxr", "{line}");
    }
    log.push(line);
    xr::sys::FALSE
}

/// An OpenXR debug-utils messenger feeding a [`DiagnosticLog`]; destroyed on drop (before the instance).
pub struct XrMessenger {
    handle: xr::sys::DebugUtilsMessengerEXT,
    destroy: xr::sys::pfn::DestroyDebugUtilsMessengerEXT,
    _log: Arc<DiagnosticLog>,
}

impl XrMessenger {
    /// Creates the messenger when XR_EXT_debug_utils is enabled on `instance`; `None` otherwise.
    pub fn new(instance: &xr::Instance, log: Arc<DiagnosticLog>) -> Option<Self> {
        let ext = instance.exts().ext_debug_utils.as_ref()?;
        let info = xr::sys::DebugUtilsMessengerCreateInfoEXT {
            ty: xr::sys::DebugUtilsMessengerCreateInfoEXT::TYPE,
            next: std::ptr::null(),
            message_severities: xr::sys::DebugUtilsMessageSeverityFlagsEXT::WARNING
                | xr::sys::DebugUtilsMessageSeverityFlagsEXT::ERROR,
            message_types: xr::sys::DebugUtilsMessageTypeFlagsEXT::GENERAL
                | xr::sys::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                | xr::sys::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE
                | xr::sys::DebugUtilsMessageTypeFlagsEXT::CONFORMANCE,
            user_callback: Some(openxr_callback),
            user_data: Arc::as_ptr(&log) as *mut c_void,
        };
        let mut handle = xr::sys::DebugUtilsMessengerEXT::NULL;
        // SAFETY: valid instance and create info; the callback's user data is kept alive by `_log`.
        let result = unsafe { (ext.create_debug_utils_messenger)(instance.as_raw(), &info, &mut handle) };
        if result.into_raw() < 0 {
            tracing::warn!("xrCreateDebugUtilsMessengerEXT failed: {result}; OpenXR validation output is not captured");
            return None;
        }
        Some(Self { handle, destroy: ext.destroy_debug_utils_messenger, _log: log })
    }
}

impl Drop for XrMessenger {
    fn drop(&mut self) {
        // SAFETY: the handle was created by `new` and the instance is still alive (the owner drops this first).
        unsafe { (self.destroy)(self.handle) };
    }
}
