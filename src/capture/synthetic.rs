//! A procedural walking figure over a still background, with exact ground-truth masks: the camera stand-in for
//! tests and benchmarks of sources, segmentation and the live loop (no camera on CI machines).
//!
//! The figure is a union of capsules (head, torso, arms, legs) with anti-aliased coverage; it walks across the
//! frame and swings its limbs with the walk phase. Colours are linear RGB. The background is a smooth wall with a
//! few darker panels (static, so a clean plate of it is exact up to the added noise).

use glam::{Vec2, Vec3};

use super::{Frame, FrameSource, SourceEvent};
use crate::buffer::{GrayImage, Image, RgbImage};

/// Parameters of the synthetic walker sequence.
#[derive(Clone, Debug, PartialEq)]
pub struct WalkerParams {
    /// Frame width in pixels.
    pub width: usize,
    /// Frame height in pixels.
    pub height: usize,
    /// Number of frames.
    pub frames: usize,
    /// Frame rate for the timestamps.
    pub fps: f32,
    /// Standard deviation of the per-pixel sensor noise (linear units), deterministic per frame.
    pub noise: f32,
}

impl Default for WalkerParams {
    fn default() -> Self {
        Self { width: 192, height: 144, frames: 12, fps: 30.0, noise: 0.01 }
    }
}

fn capsule_distance(p: Vec2, a: Vec2, b: Vec2, r: f32) -> f32 {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_squared().max(1e-12)).clamp(0.0, 1.0);
    (p - (a + ab * t)).length() - r
}

/// The background wall (linear RGB) at `width x height`.
pub fn background(width: usize, height: usize) -> RgbImage {
    Image::from_fn(width, height, |c, r| {
        let (u, v) = (c as f32 / width as f32, r as f32 / height as f32);
        let mut col = Vec3::new(0.45, 0.5, 0.55) * (0.8 + 0.2 * u) + Vec3::new(0.05, 0.03, 0.0) * v;
        // Panels: darker rectangles, a floor strip.
        if (0.08..0.22).contains(&u) && (0.15..0.55).contains(&v) {
            col = Vec3::new(0.25, 0.2, 0.15);
        }
        if (0.7..0.9).contains(&u) && (0.1..0.35).contains(&v) {
            col = Vec3::new(0.6, 0.55, 0.35);
        }
        if v > 0.88 {
            col = Vec3::new(0.3, 0.28, 0.26);
        }
        col
    })
}

/// The walker at frame `i` of `params`: straight linear RGB of the figure (black outside) and its coverage in
/// `[0, 1]` (the ground-truth alpha).
pub fn walker(params: &WalkerParams, i: usize) -> (RgbImage, GrayImage) {
    let (w, h) = (params.width as f32, params.height as f32);
    let n = params.frames.max(1) as f32;
    let t = i as f32 / n;
    // Units: fraction of the frame height; the figure is 0.8 of the height tall.
    let s = h;
    let cx = w * (0.3 + 0.4 * t);
    let phase = std::f32::consts::TAU * 2.0 * t;
    let swing = 0.35 * phase.sin();
    let hip = Vec2::new(cx, 0.55 * s);
    let shoulder = Vec2::new(cx, 0.28 * s);
    let leg = 0.32 * s;
    let arm = 0.24 * s;
    let limb = |origin: Vec2, len: f32, angle: f32| origin + Vec2::new(angle.sin(), angle.cos()) * len;
    let skin = Vec3::new(0.8, 0.55, 0.4);
    let shirt = Vec3::new(0.7, 0.08, 0.06);
    let trousers = Vec3::new(0.05, 0.08, 0.3);
    let parts: [(Vec2, Vec2, f32, Vec3); 7] = [
        (Vec2::new(cx, 0.17 * s), Vec2::new(cx, 0.17 * s), 0.065 * s, skin),
        (shoulder, hip, 0.075 * s, shirt),
        (
            hip + Vec2::new(-0.035 * s, 0.0),
            limb(hip + Vec2::new(-0.035 * s, 0.0), leg, swing - 0.08),
            0.04 * s,
            trousers,
        ),
        (
            hip + Vec2::new(0.035 * s, 0.0),
            limb(hip + Vec2::new(0.035 * s, 0.0), leg, -swing + 0.08),
            0.04 * s,
            trousers,
        ),
        (
            shoulder + Vec2::new(-0.07 * s, 0.02 * s),
            limb(shoulder + Vec2::new(-0.07 * s, 0.02 * s), arm, -0.8 * swing - 0.3),
            0.028 * s,
            skin,
        ),
        (
            shoulder + Vec2::new(0.07 * s, 0.02 * s),
            limb(shoulder + Vec2::new(0.07 * s, 0.02 * s), arm, 0.8 * swing + 0.3),
            0.028 * s,
            skin,
        ),
        (Vec2::new(cx, 0.22 * s), Vec2::new(cx, 0.27 * s), 0.03 * s, skin),
    ];
    let mut rgb = Image::new(params.width, params.height, Vec3::ZERO);
    let mut cov = Image::new(params.width, params.height, 0.0f32);
    for r in 0..params.height {
        for c in 0..params.width {
            let p = Vec2::new(c as f32 + 0.5, r as f32 + 0.5);
            // Nearest part gives the colour; coverage from the union's signed distance (1 px ramp).
            let (d, col) = parts
                .iter()
                .map(|&(a, b, rad, col)| (capsule_distance(p, a, b, rad), col))
                .fold((f32::INFINITY, Vec3::ZERO), |acc, x| if x.0 < acc.0 { x } else { acc });
            let a = (0.5 - d).clamp(0.0, 1.0);
            if a > 0.0 {
                // Simple shading: brighter towards the figure's left side.
                let shade = 0.85 + 0.15 * ((cx - p.x) / (0.1 * s)).clamp(-1.0, 1.0);
                rgb.set(c, r, col * shade);
                cov.set(c, r, a);
            }
        }
    }
    (rgb, cov)
}

/// Deterministic pseudo-random noise in `[-1, 1]` for pixel `k` of frame `i` (a hash, no RNG state).
fn noise(i: usize, k: usize) -> f32 {
    let mut x = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (k as u64).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^= x >> 31;
    x = x.wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^= x >> 29;
    (x >> 40) as f32 / (1u64 << 23) as f32 - 1.0
}

/// Frame `i` composited over the background with sensor noise: `(rgb, ground-truth mask)`.
pub fn composite(params: &WalkerParams, i: usize) -> (RgbImage, GrayImage) {
    let bg = background(params.width, params.height);
    let (fg, cov) = walker(params, i);
    let data = bg
        .data
        .iter()
        .zip(&fg.data)
        .zip(&cov.data)
        .enumerate()
        .map(|(k, ((&b, &f), &a))| {
            (f * a + b * (1.0 - a) + Vec3::splat(params.noise * noise(i, k))).clamp(Vec3::ZERO, Vec3::ONE)
        })
        .collect();
    (Image { width: params.width, height: params.height, data }, cov)
}

/// The background alone with frame-`i` noise (an empty-scene frame for the clean plate).
pub fn empty_scene(params: &WalkerParams, i: usize) -> RgbImage {
    let mut bg = background(params.width, params.height);
    for (k, v) in bg.data.iter_mut().enumerate() {
        *v = (*v + Vec3::splat(params.noise * noise(i + 1_000_000, k))).clamp(Vec3::ZERO, Vec3::ONE);
    }
    bg
}

/// The walker as a frame source: the first `plate_frames` frames show the empty scene (for clean-plate
/// segmentation), then the walker over the background; `with_alpha` adds the ground-truth alpha to each frame.
pub struct WalkerSource {
    params: WalkerParams,
    plate_frames: usize,
    with_alpha: bool,
    next: usize,
}

impl WalkerSource {
    /// A source of `plate_frames` empty frames followed by `params.frames` walker frames.
    pub fn new(params: WalkerParams, plate_frames: usize, with_alpha: bool) -> Self {
        Self { params, plate_frames, with_alpha, next: 0 }
    }
}

impl FrameSource for WalkerSource {
    fn describe(&self) -> String {
        format!("synthetic walker {}x{} ({} frames)", self.params.width, self.params.height, self.params.frames)
    }

    fn next_frame(&mut self) -> Result<SourceEvent, super::CaptureError> {
        let k = self.next;
        if k >= self.plate_frames + self.params.frames {
            return Ok(SourceEvent::End);
        }
        self.next += 1;
        let (rgb, alpha) = if k < self.plate_frames {
            let bg = empty_scene(&self.params, k);
            let a = Image::new(bg.width, bg.height, 0.0);
            (bg, a)
        } else {
            composite(&self.params, k - self.plate_frames)
        };
        let timestamp = std::time::Duration::from_secs_f64(k as f64 / self.params.fps.max(0.1) as f64);
        Ok(SourceEvent::Frame(Frame { index: k as u64, timestamp, rgb, alpha: self.with_alpha.then_some(alpha) }))
    }

    fn nominal_fps(&self) -> Option<f32> {
        Some(self.params.fps)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn walker_is_bounded_and_moves() {
        let p = WalkerParams::default();
        let (_, a0) = walker(&p, 0);
        let (_, a1) = walker(&p, p.frames - 1);
        let area = |a: &GrayImage| a.data.iter().sum::<f32>() / a.data.len() as f32;
        // A figure 0.8 of the frame height covers roughly 5-15% of the frame.
        assert!((0.04..0.2).contains(&area(&a0)), "{}", area(&a0));
        let cx = |a: &GrayImage| {
            let (mut s, mut m) = (0.0, 0.0);
            for (k, v) in a.data.iter().enumerate() {
                s += (k % a.width) as f32 * v;
                m += v;
            }
            s / m
        };
        assert!(cx(&a1) > cx(&a0) + 0.2 * p.width as f32);
        let (rgb, _) = composite(&p, 3);
        assert!(rgb.data.iter().all(|v| v.is_finite() && v.min_element() >= 0.0 && v.max_element() <= 1.0));
        assert!((-1.0..=1.0).contains(&noise(5, 7)));
    }
}
