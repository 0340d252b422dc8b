//! Where is a predicted geometry wrong: in how thick each column is, or in where the column sits in depth?
//! `cargo run --release --example geometry_oracle -- [SUBJECTS] [SEED] [SIZE]` (defaults 9, 0, 256: the subjects and
//! framings of `r2human eval --subjects 9`) or `-- --scans [--size N] FILE...` (e.g. the characters of
//! `scripts/scan-check.sh OUT`, OUT/files/characters/*/*.obj, read with `--up y --facing +z`).
//!
//! Every column of a field is reduced to one interval: its occupied length (thickness) about its occupied centroid
//! (depth), decoded at the volumetric IoU's 128 samples. Prints the volumetric IoU against the ground truth of:
//! - `I`, `B`, `F`, `BP`: the inflation prior, the body prior, the FOF net and the body-placed inflation prior, as
//!   `--geometry inflate|body|fofnet|body-placed` draw them;
//! - `G1`: the ground truth reduced to one interval per column (what any one-interval geometry can reach at best);
//! - `I|Gd`: the inflation prior's thickness at the ground truth's depths (a perfect depth placement);
//! - `Gt|Id`: the ground truth's thickness at the inflation prior's depths (a perfect thickness).
//!
//! `I|Gd` against `Gt|Id` says which of the two the inflation prior lacks more (README "Body-placed inflation").
//! Each constructed field is placed in depth by the volume-centroid convention, as the pipeline places its own.

#[path = "common/cases.rs"]
mod cases;

use cases::{IOU_SAMPLES, N};
use r2human::buffer::Image;
use r2human::geometry::depth_centre::centre_fof;
use r2human::geometry::fof::{CosineTable, Fof};
use r2human::geometry::marching::ISO_LEVEL;
use r2human::pipeline::GeometryMode;

/// Thickness and depth (body-cube units) of one column.
type Column = Option<(f32, f32)>;

/// Every column's occupied length and occupied centroid, `None` where it is empty.
fn columns(f: &Fof) -> Vec<Column> {
    let table = CosineTable::new(f.n, IOU_SAMPLES);
    let mut out = vec![0.0f32; IOU_SAMPLES];
    let step = 2.0 / IOU_SAMPLES as f32;
    (0..f.width * f.height)
        .map(|i| {
            let (col, row) = (i % f.width, i / f.width);
            if f.is_empty_column(col, row) {
                return None;
            }
            f.decode_column_with(&table, col, row, &mut out);
            let inside: Vec<f32> =
                (0..IOU_SAMPLES).filter(|&d| out[d] >= ISO_LEVEL).map(|d| (d as f32 + 0.5) * step - 1.0).collect();
            (!inside.is_empty()).then(|| (inside.len() as f32 * step, inside.iter().sum::<f32>() / inside.len() as f32))
        })
        .collect()
}

/// One interval per column, thickness from `thickness`, depth from `depth` where it has the column (else the
/// thickness field's own), placed in depth by the convention.
fn one_interval(width: usize, height: usize, thickness: &[Column], depth: &[Column]) -> anyhow::Result<Fof> {
    let data = thickness
        .iter()
        .zip(depth)
        .map(|(t, d)| match t {
            Some((length, own)) => {
                let z = d.map_or(*own, |(_, z)| z);
                vec![(z - length / 2.0, z + length / 2.0)]
            }
            None => Vec::new(),
        })
        .collect();
    Ok(centre_fof(Fof::from_intervals(&Image { width, height, data }, N)?).0)
}

fn main() -> anyhow::Result<()> {
    let (cases, size) = cases::from_args("geometry_oracle")?;
    let base = cases::geometry_options(size)?;
    cases::print_ious(&["I", "B", "F", "BP", "G1", "I|Gd", "Gt|Id"], &cases, |c| {
        let inflation = c.geometry(&base, GeometryMode::Inflate)?;
        let (w, h) = (inflation.width, inflation.height);
        let (ci, cg) = (columns(&inflation), columns(&c.truth));
        Ok(vec![
            inflation,
            c.geometry(&base, GeometryMode::Body)?,
            c.geometry(&base, GeometryMode::FofNet)?,
            c.geometry(&base, GeometryMode::BodyPlaced)?,
            one_interval(w, h, &cg, &cg)?,
            one_interval(w, h, &ci, &cg)?,
            one_interval(w, h, &cg, &ci)?,
        ])
    })
}
