//! A synthetic person photo with its mask for the XR tests and bench: a front-facing figure (head, torso, arms,
//! legs) drawn from ellipses and rectangles, so the XR path can be exercised with the real per-view pipeline
//! without depending on any photo asset.

use glam::Vec3;
use r2human::buffer::{GrayImage, RgbImage};

/// A `size x size` photo (linear RGB) and mask of a standing figure centred in the frame.
pub fn figure(size: usize) -> (RgbImage, GrayImage) {
    let s = size as f32;
    let inside = |x: f32, y: f32| -> Option<Vec3> {
        // Coordinates in [0, 1], y down.
        let ellipse = |cx: f32, cy: f32, rx: f32, ry: f32| ((x - cx) / rx).powi(2) + ((y - cy) / ry).powi(2) <= 1.0;
        let rect = |x0: f32, y0: f32, x1: f32, y1: f32| x >= x0 && x <= x1 && y >= y0 && y <= y1;
        let skin = Vec3::new(0.8, 0.55, 0.4);
        if ellipse(0.5, 0.14, 0.065, 0.08) {
            Some(skin)
        } else if rect(0.47, 0.2, 0.53, 0.25) {
            Some(skin * 0.9)
        } else if ellipse(0.5, 0.38, 0.16, 0.16) || rect(0.36, 0.26, 0.64, 0.55) {
            // Shirt with horizontal stripes so the texture has structure.
            Some(if ((y * 40.0) as i32) % 2 == 0 { Vec3::new(0.7, 0.1, 0.1) } else { Vec3::new(0.9, 0.8, 0.2) })
        } else if rect(0.27, 0.27, 0.35, 0.56) || rect(0.65, 0.27, 0.73, 0.56) {
            Some(Vec3::new(0.7, 0.1, 0.1))
        } else if rect(0.38, 0.55, 0.49, 0.95) || rect(0.51, 0.55, 0.62, 0.95) {
            Some(Vec3::new(0.1, 0.15, 0.5))
        } else {
            None
        }
    };
    let rgb = RgbImage::from_fn(size, size, |c, r| {
        inside((c as f32 + 0.5) / s, (r as f32 + 0.5) / s).unwrap_or(Vec3::new(0.5, 0.6, 0.5))
    });
    let mask = GrayImage::from_fn(size, size, |c, r| {
        if inside((c as f32 + 0.5) / s, (r as f32 + 0.5) / s).is_some() {
            1.0
        } else {
            0.0
        }
    });
    (rgb, mask)
}
