//! How steady is a rendered video from one viewpoint? Reads the frames `r2human render --video DIR --yaw Y --out OUT`
//! wrote (OUT/frame_*.png, premultiplied RGBA) and prints the mean and the minimum mask IoU of consecutive frames
//! (alpha above one half): `cargo run --release --example video_stability -- OUT [OUT2 ...]`.
//!
//! README "Live frames with a body geometry" measures with it, each clip rendered at `--yaw 90` with `--geometry
//! inflate` and `--geometry body-placed`:
//! - a still person: one photo copied 20 times into a folder;
//! - a barely moving one: frames shifted by up to 1 px.
//!
//! A geometry that follows the photo steadily scores near the inflation prior's 0.996-0.998.

use anyhow::Context;

/// The mask (alpha above one half) of one RGBA PNG.
fn mask(path: &std::path::Path) -> anyhow::Result<(u32, u32, Vec<bool>)> {
    let image = image::open(path).with_context(|| format!("reading {}", path.display()))?.to_rgba8();
    Ok((image.width(), image.height(), image.pixels().map(|p| p[3] > 127).collect()))
}

fn main() -> anyhow::Result<()> {
    let dirs: Vec<String> = std::env::args().skip(1).collect();
    anyhow::ensure!(!dirs.is_empty(), "usage: video_stability OUT [OUT2 ...] (folders of frame_*.png)");
    for dir in dirs {
        let mut frames: Vec<_> = std::fs::read_dir(&dir)
            .with_context(|| format!("reading {dir}"))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.file_name().is_some_and(|n| n.to_string_lossy().starts_with("frame_")))
            .filter(|p| p.extension().is_some_and(|e| e == "png"))
            .collect();
        frames.sort();
        anyhow::ensure!(frames.len() >= 2, "{dir}: fewer than two frame_*.png");
        let masks = frames.iter().map(|p| mask(p)).collect::<anyhow::Result<Vec<_>>>()?;
        let mut ious = Vec::new();
        for pair in masks.windows(2) {
            let ((w0, h0, a), (w1, h1, b)) = (&pair[0], &pair[1]);
            anyhow::ensure!((w0, h0) == (w1, h1), "{dir}: frames of different sizes");
            let inter = a.iter().zip(b).filter(|(x, y)| **x && **y).count();
            let union = a.iter().zip(b).filter(|(x, y)| **x || **y).count();
            ious.push(inter as f64 / union.max(1) as f64);
        }
        let mean = ious.iter().sum::<f64>() / ious.len() as f64;
        let min = ious.iter().copied().fold(f64::INFINITY, f64::min);
        println!("{dir}: {} frames, consecutive-frame mask IoU mean {mean:.4}, min {min:.4}", frames.len());
    }
    Ok(())
}
