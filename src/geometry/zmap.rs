//! The warping flow and Z-map of paper Eq. 4, and the visibility test of paper Eq. 9, for any pair of cameras.
//!
//! For every covered target pixel `v` with depth `D_t(v)`:
//! `(F_map(v), Z_map(v)) = Pi_other(Pi_target^-1(v, D_t(v)))` — the continuous pixel coordinate of the same
//! surface point in the other (usually the source) camera, and its view depth there (larger is nearer). For the
//! reference's orbit views (rotation `R` about y, orthographic) this is exactly `p_src = R^-1 p_target`.
//!
//! Visibility (Eq. 9): the point is visible in the other camera when its depth there agrees with what the other
//! camera actually sees at the flow, `|z - D_other(flow)| < lambda * s`, with `lambda` = [`VISIBILITY_LAMBDA`] and a
//! positive distance scale `s`:
//! - orthographic other camera: `s = 1 + min(z, D)` — depths of the body cube lie in `[-1, 1]`, so `1 + z` is the
//!   distance from the cube's back face, the reference's own scale (it can be negative: can depths in the cube be
//!   `< -1`, the pixel counts as not visible);
//! - perspective other camera: `s = min(-z, -D)`, the positive distances along the view axis, Eq. 9 verbatim.
//!
//! `D_other(flow)` is read with a **nearest** lookup (the pixel whose square contains the flow point), never a
//! bilinear one: interpolating across a silhouette would mix the background depth (or two surfaces at a
//! self-occlusion edge) into a depth that belongs to no surface and flag false visibility or occlusion. The
//! nearest sample is the other camera's own coverage decision at that point, so points just outside its
//! silhouette read "not covered" and are invisible. The cost is a depth error of half a pixel times the surface
//! slope, which `lambda` absorbs up to about 80 degrees of grazing at 512^2 (`0.02` is five pixels of depth).

use glam::{Affine3A, Vec2, Vec3};
use rayon::prelude::*;

use super::raster::{FastCamera, GBuffer};
use super::Camera;
use crate::buffer::{GrayImage, Image};

/// The visibility threshold `lambda` of paper Eq. 9.
pub const VISIBILITY_LAMBDA: f32 = 0.02;

/// Flow written where there is no valid flow (background, or a point the other camera cannot project): outside
/// every image, so bilinear sampling there reads only the "outside" value. Finite on purpose (no NaN downstream).
pub const FLOW_OUTSIDE: Vec2 = Vec2::new(-1.0, -1.0);

/// Flow and Z-map of one target view with respect to another camera (paper Eq. 4).
#[derive(Clone, Debug, PartialEq)]
pub struct FlowZ {
    /// Continuous pixel coordinate (centres at +0.5) in the other camera's image; [`FLOW_OUTSIDE`] where `mask` is
    /// false.
    pub flow: Image<Vec2>,
    /// View depth in the other camera (larger is nearer); 0 where `mask` is false (the reference zeroes the
    /// background too).
    pub z: GrayImage,
    /// Target pixels that are covered and project into the other camera (in front of a perspective near plane).
    pub mask: Vec<bool>,
}

impl Default for FlowZ {
    fn default() -> Self {
        Self { flow: Image::new(0, 0, FLOW_OUTSIDE), z: Image::new(0, 0, 0.0), mask: Vec::new() }
    }
}

/// Flow and Z-map of paper Eq. 4 for every covered pixel of `target` (rendered by `target_cam`), expressed in
/// `other_cam`. The target buffer's size wins over the camera's when they differ (the projection is scaled).
pub fn flow_and_zmap(target: &GBuffer, target_cam: &Camera, other_cam: &Camera) -> FlowZ {
    let mut out = FlowZ::default();
    flow_and_zmap_into(&mut out, target, target_cam, other_cam);
    out
}

/// [`flow_and_zmap`] into an existing [`FlowZ`], reusing its memory.
pub fn flow_and_zmap_into(out: &mut FlowZ, target: &GBuffer, target_cam: &Camera, other_cam: &Camera) {
    let (w, h) = (target.width, target.height);
    let n = w * h;
    out.flow.width = w;
    out.flow.height = h;
    out.flow.data.clear();
    out.flow.data.resize(n, FLOW_OUTSIDE);
    out.z.width = w;
    out.z.height = h;
    out.z.data.clear();
    out.z.data.resize(n, 0.0);
    out.mask.clear();
    out.mask.resize(n, false);
    if n == 0 || target.depth.len() != n || target.mask.len() != n {
        return;
    }
    let tcam = Camera { width: w, height: h, ..*target_cam };
    let (Some(ft), Some(fo)) = (FastCamera::new(&tcam), FastCamera::new(other_cam)) else { return };
    // Target view -> other view, one rigid transform.
    let m: Affine3A = fo.view_from_world * ft.world_from_view;
    out.flow
        .data
        .par_chunks_mut(w)
        .zip(out.z.data.par_chunks_mut(w))
        .zip(out.mask.par_chunks_mut(w))
        .enumerate()
        .for_each(|(row, ((fr, zr), mr))| {
            let v = row as f32 + 0.5;
            for col in 0..w {
                let i = row * w + col;
                if !target.mask[i] {
                    continue;
                }
                let p_t = ft.unproject_view(col as f32 + 0.5, v, target.depth[i]);
                let Some(q) = fo.project_view(m.transform_point3(p_t)) else { continue };
                if q.is_finite() {
                    fr[col] = Vec2::new(q.x, q.y);
                    zr[col] = q.z;
                    mr[col] = true;
                }
            }
        });
}

/// The positive distance scale of Eq. 9 for depths `a`, `b` seen by an orthographic or perspective camera (see
/// the module docs).
#[inline]
pub fn depth_scale(a: f32, b: f32, orthographic: bool) -> f32 {
    if orthographic {
        1.0 + a.min(b)
    } else {
        (-a).min(-b)
    }
}

/// Visibility of paper Eq. 9: for each target pixel, whether its surface point is the one `other_cam` sees at
/// the flow (`other_depth` is the other camera's G-buffer). False wherever `flowz.mask` is false.
pub fn visibility(flowz: &FlowZ, other_depth: &GBuffer, other_cam: &Camera, lambda: f32) -> Vec<bool> {
    let mut out = Vec::new();
    visibility_into(&mut out, flowz, other_depth, other_cam, lambda);
    out
}

/// [`visibility`] into an existing vector, reusing its memory.
pub fn visibility_into(out: &mut Vec<bool>, flowz: &FlowZ, other: &GBuffer, other_cam: &Camera, lambda: f32) {
    let n = flowz.mask.len();
    out.clear();
    out.resize(n, false);
    let (ow, oh) = (other.width, other.height);
    if ow == 0 || oh == 0 || other.depth.len() != ow * oh || other.mask.len() != ow * oh || other_cam.width == 0 {
        return;
    }
    // The flow is in the camera's pixels; rescale when the buffer has another size.
    let sx = ow as f32 / other_cam.width as f32;
    let sy = oh as f32 / other_cam.height.max(1) as f32;
    let ortho = other_cam.is_orthographic();
    let w = flowz.flow.width.max(1);
    out.par_chunks_mut(w).enumerate().for_each(|(row, vr)| {
        for (col, vis) in vr.iter_mut().enumerate() {
            let i = row * w + col;
            if !flowz.mask[i] {
                continue;
            }
            let f = flowz.flow.data[i];
            let (x, y) = ((f.x * sx).floor(), (f.y * sy).floor());
            if !(x >= 0.0 && y >= 0.0 && x < ow as f32 && y < oh as f32) {
                continue;
            }
            let j = y as usize * ow + x as usize;
            if !other.mask[j] {
                continue;
            }
            let (z, d) = (flowz.z.data[i], other.depth[j]);
            let s = depth_scale(z, d, ortho);
            *vis = s > 0.0 && (z - d).abs() < lambda * s;
        }
    });
}

/// The world point of a covered target pixel (for tests and debugging): `Pi_target^-1(v, D_t)`.
pub fn target_world_point(target: &GBuffer, target_cam: &Camera, col: usize, row: usize) -> Option<Vec3> {
    let i = target.index(col, row);
    target.mask.get(i).copied().filter(|&m| m)?;
    Some(target_cam.unproject(col as f32 + 0.5, row as f32 + 0.5, target.depth[i]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::raster::rasterize;
    use crate::geometry::{Fov, TriMesh};
    use glam::Quat;

    /// A G-buffer with arbitrary depths: the flow must be the closed-form rotation of (x, y, depth).
    #[test]
    fn orbit_zmap_is_the_rotated_coordinates() {
        let res = 64;
        let mut g = GBuffer::new(res, res);
        for (i, (d, m)) in g.depth.iter_mut().zip(g.mask.iter_mut()).enumerate() {
            *d = ((i * 7919) % 1000) as f32 / 500.0 - 1.0; // pseudo-random in [-1, 1)
            *m = i % 3 != 0;
        }
        for yaw in [0.0f32, 17.0, 90.0, 180.0, 243.5, -30.0] {
            let cam = Camera::orbit(yaw, 0.0, res, res);
            let fz = flow_and_zmap(&g, &cam, &Camera::source(res));
            let (s, c) = yaw.to_radians().sin_cos();
            for row in 0..res {
                for col in 0..res {
                    let i = row * res + col;
                    assert_eq!(fz.mask[i], g.mask[i]);
                    if !g.mask[i] {
                        assert_eq!(fz.flow.data[i], FLOW_OUTSIDE);
                        continue;
                    }
                    // Target view coordinates per the reference's pixel convention.
                    let xt = (col as f32 + 0.5) / (res as f32 / 2.0) - 1.0;
                    let yt = 1.0 - (row as f32 + 0.5) / (res as f32 / 2.0);
                    let zt = g.depth[i];
                    // world = Ry(yaw) * view.
                    let xs = c * xt + s * zt;
                    let zs = -s * xt + c * zt;
                    let u = (xs + 1.0) * res as f32 / 2.0;
                    let v = (1.0 - yt) * res as f32 / 2.0;
                    let f = fz.flow.data[i];
                    assert!((f.x - u).abs() < 1e-4 && (f.y - v).abs() < 1e-4, "yaw {yaw}: {f} vs {u},{v}");
                    assert!((fz.z.data[i] - zs).abs() < 1e-5);
                }
            }
        }
    }

    #[test]
    fn general_cameras_round_trip_through_world() {
        let mesh = TriMesh::uv_sphere(Vec3::new(0.1, 0.0, 0.0), 0.6, 24, 48);
        let fov = Fov::symmetric(1.0, 1.0);
        let persp = Camera::perspective(Vec3::new(0.5, 0.3, 2.5), Quat::from_rotation_y(0.2), fov, 0.05, 48, 48);
        let orbit = Camera::orbit(60.0, 25.0, 40, 40);
        for (t, o) in [(persp, orbit), (orbit, persp), (persp, Camera::source(32))] {
            let g = rasterize(&mesh, &t);
            let fz = flow_and_zmap(&g, &t, &o);
            let mut n = 0;
            for row in 0..g.height {
                for col in 0..g.width {
                    let Some(wp) = target_world_point(&g, &t, col, row) else { continue };
                    let i = g.index(col, row);
                    let q = o.project(wp);
                    assert_eq!(fz.mask[i], q.is_some());
                    if let Some(q) = q {
                        let f = fz.flow.data[i];
                        assert!((f - q.truncate()).abs().max_element() < 2e-3);
                        assert!((fz.z.data[i] - q.z).abs() < 1e-4);
                        n += 1;
                    }
                }
            }
            assert!(n > 100);
        }
    }

    fn sphere() -> TriMesh {
        TriMesh::uv_sphere(Vec3::ZERO, 0.7, 48, 96)
    }

    #[test]
    fn identity_view_is_fully_visible() {
        let src = Camera::source(96);
        let g = rasterize(&sphere(), &src);
        let fz = flow_and_zmap(&g, &src, &src);
        let vis = visibility(&fz, &g, &src, VISIBILITY_LAMBDA);
        assert_eq!(vis, g.mask);
    }

    #[test]
    fn sphere_side_view_sees_the_front_half() {
        let src = Camera::source(128);
        let gs = rasterize(&sphere(), &src);
        let tgt = Camera::orbit(90.0, 0.0, 128, 128);
        let gt = rasterize(&sphere(), &tgt);
        let fz = flow_and_zmap(&gt, &tgt, &src);
        let vis = visibility(&fz, &gs, &src, VISIBILITY_LAMBDA);
        let (mut checked, mut wrong) = (0, 0);
        for row in 0..128 {
            for col in 0..128 {
                let Some(p) = target_world_point(&gt, &tgt, col, row) else { continue };
                let i = row * 128 + col;
                // Behind the terminator z = 0 nothing may be visible (false visibility would pull wrong colours).
                // In front, the nearest lookup may reject grazing points (half a pixel times the slope exceeds
                // lambda near the silhouette at this resolution); away from grazing all must be visible.
                let grazing = p.z / 0.7 < 0.4;
                if p.z < -0.05 || (p.z > 0.0 && !grazing) {
                    checked += 1;
                    if vis[i] != (p.z > 0.0) {
                        wrong += 1;
                        eprintln!("{col},{row} {p} vis {} flow {} z {}", vis[i], fz.flow.data[i], fz.z.data[i]);
                    }
                }
            }
        }
        assert!(checked > 3000, "{checked}");
        assert_eq!(wrong, 0);
    }

    #[test]
    fn sphere_back_view_is_invisible_except_the_rim() {
        let src = Camera::source(128);
        let gs = rasterize(&sphere(), &src);
        let tgt = Camera::orbit(180.0, 0.0, 128, 128);
        let gt = rasterize(&sphere(), &tgt);
        let fz = flow_and_zmap(&gt, &tgt, &src);
        let vis = visibility(&fz, &gs, &src, VISIBILITY_LAMBDA);
        let mut visible = 0;
        for (i, &v) in vis.iter().enumerate() {
            if v {
                visible += 1;
                let p = target_world_point(&gt, &tgt, i % 128, i / 128).unwrap();
                let radial = (p.x * p.x + p.y * p.y).sqrt();
                assert!(radial > 0.7 * 0.95, "visible pixel away from the rim: {p}");
            }
        }
        assert!(visible < gt.coverage() / 20, "{visible} of {}", gt.coverage());
    }

    #[test]
    fn depth_scale_is_positive_in_the_cube_and_for_points_in_front() {
        assert!((depth_scale(-0.2, 0.3, true) - 0.8).abs() < 1e-6);
        assert!((depth_scale(-2.0, -3.0, false) - 2.0).abs() < 1e-6);
        assert!(depth_scale(-1.5, 0.0, true) < 0.0);
    }
}
