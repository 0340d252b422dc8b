//! Finding the ONNX Runtime shared library: `ORT_DYLIB_PATH`, else the project's GPU build
//! (`.tools/onnxruntime-gpu`, from `bash scripts/setup.sh --gpu`), else its CPU build (`.tools/onnxruntime`).

use std::ffi::OsStr;
use std::path::{Path, PathBuf};

use super::gpu_libs::GPU_TOOLS_SUBDIR;
use super::NeuralError;

/// Where `scripts/setup.d/neural.sh` unpacks the `onnxruntime` wheel, relative to the project root.
pub const ORT_TOOLS_SUBDIR: &str = ".tools/onnxruntime";

/// The library file inside the unpacked wheel (`onnxruntime/capi/…`).
#[cfg(target_os = "linux")]
pub const ORT_LIBRARY_FILE: &str = "onnxruntime/capi/libonnxruntime.so.1.31.1";
/// The library file inside the unpacked wheel (`onnxruntime/capi/…`).
#[cfg(target_os = "macos")]
pub const ORT_LIBRARY_FILE: &str = "onnxruntime/capi/libonnxruntime.1.31.1.dylib";
/// The library file inside the unpacked wheel (`onnxruntime/capi/…`).
#[cfg(target_os = "windows")]
pub const ORT_LIBRARY_FILE: &str = "onnxruntime/capi/onnxruntime.dll";
/// The library file inside the unpacked wheel (`onnxruntime/capi/…`).
#[cfg(not(any(target_os = "linux", target_os = "macos", target_os = "windows")))]
pub const ORT_LIBRARY_FILE: &str = "onnxruntime/capi/libonnxruntime.so";

/// Folders that may be the project root: the current directory, the executable's folder and the crate's source
/// folder (for `cargo run`/`cargo test`), each with its ancestors, without duplicates, nearest first.
pub(crate) fn project_roots() -> Vec<PathBuf> {
    let mut starts = Vec::new();
    if let Ok(dir) = std::env::current_dir() {
        starts.push(dir);
    }
    if let Some(dir) = std::env::current_exe().ok().and_then(|exe| exe.parent().map(Path::to_path_buf)) {
        starts.push(dir);
    }
    starts.push(PathBuf::from(env!("CARGO_MANIFEST_DIR")));
    let mut roots: Vec<PathBuf> = Vec::new();
    for start in starts {
        for dir in start.ancestors() {
            if !roots.iter().any(|r| r == dir) {
                roots.push(dir.to_path_buf());
            }
        }
    }
    roots
}

/// The paths tried, in order: `env_override` (the value of `ORT_DYLIB_PATH`) when set and non-empty, then for every
/// root `<root>/.tools/onnxruntime-gpu/<ORT_LIBRARY_FILE>` (the GPU build, which runs on the CPU too) and
/// `<root>/.tools/onnxruntime/<ORT_LIBRARY_FILE>` (the CPU build).
pub fn library_candidates(env_override: Option<&OsStr>, roots: &[PathBuf]) -> Vec<PathBuf> {
    let mut out = Vec::new();
    if let Some(p) = env_override.filter(|p| !p.is_empty()) {
        out.push(PathBuf::from(p));
    }
    for root in roots {
        out.push(root.join(GPU_TOOLS_SUBDIR).join(ORT_LIBRARY_FILE));
        out.push(root.join(ORT_TOOLS_SUBDIR).join(ORT_LIBRARY_FILE));
    }
    out
}

/// Finds the ONNX Runtime library: an explicit `ORT_DYLIB_PATH` must exist (it is never silently ignored); otherwise
/// the first existing project install. The error lists every path tried and how to install the library.
pub fn find_library(env_override: Option<&OsStr>, roots: &[PathBuf]) -> Result<PathBuf, NeuralError> {
    let candidates = library_candidates(env_override, roots);
    if let Some(p) = env_override.filter(|p| !p.is_empty()) {
        let p = PathBuf::from(p);
        return if p.is_file() {
            Ok(p)
        } else {
            Err(NeuralError::LibraryLoad {
                path: p,
                reason: "ORT_DYLIB_PATH points at a file that does not exist".into(),
            })
        };
    }
    candidates.iter().find(|p| p.is_file()).cloned().ok_or(NeuralError::LibraryNotFound { searched: candidates })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn candidates_put_the_override_first_and_skip_empty_values() {
        let roots = vec![PathBuf::from("/a"), PathBuf::from("/b")];
        let c = library_candidates(Some(OsStr::new("/x/lib.so")), &roots);
        assert_eq!(c[0], PathBuf::from("/x/lib.so"));
        assert_eq!(c[1], PathBuf::from("/a").join(GPU_TOOLS_SUBDIR).join(ORT_LIBRARY_FILE));
        assert_eq!(c[2], PathBuf::from("/a").join(ORT_TOOLS_SUBDIR).join(ORT_LIBRARY_FILE));
        assert_eq!(c[3], PathBuf::from("/b").join(GPU_TOOLS_SUBDIR).join(ORT_LIBRARY_FILE));
        assert_eq!(c.len(), 5);
        assert_eq!(library_candidates(Some(OsStr::new("")), &roots).len(), 4);
    }

    #[test]
    fn finds_the_project_install_and_reports_every_path_otherwise() {
        let tmp = tempfile::tempdir().unwrap();
        let empty = tmp.path().join("empty");
        let full = tmp.path().join("full");
        let lib = full.join(ORT_TOOLS_SUBDIR).join(ORT_LIBRARY_FILE);
        std::fs::create_dir_all(lib.parent().unwrap()).unwrap();
        std::fs::write(&lib, b"x").unwrap();
        assert_eq!(find_library(None, &[empty.clone(), full.clone()]).unwrap(), lib);
        match find_library(None, std::slice::from_ref(&empty)) {
            Err(e @ NeuralError::LibraryNotFound { .. }) => {
                let msg = e.to_string();
                assert!(msg.contains("scripts/setup.d/neural.sh"), "{msg}");
                assert!(msg.contains(&empty.display().to_string()), "{msg}");
            }
            other => panic!("expected LibraryNotFound, got {other:?}"),
        }
        // With the GPU build installed beside the CPU build, the GPU build (which also runs on the CPU) is chosen.
        let gpu = full.join(GPU_TOOLS_SUBDIR).join(ORT_LIBRARY_FILE);
        std::fs::create_dir_all(gpu.parent().unwrap()).unwrap();
        std::fs::write(&gpu, b"x").unwrap();
        assert_eq!(find_library(None, &[empty.clone(), full.clone()]).unwrap(), gpu);
        // A nearer root's CPU build still wins over a farther root's GPU build.
        let near = tmp.path().join("near");
        let near_cpu = near.join(ORT_TOOLS_SUBDIR).join(ORT_LIBRARY_FILE);
        std::fs::create_dir_all(near_cpu.parent().unwrap()).unwrap();
        std::fs::write(&near_cpu, b"x").unwrap();
        assert_eq!(find_library(None, &[near, full.clone()]).unwrap(), near_cpu);
        // An explicit override that does not exist is an error, not a silent fallback to the project install.
        let bad = tmp.path().join("missing.so");
        assert!(matches!(find_library(Some(bad.as_os_str()), &[full]), Err(NeuralError::LibraryLoad { .. })));
    }
}
