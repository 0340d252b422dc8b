//! The inputs of the geometry examples (`geometry_blend`, `geometry_oracle`): synthetic clothed subjects in the
//! framings of `r2human eval --subjects N`, or scans read as the scan check reads them, each as the source view the
//! pipeline receives and its ground-truth FOF. Included with `#[path]` (not an example of its own).

use std::path::Path;

use anyhow::Context;
use r2human::buffer::{GrayImage, RgbImage};
use r2human::eval::dataset::subject_seed;
use r2human::eval::ground_truth::render_ground_truth;
use r2human::eval::runner::fof_occupancy_iou;
use r2human::geometry::camera::Camera;
use r2human::geometry::fof::Fof;
use r2human::io::mesh_io::TexturedMesh;
use r2human::neural::RuntimeOptions;
use r2human::pipeline::input::NormalisedInput;
use r2human::pipeline::{
    compute_geometry, load_body_for, load_fof_net, load_placement_net, GeometryMode, PrepareOptions, StageTimings,
};
use r2human::synth::framing::{self, FramingChoice};
use r2human::synth::scan::{load_scan_with, Facing, ScanOrientation, UpAxis};
use r2human::synth::{self, SubjectParams, SynthAssets};

/// FOF coefficients per pixel (the pipeline's default order).
pub const N: usize = 32;
/// Depth samples per column of the volumetric IoU (as `r2human eval`).
pub const IOU_SAMPLES: usize = 128;

/// One input with its ground truth.
pub struct Case {
    /// Subject index and framing, or the scan's file stem.
    pub label: String,
    /// The source view as the pipeline receives it.
    pub input: NormalisedInput,
    /// The ground-truth FOF on the source grid.
    pub truth: Fof,
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

/// The cases the command line asks for: `[SUBJECTS] [SEED] [SIZE]` (defaults 9, 0, 256) or
/// `--scans [--size N] FILE...` (read with `--up y --facing +z`), and the grid size.
pub fn from_args(name: &str) -> anyhow::Result<(Vec<Case>, usize)> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let usage = || format!("usage: {name} [SUBJECTS] [SEED] [SIZE] | --scans [--size N] FILE...");
    let mut size = 256;
    let mut cases = Vec::new();
    if args.first().is_some_and(|a| a == "--scans") {
        args.remove(0);
        if args.first().is_some_and(|a| a == "--size") {
            size = args.get(1).with_context(usage)?.parse().with_context(usage)?;
            args.drain(..2);
        }
        anyhow::ensure!(!args.is_empty(), "{}", usage());
        let orientation = ScanOrientation { up: Some(UpAxis::Y), facing: Some(Facing::PlusZ) };
        for file in &args {
            let path = Path::new(file);
            let scan = load_scan_with(path, &orientation)?;
            let label = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| file.clone());
            cases.push(case(label, &scan.mesh, size, None)?);
        }
    } else {
        let subjects: usize = args.first().map(|s| s.parse()).transpose().with_context(usage)?.unwrap_or(9);
        let seed: u64 = args.get(1).map(|s| s.parse()).transpose().with_context(usage)?.unwrap_or(0);
        size = args.get(2).map(|s| s.parse()).transpose().with_context(usage)?.unwrap_or(256);
        let assets = SynthAssets::shared()?;
        for i in 0..subjects {
            let s = synth::generate(assets, &SubjectParams::sample(subject_seed(seed, i)), 256)?;
            let s = framing::crop(&s, FramingChoice::Mixed.of(i), &assets.rig)?;
            cases.push(case(format!("{i} {}", s.crop.framing.label()), &s.mesh, size, Some(s.source_frame(size)))?);
        }
    }
    Ok((cases, size))
}

/// The pipeline options of the examples at `size`, with the shipped FOF net and the body prior loaded (the
/// geometries of `--geometry fofnet|body|body-placed`; the inflation prior needs neither).
pub fn geometry_options(size: usize) -> anyhow::Result<PrepareOptions> {
    let options = RuntimeOptions::default();
    let net = load_fof_net(GeometryMode::FofNet, None, N, &options)?;
    let body = load_body_for(GeometryMode::BodyPlaced, net.as_ref(), &options)?;
    let placement = load_placement_net(GeometryMode::BodyPlaced, None, N, &options)?;
    Ok(PrepareOptions { resolution: size, depth_samples: size, fof_net: net, body, placement, ..Default::default() })
}

impl Case {
    /// The geometry `mode` draws for this input, as `r2human --geometry` computes it (placed in depth).
    pub fn geometry(&self, base: &PrepareOptions, mode: GeometryMode) -> anyhow::Result<Fof> {
        let opts = PrepareOptions { geometry: mode, ..base.clone() };
        compute_geometry(&self.input, &opts, &mut StageTimings::default()).with_context(|| self.label.clone())
    }
}

/// Prints a table of the volumetric IoU of each field `fields` gives a case (one column per name) against that
/// case's ground truth, a row per case and their mean.
pub fn print_ious(
    names: &[&str],
    cases: &[Case],
    fields: impl Fn(&Case) -> anyhow::Result<Vec<Fof>>,
) -> anyhow::Result<()> {
    let width = names.iter().map(|n| n.len()).max().unwrap_or(0).max(6) + 2;
    println!("{:<20}{}", "input", names.iter().map(|n| format!("{n:>width$}")).collect::<String>());
    let mut sums = vec![0.0f64; names.len()];
    for c in cases {
        let mut line = format!("{:<20}", c.label);
        for (sum, field) in sums.iter_mut().zip(fields(c)?) {
            let iou = f64::from(fof_occupancy_iou(&field, &c.truth, IOU_SAMPLES));
            *sum += iou;
            line += &format!("{iou:>width$.3}");
        }
        println!("{line}");
    }
    let n = cases.len().max(1) as f64;
    println!("{:<20}{}", "mean", sums.iter().map(|s| format!("{:>width$.3}", s / n)).collect::<String>());
    Ok(())
}
