//! End-to-end stage times at 512x512 on a synthetic figure: the per-input stages (normalise, inflation -> FOF,
//! marching cubes, source raster) and the per-view stages (target raster, flow/Z-map/warp, panorama compose).
//! `cargo bench --bench pipeline`; docs/performance.md quotes the medians.

#[path = "../tests/common/mod.rs"]
mod common;

use criterion::{criterion_group, criterion_main, Criterion};
use r2human::compose::{self, Mode};
use r2human::geometry::Camera;
use r2human::io::environment::Environment;
use r2human::io::image_io;
use r2human::pipeline::warp::OcclusionFill;
use r2human::pipeline::{PrepareOptions, PreparedInput, ViewRenderer};

fn bench(c: &mut Criterion) {
    let photo = image_io::from_dynamic(&image::DynamicImage::ImageRgba8(common::figure_rgba(600, 800)));
    let mask = photo.alpha.clone().unwrap();
    let opts = PrepareOptions::default();
    let mut g = c.benchmark_group("pipeline_512");
    g.sample_size(10);
    g.bench_function("per_input_prepare", |b| b.iter(|| PreparedInput::prepare(&photo.rgb, &mask, &opts).unwrap()));
    let prepared = PreparedInput::prepare(&photo.rgb, &mask, &opts).unwrap();
    let env = Environment::default_embedded();
    let cam = Camera::orbit(135.0, 10.0, 512, 512);
    let mut renderer = ViewRenderer::new(&prepared, OcclusionFill::MirroredFront, false);
    g.bench_function("per_view_person", |b| b.iter(|| renderer.render_person(&cam).unwrap()));
    let person = renderer.render_person(&cam).unwrap();
    g.bench_function("per_view_compose_vr", |b| b.iter(|| compose::compose_vr(&person, &env, &cam)));
    g.bench_function("per_view_total_vr", |b| b.iter(|| renderer.render_frame(&cam, Mode::Vr, &env).unwrap()));
    g.bench_function("per_view_total_ar", |b| b.iter(|| renderer.render_frame(&cam, Mode::Ar, &env).unwrap()));
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
