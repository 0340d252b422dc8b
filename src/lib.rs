//! r2human: real-time novel-view rendering of a person from one photo, after R²Human (ISMAR 2024).
//!
//! One input frame is segmented, normalised into the body cube, turned into geometry (a Fourier occupancy
//! field, then a mesh) and — with a neural model — into encoder features. Each view (an orbit camera, a
//! desktop window or an XR eye) then rasterises target depth and normals, computes the flow and Z-map of
//! paper Eq. 4, warps the source appearance, fuses with the previous view (Eq. 8) and composites the person
//! into a panorama (VR) or a premultiplied alpha layer (AR).
//!
//! Layers (dependencies point downward only; the layer table of docs/architecture.md is the reference, and
//! `tests/layers.rs` checks the imports against it):
//! - [`cli`]: command-line commands; no algorithm lives there.
//! - [`app`]: the use cases (offline render, the `view` window, the XR session, live capture).
//! - [`xr`], [`window`], [`gpu`]: the OpenXR client, the XR desktop mirror window, and the one Vulkan platform
//!   (device, presentation, the renderer).
//! - [`eval`]: error against run time per method.
//! - [`pipeline`], [`synth`]: the stages as plain functions over images, with the CPU reference for each, and the
//!   person-renderer seam; procedural subjects.
//! - [`body`], [`capture`], [`compose`], then [`io`], [`neural`], then [`geometry`]: the building blocks.
//! - [`buffer`]: the 2-D image buffer every stage passes around.
//! - `fuzzing` (hidden): the loaders' fuzz targets, shared by `tests/fuzz.rs` and the `cargo fuzz` crate in `fuzz/`.

pub mod app;
pub mod body;
pub mod buffer;
pub mod capture;
pub mod cli;
pub mod compose;
pub mod eval;
#[doc(hidden)]
pub mod fuzzing;
pub mod geometry;
pub mod gpu;
pub mod io;
pub mod neural;
pub mod pipeline;
pub mod synth;
pub mod window;
pub mod xr;
