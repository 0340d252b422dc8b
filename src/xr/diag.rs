//! OpenXR validation-message capture: a debug-utils messenger (XR_EXT_debug_utils, which the core validation layer
//! reports through) feeding the same [`ValidationLog`] type the Vulkan device keeps (`crate::gpu::Context::
//! validation`). Warnings and errors are logged with `tracing` and kept, so a run can report "validation said
//! nothing".

use std::ffi::{c_void, CStr};
use std::sync::Arc;

use openxr as xr;
use xr::sys::Handle as _;

pub use crate::gpu::ValidationLog;

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

/// The OpenXR debug-utils callback: records warnings and errors into the [`ValidationLog`] in `user_data`.
///
/// # Safety
/// Called by the runtime only: `data` is null or valid for the call, `user_data` is null or the `ValidationLog`
/// registered with the messenger (alive while the messenger is).
unsafe extern "system" fn openxr_callback(
    severity: xr::sys::DebugUtilsMessageSeverityFlagsEXT,
    _types: xr::sys::DebugUtilsMessageTypeFlagsEXT,
    data: *const xr::sys::DebugUtilsMessengerCallbackDataEXT,
    user_data: *mut c_void,
) -> xr::sys::Bool32 {
    if data.is_null() || user_data.is_null() {
        return xr::sys::FALSE;
    }
    // SAFETY: the runtime passes valid callback data for the duration of the call; user_data is the
    // Arc<ValidationLog> registered in `XrMessenger::new`, which keeps it alive as long as the messenger.
    let (function, text, log) =
        unsafe { (c_str((*data).function_name), c_str((*data).message), &*(user_data as *const ValidationLog)) };
    let line = format!("{function}: {text}");
    let error = severity.contains(xr::sys::DebugUtilsMessageSeverityFlagsEXT::ERROR);
    if error {
        tracing::error!(target: "openxr", "{line}");
    } else {
        tracing::warn!(target: "openxr", "{line}");
    }
    log.record(error, line);
    xr::sys::FALSE
}

/// An OpenXR debug-utils messenger feeding a [`ValidationLog`]; destroyed on drop (before the instance).
pub struct XrMessenger {
    handle: xr::sys::DebugUtilsMessengerEXT,
    destroy: xr::sys::pfn::DestroyDebugUtilsMessengerEXT,
    _log: Arc<ValidationLog>,
}

impl XrMessenger {
    /// Creates the messenger when XR_EXT_debug_utils is enabled on `instance`; `None` otherwise.
    pub fn new(instance: &xr::Instance, log: Arc<ValidationLog>) -> Option<Self> {
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
