//! Desktop windows on winit: the XR desktop mirror ([`mirror`]: both eye images side by side while an OpenXR
//! session runs). Presentation goes through the one Vulkan swapchain module, [`crate::gpu::present`], which also
//! serves the `view` window (its loop is [`crate::app::window`]).

pub mod mirror;
