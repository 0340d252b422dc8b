//! The one Vulkan platform of r2human (ash): the device ([`Context`], created by us — headless or for a window —
//! or through OpenXR's `XR_KHR_vulkan_enable2` with a [`DeviceFactory`]), resources and submissions
//! ([`resources`], [`commands`]), presentation to a window ([`present`]), and the per-view passes above it
//! ([`Renderer`]): target depth/normal rasterisation of the mesh, flow + Z-map + visibility (paper Eq. 4, 9),
//! warp of colour and of neural features, spatial fusion (Eq. 8), the VR panorama composite and the AR alpha
//! layer. Each pass matches the CPU reference's data contract (see `tests/gpu_parity.rs`).
//!
//! Shaders are GLSL in `shaders/`, compiled to SPIR-V by `build.rs` with naga; nothing is compiled at run time.
//! Everything is allocated when the renderer is created or when an input changes (mesh, source, panorama),
//! never per frame: a frame records one command buffer, submits it and waits on one fence.
//!
//! Validation: set `R2HUMAN_VULKAN_VALIDATION=1` (or [`ContextOptions::validation`]) to enable the Khronos
//! validation layer; its errors and warnings are counted in [`Context::validation`].

pub mod backend;
pub mod commands;
pub mod context;
pub mod devices;
pub mod offline;
pub mod overlay;
pub mod person;
pub mod present;
pub mod renderer;
pub mod resources;
pub mod shaders;

pub use commands::CommandSlot;
pub use context::{Context, ContextOptions, DeviceFactory, ValidationLog, VALIDATION_ENV};
pub use devices::{list_devices, DeviceSummary};
pub use overlay::OverlayMask;
pub use person::{gpu_neural_person, GpuView, NeuralViewError};
pub use present::{Acquired, Swapchain, SwapchainOptions};
pub use renderer::{PresentTarget, Renderer, RendererCounters};

use ash::vk;

/// Errors of the GPU layer. Messages are sentences that say what to do next.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// The Vulkan loader library could not be loaded.
    #[error("Vulkan is not available on this machine ({0}); install a Vulkan driver (e.g. mesa-vulkan-drivers) or use --backend cpu")]
    NoVulkan(String),
    /// No device satisfies the requirements.
    #[error("no usable Vulkan device: {0}; install a Vulkan 1.2 driver (e.g. mesa-vulkan-drivers for lavapipe) or use --backend cpu")]
    NoDevice(String),
    /// Validation was requested but the layer is not installed.
    #[error("the Khronos validation layer was requested ({VALIDATION_ENV}=1) but is not installed; install vulkan-validationlayers or unset {VALIDATION_ENV}")]
    ValidationUnavailable,
    /// The device was lost (driver reset, GPU hang, unplugged).
    #[error("the Vulkan device was lost (driver reset or GPU fault); restart the program")]
    DeviceLost,
    /// The window surface is gone or unusable.
    #[error("the window surface is unusable: {0}")]
    Surface(String),
    /// Out of device or host memory.
    #[error("out of memory on the Vulkan device: {0}; use a smaller output size or --backend cpu")]
    OutOfMemory(String),
    /// A built-in shader was rejected.
    #[error("a built-in shader is invalid: {0}")]
    Shader(String),
    /// Invalid arguments (sizes, empty inputs).
    #[error("{0}")]
    Invalid(String),
    /// The mesh to draw is broken.
    #[error("invalid mesh: {0}")]
    Mesh(#[from] crate::geometry::MeshError),
    /// Any other Vulkan failure.
    #[error("Vulkan call failed while trying to {what}: {result}")]
    Vulkan {
        /// What was being done.
        what: &'static str,
        /// The Vulkan result code.
        result: vk::Result,
    },
}

impl GpuError {
    /// Maps a `vk::Result` to an error, naming the step that failed (device loss and memory exhaustion get
    /// their own variants so callers can react).
    pub fn vk(what: &'static str) -> impl Fn(vk::Result) -> GpuError {
        move |result| match result {
            vk::Result::ERROR_DEVICE_LOST => GpuError::DeviceLost,
            vk::Result::ERROR_OUT_OF_DEVICE_MEMORY | vk::Result::ERROR_OUT_OF_HOST_MEMORY => {
                GpuError::OutOfMemory(format!("while trying to {what}"))
            }
            vk::Result::ERROR_SURFACE_LOST_KHR => GpuError::Surface(format!("surface lost while trying to {what}")),
            _ => GpuError::Vulkan { what, result },
        }
    }
}
