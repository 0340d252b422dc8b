//! A plain row-major 2-D buffer ([`Image`]) used by every stage, and the colour conventions.
//!
//! Colour convention: images inside the pipeline are **linear** light, `f32` per channel in `[0, 1]`
//! (HDR environments may exceed 1). RGBA images are **premultiplied** by alpha. sRGB encoding happens only at
//! the file/display edge ([`srgb_to_linear`], [`linear_to_srgb`]).

use glam::{Vec2, Vec3, Vec4};

/// Buffers at least this large are backed by transparent huge pages where the system allows ([`zeroed_f32`]).
pub const HUGE_PAGE_MIN_BYTES: usize = 4 << 20;
/// The huge-page size [`zeroed_f32`] aligns its advice to (x86-64 and aarch64 with 4 KiB base pages).
const HUGE_PAGE: usize = 2 << 20;

/// `len` zeros (`vec![0.0; len]`), for the per-input fields of tens of megabytes (a 512² FOF of 32 coefficients is
/// 32 MB).
///
/// The C library maps such a request fresh and does not write it: the kernel fills it page by page on first write,
/// with 4 KiB pages 8192 page faults for 32 MB, about 10 ms of CPU per field on the 2-core machine the still-photo
/// target is measured on. On Linux the buffer's whole 2 MiB pages are therefore advised as huge pages before any
/// is written (`madvise(MADV_HUGEPAGE)`, followed when transparent huge pages are set to `madvise` or `always`;
/// otherwise, or elsewhere, the advice changes nothing), and the threads that first write them fault in 2 MiB at a
/// time. Measured (`examples/still_stages`, the `astronaut` portrait, CPU): encoding the body FOF 20.4 -> 10.6 ms,
/// the FOF net 43.5 -> 32.8 ms, the inflation prior 41.7 -> 32.3 ms.
pub fn zeroed_f32(len: usize) -> Vec<f32> {
    let buffer = vec![0.0f32; len];
    advise_huge_pages(buffer.as_ptr() as usize, std::mem::size_of_val(buffer.as_slice()));
    buffer
}

/// Advises the whole huge pages inside the allocation `[start, start + bytes)` as huge pages (Linux).
#[cfg(target_os = "linux")]
fn advise_huge_pages(start: usize, bytes: usize) {
    if bytes < HUGE_PAGE_MIN_BYTES {
        return;
    }
    // The whole huge pages inside the buffer.
    let (first, end) = (start.next_multiple_of(HUGE_PAGE), (start + bytes) / HUGE_PAGE * HUGE_PAGE);
    if end <= first {
        return;
    }
    // SAFETY: [first, end) lies inside the caller's live allocation. MADV_HUGEPAGE only changes how the kernel backs
    // these pages, never the mapping or what is read from it;
    // a failure (a kernel without transparent huge pages) leaves the ordinary pages and is ignored.
    unsafe {
        libc::madvise(first as *mut libc::c_void, end - first, libc::MADV_HUGEPAGE);
    }
}

#[cfg(not(target_os = "linux"))]
fn advise_huge_pages(_start: usize, _bytes: usize) {}

/// A row-major image of `T`: pixel `(col, row)` lives at `data[row * width + col]`, row 0 at the top.
#[derive(Clone, Debug, PartialEq)]
pub struct Image<T> {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `width * height` pixels, row-major, top row first.
    pub data: Vec<T>,
}

impl<T: Clone> Image<T> {
    /// An image of `width x height` pixels, all set to `fill`.
    pub fn new(width: usize, height: usize, fill: T) -> Self {
        Self { width, height, data: vec![fill; width * height] }
    }

    /// Builds an image by calling `f(col, row)` for every pixel.
    pub fn from_fn(width: usize, height: usize, mut f: impl FnMut(usize, usize) -> T) -> Self {
        let mut data = Vec::with_capacity(width * height);
        for row in 0..height {
            for col in 0..width {
                data.push(f(col, row));
            }
        }
        Self { width, height, data }
    }

    /// The pixel at `(col, row)`. Panics when out of range (a programming error, never user input).
    #[inline]
    pub fn get(&self, col: usize, row: usize) -> &T {
        &self.data[row * self.width + col]
    }

    /// Mutable pixel at `(col, row)`.
    #[inline]
    pub fn get_mut(&mut self, col: usize, row: usize) -> &mut T {
        &mut self.data[row * self.width + col]
    }

    /// Sets the pixel at `(col, row)`.
    #[inline]
    pub fn set(&mut self, col: usize, row: usize, value: T) {
        self.data[row * self.width + col] = value;
    }

    /// Applies `f` to every pixel, producing a new image of the same size.
    pub fn map<U>(&self, f: impl Fn(&T) -> U) -> Image<U> {
        Image { width: self.width, height: self.height, data: self.data.iter().map(f).collect() }
    }

    /// Rows as slices, top first.
    pub fn rows(&self) -> std::slice::ChunksExact<'_, T> {
        self.data.chunks_exact(self.width.max(1))
    }
}

/// Linear RGB image (`Vec3` per pixel).
pub type RgbImage = Image<Vec3>;
/// Linear, premultiplied RGBA image (`Vec4` per pixel).
pub type RgbaImage = Image<Vec4>;
/// Single-channel float image (masks in `[0, 1]`, depths).
pub type GrayImage = Image<f32>;

/// A `size` x `size` grid of cells read from `img`: each cell the mean of `taps` x `taps` bilinear samples
/// ([`sample_bilinear`], black off the image) at `map(q)`, `q` the sample's point in grid coordinates (cell `(c, r)`
/// spans `[c, c + 1] x [r, r + 1]`). Row-major; rows in parallel (each cell on its own, so the same values in any
/// order). How the networks' square crops are read (the pose region, the rotated face region).
pub fn supersampled(img: &RgbImage, size: usize, taps: usize, map: impl Fn(Vec2) -> Vec2 + Sync) -> Vec<Vec3> {
    use rayon::prelude::*;
    let taps = taps.max(1);
    let mut out = vec![Vec3::ZERO; size * size];
    out.par_chunks_mut(size.max(1)).enumerate().for_each(|(r, row)| {
        for (c, cell) in row.iter_mut().enumerate() {
            let mut acc = Vec3::ZERO;
            for j in 0..taps {
                for i in 0..taps {
                    let q =
                        Vec2::new(c as f32 + (i as f32 + 0.5) / taps as f32, r as f32 + (j as f32 + 0.5) / taps as f32);
                    let p = map(q);
                    acc += sample_bilinear(img, p.x, p.y, Vec3::ZERO);
                }
            }
            *cell = acc / (taps * taps) as f32;
        }
    });
    out
}

/// `img` read bilinearly on an axis-aligned grid: output pixel `(c, r)` is `sample_bilinear(img, xs[c], ys[r],
/// outside)`, to the bit, with each column's and row's bilinear cell worked out once instead of per pixel (an image
/// scaled and shifted: a network's mask brought back to the frame, a frame brought to the source view). Rows in
/// parallel (each pixel on its own, so the same values in any order).
pub fn sample_bilinear_grid<T>(img: &Image<T>, xs: &[f32], ys: &[f32], outside: T) -> Image<T>
where
    T: Copy + Send + Sync + std::ops::Mul<f32, Output = T> + std::ops::Add<Output = T>,
{
    use rayon::prelude::*;
    let (w, h) = (xs.len(), ys.len());
    let columns: Vec<Option<(i64, f32)>> = xs.iter().map(|&x| bilinear_cell(x)).collect();
    let mut data = vec![outside; w * h];
    data.par_chunks_mut(w.max(1)).zip(ys.par_iter()).for_each(|(row, &y)| {
        let Some(cell_y) = bilinear_cell(y) else { return };
        for (out, column) in row.iter_mut().zip(&columns) {
            if let Some(cell_x) = *column {
                *out = sample_bilinear_cell(img, cell_x, cell_y, outside);
            }
        }
    });
    Image { width: w, height: h, data }
}

/// Bilinear sample of an image at continuous pixel coordinates (pixel centres at `+0.5`).
///
/// Samples outside the image read `outside` (the reference warps with zeros outside), and any non-finite
/// coordinate reads `outside` too, so NaN never propagates from a bad flow.
pub fn sample_bilinear<T>(img: &Image<T>, x: f32, y: f32, outside: T) -> T
where
    T: Copy + std::ops::Mul<f32, Output = T> + std::ops::Add<Output = T>,
{
    match (bilinear_cell(x), bilinear_cell(y)) {
        (Some(column), Some(row)) => sample_bilinear_cell(img, column, row, outside),
        _ => outside,
    }
}

/// The bilinear cell of one continuous pixel coordinate (pixel centres at `+0.5`): the lower pixel and the weight
/// of the next one, as [`sample_bilinear`] finds it; `None` when the coordinate is not finite. A caller sampling
/// many points on the same columns or rows (an axis-aligned grid) works each one out once.
#[inline]
pub fn bilinear_cell(x: f32) -> Option<(i64, f32)> {
    if !x.is_finite() {
        return None;
    }
    let f = x - 0.5;
    let x0 = floor_fast(f);
    Some((x0 as i64, f - x0))
}

/// [`sample_bilinear`] in the cell of its column and row ([`bilinear_cell`]): pixels outside the image read
/// `outside`.
#[inline]
pub fn sample_bilinear_cell<T>(img: &Image<T>, (c0, tx): (i64, f32), (r0, ty): (i64, f32), outside: T) -> T
where
    T: Copy + std::ops::Mul<f32, Output = T> + std::ops::Add<Output = T>,
{
    let (w, h) = (img.width as i64, img.height as i64);
    let fetch = |c: i64, r: i64| -> T {
        if c < 0 || r < 0 || c >= w || r >= h {
            outside
        } else {
            img.data[(r * w + c) as usize]
        }
    };
    let top = fetch(c0, r0) * (1.0 - tx) + fetch(c0 + 1, r0) * tx;
    let bottom = fetch(c0, r0 + 1) * (1.0 - tx) + fetch(c0 + 1, r0 + 1) * tx;
    top * (1.0 - ty) + bottom * ty
}

/// `x.floor()` without the libm call that baseline x86-64 (no SSE4.1) makes for it: hot per-pixel loops use
/// this. Equal to `f32::floor` for every input, NaN and infinities included (only `-0.0` comes back as `+0.0`).
#[inline]
pub fn floor_fast(x: f32) -> f32 {
    // Beyond 2^23 every f32 is an integer (and NaN/inf fail the test and come back unchanged).
    if x.abs() < 8_388_608.0 {
        let t = x as i32 as f32;
        if t > x {
            t - 1.0
        } else {
            t
        }
    } else {
        x
    }
}

/// The luminance of a linear RGB colour (Rec. 709 / sRGB primaries: 0.2126 R + 0.7152 G + 0.0722 B).
#[inline]
pub fn luminance(v: Vec3) -> f32 {
    0.2126 * v.x + 0.7152 * v.y + 0.0722 * v.z
}

/// sRGB (IEC 61966-2-1) encoded value in `[0, 1]` to linear light.
#[inline]
pub fn srgb_to_linear(v: f32) -> f32 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// An 8-bit sRGB value to linear light: [`srgb_to_linear`] of `v / 255`, looked up in a table of the 256 values
/// (bit for bit the same; a 640×480 frame is 0.9M of them).
#[inline]
pub fn srgb8_to_linear(v: u8) -> f32 {
    static TABLE: std::sync::LazyLock<[f32; 256]> =
        std::sync::LazyLock::new(|| std::array::from_fn(|i| srgb_to_linear(i as f32 / 255.0)));
    TABLE[v as usize]
}

/// Linear light to sRGB encoded value in `[0, 1]`; clamps out-of-range and maps NaN to 0.
#[inline]
pub fn linear_to_srgb(v: f32) -> f32 {
    let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
    if v <= 0.003_130_8 {
        v * 12.92
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// Premultiplies a straight-alpha colour.
#[inline]
pub fn premultiply(rgb: Vec3, alpha: f32) -> Vec4 {
    (rgb * alpha).extend(alpha)
}

/// Undoes premultiplication (colour of a fully transparent pixel is black).
#[inline]
pub fn unpremultiply(rgba: Vec4) -> Vec3 {
    if rgba.w > 1e-6 {
        rgba.truncate() / rgba.w
    } else {
        Vec3::ZERO
    }
}

/// The 4-connected neighbours (left, right, up, down) of pixel index `p` in a row-major `width x height` image,
/// those inside the image only.
pub fn neighbours4(p: usize, width: usize, height: usize) -> impl Iterator<Item = usize> {
    let (x, y) = (p % width, p / width);
    [
        (x > 0).then(|| p - 1),
        (x + 1 < width).then(|| p + 1),
        (y > 0).then(|| p - width),
        (y + 1 < height).then(|| p + width),
    ]
    .into_iter()
    .flatten()
}

/// The 8-connected neighbours of pixel index `p` in a row-major `width x height` image, those inside the image
/// only, row by row (above, beside, below; left to right).
pub fn neighbours8(p: usize, width: usize, height: usize) -> impl Iterator<Item = usize> {
    let (x, y) = ((p % width) as i64, (p / width) as i64);
    (-1i64..=1)
        .flat_map(move |dy| (-1i64..=1).map(move |dx| (x + dx, y + dy)))
        .filter(move |&(c, r)| (c, r) != (x, y) && c >= 0 && r >= 0 && c < width as i64 && r < height as i64)
        .map(move |(c, r)| r as usize * width + c as usize)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_sampler_gives_the_bits_of_sampling_each_pixel() {
        let img = GrayImage::from_fn(37, 23, |c, r| ((c * 31 + r * 17) % 11) as f32 * 0.1 - 0.3);
        // Scaled down, scaled up and shifted off the image, with a non-finite column and row.
        let xs: Vec<f32> = (0..50).map(|c| if c == 7 { f32::NAN } else { -3.0 + c as f32 * 0.83 }).collect();
        let ys: Vec<f32> = (0..31).map(|r| if r == 4 { f32::INFINITY } else { 25.0 - r as f32 * 1.7 }).collect();
        let grid = sample_bilinear_grid(&img, &xs, &ys, 0.25);
        assert_eq!((grid.width, grid.height), (50, 31));
        for (r, &y) in ys.iter().enumerate() {
            for (c, &x) in xs.iter().enumerate() {
                assert_eq!(grid.get(c, r).to_bits(), sample_bilinear(&img, x, y, 0.25).to_bits(), "({c}, {r})");
            }
        }
        assert!(sample_bilinear_grid(&img, &[], &ys, 0.0).data.is_empty());
    }

    #[test]
    fn zeroed_buffers_hold_zeros_large_or_small() {
        for len in [0, 1, 1000, HUGE_PAGE_MIN_BYTES / 4 + 12345] {
            let buffer = zeroed_f32(len);
            assert_eq!(buffer.len(), len);
            assert!(buffer.iter().all(|v| v.to_bits() == 0), "len {len}");
        }
    }

    #[test]
    fn neighbours4_stay_inside() {
        let n = |p| neighbours4(p, 3, 2).collect::<Vec<_>>();
        assert_eq!(n(0), vec![1, 3]);
        assert_eq!(n(4), vec![3, 5, 1]);
        assert_eq!(n(5), vec![4, 2]);
        assert_eq!(neighbours4(0, 1, 1).count(), 0);
    }

    #[test]
    fn neighbours8_stay_inside_row_by_row() {
        // 3 x 3: the middle has all eight; a corner three; the middle of the bottom row five.
        let n = |p| neighbours8(p, 3, 3).collect::<Vec<_>>();
        assert_eq!(n(4), vec![0, 1, 2, 3, 5, 6, 7, 8]);
        assert_eq!(n(0), vec![1, 3, 4]);
        assert_eq!(n(7), vec![3, 4, 5, 6, 8]);
        assert_eq!(neighbours8(0, 1, 1).count(), 0);
    }

    #[test]
    fn floor_fast_equals_floor() {
        let specials = [0.0f32, -0.0, 0.5, -0.5, 1.0, -1.0, -1.5, 8_388_607.5, -8_388_607.5, 8_388_608.0, 1e10, -1e10];
        let mut x = -1000.0f32;
        let mut all: Vec<f32> = specials.to_vec();
        while x < 1000.0 {
            all.extend([x, x.next_up(), x.next_down()]);
            x += 0.731;
        }
        for v in all {
            assert_eq!(floor_fast(v), v.floor(), "{v}");
        }
        assert!(floor_fast(f32::NAN).is_nan());
        assert_eq!(floor_fast(f32::INFINITY), f32::INFINITY);
        assert_eq!(floor_fast(f32::NEG_INFINITY), f32::NEG_INFINITY);
    }

    #[test]
    fn the_srgb8_table_is_the_formula() {
        for v in 0..=255u8 {
            assert_eq!(srgb8_to_linear(v).to_bits(), srgb_to_linear(f32::from(v) / 255.0).to_bits(), "{v}");
        }
    }

    #[test]
    fn srgb_round_trip() {
        for i in 0..=255 {
            let v = i as f32 / 255.0;
            assert!((linear_to_srgb(srgb_to_linear(v)) - v).abs() < 1e-5);
        }
        assert_eq!(linear_to_srgb(f32::NAN), 0.0);
    }

    #[test]
    fn bilinear_hits_pixel_centres_and_interpolates() {
        let img = Image::from_fn(3, 2, |c, r| (c + 10 * r) as f32);
        assert_eq!(sample_bilinear(&img, 0.5, 0.5, -1.0), 0.0);
        assert_eq!(sample_bilinear(&img, 2.5, 1.5, -1.0), 12.0);
        assert!((sample_bilinear(&img, 1.0, 0.5, -1.0) - 0.5).abs() < 1e-6);
        assert!((sample_bilinear(&img, 1.5, 1.0, -1.0) - 6.0).abs() < 1e-6);
        assert_eq!(sample_bilinear(&img, f32::NAN, 0.5, -1.0), -1.0);
        // Outside: blends towards the `outside` value.
        assert!((sample_bilinear(&img, 0.0, 0.5, 0.0) - 0.0).abs() < 1e-6);
    }
}
