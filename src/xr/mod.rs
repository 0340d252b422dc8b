//! OpenXR client (XR_KHR_vulkan_enable2 on ash): runtime discovery ([`check`]), the Vulkan device the runtime
//! asks for, created as the one [`crate::gpu::Context`] type ([`device`]), the per-eye swapchains filled on the GPU
//! ([`swapchain`]), the session state machine and frame loop ([`session`]), the placement of the person in the
//! room ([`placement`]), the per-eye Vulkan renderers ([`eyes`]), the render thread that keeps the display loop
//! from ever waiting on them ([`pacing`]) and the OpenXR validation messenger ([`diag`]). Everything Vulkan that
//! is not OpenXR-specific (device, validation log, queue locks, the mirror's swapchain) is [`crate::gpu`]'s; the
//! desktop mirror window is [`crate::window::mirror`].
//!
//! The eyes are rendered by [`crate::gpu::Renderer`] (one per eye) from a [`crate::pipeline::Scene`] — the
//! person's mesh and source view, uploaded once per input frame from a [`SceneFeed`] (a still photo, or a live
//! source in the app layer). No eye image passes through the CPU on its way to the headset.

pub mod check;
pub mod device;
pub mod diag;
pub mod eyes;
pub mod pacing;
pub mod placement;
pub mod session;
pub mod swapchain;

pub use check::{check_runtime, RuntimeReport};
pub use eyes::{GpuEyes, NeuralEyeStats, SceneFeed, StaticScene};
pub use pacing::{EyeError, EyeRenderer, EyeRequest};
pub use placement::{Controls, Placement};
pub use session::{
    run_session, BlendChoice, EndReason, ExportFailure, ExportHook, EyeCapture, PersonExporter, SessionConfig,
    SessionReport,
};

use openxr as xr;

/// Everything that can go wrong in the OpenXR client. Each message says what to do next.
#[derive(Debug, thiserror::Error)]
pub enum XrError {
    /// The OpenXR loader library is not installed.
    #[error(
        "no OpenXR loader found ({0}): install the OpenXR loader and a runtime, e.g. on Debian/Ubuntu \
         `apt install libopenxr-loader1 monado-service libopenxr1-monado`"
    )]
    LoaderMissing(String),
    /// The loader is there but no runtime is active.
    #[error(
        "the OpenXR loader found no active runtime: install one (e.g. Monado: `apt install monado-service \
         libopenxr1-monado`), start it (`monado-service`), or point XR_RUNTIME_JSON at its manifest"
    )]
    RuntimeUnavailable,
    /// The runtime is installed but could not be reached (its service is not running).
    #[error(
        "the OpenXR runtime is installed but not running ({0}): start it (for Monado: `monado-service`) and retry"
    )]
    RuntimeNotRunning(xr::sys::Result),
    /// The runtime is there but no headset is connected.
    #[error("the OpenXR runtime reports no head-mounted display: connect and switch on the headset, then retry")]
    NoHeadset,
    /// A required extension is missing from the runtime.
    #[error("the OpenXR runtime does not offer {0}, which r2human needs: use a runtime with Vulkan support")]
    MissingExtension(&'static str),
    /// An OpenXR call failed.
    #[error("OpenXR call {call} failed: {result}")]
    Openxr {
        /// The OpenXR function that failed.
        call: &'static str,
        /// Its result code.
        result: xr::sys::Result,
    },
    /// The Vulkan device (no loader, no usable device, a failed call, a lost device, the mirror's window).
    #[error(transparent)]
    Gpu(#[from] crate::gpu::GpuError),
    /// The runtime or device cannot do something r2human needs.
    #[error("unsupported by the OpenXR runtime or Vulkan device: {0}")]
    Unsupported(String),
    /// The person renderer failed.
    #[error("rendering an eye image failed: {0}")]
    Render(String),
    /// The GPU person renderer for the eyes cannot be set up.
    #[error("rendering an eye image failed: cannot set up the GPU renderer: {0}")]
    RenderSetup(#[source] crate::gpu::GpuError),
}

/// Adds the name of the failing OpenXR call to an `openxr` result.
pub(crate) trait XrContext<T> {
    /// Maps the error to [`XrError::Openxr`] naming `call`.
    fn xr(self, call: &'static str) -> Result<T, XrError>;
}

impl<T> XrContext<T> for Result<T, xr::sys::Result> {
    fn xr(self, call: &'static str) -> Result<T, XrError> {
        self.map_err(|result| match result {
            xr::sys::Result::ERROR_RUNTIME_UNAVAILABLE => XrError::RuntimeUnavailable,
            xr::sys::Result::ERROR_FORM_FACTOR_UNAVAILABLE => XrError::NoHeadset,
            xr::sys::Result::ERROR_RUNTIME_FAILURE
            | xr::sys::Result::ERROR_INSTANCE_LOST
            | xr::sys::Result::ERROR_INITIALIZATION_FAILED
                if call == "xrCreateInstance" =>
            {
                XrError::RuntimeNotRunning(result)
            }
            result => XrError::Openxr { call, result },
        })
    }
}

/// Loads the OpenXR loader library, turning "not installed" into [`XrError::LoaderMissing`].
pub fn load_entry() -> Result<xr::Entry, XrError> {
    // SAFETY: the library loaded is the system's OpenXR loader, which implements the OpenXR ABI.
    unsafe { xr::Entry::load(&()) }.map_err(|e| match e {
        xr::EntryError::Load(inner) => XrError::LoaderMissing(format!("libopenxr_loader.so.1: {inner}")),
        xr::EntryError::Xr(result) => XrError::Openxr { call: "xrInitializeLoaderKHR", result },
    })
}
