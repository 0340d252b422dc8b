//! 360-degree environments: equirectangular JPEG/PNG photos and Radiance `.hdr` files, loaded into linear RGB
//! in display range, and sampled by world direction (spherical projection).
//!
//! Mapping (the one convention; the GPU compositor matches it): a unit world direction `d` (y up) reads
//! `u = 0.5 + atan2(d.x, -d.z) / 2pi` (looking down -z hits the panorama centre; `u` wraps) and
//! `v = acos(d.y) / pi` (0 = zenith, top row). Texel centres at `(i + 0.5) / W`. Bilinear filtering wraps
//! horizontally (no seam at the longitude wrap) and at the poles reads across the pole (the texel half a turn
//! away), so there is no pinch artefact.

use std::path::Path;

use glam::Vec3;

use crate::buffer::{floor_fast, Image, RgbImage};
use crate::io::image_io::{self, IoError};

/// The panorama embedded in the binary, used when no `--env` is given (CC0, see environments/CREDITS.md).
pub const DEFAULT_ENVIRONMENT_PNG: &[u8] = include_bytes!("../../environments/courtyard.png");

/// A loaded panorama in linear RGB, display range (HDR files are exposure-keyed and tone-mapped on load).
#[derive(Clone, Debug)]
pub struct Environment {
    /// Equirectangular image, top row = zenith, linear RGB in `[0, 1]`.
    pub image: RgbImage,
    /// Rotation of the panorama about the vertical axis (radians), applied before the lookup.
    pub yaw: f32,
}

impl Environment {
    /// Loads a panorama from a PNG/JPEG (sRGB) or Radiance `.hdr` (linear, tone-mapped here) file.
    pub fn load(path: &Path) -> Result<Self, IoError> {
        let is_hdr = path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("hdr"));
        let image = if is_hdr { load_hdr(path)? } else { image_io::load_image(path)?.rgb };
        Self::from_image(image, path)
    }

    /// The embedded default panorama.
    pub fn default_embedded() -> Self {
        let rgb = image_io::load_image_bytes(DEFAULT_ENVIRONMENT_PNG, "embedded courtyard.png")
            .expect("the embedded panorama is a valid PNG (checked by a test)")
            .rgb;
        Self { image: rgb, yaw: 0.0 }
    }

    fn from_image(image: RgbImage, path: &Path) -> Result<Self, IoError> {
        if image.width < 2 || image.height < 1 {
            return Err(IoError::Decode { path: path.to_owned(), reason: "panorama too small".into() });
        }
        let aspect = image.width as f32 / image.height as f32;
        if !(1.9..=2.1).contains(&aspect) {
            tracing::warn!(
                "{} is {}x{}, not 2:1; it is read as equirectangular anyway",
                path.display(),
                image.width,
                image.height
            );
        }
        Ok(Self { image, yaw: 0.0 })
    }

    /// Panorama texel coordinates `(u, v)` in `[0, 1]` for a world direction (need not be normalised).
    pub fn direction_to_uv(&self, d: Vec3) -> (f32, f32) {
        direction_to_uv(d, self.yaw)
    }

    /// Linear colour seen along world direction `d` (bilinear, wrap-around, pole-aware). For many lookups use
    /// [`Environment::lookup`] (the same result without per-call setup).
    pub fn sample(&self, d: Vec3) -> Vec3 {
        self.lookup().sample(d)
    }

    /// A lookup with the per-panorama constants (yaw rotation, sizes) computed once, for per-pixel loops.
    pub fn lookup(&self) -> PanoramaLookup<'_> {
        let (sin_yaw, cos_yaw) = if self.yaw == 0.0 { (0.0, 1.0) } else { self.yaw.sin_cos() };
        PanoramaLookup {
            env: self,
            sin_yaw,
            cos_yaw,
            width: self.image.width as f32,
            height: self.image.height as f32,
            interior_x: self.image.width as f32 - 1.0,
            interior_y: self.image.height as f32 - 1.0,
        }
    }

    /// Bilinear lookup at panorama coordinates (see the module docs for wrapping).
    pub fn sample_uv(&self, u: f32, v: f32) -> Vec3 {
        self.lookup().sample_uv(u, v)
    }

    /// [`Environment::sample_uv`] for any coordinates: wraps the longitude and reads across the poles. The
    /// lookup's interior fast path ([`PanoramaLookup::sample_uv`]) falls back to it near the edges.
    fn sample_uv_wrapped(&self, u: f32, v: f32) -> Vec3 {
        let img = &self.image;
        let (w, h) = (img.width as i64, img.height as i64);
        let x = u * w as f32 - 0.5;
        let y = v * h as f32 - 0.5;
        if !(x.is_finite() && y.is_finite()) {
            return Vec3::ZERO;
        }
        let (x0, y0) = (floor_fast(x), floor_fast(y));
        let (tx, ty) = (x - x0, y - y0);
        let fetch = |cx: i64, cy: i64| -> Vec3 {
            // Across a pole the row reflects and the column moves half a turn.
            let (mut cx, mut cy) = (cx, cy);
            if cy < 0 {
                cy = -1 - cy;
                cx += w / 2;
            } else if cy >= h {
                cy = 2 * h - 1 - cy;
                cx += w / 2;
            }
            let cy = cy.clamp(0, h - 1);
            let cx = cx.rem_euclid(w);
            img.data[(cy * w + cx) as usize]
        };
        let (x0, y0) = (x0 as i64, y0 as i64);
        let top = fetch(x0, y0) * (1.0 - tx) + fetch(x0 + 1, y0) * tx;
        let bottom = fetch(x0, y0 + 1) * (1.0 - tx) + fetch(x0 + 1, y0 + 1) * tx;
        top * (1.0 - ty) + bottom * ty
    }
}

/// [`Environment::sample`] with its constants precomputed: what the compositor calls once per background pixel.
#[derive(Clone, Copy, Debug)]
pub struct PanoramaLookup<'a> {
    env: &'a Environment,
    sin_yaw: f32,
    cos_yaw: f32,
    width: f32,
    height: f32,
    /// Texel coordinates below these (and at least 0) need no wrapping or pole reflection.
    interior_x: f32,
    interior_y: f32,
}

impl PanoramaLookup<'_> {
    /// Linear colour seen along world direction `d` (need not be normalised); equal to [`Environment::sample`].
    #[inline]
    pub fn sample(&self, d: Vec3) -> Vec3 {
        let (u, v) = self.uv(d);
        self.sample_uv(u, v)
    }

    /// Panorama coordinates of world direction `d` (need not be normalised); equal to [`direction_to_uv`].
    #[inline]
    pub fn uv(&self, d: Vec3) -> (f32, f32) {
        uv_rotated(d, self.sin_yaw, self.cos_yaw)
    }

    /// The panorama's size in texels, `(width, height)`.
    pub fn size(&self) -> (f32, f32) {
        (self.width, self.height)
    }

    /// Bilinear lookup at panorama coordinates; equal to [`Environment::sample_uv`].
    #[inline]
    pub fn sample_uv(&self, u: f32, v: f32) -> Vec3 {
        let x = u * self.width - 0.5;
        let y = v * self.height - 0.5;
        // Interior (almost every lookup): truncation is the floor for non-negative values; no wrap, no pole.
        if x >= 0.0 && y >= 0.0 && x < self.interior_x && y < self.interior_y {
            // Via i32: one conversion instruction (a float-to-usize cast is a long saturating sequence on x86-64).
            let (x0, y0) = (x as i32 as usize, y as i32 as usize);
            let (tx, ty) = (x - x0 as f32, y - y0 as f32);
            let w = self.env.image.width;
            let i = y0 * w + x0;
            if let (Some(top), Some(bottom)) =
                (self.env.image.data.get(i..i + 2), self.env.image.data.get(i + w..i + w + 2))
            {
                let top = top[0] * (1.0 - tx) + top[1] * tx;
                let bottom = bottom[0] * (1.0 - tx) + bottom[1] * tx;
                return top * (1.0 - ty) + bottom * ty;
            }
        }
        self.env.sample_uv_wrapped(u, v)
    }
}

/// Panorama coordinates for a world direction with the panorama rotated by `yaw` radians about +y.
pub fn direction_to_uv(d: Vec3, yaw: f32) -> (f32, f32) {
    let (s, c) = if yaw == 0.0 { (0.0, 1.0) } else { yaw.sin_cos() };
    uv_rotated(d, s, c)
}

/// [`direction_to_uv`] with the yaw given as its sine and cosine.
#[inline]
fn uv_rotated(d: Vec3, s: f32, c: f32) -> (f32, f32) {
    // Both angles are ratios of components, so `d` needs no normalisation (one square root instead of three);
    // only a zero or non-finite direction is replaced (by the panorama centre, -z).
    let big = d.abs().max_element();
    let d = if !(d.is_finite() && big > 0.0) {
        Vec3::NEG_Z
    } else if (1e-12..=1e12).contains(&big) {
        d
    } else {
        d / big // rescaled so the squares below neither underflow nor overflow
    };
    // Rotate the direction by -yaw so a positive yaw turns the panorama to the left.
    let dx = c * d.x + s * d.z;
    let dz = -s * d.x + c * d.z;
    // Multiplications by the reciprocals: a float division by a constant stays a division.
    let u = 0.5 + atan2_fast(dx, -dz) * (1.0 / std::f32::consts::TAU);
    // Polar angle from +y: acos(y / |d|) = atan2(|d_xz|, y), in [0, pi].
    let v = atan2_fast((dx * dx + dz * dz).sqrt(), d.y) * std::f32::consts::FRAC_1_PI;
    (u, v)
}

/// `y.atan2(x)` to within 2e-5 radians (0.013 texels of a 4096-wide panorama) at a fraction of libm's cost: this
/// runs for every background pixel of every VR frame. Odd minimax polynomial on `[0, 1]` (Hastings) after
/// reducing by octant; the exact libm value where both arguments vanish (the poles).
#[inline]
fn atan2_fast(y: f32, x: f32) -> f32 {
    let (ax, ay) = (x.abs(), y.abs());
    // One test for "both finite and not both (nearly) zero": the sum is NaN or infinite otherwise.
    let sum = ax + ay;
    if !(sum > 1e-30 && sum < f32::INFINITY) {
        return y.atan2(x);
    }
    let a = ax.min(ay) / ax.max(ay);
    let s = a * a;
    let mut r = a * (0.999_866 + s * (-0.330_299_5 + s * (0.180_141 + s * (-0.085_133 + s * 0.020_835_1))));
    if ay > ax {
        r = std::f32::consts::FRAC_PI_2 - r;
    }
    if x < 0.0 {
        r = std::f32::consts::PI - r;
    }
    if y < 0.0 {
        -r
    } else {
        r
    }
}

/// Inverse of [`direction_to_uv`] with zero yaw: the unit direction at panorama coordinates `(u, v)`.
pub fn uv_to_direction(u: f32, v: f32) -> Vec3 {
    let lon = (u - 0.5) * std::f32::consts::TAU;
    let lat = v * std::f32::consts::PI;
    Vec3::new(lat.sin() * lon.sin(), lat.cos(), -lat.sin() * lon.cos())
}

/// Loads a Radiance `.hdr` panorama and maps it to display range: exposure keyed so the solid-angle-weighted
/// log-average luminance becomes 0.18, then the Narkowicz ACES fit (as the shipped PNG versions were made).
pub fn load_hdr(path: &Path) -> Result<RgbImage, IoError> {
    let file = std::fs::File::open(path).map_err(|e| IoError::Read { path: path.to_owned(), source: e })?;
    let len = file.metadata().map_err(|e| IoError::Read { path: path.to_owned(), source: e })?.len();
    let decoder = image::codecs::hdr::HdrDecoder::new(std::io::BufReader::new(file))
        .map_err(|e| IoError::Decode { path: path.to_owned(), reason: e.to_string() })?;
    let meta = decoder.metadata();
    image_io::check_dimensions(path, Some(image::ImageFormat::Hdr), meta.width, meta.height, len)?;
    let img = image::DynamicImage::from_decoder(decoder)
        .map_err(|e| IoError::Decode { path: path.to_owned(), reason: e.to_string() })?
        .into_rgb32f();
    let (w, h) = (img.width() as usize, img.height() as usize);
    let raw = img.as_raw();
    let linear = Image::from_fn(w, h, |c, r| {
        let i = (r * w + c) * 3;
        let v = Vec3::new(raw[i], raw[i + 1], raw[i + 2]);
        // RGBE cannot be negative, but guard against NaN/inf from a damaged file.
        if v.is_finite() {
            v.max(Vec3::ZERO)
        } else {
            Vec3::ZERO
        }
    });
    Ok(tone_map(&linear))
}

/// Exposure (log-average luminance keyed to 0.18, weighted by solid angle) followed by the ACES fit.
pub fn tone_map(linear: &RgbImage) -> RgbImage {
    let (w, h) = (linear.width, linear.height);
    let mut sum_log = 0.0f64;
    let mut sum_w = 0.0f64;
    for r in 0..h {
        let weight = (std::f64::consts::PI * (r as f64 + 0.5) / h as f64).sin();
        for c in 0..w {
            let v = linear.get(c, r);
            let lum = crate::buffer::luminance(*v);
            sum_log += weight * (1e-6 + lum as f64).ln();
            sum_w += weight;
        }
    }
    let avg = if sum_w > 0.0 { (sum_log / sum_w).exp() } else { 1.0 };
    let exposure = (0.18 / avg.max(1e-9)) as f32;
    linear.map(|v| {
        let x = *v * (0.6 * exposure);
        let aces = (x * (x * 2.51 + 0.03)) / (x * (x * 2.43 + 0.59) + 0.14);
        aces.clamp(Vec3::ZERO, Vec3::ONE)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_atan2_is_within_2e5_radians_of_libm() {
        let mut worst = 0.0f32;
        for i in 0..20_000 {
            let t = i as f32 / 20_000.0 * std::f32::consts::TAU;
            for r in [1e-6f32, 0.3, 1.0, 250.0] {
                let (y, x) = (r * t.sin(), r * t.cos());
                worst = worst.max((atan2_fast(y, x) - y.atan2(x)).abs());
            }
        }
        assert!(worst < 2e-5, "worst error {worst}");
        // Axes and poles: exact.
        for (y, x) in [(0.0f32, 1.0f32), (1.0, 0.0), (0.0, -1.0), (-1.0, 0.0), (0.0, 0.0), (0.0, -0.0)] {
            assert!((atan2_fast(y, x) - y.atan2(x)).abs() < 1e-6, "{y} {x}");
        }
        assert!(atan2_fast(f32::NAN, 1.0).is_nan());
    }

    #[test]
    fn mapping_closed_forms() {
        let close = |a: (f32, f32), b: (f32, f32)| (a.0 - b.0).abs() < 1e-6 && (a.1 - b.1).abs() < 1e-6;
        assert!(close(direction_to_uv(Vec3::NEG_Z, 0.0), (0.5, 0.5)));
        assert!(close(direction_to_uv(Vec3::X, 0.0), (0.75, 0.5)));
        assert!(close(direction_to_uv(Vec3::NEG_X, 0.0), (0.25, 0.5)));
        assert!((direction_to_uv(Vec3::Y, 0.0).1).abs() < 1e-6);
        assert!((direction_to_uv(Vec3::NEG_Y, 0.0).1 - 1.0).abs() < 1e-6);
        // Exactly straight up or down: u is some finite value, no NaN.
        assert!(direction_to_uv(Vec3::Y, 0.0).0.is_finite());
        assert!(direction_to_uv(Vec3::ZERO, 0.0).0.is_finite());
        for &(u, v) in &[(0.1f32, 0.2f32), (0.9, 0.7), (0.5, 0.5)] {
            assert!(close(direction_to_uv(uv_to_direction(u, v), 0.0), (u, v)));
            // Unnormalised directions (tiny and huge lengths) map to the same place.
            for scale in [1e-20f32, 1e-3, 7.5, 1e20] {
                assert!(close(direction_to_uv(uv_to_direction(u, v) * scale, 0.0), (u, v)), "{u},{v} x{scale}");
            }
        }
        // Zero and non-finite directions fall back to the panorama centre.
        for d in [Vec3::ZERO, Vec3::new(f32::NAN, 0.0, -1.0), Vec3::new(0.0, f32::INFINITY, 0.0)] {
            assert!(close(direction_to_uv(d, 0.0), (0.5, 0.5)), "{d}");
        }
        // A yaw of +90 degrees turns the panorama: +x now shows what -z showed.
        let (u, _) = direction_to_uv(Vec3::X, std::f32::consts::FRAC_PI_2);
        assert!((u - 0.5).abs() < 1e-5, "{u}");
    }

    #[test]
    fn sampling_is_seamless_at_the_wrap_and_poles() {
        let w = 64;
        let h = 32;
        let env = Environment {
            image: Image::from_fn(w, h, |c, r| Vec3::new(c as f32 / w as f32, r as f32 / h as f32, 0.5)),
            yaw: 0.0,
        };
        // Just either side of the wrap (looking down +z): equal colours.
        let a = env.sample(Vec3::new(1e-4, 0.0, 1.0));
        let b = env.sample(Vec3::new(-1e-4, 0.0, 1.0));
        assert!((a - b).length() < 1e-2, "{a} {b}");
        // Around the pole, directions a hair apart give close colours.
        let p = env.sample(Vec3::new(1e-4, 1.0, 0.0));
        let q = env.sample(Vec3::new(-1e-4, 1.0, 0.0));
        assert!((p.y - q.y).abs() < 0.05);
        assert!(p.is_finite() && q.is_finite());
    }

    #[test]
    fn the_per_pixel_lookup_equals_the_general_path() {
        let (w, h) = (96, 48);
        for yaw in [0.0f32, 0.7, -2.9] {
            let env = Environment {
                image: Image::from_fn(w, h, |c, r| Vec3::new(c as f32 / w as f32, r as f32 / h as f32, (c ^ r) as f32)),
                yaw,
            };
            let lookup = env.lookup();
            let mut seed = 12345u32;
            let mut rnd = || {
                seed = seed.wrapping_mul(1664525).wrapping_add(1013904223);
                (seed >> 8) as f32 / (1u32 << 24) as f32 * 2.0 - 1.0
            };
            let mut dirs: Vec<Vec3> = (0..4000).map(|_| Vec3::new(rnd(), rnd(), rnd()) * 3.0).collect();
            // The wrap, the poles and the texel edges of the border rows and columns.
            dirs.extend([Vec3::Z, Vec3::new(1e-6, 0.0, 1.0), Vec3::Y, Vec3::NEG_Y, Vec3::new(0.01, 1.0, 0.0)]);
            dirs.extend([Vec3::new(0.0, -0.9999, 0.01), Vec3::ZERO, Vec3::splat(f32::NAN)]);
            for d in dirs {
                let (u, v) = direction_to_uv(d, yaw);
                let want = env.sample_uv_wrapped(u, v);
                assert_eq!(lookup.sample(d), want, "yaw {yaw} d {d}");
                assert_eq!(env.sample(d), want);
            }
        }
    }

    #[test]
    fn embedded_panorama_loads() {
        let env = Environment::default_embedded();
        assert_eq!(env.image.width, 2 * env.image.height);
    }

    #[test]
    fn shipped_hdr_tone_maps_into_range() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("environments/courtyard.hdr");
        let img = load_hdr(&path).unwrap();
        assert_eq!((img.width, img.height), (1024, 512));
        let mean = img.data.iter().copied().sum::<Vec3>() / img.data.len() as f32;
        assert!(img.data.iter().all(|v| v.is_finite() && v.max_element() <= 1.0));
        assert!(mean.x > 0.05 && mean.x < 0.8, "mean {mean}");
    }
}
