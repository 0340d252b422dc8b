//! Host-side packing of uploads: G-buffers as `vec4`, half floats as GLSL's `packHalf2x16`, and the mean colour
//! the warp falls back to.

use glam::{Vec3, Vec4};

use crate::buffer::RgbaImage;
use crate::geometry::raster::{GBuffer, BACKGROUND_DEPTH};

/// Mean un-premultiplied colour of the person in a premultiplied source (`sum c / sum min(m, 1)` where `m > 0`),
/// as the CPU warp's fallback when a view sees nothing of the photo; mid grey without a person.
pub(super) fn mean_masked(color: &RgbaImage) -> Vec3 {
    let (sum, w) = color.data.iter().fold((Vec3::ZERO, 0.0f32), |(s, w), c| {
        if c.w > 0.0 {
            (s + c.truncate(), w + c.w.min(1.0))
        } else {
            (s, w)
        }
    });
    if w > 0.0 {
        (sum / w).clamp(Vec3::ZERO, Vec3::ONE)
    } else {
        Vec3::splat(0.5)
    }
}

/// A G-buffer as `vec4(normal, depth)` per pixel with [`BACKGROUND_DEPTH`] where not covered.
pub(super) fn pack_geometry(g: &GBuffer) -> Vec<Vec4> {
    (0..g.mask.len())
        .map(|i| if g.mask[i] { g.normal[i].extend(g.depth[i]) } else { Vec4::new(0.0, 0.0, 0.0, BACKGROUND_DEPTH) })
        .collect()
}

/// Packs two f32 into IEEE half floats (round to nearest even), as GLSL `packHalf2x16`.
pub fn pack_half2(a: f32, b: f32) -> u32 {
    u32::from(f32_to_f16(a)) | (u32::from(f32_to_f16(b)) << 16)
}

/// f32 -> IEEE 754 binary16 bits, round to nearest even; overflow gives infinity, NaN stays NaN.
pub fn f32_to_f16(x: f32) -> u16 {
    let bits = x.to_bits();
    let sign = ((bits >> 16) & 0x8000) as u16;
    let exp = ((bits >> 23) & 0xff) as i32;
    let man = bits & 0x7f_ffff;
    if exp == 0xff {
        return sign | 0x7c00 | if man != 0 { 0x200 } else { 0 };
    }
    let e = exp - 127 + 15;
    if e >= 0x1f {
        return sign | 0x7c00;
    }
    if e <= 0 {
        // Subnormal half (or zero).
        if e < -10 {
            return sign;
        }
        let m = man | 0x80_0000;
        let shift = (14 - e) as u32;
        let half = m >> shift;
        let rem = m & ((1 << shift) - 1);
        let halfway = 1 << (shift - 1);
        let round = rem > halfway || (rem == halfway && half & 1 == 1);
        return sign | (half + u32::from(round)) as u16;
    }
    let half = ((e as u32) << 10) | (man >> 13);
    let rem = man & 0x1fff;
    let round = rem > 0x1000 || (rem == 0x1000 && half & 1 == 1);
    sign | (half + u32::from(round)) as u16
}

#[cfg(test)]
mod tests {
    use super::*;

    fn f16_to_f32(h: u16) -> f32 {
        let sign = if h & 0x8000 != 0 { -1.0 } else { 1.0 };
        let exp = i32::from((h >> 10) & 0x1f);
        let man = f32::from(h & 0x3ff);
        match exp {
            0 => sign * man * 2f32.powi(-24),
            0x1f => {
                if man == 0.0 {
                    sign * f32::INFINITY
                } else {
                    f32::NAN
                }
            }
            _ => sign * (1.0 + man / 1024.0) * 2f32.powi(exp - 15),
        }
    }

    #[test]
    fn half_conversion_is_exact_where_representable_and_rounds_otherwise() {
        for &v in &[0.0f32, 1.0, -2.5, 0.5, 65504.0, 6.1035156e-5, 5.9604645e-8, 0.333_251_95] {
            assert_eq!(f16_to_f32(f32_to_f16(v)), v, "{v}");
        }
        assert_eq!(f32_to_f16(1.0e6), 0x7c00);
        assert!(f16_to_f32(f32_to_f16(f32::NAN)).is_nan());
        // Relative error bound 2^-11 over [1e-4, 1]
        let mut x = 1.0e-4f32;
        while x < 1.0 {
            let r = f16_to_f32(f32_to_f16(x));
            assert!(((r - x) / x).abs() <= 1.0 / 2048.0 + 1e-7, "{x} -> {r}");
            x *= 1.0137;
        }
        // Ties to even: 1 + 2^-11 is halfway between 1 and 1 + 2^-10 -> 1.
        assert_eq!(f32_to_f16(1.0 + 1.0 / 2048.0), 0x3c00);
        assert_eq!(f32_to_f16(1.0 + 3.0 / 2048.0), 0x3c02);
    }
}
