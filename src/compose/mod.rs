//! Compositing: the person over an equirectangular panorama by spherical projection (VR), or as a
//! premultiplied alpha layer for passthrough (AR). Only what the mode needs is computed: AR touches no panorama.

use glam::{Affine3A, Vec3, Vec4};
use rayon::prelude::*;

use crate::buffer::{Image, RgbImage, RgbaImage};
use crate::geometry::{Camera, Fov};
use crate::io::environment::Environment;

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

/// VR composite: `person.rgb + (1 - person.a) * environment(ray)` per pixel, in linear RGB. The panorama is
/// sampled only where the person does not fully cover the pixel.
pub fn compose_vr(person: &RgbaImage, environment: &Environment, camera: &Camera) -> RgbImage {
    let rays = background_camera(camera).ray_grid();
    let (w, h) = (person.width, person.height);
    let mut out = Image::new(w, h, Vec3::ZERO);
    let panorama = environment.lookup();
    out.data.par_chunks_mut(w.max(1)).enumerate().for_each(|(row, out_row)| {
        for (col, o) in out_row.iter_mut().enumerate() {
            let p: Vec4 = person.data[row * w + col];
            let a = if p.w.is_finite() { p.w.clamp(0.0, 1.0) } else { 0.0 };
            let fg = if p.is_finite() { p.truncate().max(Vec3::ZERO) } else { Vec3::ZERO };
            *o = if a >= 1.0 {
                fg
            } else {
                // The lookup normalises the direction itself.
                let direction = rays.direction_unnormalised(col as f32 + 0.5, row as f32 + 0.5);
                fg + panorama.sample(direction) * (1.0 - a)
            };
        }
    });
    out
}

/// AR layer: the person as premultiplied linear RGBA, sanitised (finite, alpha in `[0, 1]`, colour <= alpha)
/// so a compositor blending it with passthrough never sees an invalid premultiplied pixel.
pub fn compose_ar(person: &RgbaImage) -> RgbaImage {
    person.map(|p| {
        if !p.is_finite() {
            return Vec4::ZERO;
        }
        let a = p.w.clamp(0.0, 1.0);
        p.truncate().clamp(Vec3::ZERO, Vec3::splat(a)).extend(a)
    })
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
    }
}
