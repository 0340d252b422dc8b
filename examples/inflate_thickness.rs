//! How thick should the silhouette-inflation prior be? Volumetric IoU of the inflation prior against the ground
//! truth for several values of κ ([`InflateParams::thickness`], `h = κ sqrt(u)`):
//! `cargo run --release --example inflate_thickness -- [SUBJECTS] [SEED] [SIZE] [--up y|z] [--facing +z|-z|+x|-x]
//! [SCAN ...]` (defaults 30, 100, 256; scans: any glTF/GLB/OBJ/PLY, e.g. the characters `scripts/scan-check.sh`
//! writes to OUT/files/characters/*/*.obj, which need `--up y --facing +z` as in its eval; without the flags the
//! orientation is detected as `eval --scan` does). With two or more scans a last row gives their mean.
//!
//! Synthetic subjects are clothed, in the three framings in turn (seed 100 by default: not the evaluation's seed
//! 0); the ground truth and the prior are both placed in depth by the volume-centroid convention
//! ([`r2human::geometry::depth_centre`]), as `r2human eval` does. Prints the mean IoU per framing and per scan for
//! every κ: a κ is worth changing only if the synthetic people and the independent scans agree.

use std::path::PathBuf;

use anyhow::Context;
use r2human::eval::dataset::subject_seed;
use r2human::eval::ground_truth::render_ground_truth;
use r2human::eval::runner::fof_occupancy_iou;
use r2human::geometry::camera::Camera;
use r2human::geometry::depth_centre::centre_fof;
use r2human::geometry::fof::Fof;
use r2human::geometry::inflate::{inflate_to_fof, InflateParams};
use r2human::io::mesh_io::TexturedMesh;
use r2human::synth::framing::{self, Framing};
use r2human::synth::{self, SubjectParams, SynthAssets};

const KAPPAS: [f32; 7] = [0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0];
const N: usize = 32;

/// IoU of the inflation prior of `mesh`'s source-view mask for every κ of [`KAPPAS`].
fn ious(mesh: &TexturedMesh, size: usize) -> anyhow::Result<Vec<f32>> {
    let gt_view = render_ground_truth(mesh, &Camera::source(size));
    let mask = gt_view.mask_image();
    let gt = Fof::from_mesh(&mesh.mesh, size, N)?;
    KAPPAS
        .iter()
        .map(|&k| {
            let params = InflateParams { thickness: k, ..InflateParams::default() };
            let frame = r2human::body::prior::effective_frame(&mask, None);
            let prior = centre_fof(inflate_to_fof(&mask, N, &params, Some(frame))?).0;
            Ok(fof_occupancy_iou(&prior, &gt, 128))
        })
        .collect()
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let subjects: usize = args.first().map(|s| s.parse()).transpose().context("SUBJECTS")?.unwrap_or(30);
    let seed: u64 = args.get(1).map(|s| s.parse()).transpose().context("SEED")?.unwrap_or(100);
    let size: usize = args.get(2).map(|s| s.parse()).transpose().context("SIZE")?.unwrap_or(256);
    let mut orientation = synth::scan::ScanOrientation::default();
    let mut scans: Vec<PathBuf> = Vec::new();
    let mut rest = args.iter().skip(3);
    while let Some(arg) = rest.next() {
        match arg.as_str() {
            "--up" => orientation.up = Some(rest.next().context("--up needs y or z")?.parse()?),
            "--facing" => orientation.facing = Some(rest.next().context("--facing needs +z, -z, +x or -x")?.parse()?),
            path => scans.push(PathBuf::from(path)),
        }
    }
    let assets = SynthAssets::shared()?;
    let mut rows: Vec<(String, Vec<f32>, usize)> =
        Framing::ALL.iter().map(|f| (format!("synthetic {}", f.label()), vec![0.0; KAPPAS.len()], 0)).collect();
    for index in 0..subjects {
        let subject = synth::generate(assets, &SubjectParams::sample(subject_seed(seed, index)), 64)?;
        let subject = framing::crop(&subject, Framing::mixed(index), &assets.rig)?;
        let k = Framing::ALL.iter().position(|&f| f == subject.crop.framing).unwrap_or(0);
        for (acc, v) in rows[k].1.iter_mut().zip(ious(&subject.mesh, size)?) {
            *acc += v;
        }
        rows[k].2 += 1;
    }
    let mut scan_sums = vec![0.0; KAPPAS.len()];
    for path in &scans {
        let scan =
            synth::scan::load_scan_with(path, &orientation).with_context(|| format!("scan {}", path.display()))?;
        let values = ious(&scan.mesh, size)?;
        scan_sums.iter_mut().zip(&values).for_each(|(acc, v)| *acc += v);
        rows.push((format!("scan {}", path.display()), values, 1));
    }
    if scans.len() > 1 {
        rows.push(("scans, mean".to_string(), scan_sums, scans.len()));
    }
    println!("| input | n | {} |", KAPPAS.iter().map(|k| format!("κ = {k}")).collect::<Vec<_>>().join(" | "));
    println!("|---|---:|{}", "---:|".repeat(KAPPAS.len()));
    for (name, sums, n) in rows.iter().filter(|r| r.2 > 0) {
        let means: Vec<String> = sums.iter().map(|s| format!("{:.3}", s / *n as f32)).collect();
        println!("| {name} | {n} | {} |", means.join(" | "));
    }
    Ok(())
}
