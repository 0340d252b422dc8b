//! The frame path's geometry: a person given as front and back depth maps with one shell per column (the
//! silhouette-inflation prior and everything built on it, [`InflatedSurfaces`]) becomes a mesh and a source view
//! directly, without the Fourier occupancy field.
//!
//! - [`mesh_from_surfaces`]: the two height fields sampled every `step` pixels, joined along the outline by a wall
//!   of quads (a closed, consistently wound mesh) whose outline lies on the mask's edge. A 512² input at step 2 gives about a tenth of the triangles of
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
use crate::buffer::{sample_bilinear, GrayImage};

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

/// The body-cube point at `(x, y)` pixels from the source grid's top-left corner (pixel `(c, r)`'s centre is at
/// `(c + 0.5, r + 0.5)`) at depth `z`.
#[inline]
fn point_at(x: f32, y: f32, w: usize, h: usize, z: f32) -> Vec3 {
    Vec3::new(x / (w as f32 * 0.5) - 1.0, 1.0 - y / (h as f32 * 0.5), z)
}

/// The body-cube point of pixel `(col, row)` of a `w` x `h` source grid at depth `z` (the source camera's pixel
/// centres, [`crate::geometry::Camera::source`]).
#[inline]
fn point(col: usize, row: usize, w: usize, h: usize, z: f32) -> Vec3 {
    point_at(col as f32 + 0.5, row as f32 + 0.5, w, h, z)
}

/// A closed mesh of `surfaces` sampled at every `step`-th pixel centre of the mask: the front height field
/// (facing +z), the back one (facing -z) and a wall joining them along every outline edge, so each edge is shared
/// by exactly two triangles of opposite direction. A 2x2 block of samples gives two triangles when all four lie
/// in the mask and one (over the three) when three do, so the outline is followed to within one step along the
/// diagonals as well. The outline's samples then move out along the outline's normal to the mask's edge (where the
/// mask, bilinear between pixel centres, falls to 0.5; [`rim_positions`]), keeping their depths, so the mesh covers
/// the mask's pixels as the FOF path's marching cubes do instead of stopping up to a step inside them. The mesh's
/// normals are its area-weighted vertex normals ([`TriMesh::compute_normals`]).
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
    let pixels: Vec<[usize; 2]> =
        (0..gw * gh).filter(|&k| index[k] != u32::MAX).map(|k| [(k % gw) * step, (k / gw) * step]).collect();
    for (v, [x, y], i) in rim_positions(&surfaces.mask, &pixels, &outline, &triangles, step) {
        front[v as usize] = point_at(x, y, w, h, surfaces.front.data[i]);
        back[v as usize] = point_at(x, y, w, h, surfaces.back.data[i]);
    }
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

/// Where the outline samples of [`mesh_from_surfaces`] move to: each outline vertex (`pixels`: every front
/// vertex's sample pixel; `outline`: the front's outline edges) goes along its outward normal (the mean of its two
/// outline edges' normals) to where the mask, bilinear between pixel centres, first falls to 0.5: the mask's edge,
/// where the FOF path's marching cubes put the silhouette. At most `step` √2 pixels (a diagonal of the sample grid);
/// a vertex where the outline touches itself, or whose normal cancels, stays. A move that would shrink one of
/// the front `triangles` to under a tenth of its area or flip it is undone, so the mesh keeps its winding.
/// Returns `(vertex, [x, y], pixel)`: the new position in pixels from the grid's top-left corner and the row-major
/// index of the inside pixel whose depths it takes (the one it lies in, else the last inside one on its way out:
/// the outermost column, as the FOF path's wall has it, so the rim's front agrees with the source view's).
fn rim_positions(
    mask: &GrayImage,
    pixels: &[[usize; 2]],
    outline: &[(u32, u32)],
    triangles: &[[u32; 3]],
    step: usize,
) -> Vec<(u32, [f32; 2], usize)> {
    let centre = |v: u32| {
        let [c, r] = pixels[v as usize];
        [c as f32 + 0.5, r as f32 + 0.5]
    };
    let mut normal = vec![([0f32; 2], 0u8); pixels.len()];
    for &(p, q) in outline {
        let ([px, py], [qx, qy]) = (centre(p), centre(q));
        let (ex, ey) = (qx - px, qy - py);
        let length = (ex * ex + ey * ey).sqrt();
        if length <= 0.0 {
            continue;
        }
        // Pixel rows go down; the front winds counter-clockwise seen from +z, so the outside is at (-ey, ex).
        for v in [p, q] {
            let (n, count) = &mut normal[v as usize];
            (n[0], n[1]) = (n[0] - ey / length, n[1] + ex / length);
            *count = count.saturating_add(1);
        }
    }
    let reach = step as f32 * std::f32::consts::SQRT_2;
    let march = 0.25f32;
    let mut position: Vec<[f32; 2]> = (0..pixels.len() as u32).map(centre).collect();
    let mut moved = vec![false; pixels.len()];
    for (v, &([nx, ny], count)) in normal.iter().enumerate() {
        let length = (nx * nx + ny * ny).sqrt();
        if count != 2 || length < 1e-3 {
            continue;
        }
        let (dx, dy) = (nx / length, ny / length);
        let [x0, y0] = position[v];
        // The mask bilinear between pixel centres, 0 beyond the grid (a mask touching the border ends there).
        let at = |t: f32| sample_bilinear(mask, x0 + t * dx, y0 + t * dy, 0.0);
        // The first step along the normal where the mask is no longer inside, then bisection down to 1/1000 px.
        let mut t = 0.0f32;
        let mut out = None;
        while t < reach {
            let next = (t + march).min(reach);
            if at(next) <= 0.5 {
                out = Some(next);
                break;
            }
            t = next;
        }
        let t = match out {
            Some(mut hi) => {
                let mut lo = t;
                for _ in 0..8 {
                    let mid = 0.5 * (lo + hi);
                    if at(mid) > 0.5 {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                0.5 * (lo + hi)
            }
            None => reach,
        };
        if t.is_finite() && t > 0.0 {
            position[v] = [x0 + t * dx, y0 + t * dy];
            moved[v] = true;
        }
    }
    // Undo the moves of any triangle they would flip or crush, until none does (all undone gives the grid back).
    let area = |p: &[[f32; 2]], [a, b, c]: [u32; 3]| {
        let ([ax, ay], [bx, by], [cx, cy]) = (p[a as usize], p[b as usize], p[c as usize]);
        (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    };
    let grid: Vec<[f32; 2]> = (0..pixels.len() as u32).map(centre).collect();
    loop {
        let mut undone = false;
        for &t in triangles {
            if !t.iter().any(|&v| moved[v as usize]) {
                continue;
            }
            let before = area(&grid, t);
            let after = area(&position, t);
            // Written so that a NaN area is undone too.
            let kept = after * before.signum() >= 0.1 * before.abs();
            if !kept {
                for v in t {
                    position[v as usize] = grid[v as usize];
                    moved[v as usize] = false;
                }
                undone = true;
            }
        }
        if !undone {
            break;
        }
    }
    // The inside pixel under each moved vertex: walking back to its sample (inside) from just within the edge.
    let pixel_of = |[x, y]: [f32; 2]| -> Option<usize> {
        let (c, r) = (x.floor(), y.floor());
        let inside_grid = c >= 0.0 && r >= 0.0 && (c as usize) < mask.width && (r as usize) < mask.height;
        let i = r as usize * mask.width + c as usize;
        (inside_grid && mask.data.get(i).is_some_and(|&m| m > 0.5)).then_some(i)
    };
    (0..pixels.len())
        .filter(|&v| moved[v])
        .map(|v| {
            let ([x, y], [x0, y0]) = (position[v], grid[v]);
            let distance = ((x - x0).powi(2) + (y - y0).powi(2)).sqrt();
            let [c, r] = pixels[v];
            let sample = r * mask.width + c;
            let along = |t: f32| [x0 + (x - x0) * t, y0 + (y - y0) * t];
            // From 1/1000 px inside the edge back to the sample in quarter pixels.
            let back_steps = (distance / 0.25).ceil() as usize;
            let first = 1.0 - 1e-3 / distance.max(1e-3);
            let pixel = (0..=back_steps)
                .map(|k| (first - k as f32 * 0.25 / distance.max(1e-3)).max(0.0))
                .find_map(|t| pixel_of(along(t)))
                .unwrap_or(sample);
            (v as u32, position[v], pixel)
        })
        .collect()
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
            // Outward: positive volume, close to the ellipsoid's 4/3 pi a b c (the outline on the mask's edge, its
            // wall as thick as the samples it moved from).
            let exact = 4.0 / 3.0 * std::f32::consts::PI * 0.6 * 0.8 * 0.4;
            let v = mesh.signed_volume();
            assert!(v > 0.95 * exact && v <= 1.05 * exact, "step {step}: volume {v} against {exact}");
        }
    }

    /// The xy area of triangle `t` of `mesh` in the body cube, positive counter-clockwise seen from +z.
    fn xy_area(mesh: &TriMesh, t: [u32; 3]) -> f32 {
        let [a, b, c] = t.map(|v| mesh.positions[v as usize]);
        0.5 * ((b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x))
    }

    /// The outline's vertices: those of a wall (a triangle with no area seen from +z).
    fn rim_vertices(mesh: &TriMesh) -> Vec<bool> {
        let mut rim = vec![false; mesh.positions.len()];
        for &t in &mesh.triangles {
            if xy_area(mesh, t).abs() < 1e-9 {
                t.iter().for_each(|&v| rim[v as usize] = true);
            }
        }
        rim
    }

    /// Closed and consistently wound (every directed edge matched by its reverse as often), and no front triangle
    /// (all its vertices in the first half, the front's) flipped or crushed to nothing seen from +z.
    fn assert_closed_and_unflipped(mesh: &TriMesh, what: &str) {
        let mut edges = std::collections::HashMap::new();
        for t in &mesh.triangles {
            for k in 0..3 {
                *edges.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
            }
        }
        assert!(edges.iter().all(|(&(p, q), &n)| n <= 2 && edges.get(&(q, p)) == Some(&n)), "{what}: not closed");
        let half = (mesh.positions.len() / 2) as u32;
        for &t in &mesh.triangles {
            if t.iter().all(|&v| v < half) {
                assert!(xy_area(mesh, t) > 0.0, "{what}: front triangle {t:?} flipped");
            }
        }
        assert!(mesh.positions.iter().all(|p| p.is_finite()), "{what}: a vertex is not finite");
    }

    #[test]
    fn the_outline_lies_on_the_mask_edge() {
        // An ellipse's mask anti-aliased (each pixel's covered fraction, 16² samples) and the ellipsoid's depths:
        // the outline vertices lie on the analytic ellipse and the mesh's silhouette (its projected area, exact;
        // and a 4x finer raster) is the ellipse's to a small fraction of a pixel, at every step.
        let n = 96;
        let (rx, ry, rz) = (0.55f32, 0.75f32, 0.35f32);
        let px = n as f32 / 2.0; // pixels per cube unit
        let mut s = ellipsoid(n, rx, ry, rz, 0.0);
        let k = 16;
        for r in 0..n {
            for c in 0..n {
                let mut covered = 0;
                for j in 0..k {
                    for i in 0..k {
                        let x = (c as f32 + (i as f32 + 0.5) / k as f32) / px - 1.0;
                        let y = 1.0 - (r as f32 + (j as f32 + 0.5) / k as f32) / px;
                        covered += usize::from((x / rx).powi(2) + (y / ry).powi(2) < 1.0);
                    }
                }
                let i = r * n + c;
                s.mask.data[i] = covered as f32 / (k * k) as f32;
                // Inside by the threshold but with its centre just outside the ellipse: a zero-thickness column.
                if s.mask.data[i] > 0.5 && s.front.data[i] < s.back.data[i] + 1e-6 {
                    (s.front.data[i], s.back.data[i]) = (0.0, 0.0);
                }
            }
        }
        let true_area = std::f32::consts::PI * rx * ry;
        let (a, b) = (rx, ry);
        let perimeter = std::f32::consts::PI * (3.0 * (a + b) - ((3.0 * a + b) * (a + 3.0 * b)).sqrt());
        for step in [1, 2, 3] {
            let mesh = mesh_from_surfaces(&s, step).unwrap();
            assert_closed_and_unflipped(&mesh, &format!("step {step}"));
            let rim = rim_vertices(&mesh);
            // Signed distance to the ellipse, to first order, in pixels.
            let distance = |p: Vec3| {
                let g = 2.0 * ((p.x / (rx * rx)).powi(2) + (p.y / (ry * ry)).powi(2)).sqrt();
                ((p.x / rx).powi(2) + (p.y / ry).powi(2) - 1.0) / g * px
            };
            let d: Vec<f32> =
                (0..mesh.positions.len()).filter(|&v| rim[v]).map(|v| distance(mesh.positions[v])).collect();
            let worst = d.iter().fold(0f32, |m, x| m.max(x.abs()));
            let mean = d.iter().map(|x| x.abs()).sum::<f32>() / d.len() as f32;
            // The silhouette's mean offset from the ellipse: (area - true area) / perimeter.
            let area: f32 = mesh.triangles.iter().map(|&t| xy_area(&mesh, t).max(0.0)).sum();
            let offset = (area - true_area) / perimeter * px;
            let fine = 4 * n;
            let raster = rasterize(&mesh, &Camera::source(fine));
            let raster_area = raster.coverage() as f32 / (fine * fine) as f32 * 4.0;
            let raster_offset = (raster_area - true_area) / perimeter * px;
            // Measured: worst 0.097 px, mean 0.047-0.052 px; silhouette offset +0.001 / -0.017 / -0.030 px at
            // steps 1 / 2 / 3 (the chords between the outline's vertices), the raster's the same to 0.003 px.
            assert!(d.len() > 50, "step {step}: {} rim vertices", d.len());
            assert!(
                worst < 0.25 && mean < 0.1,
                "step {step}: rim vertices off the ellipse by {mean} px (worst {worst})"
            );
            assert!(offset.abs() < 0.1, "step {step}: the silhouette is {offset} px off the ellipse");
            assert!(raster_offset.abs() < 0.15, "step {step}: the raster's silhouette is {raster_offset} px off");
        }
    }

    #[test]
    fn rough_outlines_stay_closed_and_unflipped() {
        // A ragged mask (a disc with sines on its radius, holes and one-pixel spurs; binary and soft) at steps 1-4:
        // moving the outline never opens, flips or crushes the mesh.
        let n = 80;
        for soft in [false, true] {
            let mut s = InflatedSurfaces {
                front: GrayImage::new(n, n, 0.2),
                back: GrayImage::new(n, n, -0.2),
                mask: GrayImage::new(n, n, 0.0),
            };
            for r in 0..n {
                for c in 0..n {
                    let (x, y) = (c as f32 - 40.0, r as f32 - 40.0);
                    let angle = y.atan2(x);
                    let radius = 28.0 + 6.0 * (5.0 * angle).sin() + 3.0 * (13.0 * angle).cos();
                    let edge = radius - (x * x + y * y).sqrt();
                    let hole = ((x - 8.0).powi(2) + y * y).sqrt() < 3.0;
                    let spur = (c == 40 || r == 12) && edge > -10.0;
                    let value = if soft { (0.5 + 0.4 * edge).clamp(0.0, 1.0) } else { f32::from(u8::from(edge > 0.0)) };
                    s.mask.data[r * n + c] = if hole {
                        0.0
                    } else if spur {
                        value.max(1.0)
                    } else {
                        value
                    };
                }
            }
            for step in 1..=4 {
                let mesh = mesh_from_surfaces(&s, step).unwrap();
                assert_closed_and_unflipped(&mesh, &format!("soft {soft}, step {step}"));
            }
        }
    }

    #[test]
    fn the_mesh_lies_on_the_ellipsoid() {
        let (rx, ry, rz, cz) = (0.5, 0.7, 0.3, -0.2);
        // Inside the outline every vertex is a sample of the ellipsoid; the outline's vertices keep their samples'
        // depths, moved out to the (binary) mask's edge: within a pixel of the ellipse.
        let n = 128;
        let mesh = mesh_from_surfaces(&ellipsoid(n, rx, ry, rz, cz), 2).unwrap();
        let rim = rim_vertices(&mesh);
        for (v, p) in mesh.positions.iter().enumerate() {
            let q = (p.x / rx).powi(2) + (p.y / ry).powi(2) + ((p.z - cz) / rz).powi(2);
            if rim[v] {
                let g = 2.0 * ((p.x / (rx * rx)).powi(2) + (p.y / (ry * ry)).powi(2)).sqrt();
                let d = ((p.x / rx).powi(2) + (p.y / ry).powi(2) - 1.0) / g * (n as f32 / 2.0);
                assert!(d.abs() < 1.0 && (p.z - cz).abs() <= rz, "{p:?}: {d} px off the ellipse");
            } else {
                assert!((q - 1.0).abs() < 1e-4, "{p:?}: {q}");
            }
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
            // Measured: IoU 0.996 from the front and the back, above 0.99 from the side (both outlines on the mask's
            // edge; 0.957-0.992 with the outline on the samples' centres), median depth difference under 0.002
            // cube units.
            assert!(iou > 0.99, "yaw {yaw}: mask IoU {iou}");
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
