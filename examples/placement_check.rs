//! Does a placement net carry over from the synthetic people it was trained on? Volumetric IoU against the ground
//! truth of the inflation prior (I), `body-placed` by the fixed rule (P) and `body-placed` by each placement net
//! given in `R2HUMAN_PLACEMENT_MODELS` (model folders holding a `placement.onnx`, separated by `:`; each column is
//! named by its folder): `R2HUMAN_PLACEMENT_MODELS=m1:m2 cargo run --release --example placement_check --
//! [SUBJECTS] [SEED] [SIZE]` (the subjects and framings of `r2human eval --subjects N`), or on scans: `... --
//! --scans [--size N] FILE...` (e.g. the characters `scripts/scan-check.sh OUT` writes to
//! OUT/files/characters/*/*.obj). Every geometry comes from [`r2human::pipeline::compute_geometry`] exactly as
//! `--geometry` draws it. Only volume: `r2human eval --models DIR` measures the rendered views.

#[path = "common/cases.rs"]
mod cases;

use r2human::neural::RuntimeOptions;
use r2human::pipeline::{load_placement_net, GeometryMode, PrepareOptions};

fn main() -> anyhow::Result<()> {
    let (cases, size) = cases::from_args("placement_check")?;
    let base = PrepareOptions { placement: None, ..cases::geometry_options(size)? };
    let folders: Vec<String> = std::env::var("R2HUMAN_PLACEMENT_MODELS")
        .unwrap_or_default()
        .split(':')
        .filter(|s| !s.is_empty())
        .map(str::to_owned)
        .collect();
    let mut variants = vec![("I".to_owned(), None), ("P".to_owned(), Some(base.clone()))];
    for folder in &folders {
        let dir = std::path::Path::new(folder);
        let net = load_placement_net(GeometryMode::BodyPlaced, Some(dir), cases::N, &RuntimeOptions::default())?;
        anyhow::ensure!(net.is_some(), "{folder} holds no {}", r2human::neural::PLACEMENT_FILE);
        let name = dir.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| folder.clone());
        variants.push((name, Some(PrepareOptions { placement: net, ..base.clone() })));
    }
    let names: Vec<&str> = variants.iter().map(|(n, _)| n.as_str()).collect();
    cases::print_ious(&names, &cases, |c| {
        variants
            .iter()
            .map(|(_, o)| match o {
                None => c.geometry(&base, GeometryMode::Inflate),
                Some(o) => c.geometry(o, GeometryMode::BodyPlaced),
            })
            .collect()
    })
}
