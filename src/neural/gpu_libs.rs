//! The GPU runtime libraries that `scripts/setup-gpu.sh` (`bash scripts/setup.sh --gpu`) installs beside ONNX
//! Runtime's GPU build in `.tools/onnxruntime-gpu`: the CUDA, cuDNN and TensorRT libraries of NVIDIA's PyPI wheels.
//!
//! The script writes a manifest (`r2human-gpu-libs.txt`) that lists those libraries in load order (dependencies
//! first) and, per provider, every shared library it needs. Before a GPU provider is registered, [`preload`] opens
//! each listed library by absolute path with `RTLD_GLOBAL`: when ONNX Runtime then opens its CUDA or TensorRT
//! provider, the dynamic loader finds `libcublas.so.13`, `libcudnn.so.9`, … among the libraries already loaded (it
//! matches a needed name against their sonames before it searches any path), so nobody has to set
//! `LD_LIBRARY_PATH`. The NVIDIA driver's `libcuda.so.1` is never in the tree: it comes with the GPU driver.

use std::ffi::CString;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::provider::ActiveProvider;
use super::NeuralError;

/// Where `scripts/setup-gpu.sh` unpacks the `onnxruntime-gpu` wheel and the NVIDIA runtime wheels, relative to the
/// project root.
pub const GPU_TOOLS_SUBDIR: &str = ".tools/onnxruntime-gpu";

/// The manifest the set-up script writes at the top of [`GPU_TOOLS_SUBDIR`].
pub const GPU_MANIFEST_FILE: &str = "r2human-gpu-libs.txt";

/// Where a needed library was found: in the installed tree, on the system, from the NVIDIA driver, or nowhere.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Found {
    /// A file of the installed wheels (preloaded by path).
    Tree,
    /// A library of the system (the C library, the C++ runtime, ...).
    System,
    /// The NVIDIA driver's own library (`libcuda.so.1`): present only where the driver is installed.
    Driver,
    /// Found nowhere.
    Missing,
}

impl std::fmt::Display for Found {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Tree => "in the tree",
            Self::System => "on the system",
            Self::Driver => "from the NVIDIA driver",
            Self::Missing => "missing",
        })
    }
}

/// One shared library a GPU provider needs (directly or through another library).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct NeededLibrary {
    /// The provider that needs it ([`ActiveProvider::Cuda`] or [`ActiveProvider::TensorRt`]).
    pub provider: ActiveProvider,
    /// Its soname (`libcublas.so.13`).
    pub soname: String,
    /// Where the set-up script found it.
    pub found: Found,
}

/// The parsed manifest of a GPU tree.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GpuManifest {
    /// The manifest file.
    pub path: PathBuf,
    /// The libraries to open, by absolute path, in load order.
    pub preload: Vec<PathBuf>,
    /// What each provider needs.
    pub needs: Vec<NeededLibrary>,
}

impl GpuManifest {
    /// The manifest of the GPU tree that holds `ort_library` (`<tree>/onnxruntime/capi/libonnxruntime.so.*`), if
    /// that tree has one; `None` for the CPU build and for libraries outside such a tree.
    pub fn beside(ort_library: &Path) -> Option<PathBuf> {
        let capi = ort_library.parent()?;
        let tree = capi.parent()?.parent()?;
        let path = tree.join(GPU_MANIFEST_FILE);
        path.is_file().then_some(path)
    }

    /// Reads and parses the manifest at `path`.
    pub fn read(path: &Path) -> Result<Self, NeuralError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| NeuralError::GpuManifestRead { path: path.to_path_buf(), source })?;
        Self::parse(&text, path)
    }

    /// Parses a manifest's text; relative library paths are taken from the folder of `path`. Every line is
    /// `preload<TAB>path` or `need<TAB>cuda|tensorrt<TAB>soname<TAB>tree|system|driver|missing`; `#` starts a
    /// comment line. A preloaded path that leaves the tree (absolute, or with `..`) is rejected.
    pub fn parse(text: &str, path: &Path) -> Result<Self, NeuralError> {
        let dir = path.parent().unwrap_or(Path::new("."));
        let bad = |line: usize, problem: String| NeuralError::GpuManifest { path: path.to_path_buf(), line, problem };
        let mut preload = Vec::new();
        let mut needs = Vec::new();
        for (i, line) in text.lines().enumerate() {
            let n = i + 1;
            if line.trim().is_empty() || line.starts_with('#') {
                continue;
            }
            let fields: Vec<&str> = line.split('\t').collect();
            match fields.as_slice() {
                ["preload", rel] => {
                    let rel = Path::new(rel);
                    if rel.is_absolute() || rel.components().any(|c| matches!(c, std::path::Component::ParentDir)) {
                        return Err(bad(n, format!("`{}` is not a path inside the tree", rel.display())));
                    }
                    preload.push(dir.join(rel));
                }
                ["need", provider, soname, found] => {
                    let provider = match *provider {
                        "cuda" => ActiveProvider::Cuda,
                        "tensorrt" => ActiveProvider::TensorRt,
                        other => return Err(bad(n, format!("unknown provider `{other}` (cuda or tensorrt)"))),
                    };
                    let found = match *found {
                        "tree" => Found::Tree,
                        "system" => Found::System,
                        "driver" => Found::Driver,
                        "missing" => Found::Missing,
                        other => {
                            return Err(bad(n, format!("unknown place `{other}` (tree, system, driver, missing)")))
                        }
                    };
                    if soname.is_empty() || soname.contains('/') {
                        return Err(bad(n, format!("`{soname}` is not a library name")));
                    }
                    needs.push(NeededLibrary { provider, soname: soname.to_string(), found });
                }
                _ => {
                    return Err(bad(
                        n,
                        format!("`{line}` is neither `preload<TAB>path` nor `need<TAB>provider<TAB>soname<TAB>place`"),
                    ))
                }
            }
        }
        Ok(Self { path: path.to_path_buf(), preload, needs })
    }

    /// The libraries `provider` needs.
    pub fn needs_of(&self, provider: ActiveProvider) -> impl Iterator<Item = &NeededLibrary> {
        self.needs.iter().filter(move |n| n.provider == provider)
    }

    /// Where each library `provider` needs is now: a library the tree holds is [`Found::Tree`] when its file is
    /// among the preloaded ones (else [`Found::Missing`]: the tree was changed since the set-up); any other is
    /// looked up by the dynamic loader ([`system_has`]) and is [`Found::Driver`] / [`Found::System`] when it loads.
    pub fn resolve(&self, provider: ActiveProvider) -> Vec<(String, Found)> {
        self.needs_of(provider)
            .map(|n| {
                let found = match n.found {
                    Found::Tree if self.preload_exists(&n.soname) => Found::Tree,
                    Found::Tree => Found::Missing,
                    place => match (system_has(&n.soname), place) {
                        (true, Found::Driver) => Found::Driver,
                        (true, _) => Found::System,
                        (false, _) => Found::Missing,
                    },
                };
                (n.soname.clone(), found)
            })
            .collect()
    }

    /// Whether a preloaded file is named `soname` and exists (the wheels name each library file by its soname).
    fn preload_exists(&self, soname: &str) -> bool {
        self.preload.iter().any(|p| p.file_name().is_some_and(|f| f == soname) && p.is_file())
    }
}

/// Whether the dynamic loader can open the library `soname` from its ordinary search path (the system's folders,
/// or already loaded). The library stays loaded when it opens (as ONNX Runtime would load it next).
pub fn system_has(soname: &str) -> bool {
    let Ok(name) = CString::new(soname) else { return false };
    // SAFETY: `name` is a valid NUL-terminated string; RTLD_LAZY only maps the library and runs its initialisers,
    // as loading it for a provider would. The handle is kept (never closed): libraries stay for the process.
    let handle = unsafe { libc::dlopen(name.as_ptr(), libc::RTLD_LAZY | libc::RTLD_GLOBAL) };
    !handle.is_null()
}

/// What [`preload`] did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct PreloadReport {
    /// The manifest read.
    pub manifest: PathBuf,
    /// Libraries opened.
    pub loaded: usize,
    /// Libraries that failed, with the loader's message.
    pub failed: Vec<(PathBuf, String)>,
    /// Time spent opening them.
    pub elapsed: Duration,
}

/// Opens every library of `manifest` in its order, by absolute path, with `RTLD_NOW | RTLD_GLOBAL`, so that the
/// providers ONNX Runtime opens later find them by soname. A library that fails is recorded (with the loader's
/// message, which names what it lacked) and the rest are still tried. Libraries stay loaded for the process.
pub fn preload(manifest: &GpuManifest) -> PreloadReport {
    let start = Instant::now();
    let mut report = PreloadReport { manifest: manifest.path.clone(), ..Default::default() };
    for path in &manifest.preload {
        match open_global(path) {
            Ok(()) => report.loaded += 1,
            Err(NeuralError::GpuLibraryOpen { reason, .. }) => report.failed.push((path.clone(), reason)),
            Err(other) => report.failed.push((path.clone(), other.to_string())),
        }
    }
    report.elapsed = start.elapsed();
    report
}

/// `dlopen(path, RTLD_NOW | RTLD_GLOBAL)`, or [`NeuralError::GpuLibraryOpen`] with the loader's message.
fn open_global(path: &Path) -> Result<(), NeuralError> {
    use std::os::unix::ffi::OsStrExt;
    let failed = |reason: String| NeuralError::GpuLibraryOpen { path: path.to_path_buf(), reason };
    let Ok(name) = CString::new(path.as_os_str().as_bytes()) else {
        return Err(failed("the path holds a NUL byte".into()));
    };
    // SAFETY: `name` is a valid NUL-terminated path. The library's initialisers run (the NVIDIA runtime libraries'
    // only register themselves); the handle is deliberately never closed, so nothing it exports is ever unmapped.
    let handle = unsafe { libc::dlopen(name.as_ptr(), libc::RTLD_NOW | libc::RTLD_GLOBAL) };
    if !handle.is_null() {
        return Ok(());
    }
    // SAFETY: dlerror returns the calling thread's last loader message (or null); it is copied at once.
    let message = unsafe { libc::dlerror() };
    if message.is_null() {
        return Err(failed("the dynamic loader gave no reason".into()));
    }
    // SAFETY: non-null: a NUL-terminated string owned by the loader, valid until the next dl* call on this thread.
    Err(failed(unsafe { std::ffi::CStr::from_ptr(message) }.to_string_lossy().into_owned()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(path: &Path, text: &str) {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, text).unwrap();
    }

    #[test]
    fn the_manifest_is_found_beside_the_gpu_build_only() {
        let tmp = tempfile::tempdir().unwrap();
        let tree = tmp.path().join(GPU_TOOLS_SUBDIR);
        let lib = tree.join("onnxruntime/capi/libonnxruntime.so.1.31.1");
        write(&lib, "x");
        assert_eq!(GpuManifest::beside(&lib), None, "no manifest yet");
        write(&tree.join(GPU_MANIFEST_FILE), "# empty\n");
        assert_eq!(GpuManifest::beside(&lib), Some(tree.join(GPU_MANIFEST_FILE)));
        assert_eq!(GpuManifest::beside(Path::new("libonnxruntime.so")), None);
    }

    #[test]
    fn parses_preloads_and_needs_and_rejects_bad_lines_with_their_number() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join(GPU_MANIFEST_FILE);
        let text = "# comment\npreload\tnvidia/cu13/lib/libcudart.so.13\n\nneed\tcuda\tlibcudart.so.13\ttree\n\
                    need\ttensorrt\tlibnvinfer.so.10\tmissing\nneed\tcuda\tlibcuda.so.1\tdriver\n";
        let m = GpuManifest::parse(text, &path).unwrap();
        assert_eq!(m.preload, vec![tmp.path().join("nvidia/cu13/lib/libcudart.so.13")]);
        assert_eq!(m.needs.len(), 3);
        assert_eq!(m.needs_of(ActiveProvider::Cuda).count(), 2);
        assert_eq!(
            m.needs[1],
            NeededLibrary {
                provider: ActiveProvider::TensorRt,
                soname: "libnvinfer.so.10".into(),
                found: Found::Missing
            }
        );
        for (bad, line, words) in [
            ("preload\t/usr/lib/libc.so.6\n", 1, "not a path inside the tree"),
            ("# x\npreload\t../../etc/x.so\n", 2, "not a path inside the tree"),
            ("need\trocm\tlibx.so\ttree\n", 1, "unknown provider `rocm`"),
            ("need\tcuda\tlibx.so\tcloud\n", 1, "unknown place `cloud`"),
            ("need\tcuda\ta/b.so\ttree\n", 1, "not a library name"),
            ("preload libx.so\n", 1, "is neither"),
        ] {
            let e = GpuManifest::parse(bad, &path).unwrap_err();
            let msg = e.to_string();
            assert!(matches!(e, NeuralError::GpuManifest { line: l, .. } if l == line), "{bad:?}: {msg}");
            assert!(msg.contains(words) && msg.contains("setup-gpu.sh"), "{bad:?}: {msg}");
        }
    }

    #[test]
    fn resolution_follows_the_files_and_the_system() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join(GPU_MANIFEST_FILE);
        write(&tmp.path().join("nvidia/lib/libcublas.so.13"), "fake");
        let text = "preload\tnvidia/lib/libcublas.so.13\npreload\tnvidia/lib/libcudnn.so.9\n\
                    need\tcuda\tlibcublas.so.13\ttree\nneed\tcuda\tlibcudnn.so.9\ttree\n\
                    need\tcuda\tlibc.so.6\tsystem\nneed\tcuda\tlibr2human-no-such-driver.so.1\tdriver\n\
                    need\ttensorrt\tlibnvinfer.so.10\ttree\n";
        let m = GpuManifest::parse(text, &path).unwrap();
        let cuda = m.resolve(ActiveProvider::Cuda);
        assert_eq!(
            cuda,
            vec![
                ("libcublas.so.13".to_string(), Found::Tree),
                // Listed but its file is gone: missing, not silently "in the tree".
                ("libcudnn.so.9".to_string(), Found::Missing),
                ("libc.so.6".to_string(), Found::System),
                ("libr2human-no-such-driver.so.1".to_string(), Found::Missing),
            ]
        );
        // Needed from the tree but never listed for preloading.
        assert_eq!(m.resolve(ActiveProvider::TensorRt), vec![("libnvinfer.so.10".to_string(), Found::Missing)]);
    }

    #[test]
    fn preload_reports_each_library_that_does_not_open_with_the_loaders_reason() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join(GPU_MANIFEST_FILE);
        // A file that is not a shared object and one that does not exist.
        write(&tmp.path().join("lib/libfake.so.1"), "not an ELF file");
        let m = GpuManifest::parse("preload\tlib/libfake.so.1\npreload\tlib/libgone.so.2\n", &path).unwrap();
        let r = preload(&m);
        assert_eq!(r.loaded, 0);
        assert_eq!(r.failed.len(), 2, "{r:?}");
        assert!(r.failed[0].1.contains("libfake.so.1"), "{r:?}");
        assert!(r.failed[1].1.contains("libgone.so.2"), "{r:?}");
        assert_eq!(r.manifest, path);
    }
}
