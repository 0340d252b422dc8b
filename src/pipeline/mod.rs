//! The per-input and per-view stages as plain functions over images, each with its CPU reference, and the objects
//! that schedule them. One file per concern:
//!
//! | file | what |
//! |---|---|
//! | [`prepared`] | [`PreparedInput`]: what one input frame becomes before any view (normalised photo, geometry, mesh, source view, back and side images); [`PrepareOptions`], [`StageTimings`] |
//! | [`still`] | **the still path** ([`PreparedInput::prepare`]): geometry as a Fourier occupancy field → marching cubes → source raster; the back image beside it |
//! | [`frame`] | **the frame path** ([`frame::FramePath`]): for video and camera frames, the one-shell geometry's depth maps become the mesh and the source view directly; slow parts (pose read, face, back face) at their own rate |
//! | [`geometry`] | which geometry a mode draws ([`GeometryMode`], [`AUTO_CHOICE`], [`FRAMES_AUTO_CHOICE`]) and how each is computed |
//! | [`models`] | loading the geometry's networks (FOF net, placement net, body prior, the back image's pose network) |
//! | [`view`] | [`ViewRenderer`]: per view, target raster → flow/Z-map/visibility → warp or decoder → spatial fusion |
//! | [`neural`] | the neural renderer on the CPU: encoder once per input, residual decoder per view, the lookup it keeps |
//! | [`person`] | the person-renderer seam shared with the Vulkan renderer ([`SourceView`], [`NeuralPolicy`]) |
//! | [`error`] | [`PipelineError`] |
//! | [`input`], [`warp`], [`fusion`], [`back`], [`guard`], [`export`] | normalisation, the geometric warp and fills, spatial fusion (Eq. 8), the back image, the FOF net's guard, glTF export |
//!
//! Two renderers draw the person ([`RendererChoice`]): the geometric warp ([`warp::render_geometric`]) and the
//! neural one ([`NeuralRenderer`]). Spatial fusion applies to both. A decoder failure or non-finite output on a
//! view logs a warning and that view is drawn by the geometric renderer: never a black frame.

pub mod back;
pub mod error;
pub mod export;
pub mod frame;
pub mod fusion;
pub mod geometry;
pub mod guard;
pub mod input;
pub mod models;
pub mod neural;
pub mod person;
pub mod person_model;
pub mod prepared;
pub mod still;
pub mod view;
pub mod warp;

pub use error::PipelineError;
pub use geometry::*;
pub use models::*;
pub use neural::*;
pub use person::{
    Drawn, Neural, NeuralCounters, NeuralPolicy, NeuralRef, NeuralRequest, NeuralViewTimes, PersonBackend, Scene,
    SceneNeural, SourceView,
};
pub use prepared::{mesh_for_view, CoarseMesh, PrepareOptions, PreparedInput, StageTimings, ViewMesh};
pub use still::*;
pub use view::{CpuView, ViewRenderer};
