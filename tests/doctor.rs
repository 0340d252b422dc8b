//! `r2human doctor` and the provider report behind it, against the ONNX Runtime this machine has: the CPU build
//! (`scripts/setup.d/neural.sh`, CI) or the GPU build of `bash scripts/setup.sh --gpu`. Without an NVIDIA GPU every
//! GPU provider must fail with a classified reason (not in the build, a named library missing, no driver, no
//! device), never an unexplained one, and `--ep auto` must be the CPU.

use std::path::Path;
use std::process::Command;

use r2human::neural::{runtime_report, ActiveProvider, ExecutionProvider, ProviderStatus, RuntimeOptions};

fn has_nvidia_gpu() -> bool {
    Path::new("/dev/nvidia0").exists()
}

#[test]
fn every_provider_is_reported_with_a_classified_reason() {
    let report = runtime_report(&RuntimeOptions { ep: ExecutionProvider::Auto, ..Default::default() })
        .expect("ONNX Runtime loads (scripts/setup.d/neural.sh installs it)");
    let order: Vec<ActiveProvider> = report.providers.iter().map(|p| p.provider).collect();
    assert_eq!(order, [ActiveProvider::TensorRt, ActiveProvider::Cuda, ActiveProvider::Cpu]);
    let cpu = &report.providers[2];
    assert_eq!(cpu.status, ProviderStatus::Works, "the CPU provider makes a session on the probe model");
    assert!(report.library.is_file(), "{report:?}");
    assert!(report.version.starts_with("1.31"), "{report:?}");
    if has_nvidia_gpu() {
        return;
    }
    for check in &report.providers[..2] {
        assert!(
            !matches!(check.status, ProviderStatus::Works | ProviderStatus::Failed { .. }),
            "{}: {:?}",
            check.provider,
            check.status
        );
    }
    assert_eq!(report.auto_choice(), ActiveProvider::Cpu);
    match &report.manifest {
        // The GPU build with its libraries: CUDA has everything but the driver (or, with a driver but no GPU, fails
        // at the device); TensorRT lacks only its own libraries or the device.
        Some(_) => {
            let preload = report.preload.as_ref().expect("the GPU libraries were opened");
            assert!(preload.loaded > 0, "{preload:?}");
            let cuda = &report.providers[1];
            assert!(
                matches!(cuda.status, ProviderStatus::NoDriver { .. } | ProviderStatus::NoDevice { .. }),
                "{:?}",
                cuda.status
            );
            if let ProviderStatus::LibraryMissing { missing, .. } = &report.providers[0].status {
                assert!(missing.iter().all(|m| m.starts_with("libnv")), "{missing:?}");
            }
        }
        None => {
            for check in &report.providers[..2] {
                assert_eq!(check.status, ProviderStatus::NotInBuild, "{}", check.provider);
            }
        }
    }
}

#[test]
fn the_doctor_command_reports_every_part() {
    let out = Command::new(env!("CARGO_BIN_EXE_r2human"))
        .args(["doctor", "--cameras", "false", "--xr", "false"])
        .env("R2HUMAN_LOG", "warn")
        .output()
        .expect("r2human runs");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}\n{}", String::from_utf8_lossy(&out.stderr));
    for part in ["Vulkan\n", "ONNX Runtime\n", "  TensorRT:", "  CUDA:", "  CPU:      works", "--ep auto: "] {
        assert!(text.contains(part), "`{part}` missing from:\n{text}");
    }
    assert!(!text.contains("OpenXR\n") && !text.contains("Cameras\n"), "{text}");
    if !has_nvidia_gpu() {
        assert!(text.contains("--ep auto: CPU"), "{text}");
    }
}
