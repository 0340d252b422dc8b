//! A synthetic, person-like coloured mesh for tests, benches and the gallery example: head, torso, arms and
//! legs as ellipsoids with per-vertex colours (a striped shirt with a logo on the front only, a face on the
//! front and hair on the back of the head), inside the body cube like the reference's normalised subjects.

use glam::Vec3;
use r2human::geometry::TriMesh;

/// An ellipsoid: a UV sphere scaled by `radii` about `center`, normals recomputed.
pub fn ellipsoid(center: Vec3, radii: Vec3, stacks: u32, slices: u32) -> TriMesh {
    let unit = TriMesh::uv_sphere(Vec3::ZERO, 1.0, stacks, slices);
    TriMesh::new(unit.positions.iter().map(|p| center + *p * radii).collect(), unit.triangles)
}

/// Concatenates meshes (normals and colours kept).
pub fn merge(parts: &[TriMesh]) -> TriMesh {
    let mut out = TriMesh::default();
    for p in parts {
        let base = out.positions.len() as u32;
        out.positions.extend_from_slice(&p.positions);
        out.normals.extend_from_slice(&p.normals);
        out.colors.extend_from_slice(&p.colors);
        out.triangles.extend(p.triangles.iter().map(|t| t.map(|i| i + base)));
    }
    out
}

fn coloured(mut m: TriMesh, f: impl Fn(Vec3) -> Vec3) -> TriMesh {
    m.colors = m.positions.iter().map(|&p| f(p)).collect();
    m
}

/// The person, about 1.8 tall (y in [-0.9, 0.9]). `detail` scales the tessellation: 1 gives about 12k
/// triangles, 3 about 110k.
pub fn person(detail: u32) -> TriMesh {
    let d = detail.max(1);
    let skin = Vec3::new(0.75, 0.5, 0.38);
    let hair = Vec3::new(0.2, 0.1, 0.05);
    let trousers = Vec3::new(0.12, 0.14, 0.22);
    let head = coloured(ellipsoid(Vec3::new(0.0, 0.72, 0.0), Vec3::new(0.12, 0.15, 0.13), 24 * d, 48 * d), |p| {
        if p.z < 0.02 || p.y > 0.8 {
            hair
        } else if (p.y - 0.74).abs() < 0.015 && (p.x.abs() - 0.045).abs() < 0.02 {
            Vec3::new(0.05, 0.05, 0.08) // eyes
        } else {
            skin
        }
    });
    let torso = coloured(ellipsoid(Vec3::new(0.0, 0.25, 0.0), Vec3::new(0.25, 0.34, 0.14), 40 * d, 80 * d), |p| {
        if p.z > 0.05 && p.x.abs() < 0.1 && (p.y - 0.35).abs() < 0.08 {
            Vec3::new(0.95, 0.8, 0.1) // logo, front only
        } else if ((p.y * 20.0).floor() as i32).rem_euclid(2) == 0 {
            Vec3::new(0.1, 0.3, 0.7)
        } else {
            Vec3::new(0.8, 0.82, 0.85)
        }
    });
    let arm = |x: f32| {
        coloured(ellipsoid(Vec3::new(x, 0.2, 0.0), Vec3::new(0.055, 0.33, 0.06), 24 * d, 24 * d), move |p| {
            if p.y > 0.35 {
                Vec3::new(0.1, 0.3, 0.7)
            } else {
                skin
            }
        })
    };
    let leg = |x: f32| {
        coloured(ellipsoid(Vec3::new(x, -0.45, 0.0), Vec3::new(0.085, 0.45, 0.09), 32 * d, 24 * d), move |p| {
            if p.y < -0.84 {
                Vec3::new(0.03, 0.03, 0.03)
            } else {
                trousers
            }
        })
    };
    merge(&[head, torso, arm(-0.31), arm(0.31), leg(-0.12), leg(0.12)])
}
