//! Tensors passed between the pipeline and the networks: feature maps, FOF coefficient views, pixel boxes, and the
//! conversions from pipeline images (linear, premultiplied) to network tensors (planar, sRGB `[-1, 1]`).

use glam::Vec3;
use rayon::prelude::*;

use crate::buffer::{linear_to_srgb, GrayImage, Image, RgbImage};

/// A planar (channel-major, `CHW`) float feature map, e.g. the encoder's output at 1/4 of the source resolution.
#[derive(Clone, Debug, PartialEq)]
pub struct FeatureMap {
    /// Number of channels `C`.
    pub channels: usize,
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `channels * height * width` values: channel `c`, pixel `(col, row)` at `c*H*W + row*W + col`.
    pub data: Vec<f32>,
}

impl FeatureMap {
    /// A zero feature map.
    pub fn zeros(channels: usize, width: usize, height: usize) -> Self {
        Self { channels, width, height, data: vec![0.0; channels * width * height] }
    }

    /// Bilinearly samples all channels at body-cube coordinates `(x, y)` of the source camera (`x` right, `y` up,
    /// both in `[-1, 1]` across the map, pixel centres at `x = (col+0.5)/(W/2) - 1`), reading zeros outside the
    /// map, exactly like the reference's `grid_sample(align_corners=False, padding_mode="zeros")`. Writes
    /// `channels` values to `out`; non-finite coordinates give zeros.
    pub fn sample_cube(&self, x: f32, y: f32, out: &mut [f32]) {
        let out = &mut out[..self.channels];
        out.fill(0.0);
        if !(x.is_finite() && y.is_finite()) {
            return;
        }
        // Continuous pixel coordinates, centres at +0.5, then shifted so integer values hit centres.
        let fx = (x + 1.0) * 0.5 * self.width as f32 - 0.5;
        let fy = (1.0 - y) * 0.5 * self.height as f32 - 0.5;
        let (x0, y0) = (fx.floor(), fy.floor());
        let (tx, ty) = (fx - x0, fy - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let plane = self.width * self.height;
        let taps = [
            (x0, y0, (1.0 - tx) * (1.0 - ty)),
            (x0 + 1, y0, tx * (1.0 - ty)),
            (x0, y0 + 1, (1.0 - tx) * ty),
            (x0 + 1, y0 + 1, tx * ty),
        ];
        for (c, r, w) in taps {
            if c < 0 || r < 0 || c >= self.width as i64 || r >= self.height as i64 || w == 0.0 {
                continue;
            }
            let base = r as usize * self.width + c as usize;
            for (ch, o) in out.iter_mut().enumerate() {
                *o += w * self.data[ch * plane + base];
            }
        }
    }
}

/// A read-only view of per-pixel FOF-X coefficients, pixel-major (`HWN`, as `fof.npy`): pixel `(col, row)`'s `n`
/// coefficients start at `(row*width + col)*n`.
#[derive(Clone, Copy, Debug)]
pub struct Coefficients<'a> {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Coefficients per pixel.
    pub n: usize,
    /// `width*height*n` values.
    pub data: &'a [f32],
}

/// An axis-aligned pixel rectangle `[x0, x1) x [y0, y1)`; it may extend past the image (outside reads as zero).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PixelBox {
    /// First column.
    pub x0: i64,
    /// First row.
    pub y0: i64,
    /// One past the last column.
    pub x1: i64,
    /// One past the last row.
    pub y1: i64,
}

impl PixelBox {
    /// The bounding box of the pixels with `mask > 0`, or `None` for an empty mask.
    pub fn of_mask(mask: &GrayImage) -> Option<Self> {
        Self::of_alpha(mask.width, mask.height, |i| mask.data[i])
    }

    /// The bounding box of the pixels of a `width x height` image whose `alpha(row*width + col) > 0`.
    pub fn of_alpha(width: usize, height: usize, alpha: impl Fn(usize) -> f32) -> Option<Self> {
        let mut b: Option<Self> = None;
        for row in 0..height {
            let base = row * width;
            let first = (0..width).position(|c| alpha(base + c) > 0.0);
            let Some(first) = first else { continue };
            let last = (0..width).rposition(|c| alpha(base + c) > 0.0).unwrap_or(first);
            let (r, f, l) = (row as i64, first as i64, last as i64 + 1);
            b = Some(match b {
                None => Self { x0: f, y0: r, x1: l, y1: r + 1 },
                Some(b) => Self { x0: b.x0.min(f), y0: b.y0, x1: b.x1.max(l), y1: r + 1 },
            });
        }
        b
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        (self.x1 - self.x0).max(0) as usize
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        (self.y1 - self.y0).max(0) as usize
    }

    /// The box grown by `margin` on every side, clipped to a `width x height` image, then with its origin moved down
    /// to a multiple of `stride` and its size rounded up to a multiple of `stride` (the end may then pass the image
    /// edge; those pixels are zero, like background). Aligning the origin keeps the network's down-sampling grid
    /// where it is on the full frame.
    pub fn padded(&self, margin: usize, stride: usize, width: usize, height: usize) -> Self {
        let (m, s) = (margin as i64, stride.max(1) as i64);
        let x0 = (self.x0 - m).max(0);
        let y0 = (self.y0 - m).max(0);
        let x1 = (self.x1 + m).min(width as i64);
        let y1 = (self.y1 + m).min(height as i64);
        let (x0, y0) = (x0 / s * s, y0 / s * s);
        let w = ((x1 - x0).max(1) + s - 1) / s * s;
        let h = ((y1 - y0).max(1) + s - 1) / s * s;
        Self { x0, y0, x1: x0 + w, y1: y0 + h }
    }
}

/// Resamples one `sw x sh` plane to `dw x dh`: a box average when the source is an integer multiple of the
/// destination (the usual 512 -> 256), else bilinear at pixel centres (clamped at the edges).
pub(crate) fn resample_plane(src: &[f32], sw: usize, sh: usize, dw: usize, dh: usize) -> Vec<f32> {
    if sw == dw && sh == dh {
        return src.to_vec();
    }
    let mut out = vec![0.0; dw * dh];
    if sw % dw == 0 && sh % dh == 0 {
        let (kx, ky) = (sw / dw, sh / dh);
        let norm = 1.0 / (kx * ky) as f32;
        for r in 0..dh {
            for c in 0..dw {
                let mut acc = 0.0;
                for yy in r * ky..(r + 1) * ky {
                    acc += src[yy * sw + c * kx..yy * sw + (c + 1) * kx].iter().sum::<f32>();
                }
                out[r * dw + c] = acc * norm;
            }
        }
        return out;
    }
    let (fx, fy) = (sw as f32 / dw as f32, sh as f32 / dh as f32);
    for r in 0..dh {
        let y = ((r as f32 + 0.5) * fy - 0.5).clamp(0.0, (sh - 1) as f32);
        let (y0, ty) = (y.floor() as usize, y - y.floor());
        let y1 = (y0 + 1).min(sh - 1);
        for c in 0..dw {
            let x = ((c as f32 + 0.5) * fx - 0.5).clamp(0.0, (sw - 1) as f32);
            let (x0, tx) = (x.floor() as usize, x - x.floor());
            let x1 = (x0 + 1).min(sw - 1);
            let top = src[y0 * sw + x0] * (1.0 - tx) + src[y0 * sw + x1] * tx;
            let bottom = src[y1 * sw + x0] * (1.0 - tx) + src[y1 * sw + x1] * tx;
            out[r * dw + c] = top * (1.0 - ty) + bottom * ty;
        }
    }
    out
}

/// The network's `image` tensor (planar `[3, R, R]`): sRGB-encoded colour premultiplied by the mask, mapped to
/// `[-1, 1]`, from a linear premultiplied RGB image and its mask, resampled to `r x r`.
pub(crate) fn image_tensor(rgb: &RgbImage, mask: &GrayImage, r: usize) -> Vec<f32> {
    let (w, h) = (rgb.width, rgb.height);
    let mut planes = vec![0.0f32; 3 * w * h];
    for (i, (&c, &a)) in rgb.data.iter().zip(&mask.data).enumerate() {
        let a = if a.is_finite() { a.clamp(0.0, 1.0) } else { 0.0 };
        let straight = if a > 1e-6 { c / a } else { Vec3::ZERO };
        for (k, v) in [straight.x, straight.y, straight.z].into_iter().enumerate() {
            planes[k * w * h + i] = linear_to_srgb(v) * a * 2.0 - 1.0;
        }
    }
    planes.chunks_exact(w * h).flat_map(|p| resample_plane(p, w, h, r, r)).collect()
}

/// The `normals` tensor (planar `[3, r, r]`) from view-space normals, resampled and renormalised (zero stays
/// zero; non-finite normals become zero).
pub(crate) fn normals_tensor(normals: &Image<Vec3>, r: usize) -> Vec<f32> {
    let (w, h) = (normals.width, normals.height);
    let mut planes = vec![0.0f32; 3 * w * h];
    for (i, n) in normals.data.iter().enumerate() {
        let n = if n.is_finite() { *n } else { Vec3::ZERO };
        planes[i] = n.x;
        planes[w * h + i] = n.y;
        planes[2 * w * h + i] = n.z;
    }
    let mut out: Vec<f32> = planes.chunks_exact(w * h).flat_map(|p| resample_plane(p, w, h, r, r)).collect();
    let plane = r * r;
    for i in 0..plane {
        let v = Vec3::new(out[i], out[plane + i], out[2 * plane + i]);
        let len = v.length();
        let v = if len > 1e-3 { v / len } else { Vec3::ZERO };
        out[i] = v.x;
        out[plane + i] = v.y;
        out[2 * plane + i] = v.z;
    }
    out
}

/// The `fof` tensor (planar `[n, r, r]`) from pixel-major coefficients (non-finite values become zero).
pub(crate) fn coefficients_tensor(c: &Coefficients<'_>, r: usize) -> Vec<f32> {
    let (w, h, n) = (c.width, c.height, c.n);
    if r > 0 && w % r == 0 && h % r == 0 {
        // The usual 512 -> 128 box average straight from the pixel-major layout: one pass over contiguous
        // columns instead of a full-resolution planar copy (the same values as the general path below). Output
        // rows in parallel (pixel-major), then made planar.
        let (kx, ky) = (w / r, h / r);
        let norm = 1.0 / (kx * ky) as f32;
        let plane = r * r;
        let mut pixels = vec![0.0f32; n * plane];
        pixels.par_chunks_mut(r * n).enumerate().for_each(|(row, line_out)| {
            for (col, acc) in line_out.chunks_exact_mut(n).enumerate() {
                for y in row * ky..(row + 1) * ky {
                    let line = &c.data[(y * w + col * kx) * n..(y * w + (col + 1) * kx) * n];
                    for px in line.chunks_exact(n) {
                        for (a, &v) in acc.iter_mut().zip(px) {
                            *a += if v.is_finite() { v } else { 0.0 };
                        }
                    }
                }
            }
        });
        let mut out = vec![0.0f32; n * plane];
        for (i, px) in pixels.chunks_exact(n).enumerate() {
            for (k, a) in px.iter().enumerate() {
                out[k * plane + i] = a * norm;
            }
        }
        return out;
    }
    let mut planes = vec![0.0f32; n * w * h];
    for (i, px) in c.data.chunks_exact(n).enumerate() {
        for (k, &v) in px.iter().enumerate() {
            planes[k * w * h + i] = if v.is_finite() { v } else { 0.0 };
        }
    }
    planes.chunks_exact(w * h).flat_map(|p| resample_plane(p, w, h, r, r)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coefficients_tensor_box_path_matches_the_planar_path() {
        // A 6x4 grid of 3 coefficients with one NaN, box-averaged to 2x2 (factors 3 and 2, the fast path), against
        // the planar reference: NaN zeroed, one plane per coefficient, `resample_plane`.
        let data: Vec<f32> = (0..6 * 4 * 3).map(|i| if i == 7 { f32::NAN } else { (i as f32 * 0.37).sin() }).collect();
        let fast = coefficients_tensor(&Coefficients { width: 6, height: 4, n: 3, data: &data }, 2);
        assert_eq!(fast.len(), 3 * 4);
        for k in 0..3 {
            let plane: Vec<f32> =
                (0..24).map(|i| data[i * 3 + k]).map(|v| if v.is_finite() { v } else { 0.0 }).collect();
            let want = resample_plane(&plane, 6, 4, 2, 2);
            for (a, b) in fast[k * 4..(k + 1) * 4].iter().zip(&want) {
                assert!((a - b).abs() < 1e-6, "k{k}: {a} vs {b}");
            }
        }
        // Pixel (0,0) of coefficient 0 by hand: the mean of the 3x2 block's first coefficients.
        let block: f32 = [0usize, 1, 2, 6, 7, 8].iter().map(|&p| data[p * 3]).sum::<f32>() / 6.0;
        assert!((fast[0] - block).abs() < 1e-6);
    }

    #[test]
    fn sample_cube_hits_centres_and_reads_zero_outside() {
        // 4x2 map, 2 channels: channel 0 = col + 10*row, channel 1 = -(same).
        let mut f = FeatureMap::zeros(2, 4, 2);
        for r in 0..2 {
            for c in 0..4 {
                f.data[r * 4 + c] = (c + 10 * r) as f32;
                f.data[8 + r * 4 + c] = -((c + 10 * r) as f32);
            }
        }
        let mut out = [0.0; 2];
        // Centre of pixel (col 1, row 0): x = 1.5/2 - 1 = -0.25, y = 1 - 0.5/1 = 0.5.
        f.sample_cube(-0.25, 0.5, &mut out);
        assert_eq!(out, [1.0, -1.0]);
        // Halfway between rows 0 and 1 at col 3 (y = 0).
        f.sample_cube(0.75, 0.0, &mut out);
        assert!((out[0] - 8.0).abs() < 1e-5 && (out[1] + 8.0).abs() < 1e-5, "{out:?}");
        // At the right edge (x = 1) half the weight falls outside: zeros padding.
        f.sample_cube(1.0, 0.5, &mut out);
        assert!((out[0] - 1.5).abs() < 1e-5, "{out:?}");
        f.sample_cube(3.0, 0.0, &mut out);
        assert_eq!(out, [0.0, 0.0]);
        f.sample_cube(f32::NAN, 0.0, &mut out);
        assert_eq!(out, [0.0, 0.0]);
    }

    #[test]
    fn mask_box_and_padding() {
        let mut mask = GrayImage::new(20, 10, 0.0);
        assert_eq!(PixelBox::of_mask(&mask), None);
        mask.set(5, 3, 1.0);
        mask.set(9, 6, 0.5);
        mask.set(7, 2, 0.2);
        let b = PixelBox::of_mask(&mask).unwrap();
        assert_eq!(b, PixelBox { x0: 5, y0: 2, x1: 10, y1: 7 });
        assert_eq!((b.width(), b.height()), (5, 5));
        // margin 2 -> [3,12) x [0,9); stride 4 -> origin (0, 0), size rounded up to (12, 12).
        let p = b.padded(2, 4, 20, 10);
        assert_eq!(p, PixelBox { x0: 0, y0: 0, x1: 12, y1: 12 });
        assert!(p.x0 <= b.x0 && p.y0 <= b.y0 && p.x1 >= b.x1 && p.y1 >= b.y1);
        let q = b.padded(0, 8, 20, 10);
        assert_eq!((q.x0 % 8, q.y0 % 8, q.width() % 8, q.height() % 8), (0, 0, 0, 0));
        assert!(q.x1 >= b.x1 && q.y1 >= b.y1);
    }

    #[test]
    fn resample_box_and_bilinear() {
        let src: Vec<f32> = (0..16).map(|v| v as f32).collect(); // 4x4, value = 4*row + col
        let half = resample_plane(&src, 4, 4, 2, 2);
        assert_eq!(half, vec![2.5, 4.5, 10.5, 12.5]);
        // Bilinear 4 -> 3: column centre 0.5 * 4/3 - 0.5 = 1/6 in source index units.
        let b = resample_plane(&src, 4, 4, 3, 3);
        assert!((b[0] - (1.0 / 6.0) * 5.0).abs() < 1e-5, "{b:?}");
        assert!((b[4] - 7.5).abs() < 1e-5, "{b:?}");
    }

    #[test]
    fn image_tensor_is_srgb_premultiplied_in_minus_one_one() {
        let rgb = RgbImage::from_fn(2, 2, |c, _| if c == 0 { Vec3::new(1.0, 0.2140, 0.0) * 0.5 } else { Vec3::ZERO });
        let mask = GrayImage::from_fn(2, 2, |c, _| if c == 0 { 0.5 } else { 0.0 });
        let t = image_tensor(&rgb, &mask, 2);
        assert_eq!(t.len(), 12);
        // Planes R, G, B of 2x2 each. Straight colour (1, 0.214, 0) -> sRGB (1, ~0.5, 0), times alpha 0.5, *2-1.
        assert!((t[0] - 0.0).abs() < 1e-4, "{t:?}");
        assert!((t[4] - (0.5 * 0.5 * 2.0 - 1.0)).abs() < 2e-3, "{t:?}");
        assert!((t[8] + 1.0).abs() < 1e-6);
        // Background is -1 in every channel.
        assert_eq!([t[1], t[5], t[9]], [-1.0, -1.0, -1.0]);
    }

    #[test]
    fn normals_tensor_renormalises_and_drops_nan() {
        let n = Image::from_fn(2, 2, |c, r| match (c, r) {
            (0, 0) => Vec3::Z,
            (1, 0) => Vec3::X,
            (0, 1) => Vec3::new(f32::NAN, 0.0, 0.0),
            _ => Vec3::ZERO,
        });
        let t = normals_tensor(&n, 1);
        let v = Vec3::new(t[0], t[1], t[2]);
        assert!((v - Vec3::new(1.0, 0.0, 1.0).normalize()).length() < 1e-5, "{v:?}");
        let same = normals_tensor(&n, 2);
        assert_eq!((same[0], same[2 * 4], same[1]), (0.0, 1.0, 1.0));
        assert_eq!(same[2], 0.0);
    }
}
