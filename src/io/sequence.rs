//! Writing rendered view sequences as an animated GIF and a contact sheet, atomically. The writers take opaque
//! linear RGB images (e.g. `compose::RenderedFrame::preview`).

use std::path::Path;

use glam::Vec3;

use crate::buffer::{Image, RgbImage};
use crate::io::image_io::{self, IoError};

/// Writes an animated GIF of the frames (looping, `delay_ms` per frame), atomically.
pub fn write_gif(path: &Path, frames: &[RgbImage], delay_ms: u32) -> Result<(), IoError> {
    let images: Vec<image::RgbaImage> =
        frames.iter().map(|f| image::DynamicImage::ImageRgb8(image_io::to_srgb8(f)).into_rgba8()).collect();
    image_io::write_atomic(path, |file| {
        let mut encoder = image::codecs::gif::GifEncoder::new_with_speed(std::io::BufWriter::new(file), 10);
        encoder.set_repeat(image::codecs::gif::Repeat::Infinite).map_err(std::io::Error::other)?;
        for img in images {
            let frame = image::Frame::from_parts(img, 0, 0, image::Delay::from_numer_denom_ms(delay_ms, 1));
            encoder.encode_frame(frame).map_err(std::io::Error::other)?;
        }
        Ok(())
    })
}

/// Lays the frames out in a grid (`columns` wide, each scaled to `thumb` pixels high) and writes a PNG,
/// atomically.
pub fn write_contact_sheet(path: &Path, frames: &[RgbImage], columns: usize, thumb: usize) -> Result<(), IoError> {
    let columns = columns.max(1);
    let rows = frames.len().div_ceil(columns).max(1);
    let (fw, fh) = frames.first().map(|f| (f.width, f.height)).unwrap_or((1, 1));
    let tw = (thumb * fw / fh.max(1)).max(1);
    let gap = 4;
    let mut sheet = Image::new(columns * (tw + gap) + gap, rows * (thumb + gap) + gap, Vec3::splat(0.02));
    for (i, preview) in frames.iter().enumerate() {
        let (x0, y0) = (gap + (i % columns) * (tw + gap), gap + (i / columns) * (thumb + gap));
        for r in 0..thumb {
            for c in 0..tw {
                // Box filter over the source footprint of this thumbnail pixel.
                let (sx0, sx1) = (c * fw / tw, ((c + 1) * fw / tw).max(c * fw / tw + 1));
                let (sy0, sy1) = (r * fh / thumb, ((r + 1) * fh / thumb).max(r * fh / thumb + 1));
                let mut acc = Vec3::ZERO;
                for sy in sy0..sy1.min(fh) {
                    for sx in sx0..sx1.min(fw) {
                        acc += *preview.get(sx, sy);
                    }
                }
                let n = ((sy1.min(fh) - sy0) * (sx1.min(fw) - sx0)).max(1) as f32;
                sheet.set(x0 + c, y0 + r, acc / n);
            }
        }
    }
    image_io::save_rgb_png(path, &sheet)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gif_and_sheet_are_readable() {
        let dir = tempfile::tempdir().unwrap();
        let frames: Vec<RgbImage> = (0..5)
            .map(|i| Image::from_fn(32, 32, |c, _| if c < 6 * i { Vec3::new(0.5, 0.1, 0.1) } else { Vec3::splat(0.3) }))
            .collect();
        let gif = dir.path().join("o.gif");
        write_gif(&gif, &frames, 80).unwrap();
        let decoded = image::open(&gif).unwrap();
        assert_eq!(decoded.width(), 32);
        let sheet = dir.path().join("s.png");
        write_contact_sheet(&sheet, &frames, 3, 16).unwrap();
        let s = image::open(&sheet).unwrap();
        assert_eq!((s.width(), s.height()), (3 * 20 + 4, 2 * 20 + 4));
    }
}
