//! Cameras, written once: the orthographic source camera of the reference, orthographic orbit views and
//! perspective cameras from a pose + field of view (what an XR eye gives), all behind one type.
//!
//! # Conventions (exactly the reference's)
//! - **Body cube** (world) coordinates: the person lives in `[-1, 1]^3`, x right, **y up**, **+z toward the
//!   source camera**.
//! - **View space**: a rigid transform of world space ([`Camera::view_from_world`]). The camera looks down
//!   **-z**; x right, y up in the image.
//! - **Depth** is view-space z, so **larger depth is nearer** for both projections: the orthographic source
//!   camera keeps the largest z like the reference's depth test, and a perspective camera has depth
//!   `-distance along the view axis` (negative in front of the eye).
//! - **Pixels**: continuous pixel coordinates `(u, v)` with pixel centres at `col + 0.5`, `row + 0.5`, row 0
//!   at the top. For the source camera at `W x H`, pixel centre `x = (col+0.5)/(W/2) - 1`,
//!   `y = 1 - (row+0.5)/(H/2)`.

use glam::{Affine3A, Mat3, Quat, Vec2, Vec3};

/// Side length, in pixels, of the reference's source image and FOF grid.
pub const SOURCE_RESOLUTION: usize = 512;

/// An asymmetric field of view as OpenXR's `XrFovf`: angles in radians from the view axis, `left` and `down`
/// usually negative.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fov {
    /// Angle of the left edge (radians, negative to the left).
    pub angle_left: f32,
    /// Angle of the right edge (radians).
    pub angle_right: f32,
    /// Angle of the top edge (radians).
    pub angle_up: f32,
    /// Angle of the bottom edge (radians, negative below).
    pub angle_down: f32,
}

impl Fov {
    /// A symmetric field of view with the given full vertical angle (radians) and aspect ratio `w/h`.
    pub fn symmetric(vertical: f32, aspect: f32) -> Self {
        let tan_half_v = (vertical * 0.5).tan();
        let half_h = (tan_half_v * aspect).atan();
        Self { angle_left: -half_h, angle_right: half_h, angle_up: vertical * 0.5, angle_down: -vertical * 0.5 }
    }
}

/// How view space maps to the image plane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Projection {
    /// Parallel projection: view x in `[-half_width, half_width]` spans the image width, y likewise.
    Orthographic {
        /// Half the visible width in view units.
        half_width: f32,
        /// Half the visible height in view units.
        half_height: f32,
    },
    /// Pinhole projection through an asymmetric frustum; points closer than `near` are not projected.
    Perspective {
        /// The frustum angles.
        fov: Fov,
        /// Near distance (positive, view units).
        near: f32,
    },
}

/// A camera: rigid pose, projection and image size. See the module docs for every convention.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// World (body cube) to view transform; rigid (rotation + translation).
    pub view_from_world: Affine3A,
    /// The projection.
    pub projection: Projection,
    /// Image width in pixels.
    pub width: usize,
    /// Image height in pixels.
    pub height: usize,
}

/// Every pixel's viewing ray of one camera, precomputed as affine functions of the pixel coordinates
/// ([`Camera::ray_grid`]); [`RayGrid::ray`] equals [`Camera::ray`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayGrid {
    /// Orthographic: the ray origin at pixel (0, 0); perspective: the eye.
    origin: Vec3,
    /// Unnormalised direction at pixel (0, 0).
    direction: Vec3,
    /// Change per unit of `u` (of the origin when orthographic, else of the direction).
    per_u: Vec3,
    /// Change per unit of `v`.
    per_v: Vec3,
    orthographic: bool,
}

impl RayGrid {
    /// The ray through continuous pixel coordinates `(u, v)` (centres at +0.5).
    #[inline]
    pub fn ray(&self, u: f32, v: f32) -> Ray {
        if self.orthographic {
            Ray { origin: self.origin + u * self.per_u + v * self.per_v, direction: self.direction.normalize() }
        } else {
            Ray { origin: self.origin, direction: self.direction_unnormalised(u, v).normalize() }
        }
    }

    /// The direction through `(u, v)` before normalisation (cheaper when only the direction's angle matters).
    #[inline]
    pub fn direction_unnormalised(&self, u: f32, v: f32) -> Vec3 {
        if self.orthographic {
            self.direction
        } else {
            self.direction + u * self.per_u + v * self.per_v
        }
    }
}

/// A ray in world space (`direction` is unit length).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    /// Start point.
    pub origin: Vec3,
    /// Unit direction.
    pub direction: Vec3,
}

impl Camera {
    /// The reference's orthographic source camera: identity pose over the body cube, `resolution^2` pixels.
    pub fn source(resolution: usize) -> Self {
        Self::orthographic(Affine3A::IDENTITY, 1.0, resolution, resolution)
    }

    /// An orthographic camera with the given pose and half extent (vertical), aspect from the image size.
    pub fn orthographic(view_from_world: Affine3A, half_height: f32, width: usize, height: usize) -> Self {
        let aspect = width as f32 / height.max(1) as f32;
        Self {
            view_from_world,
            projection: Projection::Orthographic { half_width: half_height * aspect, half_height },
            width,
            height,
        }
    }

    /// An orthographic orbit view of the body cube: the camera sits on a sphere around the body, `yaw` about
    /// the body's vertical (y) axis from the source direction (+z) toward +x, `pitch` up (positive looks down
    /// on the person). Yaw 0, pitch 0 is the source camera. Angles in degrees; any finite value is accepted.
    pub fn orbit(yaw_deg: f32, pitch_deg: f32, width: usize, height: usize) -> Self {
        Self::orthographic(Self::orbit_rotation(yaw_deg, pitch_deg), 1.0, width, height)
    }

    /// The view-from-world rotation of an orbit view (see [`Camera::orbit`]).
    pub fn orbit_rotation(yaw_deg: f32, pitch_deg: f32) -> Affine3A {
        // camera-to-world = Ry(yaw) * Rx(-pitch); view-from-world is its inverse.
        let world_from_view =
            Quat::from_rotation_y(yaw_deg.to_radians()) * Quat::from_rotation_x(-pitch_deg.to_radians());
        Affine3A::from_quat(world_from_view.inverse())
    }

    /// A perspective camera from an eye pose in world (body cube) coordinates — position and orientation of
    /// the eye, looking down its local -z — and a field of view, as OpenXR's `XrView` gives them.
    pub fn perspective(position: Vec3, orientation: Quat, fov: Fov, near: f32, width: usize, height: usize) -> Self {
        let world_from_view = Affine3A::from_rotation_translation(orientation.normalize(), position);
        Self {
            view_from_world: world_from_view.inverse(),
            projection: Projection::Perspective { fov, near: near.max(1e-6) },
            width,
            height,
        }
    }

    /// The camera's position in world space (for orthographic cameras: a point on the view axis at view z = 0).
    pub fn position(&self) -> Vec3 {
        self.view_from_world.inverse().translation.into()
    }

    /// The world distance one pixel spans at `world` (the smaller of its width and height there): constant for an
    /// orthographic camera, growing with view depth for a perspective one. `0` for a point at or before the near
    /// plane or behind a perspective eye, or an image without pixels.
    pub fn pixel_footprint(&self, world: Vec3) -> f32 {
        if self.width == 0 || self.height == 0 {
            return 0.0;
        }
        let (w, h) = (self.width as f32, self.height as f32);
        match self.projection {
            Projection::Orthographic { half_width, half_height } => {
                (2.0 * half_width / w).min(2.0 * half_height / h).max(0.0)
            }
            Projection::Perspective { fov, near } => {
                let depth = -self.view_from_world.transform_point3(world).z;
                if depth.is_nan() || depth < near {
                    return 0.0;
                }
                let (tl, tr, tu, td) = tangents(&fov);
                (depth * (tr - tl) / w).min(depth * (tu - td) / h).max(0.0)
            }
        }
    }

    /// Rotation of this view relative to the source view, in radians in `[0, pi]` (the paper's phi in Eq. 8).
    pub fn angle_from_source(&self) -> f32 {
        let rot = Quat::from_mat3(&Mat3::from(self.view_from_world.matrix3)).normalize();
        // angle = 2 acos(|w|), computed stably with atan2 so it is exact near 0 and pi.
        2.0 * rot.xyz().length().atan2(rot.w.abs())
    }

    /// Projects a world point to `(u, v, depth)`: continuous pixel coordinates (centres at +0.5) and view depth
    /// (larger is nearer). `None` for a perspective point closer than the near plane or behind the eye.
    pub fn project(&self, world: Vec3) -> Option<Vec3> {
        let p = self.view_from_world.transform_point3(world);
        let ndc = self.view_to_ndc(p)?;
        let (u, v) = self.ndc_to_pixel(ndc);
        Some(Vec3::new(u, v, p.z))
    }

    /// View-space point to normalised device coordinates (x right, y up, `[-1, 1]` over the image).
    pub fn view_to_ndc(&self, p: Vec3) -> Option<Vec2> {
        match self.projection {
            Projection::Orthographic { half_width, half_height } => {
                Some(Vec2::new(p.x / half_width, p.y / half_height))
            }
            Projection::Perspective { fov, near } => {
                if -p.z < near {
                    return None;
                }
                let (tl, tr, tu, td) = tangents(&fov);
                let tx = p.x / -p.z;
                let ty = p.y / -p.z;
                Some(Vec2::new((2.0 * tx - (tr + tl)) / (tr - tl), (2.0 * ty - (tu + td)) / (tu - td)))
            }
        }
    }

    /// NDC to continuous pixel coordinates.
    #[inline]
    pub fn ndc_to_pixel(&self, ndc: Vec2) -> (f32, f32) {
        ((ndc.x + 1.0) * 0.5 * self.width as f32, (1.0 - ndc.y) * 0.5 * self.height as f32)
    }

    /// Continuous pixel coordinates to NDC.
    #[inline]
    pub fn pixel_to_ndc(&self, u: f32, v: f32) -> Vec2 {
        Vec2::new(u / (0.5 * self.width as f32) - 1.0, 1.0 - v / (0.5 * self.height as f32))
    }

    /// The view-space point at pixel `(u, v)` with view depth `depth` (inverse of [`Camera::project`]).
    pub fn unproject_view(&self, u: f32, v: f32, depth: f32) -> Vec3 {
        let ndc = self.pixel_to_ndc(u, v);
        match self.projection {
            Projection::Orthographic { half_width, half_height } => {
                Vec3::new(ndc.x * half_width, ndc.y * half_height, depth)
            }
            Projection::Perspective { fov, .. } => {
                let (tx, ty) = ndc_to_tangent(&fov, ndc);
                let dist = -depth;
                Vec3::new(tx * dist, ty * dist, depth)
            }
        }
    }

    /// The world point at pixel `(u, v)` with view depth `depth`: `(Pi)^-1(v, D)` of paper Eq. 4.
    pub fn unproject(&self, u: f32, v: f32, depth: f32) -> Vec3 {
        self.view_from_world.inverse().transform_point3(self.unproject_view(u, v, depth))
    }

    /// The world-space viewing ray through pixel `(u, v)`. Orthographic rays start on the plane view z = 0
    /// and point down view -z; perspective rays start at the eye.
    pub fn ray(&self, u: f32, v: f32) -> Ray {
        self.ray_grid().ray(u, v)
    }

    /// The camera's rays with the per-camera work (matrix inverse, field-of-view tangents) done once: use it when
    /// asking for the ray of every pixel.
    pub fn ray_grid(&self) -> RayGrid {
        let world_from_view = self.view_from_world.inverse();
        let (w, h) = (self.width.max(1) as f32, self.height.max(1) as f32);
        match self.projection {
            Projection::Orthographic { half_width, half_height } => {
                // ndc.x = 2u/w - 1, ndc.y = 1 - 2v/h: the origin is affine in (u, v), the direction constant.
                let origin = world_from_view.transform_point3(Vec3::new(-half_width, half_height, 0.0));
                RayGrid {
                    origin,
                    direction: world_from_view.transform_vector3(Vec3::NEG_Z),
                    per_u: world_from_view.transform_vector3(Vec3::new(2.0 * half_width / w, 0.0, 0.0)),
                    per_v: world_from_view.transform_vector3(Vec3::new(0.0, -2.0 * half_height / h, 0.0)),
                    orthographic: true,
                }
            }
            Projection::Perspective { fov, .. } => {
                // tan_x = tl + (u / w)(tr - tl), tan_y = tu - (v / h)(tu - td): the direction is affine in (u, v).
                let (tl, tr, tu, td) = tangents(&fov);
                RayGrid {
                    origin: world_from_view.translation.into(),
                    direction: world_from_view.transform_vector3(Vec3::new(tl, tu, -1.0)),
                    per_u: world_from_view.transform_vector3(Vec3::new((tr - tl) / w, 0.0, 0.0)),
                    per_v: world_from_view.transform_vector3(Vec3::new(0.0, -(tu - td) / h, 0.0)),
                    orthographic: false,
                }
            }
        }
    }

    /// Is this an orthographic camera?
    pub fn is_orthographic(&self) -> bool {
        matches!(self.projection, Projection::Orthographic { .. })
    }
}

fn tangents(fov: &Fov) -> (f32, f32, f32, f32) {
    (fov.angle_left.tan(), fov.angle_right.tan(), fov.angle_up.tan(), fov.angle_down.tan())
}

fn ndc_to_tangent(fov: &Fov, ndc: Vec2) -> (f32, f32) {
    let (tl, tr, tu, td) = tangents(fov);
    (tl + (ndc.x + 1.0) * 0.5 * (tr - tl), td + (ndc.y + 1.0) * 0.5 * (tu - td))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: Vec3, b: Vec3, eps: f32) -> bool {
        (a - b).abs().max_element() < eps
    }

    #[test]
    fn ray_grid_rays_pass_through_the_unprojected_points() {
        let fov = Fov { angle_left: -0.7, angle_right: 0.5, angle_up: 0.6, angle_down: -0.4 };
        let eye = Camera::perspective(
            Vec3::new(0.3, 1.6, 2.5),
            Quat::from_rotation_y(0.4) * Quat::from_rotation_x(-0.2),
            fov,
            0.05,
            320,
            240,
        );
        let orbit = Camera::orbit(135.0, 30.0, 200, 100);
        for cam in [eye, orbit] {
            let grid = cam.ray_grid();
            for &(u, v) in &[(0.5f32, 0.5f32), (160.0, 120.0), (319.5, 3.25), (12.0, 239.5)] {
                let ray = grid.ray(u, v);
                // Two points on the ray from the camera's own unprojection (independent of the grid).
                let (near, far) = if cam.is_orthographic() { (0.0, -1.0) } else { (-1.0, -2.0) };
                let (a, b) = (cam.unproject(u, v, near), cam.unproject(u, v, far));
                assert!(close(ray.direction, (b - a).normalize(), 1e-5), "{u} {v}: {:?}", ray.direction);
                let t = (a - ray.origin).dot(ray.direction);
                assert!(close(ray.origin + t * ray.direction, a, 1e-4), "{u} {v}: origin {:?}", ray.origin);
                assert!(close(grid.direction_unnormalised(u, v).normalize(), ray.direction, 1e-6));
            }
        }
    }

    #[test]
    fn source_pixel_centres_match_the_reference() {
        let cam = Camera::source(512);
        // pixel centre x = (col+0.5)/256 - 1, y = 1 - (row+0.5)/256
        for &(col, row) in &[(0usize, 0usize), (255, 256), (511, 511), (17, 400)] {
            let p = cam.unproject(col as f32 + 0.5, row as f32 + 0.5, 0.3);
            let x = (col as f32 + 0.5) / 256.0 - 1.0;
            let y = 1.0 - (row as f32 + 0.5) / 256.0;
            assert!(close(p, Vec3::new(x, y, 0.3), 1e-6), "{p:?}");
            let back = cam.project(p).unwrap();
            assert!(close(back, Vec3::new(col as f32 + 0.5, row as f32 + 0.5, 0.3), 1e-4));
        }
    }

    #[test]
    fn orbit_yaw_90_sees_the_right_side() {
        // Yaw 90: the camera sits on +x looking toward -x, so world +x is nearest (largest depth).
        let cam = Camera::orbit(90.0, 0.0, 64, 64);
        let near = cam.project(Vec3::new(0.5, 0.0, 0.0)).unwrap();
        let far = cam.project(Vec3::new(-0.5, 0.0, 0.0)).unwrap();
        assert!(near.z > far.z);
        assert!(close(cam.position().normalize_or_zero(), Vec3::ZERO, 1e-6) || cam.position().length() < 1e-6);
        // World +z (the person's front) now appears on the left of the image.
        let front = cam.project(Vec3::new(0.0, 0.0, 0.5)).unwrap();
        assert!(front.x < 32.0);
        assert!((cam.angle_from_source() - std::f32::consts::FRAC_PI_2).abs() < 1e-5);
    }

    #[test]
    fn orbit_pitch_90_looks_down_without_nan() {
        for pitch in [90.0f32, -90.0, 89.9, -89.9] {
            let cam = Camera::orbit(180.0, pitch, 32, 32);
            let top = cam.project(Vec3::new(0.0, 0.9, 0.0)).unwrap();
            let bottom = cam.project(Vec3::new(0.0, -0.9, 0.0)).unwrap();
            assert!(top.is_finite() && bottom.is_finite());
            if pitch > 0.0 {
                assert!(top.z > bottom.z, "looking down, the head is nearest");
            } else {
                assert!(top.z < bottom.z);
            }
            let r = cam.ray(16.0, 16.0);
            assert!(r.direction.is_finite() && (r.direction.length() - 1.0).abs() < 1e-5);
        }
    }

    #[test]
    fn yaw_180_angle_is_pi() {
        let cam = Camera::orbit(180.0, 0.0, 8, 8);
        assert!((cam.angle_from_source() - std::f32::consts::PI).abs() < 1e-5);
        assert!(Camera::source(8).angle_from_source().abs() < 1e-6);
    }

    #[test]
    fn perspective_round_trip_and_centre_ray() {
        let fov = Fov { angle_left: -0.7, angle_right: 0.6, angle_up: 0.65, angle_down: -0.75 };
        let q = Quat::from_rotation_y(0.3) * Quat::from_rotation_x(-0.2);
        let cam = Camera::perspective(Vec3::new(0.2, 0.1, 3.0), q, fov, 0.05, 100, 90);
        for &(u, v, d) in &[(10.0f32, 20.0f32, -2.0f32), (50.0, 45.0, -3.5), (99.0, 1.0, -0.5)] {
            let w = cam.unproject(u, v, d);
            let p = cam.project(w).unwrap();
            assert!(close(p, Vec3::new(u, v, d), 1e-3), "{p:?}");
        }
        // Behind the eye: not projected.
        assert!(cam.project(cam.position() + q * Vec3::Z).is_none());
        // A ray through a pixel passes through the unprojected point.
        let r = cam.ray(30.0, 60.0);
        let w = cam.unproject(30.0, 60.0, -2.0);
        let t = (w - r.origin).dot(r.direction);
        assert!(close(r.origin + r.direction * t, w, 1e-4));
    }

    #[test]
    fn symmetric_fov_is_symmetric() {
        let f = Fov::symmetric(1.0, 2.0);
        assert!((f.angle_left + f.angle_right).abs() < 1e-7);
        assert!(((f.angle_right.tan()) - 2.0 * (0.5f32).tan()).abs() < 1e-6);
    }

    #[test]
    fn a_pixel_spans_the_frustum_width_over_the_image_at_its_depth() {
        // Orthographic: the visible extent over the pixels, the finer of the two directions.
        let ortho = Camera::orthographic(Affine3A::IDENTITY, 1.0, 400, 200);
        assert!((ortho.pixel_footprint(Vec3::new(0.3, -0.2, 0.9)) - 0.01).abs() < 1e-7);
        // Perspective, 90 degrees by 90 degrees over 100 x 50 pixels, a point 3 units ahead: the width spans 6
        // units over 100 pixels (0.06), the height 6 over 50 (0.12).
        let q = std::f32::consts::FRAC_PI_4;
        let fov = Fov { angle_left: -q, angle_right: q, angle_up: q, angle_down: -q };
        let eye = Camera::perspective(Vec3::new(0.0, 0.0, 5.0), Quat::IDENTITY, fov, 0.1, 100, 50);
        assert!((eye.pixel_footprint(Vec3::new(0.5, 0.0, 2.0)) - 0.06).abs() < 1e-5);
        // Behind the eye, before the near plane, no pixels: 0.
        assert_eq!(eye.pixel_footprint(Vec3::new(0.0, 0.0, 6.0)), 0.0);
        assert_eq!(eye.pixel_footprint(Vec3::new(0.0, 0.0, 4.95)), 0.0);
        let empty = Camera::orthographic(Affine3A::IDENTITY, 1.0, 0, 10);
        assert_eq!(empty.pixel_footprint(Vec3::ZERO), 0.0);
    }
}
