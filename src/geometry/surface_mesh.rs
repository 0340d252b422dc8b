//! The frame path's geometry: a person given as front and back depth maps with one shell per column (the
//! silhouette-inflation prior and everything built on it, [`InflatedSurfaces`]) becomes a mesh and a source view
//! directly, without the Fourier occupancy field.
//!
//! - [`mesh_from_surfaces`]: the two height fields sampled every `step` pixels, joined along the outline by a wall
//!   of quads (a closed, consistently wound mesh). A 512² input at step 2 gives about a tenth of the triangles of
//!   the FOF's marching cubes, most of which are smaller than a pixel of any view.
//! - [`source_gbuffer`]: what the source camera sees of the same surfaces, read off the front map at every pixel
//!   (depth = the front, normal = from the front's slopes) instead of rasterising the mesh back.
//!
//! A column with more than one shell cannot be written as two depth maps: such geometry (the FOF network's, the
//! body prior's) keeps the FOF path (`pipeline::still`).

use glam::Vec3;

use super::inflate::InflatedSurfaces;
use super::mesh::TriMesh;
use super::raster::{GBuffer, BACKGROUND_DEPTH};
use crate::buffer::GrayImage;

/// Why [`mesh_from_surfaces`] made no mesh.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SurfaceMeshError {
    /// The three maps are not the same size, or are empty.
    #[error("front, back and mask maps differ in size or are empty ({front:?}, {back:?}, {mask:?})")]
    Sizes {
        /// Front map size.
        front: (usize, usize),
        /// Back map size.
        back: (usize, usize),
        /// Mask size.
        mask: (usize, usize),
    },
    /// The step is 0.
    #[error("the sampling step must be at least 1 pixel")]
    Step,
    /// A masked depth is not finite, or the back lies in front of the front.
    #[error("pixel {index}: front {front} and back {back} are not a finite interval")]
    BadInterval {
        /// Row-major pixel index.
        index: usize,
        /// Front depth there.
        front: f32,
        /// Back depth there.
        back: f32,
    },
    /// No 2x2 block of samples (3 of 4) lies inside the mask: nothing to triangulate at this step.
    #[error("the mask holds no triangle at a step of {step} px")]
    Empty {
        /// The step.
        step: usize,
    },
}

/// Whether pixel `i` of `mask` belongs to the person (the threshold every stage uses).
#[inline]
fn inside(mask: &GrayImage, i: usize) -> bool {
    mask.data[i] > 0.5
}

fn check(s: &InflatedSurfaces) -> Result<(usize, usize), SurfaceMeshError> {
    let size = |m: &GrayImage| (m.width, m.height);
    let (w, h) = size(&s.mask);
    if size(&s.front) != (w, h) || size(&s.back) != (w, h) || w == 0 || h == 0 || s.mask.data.len() != w * h {
        return Err(SurfaceMeshError::Sizes { front: size(&s.front), back: size(&s.back), mask: (w, h) });
    }
    for i in (0..w * h).filter(|&i| inside(&s.mask, i)) {
        let (front, back) = (s.front.data[i], s.back.data[i]);
        if !(front.is_finite() && back.is_finite()) || back > front {
            return Err(SurfaceMeshError::BadInterval { index: i, front, back });
        }
    }
    Ok((w, h))
}

/// The body-cube point of pixel `(col, row)` of a `w` x `h` source grid at depth `z` (the source camera's pixel
/// centres, [`crate::geometry::Camera::source`]).
#[inline]
fn point(col: usize, row: usize, w: usize, h: usize, z: f32) -> Vec3 {
    Vec3::new((col as f32 + 0.5) / (w as f32 * 0.5) - 1.0, 1.0 - (row as f32 + 0.5) / (h as f32 * 0.5), z)
}

/// A closed mesh of `surfaces` sampled at every `step`-th pixel centre of the mask: the front height field
/// (facing +z), the back one (facing -z) and a wall joining them along every outline edge, so each edge is shared
/// by exactly two triangles of opposite direction. A 2x2 block of samples gives two triangles when all four lie
/// in the mask and one (over the three) when three do, so the outline is followed to within one step along the
/// diagonals as well. The mesh's normals are its area-weighted vertex normals ([`TriMesh::compute_normals`]).
pub fn mesh_from_surfaces(surfaces: &InflatedSurfaces, step: usize) -> Result<TriMesh, SurfaceMeshError> {
    if step == 0 {
        return Err(SurfaceMeshError::Step);
    }
    let (w, h) = check(surfaces)?;
    let (gw, gh) = ((w - 1) / step + 1, (h - 1) / step + 1);
    // Sample index -> front vertex index (u32::MAX: outside the mask); the back vertex is front + count.
    let mut index = vec![u32::MAX; gw * gh];
    let mut front = Vec::new();
    let mut back = Vec::new();
    for gr in 0..gh {
        for gc in 0..gw {
            let (c, r) = (gc * step, gr * step);
            let i = r * w + c;
            if inside(&surfaces.mask, i) {
                index[gr * gw + gc] = front.len() as u32;
                front.push(point(c, r, w, h, surfaces.front.data[i]));
                back.push(point(c, r, w, h, surfaces.back.data[i]));
            }
        }
    }
    let count = front.len() as u32;
    let mut triangles: Vec<[u32; 3]> = Vec::new();
    let at = |gc: usize, gr: usize| index[gr * gw + gc];
    for gr in 0..gh.saturating_sub(1) {
        for gc in 0..gw.saturating_sub(1) {
            // Corners: a top-left, b bottom-left, c top-right, d bottom-right. (a, b, c) winds counter-clockwise
            // seen from +z (x right, y up; rows go down).
            let (a, b, c, d) = (at(gc, gr), at(gc, gr + 1), at(gc + 1, gr), at(gc + 1, gr + 1));
            let n = [a, b, c, d].iter().filter(|&&v| v != u32::MAX).count();
            match n {
                4 => {
                    // The diagonal along the smaller depth jump keeps creases where the surface has them.
                    let f = |v: u32| front[v as usize].z;
                    if (f(a) - f(d)).abs() <= (f(b) - f(c)).abs() {
                        triangles.push([a, b, d]);
                        triangles.push([a, d, c]);
                    } else {
                        triangles.push([a, b, c]);
                        triangles.push([b, d, c]);
                    }
                }
                3 => triangles.push(match () {
                    _ if a == u32::MAX => [b, d, c],
                    _ if b == u32::MAX => [a, d, c],
                    _ if c == u32::MAX => [a, b, d],
                    _ => [a, b, c],
                }),
                _ => {}
            }
        }
    }
    if triangles.is_empty() {
        return Err(SurfaceMeshError::Empty { step });
    }
    let outline = outline_edges(&index, gw, gh);
    let front_count = triangles.len();
    triangles.reserve(front_count + 2 * outline.len());
    for k in 0..front_count {
        let [p, q, r] = triangles[k];
        triangles.push([p + count, r + count, q + count]);
    }
    for (p, q) in outline {
        // The front holds p -> q and the back q' -> p': the wall holds q -> p and p' -> q'.
        triangles.push([q, p, p + count]);
        triangles.push([q, p + count, q + count]);
    }
    front.extend(back);
    Ok(TriMesh::new(front, triangles))
}

/// The front's outline: every directed edge of the front triangles of [`mesh_from_surfaces`] whose reverse no front
/// triangle holds, in the direction the front traverses it, read off the grid instead of searching the triangles.
/// A cell (2x2 samples, `index` of its corners `u32::MAX` where outside) with three or four corners covers each
/// of its sides whose two ends it has; a side covered by one cell only is outline, and so is the long side of a
/// three-corner cell. Every cell winds counter-clockwise seen from +z: its top side right to left, its left side
/// top to bottom, its bottom side left to right, its right side bottom to top.
fn outline_edges(index: &[u32], gw: usize, gh: usize) -> Vec<(u32, u32)> {
    const NONE: u32 = u32::MAX;
    let at = |gc: usize, gr: usize| index[gr * gw + gc];
    // Corners of the cell whose top-left sample is (gc, gr), when it holds a triangle.
    let cell = |gc: usize, gr: usize| -> Option<[u32; 4]> {
        if gc + 1 >= gw || gr + 1 >= gh {
            return None;
        }
        let c = [at(gc, gr), at(gc, gr + 1), at(gc + 1, gr), at(gc + 1, gr + 1)];
        (c.iter().filter(|&&v| v != NONE).count() >= 3).then_some(c)
    };
    let mut outline = Vec::new();
    for gr in 0..gh {
        for gc in 0..gw {
            // The long side of a three-corner cell (whose top-left corner may be the one missing).
            if let Some([a, b, c, d]) = cell(gc, gr) {
                match () {
                    _ if a == NONE => outline.push((c, b)),
                    _ if b == NONE => outline.push((a, d)),
                    _ if c == NONE => outline.push((d, a)),
                    _ if d == NONE => outline.push((b, c)),
                    _ => {}
                }
            }
            let here = at(gc, gr);
            if here == NONE {
                continue;
            }
            // The horizontal side from (gc, gr) to (gc + 1, gr): the bottom of the cell above, the top of the cell
            // below.
            if gc + 1 < gw && at(gc + 1, gr) != NONE {
                let right = at(gc + 1, gr);
                let above = gr > 0 && cell(gc, gr - 1).is_some();
                let below = cell(gc, gr).is_some();
                match (above, below) {
                    (true, false) => outline.push((here, right)),
                    (false, true) => outline.push((right, here)),
                    _ => {}
                }
            }
            // The vertical side from (gc, gr) to (gc, gr + 1): the right of the cell to the left, the left of the
            // cell to the right.
            if gr + 1 < gh && at(gc, gr + 1) != NONE {
                let down = at(gc, gr + 1);
                let left = gc > 0 && cell(gc - 1, gr).is_some();
                let right = cell(gc, gr).is_some();
                match (left, right) {
                    (true, false) => outline.push((down, here)),
                    (false, true) => outline.push((here, down)),
                    _ => {}
                }
            }
        }
    }
    outline
}

/// What the source camera sees of `surfaces`: at every masked pixel the front's depth and the normal of the front
/// height field there (central differences, one-sided beside the outline, flat where a pixel has no masked
/// neighbour on an axis), in the source camera's view space (the body cube's axes). Unmasked pixels are
/// background. Same-sized maps are assumed ([`mesh_from_surfaces`] checks them).
pub fn source_gbuffer(surfaces: &InflatedSurfaces) -> GBuffer {
    let (w, h) = (surfaces.mask.width, surfaces.mask.height);
    let mut g = GBuffer::new(w, h);
    if surfaces.front.data.len() != w * h || surfaces.mask.data.len() != w * h {
        return g;
    }
    let z = &surfaces.front.data;
    let is_in = |c: usize, r: usize| inside(&surfaces.mask, r * w + c);
    // Body-cube units per pixel along x and y.
    let (dx, dy) = (2.0 / w as f32, 2.0 / h as f32);
    // The slope along one axis from the masked neighbours `lo` and `hi` of pixel `i` (`None`: not in the mask).
    let slope = |i: usize, lo: Option<usize>, hi: Option<usize>, spacing: f32| match (lo, hi) {
        (Some(l), Some(u)) => (z[u] - z[l]) / (2.0 * spacing),
        (Some(l), None) => (z[i] - z[l]) / spacing,
        (None, Some(u)) => (z[u] - z[i]) / spacing,
        (None, None) => 0.0,
    };
    for r in 0..h {
        for c in 0..w {
            let i = r * w + c;
            if !is_in(c, r) {
                continue;
            }
            let left = (c > 0 && is_in(c - 1, r)).then(|| i - 1);
            let right = (c + 1 < w && is_in(c + 1, r)).then_some(i + 1);
            // y grows upward: the row above is the higher neighbour.
            let below = (r + 1 < h && is_in(c, r + 1)).then_some(i + w);
            let above = (r > 0 && is_in(c, r - 1)).then(|| i - w);
            let (sx, sy) = (slope(i, left, right, dx), slope(i, below, above, dy));
            let n = Vec3::new(-sx, -sy, 1.0).try_normalize().unwrap_or(Vec3::Z);
            g.depth[i] = z[i];
            g.normal[i] = if n.is_finite() { n } else { Vec3::Z };
            g.mask[i] = true;
        }
    }
    debug_assert!(g.depth.iter().all(|d| d.is_finite() || *d == BACKGROUND_DEPTH));
    g
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::raster::rasterize;
    use crate::geometry::Camera;

    /// A sphere of radius `r` about the cube's centre (shifted by `cz` in depth) as two depth maps on an `n`² grid:
    /// the exact front and back of every column inside its disc.
    fn ellipsoid(n: usize, rx: f32, ry: f32, rz: f32, cz: f32) -> InflatedSurfaces {
        let mut s = InflatedSurfaces {
            front: GrayImage::new(n, n, -1.0),
            back: GrayImage::new(n, n, -1.0),
            mask: GrayImage::new(n, n, 0.0),
        };
        for r in 0..n {
            for c in 0..n {
                let p = point(c, r, n, n, 0.0);
                let q = 1.0 - (p.x / rx).powi(2) - (p.y / ry).powi(2);
                if q > 0.0 {
                    let half = rz * q.sqrt();
                    let i = r * n + c;
                    s.front.data[i] = cz + half;
                    s.back.data[i] = cz - half;
                    s.mask.data[i] = 1.0;
                }
            }
        }
        s
    }

    #[test]
    fn the_mesh_is_closed_and_wound_outward() {
        let s = ellipsoid(64, 0.6, 0.8, 0.4, 0.1);
        for step in [1, 2, 3] {
            let mesh = mesh_from_surfaces(&s, step).unwrap();
            // Every directed edge is matched by its reverse as often as it appears: closed (no boundary) and
            // consistently wound. (Twice at most: where the outline touches itself at one sample, two wall quads
            // meet there.)
            let mut edges = std::collections::HashMap::new();
            for t in &mesh.triangles {
                for k in 0..3 {
                    *edges.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
                }
            }
            assert!(edges.iter().all(|(&(p, q), &n)| n <= 2 && edges.get(&(q, p)) == Some(&n)), "step {step}");
            // Outward: positive volume, close to the ellipsoid's 4/3 pi a b c (the sampled outline lies inside).
            let exact = 4.0 / 3.0 * std::f32::consts::PI * 0.6 * 0.8 * 0.4;
            let v = mesh.signed_volume();
            assert!(v > 0.85 * exact && v <= 1.01 * exact, "step {step}: volume {v} against {exact}");
        }
    }

    #[test]
    fn the_mesh_lies_on_the_ellipsoid() {
        let (rx, ry, rz, cz) = (0.5, 0.7, 0.3, -0.2);
        let mesh = mesh_from_surfaces(&ellipsoid(128, rx, ry, rz, cz), 2).unwrap();
        for p in &mesh.positions {
            let q = (p.x / rx).powi(2) + (p.y / ry).powi(2) + ((p.z - cz) / rz).powi(2);
            assert!((q - 1.0).abs() < 1e-4, "{p:?}: {q}");
        }
    }

    #[test]
    fn the_source_view_is_the_raster_of_the_mesh() {
        // At step 1 the mesh's own source raster and the maps agree: depth to the facets' chord error, normals
        // to a few degrees away from the outline.
        let s = ellipsoid(96, 0.6, 0.75, 0.45, 0.05);
        let mesh = mesh_from_surfaces(&s, 1).unwrap();
        let raster = rasterize(&mesh, &Camera::source(96));
        let maps = source_gbuffer(&s);
        let (mut compared, mut worst_depth, mut worst_angle) = (0, 0f32, 0f32);
        for r in 0..96usize {
            for c in 0..96usize {
                let i = r * 96 + c;
                // Interior pixels (two pixels from the outline), where both see the front.
                let interior = (r.saturating_sub(2)..=(r + 2).min(95))
                    .all(|rr| (c.saturating_sub(2)..=(c + 2).min(95)).all(|cc| s.mask.data[rr * 96 + cc] > 0.5));
                if !interior {
                    continue;
                }
                assert!(raster.mask[i] && maps.mask[i]);
                compared += 1;
                worst_depth = worst_depth.max((raster.depth[i] - maps.depth[i]).abs());
                worst_angle = worst_angle.max(raster.normal[i].angle_between(maps.normal[i]).to_degrees());
            }
        }
        assert!(compared > 2500, "{compared}");
        assert!(worst_depth < 1e-3, "depth {worst_depth}");
        assert!(worst_angle < 8.0, "normal {worst_angle} degrees");
    }

    #[test]
    fn the_frame_mesh_draws_what_the_fof_path_draws() {
        // An ellipsoid's depth maps at 128², meshed directly (step 2) and through the still path's FOF (N = 32) and
        // marching cubes (128 depth samples): from the front and from the side, the two cover the same pixels and
        // lie at the same depth to within the FOF's own blur.
        let n = 128;
        let s = ellipsoid(n, 0.55, 0.8, 0.35, 0.05);
        let direct = mesh_from_surfaces(&s, 2).unwrap();
        let fof = crate::geometry::fof::Fof::from_depth_maps(&s.front, &s.back, &s.mask, 32).unwrap();
        let still = crate::geometry::marching::extract_mesh(&fof, n);
        for yaw in [0.0f32, 90.0, 180.0] {
            let camera = Camera::orbit(yaw, 0.0, n, n);
            let (a, b) = (rasterize(&direct, &camera), rasterize(&still, &camera));
            let both = a.mask.iter().zip(&b.mask).filter(|(x, y)| **x && **y).count();
            let either = a.mask.iter().zip(&b.mask).filter(|(x, y)| **x || **y).count();
            let iou = both as f32 / either as f32;
            let mut errors: Vec<f32> =
                (0..n * n).filter(|&i| a.mask[i] && b.mask[i]).map(|i| (a.depth[i] - b.depth[i]).abs()).collect();
            errors.sort_by(f32::total_cmp);
            let median = errors[errors.len() / 2];
            // Measured: IoU 0.958 / 0.992 / 0.957 (the outline sampled every 2 px of a 128² grid), median depth
            // difference 0.0003-0.0017 cube units.
            assert!(iou > 0.94, "yaw {yaw}: mask IoU {iou}");
            assert!(median < 0.005, "yaw {yaw}: median depth difference {median} cube units");
        }
    }

    #[test]
    fn source_normals_in_closed_form() {
        // A plane z = 0.2 + 0.3 x - 0.1 y: normal (-0.3, 0.1, 1) normalised everywhere, the rim included.
        let n = 16;
        let mut s = InflatedSurfaces {
            front: GrayImage::new(n, n, -1.0),
            back: GrayImage::new(n, n, -1.0),
            mask: GrayImage::new(n, n, 0.0),
        };
        for r in 2..14 {
            for c in 2..14 {
                let p = point(c, r, n, n, 0.0);
                let i = r * n + c;
                s.front.data[i] = 0.2 + 0.3 * p.x - 0.1 * p.y;
                s.back.data[i] = -0.5;
                s.mask.data[i] = 1.0;
            }
        }
        let g = source_gbuffer(&s);
        let want = Vec3::new(-0.3, 0.1, 1.0).normalize();
        for i in 0..n * n {
            if s.mask.data[i] > 0.5 {
                assert!(g.mask[i] && (g.normal[i] - want).length() < 1e-5, "{i}: {:?}", g.normal[i]);
                assert_eq!(g.depth[i], s.front.data[i]);
            } else {
                assert!(!g.mask[i] && g.depth[i] == BACKGROUND_DEPTH);
            }
        }
    }

    #[test]
    fn degenerate_masks_give_an_error_or_a_finite_mesh() {
        let n = 32;
        let empty = InflatedSurfaces {
            front: GrayImage::new(n, n, -1.0),
            back: GrayImage::new(n, n, -1.0),
            mask: GrayImage::new(n, n, 0.0),
        };
        assert_eq!(mesh_from_surfaces(&empty, 1), Err(SurfaceMeshError::Empty { step: 1 }));
        // One pixel: no triangle at any step, and a finite one-pixel source view.
        let mut one = empty.clone();
        one.mask.data[5 * n + 7] = 1.0;
        one.front.data[5 * n + 7] = 0.1;
        one.back.data[5 * n + 7] = -0.1;
        assert!(matches!(mesh_from_surfaces(&one, 1), Err(SurfaceMeshError::Empty { .. })));
        let g = source_gbuffer(&one);
        assert_eq!(g.coverage(), 1);
        assert_eq!(g.normal[5 * n + 7], Vec3::Z);
        // A one-pixel-wide line: no area, no triangle.
        let mut line = empty.clone();
        for r in 0..n {
            line.mask.data[r * n + 9] = 1.0;
            line.front.data[r * n + 9] = 0.05;
            line.back.data[r * n + 9] = -0.05;
        }
        assert!(matches!(mesh_from_surfaces(&line, 1), Err(SurfaceMeshError::Empty { .. })));
        assert!(source_gbuffer(&line).normal.iter().all(|v| v.is_finite()));
        // The full frame: closed, finite.
        let mut full = empty.clone();
        full.mask.data.fill(1.0);
        full.front.data.fill(0.3);
        full.back.data.fill(-0.3);
        let mesh = mesh_from_surfaces(&full, 4).unwrap();
        assert!(mesh.validate().is_ok());
        assert!(mesh.signed_volume() > 0.0);
        // Bad input is refused, never a NaN vertex.
        let mut nan = full.clone();
        nan.front.data[3] = f32::NAN;
        assert!(matches!(mesh_from_surfaces(&nan, 1), Err(SurfaceMeshError::BadInterval { index: 3, .. })));
        let mut reversed = full.clone();
        reversed.back.data[4] = 0.9;
        assert!(matches!(mesh_from_surfaces(&reversed, 1), Err(SurfaceMeshError::BadInterval { index: 4, .. })));
        assert_eq!(mesh_from_surfaces(&full, 0), Err(SurfaceMeshError::Step));
        let mut small = full.clone();
        small.back = GrayImage::new(3, 3, 0.0);
        assert!(matches!(mesh_from_surfaces(&small, 1), Err(SurfaceMeshError::Sizes { .. })));
    }
}
