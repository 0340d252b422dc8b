//! Normalisation into the body cube like the reference's FOF preprocessing: height scaled to 1.8 (y in
//! `[-0.9, 0.9]`), x and z centred on the minimal enclosing circle of the xz projection (Welzl's algorithm) —
//! then z re-centred on the occupied volume by the project's depth convention
//! ([`crate::geometry::depth_centre`], [`centre_depth`]), which every predicted geometry follows too.

use glam::{Vec2, Vec3};

pub use crate::geometry::circle::min_enclosing_circle;
use serde::{Deserialize, Serialize};

/// Target height of a normalised subject (body cube units).
pub const BODY_HEIGHT: f32 = 1.8;

/// The similarity `p' = scale * (p - center)` that normalises a mesh.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Normalization {
    /// Uniform scale.
    pub scale: f32,
    /// Point mapped to the origin (input units): x, z = enclosing-circle centre, y = middle of the height.
    pub center: [f32; 3],
    /// Radius of the minimal enclosing circle of the xz projection after normalisation.
    pub xz_radius: f32,
}

impl Normalization {
    /// The same normalisation followed by a shift of `dz` along z (body-cube units).
    pub fn shifted_in_depth(self, dz: f32) -> Self {
        let mut center = self.center;
        center[2] -= dz / self.scale;
        Self { center, ..self }
    }

    /// Applies the transform to a point.
    pub fn apply(&self, p: Vec3) -> Vec3 {
        self.scale * (p - Vec3::from(self.center))
    }
}

/// Computes the normalisation of a point set; `None` when it is empty, not finite or has zero height.
pub fn compute(points: &[Vec3]) -> Option<Normalization> {
    if points.is_empty() || points.iter().any(|p| !p.is_finite()) {
        return None;
    }
    let (ymin, ymax) = points.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), p| (a.min(p.y), b.max(p.y)));
    let height = ymax - ymin;
    if height.is_nan() || height <= 0.0 || !height.is_finite() {
        return None;
    }
    let xz: Vec<Vec2> = points.iter().map(|p| Vec2::new(p.x, p.z)).collect();
    let (c, r) = min_enclosing_circle(&xz);
    let scale = BODY_HEIGHT / height;
    Some(Normalization { scale, center: [c.x, 0.5 * (ymin + ymax), c.y], xz_radius: r * scale })
}

/// Moves a normalised mesh (body-cube coordinates) along z by the depth convention
/// ([`crate::geometry::depth_centre::mesh_centring_shift`]): the centroid of its occupied volume to z = 0, as far
/// as the cube allows. Returns the shift (0 for a mesh that covers nothing).
pub fn centre_depth(mesh: &mut crate::geometry::TriMesh) -> f32 {
    let dz = crate::geometry::depth_centre::mesh_centring_shift(mesh).unwrap_or(0.0);
    if dz != 0.0 {
        mesh.positions.iter_mut().for_each(|p| p.z += dz);
    }
    dz
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn circle_of_known_sets() {
        // Square: centre at the middle, radius half the diagonal.
        let sq =
            [Vec2::new(0.0, 0.0), Vec2::new(2.0, 0.0), Vec2::new(2.0, 2.0), Vec2::new(0.0, 2.0), Vec2::new(1.0, 1.2)];
        let (c, r) = min_enclosing_circle(&sq);
        assert!((c - Vec2::ONE).length() < 1e-5 && (r - 2f32.sqrt()).abs() < 1e-5);
        // Obtuse triangle: the circle on the longest side.
        let (c, r) = min_enclosing_circle(&[Vec2::new(-1.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(0.0, 0.2)]);
        assert!((c - Vec2::ZERO).length() < 1e-6 && (r - 1.0).abs() < 1e-6);
        // Equilateral triangle: circumcircle.
        let h = 3f32.sqrt();
        let (c, r) = min_enclosing_circle(&[Vec2::new(-1.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(0.0, h)]);
        assert!((c - Vec2::new(0.0, h / 3.0)).length() < 1e-5 && (r - 2.0 / h).abs() < 1e-5);
        // Points on a circle plus interior points; collinear and duplicate points.
        let ring: Vec<Vec2> = (0..200)
            .map(|i| {
                let a = i as f32 * 0.731;
                Vec2::new(3.0 + 2.0 * a.cos(), -1.0 + 2.0 * a.sin()) * if i % 3 == 0 { 0.5 } else { 1.0 }
            })
            .collect();
        let (_, r) = min_enclosing_circle(&ring);
        assert!(ring.iter().all(|p| p.distance(min_enclosing_circle(&ring).0) <= r + 1e-4));
        let line = [Vec2::ZERO, Vec2::X, Vec2::X * 2.0, Vec2::X * 2.0];
        let (c, r) = min_enclosing_circle(&line);
        assert!((c - Vec2::X).length() < 1e-6 && (r - 1.0).abs() < 1e-6);
        assert_eq!(min_enclosing_circle(&[Vec2::new(4.0, 5.0)]), (Vec2::new(4.0, 5.0), 0.0));
    }

    #[test]
    fn normalisation_maps_height_and_centre() {
        let pts = [Vec3::new(10.0, 2.0, 5.0), Vec3::new(14.0, 22.0, 5.0), Vec3::new(12.0, 12.0, 7.0)];
        let n = compute(&pts).unwrap();
        let q: Vec<Vec3> = pts.iter().map(|&p| n.apply(p)).collect();
        let ys: Vec<f32> = q.iter().map(|p| p.y).collect();
        assert!((ys[0] + 0.9).abs() < 1e-6 && (ys[1] - 0.9).abs() < 1e-6);
        let (c, _) = min_enclosing_circle(&q.iter().map(|p| Vec2::new(p.x, p.z)).collect::<Vec<_>>());
        assert!(c.length() < 1e-5);
        assert!(compute(&[]).is_none());
        assert!(compute(&[Vec3::ONE, Vec3::new(2.0, 1.0, 0.0)]).is_none(), "zero height");
        assert!(compute(&[Vec3::ONE, Vec3::NAN]).is_none());
    }
}
