//! The body prior: the MakeHuman body model (base mesh [`base`], macro morph targets [`morph`], the MPFB2 rig
//! and linear blend skinning [`rig`]) that the synthetic subjects are made of and that the body fitter poses to a
//! photo, and the pose landmarks of the person in a photo ([`pose`]).
//!
//! Run-time data: the base mesh is compiled in (`assets/makehuman/`, CC0); the morph targets and the rig come
//! from PyPI packages that `scripts/setup.d/synth.sh` unpacks into `.tools/` (override with
//! `R2HUMAN_TOOLS_DIR`, see [`tools_dir`]). Missing data is a clear [`BodyError::Asset`], never a silent
//! fallback.

pub mod base;
pub mod distance;
pub mod fit;
pub mod model;
pub mod morph;
pub mod placed;
pub mod pose;
pub mod prior;
pub mod reconcile;
pub mod rig;

use std::path::{Path, PathBuf};

/// Errors of the body layer.
#[derive(Debug, thiserror::Error)]
pub enum BodyError {
    /// Data the body model needs is missing or malformed (names the file and how to install it).
    #[error("{what}: {message}")]
    Asset {
        /// The file or asset.
        what: String,
        /// What is wrong and how to fix it.
        message: String,
    },
    /// The pose landmark model is missing, cannot be loaded or failed on an input (says what to do).
    #[error("pose landmarks: {0}")]
    Model(String),
    /// The fitted body's intervals do not make a valid Fourier occupancy field.
    #[error("pose landmarks: body FOF: {0}")]
    Fof(#[source] crate::geometry::fof::FofError),
    /// The pose landmark model cannot be loaded (ONNX Runtime missing, the file corrupt or unreadable).
    #[error("pose landmarks: {0}")]
    ModelLoad(#[source] crate::neural::NeuralError),
}

/// Where the registry data lives: `$R2HUMAN_TOOLS_DIR`, else `<crate root>/.tools`.
pub fn tools_dir() -> PathBuf {
    std::env::var_os("R2HUMAN_TOOLS_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join(".tools"))
}
