//! Does the silhouette-inflation prior cover the person on every mask? A sweep over synthetic subjects (clothed and
//! unclothed, every framing) at several source sizes:
//! `cargo run --release --example inflate_sweep -- [SUBJECTS] [SEED] [SIZES]` (defaults 60, 0, `128,256,512`).
//!
//! Per mask it runs [`inflate_to_fof`] and measures [`mask_coverage`] (the fraction of the mask's interior whose
//! FOF column reaches occupancy 0.5 anywhere). Prints one line per mask below 0.99 and a summary per size: masks
//! tried, failures of the prior, the minimum and the 1st percentile of the coverage. A bug of this kind (an outline
//! edge walked twice flipped the inside/outside labels of the triangulation) gave coverage 0 on an ordinary
//! full-body mask; the sweep is how such a bug is found before a user meets it.

use anyhow::Context;
use r2human::eval::dataset::subject_seed;
use r2human::eval::ground_truth::render_ground_truth;
use r2human::geometry::camera::Camera;
use r2human::geometry::inflate::{inflate_to_fof, mask_coverage, InflateParams};
use r2human::synth::framing::{self, Framing};
use r2human::synth::{self, SubjectParams, SynthAssets};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let subjects: usize = args.first().map(|s| s.parse()).transpose().context("SUBJECTS")?.unwrap_or(60);
    let seed: u64 = args.get(1).map(|s| s.parse()).transpose().context("SEED")?.unwrap_or(0);
    let sizes: Vec<usize> = match args.get(2) {
        Some(s) => s.split(',').map(|v| v.parse().context("SIZES")).collect::<anyhow::Result<_>>()?,
        None => vec![128, 256, 512],
    };
    let assets = SynthAssets::shared()?;
    let mut results: Vec<Vec<f32>> = vec![Vec::new(); sizes.len()];
    let mut errors = 0usize;
    for index in 0..subjects {
        let s = subject_seed(seed, index);
        for clothed in [true, false] {
            let mut params = SubjectParams::sample(s);
            if !clothed {
                params.outfit = synth::Outfit::none(params.appearance.top_fabric);
            }
            let subject = synth::generate(assets, &params, 64)?;
            for framing in Framing::ALL {
                let subject = framing::crop(&subject, framing, &assets.rig)?;
                for (k, &size) in sizes.iter().enumerate() {
                    let gt = render_ground_truth(&subject.mesh, &Camera::source(size));
                    let mask = gt.mask_image();
                    let label = format!(
                        "seed {s} {} {} {size}px",
                        if clothed { "clothed" } else { "unclothed" },
                        subject.crop.framing.label()
                    );
                    match inflate_to_fof(
                        &mask,
                        32,
                        &InflateParams::default(),
                        Some(r2human::body::prior::effective_frame(&mask, None)),
                    ) {
                        Ok(fof) => {
                            let c = mask_coverage(&fof, &mask, 2).unwrap_or(1.0);
                            if c < 0.99 {
                                println!("{label}: coverage {c:.3}");
                            }
                            results[k].push(c);
                        }
                        Err(e) => {
                            errors += 1;
                            println!("{label}: error {e}");
                        }
                    }
                }
            }
        }
    }
    println!("| size | masks | coverage < 0.99 | min | 1st percentile |");
    println!("|---:|---:|---:|---:|---:|");
    for (k, size) in sizes.iter().enumerate() {
        let mut c = results[k].clone();
        c.sort_by(f32::total_cmp);
        let fails = c.iter().filter(|&&v| v < 0.99).count();
        let p1 = c.get(c.len() / 100).copied().unwrap_or(f32::NAN);
        println!("| {size} | {} | {fails} | {:.3} | {:.3} |", c.len(), c.first().copied().unwrap_or(f32::NAN), p1);
    }
    println!("inflation errors: {errors}");
    Ok(())
}
