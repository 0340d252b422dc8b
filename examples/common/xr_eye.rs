//! The XR eye an example draws the person with: as `xr` places the person, seen by a viewer walking around them.

use glam::{Quat, Vec3};
use r2human::geometry::{Camera, Fov};
use r2human::xr::placement::Placement;

/// An eye of `size` pixels with a 90° vertical view, of a viewer whose head (1.6 m up) stands `distance` metres
/// from the person placed as `xr` places them, walked `yaw_degrees` about the person's vertical axis, looking down
/// at the person's centre.
pub fn around_the_person(distance: f32, yaw_degrees: f32, (w, h): (usize, usize)) -> Camera {
    let head = Vec3::new(0.0, 1.6, 0.0);
    let placement = Placement::in_front_of(head, Quat::IDENTITY, 0.0, distance);
    let turn = Quat::from_rotation_y(yaw_degrees.to_radians());
    let eye = placement.position + turn * (head - placement.position);
    let look = turn * Quat::from_rotation_x(-(0.7f32 / distance).atan());
    placement.eye_camera(eye, look, Fov::symmetric(std::f32::consts::FRAC_PI_2, w as f32 / h as f32), w, h)
}
