//! Per-view frame time at 512x512, Vulkan passes against the CPU reference, in the same run and on the same
//! prepared input: raster -> flow/Z-map/visibility -> warp (+ hole fill) -> spatial fusion -> VR panorama
//! composite. The camera moves every iteration, so no stage is skipped as "unchanged view".
//!
//! `cargo bench --bench gpu` (criterion prints medians). On this machine the Vulkan device is lavapipe, a CPU
//! rasteriser: the comparison is then CPU code against CPU code.

use std::sync::Arc;

use criterion::{criterion_group, criterion_main, Criterion};
use glam::Vec3;
use r2human::buffer::Image;
use r2human::compose::Mode;
use r2human::geometry::Camera;
use r2human::gpu::{Context, Renderer};
use r2human::io::environment::Environment;
use r2human::pipeline::warp::OcclusionFill;
use r2human::pipeline::{PrepareOptions, PreparedInput, ViewRenderer};

const SIZE: usize = 512;

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

fn bench(c: &mut Criterion) {
    let (rgb, mask) = person();
    let input = PreparedInput::prepare(&rgb, &mask, &PrepareOptions::default()).expect("the bench input prepares");
    let env = Environment::default_embedded();
    let mut group = c.benchmark_group("per_view_512");
    group.sample_size(10);
    group.measurement_time(std::time::Duration::from_secs(8));

    let mut cpu = ViewRenderer::new(&input, OcclusionFill::default(), true);
    let mut yaw = 0.0f32;
    group.bench_function("cpu_reference_vr", |b| {
        b.iter(|| {
            yaw += 7.0;
            cpu.render_frame(&Camera::orbit(yaw, 10.0, SIZE, SIZE), Mode::Vr, &env).expect("CPU frame")
        })
    });

    match Context::headless() {
        Ok(ctx) => {
            let ctx = Arc::new(ctx);
            eprintln!("Vulkan device: {}", ctx.device_name());
            let mut gpu = Renderer::new(ctx, SIZE, SIZE).expect("renderer");
            gpu.set_mesh(&input.mesh).expect("mesh");
            gpu.set_source_parts(
                &input.normalised.rgb,
                &input.normalised.mask,
                &input.source_gbuffer,
                &input.source_camera,
            )
            .expect("source");
            gpu.set_environment(&env).expect("panorama");
            gpu.set_fusion(true);
            let mut yaw = 0.0f32;
            group.bench_function("vulkan_vr", |b| {
                b.iter(|| {
                    yaw += 7.0;
                    gpu.render_frame(&Camera::orbit(yaw, 10.0, SIZE, SIZE), Mode::Vr, None).expect("GPU frame")
                })
            });
            group.bench_function("vulkan_ar", |b| {
                b.iter(|| {
                    yaw += 7.0;
                    gpu.render_frame(&Camera::orbit(yaw, 10.0, SIZE, SIZE), Mode::Ar, None).expect("GPU frame")
                })
            });
        }
        Err(e) => eprintln!("SKIPPED the Vulkan benchmarks: {e}"),
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
