//! Neural renderer speed on this machine's CPU (ONNX Runtime CPU provider): the decoder per view at 256x256 and
//! 512x512 over a person-shaped target mask, the encoder per input frame (512x512 source, resampled to the
//! model's resolution), for every tier whose models are present, and the whole per-view path of the shipped
//! `tiny` (target raster + flow/Z-map + colour lookup + decoder + panorama compose, `ViewRenderer::render_frame`)
//! at 256x256 against the 40 ms target, next to the geometric renderer on the same input. Per input, the FOF net
//! (`FofNet::refine_with`: the 512x512 inputs it declares in, the corrected 512x512 FOF out; a net that takes the
//! body FOF gets a thicker inflation FOF in its place, which costs the network the same) alone, and the whole
//! per-input preparation with `--geometry inflate` against `--geometry fofnet` (normalise, inflation, body prior
//! when the net takes it, network, marching cubes, source raster; on this bench's drawn mask the pose network may
//! find no person, and the body prior then falls back to the inflation prior: `cargo bench --bench still` times the
//! FOF-net path on real photos).
//!
//! Models: `models/<tier>` of the project (the shipped `tiny`), or the tier folders inside `R2HUMAN_BENCH_MODELS`.
//! Untrained `small`/`paper` models for speed measurements: `python -m train export-untrained --tier paper
//! --out /tmp/bench_models/paper` (see train/README.md). Threads: `R2HUMAN_BENCH_THREADS` (default: ONNX
//! Runtime's choice). Run: `cargo bench --bench neural`.

use std::hint::black_box;
use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion};
use glam::Vec3;
use r2human::buffer::{GrayImage, Image, RgbImage, RgbaImage};
use r2human::compose::Mode;
use r2human::geometry::inflate::{inflate_to_fof, InflateParams};
use r2human::geometry::Camera;
use r2human::io::environment::Environment;
use r2human::neural::{
    default_model_dir, Coefficients, Decoder, Encoder, EncoderInput, ExecutionProvider, FeatureMap, FofNet,
    RuntimeOptions, FOF_FILE,
};
use r2human::pipeline::warp::OcclusionFill;
use r2human::pipeline::{
    load_body_for, load_fof_net, load_renderer, GeometryMode, PrepareOptions, PreparedInput, RendererChoice,
    ViewRenderer,
};

fn model_dir(tier: &str) -> Option<PathBuf> {
    if let Some(root) = std::env::var_os("R2HUMAN_BENCH_MODELS") {
        let dir = PathBuf::from(root).join(tier);
        return dir.join("decoder.onnx").is_file().then_some(dir);
    }
    default_model_dir(tier)
}

fn options() -> RuntimeOptions {
    let threads = std::env::var("R2HUMAN_BENCH_THREADS").ok().and_then(|t| t.parse().ok());
    RuntimeOptions { ep: ExecutionProvider::Cpu, intra_threads: threads, ..Default::default() }
}

/// A standing person's silhouette at `size x size`: torso, head, arms and legs (about 20% of the frame; its
/// padded bounding box, which the decoder runs over, is about 40%).
fn person_mask(size: usize) -> GrayImage {
    let s = size as f32;
    GrayImage::from_fn(size, size, |c, r| {
        let (x, y) = ((c as f32 + 0.5) / s - 0.5, (r as f32 + 0.5) / s);
        let head = (x / 0.07).powi(2) + ((y - 0.12) / 0.08).powi(2) < 1.0;
        let torso = x.abs() < 0.13 && (0.2..0.55).contains(&y);
        let arms = (0.14..0.2).contains(&x.abs()) && (0.22..0.55).contains(&y);
        let legs = (0.02..0.11).contains(&x.abs()) && (0.55..0.95).contains(&y);
        if head || torso || arms || legs {
            1.0
        } else {
            0.0
        }
    })
}

fn bench_decoder(c: &mut Criterion) {
    let mut group = c.benchmark_group("neural_decoder");
    group.sample_size(10);
    for tier in ["tiny", "small", "paper"] {
        let Some(dir) = model_dir(tier) else {
            eprintln!("neural bench: no {tier} models, skipping (see the bench's module docs)");
            continue;
        };
        let mut dec = match Decoder::load(&dir.join("decoder.onnx"), &options()) {
            Ok(d) => d,
            Err(e) => {
                eprintln!("neural bench: {e}");
                continue;
            }
        };
        let ch = dec.info().feature_channels;
        for size in [256usize, 512] {
            let mask = person_mask(size);
            let n = size * size;
            let warped = FeatureMap {
                channels: ch,
                width: size,
                height: size,
                data: (0..ch * n).map(|i| ((i * 7919) % 1000) as f32 / 1000.0 - 0.5).collect(),
            };
            let z = GrayImage::from_fn(size, size, |c, _| c as f32 / size as f32 - 0.5);
            let normals = Image::new(size, size, Vec3::Z);
            let lookup = RgbaImage::from_fn(size, size, |c, r| {
                Vec3::new(0.5, c as f32 / size as f32, 0.3).extend(1.0) * *mask.get(c, r)
            });
            group.bench_function(format!("{tier}/{size}"), |b| {
                b.iter(|| black_box(dec.run(&warped, &lookup, &z, &normals, &mask).expect("decoder run")))
            });
        }
    }
    group.finish();
}

fn bench_encoder(c: &mut Criterion) {
    let mut group = c.benchmark_group("neural_encoder");
    group.sample_size(10);
    for tier in ["tiny", "small", "paper"] {
        let Some(dir) = model_dir(tier) else { continue };
        let mut enc = match Encoder::load(&dir.join("encoder.onnx"), &options()) {
            Ok(e) => e,
            Err(e) => {
                eprintln!("neural bench: {e}");
                continue;
            }
        };
        let fof_n = enc.info().fof_n;
        let size = 512;
        let mask = person_mask(size);
        let rgb = RgbImage::from_fn(size, size, |c, r| Vec3::new(0.6, 0.4, (c + r) as f32 / 1024.0) * *mask.get(c, r));
        let normals = Image::from_fn(size, size, |c, r| if *mask.get(c, r) > 0.0 { Vec3::Z } else { Vec3::ZERO });
        let fof: Vec<f32> = (0..size * size * fof_n).map(|i| ((i % 97) as f32 - 48.0) / 100.0).collect();
        let input = EncoderInput {
            rgb: &rgb,
            mask: &mask,
            fof: Some(Coefficients { width: size, height: size, n: fof_n, data: &fof }),
            normals: &normals,
        };
        group.bench_function(format!("{tier}/512-input"), |b| {
            b.iter(|| black_box(enc.run(&input).expect("encoder run")))
        });
    }
    group.finish();
}

/// The whole per-view path at 256x256 (VR frame over the panorama) for the shipped `tiny` and the geometric
/// renderer, on the person mask above turned into a prepared input at 512x512.
fn bench_per_view(c: &mut Criterion) {
    let Some(dir) = model_dir("tiny") else {
        eprintln!("neural bench: no tiny models, skipping the per-view bench");
        return;
    };
    let size = 512;
    let mask = person_mask(size);
    let rgb = RgbImage::from_fn(size, size, |c, r| Vec3::new(0.6, 0.4, (c + r) as f32 / 1024.0) * *mask.get(c, r));
    let prepared = PreparedInput::prepare(&rgb, &mask, &PrepareOptions::default()).expect("prepare");
    let neural = match load_renderer(RendererChoice::Neural, Some(&dir), &options()) {
        Ok(n) => n,
        Err(e) => {
            eprintln!("neural bench: {e}");
            return;
        }
    };
    let env = Environment::default_embedded();
    let mut group = c.benchmark_group("neural_per_view");
    group.sample_size(10);
    let cam = Camera::orbit(120.0, 10.0, 256, 256);
    let mut geo = ViewRenderer::new(&prepared, OcclusionFill::MirroredFront, false);
    group.bench_function("geometric/256", |b| b.iter(|| black_box(geo.render_frame(&cam, Mode::Vr, &env).unwrap())));
    let mut net = ViewRenderer::for_renderer(&prepared, OcclusionFill::MirroredFront, false, neural.as_ref());
    assert!(net.is_neural(), "the tiny encoder failed");
    group.bench_function("tiny/256", |b| b.iter(|| black_box(net.render_frame(&cam, Mode::Vr, &env).unwrap())));
    assert_eq!(net.neural_fallbacks(), 0, "the decoder fell back to the geometric renderer");
    group.finish();
}

/// The FOF net per input for every tier with a `fof.onnx`, and the per-input preparation of the shipped `tiny`
/// with the inflation prior against the FOF net.
fn bench_fof_net(c: &mut Criterion) {
    let size = 512;
    let mask = person_mask(size);
    let rgb = RgbImage::from_fn(size, size, |c, r| Vec3::new(0.6, 0.4, (c + r) as f32 / 1024.0) * *mask.get(c, r));
    let mut group = c.benchmark_group("fof_net");
    group.sample_size(10);
    for tier in ["tiny", "small", "paper"] {
        let Some(path) = model_dir(tier).map(|d| d.join(FOF_FILE)).filter(|p| p.is_file()) else { continue };
        let mut net = match FofNet::load(&path, &options()) {
            Ok(n) => n,
            Err(e) => {
                eprintln!("neural bench: {e}");
                continue;
            }
        };
        let prior = inflate_to_fof(&mask, net.info().fof_n, &InflateParams::default(), None).expect("inflation");
        let thicker = InflateParams { thickness: 1.3 * InflateParams::default().thickness, ..Default::default() };
        let body =
            net.takes_body().then(|| inflate_to_fof(&mask, net.info().fof_n, &thicker, None).expect("inflation"));
        group.bench_function(format!("{tier}/512-input"), |b| {
            b.iter(|| black_box(net.refine_with(&rgb, &mask, &prior, body.as_ref()).expect("FOF net run")))
        });
    }
    if let Some(dir) = model_dir("tiny").filter(|d| d.join(FOF_FILE).is_file()) {
        let inflate = PrepareOptions::default();
        group.bench_function("prepare/inflate", |b| {
            b.iter(|| black_box(PreparedInput::prepare(&rgb, &mask, &inflate).expect("prepare")))
        });
        let fof_net = load_fof_net(GeometryMode::FofNet, Some(&dir), inflate.fof_order, &options()).expect("fof.onnx");
        let body = load_body_for(GeometryMode::FofNet, fof_net.as_ref(), &options()).expect("body prior");
        let with_net = PrepareOptions { geometry: GeometryMode::FofNet, fof_net, body, ..PrepareOptions::default() };
        group.bench_function("prepare/fofnet-tiny", |b| {
            b.iter(|| black_box(PreparedInput::prepare(&rgb, &mask, &with_net).expect("prepare")))
        });
    } else {
        eprintln!("neural bench: no models/tiny/fof.onnx, skipping the FOF-net preparation bench");
    }
    group.finish();
}

criterion_group!(benches, bench_decoder, bench_encoder, bench_per_view, bench_fof_net);
criterion_main!(benches);
