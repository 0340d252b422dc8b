//! The pipeline layer's error type.

use crate::geometry::fof::FofError;
use crate::geometry::inflate::InflateError;
use crate::neural::NeuralError;

use super::input::InputError;

/// Errors of the pipeline layer.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// The photo or mask cannot be used.
    #[error(transparent)]
    Input(#[from] InputError),
    /// The silhouette-inflation prior failed.
    #[error("cannot build geometry from the mask: {0}")]
    Inflate(#[from] InflateError),
    /// The Fourier occupancy field could not be built.
    #[error("Fourier occupancy field: {0}")]
    Fof(#[from] FofError),
    /// The reconstructed mesh is empty.
    #[error("the reconstructed geometry is empty; the mask may be too thin or fragmented to reconstruct")]
    EmptyGeometry,
    /// A stage produced NaN or infinity (a bug: reported instead of drawing a broken frame).
    #[error("internal error: the {0} stage produced non-finite values; please report this with the input")]
    NonFinite(&'static str),
    /// The neural renderer was requested explicitly and cannot run.
    #[error("neural renderer: {0}")]
    Neural(#[from] NeuralError),
    /// The neural renderer was requested explicitly but no model folder was given or found.
    #[error(
        "neural renderer: no model folder found (looked for models/{0}/encoder.onnx next to the working \
         directory, the executable and the source tree). Pass --models DIR, or use --renderer geometric"
    )]
    NoModels(String),
    /// The FOF network was requested (`--geometry fofnet`) but cannot be used.
    #[error(
        "FOF network: {0}. Pass --models DIR with a fof.onnx (train it with `python -m train fit-fof`, see \
         train/README.md), or use --geometry inflate"
    )]
    NoFofNet(String),
    /// The body prior (`--geometry body`) cannot be used: the pose model or the body model data is missing.
    #[error("body prior: {0}. Install them with `bash scripts/setup.sh`, or use --geometry inflate")]
    NoBody(String),
    /// The FOF network's file is there but cannot be loaded (`--geometry fofnet`): ONNX Runtime is missing, or the
    /// file is corrupt or not a FOF network. Worded as [`PipelineError::NoFofNet`]; the cause is the source.
    #[error(
        "FOF network: {0}. Pass --models DIR with a fof.onnx (train it with `python -m train fit-fof`, see \
         train/README.md), or use --geometry inflate"
    )]
    FofNetLoad(#[source] NeuralError),
    /// The model folder's `placement.onnx` is there but cannot be loaded (`--geometry body-placed`): ONNX Runtime
    /// is missing, or the file is corrupt or not a placement network. The cause is the source.
    #[error(
        "placement network: it does not load. Remove or re-export it (`python -m train export --placement`, see \
         train/README.md), pass --models DIR without it (no placement: the face relief alone), or use --geometry \
         inflate"
    )]
    PlacementLoad(#[source] NeuralError),
    /// The model folder's `placement.onnx` reads another number of FOF coefficients than `--fof-order`.
    #[error(
        "placement network: {0}. Re-export it for this order, pass --models DIR without it (no placement: the face \
         relief alone), or use --geometry inflate"
    )]
    PlacementOrder(String),
    /// The body prior's pose model or body data cannot be loaded (`--geometry body`). Worded as
    /// [`PipelineError::NoBody`]; the cause is the source.
    #[error("body prior: {0}. Install them with `bash scripts/setup.sh`, or use --geometry inflate")]
    BodyLoad(#[source] crate::body::BodyError),
    /// The FOF network (`--geometry fofnet`) failed on this input (a run error or non-finite coefficients).
    #[error(
        "FOF network failed on this input: {0}. Use --geometry auto (falls back to the inflation prior) or inflate"
    )]
    FofNetFailed(#[source] NeuralError),
}
