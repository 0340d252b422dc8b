//! The neural renderer in the interactive paths (window, live input, XR eyes).
//!
//! - [`NeuralSetup`] / [`NeuralAvailability`]: `--renderer auto|geometric|neural` resolved once, keeping the
//!   reason when the neural renderer is not available (the window shows it in one overlay line when `N` is
//!   pressed) instead of only logging it.
//! - The Vulkan paths draw neural views through the host-memory seam [`crate::gpu::gpu_neural_person`].
//!
//! The encoder runs once per input frame (a photo once; live frames on the pipeline's worker thread, see
//! [`crate::app::live::EncodeProcessor`]); the decoder once per view.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use crate::neural::{ActiveProvider, NeuralError, RuntimeOptions};
use crate::pipeline::{load_renderer, NeuralRenderer, PipelineError, RendererChoice, SharedNeural};

/// What `--renderer`, `--models` and `--ep` ask for.
#[derive(Clone, Debug, Default)]
pub struct NeuralSetup {
    /// Which renderer (geometric, neural, auto).
    pub choice: RendererChoice,
    /// Model folder; default: the project's `models/tiny`.
    pub models: Option<PathBuf>,
    /// ONNX Runtime options (execution provider, threads).
    pub options: RuntimeOptions,
}

/// Switching to the neural renderer was refused: the one line saying why there is none and how to enable it (the
/// window shows it in its overlay).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct NeuralUnavailable(pub String);

/// The neural renderer of an interactive session, or why there is none.
#[derive(Clone)]
pub struct NeuralAvailability {
    /// The loaded renderer (decoder for the views; encoder for a still input).
    pub renderer: Option<SharedNeural>,
    /// Why there is no neural renderer: one line for the window's overlay, saying how to enable it.
    pub unavailable: Option<String>,
    /// The folder the models came from and the options they were loaded with (to load a second instance for the
    /// live worker thread, so the encoder never holds the display's decoder lock).
    pub source: Option<(PathBuf, RuntimeOptions)>,
}

impl std::fmt::Debug for NeuralAvailability {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NeuralAvailability")
            .field("loaded", &self.renderer.is_some())
            .field("unavailable", &self.unavailable)
            .field("source", &self.source.as_ref().map(|s| &s.0))
            .finish()
    }
}

impl NeuralAvailability {
    /// No neural renderer, for `reason`.
    pub fn none(reason: impl Into<String>) -> Self {
        Self { renderer: None, unavailable: Some(reason.into()), source: None }
    }

    /// A loaded renderer (its folder is taken from the models).
    pub fn loaded(renderer: SharedNeural, options: RuntimeOptions) -> Self {
        let dir = renderer.lock().unwrap_or_else(|p| p.into_inner()).runtime.dir.clone();
        Self { renderer: Some(renderer), unavailable: None, source: Some((dir, options)) }
    }

    /// A second, independent instance of the same models (its own ONNX Runtime sessions), for a worker thread;
    /// `None` when there is no neural renderer.
    pub fn second_instance(&self) -> Result<Option<SharedNeural>, NeuralError> {
        let Some((dir, options)) = &self.source else { return Ok(None) };
        Ok(Some(Arc::new(Mutex::new(NeuralRenderer::load(dir, options)?))))
    }
}

/// Whether `--renderer auto` draws with the neural renderer, given where its decoder runs and whether the input is
/// live (a video or a camera, whose frames must keep up with the source). On the CPU provider a live source is
/// drawn geometrically: there the encoder and decoder cost about as much as the rest of a frame (`bench-live` on a
/// 640×480 clip: 15.7 completed frames a second geometric against 10.2–11.4 neural; the window 12.9 against 8.2)
/// and the evaluation's frame-path rows give the neural renderer nothing for it (divergent whole-frame PSNR
/// −0.6 to +0.02 dB, docs/live.md). A photo, or a GPU provider, keeps the neural renderer.
pub fn auto_draws_neural(provider: ActiveProvider, live: bool) -> bool {
    !(live && provider == ActiveProvider::Cpu)
}

/// Resolves `--renderer` for an interactive session (`live`: the input is a video or a camera):
/// [`RendererChoice::Geometric`] loads nothing (the reason says how to start with the neural renderer);
/// [`RendererChoice::Neural`] fails when the models cannot be loaded; [`RendererChoice::Auto`] logs one warning and
/// keeps the reason ([`unavailable_hint`]) when they cannot, and draws what [`auto_draws_neural`] says when they can
/// (saying so once).
pub fn load_interactive(setup: &NeuralSetup, live: bool) -> Result<NeuralAvailability, PipelineError> {
    if setup.choice == RendererChoice::Geometric {
        return Ok(NeuralAvailability::none(
            "NEURAL RENDERER NOT LOADED (--RENDERER GEOMETRIC): START WITH --RENDERER AUTO OR NEURAL",
        ));
    }
    // The strict choice keeps the error, so Auto can say why in the window.
    match (load_renderer(RendererChoice::Neural, setup.models.as_deref(), &setup.options), setup.choice) {
        (Ok(Some(shared)), RendererChoice::Auto) => {
            let provider = shared.lock().unwrap_or_else(|p| p.into_inner()).runtime.decoder.provider();
            if auto_draws_neural(provider, live) {
                return Ok(NeuralAvailability::loaded(shared, setup.options.clone()));
            }
            tracing::info!(
                "renderer: auto draws live input geometrically on the {provider} provider (the neural renderer costs \
                 about a third of the frame rate there for no gain in the evaluation; docs/live.md); pass \
                 --renderer neural to draw it"
            );
            Ok(NeuralAvailability::none("NEURAL RENDERER OFF FOR LIVE INPUT ON THE CPU (AUTO): --RENDERER NEURAL"))
        }
        (Ok(Some(shared)), _) => Ok(NeuralAvailability::loaded(shared, setup.options.clone())),
        (Ok(None), _) => Ok(NeuralAvailability::none("NEURAL RENDERER OFF")),
        (Err(e), RendererChoice::Auto) => {
            tracing::warn!(
                "using the geometric renderer: {e}. To enable the neural one, install ONNX Runtime with \
                 `bash scripts/setup.d/neural.sh` and pass --models DIR (see train/README.md)"
            );
            Ok(NeuralAvailability::none(unavailable_hint(&e)))
        }
        (Err(e), _) => Err(e),
    }
}

/// One short line (upper case, for the overlay font) saying why the neural renderer cannot run and how to enable
/// it.
pub fn unavailable_hint(e: &PipelineError) -> String {
    let text = match e {
        PipelineError::NoModels(tier) => {
            format!("NEURAL RENDERER OFF: NO MODELS/{tier} FOUND - PASS --MODELS DIR")
        }
        PipelineError::Neural(NeuralError::LibraryNotFound { .. } | NeuralError::LibraryLoad { .. }) => {
            "NEURAL RENDERER OFF: NO ONNX RUNTIME - RUN BASH SCRIPTS/SETUP.D/NEURAL.SH".to_string()
        }
        PipelineError::Neural(NeuralError::ModelMissing { path }) => {
            format!("NEURAL RENDERER OFF: {} MISSING - PASS --MODELS DIR", file_name(path))
        }
        PipelineError::Neural(_) => "NEURAL RENDERER OFF: THE MODELS DO NOT LOAD (SEE THE LOG)".to_string(),
        _ => "NEURAL RENDERER OFF (SEE THE LOG)".to_string(),
    };
    text.to_uppercase()
}

fn file_name(path: &Path) -> String {
    path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hints_name_the_cause_and_the_fix_in_one_line() {
        let no_models = unavailable_hint(&PipelineError::NoModels("tiny".into()));
        assert!(no_models.contains("MODELS/TINY") && no_models.contains("--MODELS DIR"), "{no_models}");
        let no_lib = unavailable_hint(&PipelineError::Neural(NeuralError::LibraryNotFound { searched: vec![] }));
        assert!(no_lib.contains("ONNX RUNTIME") && no_lib.contains("NEURAL.SH"), "{no_lib}");
        let missing =
            unavailable_hint(&PipelineError::Neural(NeuralError::ModelMissing { path: "/x/decoder.onnx".into() }));
        assert!(missing.contains("DECODER.ONNX MISSING"), "{missing}");
        for h in [no_models, no_lib, missing] {
            assert!(!h.contains('\n') && h == h.to_uppercase());
        }
    }

    #[test]
    fn auto_draws_live_input_geometrically_on_the_cpu_only() {
        assert!(!auto_draws_neural(ActiveProvider::Cpu, true));
        assert!(auto_draws_neural(ActiveProvider::Cpu, false));
        for gpu in [ActiveProvider::Cuda, ActiveProvider::TensorRt] {
            assert!(auto_draws_neural(gpu, true) && auto_draws_neural(gpu, false));
        }
    }

    #[test]
    fn geometric_choice_loads_nothing_and_says_how_to_enable() {
        let a =
            load_interactive(&NeuralSetup { choice: RendererChoice::Geometric, ..Default::default() }, false).unwrap();
        assert!(a.renderer.is_none() && a.second_instance().unwrap().is_none());
        assert!(a.unavailable.unwrap().contains("--RENDERER AUTO"));
    }

    #[test]
    fn auto_without_models_keeps_the_reason_and_neural_fails() {
        let dir = tempfile::tempdir().unwrap();
        let setup =
            NeuralSetup { choice: RendererChoice::Auto, models: Some(dir.path().to_path_buf()), ..Default::default() };
        let a = load_interactive(&setup, false).unwrap();
        assert!(a.renderer.is_none());
        let reason = a.unavailable.unwrap();
        // Either the library or the model file is what is missing, depending on the machine.
        assert!(reason.starts_with("NEURAL RENDERER OFF:"), "{reason}");
        let strict = NeuralSetup { choice: RendererChoice::Neural, ..setup };
        assert!(load_interactive(&strict, false).is_err());
    }
}
