//! r2human: real-time novel-view rendering of a person from one photo, after R²Human (ISMAR 2024).
//!
//! One input frame is segmented, normalised into the body cube, turned into geometry (a Fourier occupancy
//! field, then a mesh) and — with a neural model — into encoder features. Each view (an orbit camera, a
//! desktop window or an XR eye) then rasterises target depth and normals, computes the flow and Z-map of
//! paper Eq. 4, warps the source appearance, fuses with the previous view (Eq. 8) and composites the person
//! into a panorama (VR) or a premultiplied alpha layer (AR).
//!
//! Layers (dependencies point downward only):
//! - [`cli`]: command-line commands; no algorithm lives there.
//! - [`app`]: live loops (desktop mirror, XR session, capture) that schedule the pipeline.
//! - [`xr`], [`gpu`], [`window`]: OpenXR client, the Vulkan renderer and the desktop window.
//! - [`pipeline`]: the stages as plain functions over images, with the CPU reference for each.
//! - [`neural`], [`geometry`], [`compose`], [`io`], [`eval`], [`synth`], [`capture`]: the building blocks.
//! - [`body`] (beside [`geometry`]): the MakeHuman body model the synthetic subjects and the body prior share.
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
