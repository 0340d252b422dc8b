//! Command-line commands: argument parsing and hand-over to the library. No algorithm lives here.

mod data;
mod doctor;
mod live;
mod render;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// r2human: render a person from one photo from any viewpoint — in a VR panorama, as an AR layer, or on the
/// desktop.
#[derive(Parser, Debug)]
#[command(name = "r2human", version, about, long_about = None)]
pub struct Cli {
    /// The command to run.
    #[command(subcommand)]
    pub command: Command,
}

/// Top-level commands.
#[derive(Subcommand, Debug)]
pub enum Command {
    /// Render novel views of the person in a photo: one view (--yaw/--pitch) or an orbit (--orbit N).
    Render(render::RenderArgs),
    /// Write the person in a photo as a textured glTF 2.0 binary (.glb) in metres, for Blender, game engines, web
    /// viewers and other XR apps.
    Export(render::ExportArgs),
    /// Run the whole pipeline on the embedded default person and panorama; writes an orbit (PNGs, GIF, contact
    /// sheet).
    Demo(render::DemoArgs),
    /// Write a dataset of synthetic people with ground truth (source view, FOF, target views).
    Dataset(data::DatasetArgs),
    /// Write one synthetic person as a textured glTF binary (.glb).
    Synth(data::SynthArgs),
    /// Measure error against run time for every method on synthetic subjects (and scans) with ground truth.
    Eval(data::EvalArgs),
    /// Open a desktop window: drag to orbit, wheel to zoom, V/A for VR/AR, G/N geometric/neural, S screenshot.
    View(live::ViewArgs),
    /// Run as an OpenXR application (VR panorama or AR passthrough); --check describes the runtime.
    Xr(live::XrArgs),
    /// List the cameras that can feed the pipeline.
    Devices,
    /// Say what this machine offers (Vulkan devices, OpenXR runtime, cameras, ONNX Runtime and which execution
    /// providers load, and why the others do not) and what `auto` chooses.
    Doctor(doctor::DoctorArgs),
    /// Play a clip through the live pipeline without a window and report completed frames per second, dropped
    /// frames, latency (p50, p95) and the per-stage medians.
    BenchLive(live::BenchLiveArgs),
}

/// Entry point of the binary: parses arguments, runs the command, prints errors as sentences.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    keep_freed_memory();
    init_logging();
    start_heap_log();
    let result = match cli.command {
        Command::Render(args) => render::run_render(&args),
        Command::Export(args) => render::run_export(&args),
        Command::Demo(args) => render::run_demo(&args),
        Command::Dataset(args) => data::run_dataset(&args),
        Command::Synth(args) => data::run_synth(&args),
        Command::Eval(args) => data::run_eval(&args),
        Command::View(args) => live::run_view(&args),
        Command::Xr(args) => live::run_xr(&args),
        Command::Devices => live::run_devices(),
        Command::Doctor(args) => doctor::run_doctor(&args),
        Command::BenchLive(args) => live::run_bench_live(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", error_sentence(&e));
            ExitCode::FAILURE
        }
    }
}

/// The error and its causes joined with ": ", skipping a cause whose text the message already holds (many error
/// types print their source inside their own message; `{:#}` would repeat it).
pub fn error_sentence(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let part = cause.to_string();
        if text.is_empty() {
            text = part;
        } else if !text.contains(&part) {
            text.push_str(": ");
            text.push_str(&part);
        }
    }
    text
}

fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_env("R2HUMAN_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info,ort=warn"));
    let _ =
        tracing_subscriber::fmt().with_env_filter(filter).with_target(false).with_writer(std::io::stderr).try_init();
}

/// Every frame allocates and frees the same few dozen image-sized buffers (0.25-3 MiB each). glibc hands blocks that
/// large out as fresh `mmap`s or trims them back to the system when they are freed, so every frame paid for its
/// buffers again in page faults (about a tenth of a live frame's time in `perf`). Freed memory is kept for reuse
/// instead: blocks up to 64 MiB come from the heap and the heap is not trimmed below its peak. Memory stays
/// bounded by the peak of one frame's work (the soak runs' heap log shows it).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn keep_freed_memory() {
    const LIMIT: libc::c_int = 64 << 20;
    // SAFETY: mallopt only sets allocator parameters (glibc documents both) and is called once at start-up, before
    // any other thread exists.
    let ok = unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, LIMIT) == 1 && libc::mallopt(libc::M_TRIM_THRESHOLD, LIMIT) == 1
    };
    if !ok {
        tracing::debug!("mallopt refused the allocator settings; freed memory goes back to the system");
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn keep_freed_memory() {}

/// `R2HUMAN_HEAP_LOG=FILE` (soak runs, `scripts/soak.sh`): once a second, appends the C heap's figures to FILE as
/// `seconds,in_use_kib,held_kib` — bytes handed out by `malloc` (Rust's allocations, the Vulkan driver's, the
/// OpenXR runtime client's) and bytes the allocator holds from the system, from glibc's `mallinfo2`. Resident
/// memory that grows while the bytes in use stay flat is the allocator keeping freed memory, not a leak.
fn start_heap_log() {
    let Some(path) = std::env::var_os("R2HUMAN_HEAP_LOG") else { return };
    let path = std::path::PathBuf::from(path);
    let file = std::fs::OpenOptions::new().create(true).truncate(true).write(true).open(&path);
    let mut file = match file {
        Ok(f) => f,
        Err(e) => {
            tracing::warn!("R2HUMAN_HEAP_LOG: cannot write {}: {e}; no heap log", path.display());
            return;
        }
    };
    let Some(first) = heap_figures() else {
        tracing::warn!("R2HUMAN_HEAP_LOG: this C library has no mallinfo2 (glibc only); no heap log");
        return;
    };
    let start = std::time::Instant::now();
    let spawned = std::thread::Builder::new().name("r2human-heap-log".into()).spawn(move || {
        use std::io::Write;
        let written = (|| -> std::io::Result<()> {
            writeln!(file, "seconds,in_use_kib,held_kib")?;
            let mut figures = Some(first);
            while let Some(f) = figures {
                writeln!(file, "{:.2},{},{}", start.elapsed().as_secs_f64(), f.in_use / 1024, f.held / 1024)?;
                std::thread::sleep(std::time::Duration::from_secs(1));
                figures = heap_figures();
            }
            Ok(())
        })();
        if let Err(e) = written {
            tracing::warn!("R2HUMAN_HEAP_LOG: writing {} failed: {e}; the heap log stops", path.display());
        }
    });
    if let Err(e) = spawned {
        tracing::warn!("R2HUMAN_HEAP_LOG: cannot start the heap log thread: {e}");
    }
}

/// The C heap: bytes in use (arenas + mmapped chunks) and bytes held from the system (the same, plus free space).
#[derive(Clone, Copy, Debug)]
struct HeapFigures {
    in_use: usize,
    held: usize,
}

#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn heap_figures() -> Option<HeapFigures> {
    // SAFETY: mallinfo2 takes no arguments, returns a plain struct by value and only reads the allocator's state
    // under its own locks (glibc 2.33 and later; the symbol is missing before, and the program would not start).
    let m = unsafe { libc::mallinfo2() };
    Some(HeapFigures { in_use: m.uordblks + m.hblkhd, held: m.arena + m.hblkhd })
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn heap_figures() -> Option<HeapFigures> {
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    #[test]
    fn heap_figures_follow_an_allocation_and_its_release() {
        let before = heap_figures().unwrap();
        assert!(before.held >= before.in_use, "{before:?}");
        // 256 MiB (an mmapped chunk, counted in both figures); the margins leave room for other tests' allocations
        // running at the same time.
        let block = vec![1u8; 256 << 20];
        let during = heap_figures().unwrap();
        assert!(during.in_use >= before.in_use + (192 << 20), "{before:?} -> {during:?}");
        assert!(during.held >= during.in_use, "{during:?}");
        drop(std::hint::black_box(block));
        let after = heap_figures().unwrap();
        assert!(after.in_use + (192 << 20) <= during.in_use, "{during:?} -> {after:?}");
    }

    #[test]
    fn error_sentence_names_each_cause_once() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "No such file or directory (os error 2)");
        let inner = crate::io::image_io::IoError::Read { path: "a.png".into(), source: io };
        let e = anyhow::Error::new(inner).context("loading the input photo");
        let text = error_sentence(&e);
        assert_eq!(text, "loading the input photo: cannot read a.png: No such file or directory (os error 2)");
        // A cause that adds information is kept.
        let e = anyhow::anyhow!("disk full").context("writing out.png");
        assert_eq!(error_sentence(&e), "writing out.png: disk full");
    }
}
