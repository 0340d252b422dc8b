//! Model metadata (`r2human.*` keys written by `train/`'s exporter) and signature checks.

use std::path::{Path, PathBuf};

use ort::session::Session;
use ort::value::{TensorElementType, ValueType};

use super::NeuralError;

/// The metadata format version this build reads (`r2human.format`).
pub const FORMAT_VERSION: u32 = 1;

/// Which of the three networks a file holds (`r2human.kind`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModelKind {
    /// Photo (+ prior) to FOF coefficients: `fof`.
    Fof,
    /// Photo + FOF + normals to features at 1/4 resolution: `encoder`.
    Encoder,
    /// Warped features + Z-map + target normals to RGB: `decoder`.
    Decoder,
    /// Body FOF + inflation prior to a depth shift per column of the prior: `placement`.
    Placement,
}

impl ModelKind {
    /// The metadata value.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Fof => "fof",
            Self::Encoder => "encoder",
            Self::Decoder => "decoder",
            Self::Placement => "placement",
        }
    }
}

/// The metadata of one model, read from its ONNX `metadata_props`.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelInfo {
    /// Which network (`r2human.kind`).
    pub kind: ModelKind,
    /// Size tier: `tiny`, `small` or `paper` (`r2human.tier`).
    pub tier: String,
    /// Side of the square source image the model was trained at (`r2human.resolution`).
    pub resolution: usize,
    /// Number of FOF-X coefficients `N` (`r2human.fof_n`).
    pub fof_n: usize,
    /// Encoder feature channels `C` (`r2human.feature_channels`; 0 for the FOF and placement nets).
    pub feature_channels: usize,
    /// Spatial sizes fed to the model must be multiples of this (`r2human.stride`, default 1).
    pub stride: usize,
    /// How the model was trained: data, steps, losses (`r2human.recipe`, free text / JSON).
    pub recipe: String,
}

fn meta_error(path: &Path, key: &str, problem: impl Into<String>) -> NeuralError {
    NeuralError::Metadata { path: path.to_path_buf(), key: key.to_string(), problem: problem.into() }
}

impl ModelInfo {
    /// Reads and validates the metadata of a loaded session; `expected` is the kind the caller wants.
    pub(crate) fn read(session: &Session, path: &Path, expected: ModelKind) -> Result<Self, NeuralError> {
        let meta = session.metadata().map_err(|e| meta_error(path, "*", format!("cannot be read: {e}")))?;
        let get = |key: &str| -> Result<String, NeuralError> {
            meta.custom(key).ok_or_else(|| meta_error(path, key, "is missing"))
        };
        let number = |key: &str| -> Result<usize, NeuralError> {
            let v = get(key)?;
            v.trim().parse::<usize>().map_err(|_| meta_error(path, key, format!("is `{v}`, not a whole number")))
        };
        let format = number("r2human.format")?;
        if format != FORMAT_VERSION as usize {
            return Err(meta_error(
                path,
                "r2human.format",
                format!("is {format} but this build reads {FORMAT_VERSION}"),
            ));
        }
        let kind_str = get("r2human.kind")?;
        let kind = match kind_str.as_str() {
            "fof" => ModelKind::Fof,
            "encoder" => ModelKind::Encoder,
            "decoder" => ModelKind::Decoder,
            "placement" => ModelKind::Placement,
            other => {
                return Err(meta_error(
                    path,
                    "r2human.kind",
                    format!("is `{other}`, not fof/encoder/decoder/placement"),
                ))
            }
        };
        if kind != expected {
            return Err(meta_error(
                path,
                "r2human.kind",
                format!("is `{}` but this file is loaded as the {}", kind.as_str(), expected.as_str()),
            ));
        }
        let resolution = number("r2human.resolution")?;
        if resolution == 0 || resolution % 4 != 0 {
            return Err(meta_error(
                path,
                "r2human.resolution",
                format!("is {resolution}; it must be a positive multiple of 4"),
            ));
        }
        let fof_n = number("r2human.fof_n")?;
        if fof_n == 0 {
            return Err(meta_error(path, "r2human.fof_n", "is 0"));
        }
        let takes_features = matches!(kind, ModelKind::Encoder | ModelKind::Decoder);
        let feature_channels = if takes_features { number("r2human.feature_channels")? } else { 0 };
        if takes_features && feature_channels == 0 {
            return Err(meta_error(path, "r2human.feature_channels", "is 0"));
        }
        let stride = match meta.custom("r2human.stride") {
            None => 1,
            Some(_) => number("r2human.stride")?,
        };
        if stride == 0 || stride > 256 {
            return Err(meta_error(path, "r2human.stride", format!("is {stride}; expected 1..=256")));
        }
        Ok(Self {
            kind,
            tier: get("r2human.tier")?,
            resolution,
            fof_n,
            feature_channels,
            stride,
            recipe: get("r2human.recipe")?,
        })
    }
}

/// An optional `r2human.*` metadata value of a loaded session (`None` when the key is absent).
pub(crate) fn optional_key(session: &Session, path: &Path, key: &str) -> Result<Option<String>, NeuralError> {
    let meta = session.metadata().map_err(|e| meta_error(path, "*", format!("cannot be read: {e}")))?;
    Ok(meta.custom(key))
}

/// A metadata error naming the file and the key (for checks done by the network types).
pub(crate) fn metadata_problem(path: &Path, key: &str, problem: impl Into<String>) -> NeuralError {
    meta_error(path, key, problem)
}

/// An expected tensor dimension.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Dim {
    /// Must be exactly this (a dynamic dimension is accepted too).
    Is(i64),
    /// Anything.
    Any,
}

/// Checks one named tensor of a session's inputs or outputs: f32, rank 4, batch 1, then `dims`. Returns the
/// declared shape (`-1` for dynamic dimensions).
pub(crate) fn check_tensor(
    session: &Session,
    path: &Path,
    output: bool,
    name: &str,
    dims: [Dim; 3],
) -> Result<Vec<i64>, NeuralError> {
    let outlets = if output { session.outputs() } else { session.inputs() };
    let side = if output { "output" } else { "input" };
    let sig = |problem: String| NeuralError::Signature { path: PathBuf::from(path), problem };
    let names: Vec<&str> = outlets.iter().map(|o| o.name()).collect();
    let outlet = outlets
        .iter()
        .find(|o| o.name() == name)
        .ok_or_else(|| sig(format!("has no {side} named `{name}` (its {side}s are {names:?})")))?;
    let (ty, shape) = match outlet.dtype() {
        ValueType::Tensor { ty, shape, .. } => (*ty, shape.to_vec()),
        other => return Err(sig(format!("{side} `{name}` is {other:?}, not a tensor"))),
    };
    if ty != TensorElementType::Float32 {
        return Err(sig(format!("{side} `{name}` has element type {ty:?}, expected float32")));
    }
    let want: Vec<String> = std::iter::once("1".to_string())
        .chain(dims.iter().map(|d| match d {
            Dim::Is(v) => v.to_string(),
            Dim::Any => "?".to_string(),
        }))
        .collect();
    let want = format!("[{}]", want.join(", "));
    if shape.len() != 4 {
        return Err(sig(format!("{side} `{name}` has shape {shape:?}, expected {want}")));
    }
    let ok_batch = shape[0] == 1 || shape[0] < 0;
    let ok_rest = dims.iter().zip(&shape[1..]).all(|(d, &s)| match d {
        Dim::Is(v) => s == *v || s < 0,
        Dim::Any => true,
    });
    if !(ok_batch && ok_rest) {
        return Err(sig(format!("{side} `{name}` has shape {shape:?}, expected {want}")));
    }
    Ok(shape)
}

/// Fails when the model has inputs the caller cannot feed (anything outside `known`).
pub(crate) fn check_no_extra_inputs(session: &Session, path: &Path, known: &[&str]) -> Result<(), NeuralError> {
    for input in session.inputs() {
        if !known.contains(&input.name()) {
            return Err(NeuralError::Signature {
                path: path.to_path_buf(),
                problem: format!("has an unexpected input `{}` (this build feeds {known:?})", input.name()),
            });
        }
    }
    Ok(())
}
