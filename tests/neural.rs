//! Neural runtime tests against tiny ONNX fixtures with closed-form outputs (tests/data/neural/make_fixtures.py).
//! They need the ONNX Runtime library: `bash scripts/setup.d/neural.sh` (or ORT_DYLIB_PATH).

use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3, Vec4};
use r2human::buffer::{linear_to_srgb, srgb_to_linear, GrayImage, Image, RgbImage};
use r2human::geometry::raster::GBuffer;
use r2human::geometry::zmap::{FlowZ, FLOW_OUTSIDE};
use r2human::neural::{
    environment, Coefficients, Decoder, Encoder, EncoderInput, ExecutionProvider, FeatureMap, FofNet, NeuralError,
    NeuralRuntime, RuntimeOptions,
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

fn fixture_decoder_expected(
    feat: &FeatureMap,
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
    let v = [0, 1, 2].map(|c| feat.data[c * plane + i] + 0.5 * zz + 0.25 * nn[c] + conv);
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
        let out = dec.run(&feat, &z, &n, &mask).unwrap();
        let mut inside = 0;
        for r in 0..h {
            for c in 0..w {
                let want = fixture_decoder_expected(&feat, &z, &n, &mask, c, r);
                let got = *out.get(c, r);
                assert!((got - want).abs().max_element() < 1e-4, "({c},{r}) corner {corner_pixel}: {got} vs {want}");
                inside += (*mask.get(c, r) > 0.0) as usize;
            }
        }
        assert!(inside > 100);
    }
}

#[test]
fn decoder_render_warps_encoder_features_by_the_flow() {
    let mut dec = Decoder::load(&data("good/decoder.onnx"), &cpu()).unwrap();
    let (fw, fh) = (4, 4);
    let mut src = FeatureMap::zeros(C, fw, fh);
    for (i, v) in src.data.iter_mut().enumerate() {
        *v = hash(i, 7, 0, -0.2, 0.2);
    }
    let (w, h) = (24, 20);
    let mask = GrayImage::from_fn(w, h, |c, r| if (3..21).contains(&c) && (2..17).contains(&r) { 1.0 } else { 0.0 });
    // Each target pixel looks up a source feature-pixel centre: x = (i+0.5)/(W/2) - 1, y = 1 - (j+0.5)/(H/2).
    let pick = |c: usize, r: usize| ((c * 3 + r) % fw, (c + 2 * r) % fh);
    let flow = Image::from_fn(w, h, |c, r| {
        let (i, j) = pick(c, r);
        Vec2::new((i as f32 + 0.5) / 2.0 - 1.0, 1.0 - (j as f32 + 0.5) / 2.0)
    });
    let mut warped = FeatureMap::zeros(C, w, h);
    for r in 0..h {
        for c in 0..w {
            let (i, j) = pick(c, r);
            for ch in 0..C {
                warped.data[ch * w * h + r * w + c] = src.data[ch * fw * fh + j * fw + i];
            }
        }
    }
    let z = GrayImage::from_fn(w, h, |c, r| hash(c, r, 5, -0.5, 0.5));
    let n = Image::from_fn(w, h, |_, _| Vec3::Z);
    let a = dec.render(&src, &flow, &z, &n, &mask).unwrap();
    for r in 0..h {
        for c in 0..w {
            let want = fixture_decoder_expected(&warped, &z, &n, &mask, c, r);
            assert!((*a.get(c, r) - want).abs().max_element() < 1e-4, "({c},{r})");
        }
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
    let out = dec.render_view(&src, &flowz, source_res, &target).unwrap();
    for r in 0..h {
        for c in 0..w {
            let want = fixture_decoder_expected(&warped, &flowz.z, &normals, &mask, c, r);
            assert!((*out.get(c, r) - want).abs().max_element() < 1e-4, "({c},{r}): {} vs {want}", out.get(c, r));
        }
    }
    assert_eq!(*out.get(2, 2), Vec4::ZERO);
    let bad = GBuffer::new(w + 1, h);
    assert!(matches!(dec.render_view(&src, &flowz, source_res, &bad), Err(NeuralError::BadInput { .. })));
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
    let out = dec.run(&feat, &z, &n, &small).unwrap();
    for r in 0..h {
        for c in 0..w {
            let want = fixture_decoder_expected(&feat, &z, &n, &small, c, r);
            assert!((*out.get(c, r) - want).abs().max_element() < 1e-4, "({c},{r})");
        }
    }
    let big = GrayImage::from_fn(w, h, |c, _| if (2..15).contains(&c) { 1.0 } else { 0.0 });
    match dec.run(&feat, &z, &n, &big) {
        Err(NeuralError::BadInput { problem, .. }) => assert!(problem.contains("fixed 8x8"), "{problem}"),
        other => panic!("expected BadInput, got {:?}", other.map(|_| ())),
    }
}

#[test]
fn empty_mask_renders_a_transparent_image_without_running() {
    let mut dec = Decoder::load(&data("good/decoder.onnx"), &cpu()).unwrap();
    let mask = GrayImage::new(8, 8, 0.0);
    let out = dec.run(&FeatureMap::zeros(C, 8, 8), &mask, &Image::new(8, 8, Vec3::Z), &mask).unwrap();
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
    match dec.run(&FeatureMap::zeros(C, 8, 8), &mask, &Image::new(8, 8, Vec3::Z), &mask) {
        Err(e @ NeuralError::NonFinite { .. }) => assert!(e.to_string().contains("non-finite"), "{e}"),
        other => panic!("expected NonFinite, got {:?}", other.map(|_| ())),
    }
}

#[test]
fn wrong_input_sizes_are_errors() {
    let mut dec = Decoder::load(&data("good/decoder.onnx"), &cpu()).unwrap();
    let mask = GrayImage::new(8, 8, 1.0);
    let n = Image::new(8, 8, Vec3::Z);
    assert!(matches!(dec.run(&FeatureMap::zeros(C + 1, 8, 8), &mask, &n, &mask), Err(NeuralError::BadInput { .. })));
    assert!(matches!(dec.run(&FeatureMap::zeros(C, 8, 4), &mask, &n, &mask), Err(NeuralError::BadInput { .. })));
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
