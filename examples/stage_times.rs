//! Per-stage wall times of the CPU pipeline on the embedded demo person, medians over repeated runs, with the
//! mesh size that drives the raster cost: `cargo run --release --example stage_times [-- DEPTH_SAMPLES]`.
//! A quick profiling aid next to the criterion benches (`cargo bench --bench pipeline`), which docs/performance.md
//! quotes.

use std::time::Duration;

use r2human::compose::Mode;
use r2human::geometry::Camera;
use r2human::io::environment::Environment;
use r2human::io::image_io;
use r2human::pipeline::warp::OcclusionFill;
use r2human::pipeline::{PrepareOptions, PreparedInput, ViewRenderer};

fn median(mut v: Vec<Duration>) -> f64 {
    v.sort();
    v[v.len() / 2].as_secs_f64() * 1e3
}

fn main() -> anyhow::Result<()> {
    let depth_samples = std::env::args().nth(1).map(|s| s.parse()).transpose()?.unwrap_or(512);
    let photo = image_io::load_image_bytes(include_bytes!("../assets/demo/person.png"), "demo person")?;
    let mask = photo.alpha.clone().ok_or_else(|| anyhow::anyhow!("the demo person has no alpha"))?;
    let opts = PrepareOptions { depth_samples, ..Default::default() };
    let mut stages: Vec<(&'static str, Vec<Duration>)> = Vec::new();
    let mut prepared = None;
    for _ in 0..7 {
        let p = PreparedInput::prepare(&photo.rgb, &mask, &opts)?;
        for (i, (name, d)) in p.timings.0.iter().enumerate() {
            if stages.len() <= i {
                stages.push((name, Vec::new()));
            }
            stages[i].1.push(*d);
        }
        prepared = Some(p);
    }
    let prepared = prepared.expect("ran at least once");
    println!(
        "mesh: {} vertices, {} triangles (depth samples {depth_samples})",
        prepared.mesh.positions.len(),
        prepared.mesh.triangles.len()
    );
    for (name, v) in stages {
        println!("per input  {name:<32} {:7.1} ms", median(v));
    }
    let env = Environment::default_embedded();
    let mut renderer = ViewRenderer::new(&prepared, OcclusionFill::MirroredFront, false);
    for (yaw, pitch) in [(0.0, 0.0), (135.0, 10.0), (180.0, 0.0), (30.0, 89.9)] {
        let cam = Camera::orbit(yaw, pitch, 512, 512);
        let mut per: Vec<(&'static str, Vec<Duration>)> = Vec::new();
        for _ in 0..15 {
            renderer.render_frame(&cam, Mode::Vr, &env)?;
            for (i, (name, d)) in renderer.timings.0.iter().enumerate() {
                if per.len() <= i {
                    per.push((name, Vec::new()));
                }
                per[i].1.push(*d);
            }
        }
        let line: Vec<String> = per.into_iter().map(|(n, v)| format!("{n} {:.1}", median(v))).collect();
        println!("view yaw {yaw:>5} pitch {pitch:>5}: {} ms", line.join(", "));
    }
    Ok(())
}
