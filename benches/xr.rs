//! XR frame rate and per-eye render time with Monado's simulated HMD, against the desktop paths, in one run.
//!
//! `cargo bench --bench xr` (as root) builds or reuses the Monado root (scripts/xr/make-root.sh) and re-runs
//! itself inside it through `scripts/xr/run-in-root.sh --xvfb`: Monado's XCB compositor on Xvfb paces at display
//! rate (about 55 Hz) instead of the null compositor's fixed 20 Hz. Measured:
//! - `desktop/gpu_eye_render`: one eye image (person + panorama) on the Vulkan renderer, headless, no XR at all;
//! - `desktop/cpu_eye_render`: the same eye through the CPU reference pipeline;
//! - `xr_simulated_hmd/frame_interval`: time per submitted XR frame while the GPU renders the person per eye;
//! - after the benchmarks, one session's report: per-eye GPU render time inside the session, fresh-render share,
//!   motion-to-photon latency of the person layer, and the frame loop's waits for the shared Vulkan queue.

#[path = "../tests/xr_support/mod.rs"]
mod xr_support;

use std::process::{Command, Stdio};
use std::sync::Arc;
use std::time::Duration;

use criterion::{criterion_group, Criterion};
use glam::{Quat, Vec3};
use r2human::app::xr_session::scene_from_prepared;
use r2human::compose::{self, Mode};
use r2human::geometry::camera::Fov;
use r2human::gpu::{Context, Renderer};
use r2human::io::environment::Environment;
use r2human::pipeline::{PrepareOptions, PreparedInput};
use r2human::xr::{run_session, Placement, SessionConfig, StaticScene, XrMode};

/// Eye image size cap used in all paths (the CLI default).
const EYE_SIDE: u32 = 384;

fn prepared() -> PreparedInput {
    let (rgb, mask) = xr_support::figure(512);
    PreparedInput::prepare(&rgb, &mask, &PrepareOptions::default()).expect("prepare")
}

fn config(frames: u64) -> SessionConfig {
    SessionConfig {
        mode: XrMode::Vr,
        max_person_frames: Some(frames.max(1)),
        max_duration: Some(Duration::from_secs(120)),
        eye_max_side: EYE_SIDE,
        capture: false,
        mirror: false,
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
            let scene = scene_from_prepared(&input);
            renderer.set_mesh(&scene.mesh).expect("mesh");
            renderer
                .set_source_parts(&scene.source_rgb, &scene.source_mask, &scene.source_gbuffer, &scene.source_camera)
                .expect("source");
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
    group.finish();

    // XR: time per submitted frame with the simulated HMD while the GPU renders the person per eye.
    let mut group = c.benchmark_group("xr_simulated_hmd");
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(20));
    group.bench_function("frame_interval", |b| {
        b.iter_custom(|iters| {
            let feed = Box::new(StaticScene::new(scene_from_prepared(&input)));
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
    let feed = Box::new(StaticScene::new(scene_from_prepared(&input)));
    let report = run_session(&config(200), feed, Some(env.clone())).expect("XR session");
    println!("\nXR session with the simulated HMD (200 person frames):\n{report}\n");
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
