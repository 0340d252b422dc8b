//! Would averaging the three per-input geometries beat each of them? Volumetric IoU against the ground truth of
//! the inflation prior (I), the body prior (B), the FOF net (F, the project's `models/tiny/fof.onnx`) and of the
//! weighted means of their FOF coefficients:
//! `cargo run --release --example geometry_blend -- [SUBJECTS] [SEED] [SIZE]` (defaults 9, 0, 256: the subjects and
//! framings of `r2human eval --subjects 9`), or on scans:
//! `cargo run --release --example geometry_blend -- --scans [--size N] FILE...` (e.g. the ten characters
//! `scripts/scan-check.sh OUT` writes to OUT/files/characters/*/*.obj, read with `--up y --facing +z` as its eval
//! reads them).
//!
//! A FOF is linear in the occupancy it encodes, so the mean of two FOFs decodes to the mean of their occupancies,
//! and thresholding it at the marching level keeps what the weighted majority of the geometries keeps (a soft
//! vote). Each geometry comes from [`r2human::pipeline::compute_geometry`] exactly as `--geometry` draws it (placed
//! in depth by the volume-centroid convention); a blend is placed again the same way
//! ([`r2human::geometry::depth_centre::centre_fof`]). Prints one row per input and the mean: a blend is worth
//! shipping only if the synthetic people and the independent characters agree (README "Which geometry, where").

use std::path::Path;

use anyhow::Context;
use r2human::buffer::{GrayImage, RgbImage};
use r2human::eval::dataset::subject_seed;
use r2human::eval::ground_truth::render_ground_truth;
use r2human::eval::runner::fof_occupancy_iou;
use r2human::geometry::camera::Camera;
use r2human::geometry::depth_centre::centre_fof;
use r2human::geometry::fof::Fof;
use r2human::io::mesh_io::TexturedMesh;
use r2human::neural::RuntimeOptions;
use r2human::pipeline::input::NormalisedInput;
use r2human::pipeline::{compute_geometry, load_body_for, load_fof_net, GeometryMode, PrepareOptions, StageTimings};
use r2human::synth::framing::{self, FramingChoice};
use r2human::synth::scan::{load_scan_with, Facing, ScanOrientation, UpAxis};
use r2human::synth::{self, SubjectParams, SynthAssets};

/// FOF coefficients per pixel (the pipeline's default order).
const N: usize = 32;
/// Depth samples per column of the volumetric IoU (as `r2human eval`).
const IOU_SAMPLES: usize = 128;
/// The columns: weights of (inflation, body, FOF net) in each candidate.
const CANDIDATES: [(&str, [f32; 3]); 9] = [
    ("I", [1.0, 0.0, 0.0]),
    ("B", [0.0, 1.0, 0.0]),
    ("F", [0.0, 0.0, 1.0]),
    ("I+B", [1.0, 1.0, 0.0]),
    ("I+F", [1.0, 0.0, 1.0]),
    ("B+F", [0.0, 1.0, 1.0]),
    ("I+B+F", [1.0, 1.0, 1.0]),
    ("I+2B", [1.0, 2.0, 0.0]),
    ("B+2F", [0.0, 1.0, 2.0]),
];

/// One input with its ground truth.
struct Case {
    label: String,
    input: NormalisedInput,
    truth: Fof,
}

/// The weighted mean of `fofs`' coefficients (same grid and order), placed in depth by the convention.
fn blend(fofs: &[&Fof; 3], weights: [f32; 3]) -> Fof {
    let total: f32 = weights.iter().sum();
    let mut out = fofs[0].clone();
    for (i, c) in out.coeffs.iter_mut().enumerate() {
        *c = fofs.iter().zip(weights).map(|(f, w)| w * f.coeffs[i]).sum::<f32>() / total;
    }
    centre_fof(out).0
}

/// The source view of a mesh as the eval's input, and the mesh's ground-truth FOF.
fn case(
    label: String,
    mesh: &TexturedMesh,
    size: usize,
    frame: Option<(glam::Vec2, glam::Vec2)>,
) -> anyhow::Result<Case> {
    let view = render_ground_truth(mesh, &Camera::source(size));
    let rgb: RgbImage = view.to_linear_rgba().map(|p| p.truncate());
    let mask: GrayImage = view.mask_image();
    let mut input = NormalisedInput::in_source_view(rgb, mask);
    if let Some(frame) = frame {
        input.frame = frame;
    }
    Ok(Case { label, input, truth: Fof::from_mesh(&mesh.mesh, size, N)? })
}

fn main() -> anyhow::Result<()> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: geometry_blend [SUBJECTS] [SEED] [SIZE] | --scans [--size N] FILE...";
    let mut size = 256;
    let mut cases = Vec::new();
    if args.first().is_some_and(|a| a == "--scans") {
        args.remove(0);
        if args.first().is_some_and(|a| a == "--size") {
            size = args.get(1).context(usage)?.parse().context(usage)?;
            args.drain(..2);
        }
        anyhow::ensure!(!args.is_empty(), "{usage}");
        let orientation = ScanOrientation { up: Some(UpAxis::Y), facing: Some(Facing::PlusZ) };
        for file in &args {
            let path = Path::new(file);
            let scan = load_scan_with(path, &orientation)?;
            let label = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| file.clone());
            cases.push(case(label, &scan.mesh, size, None)?);
        }
    } else {
        let subjects: usize = args.first().map(|s| s.parse()).transpose().context(usage)?.unwrap_or(9);
        let seed: u64 = args.get(1).map(|s| s.parse()).transpose().context(usage)?.unwrap_or(0);
        size = args.get(2).map(|s| s.parse()).transpose().context(usage)?.unwrap_or(256);
        let assets = SynthAssets::shared()?;
        for i in 0..subjects {
            let s = synth::generate(assets, &SubjectParams::sample(subject_seed(seed, i)), 256)?;
            let s = framing::crop(&s, FramingChoice::Mixed.of(i), &assets.rig)?;
            cases.push(case(format!("{i} {}", s.crop.framing.label()), &s.mesh, size, Some(s.source_frame(size)))?);
        }
    }
    let options = RuntimeOptions::default();
    let net = load_fof_net(GeometryMode::FofNet, None, N, &options)?;
    let body = load_body_for(GeometryMode::FofNet, net.as_ref(), &options)?;
    let base = PrepareOptions { resolution: size, depth_samples: size, fof_net: net, body, ..Default::default() };
    let names: String = CANDIDATES.iter().map(|(n, _)| format!("{n:>7}")).collect();
    println!("{:<20}{names}", "input");
    let mut sums = [0.0f64; CANDIDATES.len()];
    for c in &cases {
        let geometry = |mode| -> anyhow::Result<Fof> {
            let opts = PrepareOptions { geometry: mode, ..base.clone() };
            compute_geometry(&c.input, &opts, &mut StageTimings::default()).with_context(|| c.label.clone())
        };
        let (i, b, f) =
            (geometry(GeometryMode::Inflate)?, geometry(GeometryMode::Body)?, geometry(GeometryMode::FofNet)?);
        let mut line = format!("{:<20}", c.label);
        for (k, (_, w)) in CANDIDATES.iter().enumerate() {
            let iou = f64::from(fof_occupancy_iou(&blend(&[&i, &b, &f], *w), &c.truth, IOU_SAMPLES));
            sums[k] += iou;
            line += &format!("{iou:>7.3}");
        }
        println!("{line}");
    }
    let n = cases.len().max(1) as f64;
    println!("{:<20}{}", "mean", sums.iter().map(|s| format!("{:>7.3}", s / n)).collect::<String>());
    Ok(())
}
