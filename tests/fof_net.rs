//! The FOF network as geometry (`--geometry fofnet|auto`): closed-form fixtures for the full-resolution
//! correction of the inflation prior (tests/data/fof_net/make_fixtures.py), the shipped `models/tiny/fof.onnx` on
//! held-out synthetic subjects against the inflation prior, and broken or missing models; the placement net of
//! `--geometry body-placed` (its upsampled shift, loading, fall-back). Needs the ONNX Runtime
//! library (`bash scripts/setup.d/neural.sh` or ORT_DYLIB_PATH).

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Arc, Mutex};

use glam::Vec3;
use r2human::buffer::{GrayImage, RgbImage};
use r2human::eval::dataset::subject_seed;
use r2human::eval::ground_truth::render_ground_truth;
use r2human::eval::runner::fof_occupancy_iou;
use r2human::geometry::fof::Fof;
use r2human::geometry::inflate::{inflate_to_fof, InflateParams};
use r2human::geometry::Camera;
use r2human::neural::{ExecutionProvider, FofInput, FofNet, NeuralError, PlacementNet, RuntimeOptions};
use r2human::pipeline::{
    body_prior_fof, centre_visible_depth, compute_geometry, load_body_for, load_fof_net, GeometryMode, PipelineError,
    PrepareOptions, PreparedInput, StageTimings,
};
use r2human::synth::{self, SubjectParams, SynthAssets};

/// The fixtures' order and resolution.
const N: usize = 4;
const R: usize = 16;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/fof_net").join(name)
}

fn shipped_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("models/tiny")
}

fn cpu() -> RuntimeOptions {
    RuntimeOptions { ep: ExecutionProvider::Cpu, intra_threads: Some(1), ..Default::default() }
}

/// A `size x size` source with a person-like mask (torso block, head, legs) and a flat colour.
fn blocky_person(size: usize) -> (RgbImage, GrayImage) {
    let s = size as f32;
    let mask = GrayImage::from_fn(size, size, |c, r| {
        let (x, y) = ((c as f32 + 0.5) / s, (r as f32 + 0.5) / s);
        let torso = (0.35..0.65).contains(&x) && (0.25..0.6).contains(&y);
        let head = (x - 0.5).powi(2) + (y - 0.15).powi(2) < 0.08f32.powi(2);
        let legs = ((0.37..0.47).contains(&x) || (0.53..0.63).contains(&x)) && (0.6..0.95).contains(&y);
        if torso || head || legs {
            1.0
        } else {
            0.0
        }
    });
    let rgb = RgbImage::from_fn(size, size, |c, r| Vec3::new(0.5, 0.3, 0.2) * *mask.get(c, r));
    (rgb, mask)
}

fn shared(path: &Path) -> Arc<Mutex<FofNet>> {
    Arc::new(Mutex::new(FofNet::load(path, &cpu()).unwrap_or_else(|e| panic!("{e}"))))
}

/// The correction is applied at full resolution on top of the full-resolution prior: a net that adds 0.25 to c0
/// everywhere gives exactly prior + 0.25 on c0 at every pixel the prior covers (the mask-aware upsampling of a
/// constant correction is that constant, also at the silhouette edge), leaves the other coefficients alone and
/// the background empty; the identity net (an untrained residual net) gives the prior back exactly, and a net that
/// empties every column gives the prior back too (it may reshape the body in depth, never erase the silhouette).
#[test]
fn refine_applies_the_correction_at_full_resolution_inside_the_prior_only() {
    let size = 4 * R;
    let (rgb, mask) = blocky_person(size);
    // Thick enough that N = 4 coefficients reach the 0.5 level in (almost) every column (the silhouette rule of
    // `refine` skips columns that hold no body).
    let thick = InflateParams { thickness: 3.0, ..Default::default() };
    let prior = inflate_to_fof(&mask, N, &thick, None).unwrap();
    let mut identity = FofNet::load(&fixture("fof_identity.onnx"), &cpu()).unwrap();
    assert!(identity.has_prior());
    assert_eq!(identity.refine(&rgb, &mask, &prior).unwrap(), prior);

    // A net that predicts empty columns everywhere cannot erase the silhouette: every column keeps the prior.
    let mut eraser = FofNet::load(&fixture("fof_zero.onnx"), &cpu()).unwrap();
    assert_eq!(eraser.refine(&rgb, &mask, &prior).unwrap(), prior);

    let mut offset = FofNet::load(&fixture("fof_offset.onnx"), &cpu()).unwrap();
    let fof = offset.refine(&rgb, &mask, &prior).unwrap();
    let (inside, corrected) = offset_columns(&prior, &fof, size);
    assert!(inside > 500 && corrected as f32 > 0.95 * inside as f32, "{corrected} of {inside}");
    // The corrected field holds more body (occupied depth samples) than the prior, and still makes a valid mesh.
    let occupied = |f: &Fof| {
        let mut col = vec![0.0; 64];
        let mut count = 0;
        for row in 0..size {
            for c in 0..size {
                f.decode_column(c, row, 64, &mut col);
                count += col.iter().filter(|v| **v >= 0.5).count();
            }
        }
        count
    };
    assert!(occupied(&fof) as f32 > 1.05 * occupied(&prior) as f32, "{} vs {}", occupied(&fof), occupied(&prior));
    let opts = PrepareOptions { resolution: size, depth_samples: size, fof_order: N, ..Default::default() };
    let norm = r2human::pipeline::input::normalise(&rgb, &mask, size).unwrap();
    let thick = PreparedInput::from_fof(norm, fof, &opts, StageTimings::default()).unwrap();
    assert!(thick.mesh.triangle_count() > 100);
}

/// `--geometry fofnet` with a model that outputs NaN is an error naming the FOF net; `--geometry auto` warns and
/// uses the inflation prior (the same geometry as `--geometry inflate`), never a broken mesh.
#[test]
fn nan_fof_net_is_an_error_when_explicit_and_the_prior_in_auto() {
    let size = 4 * R;
    let (rgb, mask) = blocky_person(size);
    let base = PrepareOptions { resolution: size, depth_samples: size, fof_order: N, ..Default::default() };
    let inflated = PreparedInput::prepare(&rgb, &mask, &base).unwrap();
    let net = shared(&fixture("fof_nan.onnx"));
    let explicit = PrepareOptions { geometry: GeometryMode::FofNet, fof_net: Some(Arc::clone(&net)), ..base.clone() };
    match PreparedInput::prepare(&rgb, &mask, &explicit) {
        Err(e @ PipelineError::FofNetFailed(NeuralError::NonFinite { .. })) => {
            let text = e.to_string();
            assert!(text.contains("FOF net") && text.contains("--geometry"), "{text}");
        }
        other => panic!("expected a non-finite FOF-net error, got {:?}", other.map(|p| p.mesh.triangle_count())),
    }
    let auto = PrepareOptions { geometry: GeometryMode::Auto, fof_net: Some(net), ..base.clone() };
    let fallback = PreparedInput::prepare(&rgb, &mask, &auto).unwrap();
    assert_eq!(fallback.fof, inflated.fof);
    assert_eq!(fallback.mesh.triangle_count(), inflated.mesh.triangle_count());
    // Auto without a network is the prior too; explicit without one is an error.
    let none = PrepareOptions { geometry: GeometryMode::Auto, ..base.clone() };
    assert_eq!(PreparedInput::prepare(&rgb, &mask, &none).unwrap().fof, inflated.fof);
    let missing = PrepareOptions { geometry: GeometryMode::FofNet, ..base };
    assert!(matches!(PreparedInput::prepare(&rgb, &mask, &missing), Err(PipelineError::NoFofNet(_))));
}

/// Resolving `--geometry`: fofnet without a model (or with the wrong N, or a corrupt file) is an error that says
/// how to get one; auto returns no network (one warning); inflate never looks.
#[test]
fn fofnet_without_a_usable_model_is_a_clear_error() {
    let tmp = tempfile::tempdir().unwrap();
    let e = load_fof_net(GeometryMode::FofNet, Some(tmp.path()), 32, &cpu()).expect_err("no fof.onnx");
    let text = e.to_string();
    assert!(text.contains("fof.onnx") && text.contains("--geometry inflate") && text.contains("--models"), "{text}");
    assert!(load_fof_net(GeometryMode::Auto, Some(tmp.path()), 32, &cpu()).unwrap().is_none());
    assert!(load_fof_net(GeometryMode::Inflate, Some(tmp.path()), 32, &cpu()).unwrap().is_none());
    std::fs::copy(fixture("fof_offset.onnx"), tmp.path().join("fof.onnx")).unwrap();
    assert!(load_fof_net(GeometryMode::FofNet, Some(tmp.path()), N, &cpu()).unwrap().is_some());
    let e = load_fof_net(GeometryMode::FofNet, Some(tmp.path()), 32, &cpu()).expect_err("N mismatch");
    assert!(e.to_string().contains("4 FOF coefficients") && e.to_string().contains("32"), "{e}");
    assert!(load_fof_net(GeometryMode::Auto, Some(tmp.path()), 32, &cpu()).unwrap().is_none());
    std::fs::write(tmp.path().join("fof.onnx"), b"not an onnx file").unwrap();
    let e = load_fof_net(GeometryMode::FofNet, Some(tmp.path()), N, &cpu()).expect_err("corrupt");
    assert!(matches!(e, PipelineError::FofNetLoad(_)) && e.to_string().contains("corrupt"), "{e}");
    assert!(std::error::Error::source(&e).is_some(), "the load error is kept as the cause: {e:?}");
}

/// The same through the binary: `render --geometry fofnet` with a model folder lacking fof.onnx fails with that
/// sentence and writes nothing; `--geometry auto` renders with what the evaluation chose (`AUTO_CHOICE`), says
/// which at the info level, and does not warn about a model (it is a choice, not a fall-back); when its choice
/// fits a body and the body prior's data is missing (`R2HUMAN_TOOLS_DIR` pointing at an empty folder), it renders
/// the inflation prior with one warning saying how to install it.
#[test]
fn cli_geometry_fofnet_without_a_model_fails_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let img = dir.path().join("person.png");
    common::write_figure(&img, 150, 200);
    let empty = dir.path().join("models");
    std::fs::create_dir_all(&empty).unwrap();
    let run_with = |geometry: &str, out: &Path, tools: Option<&Path>| {
        let mut command = Command::new(env!("CARGO_BIN_EXE_r2human"));
        if let Some(tools) = tools {
            command.env("R2HUMAN_TOOLS_DIR", tools);
        }
        let o = command
            .env("R2HUMAN_LOG", "info")
            .args(["render", "--renderer", "geometric", "--size", "48", "--geometry", geometry, "--models"])
            .arg(&empty)
            .arg("--image")
            .arg(&img)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap();
        (o.status.success(), format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr)))
    };
    let run = |geometry: &str, out: &Path| run_with(geometry, out, None);
    let out = dir.path().join("fofnet.png");
    let (ok, text) = run("fofnet", &out);
    assert!(!ok && text.contains("fof.onnx") && text.contains("--geometry inflate"), "{text}");
    assert!(!out.exists());
    let out = dir.path().join("auto.png");
    let (ok, text) = run("auto", &out);
    assert!(ok && out.exists(), "{text}");
    let chosen = r2human::pipeline::AUTO_CHOICE.name();
    assert!(text.contains(&format!("auto is `{chosen}`")), "auto must say what it uses: {text}");
    if r2human::pipeline::AUTO_CHOICE != GeometryMode::FofNet {
        // Auto needs no model of the (empty) model folder: no warning that a model is missing. (Per-input
        // fall-backs may warn: a 48-pixel figure has no pose or face the network finds.)
        let missing: Vec<&str> = text
            .lines()
            .filter(|l| {
                l.contains("WARN") && ["does not load", "does not exist", "scripts/setup"].iter().any(|m| l.contains(m))
            })
            .collect();
        assert!(missing.is_empty(), "auto's choice needs no model of --models: {missing:?}\n{text}");
    }
    if r2human::pipeline::AUTO_CHOICE.fits_body() {
        let out = dir.path().join("auto_without_body.png");
        let (ok, text) = run_with("auto", &out, Some(&empty));
        assert!(ok && out.exists(), "{text}");
        let said = text.lines().filter(|l| l.contains("WARN") && l.contains("the body prior does not load")).count();
        assert!(said == 1 && text.contains("bash scripts/setup.sh"), "one warning saying how to install: {text}");
    }
}

/// A synthetic subject's source view at `size`: linear premultiplied RGB, mask, and the ground-truth FOF. Without
/// garments (`Outfit::none`): the unclothed subjects the shipped `models/tiny` FOF net was trained on (it predates
/// clothes as geometry; on clothed subjects it is not reliably better than the prior: docs/evaluation.md).
fn subject_source(seed: u64, size: usize) -> (RgbImage, GrayImage, Fof) {
    let assets = SynthAssets::shared().unwrap();
    let mut params = SubjectParams::sample(seed);
    params.outfit = synth::Outfit::none(params.appearance.top_fabric);
    let subject = synth::generate(assets, &params, 128).unwrap();
    let gt = render_ground_truth(&subject.mesh, &Camera::source(size));
    let rgb = gt.to_linear_rgba().map(|p| p.truncate());
    let mask = gt.mask_image();
    let fof = Fof::from_mesh(&subject.mesh.mesh, size, 32).unwrap();
    (rgb, mask, fof)
}

/// A clothed subject of `seed` in `framing` as its source view shows it (as `r2human eval` feeds it): photo, mask
/// and ground-truth FOF.
fn clothed_source(seed: u64, framing: synth::Framing, size: usize) -> (RgbImage, GrayImage, Fof) {
    let subject = synth::generate_subject(seed, framing).unwrap();
    let gt = render_ground_truth(&subject.mesh, &Camera::source(size));
    let (rgb, mask) = (gt.to_linear_rgba().map(|p| p.truncate()), gt.mask_image());
    (rgb, mask, Fof::from_mesh(&subject.mesh.mesh, size, 32).unwrap())
}

/// The shipped FOF net sees geometry only (the body FOF and the inflation prior, no photo: what it learned from
/// synthetic people carries over to photos whatever their clothes look like), loads with the body prior it needs,
/// keeps every column of the silhouette, and beats the inflation prior it refines on clothed people of a seed it
/// never saw (it was trained on seed 11; models/tiny/README.md), two in each framing: mean volumetric IoU against
/// the ground-truth FOF above the prior's, every geometry placed in depth by the pipeline's convention. Needs the
/// pose model.
#[test]
fn shipped_fof_net_sees_geometry_and_beats_its_prior_on_unseen_people() {
    let dir = shipped_dir();
    let net = load_fof_net(GeometryMode::FofNet, Some(&dir), 32, &cpu()).unwrap_or_else(|e| panic!("{e}")).unwrap();
    {
        let n = net.lock().unwrap();
        assert_eq!((n.info().tier.as_str(), n.info().fof_n), ("tiny", 32));
        assert!(!n.takes_image() && n.takes_body() && n.has_prior(), "{n:?}");
        assert_eq!(n.base(), FofInput::Prior, "residual on the inflation prior");
        assert!(n.info().recipe.contains("\"steps\""), "{}", n.info().recipe);
    }
    let body = load_body_for(GeometryMode::FofNet, Some(&net), &cpu()).unwrap_or_else(|e| panic!("{e}"));
    assert!(body.is_some(), "the shipped net takes the body FOF");
    let size = 256;
    let opts = PrepareOptions {
        resolution: size,
        depth_samples: size,
        geometry: GeometryMode::FofNet,
        fof_net: Some(net),
        body,
        ..Default::default()
    };
    let (mut sum_net, mut sum_prior) = (0.0, 0.0);
    let subjects: Vec<(u64, synth::Framing)> =
        (0..6).map(|k| (subject_seed(13, k), synth::Framing::ALL[k % 3])).collect();
    for &(seed, framing) in &subjects {
        let (rgb, mask, gt) = clothed_source(seed, framing, size);
        let norm = r2human::pipeline::input::NormalisedInput::in_source_view(rgb, mask);
        let mut timings = StageTimings::default();
        let fof = compute_geometry(&norm, &opts, &mut timings).unwrap_or_else(|e| panic!("{e}"));
        assert!(timings.0.iter().any(|(name, _)| *name == "geometry (FOF net)"), "{:?}", timings.0);
        assert!(fof.coeffs.iter().all(|v| v.is_finite()));
        let prior = inflate_to_fof(&norm.mask, 32, &InflateParams::default(), None).unwrap();
        assert_ne!(fof, prior, "the trained net changes the prior");
        for row in 0..size {
            for col in 0..size {
                // Outside the prior's (cleaned) silhouette stays empty; inside, no column is erased.
                if prior.column(col, row).iter().all(|v| *v == 0.0) {
                    assert!(fof.column(col, row).iter().all(|v| *v == 0.0), "({col},{row})");
                } else if !prior.is_empty_column(col, row) {
                    assert!(!fof.is_empty_column(col, row), "({col},{row}) erased");
                }
            }
        }
        let centre = |f: Fof| r2human::geometry::depth_centre::centre_fof(f).0;
        let (gt, prior) = (centre(gt), centre(prior));
        let (iou_net, iou_prior) = (fof_occupancy_iou(&fof, &gt, 64), fof_occupancy_iou(&prior, &gt, 64));
        eprintln!(
            "unseen subject seed {seed} ({framing:?}): volumetric IoU FOF net {iou_net:.4}, inflation {iou_prior:.4}"
        );
        sum_net += iou_net;
        sum_prior += iou_prior;
        let prepared = PreparedInput::from_fof(norm, fof, &opts, timings).unwrap();
        assert!(prepared.mesh.triangle_count() > 1000);
    }
    let n = subjects.len() as f32;
    let (mean_net, mean_prior) = (sum_net / n, sum_prior / n);
    eprintln!("mean volumetric IoU: FOF net {mean_net:.4}, inflation {mean_prior:.4}");
    assert!(mean_net > mean_prior, "mean IoU of the FOF net {mean_net} <= the inflation prior's {mean_prior}");
}

/// `r2human eval` scores the FOF-net methods next to the others: with an identity net (an untrained residual net)
/// their geometry is exactly the inflation prior's, so geometric+fofnet scores exactly like geometric+inflation
/// while costing the network's time per input; without fof.onnx the rows are absent and the report says why.
#[test]
fn eval_scores_the_fof_net_rows_and_notes_when_they_are_skipped() {
    use r2human::eval::runner::{run_eval_with, EvalOptions, NeuralEvalOptions};
    let dir = tempfile::tempdir().unwrap();
    let models = dir.path().join("models");
    std::fs::create_dir_all(&models).unwrap();
    let untrained = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/neural/untrained_tiny");
    for f in ["encoder.onnx", "decoder.onnx"] {
        std::fs::copy(untrained.join(f), models.join(f)).unwrap();
    }
    std::fs::copy(fixture("fof_identity32.onnx"), models.join("fof.onnx")).unwrap();
    let opts = EvalOptions {
        subjects: 1,
        seed: 3,
        out: dir.path().join("eval"),
        scans: Vec::new(),
        size: 48,
        yaws: vec![20.0, 180.0],
        texture_size: 64,
        save_views: false,
        ..EvalOptions::default()
    };
    let nopts = NeuralEvalOptions { models: Some(models.clone()), skip: false, ep: ExecutionProvider::Cpu };
    let rep = run_eval_with(&opts, &nopts).unwrap();
    let get = |m: &str, g: &str| rep.rows.iter().find(|r| r.method == m && r.group == g).cloned();
    for g in ["close", "divergent"] {
        let net = get("geometric+fofnet", g).unwrap_or_else(|| panic!("no geometric+fofnet {g} row: {:?}", rep.rows));
        let prior = get("geometric+inflation", g).unwrap();
        assert_eq!(
            (net.scores.mask_iou, net.scores.depth_l1, net.scores.psnr, net.scores.ssim),
            (prior.scores.mask_iou, prior.scores.depth_l1, prior.scores.psnr, prior.scores.ssim)
        );
        assert!(net.ms_per_input > 0.0);
        let neural = get("neural+fofnet", g).unwrap_or_else(|| panic!("no neural+fofnet {g} row"));
        assert_eq!(neural.scores.mask_iou, get("neural+inflation", g).unwrap().scores.mask_iou);
    }
    let ious: Vec<&str> = rep.geometry_iou.iter().map(|(n, _)| n.as_str()).collect();
    // The body prior's row follows when the pose model is installed (tests/body.rs covers it).
    assert_eq!(ious[..2], ["inflation", "fofnet"]);
    assert_eq!(rep.geometry_iou[0].1, rep.geometry_iou[1].1);
    assert!(rep.geometry_iou[0].1 > 0.01 && rep.geometry_iou[0].1 < 1.0, "{:?}", rep.geometry_iou);
    let csv = std::fs::read_to_string(opts.out.join("report.csv")).unwrap();
    assert!(csv.contains("\ngeometric+fofnet,divergent,") && csv.contains("\nneural+fofnet,close,"), "{csv}");
    let md = std::fs::read_to_string(opts.out.join("report.md")).unwrap();
    assert!(md.contains("| fofnet |") && md.contains("| inflation |"), "{md}");

    // Without fof.onnx: no FOF-net rows, and report.md says why.
    std::fs::remove_file(models.join("fof.onnx")).unwrap();
    let out = dir.path().join("eval2");
    let rep = run_eval_with(&EvalOptions { out: out.clone(), ..opts }, &nopts).unwrap();
    assert!(rep.rows.iter().all(|r| !r.method.ends_with("fofnet")), "{:?}", rep.rows);
    assert!(rep.rows.iter().any(|r| r.method == "neural+inflation"));
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("FOF-net rows") && md.contains("fof.onnx"), "{md}");
}

/// The volumetric IoU of the report against closed forms: slabs z in [-0.5, 0.5] and [0, 0.5] on the same pixels
/// overlap by half their union; disjoint pixel sets give 0; a field against itself gives 1.
#[test]
fn volumetric_iou_matches_closed_forms() {
    let (w, h) = (8, 6);
    let mask = GrayImage::new(w, h, 1.0);
    let slab = |lo: f32, hi: f32| {
        Fof::from_depth_maps(&GrayImage::new(w, h, hi), &GrayImage::new(w, h, lo), &mask, 32).unwrap()
    };
    let (a, b) = (slab(-0.5, 0.5), slab(0.0, 0.5));
    let iou = fof_occupancy_iou(&a, &b, 256);
    assert!((iou - 0.5).abs() < 0.02, "{iou}");
    assert_eq!(fof_occupancy_iou(&a, &a, 64), 1.0);
    let left = GrayImage::from_fn(w, h, |c, _| if c < w / 2 { 1.0 } else { 0.0 });
    let right = GrayImage::from_fn(w, h, |c, _| if c >= w / 2 { 1.0 } else { 0.0 });
    let d =
        |m: &GrayImage| Fof::from_depth_maps(&GrayImage::new(w, h, 0.5), &GrayImage::new(w, h, -0.5), m, 32).unwrap();
    assert_eq!(fof_occupancy_iou(&d(&left), &d(&right), 64), 0.0);
    let empty = Fof::zeros(32, w, h).unwrap();
    assert_eq!(fof_occupancy_iou(&empty, &empty, 64), 1.0);
}

/// Checks a `size`² FOF `fof` that an offset fixture net (`fof_offset.onnx`, `fof_geometry.onnx`,
/// `fof_body.onnx`: the first coefficient + 0.25 inside the silhouette) made of the FOF it is residual on,
/// `base`: empty where the base is, every coefficient but the first the base's, the first the base's or 0.25 more
/// (columns whose four model taps all miss the resampled mask keep the base). Returns (columns inside the base,
/// columns corrected by 0.25).
fn offset_columns(base: &Fof, fof: &Fof, size: usize) -> (usize, usize) {
    let (mut inside, mut corrected) = (0, 0);
    for row in 0..size {
        for col in 0..size {
            let (b, f) = (base.column(col, row), fof.column(col, row));
            if b.iter().all(|v| *v == 0.0) {
                assert!(f.iter().all(|v| *v == 0.0), "({col},{row}) outside the base: {f:?}");
                continue;
            }
            inside += 1;
            assert_eq!(&f[1..], &b[1..], "({col},{row}): the other coefficients are the base's");
            let d = f[0] - b[0];
            assert!((d - 0.25).abs() < 1e-5 || d == 0.0, "({col},{row}): c0 {} -> {}", b[0], f[0]);
            corrected += (d != 0.0) as usize;
        }
    }
    (inside, corrected)
}

/// [`blocky_person`] with two FOF inputs for the fixture nets: an inflation `prior` and, as a stand-in `body`
/// FOF, a thicker inflation of the same mask.
fn blocky_person_with_fofs(size: usize) -> (RgbImage, GrayImage, Fof, Fof) {
    let (rgb, mask) = blocky_person(size);
    let prior = inflate_to_fof(&mask, N, &InflateParams { thickness: 3.0, ..Default::default() }, None).unwrap();
    let body = inflate_to_fof(&mask, N, &InflateParams { thickness: 4.0, ..Default::default() }, None).unwrap();
    (rgb, mask, prior, body)
}

/// A FOF net on the reference's inputs (`r2human.fof_inputs = image,body,prior`, residual on the body FOF): it
/// refines the body FOF, not the inflation prior (the fixture adds 0.25 to c0 of its `body` input and ignores
/// `prior`), needs the body FOF (a clear error without it), and checks its size; old files (no
/// `r2human.fof_inputs`) keep taking image + prior; metadata naming an input this build cannot feed, or a residual
/// base the model does not take, is an error naming the key.
#[test]
fn body_fof_net_refines_the_body_fof_and_needs_it() {
    let size = 4 * R;
    let (rgb, mask, prior, body) = blocky_person_with_fofs(size);
    assert_ne!(prior, body);
    let mut net = FofNet::load(&fixture("fof_body.onnx"), &cpu()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(net.inputs(), &[FofInput::Body, FofInput::Prior]);
    assert!(net.takes_body() && net.has_prior());
    assert_eq!(net.base(), FofInput::Body);
    let e = net.refine(&rgb, &mask, &prior).expect_err("no body FOF given");
    assert!(matches!(e, NeuralError::BadInput { .. }) && e.to_string().contains("body FOF"), "{e}");
    let fof = net.refine_with(&rgb, &mask, &prior, Some(&body)).unwrap();
    let (inside, corrected) = offset_columns(&body, &fof, size);
    assert!(inside > 500 && corrected as f32 > 0.95 * inside as f32, "{corrected} of {inside}");
    // A body FOF of the wrong order or size is refused, naming it.
    let small = inflate_to_fof(&mask, N - 1, &InflateParams::default(), None).unwrap();
    let e = net.refine_with(&rgb, &mask, &prior, Some(&small)).expect_err("wrong N");
    assert!(e.to_string().contains("body has 3 coefficients"), "{e}");
    // Old files: image + prior, refining the prior.
    let legacy = FofNet::load(&fixture("fof_identity.onnx"), &cpu()).unwrap();
    assert_eq!((legacy.inputs(), legacy.takes_body(), legacy.base()), (&[FofInput::Prior][..], false, FofInput::Prior));
    for (file, key) in [("fof_bad_inputs.onnx", "r2human.fof_inputs"), ("fof_bad_residual.onnx", "r2human.residual")] {
        let e = FofNet::load(&fixture(file), &cpu()).expect_err(file);
        assert!(matches!(e, NeuralError::Metadata { .. }) && e.to_string().contains(key), "{file}: {e}");
    }
}

/// A FOF net that sees geometry only (`r2human.fof_inputs = body,prior`, no `image` input; the fixture adds 0.25 to
/// c0 of its `prior` and ignores `body`): it loads without an image input, is fed the two FOFs, and refines the
/// prior whatever the photo holds.
#[test]
fn geometry_only_fof_net_takes_no_photo() {
    let size = 4 * R;
    let (rgb, mask, prior, body) = blocky_person_with_fofs(size);
    let mut net = FofNet::load(&fixture("fof_geometry.onnx"), &cpu()).unwrap_or_else(|e| panic!("{e}"));
    assert!(!net.takes_image());
    assert_eq!((net.inputs(), net.base()), (&[FofInput::Body, FofInput::Prior][..], FofInput::Prior));
    let fof = net.refine_with(&rgb, &mask, &prior, Some(&body)).unwrap();
    // Another photo of the same silhouette gives the same geometry: the net never sees it.
    let dark = RgbImage::from_fn(size, size, |_, _| Vec3::ZERO);
    assert_eq!(net.refine_with(&dark, &mask, &prior, Some(&body)).unwrap(), fof);
    let (_, corrected) = offset_columns(&prior, &fof, size);
    assert!(corrected > 500, "{corrected}");
    assert!(FofNet::load(&fixture("fof_body.onnx"), &cpu()).unwrap().takes_image());
}

/// The pipeline feeds a net that takes the body FOF the body prior exactly as `--geometry body` computes it
/// ([`body_prior_fof`]) and falls back to that body FOF when the guard rejects; without a loaded body prior,
/// `--geometry fofnet` is an error that says so and `auto` is the inflation prior. Needs the pose model.
#[test]
fn pipeline_feeds_the_body_prior_to_a_net_that_takes_it() {
    let size = 128;
    let (rgb, mask, _) = subject_source(subject_seed(3, 9), size);
    let norm = r2human::pipeline::input::NormalisedInput::in_source_view(rgb, mask);
    let net = shared(&fixture("fof_body.onnx"));
    let base = PrepareOptions { resolution: size, depth_samples: size, fof_order: N, ..Default::default() };
    let prior = inflate_to_fof(&norm.mask, N, &base.inflate, None).unwrap();
    let explicit = PrepareOptions { geometry: GeometryMode::FofNet, fof_net: Some(Arc::clone(&net)), ..base.clone() };
    let e = compute_geometry(&norm, &explicit, &mut StageTimings::default()).expect_err("no body prior loaded");
    assert!(matches!(e, PipelineError::NoFofNet(_)) && e.to_string().contains("body FOF"), "{e}");
    let auto = PrepareOptions { geometry: GeometryMode::Auto, ..explicit.clone() };
    assert_eq!(compute_geometry(&norm, &auto, &mut StageTimings::default()).unwrap(), prior);

    let body = load_body_for(GeometryMode::FofNet, Some(&net), &cpu()).unwrap_or_else(|e| panic!("{e}"));
    assert!(body.is_some(), "a net that takes the body FOF loads the body prior");
    assert!(load_body_for(GeometryMode::FofNet, Some(&shared(&fixture("fof_identity.onnx"))), &cpu())
        .unwrap()
        .is_none());
    let with_body = PrepareOptions { body, ..explicit };
    let mut timings = StageTimings::default();
    let fof = compute_geometry(&norm, &with_body, &mut timings).unwrap_or_else(|e| panic!("{e}"));
    for stage in ["pose landmarks", "body fit", "body FOF", "geometry (FOF net)"] {
        assert!(timings.0.iter().any(|(name, _)| *name == stage), "{stage}: {:?}", timings.0);
    }
    let (body_fof, fallback) = body_prior_fof(
        &norm,
        &with_body,
        with_body.body.as_ref().unwrap(),
        prior.clone(),
        &mut StageTimings::default(),
    );
    assert!(fallback.is_none(), "the pose network finds the rendered subject: {fallback:?}");
    let refined = net.lock().unwrap().refine_with(&norm.rgb, &norm.mask, &prior, Some(&body_fof)).unwrap();
    let (want, _) = r2human::pipeline::guard::guarded(refined, body_fof, &norm.mask, &Default::default());
    // compute_geometry places whatever it chose in depth by the body cube's convention.
    assert_eq!(fof, r2human::geometry::depth_centre::centre_fof(want).0);
    assert_ne!(fof, prior);
}

/// `r2human dataset` writes `body_fof.npy` next to `prior_fof.npy`: same shape and layout, the body prior on the
/// rendered source (held inside the silhouette like the prior, and different from it), and says where it came
/// from in `subject.json` and `dataset.json`. Needs the pose model.
#[test]
fn dataset_writes_the_body_fof_of_the_rendered_source() {
    use r2human::eval::dataset::{write_dataset, DatasetOptions};
    use r2human::io::npy::{NpyArray, NpyData};
    let dir = tempfile::tempdir().unwrap();
    let opts = DatasetOptions {
        subjects: 1,
        seed: 3,
        out: dir.path().to_path_buf(),
        views: 0,
        size: 64,
        fof_n: 8,
        texture_size: 128,
        progress: false,
        ..Default::default()
    };
    let summary = write_dataset(&opts).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(summary.written.len(), 1);
    let read = |f: &str| match NpyArray::read(&dir.path().join("subject_0000").join(f)).unwrap() {
        NpyArray { shape, data: NpyData::F32(v), .. } => (shape, v),
        other => panic!("{f}: {:?}", other.shape),
    };
    let (shape, body) = read("body_fof.npy");
    let (prior_shape, prior) = read("prior_fof.npy");
    assert_eq!((shape.clone(), prior_shape), (vec![64, 64, 8], vec![64, 64, 8]));
    assert!(body.iter().all(|v| v.is_finite()));
    let occupied = |c: &[f32], i: usize| c[i * 8] > 1e-4;
    let (mut both, mut only_body, mut only_prior) = (0, 0, 0);
    for i in 0..64 * 64 {
        match (occupied(&body, i), occupied(&prior, i)) {
            (true, true) => both += 1,
            (true, false) => only_body += 1,
            (false, true) => only_prior += 1,
            _ => {}
        }
    }
    assert!(both > 200 && only_body * 50 <= both && only_prior * 10 <= both, "{both} {only_body} {only_prior}");
    assert_ne!(body, prior);
    let info: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("subject_0000/subject.json")).unwrap()).unwrap();
    let source = info["body_fof"]["source"].as_str().unwrap_or_default();
    assert!(source.contains("fitted body") || source.contains("fall-back"), "{info}");
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("dataset.json")).unwrap()).unwrap();
    assert_eq!(manifest["body_fof"], serde_json::json!(true));
    assert_eq!(manifest["body_fof_fallbacks"].as_array().map(|a| a.len()), Some(summary.body_fallbacks.len()));

    // With the body FOF comes the back image of the rendered source (the pose network found this subject's face):
    // at the dataset's size, colour where the person is and nowhere else, and not the photo itself (the face and
    // the clothing's details are filtered away).
    assert_eq!(manifest["back_image"], serde_json::json!(true));
    assert_eq!(info["back_image"], serde_json::json!(true), "{info}");
    let load = |f: &str| image::open(dir.path().join("subject_0000").join(f)).unwrap().to_rgba8();
    let (back, photo) = (load("source_back.png"), load("source_rgba.png"));
    assert_eq!(back.dimensions(), (64, 64));
    let (mut person, mut covered, mut far, mut differ) = (0, 0, 0, 0);
    // The back image is averaged from the finer grid the pipeline works on: it covers the partial pixels of the
    // outline, which the photo's own render (pixel centres) may leave out, but nothing further out.
    let near_person = |x: u32, y: u32| {
        (x.saturating_sub(1)..(x + 2).min(64))
            .any(|i| (y.saturating_sub(1)..(y + 2).min(64)).any(|j| photo.get_pixel(i, j)[3] > 0))
    };
    for (x, y, b) in back.enumerate_pixels() {
        let p = photo.get_pixel(x, y);
        person += (p[3] > 0) as usize;
        covered += (p[3] > 0 && b[3] > 0) as usize;
        far += (b[3] > 0 && !near_person(x, y)) as usize;
        differ += (p[3] > 0 && (0..3).any(|c| b[c].abs_diff(p[c]) > 8)) as usize;
    }
    assert!(covered * 10 >= person * 9 && far == 0, "{person} {covered} {far}");
    assert!(differ * 10 >= person, "the back image is the photo: {differ} of {person} pixels differ");

    // Subject by subject, the same bytes however many subjects share the run: the subjects are written in parallel
    // through one shared body estimator and one pose network, and no state of one may reach another.
    let more = tempfile::tempdir().unwrap();
    write_dataset(&DatasetOptions { subjects: 3, out: more.path().to_path_buf(), ..opts.clone() })
        .unwrap_or_else(|e| panic!("{e}"));
    for f in ["body_fof.npy", "source_back.png", "prior_fof.npy"] {
        let bytes = |d: &std::path::Path| std::fs::read(d.join("subject_0000").join(f)).unwrap();
        assert!(bytes(dir.path()) == bytes(more.path()), "{f} of subject_0000 depends on the run's size");
    }
}

/// The fitted body is placed in depth by the part the photo shows: the centroid of its occupied volume over the
/// mask goes to z = 0. Closed form (box faces on pixel edges of the 128² measuring grid): a torso box of 64 x 56
/// pixels spanning z 0.1..0.5 and an arm box of 8 x 8 pixels in front of it at z 0.55..0.95 have their centroid at
/// (3584 * 0.3 + 64 * 0.75) / 3648; a box the mask does not show lies far behind and does not count; the xz
/// circle of the extremities (the old rule) would have moved everything by about 0.5 instead. Nothing moves when
/// no part of the body covers the mask.
#[test]
fn fitted_body_is_centred_on_its_visible_part() {
    use glam::Vec3;
    use r2human::geometry::TriMesh;
    let mut mesh = TriMesh::cuboid(Vec3::new(-0.5, 0.0625, 0.1), Vec3::new(0.5, 0.9375, 0.5));
    for part in [
        TriMesh::cuboid(Vec3::new(-0.0625, 0.3125, 0.55), Vec3::new(0.0625, 0.4375, 0.95)),
        TriMesh::cuboid(Vec3::new(-0.3, -0.9, -0.9), Vec3::new(0.3, -0.1, -0.5)),
    ] {
        let offset = mesh.positions.len() as u32;
        mesh.positions.extend(&part.positions);
        mesh.triangles.extend(part.triangles.iter().map(|t| t.map(|i| i + offset)));
    }
    let shift = (3584.0 * 0.3 + 64.0 * 0.75) / 3648.0;
    let positions = mesh.positions.clone();
    // The mask covers the top half of the view (y > 0) only.
    let mask = GrayImage::from_fn(32, 32, |_, r| if r < 16 { 1.0 } else { 0.0 });
    let centred = centre_visible_depth(mesh.clone(), &mask);
    for (a, b) in positions.iter().zip(&centred.positions) {
        assert!((b.z - (a.z - shift)).abs() < 1e-4 && a.x == b.x && a.y == b.y, "{a} -> {b}");
    }
    let empty = GrayImage::from_fn(32, 32, |_, _| 0.0);
    assert_eq!(centre_visible_depth(mesh.clone(), &empty).positions, positions);
}

/// The FOF net trained on the reference's inputs ships as `models/tiny/fof_body.onnx` (not the default `fof.onnx`,
/// which sees geometry only and scores the same without reading the photo, see models/tiny/README.md): it takes
/// the photo, the body FOF and the inflation prior, is residual on the prior, and has the pipeline's order.
#[test]
fn shipped_body_input_fof_net_declares_its_inputs() {
    let net = FofNet::load(&shipped_dir().join("fof_body.onnx"), &cpu()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(net.inputs(), &[FofInput::Body, FofInput::Prior]);
    assert_eq!((net.base(), net.info().fof_n, net.info().resolution), (FofInput::Prior, 32, 128));
    assert!(net.info().recipe.contains("\"fof_inputs\""), "{}", net.info().recipe);
}

/// The placement net's shift reaches the FOF grid by mask-aware bilinear upsampling: the fixture's closed-form
/// split (0.1 on the model's left half, -0.2 on its right) comes back exactly away from the split and the
/// silhouette's edge holds the shift of the model pixels inside (renormalised, not pulled toward 0); outside the
/// mask the shift is 0. Broken files are errors that name the problem: a non-finite shift, a FOF net loaded as a
/// placement net and the other way round, inputs of another size or order.
#[test]
fn placement_net_upsamples_its_shift_inside_the_mask_and_rejects_broken_files() {
    let size = 4 * R;
    let (_, mask) = blocky_person(size);
    let prior = inflate_to_fof(&mask, N, &InflateParams::default(), None).unwrap();
    let mut net = PlacementNet::load(&fixture("placement_split.onnx"), &cpu()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((net.info().resolution, net.info().fof_n), (R, N));
    let shifts = net.shifts(&mask, &prior, &prior).unwrap();
    assert_eq!((shifts.width, shifts.height), (size, size));
    let (mut left, mut right) = (0, 0);
    for r in 0..size {
        for c in 0..size {
            let (s, m) = (*shifts.get(c, r), *mask.get(c, r));
            if m <= 0.5 {
                assert_eq!(s, 0.0, "outside the mask at ({c}, {r})");
            } else if c < size / 2 - 2 {
                assert!((s - 0.1).abs() < 1e-6, "({c}, {r}): {s}");
                left += 1;
            } else if c >= size / 2 + 2 {
                assert!((s + 0.2).abs() < 1e-6, "({c}, {r}): {s}");
                right += 1;
            } else {
                assert!((-0.2 - 1e-6..=0.1 + 1e-6).contains(&s), "({c}, {r}): {s}");
            }
        }
    }
    assert!(left > 200 && right > 200, "{left} {right}");

    let e = PlacementNet::load(&fixture("placement_nan32.onnx"), &cpu())
        .unwrap()
        .shifts(&mask, &inflate_to_fof(&mask, 32, &InflateParams::default(), None).unwrap(), &prior)
        .expect_err("N = 4 input to an N = 32 net");
    assert!(matches!(e, NeuralError::BadInput { .. }) && e.to_string().contains("32"), "{e}");
    let prior32 = inflate_to_fof(&mask, 32, &InflateParams::default(), None).unwrap();
    let e = PlacementNet::load(&fixture("placement_nan32.onnx"), &cpu())
        .unwrap()
        .shifts(&mask, &prior32, &prior32)
        .expect_err("NaN shift");
    assert!(matches!(e, NeuralError::NonFinite { .. }), "{e}");
    let e = PlacementNet::load(&fixture("fof_geometry.onnx"), &cpu()).expect_err("a FOF net is no placement net");
    assert!(e.to_string().contains("r2human.kind"), "{e}");
    let e = FofNet::load(&fixture("placement_split.onnx"), &cpu()).expect_err("a placement net is no FOF net");
    assert!(e.to_string().contains("r2human.kind"), "{e}");
    let small = GrayImage::new(size / 2, size / 2, 1.0);
    assert!(matches!(net.shifts(&small, &prior, &prior), Err(NeuralError::BadInput { .. })));
}

/// `load_placement_net` takes the model folder's `placement.onnx` for `body-placed` (and auto when it draws it),
/// none for the other geometries or when the folder has none (the confidence-aware placement of `body::placed`); a
/// file of another order is an error under `body-placed`. In the pipeline the net's shifts place the inflation
/// prior (a different geometry from the one without a net), and a net that fails on the input gives the geometry
/// without a net. Needs the pose model.
#[test]
fn body_placed_uses_the_folders_placement_net_and_falls_back_to_no_placement() {
    let dir = tempfile::tempdir().unwrap();
    let load = |mode, n| r2human::pipeline::load_placement_net(mode, Some(dir.path()), n, &cpu());
    assert!(load(GeometryMode::BodyPlaced, 32).unwrap().is_none(), "no file: no placement net");
    std::fs::copy(fixture("placement_split.onnx"), dir.path().join("placement.onnx")).unwrap();
    let e = load(GeometryMode::BodyPlaced, 32).expect_err("N = 4 file for N = 32");
    assert!(matches!(e, PipelineError::PlacementOrder(_)) && e.to_string().contains("--fof-order"), "{e}");
    std::fs::write(dir.path().join("placement.onnx"), b"not an onnx file").unwrap();
    let e = load(GeometryMode::BodyPlaced, 32).expect_err("a corrupt file");
    assert!(matches!(e, PipelineError::PlacementLoad(NeuralError::ModelLoad { .. })), "{e:?}");
    assert!(load(GeometryMode::Auto, 32).unwrap().is_none(), "auto: no placement");
    assert!(load(GeometryMode::Auto, 32).unwrap().is_none());
    std::fs::copy(fixture("placement_split32.onnx"), dir.path().join("placement.onnx")).unwrap();
    assert!(load(GeometryMode::Inflate, 32).unwrap().is_none());
    assert!(load(GeometryMode::Body, 32).unwrap().is_none());
    let split = load(GeometryMode::BodyPlaced, 32).unwrap().expect("the folder's placement net");

    let size = 128;
    let (rgb, mask, _) = subject_source(subject_seed(3, 9), size);
    let norm = r2human::pipeline::input::NormalisedInput::in_source_view(rgb, mask);
    let body = load_body_for(GeometryMode::BodyPlaced, None, &cpu()).unwrap_or_else(|e| panic!("{e}"));
    let base = PrepareOptions {
        resolution: size,
        depth_samples: size,
        geometry: GeometryMode::BodyPlaced,
        body,
        ..Default::default()
    };
    let geometry = |placement: Option<r2human::pipeline::SharedPlacementNet>| {
        let mut timings = StageTimings::default();
        let o = PrepareOptions { placement, ..base.clone() };
        (compute_geometry(&norm, &o, &mut timings).unwrap_or_else(|e| panic!("{e}")), timings)
    };
    let (fixed, _) = geometry(None);
    let (learned, timings) = geometry(Some(split));
    assert!(timings.0.iter().any(|(name, _)| *name == "body placement (network)"), "{:?}", timings.0);
    assert_ne!(learned, fixed);
    let broken = Arc::new(Mutex::new(PlacementNet::load(&fixture("placement_nan32.onnx"), &cpu()).unwrap()));
    assert_eq!(geometry(Some(broken)).0, fixed, "a failing net: the placement without a net");
}
