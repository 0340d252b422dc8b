//! Where the person stands in the room: a world-locked placement of the body cube in the OpenXR reference space,
//! the eye cameras it induces, and the controller moves (move, turn, scale, recentre).
//!
//! Units: the body cube has half-size 1 and the person spans y in [-0.9, 0.9]; with the default scale of 1 m per
//! body unit the person is 1.8 m tall. Stage (reference-space) coordinates are metres, y up, as OpenXR defines.
//! The body cube's +z (towards the source camera, i.e. the person's front) faces the viewer when placed.

use glam::{Affine3A, Quat, Vec2, Vec3};

use crate::geometry::camera::{Camera, Fov};

/// Default distance from the viewer to the person (metres).
pub const DEFAULT_DISTANCE: f32 = 1.75;
/// Assumed standing eye height above the floor (metres) when the reference space has no floor (LOCAL).
pub const STANDING_EYE_HEIGHT: f32 = 1.65;
/// Half the person's height in body-cube units (the person spans y in [-0.9, 0.9]).
pub const BODY_HALF_HEIGHT: f32 = 0.9;
/// Near plane of the eye cameras, in metres.
pub const NEAR_METRES: f32 = 0.05;
/// Scale limits (metres per body unit).
pub const SCALE_RANGE: (f32, f32) = (0.25, 4.0);
/// Controller speeds: metres per second, radians per second, and e-folds of scale per second at full deflection.
pub const MOVE_SPEED: f32 = 1.0;
/// See [`MOVE_SPEED`].
pub const TURN_SPEED: f32 = 1.5;
/// See [`MOVE_SPEED`].
pub const SCALE_SPEED: f32 = 0.5;

/// The person's pose in the reference space: `stage = position + R_y(yaw) * (scale * body)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    /// Centre of the body cube in the reference space (metres).
    pub position: Vec3,
    /// Rotation of the body about the vertical axis (radians; 0 means body +z along stage +z).
    pub yaw: f32,
    /// Metres per body-cube unit (1 makes the person 1.8 m tall).
    pub scale: f32,
}

/// One frame's controller input, already read from the OpenXR actions (all zero while the session is unfocused).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Controls {
    /// Move the person: x to the viewer's right, y away from the viewer (thumbstick, each in [-1, 1]).
    pub move_xz: Vec2,
    /// Turn the person (positive counter-clockwise seen from above), in [-1, 1].
    pub turn: f32,
    /// Grow (positive) or shrink the person, in [-1, 1].
    pub scale: f32,
    /// Put the person back in front of the viewer at the default distance and size.
    pub recentre: bool,
}

impl Controls {
    /// Any input at all?
    pub fn is_active(&self) -> bool {
        self.recentre || self.move_xz != Vec2::ZERO || self.turn != 0.0 || self.scale != 0.0
    }
}

/// The horizontal forward direction of a head orientation (its -z flattened onto the floor), unit length; looking
/// straight up or down falls back to the head's up vector flattened (the direction the face "leans"), then -z.
pub fn horizontal_forward(orientation: Quat) -> Vec3 {
    let q = orientation.normalize();
    let flat = |v: Vec3| Vec3::new(v.x, 0.0, v.z);
    let f = flat(q * Vec3::NEG_Z);
    if f.length_squared() > 1e-6 {
        return f.normalize();
    }
    // Looking straight down, the top of the head points forward; straight up, the back of the head does.
    let up = flat(q * Vec3::Y);
    let sign = if (q * Vec3::NEG_Z).y < 0.0 { 1.0 } else { -1.0 };
    if up.length_squared() > 1e-6 {
        (up * sign).normalize()
    } else {
        Vec3::NEG_Z
    }
}

impl Placement {
    /// The person `distance` metres in front of a viewer at `head_position` looking along `head_orientation`,
    /// feet on the floor at height `floor_y`, facing the viewer, 1 m per body unit.
    pub fn in_front_of(head_position: Vec3, head_orientation: Quat, floor_y: f32, distance: f32) -> Self {
        let forward = horizontal_forward(head_orientation);
        let scale = 1.0;
        let ground = head_position + forward * distance;
        let to_viewer = -forward;
        Self {
            position: Vec3::new(ground.x, floor_y + BODY_HALF_HEIGHT * scale, ground.z),
            yaw: to_viewer.x.atan2(to_viewer.z),
            scale,
        }
    }

    /// Floor height for a reference space: 0 for STAGE (its origin is on the floor), the head height minus a
    /// standing eye height for LOCAL (its origin is at the initial head position).
    pub fn floor_height(stage_has_floor: bool, head_y: f32) -> f32 {
        if stage_has_floor {
            0.0
        } else {
            head_y - STANDING_EYE_HEIGHT
        }
    }

    /// The rotation part (about y).
    pub fn rotation(&self) -> Quat {
        Quat::from_rotation_y(self.yaw)
    }

    /// Body cube to reference space.
    pub fn stage_from_body(&self) -> Affine3A {
        Affine3A::from_scale_rotation_translation(Vec3::splat(self.scale), self.rotation(), self.position)
    }

    /// A reference-space point in body-cube coordinates.
    pub fn body_from_stage_point(&self, p: Vec3) -> Vec3 {
        self.rotation().inverse() * (p - self.position) / self.scale
    }

    /// The perspective camera, in body-cube coordinates, of an eye at `eye_position`/`eye_orientation` in the
    /// reference space with field of view `fov`, rendering `width x height` pixels.
    pub fn eye_camera(
        &self,
        eye_position: Vec3,
        eye_orientation: Quat,
        fov: Fov,
        width: usize,
        height: usize,
    ) -> Camera {
        let position = self.body_from_stage_point(eye_position);
        let orientation = (self.rotation().inverse() * eye_orientation).normalize();
        Camera::perspective(position, orientation, fov, NEAR_METRES / self.scale, width, height)
    }

    /// The same eye as a camera in reference-space coordinates (for the panorama, which is locked to the room,
    /// not to the person).
    pub fn stage_camera(eye_position: Vec3, eye_orientation: Quat, fov: Fov, width: usize, height: usize) -> Camera {
        Camera::perspective(eye_position, eye_orientation, fov, NEAR_METRES, width, height)
    }

    /// Applies `dt` seconds of controller input; moves are relative to the viewer's heading (`head_orientation`),
    /// recentring uses the current head pose and `floor_y`. Non-finite input is ignored.
    pub fn apply(
        &self,
        controls: &Controls,
        head_position: Vec3,
        head_orientation: Quat,
        floor_y: f32,
        dt: f32,
    ) -> Self {
        if controls.recentre {
            return Self::in_front_of(head_position, head_orientation, floor_y, DEFAULT_DISTANCE);
        }
        let finite = |v: f32| if v.is_finite() { v.clamp(-1.0, 1.0) } else { 0.0 };
        let dt = if dt.is_finite() { dt.clamp(0.0, 0.25) } else { 0.0 };
        let forward = horizontal_forward(head_orientation);
        let right = Vec3::new(-forward.z, 0.0, forward.x);
        let mv = right * finite(controls.move_xz.x) + forward * finite(controls.move_xz.y);
        let mut out = *self;
        out.position += mv * MOVE_SPEED * dt;
        out.yaw = (self.yaw + finite(controls.turn) * TURN_SPEED * dt).rem_euclid(std::f32::consts::TAU);
        let new_scale =
            (self.scale * (finite(controls.scale) * SCALE_SPEED * dt).exp()).clamp(SCALE_RANGE.0, SCALE_RANGE.1);
        // Scale about the feet so the person stays on the floor.
        out.position.y += (new_scale - self.scale) * BODY_HALF_HEIGHT;
        out.scale = new_scale;
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f32::consts::{FRAC_PI_2, PI};

    fn close(a: Vec3, b: Vec3) -> bool {
        (a - b).abs().max_element() < 1e-4
    }

    #[test]
    fn placed_in_front_facing_the_viewer_feet_on_floor() {
        let head = Vec3::new(0.3, 1.6, -0.2);
        let p = Placement::in_front_of(head, Quat::IDENTITY, 0.0, 1.75);
        assert!(close(p.position, Vec3::new(0.3, 0.9, -1.95)));
        // Body +z (the person's front) points back toward the viewer (+z here).
        assert!(close(p.rotation() * Vec3::Z, Vec3::Z));
        // Feet at y = -0.9 in the body cube land on the floor; the head at 1.8 m.
        assert!((p.stage_from_body().transform_point3(Vec3::new(0.0, -0.9, 0.0)).y).abs() < 1e-6);
        assert!((p.stage_from_body().transform_point3(Vec3::new(0.0, 0.9, 0.0)).y - 1.8).abs() < 1e-6);
        // Viewer looking along +x (yaw -90 deg about y): the person stands on +x and faces -x.
        let q = Quat::from_rotation_y(-FRAC_PI_2);
        let p = Placement::in_front_of(Vec3::ZERO, q, -1.0, 2.0);
        assert!(close(p.position, Vec3::new(2.0, -0.1, 0.0)));
        assert!(close(p.rotation() * Vec3::Z, Vec3::NEG_X));
    }

    #[test]
    fn pitch_and_roll_do_not_tilt_the_placement_even_looking_straight_down() {
        let q = Quat::from_rotation_y(0.4) * Quat::from_rotation_x(-FRAC_PI_2);
        let f = horizontal_forward(q);
        assert!(f.is_finite() && (f.length() - 1.0).abs() < 1e-5 && f.y == 0.0);
        assert!(close(f, horizontal_forward(Quat::from_rotation_y(0.4))));
        let up = Quat::from_rotation_y(0.4) * Quat::from_rotation_x(FRAC_PI_2);
        assert!(close(horizontal_forward(up), horizontal_forward(Quat::from_rotation_y(0.4))));
    }

    #[test]
    fn eye_camera_sees_the_body_centre_straight_ahead() {
        let head = Vec3::new(0.0, 1.6, 0.0);
        let p = Placement::in_front_of(head, Quat::IDENTITY, 0.0, 1.75);
        let fov = Fov::symmetric(1.6, 1.0);
        // Look at the body centre from the head.
        let dir = (p.position - head).normalize();
        let look = Quat::from_rotation_arc(Vec3::NEG_Z, dir);
        let cam = p.eye_camera(head, look, fov, 101, 101);
        let c = cam.project(Vec3::ZERO).unwrap();
        assert!((c.x - 50.5).abs() < 1e-3 && (c.y - 50.5).abs() < 1e-3, "{c}");
        // Depth = -(distance in body units).
        assert!((c.z + (p.position - head).length()).abs() < 1e-4);
        // The stage camera through the same pixel sees the same world direction.
        let stage = Placement::stage_camera(head, look, fov, 101, 101);
        let r = stage.ray(50.5, 50.5);
        assert!(close(r.direction, dir));
        // Doubling the scale halves body-space distances.
        let mut big = p;
        big.scale = 2.0;
        let cam2 = big.eye_camera(head, look, fov, 101, 101);
        assert!((cam2.position() - big.body_from_stage_point(head)).length() < 1e-5);
        assert!((big.body_from_stage_point(p.position + Vec3::Y * 2.0) - Vec3::Y).length() < 1e-5);
    }

    #[test]
    fn body_and_stage_transforms_are_inverse() {
        let p = Placement { position: Vec3::new(1.0, 0.5, -2.0), yaw: 2.3, scale: 0.7 };
        for b in [Vec3::ZERO, Vec3::new(0.3, -0.9, 0.8), Vec3::splat(-1.0)] {
            let s = p.stage_from_body().transform_point3(b);
            assert!(close(p.body_from_stage_point(s), b));
        }
    }

    #[test]
    fn controls_move_turn_scale_and_recentre() {
        let head = Vec3::new(0.0, 1.6, 0.0);
        let p = Placement::in_front_of(head, Quat::IDENTITY, 0.0, 1.75);
        // Full stick forward for 0.1 s moves 0.1 m away (-z); right moves +x.
        let c = Controls { move_xz: Vec2::new(0.0, 1.0), ..Default::default() };
        let q = p.apply(&c, head, Quat::IDENTITY, 0.0, 0.1);
        assert!(close(q.position - p.position, Vec3::new(0.0, 0.0, -0.1)));
        let c = Controls { move_xz: Vec2::new(1.0, 0.0), ..Default::default() };
        assert!(close(p.apply(&c, head, Quat::IDENTITY, 0.0, 0.1).position - p.position, Vec3::new(0.1, 0.0, 0.0)));
        // Turning accumulates and wraps into [0, 2 pi).
        let c = Controls { turn: 1.0, ..Default::default() };
        let t = p.apply(&c, head, Quat::IDENTITY, 0.0, 0.2);
        assert!((t.yaw - (p.yaw + 0.3).rem_euclid(2.0 * PI)).abs() < 1e-5);
        // Scaling keeps the feet on the floor and is clamped.
        let c = Controls { scale: 1.0, ..Default::default() };
        let mut s = p;
        for _ in 0..200 {
            s = s.apply(&c, head, Quat::IDENTITY, 0.0, 0.25);
        }
        assert_eq!(s.scale, SCALE_RANGE.1);
        assert!(s.stage_from_body().transform_point3(Vec3::new(0.0, -0.9, 0.0)).y.abs() < 1e-4);
        // Recentre restores the default placement for the current head pose.
        let r = s.apply(&Controls { recentre: true, ..Default::default() }, head, Quat::IDENTITY, 0.0, 0.1);
        assert_eq!(r, p);
        // Garbage input changes nothing.
        let bad =
            Controls { move_xz: Vec2::new(f32::NAN, f32::INFINITY), turn: f32::NAN, scale: f32::NAN, recentre: false };
        assert_eq!(
            p.apply(&bad, head, Quat::IDENTITY, 0.0, f32::NAN),
            Placement { yaw: p.yaw.rem_euclid(2.0 * PI), ..p }
        );
    }

    #[test]
    fn local_space_floor_is_below_the_head() {
        assert_eq!(Placement::floor_height(true, 1.7), 0.0);
        assert!((Placement::floor_height(false, 0.0) + STANDING_EYE_HEIGHT).abs() < 1e-6);
    }
}
