//! `r2human doctor`: what this machine offers — Vulkan devices, the OpenXR runtime, cameras, ONNX Runtime and its
//! execution providers (with the reason each one that does not work gives) — and what `auto` chooses. Every part is
//! reported even when another fails; the command itself fails only on a bad argument.

use std::fmt::Write as _;

use anyhow::Result;

use crate::app::Backend;
use crate::neural::{ActiveProvider, ExecutionProvider, Found, ProviderStatus, RuntimeOptions};

/// `r2human doctor` options.
#[derive(clap::Args, Debug)]
pub struct DoctorArgs {
    /// Also try the cameras (opens each V4L2 device to list its formats).
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    pub cameras: bool,
    /// Also query the OpenXR runtime (starts no session).
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    pub xr: bool,
}

/// `r2human doctor`.
pub fn run_doctor(args: &DoctorArgs) -> Result<()> {
    let mut out = String::new();
    let software = vulkan_section(&mut out);
    if args.xr {
        xr_section(&mut out);
    }
    if args.cameras {
        out.push_str("\nCameras\n");
        for line in crate::capture::camera::devices_report().lines() {
            let _ = writeln!(out, "  {line}");
        }
    }
    let ep = onnx_section(&mut out);
    out.push_str("\nWhat `auto` chooses here\n");
    let backend = match software {
        Some(software) => {
            let chosen = Backend::Auto.resolve(software);
            let why =
                if software { "the Vulkan device is a software rasteriser" } else { "the Vulkan device is a GPU" };
            format!("{chosen:?} ({why})")
        }
        None => "Cpu (no usable Vulkan device; `view` needs one to present)".into(),
    };
    let _ = writeln!(out, "  view --backend auto: {backend}");
    let _ = writeln!(out, "  --renderer auto: {}", renderer_choice());
    let _ = writeln!(
        out,
        "  --ep auto: {}",
        ep.map_or_else(|| "none (ONNX Runtime does not load)".into(), |p| p.to_string())
    );
    print!("{out}");
    Ok(())
}

/// Lists the Vulkan devices and the one a headless context picks; returns whether that one is a software
/// rasteriser (`None` without a usable device).
fn vulkan_section(out: &mut String) -> Option<bool> {
    out.push_str("Vulkan\n");
    match crate::gpu::list_devices() {
        Ok(devices) if devices.is_empty() => out.push_str("  no device\n"),
        Ok(devices) => {
            for d in &devices {
                let note = if d.usable { "" } else { " — below Vulkan 1.2, not usable" };
                let _ = writeln!(out, "  {} — {}, Vulkan {}{note}", d.name, d.kind, d.api_version);
            }
        }
        Err(e) => {
            let _ = writeln!(out, "  {e}");
            return None;
        }
    }
    match crate::gpu::Context::headless() {
        Ok(ctx) => {
            let _ = writeln!(out, "  r2human uses: {}", ctx.device_name());
            Some(ctx.is_software())
        }
        Err(e) => {
            let _ = writeln!(out, "  no device could be created: {e}");
            None
        }
    }
}

fn xr_section(out: &mut String) {
    out.push_str("\nOpenXR\n");
    match crate::xr::check_runtime() {
        Ok(r) => {
            let _ = writeln!(out, "  runtime: {} {}", r.runtime_name, r.runtime_version);
            let vk = if r.has_extension("XR_KHR_vulkan_enable2") { "yes" } else { "NO (r2human needs it)" };
            let _ = writeln!(out, "  XR_KHR_vulkan_enable2: {vk}");
            match &r.system {
                Ok(s) => {
                    let _ = writeln!(out, "  headset: {}", s.name);
                }
                Err(why) => {
                    let _ = writeln!(out, "  headset: none ({why})");
                }
            }
            out.push_str("  (`r2human xr --check` prints the whole runtime report)\n");
        }
        Err(e) => {
            let _ = writeln!(out, "  {e}");
        }
    }
}

/// The ONNX Runtime part; returns the provider `--ep auto` takes (`None` when ONNX Runtime does not load).
fn onnx_section(out: &mut String) -> Option<ActiveProvider> {
    out.push_str("\nONNX Runtime\n");
    let report =
        match crate::neural::runtime_report(&RuntimeOptions { ep: ExecutionProvider::Auto, ..Default::default() }) {
            Ok(r) => r,
            Err(e) => {
                let _ = writeln!(out, "  {e}");
                return None;
            }
        };
    let _ = writeln!(out, "  library: {}", report.library.display());
    let providers: Vec<String> = report
        .providers
        .iter()
        .filter(|p| p.status != ProviderStatus::NotInBuild)
        .map(|p| p.provider.to_string())
        .collect();
    let _ = writeln!(out, "  version: {} (providers compiled in: {})", report.version, providers.join(", "));
    let _ = writeln!(out, "  build: {}", report.build.lines().next().unwrap_or(""));
    match (&report.manifest, &report.preload) {
        (Some(m), Some(p)) => {
            let _ = writeln!(
                out,
                "  GPU libraries: {} opened by path in {:.2} s (listed in {}){}",
                p.loaded,
                p.elapsed.as_secs_f64(),
                m.display(),
                if p.failed.is_empty() { String::new() } else { format!(", {} failed", p.failed.len()) }
            );
            for (lib, reason) in &p.failed {
                let _ = writeln!(out, "    cannot open {}: {reason}", lib.display());
            }
        }
        (Some(m), None) => {
            let _ = writeln!(out, "  GPU libraries: listed in {} but not opened (see the warning above)", m.display());
        }
        _ => out.push_str("  GPU libraries: none (CPU build; `bash scripts/setup.sh --gpu` installs the GPU build)\n"),
    }
    for check in &report.providers {
        let _ = writeln!(
            out,
            "  {:<9} {} ({:.2} s)",
            format!("{}:", check.provider),
            check.status.summary(),
            check.elapsed.as_secs_f64()
        );
        if !check.libraries.is_empty() {
            let count = |f: Found| check.libraries.iter().filter(|(_, found)| *found == f).count();
            let absent: Vec<&str> =
                check.libraries.iter().filter(|(_, f)| *f == Found::Missing).map(|(s, _)| s.as_str()).collect();
            let _ = writeln!(
                out,
                "            libraries it needs: {} in the tree, {} on the system, {} from the NVIDIA driver{}",
                count(Found::Tree),
                count(Found::System),
                count(Found::Driver),
                if absent.is_empty() { String::new() } else { format!("; missing: {}", absent.join(", ")) }
            );
        }
        match &check.status {
            ProviderStatus::LibraryMissing { reason, .. }
            | ProviderStatus::NoDriver { reason }
            | ProviderStatus::NoDevice { reason } => {
                let _ = writeln!(out, "            ONNX Runtime said: {}", one_line(reason));
            }
            _ => {}
        }
    }
    if let Some((dir, engines)) = &report.trt_cache {
        let _ = writeln!(
            out,
            "  TensorRT engine cache: {} ({engines} engine(s); the first TensorRT run of a model builds and stores \
             its engine there, its log says how long that took)",
            dir.display()
        );
    }
    Some(report.auto_choice())
}

/// What `--renderer auto` takes: the neural renderer when the default models load (on the CPU here, to check them).
fn renderer_choice() -> String {
    let options = RuntimeOptions { ep: ExecutionProvider::Cpu, intra_threads: Some(1), ..Default::default() };
    match crate::pipeline::load_renderer(crate::pipeline::RendererChoice::Neural, None, &options) {
        Ok(Some(n)) => {
            let guard = n.lock().unwrap_or_else(|p| p.into_inner());
            let (dir, provider) = (guard.runtime.dir.display().to_string(), guard.runtime.decoder.provider());
            let live = match crate::app::neural::auto_draws_neural(provider, true) {
                true => "neural".to_string(),
                false => format!("geometric (the decoder runs on the {provider} provider: docs/live.md)"),
            };
            format!("neural for photos (models in {dir}); for video and cameras {live}")
        }
        Ok(None) => "geometric".into(),
        Err(e) => format!("geometric ({e})"),
    }
}

/// `text` on one line (ONNX Runtime's messages may hold newlines).
fn one_line(text: &str) -> String {
    text.split_whitespace().collect::<Vec<_>>().join(" ")
}
