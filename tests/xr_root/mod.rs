//! Running a test binary's `#[ignore]`d tests inside the Monado root (`scripts/xr/make-root.sh`,
//! `scripts/xr/run-in-root.sh`), with OpenXR core validation and Vulkan validation on: shared by `tests/xr.rs`
//! and `tests/xr_faults.rs`.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// The project folder.
pub fn checkout() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn is_root_user() -> bool {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| s.lines().find(|l| l.starts_with("Uid:")).map(|l| l.split_whitespace().nth(1) == Some("0")))
        .unwrap_or(false)
}

/// Builds (or reuses) the Monado root; `Err` says why the XR tests must be skipped (not root, or the root
/// cannot be built).
pub fn prepare_root() -> Result<(), String> {
    if !is_root_user() {
        return Err("building and entering the Monado root needs root (mount, chroot)".into());
    }
    match Command::new(checkout().join("scripts/xr/make-root.sh")).stdin(Stdio::null()).output() {
        Ok(o) if o.status.success() => Ok(()),
        Ok(o) => Err(format!(
            "the XR root could not be built:\n{}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        )),
        Err(e) => Err(format!("scripts/xr/make-root.sh did not run: {e}")),
    }
}

/// Runs `args` of this test binary inside the Monado root with validation on; returns (success, output).
pub fn run_inside(extra_runner_args: &[&str], test_args: &[&str]) -> (bool, String) {
    let exe = std::env::current_exe().expect("test binary path");
    let out = Command::new(checkout().join("scripts/xr/run-in-root.sh"))
        .args(extra_runner_args)
        .arg(exe)
        .args(test_args)
        .env("XR_ENABLE_API_LAYERS", "XR_APILAYER_LUNARG_core_validation")
        .env("VK_INSTANCE_LAYERS", "VK_LAYER_KHRONOS_validation")
        .env("RUST_BACKTRACE", "1")
        .current_dir(checkout())
        .stdin(Stdio::null())
        .output()
        .expect("run-in-root.sh starts");
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    (out.status.success(), text)
}

/// Checks that the validation layers the suite asks for are really installed in the root, so "no messages" means
/// something.
pub fn assert_validation_layers_present() {
    let xr_layer = Path::new("/usr/share/openxr/1/api_layers/explicit.d");
    let found = std::fs::read_dir(xr_layer)
        .map(|d| d.flatten().any(|e| e.file_name().to_string_lossy().contains("core_validation")))
        .unwrap_or(false);
    assert!(found, "OpenXR core validation layer manifest missing in {}", xr_layer.display());
    assert_eq!(std::env::var("XR_ENABLE_API_LAYERS").as_deref(), Ok("XR_APILAYER_LUNARG_core_validation"));
    assert!(Path::new("/usr/share/vulkan/explicit_layer.d/VkLayer_khronos_validation.json").exists());
    assert_eq!(std::env::var("VK_INSTANCE_LAYERS").as_deref(), Ok("VK_LAYER_KHRONOS_validation"));
}
