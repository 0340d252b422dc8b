//! How steady is a rendered video from one viewpoint? Reads the frames `r2human render --video DIR --yaw Y --out OUT`
//! wrote (OUT/frame_*.png, premultiplied RGBA) and prints the mean and the minimum mask IoU of consecutive frames
//! (alpha above one half): `cargo run --release --example video_stability -- OUT [OUT2 ...]`.
//!
//! docs/live.md ("Stability") measures with it, each clip rendered at `--yaw 90` with `--geometry
//! inflate` and `--geometry body-placed`:
//! - a still person: one photo copied 20 times into a folder;
//! - a barely moving one: frames shifted by up to 1 px;
//! - a moving one: the photo moved right by 3 px a frame for 12 of 20 frames (its frames can also be rendered
//!   one by one, each as a clip of its own, as the reference for lag).
//!
//! A geometry that follows the photo steadily scores near the inflation prior's 0.996-0.998.
//!
//! `-- --make-clips PHOTO DIR` writes the three clips from one photo: `DIR/still` (the photo 20 times),
//! `DIR/shifted` (30 frames, each the photo moved by -1, 0 or 1 px in x and y, a fixed pseudo-random sequence,
//! black where the photo moved away) and `DIR/moving` (20 frames: 4 still, 12 each 3 px further right, 4 still;
//! the columns the photo moved away from repeat its first column), so docs/live.md's figures can be made again.

use anyhow::Context;

/// Frames of the still clip and of the shifted clip.
const STILL_FRAMES: usize = 20;
const SHIFTED_FRAMES: usize = 30;
/// The moving clip: its frames, the frames during which the photo moves, and by how much per frame (pixels).
const MOVING_FRAMES: usize = 20;
const MOVING_SPAN: std::ops::Range<usize> = 4..16;
const MOVING_STEP: u32 = 3;

/// Writes the still, the shifted and the moving clip of `photo` into `dir/still`, `dir/shifted` and `dir/moving`.
fn make_clips(photo: &str, dir: &str) -> anyhow::Result<()> {
    let image = image::open(photo).with_context(|| format!("reading {photo}"))?.to_rgb8();
    let (w, h) = image.dimensions();
    let root = std::path::Path::new(dir);
    let (still, shifted, moving) = (root.join("still"), root.join("shifted"), root.join("moving"));
    for d in [&still, &shifted, &moving] {
        std::fs::create_dir_all(d).with_context(|| format!("creating {}", d.display()))?;
    }
    for k in 0..STILL_FRAMES {
        let path = still.join(format!("frame_{k:03}.png"));
        image.save(&path).with_context(|| format!("writing {}", path.display()))?;
    }
    // A 64-bit linear congruential generator (Knuth's MMIX constants): the same shifts on every machine.
    let mut state: u64 = 5;
    let mut next = || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (state >> 33) % 3
    };
    for k in 0..SHIFTED_FRAMES {
        let (dx, dy) = (next() as i64 - 1, next() as i64 - 1);
        let frame = image::RgbImage::from_fn(w, h, |x, y| {
            let (sx, sy) = (x as i64 - dx, y as i64 - dy);
            if sx < 0 || sy < 0 || sx >= w as i64 || sy >= h as i64 {
                image::Rgb([0, 0, 0])
            } else {
                *image.get_pixel(sx as u32, sy as u32)
            }
        });
        let path = shifted.join(format!("frame_{k:03}.png"));
        frame.save(&path).with_context(|| format!("writing {}", path.display()))?;
    }
    let mut offset = 0u32;
    for k in 0..MOVING_FRAMES {
        if MOVING_SPAN.contains(&k) {
            offset += MOVING_STEP;
        }
        let frame = image::RgbImage::from_fn(w, h, |x, y| *image.get_pixel(x.saturating_sub(offset), y));
        let path = moving.join(format!("frame_{k:03}.png"));
        frame.save(&path).with_context(|| format!("writing {}", path.display()))?;
    }
    println!("wrote {}, {} and {}", still.display(), shifted.display(), moving.display());
    Ok(())
}

/// The mask (alpha above one half) of one RGBA PNG.
fn mask(path: &std::path::Path) -> anyhow::Result<(u32, u32, Vec<bool>)> {
    let image = image::open(path).with_context(|| format!("reading {}", path.display()))?.to_rgba8();
    Ok((image.width(), image.height(), image.pixels().map(|p| p[3] > 127).collect()))
}

fn main() -> anyhow::Result<()> {
    let dirs: Vec<String> = std::env::args().skip(1).collect();
    if dirs.first().is_some_and(|a| a == "--make-clips") {
        anyhow::ensure!(dirs.len() == 3, "usage: video_stability --make-clips PHOTO DIR");
        return make_clips(&dirs[1], &dirs[2]);
    }
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
