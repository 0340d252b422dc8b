//! Ground truth and evaluation: rendering known views of synthetic subjects and scans ([`ground_truth`]) and
//! writing them as a dataset ([`dataset`]), the error metrics ([`metrics`]), the method comparison ([`runner`]), its
//! summary over several scans with a dev / held-out split ([`scans`]), the ground-truth-free checks on real photos
//! ([`photos`]) and the turning clips played through the live frame path ([`turn`]).

pub mod dataset;
pub mod ground_truth;
pub mod memory;
pub mod metrics;
pub mod photos;
pub mod plausible;
pub mod runner;
pub mod scans;
pub mod turn;

use std::path::{Path, PathBuf};

/// Errors of the eval layer.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// Options out of range.
    #[error("invalid options: {0}")]
    InvalidOptions(String),
    /// `body_fof.npy` was asked for but the body prior cannot be loaded.
    #[error("invalid options: body_fof.npy needs the body prior: {0} (or pass --no-body-fof)")]
    NoBodyPrior(#[source] crate::pipeline::PipelineError),
    /// Subject generation or scan loading failed.
    #[error(transparent)]
    Synth(#[from] crate::synth::SynthError),
    /// A file or folder could not be written or read.
    #[error("{path}: {message}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// What failed.
        message: String,
    },
    /// A stage failed on an input (`stage`: e.g. `ground-truth FOF`, `inflation prior`, `rendering`).
    #[error("{stage}: {message}")]
    Stage {
        /// Which stage.
        stage: &'static str,
        /// Why.
        message: String,
    },
    /// A photo could not be read or segmented ([`crate::capture::segment::segment_photo`]).
    #[error("{path}: {source}")]
    Photo {
        /// The photo.
        path: PathBuf,
        /// Why.
        source: Box<crate::capture::segment::PhotoError>,
    },
    /// A method of the photo checks failed on a photo (geometry, mesh, encoder or rendering).
    #[error("{path}: {method}: {source}")]
    Method {
        /// The photo, as named in the report.
        path: PathBuf,
        /// The method's label.
        method: String,
        /// The pipeline's or the network's error.
        source: Box<dyn std::error::Error + Send + Sync + 'static>,
    },
    /// No subject could be written.
    #[error("every subject failed; the first error was {0}")]
    AllFailed(String),
}

impl EvalError {
    /// `stage` failed for the reason `e`.
    pub fn stage(stage: &'static str, e: impl std::fmt::Display) -> Self {
        EvalError::Stage { stage, message: e.to_string() }
    }

    /// An I/O error on `path`.
    pub fn io(path: &Path, e: std::io::Error) -> Self {
        EvalError::Io { path: path.to_path_buf(), message: e.to_string() }
    }
}
