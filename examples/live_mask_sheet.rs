//! Shows where the live segmentation (the pose model with the selfie segmenter beside it, as `view --video` reads a
//! frame) and the still segmentation (the shipped masks in `tests/data/photo_masks/`, made by ISNet) disagree on
//! the bundled photos: `cargo run --release --example live_mask_sheet -- OUT_DIR` writes `OUT_DIR/<photo>.png`
//! (the photo where both keep the person, red where only the live mask does, blue where only the still mask does,
//! dark grey where neither) and prints the IoU of the first (untracked) and second (tracked) read.

use std::path::{Path, PathBuf};
use std::time::Duration;

use glam::Vec3;
use r2human::buffer::Image;
use r2human::capture::onnx::OnnxSegmenter;
use r2human::capture::segment::Segmenter;
use r2human::capture::Frame;

fn main() -> anyhow::Result<()> {
    let out = std::env::args_os()
        .nth(1)
        .map(PathBuf::from)
        .ok_or_else(|| anyhow::anyhow!("usage: live_mask_sheet OUT_DIR"))?;
    std::fs::create_dir_all(&out)?;
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let pose = repo.join(".tools/models/pose_landmark_full.onnx");
    for photo in ["astronaut.png", "grace_hopper.jpg", "basketball_full_body.png", "cameraman_profile.png"] {
        let (rgb, _) = r2human::capture::load_image_frame(&repo.join("assets/photos").join(photo))?;
        let stem = photo.split('.').next().unwrap_or(photo);
        let still = image::open(repo.join(format!("tests/data/photo_masks/{stem}.png")))?.to_luma8();
        anyhow::ensure!(
            (still.width() as usize, still.height() as usize) == (rgb.width, rgb.height),
            "{photo}: the still mask is not the photo's size"
        );
        let mut seg = OnnxSegmenter::load(Some(&pose), 0)?;
        let frame = Frame { index: 0, timestamp: Duration::ZERO, rgb, alpha: None };
        let mut ious = Vec::new();
        let mut mask = None;
        for _ in 0..2 {
            let m = seg.segment(&frame)?;
            let (mut both, mut either) = (0usize, 0usize);
            for (m, s) in m.data.iter().zip(still.pixels()) {
                let (a, b) = (*m >= 0.5, s.0[0] >= 128);
                both += usize::from(a && b);
                either += usize::from(a || b);
            }
            ious.push(both as f32 / either.max(1) as f32);
            mask = Some(m);
        }
        let Some(mask) = mask else { continue };
        let sheet = Image::from_fn(mask.width, mask.height, |c, r| {
            let (a, b) = (*mask.get(c, r) >= 0.5, still.get_pixel(c as u32, r as u32).0[0] >= 128);
            let photo = *frame.rgb.get(c, r);
            match (a, b) {
                (true, true) => photo,
                (true, false) => Vec3::new(0.9, 0.1, 0.1) * 0.6 + photo * 0.4,
                (false, true) => Vec3::new(0.1, 0.2, 0.9) * 0.6 + photo * 0.4,
                (false, false) => photo * 0.15,
            }
        });
        r2human::io::image_io::save_rgb_png(&out.join(format!("{stem}.png")), &sheet)?;
        println!("{photo}: IoU with the still mask {:.3} (first read), {:.3} (tracked)", ious[0], ious[1]);
    }
    Ok(())
}
