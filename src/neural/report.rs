//! What ONNX Runtime offers on this machine (`r2human doctor`): the library loaded, its build, the GPU libraries
//! opened, and for each execution provider whether a session can be made on it — and, when not, why: not in this
//! build, a library missing (named), no NVIDIA driver, or no CUDA device.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use ort::ep::{self, ExecutionProvider as _};

use super::gpu_libs::{Found, GpuManifest, PreloadReport};
use super::provider::{
    default_trt_cache, engine_files, environment, loaded_library, preload_gpu_libraries, try_session, ActiveProvider,
    Attempt, ModelSource, RuntimeOptions,
};
use super::NeuralError;

/// A one-node ONNX model (`y = Identity(x)`, float `[1]`, opset 13) that every provider can take: sessions on it
/// make a provider set up its device without a model file.
pub const PROBE_MODEL: [u8; 67] = [
    8, 7, 58, 59, 10, 16, 10, 1, 120, 18, 1, 121, 34, 8, 73, 100, 101, 110, 116, 105, 116, 121, 18, 5, 112, 114, 111,
    98, 101, 90, 15, 10, 1, 120, 18, 10, 10, 8, 8, 1, 18, 4, 10, 2, 8, 1, 98, 15, 10, 1, 121, 18, 10, 10, 8, 8, 1, 18,
    4, 10, 2, 8, 1, 66, 2, 16, 13,
];

/// Whether one execution provider works here.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ProviderStatus {
    /// A session was made on it: the provider, its libraries and (for CUDA/TensorRT) a GPU work.
    Works,
    /// This ONNX Runtime build has no such provider (the CPU build): `bash scripts/setup.sh --gpu` installs one.
    NotInBuild,
    /// The provider's library or one it needs could not be loaded; the libraries are named.
    LibraryMissing {
        /// The missing shared libraries (sonames).
        missing: Vec<String>,
        /// ONNX Runtime's message.
        reason: String,
    },
    /// Every library of the provider is there except the NVIDIA driver's (`libcuda.so.1`): no driver, so no GPU.
    NoDriver {
        /// ONNX Runtime's message.
        reason: String,
    },
    /// The provider's library loaded and the provider failed at the device: no CUDA device (or a driver too old).
    NoDevice {
        /// ONNX Runtime's message.
        reason: String,
    },
    /// Any other failure.
    Failed {
        /// ONNX Runtime's message.
        reason: String,
    },
}

impl ProviderStatus {
    /// One line for the report.
    pub fn summary(&self) -> String {
        match self {
            Self::Works => "works".into(),
            Self::NotInBuild => {
                "not in this ONNX Runtime build (the CPU build): `bash scripts/setup.sh --gpu` installs the GPU \
                 build"
                    .into()
            }
            Self::LibraryMissing { missing, .. } => format!(
                "library not loaded: {} missing (`bash scripts/setup.sh --gpu` installs the GPU libraries; \
                 TensorRT's come from NVIDIA's own package index, see docs/gpu.md)",
                missing.join(", ")
            ),
            Self::NoDriver { .. } => "libraries found, no NVIDIA driver (libcuda.so.1 missing): no CUDA device".into(),
            Self::NoDevice { .. } => "library loaded, no device".into(),
            Self::Failed { reason } => format!("failed: {reason}"),
        }
    }
}

/// The verdict on one provider.
#[derive(Clone, Debug)]
pub struct ProviderCheck {
    /// Which provider.
    pub provider: ActiveProvider,
    /// Whether it works, and why not.
    pub status: ProviderStatus,
    /// Per needed library (from the GPU tree's manifest), where it is now; empty for the CPU provider and the CPU
    /// build.
    pub libraries: Vec<(String, Found)>,
    /// Time the attempt took (loading the provider, making the session).
    pub elapsed: Duration,
}

/// What [`runtime_report`] found.
#[derive(Clone, Debug)]
pub struct RuntimeReport {
    /// The ONNX Runtime library loaded.
    pub library: PathBuf,
    /// ONNX Runtime's version, from the library's file name (`1.31.1`), empty when the name has none.
    pub version: String,
    /// ONNX Runtime's build string (git branch and commit, build type).
    pub build: String,
    /// The GPU tree's library manifest beside the library, if any.
    pub manifest: Option<PathBuf>,
    /// The GPU libraries opened before the providers were tried.
    pub preload: Option<PreloadReport>,
    /// TensorRT, CUDA, CPU, in `--ep auto`'s order.
    pub providers: Vec<ProviderCheck>,
    /// TensorRT's engine cache folder and the engines in it.
    pub trt_cache: Option<(PathBuf, usize)>,
}

impl RuntimeReport {
    /// The provider `--ep auto` takes: the first that works (the CPU provider always does once ONNX Runtime loads).
    pub fn auto_choice(&self) -> ActiveProvider {
        self.providers.iter().find(|p| p.status == ProviderStatus::Works).map_or(ActiveProvider::Cpu, |p| p.provider)
    }
}

/// Sonames in a loader message (`libcublas.so.13: cannot open shared object file`): every word that ends a
/// "cannot open shared object file" clause.
fn missing_libraries(message: &str) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for (at, _) in message.match_indices(": cannot open shared object file") {
        let before = &message[..at];
        let start = before.rfind(|c: char| c.is_whitespace() || c == '"' || c == '\'' || c == '[').map_or(0, |i| i + 1);
        let name = before[start..].rsplit('/').next().unwrap_or("").to_string();
        if !name.is_empty() && !out.contains(&name) {
            out.push(name);
        }
    }
    out
}

/// Libraries only an NVIDIA driver installs.
fn is_driver_library(soname: &str) -> bool {
    soname.starts_with("libcuda.so") || soname.starts_with("libnvidia-")
}

/// Classifies why a GPU provider gave no session from ONNX Runtime's message (`registration`: it failed while the
/// provider was registered, before any session).
pub fn classify_failure(message: &str, registration: bool) -> ProviderStatus {
    let reason = message.to_string();
    let missing = missing_libraries(message);
    if !missing.is_empty() {
        return if missing.iter().all(|m| is_driver_library(m)) {
            ProviderStatus::NoDriver { reason }
        } else {
            ProviderStatus::LibraryMissing { missing, reason }
        };
    }
    let lower = message.to_ascii_lowercase();
    let device_words = [
        "no cuda-capable device",
        "cuda_error_no_device",
        "cudaerrornodevice",
        "cuda failure 100",
        "driver version is insufficient",
        "cuda failure 35",
        "no cuda gpus are available",
        "cuda driver",
    ];
    if device_words.iter().any(|w| lower.contains(w)) {
        return ProviderStatus::NoDevice { reason };
    }
    if registration && (lower.contains("not available") || lower.contains("not enabled") || lower.contains("not built"))
    {
        return ProviderStatus::NotInBuild;
    }
    ProviderStatus::Failed { reason }
}

/// Whether this ONNX Runtime build has `provider` compiled in.
fn in_build(provider: ActiveProvider) -> bool {
    let available = match provider {
        ActiveProvider::TensorRt => ep::TensorRT::is_available(),
        ActiveProvider::Cuda => ep::CUDA::is_available(),
        ActiveProvider::Cpu => return true,
    };
    match available {
        Ok(yes) => yes,
        Err(e) => {
            tracing::warn!("ONNX Runtime could not list its providers ({e}); trying {provider} anyway");
            true
        }
    }
}

/// Loads ONNX Runtime (as every neural command does), opens the GPU libraries of its tree, and tries a session on
/// TensorRT, CUDA and the CPU in turn on a tiny built-in model (`PROBE_MODEL`), each provider alone. Fails only when ONNX Runtime itself
/// cannot be loaded.
pub fn runtime_report(options: &RuntimeOptions) -> Result<RuntimeReport, NeuralError> {
    let env = environment(options)?;
    let library = loaded_library().unwrap_or_default();
    let build = ort::info().to_string();
    let version = library
        .file_name()
        .and_then(|n| n.to_str())
        .and_then(|n| n.split_once(".so.").map(|(_, v)| v.to_string()))
        .unwrap_or_default();
    let manifest_path = GpuManifest::beside(&library);
    let manifest = match &manifest_path {
        Some(p) => Some(GpuManifest::read(p)?),
        None => None,
    };
    let preload = preload_gpu_libraries().cloned();
    let mut providers = Vec::new();
    for provider in [ActiveProvider::TensorRt, ActiveProvider::Cuda, ActiveProvider::Cpu] {
        let libraries = manifest.as_ref().map(|m| m.resolve(provider)).unwrap_or_default();
        let start = Instant::now();
        let status = if !in_build(provider) {
            ProviderStatus::NotInBuild
        } else {
            let probe = RuntimeOptions { intra_threads: Some(1), ..options.clone() };
            match try_session(&env, ModelSource::Memory(&PROBE_MODEL), provider, &probe) {
                Ok(_) => ProviderStatus::Works,
                Err(Attempt::Provider(reason)) => classify_failure(&reason, true),
                Err(Attempt::Session(reason)) => classify_failure(&reason, false),
            }
        };
        providers.push(ProviderCheck { provider, status, libraries, elapsed: start.elapsed() });
    }
    let trt_cache = options.trt_engine_cache.clone().or_else(default_trt_cache).map(|dir| {
        let engines = engine_files(&dir);
        (dir, engines)
    });
    Ok(RuntimeReport { library, version, build, manifest: manifest_path, preload, providers, trt_cache })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_libraries_are_read_from_loader_messages() {
        let m = "Failed to load library libonnxruntime_providers_cuda.so with error: libcublas.so.13: cannot open \
                 shared object file: No such file or directory";
        assert_eq!(missing_libraries(m), ["libcublas.so.13"]);
        let m = "dlopen failed: /opt/x/libnvinfer.so.10: cannot open shared object file; \"libcuda.so.1: cannot \
                 open shared object file\"";
        assert_eq!(missing_libraries(m), ["libnvinfer.so.10", "libcuda.so.1"]);
        assert!(missing_libraries("CUDA failure 100: no CUDA-capable device is detected").is_empty());
    }

    #[test]
    fn failures_are_classified_by_what_is_missing() {
        let trt = "ORT error: Failed to load library libonnxruntime_providers_tensorrt.so with error: \
                   libnvinfer.so.10: cannot open shared object file: No such file or directory";
        assert_eq!(
            classify_failure(trt, true),
            ProviderStatus::LibraryMissing { missing: vec!["libnvinfer.so.10".into()], reason: trt.into() }
        );
        let cuda = "Failed to load library libonnxruntime_providers_cuda.so with error: libcuda.so.1: cannot open \
                    shared object file: No such file or directory";
        assert!(matches!(classify_failure(cuda, true), ProviderStatus::NoDriver { .. }));
        let device = "CUDA failure 100: no CUDA-capable device is detected ; GPU=0 ; hostname=x ; expr=cudaSetDevice";
        assert!(matches!(classify_failure(device, false), ProviderStatus::NoDevice { .. }));
        let old = "CUDA failure 35: CUDA driver version is insufficient for CUDA runtime version";
        assert!(matches!(classify_failure(old, false), ProviderStatus::NoDevice { .. }));
        let build = "CUDA execution provider is not enabled in this build";
        assert_eq!(classify_failure(build, true), ProviderStatus::NotInBuild);
        // The same words after registration are a failure of the session, not of the build.
        assert!(matches!(classify_failure(build, false), ProviderStatus::Failed { .. }));
        assert!(matches!(classify_failure("out of memory", false), ProviderStatus::Failed { .. }));
    }

    #[test]
    fn summaries_name_the_missing_library_and_the_fix() {
        let s = ProviderStatus::LibraryMissing { missing: vec!["libnvinfer.so.10".into()], reason: String::new() };
        assert!(s.summary().contains("libnvinfer.so.10") && s.summary().contains("setup.sh --gpu"));
        assert_eq!(ProviderStatus::NoDevice { reason: String::new() }.summary(), "library loaded, no device");
        assert!(ProviderStatus::NoDriver { reason: String::new() }.summary().contains("libcuda.so.1"));
    }
}
