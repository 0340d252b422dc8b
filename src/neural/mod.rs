//! Neural rendering through ONNX Runtime: the R²Human encoder, the Z-map decoder and the FOF network.
//!
//! # The three models (all NCHW `float32`, batch 1; see `train/README.md` for how they are trained)
//! | file | inputs | output |
//! | --- | --- | --- |
//! | `fof.onnx` (optional) | as `r2human.fof_inputs` names: `image` `[1,3,R,R]` (optional), `body` and/or `prior` `[1,N,R,R]` | `fof` `[1,N,R,R]` |
//! | `encoder.onnx` | `image` `[1,3,R,R]`, `fof` `[1,N,R,R]`, `normals` `[1,3,R,R]` | `features` `[1,C,R/4,R/4]` |
//! | `decoder.onnx` | `features` `[1,C,h,w]`, `zmap` `[1,1,h,w]`, `normals` `[1,3,h,w]`, `warped_rgb` `[1,3,h,w]` | `rgb` `[1,3,h,w]` |
//! | `placement.onnx` (optional) | `body`, `prior` `[1,N,R,R]` | `shift` `[1,1,R,R]` |
//!
//! - `image` is the source photo in the networks' colour space, **sRGB-encoded** and premultiplied by the mask, mapped
//!   to `[-1, 1]` (`image*2-1`, so the background is `-1`), exactly as the reference feeds its encoder.
//! - `normals` are view-space unit normals (zero in the background); `fof` holds FOF-X coefficients (zero in the
//!   background; zeros everywhere when no FOF is known, like the reference's test script).
//! - `zmap` is the raw source-view z of every target pixel (paper Eq. 4), zero in the background; the decoder graph
//!   itself expands it into `cos(n*pi*z), sin(n*pi*z)`, `n = 1..16` (so the paper tier's first convolution sees
//!   `256 + 32 + 3 = 291` channels).
//! - `warped_rgb` is the geometric renderer's colour lookup at full target resolution: the source photo sampled at
//!   the flow with the mask-aware bilinear sample (`sum(w*c)/sum(w*m)` over the four taps, in linear light),
//!   clamped, sRGB-encoded and mapped to `[-1, 1]`; `0` where the flow lands outside the source silhouette or the
//!   pixel is background ([`crate::pipeline::photo_lookup`]; `train/geometry.py` `warp_rgb` computes the same).
//!   With the default fill ([`crate::pipeline::warp::OcclusionFill::Back`]) and an input that has a back image,
//!   surfaces facing away from the source camera take the back image instead of the photo, exactly as the
//!   geometric renderer does ([`crate::pipeline::neural_back_lookup`]); `models/tiny` was trained on the photo
//!   alone (docs/rendering.md, "What the photo does not show", has what that costs).
//!   The decoder is **residual**: its graph outputs `warped_rgb + UNet(...)`, trained from a zero-initialised last
//!   convolution, so an untrained decoder is the geometric renderer's `MirroredFront` lookup (without the
//!   visibility test) and training adds occlusion, back-side and shading corrections. This deviates from the paper
//!   on purpose: the `tiny` tier sees encoder features at 1/4 resolution only, and the skip keeps the photo's
//!   full-resolution texture. A decoder of the earlier three-input contract is rejected at load, naming the
//!   missing `warped_rgb`. (It is not called `rgb` because ONNX value names are unique and `rgb` is the output.)
//! - `rgb` is sRGB in `[-1, 1]`; [`Decoder`] turns it into linear premultiplied RGBA with the target mask as alpha.
//! - The FOF net's inputs (`r2human.fof_inputs`, e.g. `image,body,prior`, or `body,prior` for a net that sees
//!   geometry only, as the shipped one does; files without the key take `image` and `prior` when they have it):
//!   `prior` is the silhouette-inflation FOF and `body` the fitted body's FOF (the body prior, as `--geometry body`
//!   computes it: the reference FOF net's input), each box-averaged to `R`. The net
//!   is residual on one of them (`r2human.residual`; `fof = base + UNet(...)`, zero-initialised last convolution),
//!   and [`FofNet::refine_with`] applies its correction to that base at full resolution (the pipeline's
//!   `--geometry fofnet|auto`).
//! - The placement net ([`PlacementNet`], `train/placement.py`) reads the same two FOFs and outputs the depth (body
//!   cube z) by which each column of the inflation prior moves (`--geometry body-placed`, [`crate::body::placed`]).
//!
//! Every model carries metadata (`r2human.kind`, `r2human.tier`, `r2human.resolution`, `r2human.fof_n`,
//! `r2human.recipe`, …, see [`ModelInfo`]) that is checked at load, together with the input and output names and
//! shapes; a mismatch is an error that names it. A model whose output is not finite is an error
//! ([`NeuralError::NonFinite`]), never a silent black frame: the caller falls back to the geometric renderer.
//!
//! # Runtime
//! The ONNX Runtime library is loaded at run time (`ort` with `load-dynamic`): from `ORT_DYLIB_PATH`, else from the
//! project's `.tools/onnxruntime-gpu` (the GPU build, installed by `bash scripts/setup.sh --gpu`), else from its
//! `.tools/onnxruntime` (the CPU build, `scripts/setup.d/neural.sh`). With the GPU build, the CUDA / cuDNN /
//! TensorRT libraries of its tree are opened by path before a GPU provider is registered ([`preload`]). Execution
//! providers are chosen with [`ExecutionProvider`] (`--ep auto|tensorrt|cuda|cpu`); one that fails to register
//! falls back to the next with a warning. [`runtime_report`] (`r2human doctor`) says which providers work here and
//! why the others do not.

mod gpu_libs;
mod library;
mod model;
mod nets;
mod provider;
mod report;
mod tensor;

use std::path::{Path, PathBuf};

pub use gpu_libs::{
    preload, system_has, Found, GpuManifest, NeededLibrary, PreloadReport, GPU_MANIFEST_FILE, GPU_TOOLS_SUBDIR,
};
pub(crate) use library::project_roots;
pub use library::{find_library, library_candidates, ORT_LIBRARY_FILE, ORT_TOOLS_SUBDIR};
pub use model::{ModelInfo, ModelKind, FORMAT_VERSION};
pub use nets::{Decoder, Encoder, EncoderInput, FofInput, FofNet, FofPrediction, PlacementNet, DECODER_INPUTS};
pub(crate) use provider::create_session;
pub use provider::{
    default_trt_cache, environment, loaded_library, ActiveProvider, ExecutionProvider, RuntimeOptions, TRT_CACHE_SUBDIR,
};
pub use report::{classify_failure, runtime_report, ProviderCheck, ProviderStatus, RuntimeReport};
pub use tensor::{Coefficients, FeatureMap, PixelBox};

/// Errors of the neural layer. Every message says what went wrong and what to do about it.
#[derive(Debug, thiserror::Error)]
pub enum NeuralError {
    /// No ONNX Runtime library was found.
    #[error(
        "ONNX Runtime library not found (looked for {}). Install it with `bash scripts/setup.d/neural.sh` \
         (CPU, from the PyPI wheel onnxruntime 1.31.1) or point ORT_DYLIB_PATH at libonnxruntime.so.1.31.1 \
         (GPU: from the onnxruntime-gpu 1.31.1 wheel)",
        .searched.iter().map(|p| format!("`{}`", p.display())).collect::<Vec<_>>().join(", ")
    )]
    LibraryNotFound {
        /// Every path that was tried.
        searched: Vec<PathBuf>,
    },
    /// The library exists but could not be loaded or is the wrong version.
    #[error("could not load ONNX Runtime from `{path}`: {reason}. Reinstall it with `bash scripts/setup.d/neural.sh` or set ORT_DYLIB_PATH to an ONNX Runtime 1.31 library")]
    LibraryLoad {
        /// The library path.
        path: PathBuf,
        /// What the loader said.
        reason: String,
    },
    /// A required model file is missing.
    #[error("model file `{path}` does not exist. Train or copy the models (see train/README.md), or run without the neural renderer")]
    ModelMissing {
        /// The missing file.
        path: PathBuf,
    },
    /// ONNX Runtime could not open the model (corrupt or not an ONNX file).
    #[error("could not load model `{path}`: {reason}. The file is corrupt or not an ONNX model: re-export it with `python -m train export`")]
    ModelLoad {
        /// The model file.
        path: PathBuf,
        /// What ONNX Runtime said.
        reason: String,
    },
    /// A metadata entry is missing or does not match.
    #[error("model `{path}`: metadata `{key}` {problem}. Re-export the model with `python -m train export`, which writes r2human metadata")]
    Metadata {
        /// The model file.
        path: PathBuf,
        /// The metadata key.
        key: String,
        /// What is wrong with it.
        problem: String,
    },
    /// A model input or output does not have the expected name, type or shape.
    #[error("model `{path}`: {problem}")]
    Signature {
        /// The model file.
        path: PathBuf,
        /// The mismatch, naming the tensor and both shapes.
        problem: String,
    },
    /// Two models of one set disagree (tier, resolution, FOF N, feature channels).
    #[error(
        "models in `{dir}` do not belong together: {problem}. Export encoder and decoder from the same training run"
    )]
    Inconsistent {
        /// The model folder.
        dir: PathBuf,
        /// Which values disagree.
        problem: String,
    },
    /// The caller passed tensors of the wrong size.
    #[error("bad input to the {model}: {problem}")]
    BadInput {
        /// Which model.
        model: &'static str,
        /// What is wrong.
        problem: String,
    },
    /// A network's output does not make a valid Fourier occupancy field.
    #[error("bad input to the {model}: {source}")]
    BadFof {
        /// Which model.
        model: &'static str,
        /// What is wrong with the field.
        source: crate::geometry::fof::FofError,
    },
    /// ONNX Runtime failed while running a model.
    #[error("running the {model} failed: {reason}")]
    Run {
        /// Which model.
        model: &'static str,
        /// What ONNX Runtime said.
        reason: String,
    },
    /// The model produced NaN or infinite values.
    #[error("the {model} produced {count} non-finite values out of {total}; the model is broken (falling back to the geometric renderer is safe)")]
    NonFinite {
        /// Which model.
        model: &'static str,
        /// Number of NaN/inf values.
        count: usize,
        /// Number of values.
        total: usize,
    },
    /// The GPU tree's library manifest (`scripts/setup-gpu.sh`) has a line that does not parse.
    #[error("{path}, line {line}: {problem}. Rewrite it with `bash scripts/setup-gpu.sh`")]
    GpuManifest {
        /// The manifest file.
        path: PathBuf,
        /// The line (1-based).
        line: usize,
        /// What is wrong with it.
        problem: String,
    },
    /// A GPU runtime library of the manifest could not be opened.
    #[error("cannot open the GPU runtime library {path}: {reason}")]
    GpuLibraryOpen {
        /// The library file.
        path: PathBuf,
        /// The dynamic loader's message (it names a library that is missing).
        reason: String,
    },
    /// The GPU tree's library manifest exists but cannot be read.
    #[error("cannot read {path}: {source}. Rewrite it with `bash scripts/setup-gpu.sh`")]
    GpuManifestRead {
        /// The manifest file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
}

/// The model files of one set, inside a model folder such as `models/tiny`.
pub const ENCODER_FILE: &str = "encoder.onnx";
/// The decoder's file name inside a model folder.
pub const DECODER_FILE: &str = "decoder.onnx";
/// The (optional) FOF network's file name inside a model folder.
pub const FOF_FILE: &str = "fof.onnx";
/// File name of the placement network in a model folder (optional; [`PlacementNet`]).
pub const PLACEMENT_FILE: &str = "placement.onnx";

/// Encoder, decoder and (when present) FOF network of one model folder, loaded and checked against each other.
pub struct NeuralRuntime {
    /// Runs once per input frame.
    pub encoder: Encoder,
    /// Runs once per view.
    pub decoder: Decoder,
    /// Predicts FOF coefficients from the photo; `None` when the folder has no `fof.onnx`.
    pub fof: Option<FofNet>,
    /// The folder the models came from.
    pub dir: PathBuf,
}

impl NeuralRuntime {
    /// Loads `encoder.onnx`, `decoder.onnx` and, if present, `fof.onnx` from `dir`, checks their metadata and
    /// signatures and that they agree (tier, resolution, FOF N, feature channels).
    pub fn load(dir: &Path, options: &RuntimeOptions) -> Result<Self, NeuralError> {
        let encoder = Encoder::load(&dir.join(ENCODER_FILE), options)?;
        let decoder = Decoder::load(&dir.join(DECODER_FILE), options)?;
        let fof_path = dir.join(FOF_FILE);
        let fof = if fof_path.exists() { Some(FofNet::load(&fof_path, options)?) } else { None };
        let inconsistent = |problem: String| NeuralError::Inconsistent { dir: dir.to_path_buf(), problem };
        let (e, d) = (encoder.info(), decoder.info());
        if e.tier != d.tier {
            return Err(inconsistent(format!("encoder tier `{}` but decoder tier `{}`", e.tier, d.tier)));
        }
        if e.feature_channels != d.feature_channels {
            return Err(inconsistent(format!(
                "encoder outputs {} feature channels but the decoder takes {}",
                e.feature_channels, d.feature_channels
            )));
        }
        if e.resolution != d.resolution {
            return Err(inconsistent(format!(
                "encoder trained at {} px but decoder at {} px",
                e.resolution, d.resolution
            )));
        }
        if let Some(f) = &fof {
            if f.info().fof_n != e.fof_n {
                return Err(inconsistent(format!(
                    "the FOF net predicts {} coefficients but the encoder takes {}",
                    f.info().fof_n,
                    e.fof_n
                )));
            }
        }
        Ok(Self { encoder, decoder, fof, dir: dir.to_path_buf() })
    }

    /// Like [`NeuralRuntime::load`], but a missing library or model is not an error: it logs one warning that says
    /// how to enable the neural renderer and returns `None`, so the caller runs the geometric renderer.
    pub fn load_or_warn(dir: &Path, options: &RuntimeOptions) -> Option<Self> {
        match Self::load(dir, options) {
            Ok(runtime) => Some(runtime),
            Err(e) => {
                tracing::warn!("neural renderer disabled, using the geometric renderer: {e}");
                None
            }
        }
    }
}

/// The project's model folder for a tier (`models/<tier>`), searched next to the current directory, the executable
/// and the crate's source tree, or `None` when none has an encoder.
pub fn default_model_dir(tier: &str) -> Option<PathBuf> {
    library::project_roots()
        .into_iter()
        .map(|root| root.join("models").join(tier))
        .find(|dir| dir.join(ENCODER_FILE).is_file())
}
