//! How thick should the silhouette-inflation prior be? Volumetric IoU of the inflation prior against the ground
//! truth for several values of κ ([`InflateParams::thickness`], `h = κ sqrt(u)`):
//! `cargo run --release --example inflate_thickness -- [SUBJECTS] [SEED] [SIZE] [SCAN ...]` (defaults 30, 100,
//! 256; scans: any glTF/GLB/OBJ/PLY, e.g. the Mr. Fixit files `scripts/scan-check.sh` exports).
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
            let prior = centre_fof(inflate_to_fof(&mask, N, &params)?).0;
            Ok(fof_occupancy_iou(&prior, &gt, 128))
        })
        .collect()
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let subjects: usize = args.first().map(|s| s.parse()).transpose().context("SUBJECTS")?.unwrap_or(30);
    let seed: u64 = args.get(1).map(|s| s.parse()).transpose().context("SEED")?.unwrap_or(100);
    let size: usize = args.get(2).map(|s| s.parse()).transpose().context("SIZE")?.unwrap_or(256);
    let scans: Vec<PathBuf> = args.iter().skip(3).map(PathBuf::from).collect();
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
    for path in &scans {
        let scan = synth::scan::load_scan(path).with_context(|| format!("scan {}", path.display()))?;
        rows.push((format!("scan {}", path.display()), ious(&scan.mesh, size)?, 1));
    }
    println!("| input | n | {} |", KAPPAS.iter().map(|k| format!("κ = {k}")).collect::<Vec<_>>().join(" | "));
    println!("|---|---:|{}", "---:|".repeat(KAPPAS.len()));
    for (name, sums, n) in rows.iter().filter(|r| r.2 > 0) {
        let means: Vec<String> = sums.iter().map(|s| format!("{:.3}", s / *n as f32)).collect();
        println!("| {name} | {n} | {} |", means.join(" | "));
    }
    Ok(())
}
