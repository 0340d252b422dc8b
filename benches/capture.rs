//! Live-input stages: clean-plate segmentation, mask cleanup and smoothing at webcam size (640x480), frame
//! decoding from an image sequence, the ONNX segmentation model (when installed) and the whole live loop (without
//! and with the neural encoder), whose per-stage medians are written to `target/capture_stages.json`.
//!
//! `cargo bench --bench capture`

use std::sync::{Arc, Mutex};
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use r2human::app::live::{EncodeProcessor, LiveOptions, LivePipeline};
use r2human::capture::morph::{close, fill_holes, largest_component, open, threshold};
use r2human::capture::segment::{CleanPlate, PlateParams};
use r2human::capture::smooth::{MaskSmoother, VecSmoother};
use r2human::capture::synthetic::{composite, empty_scene, walker, WalkerParams, WalkerSource};
use r2human::capture::{open_video_path, Frame, FrameSource, SegmentMethod, SourceEvent};
use r2human::neural::{ExecutionProvider, RuntimeOptions};
use r2human::pipeline::{NeuralRenderer, PrepareOptions};

fn vga() -> WalkerParams {
    WalkerParams { width: 640, height: 480, frames: 16, fps: 30.0, noise: 0.01 }
}

fn bench_segmentation(c: &mut Criterion) {
    let p = vga();
    let plate_frames: Vec<_> = (0..5).map(|i| empty_scene(&p, i)).collect();
    let plate = CleanPlate::from_frames(&plate_frames).expect("plate");
    let (rgb, truth) = composite(&p, 3);
    let params = PlateParams::default();
    let mut g = c.benchmark_group("capture_640x480");
    g.sample_size(20);
    g.bench_function("clean_plate_segment", |b| b.iter(|| plate.segment(&rgb, &params).expect("segment")));
    let raw = threshold(&truth, 0.5);
    g.bench_function("morphology_open_close_component_fill", |b| {
        b.iter(|| fill_holes(&largest_component(&close(&open(&raw, 1), 2))))
    });
    let mut smoother = MaskSmoother::new(0.6, 0.6);
    let (_, other) = walker(&p, 4);
    let mut flip = false;
    g.bench_function("mask_ema", |b| {
        b.iter(|| {
            flip = !flip;
            smoother.update(if flip { &truth } else { &other })
        })
    });
    // The live loop's FOF smoothing: 512x512 pixels x 32 coefficients, two frames that differ by a few percent
    // (the EMA path, no reset), as `app::live` configures it.
    let len = 512 * 512 * 32;
    let frame_a: Vec<f32> = (0..len).map(|i| ((i % 977) as f32 * 0.01).sin()).collect();
    let frame_b: Vec<f32> = frame_a.iter().map(|v| v * 1.03).collect();
    let mut fof_smoother = VecSmoother::new(0.6, 0.5);
    let mut work = frame_a.clone();
    g.bench_function("fof_ema_512x512x32", |b| {
        b.iter(|| {
            flip = !flip;
            work.copy_from_slice(if flip { &frame_a } else { &frame_b });
            fof_smoother.update(&mut work);
        })
    });
    assert_eq!(fof_smoother.resets(), 1, "the FOF bench frames should take the EMA path");
    g.finish();
}

fn bench_decode(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = vga();
    for i in 0..4 {
        let (rgb, _) = composite(&p, i);
        r2human::io::image_io::save_rgb_png(&dir.path().join(format!("f{i}.png")), &rgb).expect("write");
    }
    let mut g = c.benchmark_group("capture_640x480");
    g.sample_size(10);
    g.bench_function("png_sequence_decode_frame", |b| {
        b.iter(|| {
            let mut src = open_video_path(dir.path(), 30.0).expect("open");
            let mut n = 0;
            while let Ok(SourceEvent::Frame(_)) = src.next_frame() {
                n += 1;
            }
            n
        })
    });
    g.finish();
}

fn bench_onnx(c: &mut Criterion) {
    let models = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(".tools/models");
    for (name, file, size) in
        [("onnx_pose_256", "pose_landmark_full.onnx", 256), ("onnx_isnet_512", "isnet_seg.onnx", 512)]
    {
        let mut seg = match (SegmentMethod::Onnx { model: Some(models.join(file)), input_size: size }).build(None) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("{name} not benchmarked: {e}");
                continue;
            }
        };
        let p = vga();
        let (rgb, _) = composite(&p, 2);
        let frame = Frame { index: 0, timestamp: Duration::ZERO, rgb, alpha: None };
        let mut g = c.benchmark_group("capture_640x480");
        g.sample_size(10).measurement_time(Duration::from_secs(20));
        g.bench_function(name, |b| b.iter(|| seg.segment(&frame).expect("segment")));
        g.finish();
    }
}

/// Runs the live loop over a 640x480 walker delivered at 30 fps with clean-plate segmentation and the core
/// pipeline (normalise, inflation FOF, mesh, source raster at 512^2), once without and once with the neural
/// encoder (`models/tiny` on the CPU provider, when it loads), and writes the per-stage medians (the numbers the
/// window shows, "encoder" included) to target/capture_stages.json.
fn live_loop_stages(_c: &mut Criterion) {
    let models = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/tiny");
    let options = RuntimeOptions { ep: ExecutionProvider::Cpu, ..Default::default() };
    let neural = match NeuralRenderer::load(&models, &options) {
        Ok(n) => Some(Arc::new(Mutex::new(n))),
        Err(e) => {
            eprintln!("the live loop runs without the encoder: {e}");
            None
        }
    };
    let mut runs = serde_json::Map::new();
    for (name, encoder) in [("geometric", None), ("neural", neural)] {
        if name == "neural" && encoder.is_none() {
            continue;
        }
        let p = WalkerParams { frames: 90, ..vga() };
        let opts = LiveOptions {
            segment: SegmentMethod::CleanPlate { plate: None, plate_frames: 5 },
            ..LiveOptions::default()
        };
        let pp = p.clone();
        let live = LivePipeline::start(
            Box::new(move || Ok(Box::new(WalkerSource::new(pp, 5, false)) as Box<dyn FrameSource>)),
            EncodeProcessor::new(PrepareOptions::default(), encoder),
            opts,
        )
        .expect("start");
        live.wait(Duration::from_secs(180));
        let stats = live.stop();
        let stages: Vec<serde_json::Value> = stats
            .stages
            .iter()
            .map(|s| serde_json::json!({"stage": s.name, "median_ms": s.median_ms(), "samples": s.total}))
            .collect();
        runs.insert(
            name.to_string(),
            serde_json::json!({
                "read": stats.read, "dropped": stats.dropped, "completed": stats.completed,
                "throughput_fps": stats.throughput_fps, "source_fps": stats.source_fps, "stages": stages,
            }),
        );
        println!("live loop ({name}): {}", stats.overlay_line());
    }
    let json = serde_json::json!({
        "source": "synthetic walker 640x480 at 30 fps, clean-plate segmentation, core pipeline at 512^2; \
                   neural: + models/tiny encoder on the ONNX Runtime CPU provider, once per completed frame",
        "runs": runs,
    });
    let out = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target/capture_stages.json");
    let text = serde_json::to_string_pretty(&json).expect("json");
    if let Err(e) = std::fs::write(&out, &text) {
        eprintln!("cannot write {}: {e}", out.display());
    }
    println!("{text}");
}

criterion_group!(benches, bench_segmentation, bench_decode, bench_onnx, live_loop_stages);
criterion_main!(benches);
