//! Writes the person mask r2human finds in a photo (`--segment auto`: the photo's alpha when it has a real one,
//! else the segmentation model) as an 8-bit grey PNG, and prints where it came from:
//! `cargo run --example person_mask -- PHOTO OUT.png`. The masks of the shipped photos in
//! `tests/data/photo_masks/` were made with it.

use std::path::PathBuf;

use r2human::capture::segment::segment_photo;
use r2human::capture::SegmentMethod;

fn main() -> anyhow::Result<()> {
    let args: Vec<PathBuf> = std::env::args_os().skip(1).map(PathBuf::from).collect();
    let [photo, out] = args.as_slice() else { anyhow::bail!("usage: person_mask PHOTO OUT.png") };
    let person = segment_photo(photo, None, &SegmentMethod::Auto)?;
    let m = &person.mask;
    let grey = image::GrayImage::from_fn(m.width as u32, m.height as u32, |x, y| {
        image::Luma([(m.get(x as usize, y as usize).clamp(0.0, 1.0) * 255.0).round() as u8])
    });
    r2human::io::image_io::write_encoded(out, image::DynamicImage::ImageLuma8(grey))?;
    println!("{}: {}x{} mask from {}", out.display(), m.width, m.height, person.origin);
    Ok(())
}
