//! Input normalisation: the person is cropped from the photo by its mask, scaled so the mask's height spans
//! 1.8 body-cube units (y in [-0.9, 0.9], like the reference's preprocessing), centred, padded to the square
//! source resolution and premultiplied by the mask (`img * mask`, as the reference feeds its networks).

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use crate::buffer::{bilinear_cell, neighbours4, neighbours8, sample_bilinear_cell, GrayImage, Image, RgbImage};

/// Fraction of the source image height the person's mask spans (1.8 of the cube's 2 units).
pub const PERSON_HEIGHT_FRACTION: f32 = 0.9;
/// The widest a person may be, as a fraction of the source width, before the scale fits the width instead.
pub const MAX_WIDTH_FRACTION: f32 = 0.98;
/// A mask covering less than this fraction of the photo is refused (too small to reconstruct).
pub const MIN_COVERAGE: f32 = 0.01;
/// A mask covering more than this fraction of the photo is refused (nothing separates the person).
pub const MAX_COVERAGE: f32 = 0.995;

/// Errors in preparing an input photo.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum InputError {
    /// The mask has no foreground pixel.
    #[error("the mask is empty: no pixel is marked as the person. Give a photo with an alpha channel around the person, or a --mask file where the person is white")]
    EmptyMask,
    /// The mask covers (almost) the whole photo.
    #[error("the mask covers {:.1}% of the photo, so it does not separate the person from the background; give a mask (--mask FILE, person white) or a photo with transparency around the person", coverage * 100.0)]
    FullMask {
        /// Fraction covered.
        coverage: f32,
    },
    /// The person is too small in the photo.
    #[error("the person covers only {:.2}% of the photo (at least {:.0}% is needed); crop the photo closer to the person", coverage * 100.0, MIN_COVERAGE * 100.0)]
    PersonTooSmall {
        /// Fraction covered.
        coverage: f32,
    },
    /// Image and mask sizes differ.
    #[error("image is {0}x{1} but mask is {2}x{3}")]
    SizeMismatch(usize, usize, usize, usize),
    /// A pixel is NaN or infinite.
    #[error("the input contains non-finite values (NaN or infinity); the file is damaged")]
    NonFinite,
}

/// Maps original photo pixel coordinates to normalised source pixel coordinates: `p_norm = scale * p + offset`
/// (continuous pixel coordinates, centres at +0.5).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NormaliseTransform {
    /// Uniform scale from photo pixels to source pixels.
    pub scale: f32,
    /// Offset in source pixels.
    pub offset: Vec2,
}

impl NormaliseTransform {
    /// Photo pixel to source pixel.
    pub fn forward(&self, p: Vec2) -> Vec2 {
        p * self.scale + self.offset
    }
    /// Source pixel to photo pixel.
    pub fn inverse(&self, q: Vec2) -> Vec2 {
        (q - self.offset) / self.scale
    }
}

/// The person in the source camera's frame.
#[derive(Clone, Debug)]
pub struct NormalisedInput {
    /// Linear RGB premultiplied by the mask, `resolution^2`.
    pub rgb: RgbImage,
    /// Mask in `[0, 1]`, `resolution^2`.
    pub mask: GrayImage,
    /// How photo pixels map to these.
    pub transform: NormaliseTransform,
    /// Where the photo lies in the source view: `(min, max)` corners in source pixels (the photo's corners
    /// through `transform`). Outside it the source view is padding, not a place where the person ends.
    pub frame: (Vec2, Vec2),
}

impl NormalisedInput {
    /// An input already in the source view (a render of a subject in the body cube): identity transform, the
    /// whole view is the photo. `rgb` premultiplied by `mask`, both the same size.
    pub fn in_source_view(rgb: RgbImage, mask: GrayImage) -> Self {
        let frame = (Vec2::ZERO, Vec2::new(mask.width as f32, mask.height as f32));
        Self { rgb, mask, transform: NormaliseTransform { scale: 1.0, offset: Vec2::ZERO }, frame }
    }
}

/// Normalises a photo (`rgb` linear straight colour, `mask` in `[0, 1]`, same size) into the body cube at
/// `resolution^2`. See the module docs for the rule.
pub fn normalise(rgb: &RgbImage, mask: &GrayImage, resolution: usize) -> Result<NormalisedInput, InputError> {
    if (rgb.width, rgb.height) != (mask.width, mask.height) {
        return Err(InputError::SizeMismatch(rgb.width, rgb.height, mask.width, mask.height));
    }
    if rgb.data.iter().any(|v| !v.is_finite()) || mask.data.iter().any(|v| !v.is_finite()) {
        return Err(InputError::NonFinite);
    }
    let (w, h) = (mask.width, mask.height);
    let (mut c0, mut c1, mut r0, mut r1) = (usize::MAX, 0usize, usize::MAX, 0usize);
    // The box of the pixels any part of the person covers (mask > 0): outside it the premultiplied colour and
    // the mask are 0, and so is every output pixel whose taps read only there.
    let (mut z0, mut z1, mut q0, mut q1) = (usize::MAX, 0usize, usize::MAX, 0usize);
    let mut count = 0usize;
    for r in 0..h {
        for c in 0..w {
            let m = *mask.get(c, r);
            if m > 0.0 {
                (z0, z1, q0, q1) = (z0.min(c), z1.max(c), q0.min(r), q1.max(r));
            }
            if m >= 0.5 {
                count += 1;
                c0 = c0.min(c);
                c1 = c1.max(c);
                r0 = r0.min(r);
                r1 = r1.max(r);
            }
        }
    }
    if count == 0 {
        return Err(InputError::EmptyMask);
    }
    let coverage = count as f32 / (w * h) as f32;
    if coverage > MAX_COVERAGE {
        return Err(InputError::FullMask { coverage });
    }
    if coverage < MIN_COVERAGE {
        return Err(InputError::PersonTooSmall { coverage });
    }
    let res = resolution as f32;
    let person_h = (r1 + 1 - r0) as f32;
    let person_w = (c1 + 1 - c0) as f32;
    let scale = (PERSON_HEIGHT_FRACTION * res / person_h).min(MAX_WIDTH_FRACTION * res / person_w);
    let centre = Vec2::new((c0 + c1 + 1) as f32 * 0.5, (r0 + r1 + 1) as f32 * 0.5);
    let offset = Vec2::splat(res * 0.5) - centre * scale;
    let transform = NormaliseTransform { scale, offset };

    let mut premultiplied = Image::new(w, h, Vec3::ZERO);
    for r in q0..=q1 {
        let span = r * w + z0..r * w + z1 + 1;
        for ((p, c), m) in
            premultiplied.data[span.clone()].iter_mut().zip(&rgb.data[span.clone()]).zip(&mask.data[span])
        {
            *p = *c * *m;
        }
    }
    // Supersample when shrinking so thin structures are averaged rather than aliased.
    let taps = ((1.0 / scale).ceil() as usize).clamp(1, 8);
    let mut out_rgb = Image::new(resolution, resolution, Vec3::ZERO);
    let mut out_mask = Image::new(resolution, resolution, 0.0f32);
    // The transform is a scale and a shift: a tap's photo x depends on its column only and its y on its row only,
    // so each bilinear cell is worked out once (`sample_bilinear` per tap gives the same bits).
    let tap = |k: usize| (k / taps) as f32 + ((k % taps) as f32 + 0.5) / taps as f32;
    let columns: Vec<_> =
        (0..resolution * taps).map(|k| bilinear_cell(transform.inverse(Vec2::new(tap(k), 0.0)).x)).collect();
    let row_cells: Vec<_> =
        (0..resolution * taps).map(|k| bilinear_cell(transform.inverse(Vec2::new(0.0, tap(k))).y)).collect();
    // The output columns and rows whose taps read a pixel of the person's box; the rest stay 0.
    let reads = |cells: &[Option<(i64, f32)>], lo: usize, hi: usize| -> Option<(usize, usize)> {
        let hit = |k: usize| {
            cells[k * taps..(k + 1) * taps].iter().flatten().any(|&(i, _)| i + 1 >= lo as i64 && i <= hi as i64)
        };
        let first = (0..resolution).find(|&k| hit(k))?;
        let last = (first..resolution).rev().find(|&k| hit(k))?;
        Some((first, last))
    };
    let frame = (transform.forward(Vec2::ZERO), transform.forward(Vec2::new(w as f32, h as f32)));
    let (Some((col_lo, col_hi)), Some((row_lo, row_hi))) = (reads(&columns, z0, z1), reads(&row_cells, q0, q1)) else {
        return Ok(NormalisedInput { rgb: out_rgb, mask: out_mask, transform, frame });
    };
    let rows = out_rgb.data.par_chunks_mut(resolution).zip(out_mask.data.par_chunks_mut(resolution));
    rows.enumerate().skip(row_lo).take(row_hi + 1 - row_lo).for_each(|(row, (rgb_row, mask_row))| {
        let row_taps = &row_cells[row * taps..(row + 1) * taps];
        for col in col_lo..=col_hi {
            let mut acc_rgb = Vec3::ZERO;
            let mut acc_m = 0.0;
            for y in row_taps.iter().flatten() {
                for x in columns[col * taps..(col + 1) * taps].iter().flatten() {
                    acc_rgb += sample_bilinear_cell(&premultiplied, *x, *y, Vec3::ZERO);
                    acc_m += sample_bilinear_cell(mask, *x, *y, 0.0);
                }
            }
            let n = (taps * taps) as f32;
            rgb_row[col] = acc_rgb / n;
            mask_row[col] = (acc_m / n).clamp(0.0, 1.0);
        }
    });
    Ok(NormalisedInput { rgb: out_rgb, mask: out_mask, transform, frame })
}

/// Width of the mask's rim whose colours [`interior_colours_at_the_rim`] replaces, as a fraction of the
/// resolution (2 px at 512²: 1 px left a blue band along Grace Hopper's coat seen from the side, 2 and 3 px none).
/// What it costs at the views near the photo is in docs/rendering.md.
pub const RIM_FRACTION: f32 = 2.0 / 512.0;

/// `input` with the colours of the mask's rim replaced by colours from further in, premultiplied by each pixel's
/// own mask; the mask is unchanged. The rim is the mask pixels (`mask >= 0.5`) within `rim` steps (4-neighbour,
/// `rim` rounded up) of a pixel outside it, and the partly covered pixels outside it. Rings are refilled from the
/// inside out: each rim pixel takes the mean colour of its 8 neighbours one ring deeper (or in the interior), which
/// carries the interior's colour out to the outline. A part with no interior of its own (thinner than two rims: a
/// finger, a tripod leg) spreads its middle ring's colour instead, never another part's. The grid's own border is
/// not an outside (a person it cuts continues there); the padding around a photo that does not fill the grid is
/// (mask 0), so a cut at the photo's edge inside the grid is refilled like an outline. Linear in the pixels (about
/// 6 ms at 512²); 8-neighbour rings
/// took a wider band and cost the yaw-0 view more (docs/rendering.md).
pub fn interior_colours_at_the_rim(mut input: NormalisedInput, rim: f32) -> NormalisedInput {
    let (w, h) = (input.mask.width, input.mask.height);
    let rings = rim.ceil().clamp(0.0, 254.0) as u8;
    if w == 0 || h == 0 || rings == 0 {
        return input;
    }
    let mask = &input.mask.data;
    // Ring of every pixel: 0 outside the mask, 1..=rings on the rim, u8::MAX in the interior.
    const INTERIOR: u8 = u8::MAX;
    let mut ring: Vec<u8> = mask.iter().map(|&m| if m >= 0.5 { INTERIOR } else { 0 }).collect();
    let mut layers: Vec<Vec<usize>> = Vec::with_capacity(rings as usize);
    // The first ring: the mask pixels with a 4-neighbour outside it (found from the mask's side: a person covers
    // less of the grid than the background does).
    let first: Vec<usize> =
        (0..w * h).filter(|&i| ring[i] == INTERIOR && neighbours4(i, w, h).any(|j| ring[j] == 0)).collect();
    for &i in &first {
        ring[i] = 1;
    }
    layers.push(first);
    for k in 2..=rings {
        let mut next = Vec::new();
        for &i in layers.last().unwrap_or(&Vec::new()) {
            for j in neighbours4(i, w, h) {
                if ring[j] == INTERIOR {
                    ring[j] = k;
                    next.push(j);
                }
            }
        }
        layers.push(next);
    }
    let straight = |c: Vec3, m: f32| if m > 0.0 { c / m } else { Vec3::ZERO };
    let rgb = &mut input.rgb.data;
    // From the innermost ring out, then the partly covered pixels outside: the mean straight colour of the
    // neighbours deeper in (already refilled).
    let refill = |i: usize, deeper: &dyn Fn(u8) -> bool, rgb: &mut [Vec3]| {
        let (mut sum, mut n) = (Vec3::ZERO, 0.0f32);
        for j in neighbours8(i, w, h) {
            if deeper(ring[j]) && mask[j] > 0.0 {
                sum += straight(rgb[j], mask[j]);
                n += 1.0;
            }
        }
        if n > 0.0 {
            rgb[i] = sum / n * mask[i];
        }
    };
    for (k, layer) in layers.iter().enumerate().rev() {
        let k = k as u8 + 1;
        for &i in layer {
            refill(i, &|r| r > k, rgb);
        }
    }
    for i in (0..w * h).filter(|&i| mask[i] > 0.0 && mask[i] < 0.5) {
        refill(i, &|r| r > 0, rgb);
    }
    input
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rect_mask(w: usize, h: usize, c0: usize, c1: usize, r0: usize, r1: usize) -> GrayImage {
        Image::from_fn(w, h, |c, r| if (c0..=c1).contains(&c) && (r0..=r1).contains(&r) { 1.0 } else { 0.0 })
    }

    #[test]
    fn normalise_is_the_mean_of_bilinear_samples_of_the_premultiplied_photo() {
        use crate::buffer::sample_bilinear;
        // A person 300 px tall shrunk to a 64 px grid (six taps a side) and one 60 px tall grown to a 128 px grid
        // (one tap), each against the definition sampled per tap at every output pixel. The second mask also has
        // faint pixels (under the 0.5 that sets the scale) away from the person: they are drawn too.
        let mut faint = rect_mask(90, 70, 30, 60, 5, 64);
        *faint.get_mut(15, 3) = 0.2;
        *faint.get_mut(75, 66) = 0.05;
        for (w, h, mask, res) in [(200, 330, rect_mask(200, 330, 40, 150, 10, 309), 64), (90, 70, faint, 128)] {
            let rgb = Image::from_fn(w, h, |c, r| Vec3::new(c as f32 / w as f32, r as f32 / h as f32, 0.3));
            let out = normalise(&rgb, &mask, res).unwrap();
            let t = out.transform;
            let taps = ((1.0 / t.scale).ceil() as usize).clamp(1, 8);
            let premultiplied =
                Image { width: w, height: h, data: rgb.data.iter().zip(&mask.data).map(|(c, m)| *c * *m).collect() };
            for (row, col) in (0..res).flat_map(|row| (0..res).map(move |col| (row, col))) {
                let (mut acc_rgb, mut acc_m) = (Vec3::ZERO, 0.0);
                for j in 0..taps {
                    for i in 0..taps {
                        let q = Vec2::new(
                            col as f32 + (i as f32 + 0.5) / taps as f32,
                            row as f32 + (j as f32 + 0.5) / taps as f32,
                        );
                        let p = t.inverse(q);
                        acc_rgb += sample_bilinear(&premultiplied, p.x, p.y, Vec3::ZERO);
                        acc_m += sample_bilinear(&mask, p.x, p.y, 0.0);
                    }
                }
                let n = (taps * taps) as f32;
                assert_eq!(taps, if res == 64 { 6 } else { 1 });
                assert_eq!(*out.rgb.get(col, row), acc_rgb / n, "({col}, {row}), {taps} taps");
                assert_eq!(*out.mask.get(col, row), (acc_m / n).clamp(0.0, 1.0), "({col}, {row})");
            }
        }
    }

    #[test]
    fn the_rim_takes_the_colour_from_further_in_and_thin_parts_keep_theirs() {
        // A 20 x 20 square (red inside, a 2-pixel blue rim, the top-left pixel half covered, a pixel beside it a
        // quarter covered) and, far from it, a 3-pixel-wide green strip (thinner than two rims: no interior of its
        // own, but its own colour).
        let (red, blue, green) = (Vec3::X, Vec3::Z, Vec3::Y);
        let mask = Image::from_fn(40, 40, |c, r| match (c, r) {
            (10, 10) => 0.5,
            (9, 15) => 0.25,
            (10..=29, 10..=29) | (35..=37, 5..=35) => 1.0,
            _ => 0.0,
        });
        let straight = Image::from_fn(40, 40, |c, r| {
            if c >= 35 {
                green
            } else if (12..=27).contains(&c) && (12..=27).contains(&r) {
                red
            } else {
                blue
            }
        });
        let rgb = Image::from_fn(40, 40, |c, r| *straight.get(c, r) * *mask.get(c, r));
        let input = NormalisedInput::in_source_view(rgb.clone(), mask.clone());
        let out = interior_colours_at_the_rim(input, 2.0);
        let full = NormalisedInput::in_source_view(Image::new(6, 6, blue), Image::new(6, 6, 1.0));
        assert_eq!(interior_colours_at_the_rim(full, 2.0).rgb.data, vec![blue; 36]);
        assert_eq!(out.mask, mask, "the mask is kept");
        for r in 0..40 {
            for c in 0..40 {
                let (m, got) = (*mask.get(c, r), *out.rgb.get(c, r));
                let want = if m == 0.0 {
                    Vec3::ZERO
                } else if c >= 35 {
                    green
                } else {
                    red * m
                };
                assert!((got - want).abs().max_element() < 1e-6, "({c}, {r}): {got} instead of {want}");
            }
        }
        // Nothing inside: returned as it is. A mask with nothing outside has no rim either.
        let empty = NormalisedInput::in_source_view(Image::new(8, 8, Vec3::ZERO), Image::new(8, 8, 0.0));
        assert_eq!(interior_colours_at_the_rim(empty, 2.0).rgb.data, vec![Vec3::ZERO; 64]);
    }

    #[test]
    fn a_standing_person_spans_1_8_units_and_is_centred() {
        // 300x200 photo, person rectangle 20 wide and 100 tall, off-centre.
        let mask = rect_mask(300, 200, 40, 59, 50, 149);
        let rgb = Image::new(300, 200, Vec3::new(0.5, 0.4, 0.3));
        let n = normalise(&rgb, &mask, 512).unwrap();
        assert!((n.transform.scale - 0.9 * 512.0 / 100.0).abs() < 1e-4);
        // Rows covered by the mask: 0.9 of 512 = 460.8 pixels, centred.
        let rows: Vec<usize> = (0..512).filter(|&r| *n.mask.get(256, r) > 0.5).collect();
        let span = rows.len() as f32;
        assert!((span - 460.8).abs() <= 2.0, "{span}");
        let mid = (rows[0] + rows[rows.len() - 1] + 1) as f32 / 2.0;
        assert!((mid - 256.0).abs() <= 1.0, "{mid}");
        // Premultiplied: colour inside equals the straight colour, outside zero.
        assert!((*n.rgb.get(256, 256) - Vec3::new(0.5, 0.4, 0.3)).length() < 1e-5);
        assert_eq!(*n.rgb.get(5, 5), Vec3::ZERO);
        // The transform maps the photo's mask centre to the source centre.
        let c = n.transform.forward(Vec2::new(50.0, 100.0));
        assert!((c - Vec2::splat(256.0)).length() < 1e-3);
        // The photo's frame: its corners through the transform (taller than the source view here).
        assert_eq!(n.frame.0, n.transform.forward(Vec2::ZERO));
        assert!((n.frame.1.y - n.frame.0.y - 200.0 * n.transform.scale).abs() < 1e-3);
    }

    #[test]
    fn wide_person_fits_the_width() {
        let mask = rect_mask(400, 400, 0, 359, 100, 139);
        let rgb = Image::new(400, 400, Vec3::ONE);
        let n = normalise(&rgb, &mask, 256).unwrap();
        assert!((n.transform.scale - 0.98 * 256.0 / 360.0).abs() < 1e-5);
    }

    #[test]
    fn degenerate_masks_are_refused_clearly() {
        let rgb = Image::new(100, 100, Vec3::ONE);
        assert_eq!(normalise(&rgb, &Image::new(100, 100, 0.0), 64).unwrap_err(), InputError::EmptyMask);
        assert!(matches!(normalise(&rgb, &Image::new(100, 100, 1.0), 64), Err(InputError::FullMask { .. })));
        let speck = rect_mask(100, 100, 10, 12, 10, 12);
        assert!(matches!(normalise(&rgb, &speck, 64), Err(InputError::PersonTooSmall { .. })));
        let mut bad = rgb.clone();
        bad.set(3, 3, Vec3::NAN);
        assert_eq!(normalise(&bad, &rect_mask(100, 100, 10, 50, 10, 90), 64).unwrap_err(), InputError::NonFinite);
        assert!(normalise(&rgb, &Image::new(10, 10, 1.0), 64).is_err());
    }

    #[test]
    fn one_pixel_limb_survives_downscaling_as_partial_coverage() {
        // A tall person with a one-pixel-wide vertical line (a limb) in a large photo.
        let mut mask = rect_mask(1000, 1000, 450, 549, 50, 949);
        for r in 100..900 {
            mask.set(700, r, 1.0);
        }
        let rgb = Image::new(1000, 1000, Vec3::ONE);
        let n = normalise(&rgb, &mask, 256).unwrap();
        let q = n.transform.forward(Vec2::new(700.5, 500.0));
        let v = *n.mask.get(q.x as usize, q.y as usize);
        assert!(v > 0.05 && v < 0.9, "thin limb kept as partial coverage: {v}");
        assert!(n.mask.data.iter().all(|v| v.is_finite()));
    }
}
