//! Mask IoU of two renders with alpha (`--mode ar` PNGs): each render's alpha (≥ 0.5) is cut to its own mask's box
//! and scaled to a common square (so a person drawn at another scale or place still compares by shape), then
//! `IoU = |A ∩ B| / |A ∪ B|` is printed. `cargo run --release --example render_mask_iou -- A.png B.png`
//! (scripts/frames-vs-stills.sh uses it to compare the frame path's render with the still path's).

use std::path::PathBuf;

/// The common square's side, in samples.
const SIDE: usize = 256;

fn boxed_mask(path: &PathBuf) -> anyhow::Result<Vec<bool>> {
    let img = image::open(path)?.to_rgba8();
    let (w, h) = (img.width() as usize, img.height() as usize);
    let inside = |c: usize, r: usize| img.get_pixel(c as u32, r as u32).0[3] >= 128;
    let (mut c0, mut c1, mut r0, mut r1) = (usize::MAX, 0, usize::MAX, 0);
    for r in 0..h {
        for c in 0..w {
            if inside(c, r) {
                (c0, c1, r0, r1) = (c0.min(c), c1.max(c + 1), r0.min(r), r1.max(r + 1));
            }
        }
    }
    anyhow::ensure!(c0 < c1 && r0 < r1, "{}: no pixel with alpha ≥ 0.5", path.display());
    // Nearest sample of the box at each square cell's centre.
    Ok((0..SIDE * SIDE)
        .map(|k| {
            let (i, j) = (k % SIDE, k / SIDE);
            let c = c0 + (((i as f32 + 0.5) / SIDE as f32) * (c1 - c0) as f32) as usize;
            let r = r0 + (((j as f32 + 0.5) / SIDE as f32) * (r1 - r0) as f32) as usize;
            inside(c.min(c1 - 1), r.min(r1 - 1))
        })
        .collect())
}

fn main() -> anyhow::Result<()> {
    let args: Vec<PathBuf> = std::env::args_os().skip(1).map(PathBuf::from).collect();
    let [a, b] = args.as_slice() else { anyhow::bail!("usage: render_mask_iou A.png B.png") };
    let (ma, mb) = (boxed_mask(a)?, boxed_mask(b)?);
    let both = ma.iter().zip(&mb).filter(|(x, y)| **x && **y).count();
    let either = ma.iter().zip(&mb).filter(|(x, y)| **x || **y).count();
    println!("{:.3}", both as f64 / either.max(1) as f64);
    Ok(())
}
