//! The ONNX Runtime environment (one per process) and sessions on the chosen execution provider, with fallback.

use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};
use std::time::Instant;

use ort::environment::Environment;
use ort::ep;
use ort::session::builder::GraphOptimizationLevel;
use ort::session::Session;

use super::gpu_libs::{preload, GpuManifest, PreloadReport};
use super::library::{find_library, project_roots};
use super::NeuralError;

/// Where TensorRT's engine and timing caches go by default, relative to the project root (git-ignored): the first
/// session of a model builds its engine (seconds to minutes), later runs load it.
pub const TRT_CACHE_SUBDIR: &str = ".tools/tensorrt-cache";

/// The default TensorRT cache folder: [`TRT_CACHE_SUBDIR`] in the nearest project root that has a `.tools` folder
/// (the one `scripts/setup.sh` made), `None` when there is none.
pub fn default_trt_cache() -> Option<PathBuf> {
    project_roots().into_iter().find(|r| r.join(".tools").is_dir()).map(|r| r.join(TRT_CACHE_SUBDIR))
}

/// Which execution provider to run the models on (`--ep`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum ExecutionProvider {
    /// TensorRT, else CUDA, else CPU: the first one that registers and loads the model.
    #[default]
    Auto,
    /// NVIDIA TensorRT (with CUDA for the nodes TensorRT does not take), else CPU.
    #[value(name = "tensorrt")]
    TensorRt,
    /// NVIDIA CUDA, else CPU.
    Cuda,
    /// The CPU provider only.
    Cpu,
}

impl ExecutionProvider {
    /// The providers tried, in order; the CPU provider always ends the list.
    pub fn chain(self) -> &'static [ActiveProvider] {
        match self {
            Self::Auto => &[ActiveProvider::TensorRt, ActiveProvider::Cuda, ActiveProvider::Cpu],
            Self::TensorRt => &[ActiveProvider::TensorRt, ActiveProvider::Cpu],
            Self::Cuda => &[ActiveProvider::Cuda, ActiveProvider::Cpu],
            Self::Cpu => &[ActiveProvider::Cpu],
        }
    }
}

/// The execution provider a session ended up on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ActiveProvider {
    /// TensorRT (nodes it does not take run on CUDA or the CPU).
    TensorRt,
    /// CUDA (nodes it does not take run on the CPU).
    Cuda,
    /// CPU.
    Cpu,
}

impl std::fmt::Display for ActiveProvider {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::TensorRt => "TensorRT",
            Self::Cuda => "CUDA",
            Self::Cpu => "CPU",
        })
    }
}

/// How to create sessions.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RuntimeOptions {
    /// Requested execution provider.
    pub ep: ExecutionProvider,
    /// TensorRT: build fp16 engines.
    pub trt_fp16: bool,
    /// TensorRT: folder for the engine and timing caches (built engines are reused across runs); `None` uses
    /// [`default_trt_cache`] (`.tools/tensorrt-cache`), and no cache when there is no project `.tools` folder.
    pub trt_engine_cache: Option<PathBuf>,
    /// Intra-op threads for the CPU provider; `None` lets ONNX Runtime use one per physical core.
    pub intra_threads: Option<usize>,
    /// The ONNX Runtime library; `None` searches `ORT_DYLIB_PATH`, then the project's `.tools/onnxruntime`.
    pub library: Option<PathBuf>,
}

static ENVIRONMENT: Mutex<Option<(Environment, PathBuf)>> = Mutex::new(None);

/// The GPU libraries opened for this process (once, before the first GPU provider is registered): `None` when the
/// loaded ONNX Runtime has no GPU manifest beside it.
static PRELOADED: OnceLock<Option<PreloadReport>> = OnceLock::new();

/// The ONNX Runtime library this process loaded, once [`environment`] has run.
pub fn loaded_library() -> Option<PathBuf> {
    ENVIRONMENT.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).as_ref().map(|(_, p)| p.clone())
}

/// Opens the CUDA / cuDNN / TensorRT libraries of the GPU tree that holds the loaded ONNX Runtime (see
/// [`super::gpu_libs`]), once per process, and returns what happened; `None` without such a tree.
pub(crate) fn preload_gpu_libraries() -> Option<&'static PreloadReport> {
    PRELOADED
        .get_or_init(|| {
            let library = loaded_library()?;
            let path = GpuManifest::beside(&library)?;
            let manifest = match GpuManifest::read(&path) {
                Ok(m) => m,
                Err(e) => {
                    tracing::warn!("{e}; the GPU providers will not find their libraries");
                    return None;
                }
            };
            let report = preload(&manifest);
            tracing::info!(
                "opened {} GPU runtime libraries listed in `{}` in {:.2} s",
                report.loaded,
                path.display(),
                report.elapsed.as_secs_f64()
            );
            for (lib, reason) in &report.failed {
                if reason.contains("libcuda.so.1") {
                    // Expected without an NVIDIA driver: the providers will say "no NVIDIA driver".
                    tracing::info!("`{}` needs the NVIDIA driver: {reason}", lib.display());
                } else {
                    tracing::warn!("cannot open `{}`: {reason}", lib.display());
                }
            }
            Some(report)
        })
        .as_ref()
}
/// The process-wide ONNX Runtime environment, loading the library on first use (from `options.library`, else
/// `ORT_DYLIB_PATH`, else the project's `.tools/onnxruntime`). ONNX Runtime allows one library and one environment
/// per process: later calls return the first one (other ONNX users in the crate should call this too).
pub fn environment(options: &RuntimeOptions) -> Result<Environment, NeuralError> {
    let mut guard = ENVIRONMENT.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    if let Some((env, loaded)) = guard.as_ref() {
        if let Some(wanted) = &options.library {
            if wanted != loaded {
                tracing::warn!(
                    "ONNX Runtime is already loaded from `{}`; ignoring the request for `{}` (one library per process)",
                    loaded.display(),
                    wanted.display()
                );
            }
        }
        return Ok(env.clone());
    }
    let path = match &options.library {
        Some(p) => p.clone(),
        None => find_library(std::env::var_os("ORT_DYLIB_PATH").as_deref(), &project_roots())?,
    };
    let path = std::fs::canonicalize(&path)
        .map_err(|e| NeuralError::LibraryLoad { path: path.clone(), reason: e.to_string() })?;
    let builder =
        ort::init_from(&path).map_err(|e| NeuralError::LibraryLoad { path: path.clone(), reason: e.to_string() })?;
    let env = builder
        .with_name("r2human")
        .build()
        .map_err(|e| NeuralError::LibraryLoad { path: path.clone(), reason: e.to_string() })?;
    tracing::info!("ONNX Runtime loaded from `{}`", path.display());
    *guard = Some((env.clone(), path));
    Ok(env)
}

/// Why a provider gave no session.
pub(crate) enum Attempt {
    /// The provider could not be registered (not in this build, no driver, …).
    Provider(String),
    /// The session could not be created with the provider registered.
    Session(String),
}

/// Where a session's model comes from.
pub(crate) enum ModelSource<'a> {
    /// An ONNX file.
    File(&'a Path),
    /// ONNX bytes in memory.
    Memory(&'a [u8]),
}

/// A session for `model` with `provider` registered (TensorRT with CUDA behind it for the nodes it does not take).
pub(crate) fn try_session(
    env: &Environment,
    model: ModelSource<'_>,
    provider: ActiveProvider,
    options: &RuntimeOptions,
) -> Result<Session, Attempt> {
    if provider != ActiveProvider::Cpu {
        preload_gpu_libraries();
    }
    let mut builder = Session::builder(env).map_err(|e| Attempt::Session(e.to_string()))?;
    builder =
        builder.with_optimization_level(GraphOptimizationLevel::All).map_err(|e| Attempt::Session(e.to_string()))?;
    if let Some(n) = options.intra_threads {
        builder = builder.with_intra_threads(n.max(1)).map_err(|e| Attempt::Session(e.to_string()))?;
    }
    // ONNX Runtime's pool threads spin for a while after each run by default; the pipeline's own rayon stages
    // (raster, colour lookup, packing the decoder's inputs) run right before and after on the same cores, and
    // the spinning threads take their time.
    builder = builder.with_intra_op_spinning(false).map_err(|e| Attempt::Session(e.to_string()))?;
    // ONNX Runtime warns about every unused initializer of some graphs (ISNet: dozens of lines); errors stay.
    builder = builder.with_log_level(ort::logging::LogLevel::Error).map_err(|e| Attempt::Session(e.to_string()))?;
    match provider {
        ActiveProvider::Cpu => {}
        ActiveProvider::Cuda => {
            builder = builder
                .with_execution_providers([ep::CUDA::default().build().error_on_failure()])
                .map_err(|e| Attempt::Provider(e.to_string()))?;
        }
        ActiveProvider::TensorRt => {
            let mut trt = ep::TensorRT::default().with_fp16(options.trt_fp16);
            if let Some(dir) = &options.trt_engine_cache.clone().or_else(default_trt_cache) {
                if let Err(e) = std::fs::create_dir_all(dir) {
                    tracing::warn!("cannot create the TensorRT engine cache `{}`: {e}", dir.display());
                }
                let dir = dir.display().to_string();
                trt = trt
                    .with_engine_cache(true)
                    .with_engine_cache_path(&dir)
                    .with_timing_cache(true)
                    .with_timing_cache_path(&dir);
            }
            builder = builder
                .with_execution_providers([
                    trt.build().error_on_failure(),
                    // Nodes TensorRT does not take go to CUDA when it registers, else to the CPU.
                    ep::CUDA::default().build().fail_silently(),
                ])
                .map_err(|e| Attempt::Provider(e.to_string()))?;
        }
    }
    match model {
        ModelSource::File(path) => builder.commit_from_file(path),
        ModelSource::Memory(bytes) => builder.commit_from_memory(bytes),
    }
    .map_err(|e| Attempt::Session(e.to_string()))
}

/// The `.engine` files of TensorRT's cache folder.
pub(crate) fn engine_files(dir: &Path) -> usize {
    std::fs::read_dir(dir)
        .map(|entries| entries.flatten().filter(|e| e.path().extension().is_some_and(|x| x == "engine")).count())
        .unwrap_or(0)
}

/// Creates a session for the model at `path` on the first provider of `options.ep`'s chain that works, logging
/// which one runs and why the others were skipped.
pub(crate) fn create_session(
    path: &Path,
    what: &str,
    options: &RuntimeOptions,
) -> Result<(Session, ActiveProvider), NeuralError> {
    if !path.is_file() {
        return Err(NeuralError::ModelMissing { path: path.to_path_buf() });
    }
    let env = environment(options)?;
    let chain = options.ep.chain();
    for (i, &provider) in chain.iter().enumerate() {
        let next = chain.get(i + 1).map_or_else(|| "nothing".to_string(), |p| p.to_string());
        let cache = options.trt_engine_cache.clone().or_else(default_trt_cache);
        let engines_before = cache.as_deref().map_or(0, engine_files);
        let start = Instant::now();
        match try_session(&env, ModelSource::File(path), provider, options) {
            Ok(session) => {
                tracing::info!("{what} `{}` runs on {provider}", path.display());
                if let (ActiveProvider::TensorRt, Some(dir)) = (provider, &cache) {
                    // Engines of static shapes are built here; those of dynamic shapes at the first run of a shape.
                    let built = engine_files(dir).saturating_sub(engines_before);
                    tracing::info!(
                        "TensorRT session for {what} ready in {:.2} s: {} (cache `{}`)",
                        start.elapsed().as_secs_f64(),
                        if built > 0 {
                            format!("built {built} engine(s)")
                        } else {
                            "engines loaded or deferred".into()
                        },
                        dir.display()
                    );
                }
                return Ok((session, provider));
            }
            // With `--ep auto` a missing GPU provider is the expected case on CPU machines: say so at info level;
            // a provider the user asked for by name that cannot register is a warning.
            Err(Attempt::Provider(reason)) if options.ep == ExecutionProvider::Auto => {
                tracing::info!("{provider} execution provider is not available for {what} ({reason}); trying {next}");
            }
            Err(Attempt::Provider(reason)) => {
                tracing::warn!(
                    "{provider} execution provider could not be registered for {what} ({reason}); falling back to \
                     {next}. For GPU inference install ONNX Runtime's GPU build and its CUDA / cuDNN / TensorRT \
                     libraries with `bash scripts/setup.sh --gpu`; `r2human doctor` says what this machine lacks"
                );
            }
            Err(Attempt::Session(reason)) if provider != ActiveProvider::Cpu => {
                tracing::warn!(
                    "{what} `{}` could not be loaded on {provider} ({reason}); falling back to {next}",
                    path.display()
                );
            }
            Err(Attempt::Session(reason)) => {
                return Err(NeuralError::ModelLoad { path: path.to_path_buf(), reason });
            }
        }
    }
    // The chain always ends with the CPU provider, which either returns a session or an error above.
    Err(NeuralError::ModelLoad { path: path.to_path_buf(), reason: "no execution provider could load it".into() })
}
