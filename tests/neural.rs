//! Neural runtime tests against tiny ONNX fixtures with closed-form outputs (tests/data/neural/make_fixtures.py).
//! They need the ONNX Runtime library: `bash scripts/setup.d/neural.sh` (or ORT_DYLIB_PATH).

use std::path::{Path, PathBuf};

mod common;

use std::sync::{Arc, Mutex};

use glam::{Vec2, Vec3, Vec4};
use r2human::buffer::{linear_to_srgb, srgb_to_linear, GrayImage, Image, RgbImage, RgbaImage};
use r2human::geometry::raster::GBuffer;
use r2human::geometry::zmap::{flow_and_zmap, FlowZ, FLOW_OUTSIDE};
use r2human::geometry::Camera;
use r2human::io::image_io;
use r2human::neural::{
    environment, Coefficients, Decoder, Encoder, EncoderInput, ExecutionProvider, FeatureMap, FofNet, NeuralError,
    NeuralRuntime, RuntimeOptions,
};
use r2human::pipeline::warp::OcclusionFill;
use r2human::pipeline::{
    load_renderer, photo_lookup, NeuralRenderer, PipelineError, PrepareOptions, PreparedInput, RendererChoice,
    ViewRenderer,
};

const R: usize = 16;
const N: usize = 4;
const C: usize = 4;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/neural").join(name)
}

fn cpu() -> RuntimeOptions {
    RuntimeOptions { ep: ExecutionProvider::Cpu, intra_threads: Some(1), ..Default::default() }
}

/// A deterministic value in `[lo, hi)` from integer coordinates (no RNG dependency).
fn hash(a: usize, b: usize, c: usize, lo: f32, hi: f32) -> f32 {
    let mut x =
        (a as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (b as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F) ^ c as u64;
    x ^= x >> 29;
    x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^= x >> 32;
    lo + (hi - lo) * ((x % 10_000) as f32 / 10_000.0)
}

#[test]
fn gpu_requests_fall_back_to_cpu_with_the_cpu_library() {
    for ep in [ExecutionProvider::Cuda, ExecutionProvider::TensorRt, ExecutionProvider::Auto] {
        let opts = RuntimeOptions { ep, trt_fp16: true, ..cpu() };
        let enc = Encoder::load(&data("good/encoder.onnx"), &opts).unwrap_or_else(|e| panic!("{ep:?}: {e}"));
        assert_eq!(enc.provider().to_string(), "CPU", "{ep:?}");
    }
}

#[test]
fn encoder_matches_closed_form_and_resamples_larger_inputs() {
    let mut enc = Encoder::load(&data("good/encoder.onnx"), &cpu()).unwrap();
    assert_eq!((enc.info().resolution, enc.info().fof_n, enc.info().feature_channels), (R, N, C));
    assert_eq!(enc.info().tier, "test");
    for size in [R, 2 * R] {
        let k = size / R;
        let srgb = |i: usize| ((i / k) as f32 + 0.5) / R as f32; // constant per model pixel
        let rgb = RgbImage::from_fn(size, size, |c, r| {
            Vec3::new(srgb_to_linear(srgb(c)), srgb_to_linear(0.25 + 0.5 * srgb(r)), 0.0)
        });
        let mask = GrayImage::new(size, size, 1.0);
        let normals = Image::from_fn(size, size, |_, r| if r < size / 2 { Vec3::Z } else { Vec3::Y });
        let fof: Vec<f32> = (0..size * size).flat_map(|i| [0.5 + (i % size / k) as f32, 0.0, 0.0, -1.0]).collect();
        let input = EncoderInput {
            rgb: &rgb,
            mask: &mask,
            fof: Some(Coefficients { width: size, height: size, n: N, data: &fof }),
            normals: &normals,
        };
        let f = enc.run(&input).unwrap();
        assert_eq!((f.channels, f.width, f.height), (C, R / 4, R / 4));
        for by in 0..R / 4 {
            for bx in 0..R / 4 {
                // Block means of the model-resolution inputs (4x4 model pixels per feature pixel).
                let mean = |g: &dyn Fn(usize, usize) -> f32| {
                    let mut s = 0.0;
                    for y in by * 4..by * 4 + 4 {
                        for x in bx * 4..bx * 4 + 4 {
                            s += g(x, y);
                        }
                    }
                    s / 16.0
                };
                let red = mean(&|x, _| linear_to_srgb(srgb_to_linear((x as f32 + 0.5) / R as f32)) * 2.0 - 1.0);
                let green = mean(&|_, y| {
                    linear_to_srgb(srgb_to_linear(0.25 + 0.5 * ((y as f32 + 0.5) / R as f32))) * 2.0 - 1.0
                });
                let fof0 = mean(&|x, _| 0.5 + x as f32);
                let nz = mean(&|_, y| if y < R / 2 { 1.0 } else { 0.0 });
                let want = [red, fof0, nz, 0.5 * green - 0.25];
                let i = by * (R / 4) + bx;
                for (ch, w) in want.iter().enumerate() {
                    let got = f.data[ch * (R / 4) * (R / 4) + i];
                    assert!((got - w).abs() < 2e-3, "size {size} block ({bx},{by}) ch {ch}: {got} vs {w}");
                }
            }
        }
    }
}

#[test]
fn encoder_without_fof_feeds_zeros_and_background_is_minus_one() {
    let mut enc = Encoder::load(&data("good/encoder.onnx"), &cpu()).unwrap();
    let rgb = RgbImage::new(R, R, Vec3::ONE);
    let mask = GrayImage::from_fn(R, R, |c, _| if c < R / 2 { 1.0 } else { 0.0 });
    let rgb = RgbImage::from_fn(R, R, |c, r| *rgb.get(c, r) * *mask.get(c, r));
    let normals = Image::new(R, R, Vec3::ZERO);
    let f = enc.run(&EncoderInput { rgb: &rgb, mask: &mask, fof: None, normals: &normals }).unwrap();
    let q = R / 4;
    // Feature 0 = image R: +1 in the person, -1 in the background; feature 1 = fof 0 = 0.
    assert!((f.data[0] - 1.0).abs() < 1e-5 && (f.data[q - 1] + 1.0).abs() < 1e-5, "{:?}", &f.data[..q]);
    assert!(f.data[q * q..2 * q * q].iter().all(|v| *v == 0.0));
}

/// A colour lookup pixel in the decoder's `warped_rgb` space: straight sRGB `*2-1`, 0 where unknown.
fn net_rgb(p: Vec4) -> Vec3 {
    if p.w <= 0.0 {
        return Vec3::ZERO;
    }
    let c = p.truncate() / p.w;
    Vec3::new(linear_to_srgb(c.x), linear_to_srgb(c.y), linear_to_srgb(c.z)) * 2.0 - 1.0
}

/// A colour lookup with known pixels (alpha 1, hashed colours) and a few unknown ones (alpha 0).
fn hashed_lookup(w: usize, h: usize, salt: usize) -> RgbaImage {
    RgbaImage::from_fn(w, h, |c, r| {
        if (c + 3 * r) % 7 == 0 {
            Vec4::ZERO
        } else {
            Vec3::new(hash(c, r, salt, 0.0, 1.0), hash(c, r, salt + 1, 0.0, 1.0), hash(c, r, salt + 2, 0.0, 1.0))
                .extend(1.0)
        }
    })
}

/// The closed form of `good/decoder.onnx` (see make_fixtures.py): `warped_rgb + features[0:3] + 0.5 z +
/// 0.25 n + Conv3x3(features[3])`, inputs zero outside the mask.
fn fixture_decoder_expected(
    feat: &FeatureMap,
    lookup: &RgbaImage,
    z: &GrayImage,
    n: &Image<Vec3>,
    mask: &GrayImage,
    col: usize,
    row: usize,
) -> Vec4 {
    let (w, h) = (mask.width, mask.height);
    let plane = w * h;
    let a = *mask.get(col, row);
    if a <= 0.0 {
        return Vec4::ZERO;
    }
    let mut conv = 0.0;
    for dy in -1i64..=1 {
        for dx in -1i64..=1 {
            let (x, y) = (col as i64 + dx, row as i64 + dy);
            if x >= 0 && y >= 0 && x < w as i64 && y < h as i64 && *mask.get(x as usize, y as usize) > 0.0 {
                conv += 0.1 * feat.data[3 * plane + y as usize * w + x as usize];
            }
        }
    }
    let i = row * w + col;
    let nn = *n.get(col, row);
    let zz = *z.get(col, row);
    let photo = net_rgb(*lookup.get(col, row));
    let v = [0, 1, 2].map(|c| photo[c] + feat.data[c * plane + i] + 0.5 * zz + 0.25 * nn[c] + conv);
    let lin = |v: f32| srgb_to_linear(((v + 1.0) * 0.5).clamp(0.0, 1.0)) * a;
    Vec4::new(lin(v[0]), lin(v[1]), lin(v[2]), a)
}

fn blob_mask(w: usize, h: usize) -> GrayImage {
    GrayImage::from_fn(w, h, |c, r| {
        let inside = (c as f32 - 19.0).powi(2) / 81.0 + (r as f32 - 14.0).powi(2) / 49.0 < 1.0;
        if inside {
            1.0
        } else if (c, r) == (39, 35) {
            0.5 // a lone soft pixel in the corner stretches the box to the image edge
        } else {
            0.0
        }
    })
}

#[test]
fn decoder_runs_on_the_padded_mask_box_and_matches_closed_form() {
    let mut dec = Decoder::load(&data("good/decoder.onnx"), &cpu()).unwrap();
    assert_eq!(dec.info().stride, 4);
    let (w, h) = (40, 36);
    let mut mask = blob_mask(w, h);
    let mut feat = FeatureMap::zeros(C, w, h);
    for (i, v) in feat.data.iter_mut().enumerate() {
        *v = if i / (w * h) == 3 { hash(i, 1, 0, 0.0, 0.2) } else { hash(i, 2, 0, -0.3, 0.3) };
    }
    let z = GrayImage::from_fn(w, h, |c, r| hash(c, r, 3, -0.5, 0.5));
    let n = Image::from_fn(w, h, |c, r| Vec3::new(hash(c, r, 4, -1.0, 1.0), 0.3, 1.0).normalize());
    let lookup = hashed_lookup(w, h, 20);
    for corner_pixel in [false, true] {
        if !corner_pixel {
            mask.set(39, 35, 0.0);
        } else {
            mask.set(39, 35, 0.5);
        }
        let region = dec.region(&mask).unwrap().unwrap();
        assert_eq!((region.x0 % 4, region.y0 % 4, region.width() % 4, region.height() % 4), (0, 0, 0, 0));
        if !corner_pixel {
            // The blob spans cols 11..=27, rows 8..=20: the decoder must not run over the whole frame.
            assert!(region.width() < w && region.height() < h, "{region:?}");
        }
        let out = dec.run(&feat, &lookup, &z, &n, &mask).unwrap();
        let mut inside = 0;
        for r in 0..h {
            for c in 0..w {
                let want = fixture_decoder_expected(&feat, &lookup, &z, &n, &mask, c, r);
                let got = *out.get(c, r);
                assert!((got - want).abs().max_element() < 1e-4, "({c},{r}) corner {corner_pixel}: {got} vs {want}");
                inside += (*mask.get(c, r) > 0.0) as usize;
            }
        }
        assert!(inside > 100);
    }
}

#[test]
fn decoder_render_view_takes_the_pipelines_flow_and_gbuffer() {
    let mut dec = Decoder::load(&data("good/decoder.onnx"), &cpu()).unwrap();
    let (fw, fh) = (4, 4);
    let src = FeatureMap {
        channels: C,
        width: fw,
        height: fh,
        data: (0..C * fw * fh).map(|i| hash(i, 11, 0, -0.2, 0.2)).collect(),
    };
    let (w, h) = (20, 16);
    let source_res = 64; // flow in pixels of a 64x64 source: feature pixel (i, j) centre at ((i+0.5)*16, (j+0.5)*16)
    let covered = |c: usize, r: usize| (4..17).contains(&c) && (3..13).contains(&r);
    let pick = |c: usize, r: usize| ((c + r) % fw, (2 * c + r) % fh);
    let mut target = GBuffer::new(w, h);
    let mut flowz =
        FlowZ { flow: Image::new(w, h, FLOW_OUTSIDE), z: GrayImage::new(w, h, 0.0), mask: vec![false; w * h] };
    let mut warped = FeatureMap::zeros(C, w, h);
    let mut mask = GrayImage::new(w, h, 0.0);
    let mut normals = Image::new(w, h, Vec3::ZERO);
    for r in 0..h {
        for c in 0..w {
            let i = r * w + c;
            // One pixel is covered in the G-buffer but has no flow (projects nowhere): it must stay transparent.
            target.mask[i] = covered(c, r) || (c, r) == (2, 2);
            if !covered(c, r) {
                continue;
            }
            let n = Vec3::new(hash(c, r, 12, -1.0, 1.0), 0.5, 1.0).normalize();
            target.normal[i] = n;
            normals.set(c, r, n);
            let (pi, pj) = pick(c, r);
            flowz.flow.set(c, r, Vec2::new((pi as f32 + 0.5) * 16.0, (pj as f32 + 0.5) * 16.0));
            flowz.z.set(c, r, hash(c, r, 13, -0.6, 0.6));
            flowz.mask[i] = true;
            mask.set(c, r, 1.0);
            for ch in 0..C {
                warped.data[ch * w * h + i] = src.data[ch * fw * fh + pj * fw + pi];
            }
        }
    }
    let lookup = hashed_lookup(w, h, 30);
    let out = dec.render_view(&src, &flowz, source_res, &target, &lookup).unwrap();
    for r in 0..h {
        for c in 0..w {
            let want = fixture_decoder_expected(&warped, &lookup, &flowz.z, &normals, &mask, c, r);
            assert!((*out.get(c, r) - want).abs().max_element() < 1e-4, "({c},{r}): {} vs {want}", out.get(c, r));
        }
    }
    assert_eq!(*out.get(2, 2), Vec4::ZERO);
    let bad = GBuffer::new(w + 1, h);
    assert!(matches!(dec.render_view(&src, &flowz, source_res, &bad, &lookup), Err(NeuralError::BadInput { .. })));
    let small = RgbaImage::new(w, h - 1, Vec4::ZERO);
    match dec.render_view(&src, &flowz, source_res, &target, &small) {
        Err(NeuralError::BadInput { problem, .. }) => assert!(problem.contains("colour lookup"), "{problem}"),
        other => panic!("expected BadInput, got {:?}", other.map(|_| ())),
    }
}

#[test]
fn decoder_with_a_fixed_input_size_uses_a_window_and_rejects_larger_masks() {
    let mut dec = Decoder::load(&data("decoder_fixed.onnx"), &cpu()).unwrap();
    let (w, h) = (20, 20);
    let small = GrayImage::from_fn(w, h, |c, r| if (9..14).contains(&c) && (5..10).contains(&r) { 1.0 } else { 0.0 });
    let feat = FeatureMap {
        channels: C,
        width: w,
        height: h,
        data: (0..C * w * h).map(|i| hash(i, 9, 0, -0.2, 0.2)).collect(),
    };
    let z = GrayImage::new(w, h, 0.1);
    let n = Image::new(w, h, Vec3::X);
    let lookup = hashed_lookup(w, h, 40);
    let out = dec.run(&feat, &lookup, &z, &n, &small).unwrap();
    for r in 0..h {
        for c in 0..w {
            let want = fixture_decoder_expected(&feat, &lookup, &z, &n, &small, c, r);
            assert!((*out.get(c, r) - want).abs().max_element() < 1e-4, "({c},{r})");
        }
    }
    let big = GrayImage::from_fn(w, h, |c, _| if (2..15).contains(&c) { 1.0 } else { 0.0 });
    match dec.run(&feat, &lookup, &z, &n, &big) {
        Err(NeuralError::BadInput { problem, .. }) => assert!(problem.contains("fixed 8x8"), "{problem}"),
        other => panic!("expected BadInput, got {:?}", other.map(|_| ())),
    }
}

#[test]
fn empty_mask_renders_a_transparent_image_without_running() {
    let mut dec = Decoder::load(&data("good/decoder.onnx"), &cpu()).unwrap();
    let mask = GrayImage::new(8, 8, 0.0);
    let lookup = RgbaImage::new(8, 8, Vec4::ONE);
    let out = dec.run(&FeatureMap::zeros(C, 8, 8), &lookup, &mask, &Image::new(8, 8, Vec3::Z), &mask).unwrap();
    assert!(out.data.iter().all(|p| *p == Vec4::ZERO));
}

#[test]
fn fof_net_matches_closed_form_and_zeroes_the_background() {
    let mut net = FofNet::load(&data("good/fof.onnx"), &cpu()).unwrap();
    let size = 2 * R;
    let rgb = RgbImage::from_fn(size, size, |c, r| {
        Vec3::new(srgb_to_linear(0.75), srgb_to_linear(0.25), (c + r) as f32 * 0.0)
    });
    let mask = GrayImage::from_fn(size, size, |_, r| if r < size / 2 { 1.0 } else { 0.0 });
    let p = net.run(&rgb, &mask, None).unwrap();
    assert_eq!((p.width, p.height, p.n), (R, R, N));
    let image = [0.5f32, -0.5, -1.0]; // sRGB (0.75, 0.25, 0) * 2 - 1
    for r in 0..R {
        for c in 0..R {
            for k in 0..N {
                let want = if r < R / 2 { (k + 1) as f32 * image[k % 3] } else { 0.0 };
                let got = p.data[(r * R + c) * N + k];
                assert!((got - want).abs() < 2e-3, "({c},{r}) k{k}: {got} vs {want}");
            }
        }
    }
    let mut with_prior = FofNet::load(&data("fof_prior.onnx"), &cpu()).unwrap();
    let prior: Vec<f32> = (0..size * size * N).map(|i| (i % N) as f32).collect();
    let view = Coefficients { width: size, height: size, n: N, data: &prior };
    let q = with_prior.run(&rgb, &mask, Some(view)).unwrap();
    assert!((q.data[3] - (4.0 * image[0] + 3.0)).abs() < 2e-3, "{:?}", &q.data[..4]);
    let zero_prior = with_prior.run(&rgb, &mask, None).unwrap();
    assert!((zero_prior.data[3] - 4.0 * image[0]).abs() < 2e-3);
}

#[test]
fn runtime_loads_a_consistent_folder_and_rejects_mixed_models() {
    let rt = NeuralRuntime::load(&data("good"), &cpu()).unwrap();
    assert!(rt.fof.is_some());
    let tmp = tempfile::tempdir().unwrap();
    std::fs::copy(data("good/encoder.onnx"), tmp.path().join("encoder.onnx")).unwrap();
    std::fs::copy(data("decoder_5_channels.onnx"), tmp.path().join("decoder.onnx")).unwrap();
    match NeuralRuntime::load(tmp.path(), &cpu()) {
        Err(e @ NeuralError::Inconsistent { .. }) => assert!(e.to_string().contains("4 feature channels"), "{e}"),
        other => panic!("expected Inconsistent, got {:?}", other.map(|_| ())),
    }
    std::fs::remove_file(tmp.path().join("decoder.onnx")).unwrap();
    assert!(matches!(NeuralRuntime::load(tmp.path(), &cpu()), Err(NeuralError::ModelMissing { .. })));
    assert!(NeuralRuntime::load_or_warn(tmp.path(), &cpu()).is_none());
}

fn load_err(name: &str, loader: fn(&Path, &RuntimeOptions) -> Result<(), NeuralError>) -> NeuralError {
    match loader(&data(name), &cpu()) {
        Err(e) => e,
        Ok(()) => panic!("{name} loaded but must be rejected"),
    }
}

fn enc_loader(p: &Path, o: &RuntimeOptions) -> Result<(), NeuralError> {
    Encoder::load(p, o).map(|_| ())
}

fn dec_loader(p: &Path, o: &RuntimeOptions) -> Result<(), NeuralError> {
    Decoder::load(p, o).map(|_| ())
}

#[test]
fn bad_models_are_clear_errors() {
    let e = load_err("decoder_wrong_name.onnx", dec_loader);
    assert!(matches!(e, NeuralError::Signature { .. }) && e.to_string().contains("no input named `features`"), "{e}");
    assert!(e.to_string().contains("feat"), "{e}");
    let e = load_err("encoder_wrong_channels.onnx", enc_loader);
    assert!(e.to_string().contains("`image` has shape [1, 5, 16, 16], expected [1, 3, 16, 16]"), "{e}");
    let e = load_err("encoder_labelled_decoder.onnx", enc_loader);
    assert!(matches!(&e, NeuralError::Metadata { key, .. } if key == "r2human.kind"), "{e}");
    let e = load_err("encoder_no_fof_n.onnx", enc_loader);
    assert!(matches!(&e, NeuralError::Metadata { key, .. } if key == "r2human.fof_n"), "{e}");
    assert!(e.to_string().contains("is missing"), "{e}");
    // A decoder of the earlier three-input contract: the missing residual input is named, with what to do.
    let e = load_err("decoder_3_inputs.onnx", dec_loader);
    assert!(matches!(e, NeuralError::Signature { .. }), "{e}");
    let msg = e.to_string();
    assert!(msg.contains("no input named `warped_rgb`") && msg.contains("python -m train export"), "{msg}");
    // A decoder loaded as an encoder: wrong kind, named.
    let e = load_err("good/decoder.onnx", enc_loader);
    assert!(e.to_string().contains("is `decoder` but this file is loaded as the encoder"), "{e}");
}

#[test]
fn corrupt_and_missing_files_are_errors_not_crashes() {
    let tmp = tempfile::tempdir().unwrap();
    let garbage = tmp.path().join("decoder.onnx");
    std::fs::write(&garbage, (0..4096u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8).collect::<Vec<_>>())
        .unwrap();
    assert!(matches!(Decoder::load(&garbage, &cpu()), Err(NeuralError::ModelLoad { .. })));
    let empty = tmp.path().join("encoder.onnx");
    std::fs::write(&empty, b"").unwrap();
    let e = Encoder::load(&empty, &cpu()).err().expect("an empty file must not load");
    assert!(matches!(e, NeuralError::ModelLoad { .. }), "{e}");
    // Truncated real model.
    let bytes = std::fs::read(data("good/encoder.onnx")).unwrap();
    let cut = tmp.path().join("cut.onnx");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    assert!(Encoder::load(&cut, &cpu()).is_err());
    assert!(matches!(Encoder::load(&tmp.path().join("none.onnx"), &cpu()), Err(NeuralError::ModelMissing { .. })));
}

#[test]
fn nan_output_is_reported_not_rendered_black() {
    let mut dec = Decoder::load(&data("decoder_nan.onnx"), &cpu()).unwrap();
    let mask = GrayImage::from_fn(8, 8, |c, _| if c > 2 { 1.0 } else { 0.0 });
    let lookup = RgbaImage::new(8, 8, Vec4::ONE);
    match dec.run(&FeatureMap::zeros(C, 8, 8), &lookup, &mask, &Image::new(8, 8, Vec3::Z), &mask) {
        Err(e @ NeuralError::NonFinite { .. }) => assert!(e.to_string().contains("non-finite"), "{e}"),
        other => panic!("expected NonFinite, got {:?}", other.map(|_| ())),
    }
}

#[test]
fn wrong_input_sizes_are_errors() {
    let mut dec = Decoder::load(&data("good/decoder.onnx"), &cpu()).unwrap();
    let mask = GrayImage::new(8, 8, 1.0);
    let n = Image::new(8, 8, Vec3::Z);
    let lk = RgbaImage::new(8, 8, Vec4::ONE);
    assert!(matches!(
        dec.run(&FeatureMap::zeros(C + 1, 8, 8), &lk, &mask, &n, &mask),
        Err(NeuralError::BadInput { .. })
    ));
    assert!(matches!(dec.run(&FeatureMap::zeros(C, 8, 4), &lk, &mask, &n, &mask), Err(NeuralError::BadInput { .. })));
    let lk_small = RgbaImage::new(8, 7, Vec4::ONE);
    assert!(matches!(
        dec.run(&FeatureMap::zeros(C, 8, 8), &lk_small, &mask, &n, &mask),
        Err(NeuralError::BadInput { .. })
    ));
    let mut enc = Encoder::load(&data("good/encoder.onnx"), &cpu()).unwrap();
    let rgb = RgbImage::new(R, R + 1, Vec3::ZERO);
    let m = GrayImage::new(R, R + 1, 1.0);
    let nn = Image::new(R, R + 1, Vec3::Z);
    let e = enc.run(&EncoderInput { rgb: &rgb, mask: &m, fof: None, normals: &nn }).unwrap_err();
    assert!(e.to_string().contains("not square"), "{e}");
    let rgb = RgbImage::new(R, R, Vec3::ZERO);
    let m = GrayImage::new(R, R, 1.0);
    let nn = Image::new(R, R, Vec3::Z);
    let fof = vec![0.0; R * R * 3];
    let bad_fof = Coefficients { width: R, height: R, n: 3, data: &fof };
    let e = enc.run(&EncoderInput { rgb: &rgb, mask: &m, fof: Some(bad_fof), normals: &nn }).unwrap_err();
    assert!(e.to_string().contains("3 coefficients per pixel"), "{e}");
}

/// Runs in a child process (ONNX Runtime allows one library per process): loading a file that is not an ONNX
/// Runtime library must be an error, not a crash.
#[test]
fn loading_a_bad_library_is_an_error() {
    if std::env::var_os("R2HUMAN_NEURAL_CHILD").is_some() {
        let tmp = tempfile::tempdir().unwrap();
        let fake = tmp.path().join("libonnxruntime.so.1.31.1");
        std::fs::write(&fake, b"not a shared library").unwrap();
        let opts = RuntimeOptions { library: Some(fake), ..cpu() };
        match environment(&opts) {
            Err(e @ NeuralError::LibraryLoad { .. }) => {
                assert!(e.to_string().contains("ORT_DYLIB_PATH"), "{e}");
                println!("CHILD_OK");
            }
            Err(e) => panic!("unexpected error {e}"),
            Ok(_) => panic!("a text file loaded as ONNX Runtime"),
        }
        return;
    }
    let out = std::process::Command::new(std::env::current_exe().unwrap())
        .args(["--exact", "loading_a_bad_library_is_an_error", "--nocapture", "--test-threads=1"])
        .env("R2HUMAN_NEURAL_CHILD", "1")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success() && stdout.contains("CHILD_OK"), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
}

/// The shipped `models/tiny` load with their metadata and signatures checked, and render a plausible view: a
/// flat grey card seen from the source camera comes back finite, bounded, opaque inside the mask only.
#[test]
fn shipped_tiny_models_load_and_render() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/tiny");
    let mut rt = NeuralRuntime::load(&dir, &cpu()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(rt.encoder.info().tier, "tiny");
    assert!(rt.encoder.info().recipe.contains("\"steps\""), "{}", rt.encoder.info().recipe);
    let size = 128;
    let card = |c: usize, r: usize| (40..88).contains(&c) && (16..112).contains(&r);
    let mask = GrayImage::from_fn(size, size, |c, r| if card(c, r) { 1.0 } else { 0.0 });
    let rgb = RgbImage::from_fn(size, size, |c, r| Vec3::splat(0.2) * *mask.get(c, r));
    let normals = Image::from_fn(size, size, |c, r| if card(c, r) { Vec3::Z } else { Vec3::ZERO });
    let predicted = rt.fof.as_mut().map(|f| f.run(&rgb, &mask, None).unwrap());
    if let Some(p) = &predicted {
        assert!(p.data.iter().all(|v| v.is_finite()));
    }
    let features = rt.encoder.run(&EncoderInput { rgb: &rgb, mask: &mask, fof: None, normals: &normals }).unwrap();
    assert_eq!(features.channels, rt.decoder.info().feature_channels);
    // The source view itself: flow = the pixel's own position, Z-map = the card's depth 0, the lookup = the card.
    let mut target = GBuffer::new(size, size);
    let mut flowz = FlowZ {
        flow: Image::from_fn(size, size, |c, r| Vec2::new(c as f32 + 0.5, r as f32 + 0.5)),
        z: GrayImage::new(size, size, 0.0),
        mask: vec![false; size * size],
    };
    for r in 0..size {
        for c in 0..size {
            let i = r * size + c;
            target.mask[i] = card(c, r);
            flowz.mask[i] = card(c, r);
            target.normal[i] = *normals.get(c, r);
            target.depth[i] = 0.0;
        }
    }
    let lookup = photo_lookup(&rgb, &mask, &Camera::source(size), &flowz, None);
    let out = rt.decoder.render_view(&features, &flowz, size, &target, &lookup).unwrap();
    for r in 0..size {
        for c in 0..size {
            let p = *out.get(c, r);
            assert!(p.is_finite() && p.min_element() >= 0.0 && p.max_element() <= 1.0, "({c},{r}) {p}");
            assert_eq!(p.w, if card(c, r) { 1.0 } else { 0.0 });
        }
    }
}

fn figure_input(resolution: usize) -> PreparedInput {
    let photo = image_io::from_dynamic(&image::DynamicImage::ImageRgba8(common::figure_rgba(150, 200)));
    let mask = photo.alpha.clone().unwrap();
    let opts = PrepareOptions { resolution, depth_samples: resolution, ..Default::default() };
    PreparedInput::prepare(&photo.rgb, &mask, &opts).unwrap()
}

/// An untrained residual decoder (zero-initialised last convolution, exported by `python -m train
/// export-untrained --tier tiny`) reproduces the geometric renderer (`MirroredFront`, whose lookup ignores
/// visibility) on every pixel where the photo has a colour, through the whole pipeline: encoder, flow, lookup,
/// decoder over the mask box, sRGB round trip.
#[test]
fn zero_residual_decoder_is_the_geometric_renderer() {
    let prepared = figure_input(96);
    let neural = Arc::new(Mutex::new(NeuralRenderer::load(&data("untrained_tiny"), &cpu()).unwrap()));
    let encoded = neural.lock().unwrap().encode(&prepared).unwrap();
    assert_eq!(encoded.features.channels, 16);
    let mut geo = ViewRenderer::new(&prepared, OcclusionFill::MirroredFront, false);
    let mut net = ViewRenderer::with_neural(&prepared, OcclusionFill::MirroredFront, false, neural, encoded);
    assert!(net.is_neural() && net.encode_time().is_some());
    for yaw in [0.0f32, 35.0, 120.0, 180.0] {
        let cam = Camera::orbit(yaw, 10.0, 80, 80);
        let g = geo.render_person(&cam).unwrap();
        let n = net.render_person(&cam).unwrap();
        assert_eq!(net.neural_fallbacks(), 0);
        // Which pixels the photo has a colour for (the lookup's alpha).
        let mut target = GBuffer::new(80, 80);
        r2human::geometry::raster::rasterize_into(&mut target, &prepared.mesh, &cam);
        let flowz = flow_and_zmap(&target, &cam, &prepared.source_camera);
        let lookup =
            photo_lookup(&prepared.normalised.rgb, &prepared.normalised.mask, &prepared.source_camera, &flowz, None);
        let mut known = 0;
        for i in 0..80 * 80 {
            assert!(n.data[i].is_finite() && n.data[i].max_element() <= 1.0 && n.data[i].min_element() >= 0.0);
            if lookup.data[i].w > 0.0 {
                known += 1;
                assert!(
                    (n.data[i] - g.data[i]).abs().max_element() < 2e-4,
                    "yaw {yaw} px {i}: {} vs {}",
                    n.data[i],
                    g.data[i]
                );
            }
            // Alpha is the coverage in both.
            assert_eq!(n.data[i].w, g.data[i].w, "yaw {yaw} px {i}");
        }
        assert!(known > 500, "yaw {yaw}: only {known} pixels with a colour");
    }
}

/// The shipped decoder keeps the photo's own colour on every pixel whose surface point the source camera sees
/// (paper Eq. 9; `pipeline::keep_lookup_where`), so the input view is the photo and side views keep what the
/// photo shows, while it still draws the surfaces the photo does not show (the decoder's own colours there).
#[test]
fn shipped_decoder_keeps_the_photo_where_the_photo_sees_the_surface() {
    let prepared = figure_input(96);
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/tiny");
    let neural = Arc::new(Mutex::new(NeuralRenderer::load(&dir, &cpu()).unwrap()));
    let encoded = neural.lock().unwrap().encode(&prepared).unwrap();
    let mut geo = ViewRenderer::new(&prepared, OcclusionFill::MirroredFront, false);
    let mut net = ViewRenderer::with_neural(&prepared, OcclusionFill::MirroredFront, false, neural, encoded);
    let mut unseen_changed = 0;
    // Yaw and how many of the view's pixels the photo sees at least (from behind: none).
    for (yaw, least_seen) in [(0.0f32, 500), (35.0, 500), (120.0, 20), (180.0, 0)] {
        let cam = Camera::orbit(yaw, 10.0, 80, 80);
        let (g, n) = (geo.render_person(&cam).unwrap(), net.render_person(&cam).unwrap());
        assert_eq!(net.neural_fallbacks(), 0);
        let mut target = GBuffer::new(80, 80);
        r2human::geometry::raster::rasterize_into(&mut target, &prepared.mesh, &cam);
        let flowz = flow_and_zmap(&target, &cam, &prepared.source_camera);
        let seen = r2human::geometry::zmap::visibility(
            &flowz,
            &prepared.source_gbuffer,
            &prepared.source_camera,
            r2human::geometry::zmap::VISIBILITY_LAMBDA,
        );
        let lookup =
            photo_lookup(&prepared.normalised.rgb, &prepared.normalised.mask, &prepared.source_camera, &flowz, None);
        let mut kept = 0;
        for (i, &seen) in seen.iter().enumerate() {
            assert!(n.data[i].is_finite());
            if seen && lookup.data[i].w > 0.0 {
                kept += 1;
                let d = (n.data[i] - g.data[i]).abs().max_element();
                assert!(d < 2e-4, "yaw {yaw} px {i}: {} vs {}", n.data[i], g.data[i]);
            } else if n.data[i].w > 0.0 && (n.data[i] - g.data[i]).abs().max_element() > 1e-3 {
                unseen_changed += 1;
            }
        }
        assert!(kept >= least_seen, "yaw {yaw}: only {kept} pixels the photo sees");
    }
    assert!(unseen_changed > 50, "the decoder drew nothing of its own ({unseen_changed} pixels)");
}

/// A decoder that outputs NaN: the view is drawn by the geometric renderer (identical to it, not black) and the
/// fallback is counted; a working decoder in the same folder layout really draws the neural view.
#[test]
fn nan_decoder_falls_back_to_the_geometric_view() {
    let prepared = figure_input(64);
    let tmp = tempfile::tempdir().unwrap();
    std::fs::copy(data("good/encoder.onnx"), tmp.path().join("encoder.onnx")).unwrap();
    std::fs::copy(data("decoder_nan.onnx"), tmp.path().join("decoder.onnx")).unwrap();
    let neural = load_renderer(RendererChoice::Neural, Some(tmp.path()), &cpu()).unwrap().expect("models load");
    let mut r = ViewRenderer::for_renderer(&prepared, OcclusionFill::MirroredFront, false, Some(&neural));
    assert!(r.is_neural());
    let mut geo = ViewRenderer::new(&prepared, OcclusionFill::MirroredFront, false);
    for (k, yaw) in [30.0f32, 200.0].into_iter().enumerate() {
        let cam = Camera::orbit(yaw, 0.0, 48, 48);
        let out = r.render_person(&cam).unwrap();
        assert_eq!(r.neural_fallbacks(), k + 1);
        assert_eq!(out, geo.render_person(&cam).unwrap());
        assert!(out.data.iter().filter(|p| p.w > 0.5 && p.truncate().max_element() > 0.01).count() > 100);
    }
    // The closed-form fixture decoder runs: no fallback, and its output differs from the geometric view.
    std::fs::copy(data("good/decoder.onnx"), tmp.path().join("decoder.onnx")).unwrap();
    let neural = load_renderer(RendererChoice::Auto, Some(tmp.path()), &cpu()).unwrap().expect("models load");
    let mut r = ViewRenderer::for_renderer(&prepared, OcclusionFill::MirroredFront, false, Some(&neural));
    let cam = Camera::orbit(30.0, 0.0, 48, 48);
    let out = r.render_person(&cam).unwrap();
    assert_eq!(r.neural_fallbacks(), 0);
    assert_ne!(out, geo.render_person(&cam).unwrap());
}

#[test]
fn renderer_choice_resolves_models_and_reports_missing_ones() {
    let tmp = tempfile::tempdir().unwrap();
    assert!(load_renderer(RendererChoice::Geometric, Some(tmp.path()), &cpu()).unwrap().is_none());
    // Auto without models: the geometric renderer (one warning), not an error.
    assert!(load_renderer(RendererChoice::Auto, Some(tmp.path()), &cpu()).unwrap().is_none());
    // Neural without models: an error that names the missing file.
    match load_renderer(RendererChoice::Neural, Some(tmp.path()), &cpu()) {
        Err(e @ PipelineError::Neural(NeuralError::ModelMissing { .. })) => {
            assert!(e.to_string().contains("encoder.onnx"), "{e}")
        }
        other => panic!("expected a missing-model error, got {:?}", other.map(|o| o.is_some())),
    }
    // A folder with an old three-input decoder: neural fails naming the input, auto falls back.
    std::fs::copy(data("good/encoder.onnx"), tmp.path().join("encoder.onnx")).unwrap();
    std::fs::copy(data("decoder_3_inputs.onnx"), tmp.path().join("decoder.onnx")).unwrap();
    let e = load_renderer(RendererChoice::Neural, Some(tmp.path()), &cpu()).err().expect("must fail");
    assert!(e.to_string().contains("warped_rgb"), "{e}");
    assert!(load_renderer(RendererChoice::Auto, Some(tmp.path()), &cpu()).unwrap().is_none());
}

/// `r2human eval` scores the neural methods next to the others when models load, and leaves them out otherwise.
#[test]
fn eval_includes_the_neural_rows_when_models_exist() {
    use r2human::eval::runner::{run_eval_with, EvalOptions, NeuralEvalOptions};
    let dir = tempfile::tempdir().unwrap();
    let opts = EvalOptions {
        subjects: 1,
        seed: 3,
        out: dir.path().join("eval"),
        scans: Vec::new(),
        size: 48,
        yaws: vec![20.0, 90.0, 180.0],
        texture_size: 64,
        save_views: false,
        ..EvalOptions::default()
    };
    let nopts = NeuralEvalOptions { models: Some(data("untrained_tiny")), skip: false, ep: ExecutionProvider::Cpu };
    let rep = run_eval_with(&opts, &nopts).unwrap();
    assert_eq!(rep.neural_fallbacks, 0);
    let get = |m: &str, g: &str| rep.rows.iter().find(|r| r.method == m && r.group == g).cloned();
    for g in ["close", "divergent"] {
        for (neural, geometric) in [("neural+inflation", "geometric+inflation"), ("neural+gt-fof", "geometric+gt-fof")]
        {
            let n = get(neural, g).unwrap_or_else(|| panic!("no {neural} {g} row in {:?}", rep.rows));
            let geo = get(geometric, g).unwrap();
            assert_eq!(n.views, geo.views);
            assert!(n.scores.psnr.is_finite() && n.scores.ssim.is_finite() && n.ms_per_view > 0.0, "{n:?}");
            // The encoder adds to the per-input time; the untrained (zero-residual) decoder draws the geometric
            // lookup, so the same geometry scores about the same.
            assert!(n.ms_per_input > geo.ms_per_input, "{n:?} vs {geo:?}");
            assert!((n.scores.mask_iou - geo.scores.mask_iou).abs() < 0.02, "{n:?} vs {geo:?}");
            assert!((n.scores.psnr - geo.scores.psnr).abs() < 1.5, "{n:?} vs {geo:?}");
        }
    }
    let csv = std::fs::read_to_string(opts.out.join("report.csv")).unwrap();
    assert!(csv.contains("\nneural+inflation,divergent,") && csv.contains("\nneural+gt-fof,close,"), "{csv}");
    let skip = NeuralEvalOptions { skip: true, ..nopts };
    let rep = run_eval_with(&EvalOptions { out: dir.path().join("eval2"), ..opts }, &skip).unwrap();
    assert!(rep.rows.iter().all(|r| !r.method.starts_with("neural")), "{:?}", rep.rows);
}
