//! End-to-end numerical stability: the whole pipeline (normalise -> inflation -> FOF -> mesh -> raster ->
//! Z-map -> warp -> fusion -> compose) over stiff inputs and extreme views. Nothing may be NaN, everything
//! stays in range, and unusable inputs are refused with an error rather than a broken frame.

mod common;

use glam::{Quat, Vec3};
use r2human::buffer::Image;
use r2human::compose::Mode;
use r2human::compose::RenderedFrame;
use r2human::geometry::{Camera, Fov};
use r2human::io::environment::Environment;
use r2human::io::image_io;
use r2human::pipeline::warp::OcclusionFill;
use r2human::pipeline::{PrepareOptions, PreparedInput, ViewRenderer};

fn small_opts() -> PrepareOptions {
    PrepareOptions { resolution: 128, depth_samples: 128, ..Default::default() }
}

fn figure() -> (r2human::buffer::RgbImage, r2human::buffer::GrayImage) {
    let photo = image_io::from_dynamic(&image::DynamicImage::ImageRgba8(common::figure_rgba(150, 200)));
    let mask = photo.alpha.clone().unwrap();
    (photo.rgb, mask)
}

fn assert_frame_ok(frame: &RenderedFrame, what: &str) {
    match frame {
        RenderedFrame::Vr(img) => assert!(
            img.data.iter().all(|v| v.is_finite() && v.min_element() >= 0.0 && v.max_element() <= 1.0 + 1e-5),
            "{what}: VR frame out of range"
        ),
        RenderedFrame::Ar(img) => assert!(
            img.data
                .iter()
                .all(|v| v.is_finite() && v.w >= 0.0 && v.w <= 1.0 && v.truncate().max_element() <= v.w + 1e-5),
            "{what}: AR layer not valid premultiplied RGBA"
        ),
    }
}

#[test]
fn extreme_views_are_finite_and_bounded() {
    let (rgb, mask) = figure();
    let prepared = PreparedInput::prepare(&rgb, &mask, &small_opts()).unwrap();
    let env = Environment::default_embedded();
    let mut renderer = ViewRenderer::new(&prepared, OcclusionFill::MirroredFront, true);
    let mut person_pixels = Vec::new();
    for &yaw in &[0.0f32, 45.0, 90.0, 135.0, 180.0, -180.0, 270.0, 359.99, 720.0] {
        for &pitch in &[0.0f32, 30.0, 89.9, 90.0, -89.9, -90.0] {
            for mode in [Mode::Vr, Mode::Ar] {
                let cam = Camera::orbit(yaw, pitch, 64, 64);
                let frame = renderer.render_frame(&cam, mode, &env).unwrap();
                assert_frame_ok(&frame, &format!("yaw {yaw} pitch {pitch} {mode:?}"));
                if let RenderedFrame::Ar(img) = &frame {
                    person_pixels.push(img.data.iter().filter(|p| p.w > 0.5).count());
                }
            }
        }
    }
    // The person is visible in every view (including straight down and straight up).
    assert!(person_pixels.iter().all(|&n| n > 20), "{person_pixels:?}");
}

#[test]
fn perspective_cameras_inside_and_around_the_body_are_finite() {
    let (rgb, mask) = figure();
    let prepared = PreparedInput::prepare(&rgb, &mask, &small_opts()).unwrap();
    let env = Environment::default_embedded();
    let mut renderer = ViewRenderer::new(&prepared, OcclusionFill::Propagate, true);
    let fov = Fov::symmetric(1.6, 1.0);
    let poses = [
        (Vec3::new(0.0, 0.0, 3.0), Quat::IDENTITY), // in front, looking at the person
        (Vec3::new(0.0, 0.2, 0.0), Quat::IDENTITY), // inside the body
        (Vec3::new(0.0, 0.0, 0.0), Quat::from_rotation_x(-1.5707964)), // inside, looking straight down
        (Vec3::new(0.0, 5.0, 0.0), Quat::from_rotation_x(-1.5707964)), // above, looking straight down
        (Vec3::new(0.0, 0.0, -3.0), Quat::from_rotation_y(std::f32::consts::PI)), // behind
        (Vec3::new(0.0, 0.0, 1e-4), Quat::IDENTITY), // grazing the front surface
    ];
    for (i, (pos, rot)) in poses.iter().enumerate() {
        let cam = Camera::perspective(*pos, *rot, fov, 0.01, 48, 48);
        for mode in [Mode::Vr, Mode::Ar] {
            let frame = renderer.render_frame(&cam, mode, &env).unwrap();
            assert_frame_ok(&frame, &format!("pose {i} {mode:?}"));
        }
    }
}

#[test]
fn stiff_masks_reconstruct_or_are_refused_cleanly() {
    let w = 120;
    let h = 160;
    let rgb = Image::new(w, h, Vec3::new(0.6, 0.3, 0.2));
    // One-pixel-wide limbs on a body, several disconnected parts, a mask with a hole, a ragged noisy edge.
    let mut limbs = Image::new(w, h, 0.0f32);
    let mut parts = Image::new(w, h, 0.0f32);
    let mut holed = Image::new(w, h, 0.0f32);
    let mut ragged = Image::new(w, h, 0.0f32);
    for r in 0..h {
        for c in 0..w {
            let body = (45..75).contains(&c) && (20..150).contains(&r);
            if body || ((c == 30 || c == 90) && (30..140).contains(&r)) || (r == 60 && (10..110).contains(&c)) {
                limbs.set(c, r, 1.0);
            }
            if ((10..30).contains(&c) || (50..70).contains(&c) || (95..97).contains(&c)) && (10..150).contains(&r) {
                parts.set(c, r, 1.0);
            }
            if body && !((55..65).contains(&c) && (60..90).contains(&r)) {
                holed.set(c, r, 1.0);
            }
            let wobble = ((r * 7919 + c * 104729) % 13) as i64 - 6;
            if ((c as i64 - 60).abs() + wobble / 3) < 20 && (15..155).contains(&r) {
                ragged.set(c, r, 1.0);
            }
        }
    }
    for (name, mask) in [("limbs", limbs), ("parts", parts), ("holed", holed), ("ragged", ragged)] {
        match PreparedInput::prepare(&rgb, &mask, &small_opts()) {
            Ok(prepared) => {
                assert!(prepared.mesh.positions.iter().all(|p| p.is_finite() && p.abs().max_element() <= 1.0 + 1e-4));
                assert!(prepared.fof.coeffs.iter().all(|c| c.is_finite()), "{name}: FOF finite");
                let mut renderer = ViewRenderer::new(&prepared, OcclusionFill::MirroredFront, false);
                for yaw in [0.0f32, 90.0, 180.0] {
                    let person = renderer.render_person(&Camera::orbit(yaw, 0.0, 48, 48)).unwrap();
                    assert!(person.data.iter().all(|p| p.is_finite()), "{name} yaw {yaw}");
                }
            }
            Err(e) => {
                let text = e.to_string();
                assert!(!text.is_empty(), "{name}: error must say something");
            }
        }
    }
}

#[test]
fn high_fof_order_with_ringing_stays_bounded() {
    let (rgb, mask) = figure();
    let opts = PrepareOptions { fof_order: 128, ..small_opts() };
    let prepared = PreparedInput::prepare(&rgb, &mask, &opts).unwrap();
    assert!(prepared.mesh.positions.iter().all(|p| p.is_finite() && p.abs().max_element() <= 1.0 + 1e-4));
    let mut renderer = ViewRenderer::new(&prepared, OcclusionFill::MirroredFront, false);
    let person = renderer.render_person(&Camera::orbit(90.0, 0.0, 64, 64)).unwrap();
    assert!(person.data.iter().all(|p| p.is_finite()));
}
