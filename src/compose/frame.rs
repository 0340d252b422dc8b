//! [`RenderedFrame`]: the output of a view — the VR composite or the AR layer — as every renderer returns it and
//! every writer takes it (its previews).

use std::path::Path;

use glam::{Vec3, Vec4};

use crate::buffer::{Image, RgbImage, RgbaImage};
use crate::io::image_io::{self, IoError};

/// Side in pixels of the squares of the checkerboard behind an AR preview.
const CHECK_SIZE: usize = 16;
/// The two greys of that checkerboard (linear).
const CHECK_GREYS: [f32; 2] = [0.35, 0.6];

/// One rendered output frame: a VR composite (opaque linear RGB) or an AR layer (premultiplied linear RGBA).
#[derive(Clone, Debug)]
pub enum RenderedFrame {
    /// Person over the panorama.
    Vr(RgbImage),
    /// Person alone, premultiplied alpha.
    Ar(RgbaImage),
}

impl RenderedFrame {
    /// Width in pixels.
    pub fn width(&self) -> usize {
        match self {
            RenderedFrame::Vr(i) => i.width,
            RenderedFrame::Ar(i) => i.width,
        }
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        match self {
            RenderedFrame::Vr(i) => i.height,
            RenderedFrame::Ar(i) => i.height,
        }
    }

    /// Saves the frame as PNG (AR keeps its alpha, stored straight as PNG requires), atomically.
    pub fn save_png(&self, path: &Path) -> Result<(), IoError> {
        match self {
            RenderedFrame::Vr(img) => image_io::save_rgb_png(path, img),
            RenderedFrame::Ar(img) => image_io::save_rgba_png(path, img),
        }
    }

    /// An opaque preview: VR as is, AR over a grey checkerboard (what "transparent" looks like in viewers).
    pub fn preview(&self) -> RgbImage {
        match self {
            RenderedFrame::Vr(img) => img.clone(),
            RenderedFrame::Ar(img) => Image::from_fn(img.width, img.height, |c, r| {
                let p: Vec4 = *img.get(c, r);
                let check = CHECK_GREYS[((c / CHECK_SIZE) + (r / CHECK_SIZE)) % 2];
                p.truncate() + Vec3::splat(check) * (1.0 - p.w)
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ar_preview_is_the_layer_over_a_checkerboard() {
        // Transparent left half, opaque red right half, half-covered blue row at the bottom.
        let layer = Image::from_fn(48, 32, |c, r| {
            if r == 31 {
                Vec4::new(0.0, 0.0, 0.25, 0.5)
            } else if c >= 24 {
                Vec4::new(1.0, 0.0, 0.0, 1.0)
            } else {
                Vec4::ZERO
            }
        });
        let preview = RenderedFrame::Ar(layer).preview();
        assert_eq!((preview.width, preview.height), (48, 32));
        assert_eq!(*preview.get(0, 0), Vec3::splat(0.35), "square (0, 0) is the dark grey");
        assert_eq!(*preview.get(16, 0), Vec3::splat(0.6), "square (1, 0) is the light grey");
        assert_eq!(*preview.get(16, 16), Vec3::splat(0.35), "square (1, 1) is the dark grey");
        assert_eq!(*preview.get(30, 5), Vec3::new(1.0, 0.0, 0.0), "opaque pixels are the layer");
        // Premultiplied: colour + grey * (1 - alpha); (0, 31) lies in square (0, 1), the light grey.
        assert_eq!(*preview.get(0, 31), Vec3::new(0.3, 0.3, 0.25 + 0.3));
        let vr = Image::from_fn(4, 3, |c, r| Vec3::new(c as f32, r as f32, 0.5));
        assert_eq!(RenderedFrame::Vr(vr.clone()).preview().data, vr.data, "a VR frame is its own preview");
        assert_eq!((RenderedFrame::Vr(vr).width(), RenderedFrame::Ar(Image::new(5, 7, Vec4::ZERO)).height()), (4, 7));
    }

    #[test]
    fn png_round_trip_keeps_the_size_and_alpha() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.png");
        let layer = Image::from_fn(8, 6, |c, _| if c < 4 { Vec4::new(0.5, 0.5, 0.5, 1.0) } else { Vec4::ZERO });
        RenderedFrame::Ar(layer).save_png(&path).unwrap();
        let back = image::open(&path).unwrap().into_rgba8();
        assert_eq!(back.dimensions(), (8, 6));
        assert_eq!(back.get_pixel(0, 0).0[3], 255);
        assert_eq!(back.get_pixel(7, 0).0[3], 0);
    }
}
