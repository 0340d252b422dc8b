//! Compositing: the person over an equirectangular panorama by spherical projection (VR), or as a
//! premultiplied alpha layer for passthrough (AR). Only what the mode needs is computed: AR touches no panorama.

use glam::{Affine3A, Vec3, Vec4};
use rayon::prelude::*;

use crate::buffer::{Image, RgbImage, RgbaImage};
use crate::geometry::{Camera, Fov};
use crate::io::environment::Environment;

mod frame;

pub use frame::RenderedFrame;

/// Vertical field of view (degrees) of the virtual viewer used for the panorama behind orthographic renders.
pub const VIEWER_FOV_DEG: f32 = 60.0;

/// Output mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Default)]
pub enum Mode {
    /// Virtual reality: the person in a 360-degree panorama.
    #[default]
    Vr,
    /// Augmented reality: the person alone, as a premultiplied alpha layer over passthrough.
    Ar,
}

/// The camera whose rays pick the panorama behind a render: a perspective camera itself, or for an orthographic
/// (orbit) camera a pinhole viewer with the same orientation and a [`VIEWER_FOV_DEG`] vertical field of view.
pub fn background_camera(camera: &Camera) -> Camera {
    if camera.is_orthographic() {
        let rotation_only = Affine3A::from_mat3(camera.view_from_world.matrix3.into());
        let aspect = camera.width as f32 / camera.height.max(1) as f32;
        let fov = Fov::symmetric(VIEWER_FOV_DEG.to_radians(), aspect);
        let world_from_view = rotation_only.inverse();
        let orientation = glam::Quat::from_mat3a(&world_from_view.matrix3);
        Camera::perspective(Vec3::ZERO, orientation, fov, 0.01, camera.width, camera.height)
    } else {
        *camera
    }
}

/// Columns per span of the panorama lookup in [`compose_vr`]: panorama coordinates are computed exactly at span
/// ends and interpolated linearly inside.
pub const PANORAMA_SPAN: usize = 8;

/// Spans whose panorama row `v` lies within this distance of a pole are computed exactly per pixel (there `u`
/// turns fast and linear interpolation would bend).
const POLE_MARGIN: f32 = 0.1;

/// Largest deviation (texels) between the exact panorama coordinates at a span's middle pixel and the linear
/// interpolation of its ends for which the span is interpolated; beyond it (wide fields of view at low
/// resolution) the span is computed per pixel.
const SPAN_TOLERANCE_TEXELS: f32 = 0.02;

/// How many times a span that cannot be interpolated whole (it crosses the longitude wrap, comes near a pole, or
/// bends) is halved before its pixels are looked up exactly: [`PANORAMA_SPAN`] = 8 columns become spans of 4, then
/// of 2 (whose two pixels are both exact ends), so only the parts of a span next to the wrap or the bend pay a
/// lookup per pixel.
const SPAN_SPLITS: u32 = 2;

/// VR composite: `person.rgb + (1 - person.a) * environment(ray)` per pixel, in linear RGB. The panorama is
/// sampled only where the person does not fully cover the pixel.
///
/// The panorama coordinates of a view ray are a smooth function of the pixel, so they are computed exactly every
/// [`PANORAMA_SPAN`] columns (and at the middle, as a check) and interpolated in between: four arc tangents per
/// span instead of sixteen. A span that crosses the longitude wrap, comes near a pole, or bends by more than
/// `SPAN_TOLERANCE_TEXELS` at its middle is halved (its middle is already exact) and each half tested the same way
/// — a half with no pole margin, its own middle deciding — down to two pixels, which are looked up exactly; a
/// lookup moves by at most about that tolerance (tested against the exact path, with its PSNR).
pub fn compose_vr(person: &RgbaImage, environment: &Environment, camera: &Camera) -> RgbImage {
    let mut out = Image::new(person.width, person.height, Vec3::ZERO);
    compose_vr_rows(person, environment, camera, SPAN_SPLITS, &mut out.data, |c| c);
    out
}

/// [`compose_vr`] written straight into `out` as opaque linear RGBA (`alpha = 1`), the layout of an eye's result
/// buffer: `out` is resized to the person's pixel count (no allocation when it already has it) and overwritten.
pub fn compose_vr_rgba_into(person: &RgbaImage, environment: &Environment, camera: &Camera, out: &mut Vec<Vec4>) {
    out.resize(person.width * person.height, Vec4::ZERO);
    compose_vr_rows(person, environment, camera, SPAN_SPLITS, out, |c| c.extend(1.0));
}

/// The composite of [`compose_vr`] into `out` (`person`'s size, row-major), each colour stored through `store`;
/// non-interpolable spans are halved up to `splits` times before the per-pixel lookup.
fn compose_vr_rows<T: Send>(
    person: &RgbaImage,
    environment: &Environment,
    camera: &Camera,
    splits: u32,
    out: &mut [T],
    store: impl Fn(Vec3) -> T + Sync,
) {
    let rays = background_camera(camera).ray_grid();
    let w = person.width;
    let panorama = environment.lookup();
    let texels = panorama.size();
    out.par_chunks_mut(w.max(1)).zip(person.data.par_chunks(w.max(1))).enumerate().for_each(
        |(row, (out_row, person_row))| {
            let y = row as f32 + 0.5;
            // The lookup normalises the direction itself.
            let uv_at = |col: usize| panorama.uv(rays.direction_unnormalised(col as f32 + 0.5, y));
            let mut uvs = [(0.0f32, 0.0f32); PANORAMA_SPAN];
            let row_len = out_row.len().min(person_row.len());
            let mut start = 0;
            let mut uv_start = None;
            while start < row_len {
                let end = (start + PANORAMA_SPAN).min(row_len);
                let span = &person_row[start..end];
                let opaque = span.iter().all(|p| p.w >= 1.0 && p.is_finite());
                if opaque {
                    for (o, p) in out_row[start..end].iter_mut().zip(span) {
                        *o = store(p.truncate().max(Vec3::ZERO));
                    }
                    uv_start = None;
                    start = end;
                    continue;
                }
                let uv0 = uv_start.unwrap_or_else(|| uv_at(start));
                let uv1 = uv_at(end);
                let ends = SpanEnds { start, end, uv0, uv1 };
                span_uvs(&uv_at, texels, ends, POLE_MARGIN, splits, &mut uvs[..end - start]);
                for ((o, p), &(u, v)) in out_row[start..end].iter_mut().zip(span).zip(&uvs) {
                    let a = if p.w.is_finite() { p.w.clamp(0.0, 1.0) } else { 0.0 };
                    let fg = if p.is_finite() { p.truncate().max(Vec3::ZERO) } else { Vec3::ZERO };
                    *o = store(if a >= 1.0 { fg } else { fg + panorama.sample_uv(u, v) * (1.0 - a) });
                }
                uv_start = Some(uv1);
                start = end;
            }
        },
    );
}

/// A span of a row, pixels `start..end`, with the exact panorama coordinates at `start` and at `end` (the first
/// pixel after it).
#[derive(Clone, Copy)]
struct SpanEnds {
    start: usize,
    end: usize,
    uv0: (f32, f32),
    uv1: (f32, f32),
}

/// The panorama coordinates of every pixel of a span into `out` (one per pixel): interpolated between its exact
/// ends when it is smooth (no longitude wrap, `pole_margin` away from the poles, its middle pixel within
/// `SPAN_TOLERANCE_TEXELS` of the interpolation), else its halves the same way with no pole margin, up to
/// `splits` times; then exact per pixel. `texels`: the panorama's size.
fn span_uvs(
    uv_at: &impl Fn(usize) -> (f32, f32),
    texels: (f32, f32),
    s: SpanEnds,
    pole_margin: f32,
    splits: u32,
    out: &mut [(f32, f32)],
) {
    let n = s.end - s.start;
    let ((u0, v0), (u1, v1)) = (s.uv0, s.uv1);
    let exact = |out: &mut [(f32, f32)]| {
        for (k, o) in out.iter_mut().enumerate() {
            *o = if k == 0 { s.uv0 } else { uv_at(s.start + k) };
        }
    };
    if n <= 2 {
        return exact(out);
    }
    let mid = s.start + n / 2;
    let uv_mid = uv_at(mid);
    let inv_n = 1.0 / n as f32;
    let smooth = (u1 - u0).abs() < 0.25 && v0.min(v1) > pole_margin && v0.max(v1) < 1.0 - pole_margin && {
        // The curvature test: the middle pixel's exact coordinates against the interpolation.
        let t = (n / 2) as f32 * inv_n;
        let (um, vm) = uv_mid;
        ((um - (u0 + (u1 - u0) * t)).abs() * texels.0).max((vm - (v0 + (v1 - v0) * t)).abs() * texels.1)
            < SPAN_TOLERANCE_TEXELS
    };
    if smooth {
        for (k, o) in out.iter_mut().enumerate() {
            let t = k as f32 * inv_n;
            *o = (u0 + (u1 - u0) * t, v0 + (v1 - v0) * t);
        }
        return;
    }
    if splits == 0 {
        return exact(out);
    }
    let (left, right) = out.split_at_mut(n / 2);
    span_uvs(uv_at, texels, SpanEnds { end: mid, uv1: uv_mid, ..s }, 0.0, splits - 1, left);
    span_uvs(uv_at, texels, SpanEnds { start: mid, uv0: uv_mid, ..s }, 0.0, splits - 1, right);
}

/// AR layer: the person as premultiplied linear RGBA, sanitised (finite, alpha in `[0, 1]`, colour <= alpha)
/// so a compositor blending it with passthrough never sees an invalid premultiplied pixel.
pub fn compose_ar(person: &RgbaImage) -> RgbaImage {
    person.map(|p| ar_pixel(*p))
}

/// [`compose_ar`] written straight into `out` (resized to the person's pixel count, overwritten): the layout of an
/// eye's result buffer.
pub fn compose_ar_into(person: &RgbaImage, out: &mut Vec<Vec4>) {
    out.clear();
    out.extend(person.data.iter().map(|p| ar_pixel(*p)));
}

/// One pixel of the AR layer ([`compose_ar`]).
fn ar_pixel(p: Vec4) -> Vec4 {
    if !p.is_finite() {
        return Vec4::ZERO;
    }
    let a = p.w.clamp(0.0, 1.0);
    p.truncate().clamp(Vec3::ZERO, Vec3::splat(a)).extend(a)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gradient_env() -> Environment {
        Environment {
            image: Image::from_fn(64, 32, |c, r| Vec3::new(c as f32 / 64.0, r as f32 / 32.0, 0.25)),
            yaw: 0.0,
        }
    }

    #[test]
    fn opaque_person_hides_the_panorama_and_transparent_shows_it() {
        let env = gradient_env();
        let cam = Camera::orbit(0.0, 0.0, 8, 8);
        let mut person = Image::new(8, 8, Vec4::ZERO);
        person.set(3, 3, Vec4::new(0.2, 0.4, 0.6, 1.0));
        person.set(4, 4, Vec4::new(0.1, 0.1, 0.1, 0.5));
        let out = compose_vr(&person, &env, &cam);
        assert_eq!(*out.get(3, 3), Vec3::new(0.2, 0.4, 0.6));
        let bg = background_camera(&cam);
        let expect_bg = env.sample(bg.ray(4.5, 4.5).direction);
        assert!((*out.get(4, 4) - (Vec3::splat(0.1) + expect_bg * 0.5)).length() < 1e-6);
        // Centre of a yaw-0 view looks down -z: the panorama centre.
        let centre = env.sample(bg.ray(4.0, 4.0).direction);
        assert!((centre - env.sample_uv(0.5, 0.5)).length() < 1e-5);
    }

    #[test]
    fn background_follows_the_orbit_and_poles_are_finite() {
        for (yaw, pitch) in [(180.0f32, 0.0f32), (0.0, 90.0), (0.0, -90.0), (37.0, 89.9)] {
            let cam = Camera::orbit(yaw, pitch, 16, 16);
            let bg = background_camera(&cam);
            let d = bg.ray(8.0, 8.0).direction;
            // The centre ray points from the camera toward the body: opposite the camera's position direction.
            let cam_dir = Camera::orbit_rotation(yaw, pitch).inverse().transform_vector3(Vec3::Z);
            assert!((d + cam_dir).length() < 1e-4, "yaw {yaw} pitch {pitch}: {d} vs {cam_dir}");
            let out = compose_vr(&Image::new(16, 16, Vec4::ZERO), &gradient_env(), &cam);
            assert!(out.data.iter().all(|v| v.is_finite()));
        }
    }

    /// The per-pixel exact composite [`compose_vr`] approximates.
    fn compose_vr_exact(person: &RgbaImage, environment: &Environment, camera: &Camera) -> RgbImage {
        let rays = background_camera(camera).ray_grid();
        Image::from_fn(person.width, person.height, |col, row| {
            let p = *person.get(col, row);
            let a = p.w.clamp(0.0, 1.0);
            let d = rays.direction_unnormalised(col as f32 + 0.5, row as f32 + 0.5);
            p.truncate().max(Vec3::ZERO) + if a >= 1.0 { Vec3::ZERO } else { environment.sample(d) * (1.0 - a) }
        })
    }

    #[test]
    fn span_interpolation_stays_within_a_fiftieth_of_a_texel() {
        // A high-frequency panorama (period 4 texels: a 0.02-texel shift changes a value by at most ~0.016).
        let (pw, ph) = (512, 256);
        let env = Environment {
            image: Image::from_fn(pw, ph, |c, r| {
                let f = |x: f32| 0.5 + 0.5 * (x * std::f32::consts::FRAC_PI_2).sin();
                Vec3::new(f(c as f32), f(r as f32), f(c as f32 + r as f32))
            }),
            yaw: 0.4,
        };
        let eye = |fov: f32, size: usize, pitch: f32| {
            let q = glam::Quat::from_rotation_y(2.5) * glam::Quat::from_rotation_x(pitch);
            Camera::perspective(Vec3::new(0.1, 1.6, 0.3), q, Fov::symmetric(fov, 1.0), 0.05, size, size)
        };
        let mut cameras = Vec::new();
        for (yaw, pitch) in [(0.0, 0.0), (90.0, 20.0), (180.0, 0.0), (270.0, -45.0), (33.0, 89.9), (0.0, 90.0)] {
            cameras.push(Camera::orbit(yaw, pitch, 256, 256));
        }
        cameras.push(Camera::orbit(200.0, -90.0, 256, 256));
        for (fov, size, pitch) in [(100f32, 512, 0.0f32), (100.0, 48, 0.3), (20.0, 256, -1.2), (1.7, 64, 1.5)] {
            cameras.push(eye(fov.to_radians(), size, pitch));
        }
        let mut interpolated_somewhere = false;
        let mut worst_psnr = f64::INFINITY;
        for cam in cameras {
            // Transparent everywhere but a few opaque and half-transparent pixels.
            let person = Image::from_fn(cam.width, cam.height, |c, r| match (c / 8 + r) % 7 {
                0 => Vec4::new(0.2, 0.3, 0.4, 1.0),
                1 => Vec4::new(0.1, 0.1, 0.1, 0.5),
                _ => Vec4::ZERO,
            });
            let fast = compose_vr(&person, &env, &cam);
            let exact = compose_vr_exact(&person, &env, &cam);
            let worst =
                fast.data.iter().zip(&exact.data).map(|(a, b)| (*a - *b).abs().max_element()).fold(0.0, f32::max);
            assert!(worst < 0.02, "{:?} {}x{}: off by {worst}", cam.projection, cam.width, cam.height);
            interpolated_somewhere |= worst > 0.0;
            worst_psnr = worst_psnr.min(psnr(&fast, &exact));
        }
        assert!(interpolated_somewhere, "the span interpolation never ran");
        println!("span interpolation against the exact lookup: PSNR >= {worst_psnr:.1} dB on every camera");
        assert!(worst_psnr > 50.0, "PSNR {worst_psnr:.1} dB");
    }

    /// PSNR (dB, peak 1) of `a` against `b`, over the three channels.
    fn psnr(a: &RgbImage, b: &RgbImage) -> f64 {
        let se: f64 = a.data.iter().zip(&b.data).map(|(x, y)| ((*x - *y).length_squared()) as f64).sum();
        let mse = se / (3 * a.data.len().max(1)) as f64;
        if mse == 0.0 {
            f64::INFINITY
        } else {
            -10.0 * mse.log10()
        }
    }

    /// Eyes looking ahead (spans bend at the edges of a wide view), across the longitude wrap and at the poles: the
    /// halved spans against the per-pixel fallback, PSNR against the exact lookup and the fastest of 31 alternated
    /// runs (printed; a release build with `--nocapture` gives the figures of docs/performance.md).
    #[test]
    fn halving_spans_keeps_the_exact_lookup_and_saves_lookups() {
        let env = Environment::default_embedded();
        let (w, h) = (342, 384);
        let fov = Fov::symmetric(std::f32::consts::FRAC_PI_2, w as f32 / h as f32);
        let person = Image::new(w, h, Vec4::ZERO);
        let eye = |yaw: f32, pitch: f32| {
            let q = glam::Quat::from_rotation_y(yaw) * glam::Quat::from_rotation_x(pitch);
            Camera::perspective(Vec3::new(0.0, 1.6, 0.0), q, fov, 0.05, w, h)
        };
        let cameras = [
            ("ahead", eye(0.0, 0.0)),
            ("behind", eye(std::f32::consts::PI, 0.0)),
            ("up", eye(0.3, 1.2)),
            ("down", eye(2.0, -1.4)),
        ];
        for (name, cam) in cameras {
            let exact = compose_vr_exact(&person, &env, &cam);
            let mut out = [Image::new(w, h, Vec3::ZERO), Image::new(w, h, Vec3::ZERO)];
            let mut times = [Vec::new(), Vec::new()];
            for _ in 0..31 {
                for (k, splits) in [0, SPAN_SPLITS].into_iter().enumerate() {
                    let t = std::time::Instant::now();
                    compose_vr_rows(&person, &env, &cam, splits, &mut out[k].data, |c| c);
                    times[k].push(t.elapsed());
                }
            }
            let fastest = |t: &mut Vec<std::time::Duration>| t.iter().min().map_or(0.0, |d| d.as_secs_f64() * 1e3);
            let (unsplit, split) = (psnr(&out[0], &exact), psnr(&out[1], &exact));
            println!(
                "{name}: per-pixel fallback {:.2} ms ({unsplit:.1} dB), halved spans {:.2} ms ({split:.1} dB)",
                fastest(&mut times[0]),
                fastest(&mut times[1])
            );
            assert!(split > 50.0, "{name}: {split:.1} dB");
        }
        // The RGBA form is the same composite.
        let cam = eye(0.3, 1.2);
        let rgb = compose_vr(&person, &env, &cam);
        let mut rgba = vec![Vec4::ONE; 3];
        compose_vr_rgba_into(&person, &env, &cam, &mut rgba);
        assert!(rgba.len() == rgb.data.len() && rgba.iter().zip(&rgb.data).all(|(a, b)| *a == b.extend(1.0)));
    }

    #[test]
    fn ar_layer_is_valid_premultiplied() {
        let person = Image::from_fn(3, 1, |c, _| match c {
            0 => Vec4::new(0.9, 0.2, 0.1, 0.5),
            1 => Vec4::new(f32::NAN, 0.0, 0.0, 1.0),
            _ => Vec4::new(0.3, 0.3, 0.3, 1.5),
        });
        let ar = compose_ar(&person);
        assert_eq!(*ar.get(0, 0), Vec4::new(0.5, 0.2, 0.1, 0.5));
        assert_eq!(*ar.get(1, 0), Vec4::ZERO);
        assert_eq!(ar.get(2, 0).w, 1.0);
        let mut into = vec![Vec4::ONE; 7];
        compose_ar_into(&person, &mut into);
        assert_eq!(into, ar.data);
    }
}
