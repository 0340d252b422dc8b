//! Writes the person masks that each installed segmentation model gives on still photos, for looking at them:
//! `cargo run --example segment_stills -- OUT_DIR PHOTO...` writes `OUT_DIR/<photo>_<model>.png` (the photo over
//! grey outside the mask) and prints the mask's coverage and the pose landmarks it found.

use std::path::{Path, PathBuf};

use r2human::capture::onnx::MODEL_FILES;
use r2human::capture::segment::segment_photo;
use r2human::capture::SegmentMethod;

fn main() -> anyhow::Result<()> {
    let args: Vec<PathBuf> = std::env::args_os().skip(1).map(PathBuf::from).collect();
    let (out, photos) = args.split_first().ok_or_else(|| anyhow::anyhow!("usage: segment_stills OUT_DIR PHOTO..."))?;
    std::fs::create_dir_all(out)?;
    let models = Path::new(env!("CARGO_MANIFEST_DIR")).join(".tools/models");
    for photo in photos {
        for file in MODEL_FILES {
            let model = models.join(file);
            let method = SegmentMethod::Onnx { model: Some(model.clone()), input_size: 1024 };
            let t = std::time::Instant::now();
            let seg = segment_photo(photo, None, &method)?;
            let elapsed = t.elapsed();
            let coverage = seg.mask.data.iter().filter(|&&v| v >= 0.5).count() as f32 / seg.mask.data.len() as f32;
            let shown = r2human::buffer::Image::from_fn(seg.mask.width, seg.mask.height, |c, r| {
                let m = *seg.mask.get(c, r);
                *seg.photo.rgb.get(c, r) * m + glam::Vec3::new(0.1, 0.6, 0.1) * (1.0 - m)
            });
            let stem = photo.file_stem().unwrap_or_default().to_string_lossy();
            let name = out.join(format!("{stem}_{}.png", file.trim_end_matches(".onnx")));
            r2human::io::image_io::save_rgb_png(&name, &shown)?;
            println!("{}: {file}: coverage {:.1} %, {:.2} s", photo.display(), coverage * 100.0, elapsed.as_secs_f64());
        }
    }
    Ok(())
}
