//! XR frame rate and per-eye render time with Monado's simulated HMD, against the desktop paths, in one run.
//!
//! `cargo bench --bench xr` (as root) builds or reuses the Monado root (scripts/xr/make-root.sh) and re-runs
//! itself inside it through `scripts/xr/run-in-root.sh --xvfb`: Monado's XCB compositor on Xvfb paces at display
//! rate (about 55 Hz) instead of the null compositor's fixed 20 Hz. Measured:
//! - `desktop/gpu_eye_render`: one eye image (person + panorama) on the Vulkan renderer, headless, no XR at all;
//! - `desktop/cpu_eye_render`: the same eye through the CPU reference pipeline;
//! - `xr_simulated_hmd/frame_interval`: time per submitted XR frame while the GPU renders the person per eye;
//! - `desktop/{gpu,cpu}_eye_render_neural`: the same eye with the neural renderer (`models/tiny`, ONNX Runtime CPU
//!   provider): through the host-memory seam on the Vulkan renderer, and on the CPU per-view path;
//! - after the benchmarks, one session's report per renderer (geometric, neural): per-eye render time inside the
//!   session, fresh-render share, motion-to-photon latency of the person layer, and the frame loop's waits for the
//!   shared Vulkan queue; then the desktop window (`r2human view --frames 60 --spin 3`, Xvfb) with each renderer,
//!   and the load average before and after.

#[path = "../tests/xr_support/mod.rs"]
mod xr_support;

use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use criterion::{criterion_group, Criterion};
use glam::{Quat, Vec3};
use r2human::buffer::RgbaImage;
use r2human::compose::{self, Mode};
use r2human::geometry::camera::Fov;
use r2human::gpu::gpu_neural_person;
use r2human::gpu::offline;
use r2human::gpu::{Context, Renderer};
use r2human::io::environment::Environment;
use r2human::neural::{ExecutionProvider, RuntimeOptions};
use r2human::pipeline::warp::OcclusionFill;
use r2human::pipeline::{
    NeuralInput, NeuralRenderer, PrepareOptions, PreparedInput, Scene, SceneNeural, SharedNeural, SourceView,
};
use r2human::xr::{run_session, Placement, SessionConfig, StaticScene};

/// Eye image size cap used in all paths (the CLI default).
const EYE_SIDE: u32 = 384;

fn prepared() -> PreparedInput {
    let (rgb, mask) = xr_support::figure(512);
    PreparedInput::prepare(&rgb, &mask, &PrepareOptions::default()).expect("prepare")
}

fn config(frames: u64) -> SessionConfig {
    SessionConfig {
        mode: Mode::Vr,
        max_person_frames: Some(frames.max(1)),
        max_duration: Some(Duration::from_secs(120)),
        eye_max_side: EYE_SIDE,
        capture: false,
        mirror: false,
        ..Default::default()
    }
}

fn bench_xr(c: &mut Criterion) {
    let input = prepared();
    let env = Environment::default_embedded();

    // Desktop paths: the same per-eye work for a typical eye (1.6 m high, person 1.75 m ahead), the head moving a
    // little every frame so nothing is reused.
    let mut group = c.benchmark_group("desktop");
    group.sample_size(10);
    let head = Vec3::new(0.0, 1.6, 0.0);
    let placement = Placement::in_front_of(head, Quat::IDENTITY, 0.0, 1.75);
    let fov = Fov { angle_left: -0.7, angle_right: 0.7, angle_up: 0.6, angle_down: -0.6 };
    let (w, h) = (EYE_SIDE as usize, (EYE_SIDE as f32 * 0.6f32.tan() / 0.7f32.tan()).round() as usize);
    let eye_camera = |k: u64| {
        let p = head + Vec3::new(0.002 * (k % 50) as f32, 0.0, 0.0);
        (placement.eye_camera(p, Quat::IDENTITY, fov, w, h), Placement::stage_camera(p, Quat::IDENTITY, fov, w, h))
    };
    match Context::headless() {
        Ok(ctx) => {
            let ctx = Arc::new(ctx);
            let mut renderer = Renderer::new(ctx, w, h).expect("renderer");
            let scene = Scene::from_prepared(&input, None);
            renderer.set_scene(&scene.source()).expect("scene");
            renderer.set_environment(&env).expect("panorama");
            renderer.set_fusion(true);
            let mut k = 0u64;
            group.bench_function("gpu_eye_render", |b| {
                b.iter(|| {
                    k += 1;
                    renderer.render_frame(&eye_camera(k).0, Mode::Vr, None).expect("render")
                })
            });
        }
        Err(e) => println!("desktop/gpu_eye_render skipped: {e}"),
    }
    let mut view = r2human::pipeline::ViewRenderer::new(&input, Default::default(), true);
    let mut k = 0u64;
    group.bench_function("cpu_eye_render", |b| {
        b.iter(|| {
            k += 1;
            let (body, stage) = eye_camera(k);
            let person = view.render_person(&body).expect("render");
            compose::compose_vr(&person, &env, &stage)
        })
    });
    // The neural renderer for the same eyes: the Vulkan path through host memory (what the XR render thread
    // runs) and the CPU per-view path.
    let neural = load_neural();
    if let Some((shared, encoded)) = &neural {
        if let Ok(ctx) = Context::headless() {
            let mut renderer = Renderer::new(Arc::new(ctx), w, h).expect("renderer");
            offline::upload_scene(&mut renderer, &SourceView::of(&input), Some(&env), OcclusionFill::default(), true)
                .expect("upload");
            let source = SourceView::of(&input);
            group.bench_function("gpu_eye_render_neural", |b| {
                b.iter(|| {
                    k += 1;
                    let body = eye_camera(k).0;
                    let (person, _) = gpu_neural_person(&mut renderer, shared, source, encoded, &body).expect("neural");
                    renderer.render_frame_from_person(Some(&person), &body, Mode::Vr, None).expect("compose")
                })
            });
        }
        let mut view = r2human::pipeline::ViewRenderer::with_neural(
            &input,
            Default::default(),
            true,
            Arc::clone(shared),
            encoded.clone(),
        );
        group.bench_function("cpu_eye_render_neural", |b| {
            b.iter(|| {
                k += 1;
                let (body, stage) = eye_camera(k);
                let person = view.render_person(&body).expect("render");
                compose::compose_vr(&person, &env, &stage)
            })
        });
    }
    group.finish();

    // XR: time per submitted frame with the simulated HMD while the GPU renders the person per eye.
    let mut group = c.benchmark_group("xr_simulated_hmd");
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(20));
    group.bench_function("frame_interval", |b| {
        b.iter_custom(|iters| {
            let feed = Box::new(StaticScene::new(Scene::from_prepared(&input, None)));
            let report = run_session(&config(iters), feed, Some(env.clone())).expect("XR session");
            let interval = if report.display_fps > 0.0 { 1.0 / report.display_fps } else { 1.0 };
            Duration::from_secs_f64(interval * iters as f64)
        })
    });
    group.finish();

    // One longer session for the pacing numbers criterion cannot express (not in `cargo test`'s quick run).
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    println!("\nload average at the start of the sessions: {}", load_average());
    let feed = Box::new(StaticScene::new(Scene::from_prepared(&input, None)));
    // 600 person frames (about 11 s at the XCB compositor's rate): a few dozen eye renders per renderer.
    let report = run_session(&config(600), feed, Some(env.clone())).expect("XR session");
    println!("\nXR session with the simulated HMD (600 person frames, geometric renderer):\n{report}\n");
    if let Some((shared, encoded)) = &neural {
        let eye = SceneNeural { renderer: Arc::clone(shared), encoded: encoded.clone() };
        let feed = Box::new(StaticScene::new(Scene::from_prepared(&input, Some(eye))));
        let report = run_session(&config(600), feed, Some(env.clone())).expect("XR session");
        println!("\nXR session with the simulated HMD (600 person frames, neural renderer):\n{report}\n");
    }
    desktop_view_runs();
    println!("load average at the end: {}", load_average());
}

/// The shipped `models/tiny` on the ONNX Runtime CPU provider and the encoder's output for the bench input, or
/// `None` (printed) when they cannot be loaded.
fn load_neural() -> Option<(SharedNeural, NeuralInput)> {
    let models = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/tiny");
    let options = RuntimeOptions { ep: ExecutionProvider::Cpu, ..Default::default() };
    match NeuralRenderer::load(&models, &options) {
        Ok(n) => {
            let shared = Arc::new(Mutex::new(n));
            let encoded = shared.lock().expect("lock").encode(&prepared()).expect("encoder");
            Some((shared, encoded))
        }
        Err(e) => {
            println!("neural benchmarks skipped: {e}");
            None
        }
    }
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg").map(|s| s.trim().to_string()).unwrap_or_else(|_| "unknown".into())
}

/// The desktop window in the same run (Xvfb inside the root): `r2human view --frames 60 --spin 3` with each
/// renderer, at the eye size, turning so every frame is a new view.
fn desktop_view_runs() {
    let Ok(display) = std::env::var("DISPLAY") else {
        println!("desktop view runs skipped: no DISPLAY (run the bench through run-in-root.sh --xvfb)");
        return;
    };
    let dir = tempfile::tempdir().expect("temp dir");
    let person = dir.path().join("person.png");
    let (rgb, mask) = xr_support::figure(512);
    let rgba = RgbaImage::from_fn(512, 512, |c, r| (*rgb.get(c, r) * *mask.get(c, r)).extend(*mask.get(c, r)));
    r2human::io::image_io::save_rgba_png(&person, &rgba).expect("write the person");
    // The Vulkan passes in the window, as the XR eyes use them (`view`'s default `auto` picks the CPU reference
    // on lavapipe).
    for renderer in ["geometric", "neural"] {
        let out = Command::new(env!("CARGO_BIN_EXE_r2human"))
            .args(["view", "--frames", "60", "--spin", "3", "--size", &EYE_SIDE.to_string(), "--ep", "cpu"])
            .args(["--backend", "vulkan", "--renderer", renderer, "--image"])
            .arg(&person)
            .env("DISPLAY", &display)
            .stdin(Stdio::null())
            .output();
        match out {
            Ok(o) => println!(
                "desktop view ({renderer}): {}{}",
                String::from_utf8_lossy(&o.stdout).trim(),
                if o.status.success() {
                    String::new()
                } else {
                    format!(" FAILED: {}", String::from_utf8_lossy(&o.stderr))
                }
            ),
            Err(e) => println!("desktop view ({renderer}) could not start: {e}"),
        }
    }
}

criterion_group!(benches, bench_xr);

fn main() {
    if std::env::var("R2HUMAN_XR_IN_ROOT").is_err() {
        // Re-run inside the Monado root, with Xvfb so the compositor is not throttled to 20 Hz.
        let root = Command::new("id").arg("-u").output().map(|o| o.stdout.starts_with(b"0")).unwrap_or(false);
        if !root {
            println!("xr bench skipped: entering the Monado root needs root (mount, chroot)");
            return;
        }
        let dir = env!("CARGO_MANIFEST_DIR");
        let made = Command::new(format!("{dir}/scripts/xr/make-root.sh")).stdin(Stdio::null()).status();
        if !made.is_ok_and(|s| s.success()) {
            println!("xr bench skipped: the Monado root could not be built (scripts/xr/make-root.sh)");
            return;
        }
        let exe = std::env::current_exe().expect("bench binary path");
        let status = Command::new(format!("{dir}/scripts/xr/run-in-root.sh"))
            .arg("--xvfb")
            .arg(exe)
            .args(std::env::args().skip(1))
            .current_dir(dir)
            .stdin(Stdio::null())
            .status()
            .expect("run-in-root.sh");
        std::process::exit(status.code().unwrap_or(1));
    }
    benches();
    Criterion::default().configure_from_args().final_summary();
}
