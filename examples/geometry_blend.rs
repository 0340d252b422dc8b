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
//! shipping only if the synthetic people and the independent characters agree (docs/geometry.md, "Which geometry
//! wins where").

#[path = "common/cases.rs"]
mod cases;

use r2human::geometry::depth_centre::centre_fof;
use r2human::geometry::fof::Fof;
use r2human::pipeline::GeometryMode;

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

/// The weighted mean of `fofs`' coefficients (same grid and order), placed in depth by the convention.
fn blend(fofs: &[&Fof; 3], weights: [f32; 3]) -> Fof {
    let total: f32 = weights.iter().sum();
    let mut out = fofs[0].clone();
    for (i, c) in out.coeffs.iter_mut().enumerate() {
        *c = fofs.iter().zip(weights).map(|(f, w)| w * f.coeffs[i]).sum::<f32>() / total;
    }
    centre_fof(out).0
}

fn main() -> anyhow::Result<()> {
    let (cases, size) = cases::from_args("geometry_blend")?;
    let base = cases::geometry_options(size)?;
    let names: Vec<&str> = CANDIDATES.iter().map(|(n, _)| *n).collect();
    cases::print_ious(&names, &cases, |c| {
        let i = c.geometry(&base, GeometryMode::Inflate)?;
        let b = c.geometry(&base, GeometryMode::Body)?;
        let f = c.geometry(&base, GeometryMode::FofNet)?;
        Ok(CANDIDATES.iter().map(|(_, w)| blend(&[&i, &b, &f], *w)).collect())
    })
}
