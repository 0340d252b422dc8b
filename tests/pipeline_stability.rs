//! End-to-end numerical stability: the whole pipeline (normalise -> inflation -> FOF -> mesh -> raster ->
//! Z-map -> warp -> fusion -> compose) over stiff inputs and extreme views. Nothing may be NaN, everything
//! stays in range, and unusable inputs are refused with an error rather than a broken frame.

mod common;

use glam::{Quat, Vec3};
use r2human::buffer::Image;
use r2human::compose::Mode;
use r2human::compose::RenderedFrame;
use r2human::geometry::raster::rasterize;
use r2human::geometry::{Camera, Fov};
use r2human::io::environment::Environment;
use r2human::io::image_io;
use r2human::pipeline::warp::OcclusionFill;
use r2human::pipeline::{GeometryMode, PrepareOptions, PreparedInput, ViewRenderer};

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
    // The inflation prior, and the body geometries (the default, body-placed, among them) when the pose model is
    // installed: whatever the network reads in such masks, the result is finite and inside the cube, or an error.
    let mut geometries = vec![small_opts()];
    if let Ok(Some(body)) = r2human::pipeline::load_body(GeometryMode::BodyPlaced, &Default::default()) {
        for geometry in [GeometryMode::BodyPlaced, GeometryMode::Body] {
            geometries.push(PrepareOptions { geometry, body: Some(body.clone()), ..small_opts() });
        }
    } else {
        eprintln!("body geometries skipped: the pose model is not installed (bash scripts/setup.d/live.sh)");
    }
    let masks = [("limbs", limbs), ("parts", parts), ("holed", holed), ("ragged", ragged)];
    for ((name, mask), opts) in masks.iter().flat_map(|m| geometries.iter().map(move |o| (m, o))) {
        let name = format!("{name} ({})", opts.geometry.name());
        match PreparedInput::prepare(&rgb, mask, opts) {
            Ok(prepared) => {
                assert!(prepared.mesh.positions.iter().all(|p| p.is_finite() && p.abs().max_element() <= 1.0 + 1e-4));
                assert!(
                    prepared.fof.as_ref().is_some_and(|f| f.coeffs.iter().all(|c| c.is_finite())),
                    "{name}: FOF finite"
                );
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

/// The pipeline's step ([`r2human::pipeline::back_image_of`]) with the pose network: on a rendered synthetic
/// subject it finds the face and paints it in the hair's colour; on an input without a person it gives no back
/// image (the renderers' fall-back to the photo).
#[test]
fn the_pose_network_finds_the_face_of_a_rendered_subject_and_nothing_in_a_blank() {
    use r2human::pipeline::back::FacePoints;
    use r2human::pipeline::{back_image_of, back_image_with, input::NormalisedInput, SharedPose, StageTimings};
    use r2human::synth::{self, SubjectParams, SynthAssets};
    let model = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(".tools/models/pose_landmark_full.onnx");
    let Ok(assets) = SynthAssets::shared() else {
        eprintln!("skipped: no synthetic-subject data (bash scripts/setup.d/synth.sh)");
        return;
    };
    if !model.is_file() {
        eprintln!("skipped: {} is not installed (bash scripts/setup.d/live.sh)", model.display());
        return;
    }
    let pose = r2human::body::pose::PoseEstimator::load(Some(&model), &Default::default()).unwrap();
    let pose = SharedPose(std::sync::Arc::new(std::sync::Mutex::new(pose)));
    let mut params = SubjectParams::sample(3);
    params.outfit = synth::Outfit::none(params.appearance.top_fabric);
    let subject = synth::generate(assets, &params, 128).unwrap();
    let res = 256;
    let view = r2human::eval::ground_truth::render_ground_truth(&subject.mesh, &r2human::geometry::Camera::source(res));
    let rgb: r2human::buffer::RgbImage = view.to_linear_rgba().map(|p| p.truncate());
    let input = NormalisedInput::in_source_view(rgb, view.mask_image());
    let mut timings = StageTimings::default();
    let back = back_image_of(&input, &pose, &mut timings).expect("a face in a rendered subject");
    assert!(timings.0.iter().any(|(n, _)| *n == "back image (filter)"));
    // The face (between the eyes the network reads) shows the hair's colour in the back image.
    let lm = pose.0.lock().unwrap().estimate(&input.rgb, &input.mask, None).unwrap().unwrap();
    // With its head weights: the same image, from the network's own read.
    let with = back_image_with(&input, &pose, &mut StageTimings::default()).expect("a face in a rendered subject");
    assert_eq!(with.rgb.data, back.data);
    let face = FacePoints::from_pose(&lm).unwrap();
    let i = face.eyes.y as usize * res + face.eyes.x as usize;
    let m = input.mask.data[i];
    let (photo, painted) = (input.rgb.data[i] / m, back.data[i] / m);
    let hair = glam::Vec3::from(params.appearance.hair);
    eprintln!("eyes at {}: photo {photo}, back image {painted}, hair {hair}", face.eyes);
    // (This subject's skin is dark: the photo's face is 0.07 from the hair, the back image 0.003.)
    assert!((painted - hair).length() < 0.25 * (photo - hair).length(), "{painted} vs hair {hair}, photo {photo}");
    // No person (a flat grey board): no back image.
    let board =
        Image::from_fn(res, res, |c, r| if (64..192).contains(&c) && (32..224).contains(&r) { 1.0 } else { 0.0 });
    let blank = NormalisedInput::in_source_view(board.map(|&m| glam::Vec3::splat(0.4) * m), board);
    assert!(back_image_of(&blank, &pose, &mut StageTimings::default()).is_none());
}

/// The coarse mesh interactive views draw when their pixels are large: made only when asked, on the still path
/// (halved FOF) and the frame path (twice the step), a fraction of the triangles, the same person at two source
/// pixels' resolution, and drawing a finite far view that matches the full mesh's.
#[test]
fn the_coarse_view_mesh_is_made_when_asked_and_draws_the_same_person() {
    let (rgb, mask) = figure();
    let opts = PrepareOptions { resolution: 256, depth_samples: 256, ..Default::default() };
    let plain = PreparedInput::prepare(&rgb, &mask, &opts).unwrap();
    assert!(plain.coarse.is_none(), "a coarse mesh nobody asked for");
    let asked = PrepareOptions { coarse_views: true, ..opts.clone() };
    let still = PreparedInput::prepare(&rgb, &mask, &asked).unwrap();
    let mut frames = r2human::pipeline::frame::FramePath::new(asked);
    let frame = frames.prepare(&rgb, &mask).unwrap();
    // The frame path's mesh is closed by construction and says so; the still path's is not checked.
    assert!(frame.mesh_closed && frame.mesh.is_closed());
    assert!(!still.mesh_closed);
    for (what, input, spacing) in [("still", &still, 4.0 / 256.0), ("frame", &frame, 8.0 / 256.0)] {
        let coarse = input.coarse.as_ref().unwrap_or_else(|| panic!("{what}: no coarse mesh"));
        assert!((coarse.spacing - spacing).abs() < 1e-6, "{what}: spacing {}", coarse.spacing);
        // The figure stands inside the grid: both builders close the surface, so far views skip back faces.
        assert!(coarse.closed, "{what}: the coarse mesh is not closed");
        let ratio = coarse.mesh.triangle_count() as f32 / input.mesh.triangle_count() as f32;
        assert!((0.1..0.45).contains(&ratio), "{what}: {ratio} of the triangles");
        // Silhouettes at an oblique view with pixels of the coarse spacing: nearly the same.
        let camera = Camera::orthographic(Camera::orbit_rotation(40.0, 15.0), 1.0, 64, 64);
        let (a, b) = (rasterize(&input.mesh, &camera), rasterize(&coarse.mesh, &camera));
        let inter = a.mask.iter().zip(&b.mask).filter(|(x, y)| **x && **y).count() as f32;
        let union = a.mask.iter().zip(&b.mask).filter(|(x, y)| **x || **y).count() as f32;
        assert!(inter / union > 0.9, "{what}: silhouette IoU {}", inter / union);
        // A far view draws finite pixels from it.
        let mut renderer = ViewRenderer::new(input, OcclusionFill::MirroredFront, false);
        let far = Camera::perspective(Vec3::new(0.3, 0.1, 6.0), Quat::IDENTITY, Fov::symmetric(1.2, 1.0), 0.05, 96, 96);
        assert!(far.pixel_footprint(Vec3::ZERO) >= coarse.spacing);
        let frame = renderer.render_frame(&far, Mode::Ar, &Environment::default_embedded()).unwrap();
        assert_frame_ok(&frame, what);
    }
}
