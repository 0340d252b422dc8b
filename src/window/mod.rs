//! Desktop window (winit + Vulkan surface): the mirror view. Filled in by its own issue.
