//! Image and geometry error metrics for comparing a rendered view with its ground truth.
//!
//! Conventions (stated once, used by every caller):
//! - Colours are compared as **sRGB-encoded values in `[0, 1]`** of images **composited over black** (a
//!   premultiplied linear RGBA image is encoded as `linear_to_srgb(rgb)`, so the background is 0).
//! - [`psnr`] and [`ssim`] average over a **region** of pixels, normally the union of the predicted and the
//!   ground-truth masks ([`union_mask`]): background both agree on would inflate the score. SSIM statistics come
//!   from an 11x11 Gaussian window (sigma 1.5) evaluated on the whole image with edge-replicated borders, then
//!   averaged over the region; `C1 = (0.01)^2`, `C2 = (0.03)^2`, per channel, channels averaged.
//! - [`psnr_frame`] and [`ssim_frame`] are the paper's kind (R²Human Table 2): the same formulas over the **whole
//!   frame** (every pixel, outputs masked to black), so background both agree on counts as perfect. A frame
//!   whose person covers a fraction `f` of the pixels scores `10 log10(1/f)` dB more than over the union mask for
//!   the same errors; these are the numbers to read next to the paper's.
//! - [`mask_iou`] is `|A and B| / |A or B|` (1 when both masks are empty).
//! - [`depth_l1`] is the mean absolute depth difference over the union mask, with uncovered pixels at depth -1
//!   (the far face of the body cube), so a missing or extra surface costs its distance to the back of the cube.

use glam::Vec3;

/// An RGB image as sRGB-encoded values in `[0, 1]`, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct SrgbImage {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Pixels.
    pub data: Vec<Vec3>,
}

impl SrgbImage {
    /// From a premultiplied linear RGBA image: composited over black, then sRGB-encoded.
    pub fn from_linear_premultiplied(img: &crate::buffer::RgbaImage) -> Self {
        let data = img
            .data
            .iter()
            .map(|p| {
                let c = p.truncate();
                Vec3::new(enc(c.x), enc(c.y), enc(c.z))
            })
            .collect();
        Self { width: img.width, height: img.height, data }
    }
}

fn enc(v: f32) -> f32 {
    if v.is_finite() {
        crate::buffer::linear_to_srgb(v.clamp(0.0, 1.0))
    } else {
        0.0
    }
}

/// Union of two masks of equal length.
pub fn union_mask(a: &[bool], b: &[bool]) -> Vec<bool> {
    a.iter().zip(b).map(|(&x, &y)| x || y).collect()
}

/// Peak signal-to-noise ratio (dB, peak 1) over the region; `f32::INFINITY` for identical images, NaN-free.
/// An empty region gives infinity (nothing differs).
pub fn psnr(a: &SrgbImage, b: &SrgbImage, region: &[bool]) -> f32 {
    let mut sum = 0.0f64;
    let mut n = 0usize;
    for ((x, y), &r) in a.data.iter().zip(&b.data).zip(region) {
        if r {
            sum += (*x - *y).length_squared() as f64 / 3.0;
            n += 1;
        }
    }
    if n == 0 || sum == 0.0 {
        return f32::INFINITY;
    }
    let mse = sum / n as f64;
    (10.0 * (1.0 / mse).log10()) as f32
}

/// PSNR over the whole frame (every pixel; the paper's Table 2 convention, images over black); see [`psnr`].
pub fn psnr_frame(a: &SrgbImage, b: &SrgbImage) -> f32 {
    psnr(a, b, &vec![true; a.data.len().min(b.data.len())])
}

/// Mean SSIM over the whole frame (every pixel; the paper's Table 2 convention, images over black); see
/// [`ssim`]. 1 for empty images.
pub fn ssim_frame(a: &SrgbImage, b: &SrgbImage) -> f32 {
    ssim_region_of_map(&ssim_map(a, b), &vec![true; a.data.len()])
}

fn gaussian_kernel() -> [f32; 11] {
    let mut k = [0.0f32; 11];
    for (i, v) in k.iter_mut().enumerate() {
        let x = i as f32 - 5.0;
        *v = (-x * x / (2.0 * 1.5 * 1.5)).exp();
    }
    let s: f32 = k.iter().sum();
    k.map(|v| v / s)
}

/// Separable Gaussian blur with edge replication (rows in parallel; the clamped taps only near the borders).
fn blur(src: &[f32], w: usize, h: usize, k: &[f32; 11]) -> Vec<f32> {
    use rayon::prelude::*;
    let tap = |i: i64, len: usize| i.clamp(0, len as i64 - 1) as usize;
    let mut tmp = vec![0.0f32; w * h];
    tmp.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let line = &src[y * w..(y + 1) * w];
        for (x, out) in row.iter_mut().enumerate() {
            *out = if x >= 5 && x + 5 < w {
                k.iter().zip(&line[x - 5..=x + 5]).map(|(kv, v)| kv * v).sum()
            } else {
                k.iter().enumerate().map(|(j, kv)| kv * line[tap(x as i64 + j as i64 - 5, w)]).sum()
            };
        }
    });
    let mut out = vec![0.0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (j, kv) in k.iter().enumerate() {
            let yy = tap(y as i64 + j as i64 - 5, h);
            for (o, v) in row.iter_mut().zip(&tmp[yy * w..(yy + 1) * w]) {
                *o += kv * v;
            }
        }
    });
    out
}

/// Per-pixel SSIM map (channels averaged) of two images of equal size.
pub fn ssim_map(a: &SrgbImage, b: &SrgbImage) -> Vec<f32> {
    let (w, h) = (a.width, a.height);
    let n = w * h;
    if w == 0 || h == 0 || a.data.len() != n || b.data.len() != n || b.width != w {
        return Vec::new();
    }
    let k = gaussian_kernel();
    let (c1, c2) = (0.01f32 * 0.01, 0.03f32 * 0.03);
    let mut out = vec![0.0f32; n];
    for ch in 0..3 {
        let x: Vec<f32> = a.data.iter().map(|p| p[ch]).collect();
        let y: Vec<f32> = b.data.iter().map(|p| p[ch]).collect();
        let xx: Vec<f32> = x.iter().map(|v| v * v).collect();
        let yy: Vec<f32> = y.iter().map(|v| v * v).collect();
        let xy: Vec<f32> = x.iter().zip(&y).map(|(p, q)| p * q).collect();
        let (mx, my) = (blur(&x, w, h, &k), blur(&y, w, h, &k));
        let (sxx, syy, sxy) = (blur(&xx, w, h, &k), blur(&yy, w, h, &k), blur(&xy, w, h, &k));
        for i in 0..n {
            let vx = (sxx[i] - mx[i] * mx[i]).max(0.0);
            let vy = (syy[i] - my[i] * my[i]).max(0.0);
            let cxy = sxy[i] - mx[i] * my[i];
            let s = ((2.0 * mx[i] * my[i] + c1) * (2.0 * cxy + c2))
                / ((mx[i] * mx[i] + my[i] * my[i] + c1) * (vx + vy + c2));
            out[i] += s / 3.0;
        }
    }
    out
}

/// Mean SSIM over the region (1 for an empty region). Only the region's bounding box grown by the window radius
/// is filtered: the result is identical to averaging the whole-image [`ssim_map`] over the region.
pub fn ssim(a: &SrgbImage, b: &SrgbImage, region: &[bool]) -> f32 {
    let (w, h) = (a.width, a.height);
    if w == 0 || region.len() != w * h {
        return ssim_region_of_map(&ssim_map(a, b), region);
    }
    let (mut c0, mut c1, mut r0, mut r1) = (usize::MAX, 0, usize::MAX, 0);
    for (r, row) in region.chunks(w).enumerate() {
        if let (Some(x), Some(y)) = (row.iter().position(|&m| m), row.iter().rposition(|&m| m)) {
            (c0, c1, r0, r1) = (c0.min(x), c1.max(y), r0.min(r), r1.max(r));
        }
    }
    if c0 > c1 {
        return 1.0;
    }
    // Blurred values inside the box need source pixels up to 5 away (the crop edge then replicates exactly where
    // the image edge would).
    let (x0, x1, y0, y1) = (c0.saturating_sub(5), (c1 + 5).min(w - 1), r0.saturating_sub(5), (r1 + 5).min(h - 1));
    let crop = |img: &SrgbImage| SrgbImage {
        width: x1 + 1 - x0,
        height: y1 + 1 - y0,
        data: (y0..=y1).flat_map(|y| img.data[y * w + x0..=y * w + x1].iter().copied()).collect(),
    };
    let sub_region: Vec<bool> = (y0..=y1).flat_map(|y| region[y * w + x0..=y * w + x1].iter().copied()).collect();
    ssim_region_of_map(&ssim_map(&crop(a), &crop(b)), &sub_region)
}

fn ssim_region_of_map(map: &[f32], region: &[bool]) -> f32 {
    let (sum, n) =
        map.iter().zip(region).filter(|(_, &r)| r).fold((0.0f64, 0usize), |(s, n), (v, _)| (s + *v as f64, n + 1));
    if n == 0 {
        1.0
    } else {
        (sum / n as f64) as f32
    }
}

/// Intersection over union of two masks (1 when both are empty).
pub fn mask_iou(a: &[bool], b: &[bool]) -> f32 {
    let (mut inter, mut uni) = (0usize, 0usize);
    for (&x, &y) in a.iter().zip(b) {
        inter += (x && y) as usize;
        uni += (x || y) as usize;
    }
    if uni == 0 {
        1.0
    } else {
        inter as f32 / uni as f32
    }
}

/// Mean absolute depth difference over the union of the masks, uncovered pixels counted at depth -1 (0 when the
/// union is empty).
pub fn depth_l1(da: &[f32], ma: &[bool], db: &[f32], mb: &[bool]) -> f32 {
    let mut sum = 0.0f64;
    let mut n = 0usize;
    for i in 0..da.len().min(db.len()).min(ma.len()).min(mb.len()) {
        if ma[i] || mb[i] {
            let a = if ma[i] && da[i].is_finite() { da[i] } else { -1.0 };
            let b = if mb[i] && db[i].is_finite() { db[i] } else { -1.0 };
            sum += (a - b).abs() as f64;
            n += 1;
        }
    }
    if n == 0 {
        0.0
    } else {
        (sum / n as f64) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn img(w: usize, h: usize, f: impl Fn(usize, usize) -> Vec3) -> SrgbImage {
        SrgbImage { width: w, height: h, data: (0..w * h).map(|i| f(i % w, i / w)).collect() }
    }

    #[test]
    fn psnr_closed_form() {
        let a = img(8, 8, |_, _| Vec3::splat(0.5));
        let b = img(8, 8, |_, _| Vec3::splat(0.6));
        let all = vec![true; 64];
        // MSE = 0.01 -> 20 dB.
        assert!((psnr(&a, &b, &all) - 20.0).abs() < 1e-3);
        assert_eq!(psnr(&a, &a, &all), f32::INFINITY);
        // Region restricts: only pixel 0 differs and only pixel 0 counts.
        let mut c = a.clone();
        c.data[0] = Vec3::splat(0.4);
        let mut one = vec![false; 64];
        one[0] = true;
        assert!((psnr(&a, &c, &one) - 20.0).abs() < 1e-3);
        assert!((psnr(&a, &c, &all) - (20.0 + 10.0 * 64f32.log10())).abs() < 1e-3);
    }

    #[test]
    fn ssim_identity_constant_and_contrast() {
        let tex = img(32, 32, |x, y| Vec3::splat(((x * 7 + y * 13) % 10) as f32 / 10.0));
        let all = vec![true; 32 * 32];
        assert!((ssim(&tex, &tex, &all) - 1.0).abs() < 1e-5);
        // Two constant images: SSIM = (2 mu_x mu_y + C1) / (mu_x^2 + mu_y^2 + C1).
        let a = img(16, 16, |_, _| Vec3::splat(0.2));
        let b = img(16, 16, |_, _| Vec3::splat(0.6));
        let c1 = 1e-4f32;
        let expect = (2.0 * 0.2 * 0.6 + c1) / (0.04 + 0.36 + c1);
        assert!((ssim(&a, &b, &vec![true; 256]) - expect).abs() < 1e-4);
        // Inverted texture scores much lower than a slightly brightened one.
        let inv = img(32, 32, |x, y| Vec3::splat(1.0 - ((x * 7 + y * 13) % 10) as f32 / 10.0));
        let bright = img(32, 32, |x, y| Vec3::splat(((x * 7 + y * 13) % 10) as f32 / 10.0 * 0.95 + 0.05));
        assert!(ssim(&tex, &inv, &all) < 0.0);
        assert!(ssim(&tex, &bright, &all) > 0.9);
        assert!(ssim_map(&tex, &tex).iter().all(|v| v.is_finite()));
    }

    #[test]
    fn ssim_over_a_region_equals_the_whole_map_averaged_there() {
        let noise = |x: usize, y: usize, s: usize| ((x * 73 + y * 151 + s * 31) % 97) as f32 / 97.0;
        let a = img(60, 40, |x, y| Vec3::new(noise(x, y, 0), noise(x, y, 1), noise(x, y, 2)));
        let b = img(60, 40, |x, y| Vec3::new(noise(x + 1, y, 0), noise(x, y, 1) * 0.8, noise(x, y + 2, 2)));
        let map = ssim_map(&a, &b);
        // Interior blob, a blob touching two image edges, and scattered pixels.
        for region_of in [
            (|x: usize, y: usize| (20..35).contains(&x) && (10..22).contains(&y)) as fn(usize, usize) -> bool,
            |x, y| x < 7 && y > 30,
            |x, y| (x * y) % 11 == 3,
        ] {
            let region: Vec<bool> = (0..60 * 40).map(|i| region_of(i % 60, i / 60)).collect();
            let expect = ssim_region_of_map(&map, &region);
            assert!((ssim(&a, &b, &region) - expect).abs() < 1e-6, "{} vs {expect}", ssim(&a, &b, &region));
        }
        assert_eq!(ssim(&a, &b, &vec![false; 60 * 40]), 1.0);
    }

    #[test]
    fn whole_frame_metrics_in_closed_form() {
        // A 64x64 frame on black with a 10x10 person; the prediction is off by 0.1 on the person only.
        let (w, h) = (64usize, 64usize);
        let person = |x: usize, y: usize| (20..30).contains(&x) && (30..40).contains(&y);
        let gt = img(w, h, |x, y| if person(x, y) { Vec3::splat(0.5) } else { Vec3::ZERO });
        let pred = img(w, h, |x, y| if person(x, y) { Vec3::splat(0.6) } else { Vec3::ZERO });
        let union: Vec<bool> = (0..w * h).map(|i| person(i % w, i / w)).collect();
        // MSE over the frame = 0.01 * 100 / 4096: PSNR = 20 + 10 log10(40.96) dB, the union's 20 dB plus
        // 10 log10(1 / covered fraction).
        let want = 20.0 + 10.0 * (4096.0f32 / 100.0).log10();
        assert!((psnr_frame(&gt, &pred) - want).abs() < 1e-3, "{}", psnr_frame(&gt, &pred));
        assert!((psnr(&gt, &pred, &union) - 20.0).abs() < 1e-3);
        assert_eq!(psnr_frame(&gt, &gt), f32::INFINITY);
        // SSIM: pixels whose 11x11 window sees only black in both images score exactly 1; the frame mean is the
        // map's mean, so it exceeds the mean over the person alone.
        let map = ssim_map(&gt, &pred);
        let near = |x: usize, y: usize| (15..35).contains(&x) && (25..45).contains(&y);
        for (i, v) in map.iter().enumerate() {
            if !near(i % w, i / w) {
                assert!((v - 1.0).abs() < 1e-6, "pixel {i}: {v}");
            }
        }
        let frame = ssim_frame(&gt, &pred);
        assert!((frame - map.iter().map(|&v| v as f64).sum::<f64>() as f32 / 4096.0).abs() < 1e-6);
        assert!(frame > ssim(&gt, &pred, &union) && frame < 1.0);
        // Two constant frames: SSIM = (2 mu_x mu_y + C1) / (mu_x^2 + mu_y^2 + C1) everywhere.
        let a = img(16, 16, |_, _| Vec3::splat(0.2));
        let b = img(16, 16, |_, _| Vec3::splat(0.6));
        let c1 = 1e-4f32;
        assert!((ssim_frame(&a, &b) - (2.0 * 0.2 * 0.6 + c1) / (0.04 + 0.36 + c1)).abs() < 1e-4);
        // Everything missed (prediction all black): frame MSE = 0.25 * 100 / 4096.
        let black = img(w, h, |_, _| Vec3::ZERO);
        let want = 10.0 * (4096.0f32 / 25.0).log10();
        assert!((psnr_frame(&gt, &black) - want).abs() < 1e-3);
        assert!(ssim_frame(&gt, &black).is_finite() && ssim_frame(&black, &black) == 1.0);
    }

    #[test]
    fn iou_and_depth() {
        let a = [true, true, false, false];
        let b = [true, false, true, false];
        assert!((mask_iou(&a, &b) - 1.0 / 3.0).abs() < 1e-6);
        assert_eq!(mask_iou(&[false; 3], &[false; 3]), 1.0);
        // Union = pixels 0..3: |0.5-0.25| + |0.1-(-1)| + |-1-0.0| = 0.25 + 1.1 + 1.0.
        let da = [0.5, 0.1, 9.0, 9.0];
        let db = [0.25, 9.0, 0.0, 9.0];
        assert!((depth_l1(&da, &a, &db, &b) - 2.35 / 3.0).abs() < 1e-6);
        assert_eq!(depth_l1(&da, &[false; 4], &db, &[false; 4]), 0.0);
    }
}
