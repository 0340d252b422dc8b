//! Per-view frame time at 512x512, Vulkan passes against the CPU reference, in the same run and on the same
//! prepared input, per stage and in total:
//! - raster (target depth/normals), flow + Z-map + visibility + warp + hole fill, VR panorama compose, and the
//!   whole frame (which adds spatial fusion);
//! - the Vulkan total is measured by criterion (wall clock: record, submit, wait); the Vulkan stages are GPU
//!   timestamps of the same frames ([`Renderer::stage_times`]), whose medians are printed at the end.
//!
//! The camera moves every iteration, so no stage is skipped as "unchanged view". The run also checks what a
//! frame costs besides time: host heap allocations (a counting global allocator) and resources, pipelines and
//! uploads ([`Renderer::counters`]) over the measured frames; it prints both and fails if either is not zero.
//!
//! A second group times the neural renderer per view (`models/tiny`, when it loads): the CPU per-view path against
//! the Vulkan path through the host-memory seam the window and the XR eyes use.
//!
//! `cargo bench --bench gpu` (criterion prints medians). On this machine the Vulkan device is lavapipe, a CPU
//! rasteriser sharing the cores with everything else: the comparison is then CPU code against CPU code.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use glam::Vec3;
use r2human::buffer::Image;
use r2human::compose::{self, Mode};
use r2human::geometry::raster::{rasterize, rasterize_into, GBuffer};
use r2human::geometry::Camera;
use r2human::gpu::{gpu_neural_person, offline, Context, Renderer};
use r2human::io::environment::Environment;
use r2human::neural::{ExecutionProvider, RuntimeOptions};
use r2human::pipeline::warp::{render_geometric, OcclusionFill};
use r2human::pipeline::{NeuralRenderer, PrepareOptions, PreparedInput, SourceView, ViewRenderer};

const SIZE: usize = 512;

/// Counts heap allocations while `COUNTING` is on (the measured loop runs on one thread).
struct CountingAllocator;
static COUNTING: AtomicBool = AtomicBool::new(false);
static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);

// SAFETY: forwards to the system allocator.
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: CountingAllocator = CountingAllocator;

/// A person-like silhouette (head, torso, arms, legs) with a colour gradient, as a photo + mask.
fn person() -> (r2human::buffer::RgbImage, r2human::buffer::GrayImage) {
    let n = 400;
    let inside = |x: f32, y: f32| {
        let head = ((x - 200.0) / 34.0).powi(2) + ((y - 70.0) / 42.0).powi(2) <= 1.0;
        let torso = (140.0..260.0).contains(&x) && (115.0..250.0).contains(&y);
        let arms = ((105.0..135.0).contains(&x) || (265.0..295.0).contains(&x)) && (120.0..240.0).contains(&y);
        let legs = ((150.0..192.0).contains(&x) || (208.0..250.0).contains(&x)) && (245.0..380.0).contains(&y);
        head || torso || arms || legs
    };
    let mask = Image::from_fn(n, n, |c, r| if inside(c as f32 + 0.5, r as f32 + 0.5) { 1.0 } else { 0.0 });
    let rgb = Image::from_fn(n, n, |c, r| Vec3::new(c as f32 / n as f32, 0.3 + 0.4 * (r as f32 / n as f32), 0.6));
    (rgb, mask)
}

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v.get(v.len() / 2).copied().unwrap_or_default()
}

fn bench(c: &mut Criterion) {
    let (rgb, mask) = person();
    let input = PreparedInput::prepare(&rgb, &mask, &PrepareOptions::default()).expect("the bench input prepares");
    eprintln!("mesh: {} triangles, source {}x{}", input.mesh.triangle_count(), SIZE, SIZE);
    let env = Environment::default_embedded();
    let fill = OcclusionFill::default();
    // Cameras cycled by every benchmark; targets precomputed for the CPU stages that take one as input.
    let cams: Vec<Camera> = (0..16).map(|i| Camera::orbit(7.0 + 23.0 * i as f32, 10.0, SIZE, SIZE)).collect();
    let targets: Vec<GBuffer> = cams.iter().map(|cam| rasterize(&input.mesh, cam)).collect();
    let people: Vec<_> = cams
        .iter()
        .zip(&targets)
        .map(|(cam, t)| {
            render_geometric(
                &input.normalised.rgb,
                &input.normalised.mask,
                &input.source_gbuffer,
                &input.source_camera,
                t,
                cam,
                fill,
            )
        })
        .collect();

    let mut group = c.benchmark_group("per_view_512");
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(6));

    let mut k = 0usize;
    let mut target = GBuffer::new(0, 0);
    group.bench_function("cpu/raster", |b| {
        b.iter(|| {
            k += 1;
            rasterize_into(&mut target, &input.mesh, &cams[k % cams.len()]);
        })
    });
    group.bench_function("cpu/flow_zmap_warp", |b| {
        b.iter(|| {
            k += 1;
            let i = k % cams.len();
            render_geometric(
                &input.normalised.rgb,
                &input.normalised.mask,
                &input.source_gbuffer,
                &input.source_camera,
                &targets[i],
                &cams[i],
                fill,
            )
        })
    });
    group.bench_function("cpu/compose_vr", |b| {
        b.iter(|| {
            k += 1;
            let i = k % cams.len();
            compose::compose_vr(&people[i], &env, &cams[i])
        })
    });
    let mut cpu = ViewRenderer::new(&input, fill, true);
    group.bench_function("cpu/total_vr", |b| {
        b.iter(|| {
            k += 1;
            cpu.render_frame(&cams[k % cams.len()], Mode::Vr, &env).expect("CPU frame")
        })
    });

    match Context::headless() {
        Ok(ctx) => {
            let ctx = Arc::new(ctx);
            eprintln!("Vulkan device: {}", ctx.device_name());
            let mut gpu = Renderer::new(ctx, SIZE, SIZE).expect("renderer");
            offline::upload_scene(&mut gpu, &SourceView::of(&input), Some(&env), fill, true).expect("upload");
            gpu.render_frame(&cams[0], Mode::Vr, None).expect("warm-up frame");
            let before = gpu.counters();
            let mut stages: Vec<Vec<Duration>> = vec![Vec::new(); 4];
            let mut frames = 0u64;
            let mut allocations = 0u64;
            group.bench_function("vulkan/total_vr", |b| {
                b.iter(|| {
                    k += 1;
                    ALLOCATIONS.store(0, Ordering::Relaxed);
                    COUNTING.store(true, Ordering::Relaxed);
                    let r = gpu.render_frame(&cams[k % cams.len()], Mode::Vr, None);
                    COUNTING.store(false, Ordering::Relaxed);
                    allocations += ALLOCATIONS.load(Ordering::Relaxed);
                    frames += 1;
                    r.expect("GPU frame");
                    let mut sums = [Duration::ZERO; 4];
                    for (name, d) in gpu.stage_times() {
                        let slot = match *name {
                            "raster" => 0,
                            "flow + Z-map" | "warp" | "hole fill" => 1,
                            "compose VR" => 2,
                            _ => 3,
                        };
                        sums[slot] += *d;
                    }
                    for (s, d) in stages.iter_mut().zip(sums) {
                        s.push(d);
                    }
                })
            });
            let after = gpu.counters();
            let ms = |d: Duration| d.as_secs_f64() * 1e3;
            if stages[0].iter().any(|d| !d.is_zero()) {
                let [raster, warp, compose, rest] = [0, 1, 2, 3].map(|i| median(stages[i].clone()));
                eprintln!(
                    "vulkan GPU-timestamp medians over {frames} frames (ms): raster {:.2}, flow+Z-map+warp+hole fill \
                     {:.2}, compose VR {:.2}, fusion + copies {:.2}",
                    ms(raster),
                    ms(warp),
                    ms(compose),
                    ms(rest)
                );
            } else {
                eprintln!("the device has no timestamp queries: no Vulkan per-stage times");
            }
            eprintln!(
                "per-frame cost over {} measured frames: {allocations} host allocations; resources created {}, \
                 pipelines created {}, mesh uploads {}, source uploads {}",
                after.frames - before.frames,
                after.resources_created - before.resources_created,
                after.pipelines_created - before.pipelines_created,
                after.mesh_uploads - before.mesh_uploads,
                after.source_uploads - before.source_uploads,
            );
            assert_eq!(allocations, 0, "a Vulkan frame allocated on the host");
            assert_eq!(
                (after.resources_created, after.pipelines_created, after.mesh_uploads, after.source_uploads),
                (before.resources_created, before.pipelines_created, before.mesh_uploads, before.source_uploads),
                "a Vulkan frame created resources or uploaded inputs"
            );
        }
        Err(e) => eprintln!("SKIPPED the Vulkan benchmarks: {e}"),
    }
    group.finish();
    bench_neural(c, &input, &env, &cams);
}

/// The neural renderer per view at 512x512 (`models/tiny`, ONNX Runtime CPU provider), in the same run: the CPU
/// per-view path (`ViewRenderer::with_neural`) against the window's and the XR eyes' Vulkan path through the
/// host-memory seam (GPU raster + flow read back, lookup + decoder on the host, fusion + compose on the GPU).
/// The camera moves every iteration, so the decoder runs every time.
fn bench_neural(c: &mut Criterion, input: &PreparedInput, env: &Environment, cams: &[Camera]) {
    let models = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/tiny");
    let options = RuntimeOptions { ep: ExecutionProvider::Cpu, ..Default::default() };
    let shared = match NeuralRenderer::load(&models, &options) {
        Ok(n) => Arc::new(Mutex::new(n)),
        Err(e) => {
            eprintln!("SKIPPED the neural benchmarks: {e}");
            return;
        }
    };
    let encoded = shared.lock().expect("lock").encode(input).expect("encoder");
    eprintln!("encoder (once per input): {:.1} ms", encoded.encode_time.as_secs_f64() * 1e3);
    let mut group = c.benchmark_group("per_view_512_neural");
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(10));
    let mut k = 0usize;
    let mut cpu =
        ViewRenderer::with_neural(input, OcclusionFill::default(), true, Arc::clone(&shared), encoded.clone());
    group.bench_function("cpu/neural_total_vr", |b| {
        b.iter(|| {
            k += 1;
            cpu.render_frame(&cams[k % cams.len()], Mode::Vr, env).expect("CPU neural frame")
        })
    });
    assert_eq!(cpu.neural_fallbacks(), 0, "the decoder failed on the CPU path");
    match Context::headless() {
        Ok(ctx) => {
            let mut gpu = Renderer::new(Arc::new(ctx), SIZE, SIZE).expect("renderer");
            offline::upload_scene(&mut gpu, &SourceView::of(input), Some(env), OcclusionFill::default(), true)
                .expect("upload");
            let source = SourceView::of(input);
            let (mut gpu_inputs, mut decoder) = (Vec::new(), Vec::new());
            group.bench_function("vulkan/neural_seam_total_vr", |b| {
                b.iter(|| {
                    k += 1;
                    let cam = &cams[k % cams.len()];
                    let (person, times) =
                        gpu_neural_person(&mut gpu, &shared, source, &encoded, cam).expect("neural view");
                    gpu.render_frame_from_person(Some(&person), cam, Mode::Vr, None).expect("compose");
                    gpu_inputs.push(times.gpu_inputs);
                    decoder.push(times.decoder);
                })
            });
            eprintln!(
                "vulkan neural seam medians (ms): GPU raster + flow incl. read-back {:.2}, lookup + decoder {:.2}",
                median(gpu_inputs).as_secs_f64() * 1e3,
                median(decoder).as_secs_f64() * 1e3
            );
        }
        Err(e) => eprintln!("SKIPPED the Vulkan neural benchmark: {e}"),
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
