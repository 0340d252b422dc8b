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
//! - `Gt|Id`: the ground truth's thickness at the inflation prior's depths (a perfect thickness);
//! - `I|Gd/8`, `I|Gd/32`: the inflation prior's thickness at the ground truth's depths averaged over tiles of 1/32
//!   and 1/8 of the image side (how much spatial detail a depth placement needs);
//! - `I|Bd`: the inflation prior's thickness at the body prior's depths (`body-placed` at weight 1);
//! - `I|kBd`: the same with the body's depths scaled about their mean by the least-squares slope that fits the
//!   ground truth best for this input (the best single trust in the body per input; the slope goes to stderr).
//!
//! `I|Gd` against `Gt|Id` says which of the two the inflation prior lacks more (docs/geometry.md, "Which geometry
//! wins where").
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

/// `depth`'s column depths averaged over `block` x `block` pixel tiles (over the tile's columns that have one):
/// how much spatial detail of the depth a placement needs.
fn block_depths(width: usize, height: usize, depth: &[Column], block: usize) -> Vec<Column> {
    let (bw, bh) = (width.div_ceil(block), height.div_ceil(block));
    let mut sums = vec![(0.0f32, 0u32); bw * bh];
    for (i, d) in depth.iter().enumerate() {
        if let Some((_, z)) = d {
            let b = (i / width / block) * bw + (i % width) / block;
            sums[b].0 += z;
            sums[b].1 += 1;
        }
    }
    (0..width * height)
        .map(|i| {
            let b = (i / width / block) * bw + (i % width) / block;
            depth[i].map(|(t, _)| (t, sums[b].0 / sums[b].1 as f32))
        })
        .collect()
}

/// The body's column depths scaled about their mean by the least-squares slope that fits the ground truth's best
/// (the depth of the best global trust in the body for this input), where both have the column.
fn fitted_slope(body: &[Column], truth: &[Column]) -> (f32, Vec<Column>) {
    let pairs: Vec<(f32, f32)> =
        body.iter().zip(truth).filter_map(|(b, t)| Some((b.as_ref()?.1, t.as_ref()?.1))).collect();
    let n = pairs.len().max(1) as f32;
    let (mb, mt) = (pairs.iter().map(|p| p.0).sum::<f32>() / n, pairs.iter().map(|p| p.1).sum::<f32>() / n);
    let cov: f32 = pairs.iter().map(|(b, t)| (b - mb) * (t - mt)).sum();
    let var: f32 = pairs.iter().map(|(b, _)| (b - mb) * (b - mb)).sum();
    let k = if var > 0.0 { cov / var } else { 0.0 };
    (k, body.iter().map(|b| b.map(|(t, z)| (t, mb + k * (z - mb)))).collect())
}

fn main() -> anyhow::Result<()> {
    let (cases, size) = cases::from_args("geometry_oracle")?;
    let base = cases::geometry_options(size)?;
    let names = ["I", "B", "F", "BP", "G1", "I|Gd", "Gt|Id", "I|Gd/8", "I|Gd/32", "I|Bd", "I|kBd"];
    cases::print_ious(&names, &cases, |c| {
        let inflation = c.geometry(&base, GeometryMode::Inflate)?;
        let body = c.geometry(&base, GeometryMode::Body)?;
        let (w, h) = (inflation.width, inflation.height);
        let (ci, cg, cb) = (columns(&inflation), columns(&c.truth), columns(&body));
        let (k, scaled) = fitted_slope(&cb, &cg);
        eprintln!("{}: best slope of the body's depths {k:.2}", c.label);
        let (b8, b32) = (block_depths(w, h, &cg, w / 32), block_depths(w, h, &cg, w / 8));
        Ok(vec![
            inflation,
            body,
            c.geometry(&base, GeometryMode::FofNet)?,
            c.geometry(&base, GeometryMode::BodyPlaced)?,
            one_interval(w, h, &cg, &cg)?,
            one_interval(w, h, &ci, &cg)?,
            one_interval(w, h, &cg, &ci)?,
            one_interval(w, h, &ci, &b8)?,
            one_interval(w, h, &ci, &b32)?,
            one_interval(w, h, &ci, &cb)?,
            one_interval(w, h, &ci, &scaled)?,
        ])
    })
}
