//! Multi-threaded CPU rasteriser: depth, normals, coverage mask (and colour, for meshes that carry per-vertex
//! colours) of a [`TriMesh`] seen by any [`Camera`].
//!
//! # What it computes
//! - **Depth**: view-space z of the camera at the pixel centre, **larger is nearer** (see
//!   [`crate::geometry::camera`]). The z-buffer keeps the nearest surface whatever its facing: meshes from
//!   marching cubes are closed, and a camera inside the body must still see the inside.
//! - **Normals**: interpolated vertex normals, renormalised, in the camera's view space (x right, y up, +z toward
//!   the camera). They are the geometric vertex normals, not flipped toward the viewer.
//! - **Sampling**: one sample at each pixel centre (`col + 0.5`, `row + 0.5`). Vertices are snapped to 1/256 pixel
//!   and edges are evaluated with exact integer edge functions and the top-left fill rule, so two triangles that
//!   share an edge never both cover a pixel centre on it and never leave a crack.
//! - **Perspective-correct** interpolation (depth, normals, colours) for perspective cameras; orthographic
//!   cameras interpolate linearly, which is then exact.
//! - **Clipping**: perspective triangles are clipped in homogeneous space against the near plane and a wide guard
//!   band (so huge screen coordinates never overflow the fixed-point edge functions). Orthographic cameras render
//!   the whole mesh, in front of and behind the view plane, like the reference's orthographic renderer.
//!   Triangles with non-finite or out-of-range vertices are skipped; degenerate (zero-area) ones cover nothing.
//!
//! # How it runs
//! Vertices are transformed in parallel, triangles are binned into bands of [`BAND_ROWS`] rows, and the bands are
//! rasterised in parallel (rayon) into a visibility buffer (depth, triangle, barycentrics); the attributes are
//! resolved once per covered pixel afterwards, so overdraw costs no normal or colour interpolation. All scratch
//! memory lives in a per-thread cache: [`rasterize_into`] allocates nothing once the buffers have grown.

use std::cell::RefCell;

use glam::{Affine3A, Vec2, Vec3};
use rayon::prelude::*;

use super::{Camera, Projection, TriMesh};
use crate::buffer::{GrayImage, Image};

/// Depth written where no surface covers the pixel: far behind anything (depth is larger-is-nearer). It is
/// finite so arithmetic on it never produces NaN; use [`GBuffer::mask`] to test coverage, never the depth.
pub const BACKGROUND_DEPTH: f32 = -1.0e30;

/// Rows per band: the unit of parallel work and of triangle binning.
pub const BAND_ROWS: usize = 8;

/// Pixels by which binning widens a triangle's box (far more than the 1/256-pixel vertex snapping moves it).
const BIN_SLACK: f32 = 1.0 / 32.0;

/// Sub-pixel precision of the snapped vertex positions (bits).
const SUBPIXEL_BITS: u32 = 8;
const SUBPIXEL: f32 = (1u32 << SUBPIXEL_BITS) as f32;
const HALF_SUBPIXEL: i64 = 1 << (SUBPIXEL_BITS - 1);
/// Snapped coordinates stay within +-2^20 pixels, so edge functions (products of two coordinate differences of
/// at most 2^29 fixed-point units) fit in an i64 with room to spare.
const MAX_SCREEN_PIXELS: f32 = (1u32 << 20) as f32;
/// Marks a pixel no triangle covers in the visibility buffer.
pub const NO_TRIANGLE: u32 = u32::MAX;

/// The rasteriser's output for one camera. All per-pixel vectors are row-major, `width * height` long, row 0 at
/// the top.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GBuffer {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// View-space z of the nearest surface (larger is nearer); [`BACKGROUND_DEPTH`] where not covered.
    pub depth: Vec<f32>,
    /// Unit interpolated vertex normal in the camera's view space; zero where not covered.
    pub normal: Vec<Vec3>,
    /// Whether a surface covers the pixel centre.
    pub mask: Vec<bool>,
    /// Interpolated per-vertex linear RGB colour, when the mesh has one colour per vertex; zero where not covered.
    pub color: Option<Vec<Vec3>>,
    /// Interpolated per-vertex texture coordinates, when the mesh has one UV per vertex; zero where not covered.
    /// (Perspective-correct like every attribute.) Textured ground truth samples its texture here.
    pub uv: Option<Vec<Vec2>>,
    /// Index of the mesh triangle seen at each pixel ([`NO_TRIANGLE`] where not covered), only from
    /// [`rasterize_with_triangles`]: per-triangle attributes such as a multi-material mesh's material.
    pub triangle: Option<Vec<u32>>,
}

impl GBuffer {
    /// An empty (all background) buffer of `width x height` pixels, without colour.
    pub fn new(width: usize, height: usize) -> Self {
        let mut g = Self::default();
        g.reset(width, height, false);
        g
    }

    /// Resizes to `width x height` and clears to background, reusing the allocations.
    pub fn reset(&mut self, width: usize, height: usize, with_color: bool) {
        let n = width * height;
        self.width = width;
        self.height = height;
        self.depth.clear();
        self.depth.resize(n, BACKGROUND_DEPTH);
        self.normal.clear();
        self.normal.resize(n, Vec3::ZERO);
        self.mask.clear();
        self.mask.resize(n, false);
        if with_color {
            let c = self.color.get_or_insert_with(Vec::new);
            c.clear();
            c.resize(n, Vec3::ZERO);
        } else {
            self.color = None;
        }
        self.uv = None;
        self.triangle = None;
    }

    /// Like [`GBuffer::reset`], and also clears (or drops) the UV channel.
    pub fn reset_with_uv(&mut self, width: usize, height: usize, with_color: bool, with_uv: bool) {
        self.reset(width, height, with_color);
        if with_uv {
            self.uv = Some(vec![Vec2::ZERO; width * height]);
        }
    }

    /// Number of covered pixels.
    pub fn coverage(&self) -> usize {
        self.mask.iter().filter(|&&m| m).count()
    }

    /// The coverage mask as a 0/1 float image.
    pub fn mask_image(&self) -> GrayImage {
        Image { width: self.width, height: self.height, data: self.mask.iter().map(|&m| m as u8 as f32).collect() }
    }

    /// Index of pixel `(col, row)`.
    #[inline]
    pub fn index(&self, col: usize, row: usize) -> usize {
        row * self.width + col
    }
}

/// Rasterises `mesh` as seen by `camera` into a new [`GBuffer`] of the camera's size.
pub fn rasterize(mesh: &TriMesh, camera: &Camera) -> GBuffer {
    let mut out = GBuffer::default();
    rasterize_into(&mut out, mesh, camera);
    out
}

/// [`rasterize`], also recording which triangle each pixel shows ([`GBuffer::triangle`]).
pub fn rasterize_with_triangles(mesh: &TriMesh, camera: &Camera) -> GBuffer {
    let mut out = GBuffer::default();
    rasterize_into_impl(&mut out, mesh, camera, true, false);
    out
}

/// Rasterises `mesh` as seen by `camera` into `out`, resized to the camera's image size. Reuses `out`'s memory
/// and a per-thread scratch cache, so repeated calls at one size allocate nothing.
pub fn rasterize_into(out: &mut GBuffer, mesh: &TriMesh, camera: &Camera) {
    rasterize_into_impl(out, mesh, camera, false, false)
}

/// [`rasterize_into`] skipping the triangles that face away from the camera (wound clockwise on screen), for a
/// mesh that is closed and consistently wound ([`TriMesh::is_closed`]) seen from outside: there they are all
/// hidden, so the result is the same for less work. On any other mesh, or from inside a closed one, it leaves
/// holes. Triangles cut by the near plane are kept.
pub fn rasterize_front_into(out: &mut GBuffer, mesh: &TriMesh, camera: &Camera) {
    rasterize_into_impl(out, mesh, camera, false, true)
}

fn rasterize_into_impl(out: &mut GBuffer, mesh: &TriMesh, camera: &Camera, with_triangles: bool, front_only: bool) {
    let with_color = !mesh.colors.is_empty() && mesh.colors.len() == mesh.positions.len();
    let with_uv = !mesh.uvs.is_empty() && mesh.uvs.len() == mesh.positions.len();
    out.reset_with_uv(camera.width, camera.height, with_color, with_uv);
    if with_triangles {
        out.triangle = Some(vec![NO_TRIANGLE; camera.width * camera.height]);
    }
    if camera.width == 0 || camera.height == 0 || mesh.is_empty() {
        return;
    }
    let Some(fc) = FastCamera::new(camera) else { return };
    SCRATCH.with(|cell| match cell.try_borrow_mut() {
        Ok(mut scratch) => rasterize_with(&mut scratch, out, mesh, &fc, front_only),
        // Re-entered on this thread (e.g. rayon work stealing inside a nested call): use a fresh scratch.
        Err(_) => rasterize_with(&mut Scratch::default(), out, mesh, &fc, front_only),
    });
}

thread_local! {
    static SCRATCH: RefCell<Scratch> = RefCell::new(Scratch::default());
}

/// Per-thread memory reused between calls.
#[derive(Default)]
struct Scratch {
    /// Clip-space position and view depth per vertex.
    clip: Vec<ClipVertex>,
    /// Screen-space vertex, valid when the vertex's outcode is 0.
    screen: Vec<ScreenVertex>,
    /// Outcodes (bit per clip plane) per vertex.
    outcode: Vec<u8>,
    /// Pixel-centre span per vertex (valid when the outcode is 0), see [`CentreSpan`].
    spans: Vec<CentreSpan>,
    /// Triangles produced by clipping (all chunks, in chunk order): three screen vertices and their barycentrics
    /// in the original triangle.
    clipped: Vec<ClippedTriangle>,
    /// Where each chunk's clipped triangles start in `clipped`.
    clip_offset: Vec<u32>,
    /// Binning state per contiguous chunk of triangles (binned in parallel).
    chunks: Vec<BinChunk>,
    /// Visibility buffer: entry index per pixel.
    tri: Vec<u32>,
    /// Visibility buffer: perspective-correct barycentrics (of vertices 1 and 2) per pixel.
    bary: Vec<[f32; 2]>,
}

/// The bins of one contiguous chunk of triangles.
#[derive(Default)]
struct BinChunk {
    /// Triangle entries per band: `t < n_triangles` is an original triangle, otherwise this chunk's
    /// `clipped[t - n]`.
    bins: Vec<Vec<u32>>,
    /// This chunk's clipped triangles.
    clipped: Vec<ClippedTriangle>,
    /// Clipping scratch.
    poly: Vec<PolyVertex>,
}

/// Camera constants for fast projection: `u = ku * X + cu`, `v = kv * Y + cv` with `X = x / w`, `Y = y / w`,
/// `w = 1` (orthographic) or `-z` (perspective), all in view space. Shared with the Z-map code.
#[derive(Clone, Copy, Debug)]
pub(crate) struct FastCamera {
    pub view_from_world: Affine3A,
    pub world_from_view: Affine3A,
    pub ortho: bool,
    pub near: f32,
    /// NDC per unit of `X`: `ndc.x = sx * X + ox`.
    sx: f32,
    ox: f32,
    sy: f32,
    oy: f32,
    pub ku: f32,
    pub cu: f32,
    pub kv: f32,
    pub cv: f32,
    pub width: usize,
    pub height: usize,
}

impl FastCamera {
    /// `None` for a camera whose projection is degenerate (zero or non-finite extent).
    pub fn new(camera: &Camera) -> Option<Self> {
        let (ortho, near, sx, ox, sy, oy) = match camera.projection {
            Projection::Orthographic { half_width, half_height } => {
                (true, 0.0, 1.0 / half_width, 0.0, 1.0 / half_height, 0.0)
            }
            Projection::Perspective { fov, near } => {
                let (tl, tr) = (fov.angle_left.tan(), fov.angle_right.tan());
                let (tu, td) = (fov.angle_up.tan(), fov.angle_down.tan());
                (false, near, 2.0 / (tr - tl), -(tr + tl) / (tr - tl), 2.0 / (tu - td), -(tu + td) / (tu - td))
            }
        };
        let (hw, hh) = (camera.width as f32 * 0.5, camera.height as f32 * 0.5);
        let fc = Self {
            view_from_world: camera.view_from_world,
            world_from_view: camera.view_from_world.inverse(),
            ortho,
            near,
            sx,
            ox,
            sy,
            oy,
            ku: sx * hw,
            cu: (ox + 1.0) * hw,
            kv: -sy * hh,
            cv: (1.0 - oy) * hh,
            width: camera.width,
            height: camera.height,
        };
        let finite = [sx, ox, sy, oy, near].iter().all(|v| v.is_finite());
        let usable = finite && fc.ku != 0.0 && fc.kv != 0.0 && fc.view_from_world.is_finite();
        (usable && fc.world_from_view.is_finite() && (ortho || near > 0.0)).then_some(fc)
    }

    /// View-space point to `(u, v, depth)`; `None` behind the near plane of a perspective camera.
    #[inline]
    pub fn project_view(&self, p: Vec3) -> Option<Vec3> {
        let w = if self.ortho { 1.0 } else { -p.z };
        if !self.ortho && (w.is_nan() || w < self.near) {
            return None;
        }
        let inv = 1.0 / w;
        Some(Vec3::new(self.ku * p.x * inv + self.cu, self.kv * p.y * inv + self.cv, p.z))
    }

    /// Pixel `(u, v)` at view depth `depth` to the view-space point (inverse of [`FastCamera::project_view`]).
    #[inline]
    pub fn unproject_view(&self, u: f32, v: f32, depth: f32) -> Vec3 {
        let x = (u - self.cu) / self.ku;
        let y = (v - self.cv) / self.kv;
        if self.ortho {
            Vec3::new(x, y, depth)
        } else {
            Vec3::new(x * -depth, y * -depth, depth)
        }
    }
}

#[derive(Clone, Copy, Debug, Default)]
struct ClipVertex {
    /// `ndc * w` (x, y) and `w`.
    cx: f32,
    cy: f32,
    w: f32,
    /// View-space z (the depth).
    z: f32,
}

#[derive(Clone, Copy, Debug, Default)]
struct ScreenVertex {
    u: f32,
    v: f32,
    z: f32,
    /// `1 / w` (1 for orthographic).
    iw: f32,
}

#[derive(Clone, Copy, Debug)]
struct ClippedTriangle {
    original: u32,
    v: [ScreenVertex; 3],
    /// Barycentrics of each vertex in the original triangle.
    b: [[f32; 3]; 3],
}

const OUT_NEAR: u8 = 1;
const OUT_LEFT: u8 = 2;
const OUT_RIGHT: u8 = 4;
const OUT_BOTTOM: u8 = 8;
const OUT_TOP: u8 = 16;
const OUT_INVALID: u8 = 128;

impl FastCamera {
    fn clip_vertex(&self, world: Vec3) -> ClipVertex {
        let p = self.view_from_world.transform_point3(world);
        let w = if self.ortho { 1.0 } else { -p.z };
        ClipVertex { cx: self.sx * p.x + self.ox * w, cy: self.sy * p.y + self.oy * w, w, z: p.z }
    }

    /// Guard band in NDC units: screen coordinates stay within [`MAX_SCREEN_PIXELS`].
    fn guard(&self) -> f32 {
        (MAX_SCREEN_PIXELS / (self.width.max(self.height) as f32 * 0.5) - 1.0).max(1.0)
    }

    fn outcode(&self, c: &ClipVertex, guard: f32) -> u8 {
        if !(c.cx.is_finite() && c.cy.is_finite() && c.w.is_finite() && c.z.is_finite()) {
            return OUT_INVALID;
        }
        let mut code = 0;
        if !self.ortho && c.w < self.near {
            code |= OUT_NEAR;
        }
        let g = guard * c.w;
        if c.cx < -g {
            code |= OUT_LEFT;
        }
        if c.cx > g {
            code |= OUT_RIGHT;
        }
        if c.cy < -g {
            code |= OUT_BOTTOM;
        }
        if c.cy > g {
            code |= OUT_TOP;
        }
        code
    }

    fn screen_of(&self, c: &ClipVertex) -> ScreenVertex {
        let iw = 1.0 / c.w;
        let (nx, ny) = (c.cx * iw, c.cy * iw);
        let hw = self.width as f32 * 0.5;
        let hh = self.height as f32 * 0.5;
        ScreenVertex { u: (nx + 1.0) * hw, v: (1.0 - ny) * hh, z: c.z, iw }
    }
}

/// A vertex during clipping: clip coordinates, depth and barycentrics in the original triangle.
#[derive(Clone, Copy, Debug)]
struct PolyVertex {
    c: ClipVertex,
    b: [f32; 3],
}

impl PolyVertex {
    fn lerp(&self, o: &PolyVertex, t: f32) -> PolyVertex {
        let l = |a: f32, b: f32| a + (b - a) * t;
        PolyVertex {
            c: ClipVertex {
                cx: l(self.c.cx, o.c.cx),
                cy: l(self.c.cy, o.c.cy),
                w: l(self.c.w, o.c.w),
                z: l(self.c.z, o.c.z),
            },
            b: [l(self.b[0], o.b[0]), l(self.b[1], o.b[1]), l(self.b[2], o.b[2])],
        }
    }
}

/// Sutherland-Hodgman clipping of a triangle against the near plane and the guard band, in homogeneous space.
/// Intersections are always computed from the inside vertex toward the outside one, so an edge shared by two
/// clipped triangles is cut at bit-identical points (no crack along the clip edge).
fn clip_polygon(fc: &FastCamera, tri: [ClipVertex; 3], guard: f32, out: &mut Vec<PolyVertex>) {
    let mut a: Vec<PolyVertex> = Vec::with_capacity(9);
    let mut b: Vec<PolyVertex> = Vec::with_capacity(9);
    a.extend([
        PolyVertex { c: tri[0], b: [1.0, 0.0, 0.0] },
        PolyVertex { c: tri[1], b: [0.0, 1.0, 0.0] },
        PolyVertex { c: tri[2], b: [0.0, 0.0, 1.0] },
    ]);
    // Signed distances (inside >= 0) for each plane.
    let planes: [fn(&ClipVertex, f32, f32) -> f32; 5] = [
        |c, _, near| c.w - near,
        |c, g, _| c.cx + g * c.w,
        |c, g, _| g * c.w - c.cx,
        |c, g, _| c.cy + g * c.w,
        |c, g, _| g * c.w - c.cy,
    ];
    for (i, plane) in planes.iter().enumerate() {
        if i == 0 && fc.ortho {
            continue;
        }
        b.clear();
        let n = a.len();
        for k in 0..n {
            let cur = a[k];
            let nxt = a[(k + 1) % n];
            let dc = plane(&cur.c, guard, fc.near);
            let dn = plane(&nxt.c, guard, fc.near);
            if dc >= 0.0 {
                b.push(cur);
            }
            if (dc >= 0.0) != (dn >= 0.0) {
                let (inside, outside, di, do_) = if dc >= 0.0 { (cur, nxt, dc, dn) } else { (nxt, cur, dn, dc) };
                let t = di / (di - do_);
                b.push(inside.lerp(&outside, t));
            }
        }
        std::mem::swap(&mut a, &mut b);
        if a.len() < 3 {
            return;
        }
    }
    out.extend_from_slice(&a);
}

fn rasterize_with(s: &mut Scratch, out: &mut GBuffer, mesh: &TriMesh, fc: &FastCamera, front_only: bool) {
    let (w, h) = (out.width, out.height);
    let nv = mesh.positions.len();
    let guard = fc.guard();

    // 1. Vertex stage (parallel).
    s.clip.resize(nv, ClipVertex::default());
    s.screen.resize(nv, ScreenVertex::default());
    s.outcode.resize(nv, 0);
    s.spans.resize(nv, CentreSpan::default());
    s.clip
        .par_iter_mut()
        .zip(s.screen.par_iter_mut())
        .zip(s.outcode.par_iter_mut())
        .zip(s.spans.par_iter_mut())
        .zip(mesh.positions.par_iter())
        .for_each(|((((c, sv), oc), span), &p)| {
            *c = fc.clip_vertex(p);
            *oc = fc.outcode(c, guard);
            if *oc == 0 {
                *sv = fc.screen_of(c);
                *span = CentreSpan::of(sv);
            }
        });

    // 2. Binning into row bands, in parallel over contiguous triangle chunks. Bands later walk the chunks in
    //    order, so every band still sees its triangles in mesh order (ties at equal depth resolve as before).
    let n_bands = h.div_ceil(BAND_ROWS);
    let n_tris = mesh.triangles.len();
    let n_chunks = rayon::current_num_threads().clamp(1, 64);
    let chunk_len = n_tris.div_ceil(n_chunks).max(1);
    s.chunks.resize_with(n_chunks, BinChunk::default);
    let (clip, outcode, spans, screen) = (&s.clip, &s.outcode, &s.spans, &s.screen);
    s.chunks.par_iter_mut().enumerate().for_each(|(k, chunk)| {
        if chunk.bins.len() < n_bands {
            chunk.bins.resize_with(n_bands, Vec::new);
        }
        for bin in &mut chunk.bins {
            bin.clear();
        }
        chunk.clipped.clear();
        let first = (k * chunk_len).min(n_tris);
        let last = ((k + 1) * chunk_len).min(n_tris);
        for (t, tri) in mesh.triangles[first..last].iter().enumerate().map(|(j, tri)| (first + j, tri)) {
            if tri.iter().any(|&i| i as usize >= nv) {
                continue;
            }
            let [i0, i1, i2] = tri.map(|i| i as usize);
            let (o0, o1, o2) = (outcode[i0], outcode[i1], outcode[i2]);
            if (o0 | o1 | o2) & OUT_INVALID != 0 || (o0 & o1 & o2) != 0 {
                continue; // non-finite vertex, or entirely outside one plane
            }
            if (o0 | o1 | o2) == 0 {
                if front_only && faces_away([screen[i0], screen[i1], screen[i2]]) {
                    continue;
                }
                bin_spans(&mut chunk.bins, [spans[i0], spans[i1], spans[i2]], t as u32, w, h);
                continue;
            }
            chunk.poly.clear();
            clip_polygon(fc, [clip[i0], clip[i1], clip[i2]], guard, &mut chunk.poly);
            for j in 1..chunk.poly.len().saturating_sub(1) {
                let fan = [chunk.poly[0], chunk.poly[j], chunk.poly[j + 1]];
                let v = fan.map(|p| fc.screen_of(&p.c));
                if v.iter().any(|v| !(v.u.is_finite() && v.v.is_finite() && v.iw.is_finite() && v.iw > 0.0)) {
                    continue;
                }
                // Local entry; made global (offset by the earlier chunks' clipped triangles) when rasterised.
                let entry = (n_tris + chunk.clipped.len()) as u32;
                chunk.clipped.push(ClippedTriangle { original: t as u32, v, b: fan.map(|p| p.b) });
                bin_rows(&mut chunk.bins, [&v[0], &v[1], &v[2]], entry, w, h);
            }
        }
    });
    // All clipped triangles in one list (chunk order), and each chunk's offset into it.
    s.clipped.clear();
    s.clip_offset.clear();
    for chunk in &s.chunks {
        s.clip_offset.push(s.clipped.len() as u32);
        s.clipped.extend_from_slice(&chunk.clipped);
    }

    // 3. Rasterise bands in parallel into the visibility buffer.
    let n = w * h;
    s.tri.clear();
    s.tri.resize(n, NO_TRIANGLE);
    s.bary.resize(n, [0.0; 2]);
    let band_len = BAND_ROWS * w;
    let (screen, clipped, chunks, clip_offset) = (&s.screen, &s.clipped, &s.chunks, &s.clip_offset);
    out.depth
        .par_chunks_mut(band_len)
        .zip(s.tri.par_chunks_mut(band_len))
        .zip(s.bary.par_chunks_mut(band_len))
        .enumerate()
        .for_each(|(band, ((depth, tri), bary))| {
            let row0 = band * BAND_ROWS;
            let rows = depth.len() / w;
            let mut target = BandTarget { depth, tri, bary, width: w, row0, rows };
            for (chunk, &offset) in chunks.iter().zip(clip_offset) {
                for &e in &chunk.bins[band] {
                    if (e as usize) < n_tris {
                        let t = mesh.triangles[e as usize];
                        raster_triangle(&mut target, &t.map(|i| screen[i as usize]), e);
                    } else {
                        let e = e + offset;
                        raster_triangle(&mut target, &clipped[e as usize - n_tris].v, e);
                    }
                }
            }
        });

    // 4. Resolve attributes once per covered pixel (parallel over rows).
    let has_normals = mesh.normals.len() == nv;
    let rot = fc.view_from_world;
    let resolve = |i: usize| -> Option<(u32, [f32; 3])> {
        let e = s.tri[i];
        if e == NO_TRIANGLE {
            return None;
        }
        let [b1, b2] = s.bary[i];
        let b = [1.0 - b1 - b2, b1, b2];
        if (e as usize) < n_tris {
            Some((e, b))
        } else {
            let c = &s.clipped[e as usize - n_tris];
            let mut ob = [0.0f32; 3];
            for (k, obk) in ob.iter_mut().enumerate() {
                *obk = b[0] * c.b[0][k] + b[1] * c.b[1][k] + b[2] * c.b[2][k];
            }
            Some((c.original, ob))
        }
    };
    let normal_of = |t: u32, b: [f32; 3]| -> Vec3 {
        let idx = mesh.triangles[t as usize].map(|i| i as usize);
        let face = || {
            let [a, bb, c] = idx.map(|i| mesh.positions[i]);
            rot.transform_vector3((bb - a).cross(c - a)).try_normalize().unwrap_or(Vec3::Z)
        };
        if has_normals {
            let n = mesh.normals[idx[0]] * b[0] + mesh.normals[idx[1]] * b[1] + mesh.normals[idx[2]] * b[2];
            rot.transform_vector3(n).try_normalize().unwrap_or_else(face)
        } else {
            face()
        }
    };
    let colors = &mesh.colors;
    let normal = &mut out.normal;
    let mask = &mut out.mask;
    match out.color.as_mut() {
        Some(color) => {
            normal.par_chunks_mut(w).zip(mask.par_chunks_mut(w)).zip(color.par_chunks_mut(w)).enumerate().for_each(
                |(row, ((nr, mr), cr))| {
                    for col in 0..w {
                        if let Some((t, b)) = resolve(row * w + col) {
                            nr[col] = normal_of(t, b);
                            mr[col] = true;
                            let idx = mesh.triangles[t as usize].map(|i| i as usize);
                            cr[col] = colors[idx[0]] * b[0] + colors[idx[1]] * b[1] + colors[idx[2]] * b[2];
                        }
                    }
                },
            );
        }
        None => {
            normal.par_chunks_mut(w).zip(mask.par_chunks_mut(w)).enumerate().for_each(|(row, (nr, mr))| {
                for col in 0..w {
                    if let Some((t, b)) = resolve(row * w + col) {
                        nr[col] = normal_of(t, b);
                        mr[col] = true;
                    }
                }
            });
        }
    }
    if let Some(tri) = out.triangle.as_mut() {
        tri.par_chunks_mut(w).enumerate().for_each(|(row, tr)| {
            for (col, t) in tr.iter_mut().enumerate() {
                if let Some((e, _)) = resolve(row * w + col) {
                    *t = e;
                }
            }
        });
    }
    if let Some(uv) = out.uv.as_mut() {
        let uvs = &mesh.uvs;
        uv.par_chunks_mut(w).enumerate().for_each(|(row, ur)| {
            for (col, out_uv) in ur.iter_mut().enumerate() {
                if let Some((t, b)) = resolve(row * w + col) {
                    let idx = mesh.triangles[t as usize].map(|i| i as usize);
                    *out_uv = uvs[idx[0]] * b[0] + uvs[idx[1]] * b[1] + uvs[idx[2]] * b[2];
                }
            }
        });
    }
}

/// The pixel centres (`k + 0.5`) a screen vertex could share with a triangle: the first and last column and row
/// whose centre lies within [`BIN_SLACK`] pixels of it (first > last when none does). A triangle can cover a
/// pixel centre only if its box holds one, and its box's first/last centres are the minimum/maximum of its
/// vertices' (both are monotone in the coordinate), so binning needs only integer min/max per triangle. The slack
/// is far more than the 1/256-pixel vertex snapping of the rasteriser moves a vertex, so a triangle dropped here
/// never covers a pixel.
#[derive(Clone, Copy, Debug, Default)]
struct CentreSpan {
    col_first: i32,
    col_last: i32,
    row_first: i32,
    row_last: i32,
}

impl CentreSpan {
    fn of(v: &ScreenVertex) -> Self {
        // Clamped far outside any screen first (guard-band coordinates are large), so truncation toward zero plus
        // one comparison is an exact floor.
        const LIMIT: f32 = 1_048_576.0;
        let floor_small = |x: f32| {
            let t = x as i32;
            t - (x < t as f32) as i32
        };
        let first = |x: f32| -floor_small(0.5 - (x - BIN_SLACK).clamp(-LIMIT, LIMIT));
        let last = |x: f32| floor_small((x + BIN_SLACK).clamp(-LIMIT, LIMIT) - 0.5);
        Self { col_first: first(v.u), col_last: last(v.u), row_first: first(v.v), row_last: last(v.v) }
    }
}

/// Whether a screen triangle of a mesh wound counter-clockwise seen from outside ([`TriMesh`]) shows its back:
/// screen rows grow downwards, so a front face has a negative signed area in `(u, v)`.
#[inline]
fn faces_away([a, b, c]: [ScreenVertex; 3]) -> bool {
    (b.u - a.u) * (c.v - a.v) - (b.v - a.v) * (c.u - a.u) > 0.0
}

/// [`bin_spans`] for a triangle made by clipping (its vertices have no precomputed spans).
fn bin_rows(bins: &mut [Vec<u32>], vs: [&ScreenVertex; 3], entry: u32, w: usize, h: usize) {
    bin_spans(bins, vs.map(CentreSpan::of), entry, w, h);
}

/// Appends `entry` to the bins of every band a triangle with these vertex spans may cover: the triangle's span is
/// the union of its vertices' (see [`CentreSpan`]); none when it holds no pixel centre of the `w x h` screen.
#[inline]
fn bin_spans(bins: &mut [Vec<u32>], [a, b, c]: [CentreSpan; 3], entry: u32, w: usize, h: usize) {
    let col_first = a.col_first.min(b.col_first).min(c.col_first).max(0);
    let col_last = a.col_last.max(b.col_last).max(c.col_last).min(w as i32 - 1);
    let row_first = a.row_first.min(b.row_first).min(c.row_first).max(0);
    let row_last = a.row_last.max(b.row_last).max(c.row_last).min(h as i32 - 1);
    if col_first <= col_last && row_first <= row_last {
        for bin in &mut bins[row_first as usize / BAND_ROWS..=row_last as usize / BAND_ROWS] {
            bin.push(entry);
        }
    }
}

/// One band of the visibility buffer.
struct BandTarget<'a> {
    depth: &'a mut [f32],
    tri: &'a mut [u32],
    bary: &'a mut [[f32; 2]],
    width: usize,
    row0: usize,
    rows: usize,
}

#[inline]
fn snap(x: f32) -> i64 {
    // `(x * SUBPIXEL).round() as i64` without baseline x86-64's libm call: in f64 the scaled value plus one half
    // is exact, and truncation then rounds half away from zero like `f32::round` (NaN -> 0, infinities saturate).
    let y = (x * SUBPIXEL) as f64;
    if y >= 0.0 {
        (y + 0.5) as i64
    } else {
        -((0.5 - y) as i64)
    }
}

/// Smallest integer `k` with `k * 256 + 128 >= x` (first pixel whose centre is at or right of `x`).
#[inline]
fn first_centre(x: i64) -> i64 {
    (x - HALF_SUBPIXEL).div_euclid(1 << SUBPIXEL_BITS)
        + ((x - HALF_SUBPIXEL).rem_euclid(1 << SUBPIXEL_BITS) != 0) as i64
}

/// Largest integer `k` with `k * 256 + 128 <= x`.
#[inline]
fn last_centre(x: i64) -> i64 {
    (x - HALF_SUBPIXEL).div_euclid(1 << SUBPIXEL_BITS)
}

/// Scan-converts one screen triangle into the band with exact edge functions and the top-left rule.
fn raster_triangle(t: &mut BandTarget, v: &[ScreenVertex; 3], entry: u32) {
    let mut p = [(snap(v[0].u), snap(v[0].v)), (snap(v[1].u), snap(v[1].v)), (snap(v[2].u), snap(v[2].v))];
    // Vertex order after making the area positive; `perm[k]` is the original index of vertex k.
    let mut perm = [0usize, 1, 2];
    let mut area = (p[1].0 - p[0].0) * (p[2].1 - p[0].1) - (p[1].1 - p[0].1) * (p[2].0 - p[0].0);
    if area == 0 {
        return;
    }
    if area < 0 {
        p.swap(1, 2);
        perm.swap(1, 2);
        area = -area;
    }
    let sv = [v[perm[0]], v[perm[1]], v[perm[2]]];

    let col_lo = first_centre(p[0].0.min(p[1].0).min(p[2].0)).max(0);
    let col_hi = last_centre(p[0].0.max(p[1].0).max(p[2].0)).min(t.width as i64 - 1);
    let row_lo = first_centre(p[0].1.min(p[1].1).min(p[2].1)).max(t.row0 as i64);
    let row_hi = last_centre(p[0].1.max(p[1].1).max(p[2].1)).min((t.row0 + t.rows) as i64 - 1);
    if col_lo > col_hi || row_lo > row_hi {
        return;
    }

    // Edge k is opposite vertex k: from p[(k+1)%3] to p[(k+2)%3]; its function is the weight of vertex k.
    let edge = |k: usize| {
        let a = p[(k + 1) % 3];
        let b = p[(k + 2) % 3];
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let top_left = dy < 0 || (dy == 0 && dx > 0);
        (a, dx, dy, if top_left { 0 } else { 1 })
    };
    let edges = [edge(0), edge(1), edge(2)];
    let sub = 1i64 << SUBPIXEL_BITS;
    let px0 = col_lo * sub + HALF_SUBPIXEL;
    let py0 = row_lo * sub + HALF_SUBPIXEL;
    let mut row_start = [0i64; 3];
    let mut step_x = [0i64; 3];
    let mut step_y = [0i64; 3];
    let mut bias = [0i64; 3];
    for k in 0..3 {
        let (a, dx, dy, b) = edges[k];
        row_start[k] = dx * (py0 - a.1) - dy * (px0 - a.0);
        step_x[k] = -dy * sub;
        step_y[k] = dx * sub;
        bias[k] = b;
    }
    let inv_area = 1.0 / area as f32;
    let (iw0, iw1, iw2) = (sv[0].iw, sv[1].iw, sv[2].iw);
    // Barycentric index in the entry's own vertex order, for the stored (b1, b2).
    let inv_perm = {
        let mut ip = [0usize; 3];
        for (k, &o) in perm.iter().enumerate() {
            ip[o] = k;
        }
        ip
    };

    for row in row_lo..=row_hi {
        let mut e = row_start;
        let base = (row as usize - t.row0) * t.width;
        for col in col_lo..=col_hi {
            if (e[0] - bias[0]) | (e[1] - bias[1]) | (e[2] - bias[2]) >= 0 {
                // Screen-space weights, then perspective correction with 1/w.
                let l0 = e[0] as f32 * inv_area;
                let l1 = e[1] as f32 * inv_area;
                let l2 = e[2] as f32 * inv_area;
                let q = [l0 * iw0, l1 * iw1, l2 * iw2];
                let s = q[0] + q[1] + q[2];
                if s > 0.0 {
                    let inv_s = 1.0 / s;
                    let b = [q[0] * inv_s, q[1] * inv_s, q[2] * inv_s];
                    let z = b[0] * sv[0].z + b[1] * sv[1].z + b[2] * sv[2].z;
                    let i = base + col as usize;
                    if z > t.depth[i] {
                        t.depth[i] = z;
                        t.tri[i] = entry;
                        t.bary[i] = [b[inv_perm[1]], b[inv_perm[2]]];
                    }
                }
            }
            e[0] += step_x[0];
            e[1] += step_x[1];
            e[2] += step_x[2];
        }
        row_start[0] += step_y[0];
        row_start[1] += step_y[1];
        row_start[2] += step_y[2];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn snap_rounds_like_f32_round() {
        let mut x = -3000.0f32;
        while x < 3000.0 {
            for v in [x, x + 0.5 / SUBPIXEL, x - 0.5 / SUBPIXEL, -x] {
                assert_eq!(snap(v), (v * SUBPIXEL).round() as i64, "{v}");
            }
            x += 0.37;
        }
        assert_eq!(snap(f32::NAN), 0);
    }
    use crate::geometry::Fov;
    use glam::Quat;

    #[test]
    fn fast_camera_matches_camera() {
        let fov = Fov { angle_left: -0.7, angle_right: 0.6, angle_up: 0.65, angle_down: -0.75 };
        let q = Quat::from_rotation_y(0.3) * Quat::from_rotation_x(-0.2);
        let cams = [
            Camera::perspective(Vec3::new(0.2, 0.1, 3.0), q, fov, 0.05, 100, 90),
            Camera::orbit(37.0, -20.0, 64, 48),
            Camera::source(512),
        ];
        for cam in cams {
            let fc = FastCamera::new(&cam).unwrap();
            for &w in &[Vec3::new(0.1, 0.2, 0.3), Vec3::new(-0.5, 0.4, -0.2)] {
                let a = cam.project(w).unwrap();
                let b = fc.project_view(fc.view_from_world.transform_point3(w)).unwrap();
                assert!((a - b).abs().max_element() < 1e-3, "{a} {b}");
                let back = fc.world_from_view.transform_point3(fc.unproject_view(b.x, b.y, b.z));
                assert!((back - w).abs().max_element() < 1e-4);
            }
        }
    }

    #[test]
    fn pixel_centre_helpers() {
        assert_eq!(first_centre(128), 0);
        assert_eq!(first_centre(129), 1);
        assert_eq!(first_centre(-200), -1);
        assert_eq!(last_centre(128), 0);
        assert_eq!(last_centre(127), -1);
        assert_eq!(last_centre(384), 1);
    }

    /// A square split along its diagonal, snapped to pixel centres: the fill rule gives every pixel exactly once.
    #[test]
    fn shared_edges_are_covered_exactly_once() {
        let cam = Camera::source(16);
        // Corners exactly on pixel centres and on the diagonal through centres.
        let c = |col: f32, row: f32| cam.unproject(col + 0.5, row + 0.5, 0.0);
        let pos = vec![c(2.0, 2.0), c(12.0, 2.0), c(12.0, 12.0), c(2.0, 12.0)];
        let mut count = vec![0u32; 256];
        for tri in [[0u32, 1, 2], [0, 2, 3]] {
            let m = TriMesh::new(pos.clone(), vec![tri]);
            let g = rasterize(&m, &cam);
            for (i, &on) in g.mask.iter().enumerate() {
                count[i] += on as u32;
            }
        }
        // Every pixel of the square's interior and of its shared diagonal counted exactly once; no double hit.
        assert!(count.iter().all(|&c| c <= 1));
        let both = rasterize(&TriMesh::new(pos, vec![[0, 1, 2], [0, 2, 3]]), &cam);
        let total: u32 = count.iter().sum();
        assert_eq!(total as usize, both.coverage());
        // Interior pixels strictly inside the square are covered.
        for row in 3..12 {
            for col in 3..12 {
                assert!(both.mask[row * 16 + col], "crack at {col},{row}");
            }
        }
        // The top-left rule: the top (row 2) and left (col 2) edges are in, the right/bottom edges are out.
        assert!(both.mask[2 * 16 + 5] && both.mask[5 * 16 + 2]);
        assert!(!both.mask[12 * 16 + 5] && !both.mask[5 * 16 + 12]);
    }

    #[test]
    fn sub_pixel_triangles_cover_exactly_what_one_big_quad_covers() {
        // A quad tiled by triangles far smaller than a pixel (most hold no pixel centre and are dropped while
        // binning) must cover exactly the pixels of the same quad drawn as two triangles, with the same depth.
        // The quad is tilted in depth, perspective and orthographic, and its edges avoid pixel centres.
        for cam in [
            Camera::source(64),
            Camera::perspective(Vec3::new(0.1, 0.05, 3.0), glam::Quat::IDENTITY, Fov::symmetric(0.9, 1.0), 0.1, 64, 64),
        ] {
            let corner = |x: f32, y: f32| Vec3::new(-0.71 + 1.37 * x, -0.53 + 1.29 * y, 0.2 * x - 0.3 * y);
            let n = 160; // cells per side: ~0.3 pixels each
            let mut pos = Vec::new();
            for j in 0..=n {
                for i in 0..=n {
                    pos.push(corner(i as f32 / n as f32, j as f32 / n as f32));
                }
            }
            let mut tris = Vec::new();
            let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
            for j in 0..n {
                for i in 0..n {
                    tris.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                    tris.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
                }
            }
            let fine = rasterize(&TriMesh::new(pos, tris), &cam);
            let quad = vec![corner(0.0, 0.0), corner(1.0, 0.0), corner(1.0, 1.0), corner(0.0, 1.0)];
            let coarse = rasterize(&TriMesh::new(quad, vec![[0, 1, 2], [0, 2, 3]]), &cam);
            assert!(coarse.coverage() > 500, "{}", coarse.coverage());
            assert_eq!(fine.mask, coarse.mask);
            for (a, b) in fine.depth.iter().zip(&coarse.depth) {
                assert!((a - b).abs() < 1e-4, "{a} vs {b}");
            }
        }
    }

    #[test]
    fn reuse_does_not_keep_stale_pixels() {
        let cam = Camera::source(32);
        let big = TriMesh::cuboid(Vec3::splat(-0.8), Vec3::splat(0.8));
        let small = TriMesh::cuboid(Vec3::splat(-0.1), Vec3::splat(0.1));
        let mut g = rasterize(&big, &cam);
        rasterize_into(&mut g, &small, &cam);
        assert_eq!(g, rasterize(&small, &cam));
    }

    /// Ortho sphere: depth sqrt(r^2 - x^2 - y^2) and normal (x, y, z) / r, up to the tessellation error.
    #[test]
    fn sphere_depth_and_normals_are_closed_form() {
        let r = 0.7;
        let mesh = TriMesh::uv_sphere(Vec3::ZERO, r, 64, 128);
        for cam in [Camera::source(128), Camera::orbit(123.0, 40.0, 128, 128)] {
            let g = rasterize(&mesh, &cam);
            let mut n = 0;
            for row in 0..128 {
                for col in 0..128 {
                    let i = g.index(col, row);
                    let ndc = cam.pixel_to_ndc(col as f32 + 0.5, row as f32 + 0.5);
                    let rr = ndc.length_squared();
                    if rr > (r * 0.97) * (r * 0.97) {
                        continue;
                    }
                    assert!(g.mask[i]);
                    let z = (r * r - rr).sqrt();
                    assert!((g.depth[i] - z).abs() < 2e-3 * (r / z), "depth {} vs {z}", g.depth[i]);
                    let expect = Vec3::new(ndc.x, ndc.y, z) / r;
                    // The UV sphere's pole vertices each touch a single face: skip the two stacks around a pole.
                    let world = cam.view_from_world.inverse().transform_vector3(expect);
                    if world.y.abs() > (2.0 * std::f32::consts::PI / 64.0).cos() {
                        continue;
                    }
                    assert!((g.normal[i] - expect).length() < 0.01, "{} vs {expect}", g.normal[i]);
                    assert!((g.normal[i].length() - 1.0).abs() < 1e-5);
                    n += 1;
                }
            }
            assert!(n > 5000);
            // Coverage area ~ pi r^2 in pixels.
            let area = std::f32::consts::PI * r * r * 64.0 * 64.0;
            assert!((g.coverage() as f32 - area).abs() / area < 0.01);
        }
    }

    /// Perspective sphere: depth from the ray-sphere intersection.
    #[test]
    fn perspective_sphere_depth_matches_ray_intersection() {
        let r = 0.6;
        let mesh = TriMesh::uv_sphere(Vec3::ZERO, r, 64, 128);
        let fov = Fov::symmetric(0.8, 1.0);
        let cam = Camera::perspective(Vec3::new(0.3, 0.2, 2.5), Quat::from_rotation_y(0.1), fov, 0.05, 96, 96);
        let g = rasterize(&mesh, &cam);
        let eye = cam.position();
        let mut n = 0;
        for row in 0..96 {
            for col in 0..96 {
                let ray = cam.ray(col as f32 + 0.5, row as f32 + 0.5);
                // |eye + t d|^2 = r^2
                let b = eye.dot(ray.direction);
                let c = eye.length_squared() - r * r;
                let disc = b * b - c;
                let i = g.index(col, row);
                if disc < 0.02 {
                    if disc < -0.02 {
                        assert!(!g.mask[i]);
                    }
                    continue;
                }
                let t = -b - disc.sqrt();
                let hit = eye + ray.direction * t;
                let depth = cam.view_from_world.transform_point3(hit).z;
                assert!(g.mask[i]);
                assert!((g.depth[i] - depth).abs() < 4e-3, "{} vs {depth}", g.depth[i]);
                let nv = cam.view_from_world.transform_vector3(hit / r);
                assert!((g.normal[i] - nv).length() < 0.02);
                n += 1;
            }
        }
        assert!(n > 1000);
    }

    /// A box seen at yaw 45: two planar faces, depth a*sqrt(2) - |x| exactly (orthographic is linear).
    #[test]
    fn box_depth_is_exact_and_face_normals_without_vertex_normals() {
        let a = 0.5;
        let mut mesh = TriMesh::cuboid(Vec3::splat(-a), Vec3::splat(a));
        mesh.normals.clear(); // face normals
        let cam = Camera::orbit(45.0, 0.0, 64, 64);
        let g = rasterize(&mesh, &cam);
        let s2 = std::f32::consts::SQRT_2;
        for row in 0..64 {
            for col in 0..64 {
                let ndc = cam.pixel_to_ndc(col as f32 + 0.5, row as f32 + 0.5);
                let i = g.index(col, row);
                let inside = ndc.x.abs() < a * s2 - 0.02 && ndc.y.abs() < a - 0.02;
                let outside = ndc.x.abs() > a * s2 + 0.02 || ndc.y.abs() > a + 0.02;
                if inside {
                    assert!(
                        (g.depth[i] - (a * s2 - ndc.x.abs())).abs() < 2e-4,
                        "{col},{row}: {} vs {}",
                        g.depth[i],
                        a * s2 - ndc.x.abs()
                    );
                    // Left half shows the +z face (normal rotated to view: (-1,0,1)/sqrt2), right half +x.
                    let expect = if ndc.x < -0.02 {
                        Vec3::new(-1.0, 0.0, 1.0) / s2
                    } else if ndc.x > 0.02 {
                        Vec3::new(1.0, 0.0, 1.0) / s2
                    } else {
                        continue;
                    };
                    assert!((g.normal[i] - expect).length() < 1e-5, "{}", g.normal[i]);
                }
                if outside {
                    assert!(!g.mask[i] && g.depth[i] == BACKGROUND_DEPTH);
                }
            }
        }
    }

    /// A camera inside a box sees the inside faces (both-sided), clipped at the near plane without NaN.
    #[test]
    fn camera_inside_a_box_sees_every_pixel() {
        let mesh = TriMesh::cuboid(Vec3::splat(-1.0), Vec3::splat(1.0));
        let fov = Fov::symmetric(1.6, 1.0);
        let cam = Camera::perspective(Vec3::new(0.2, -0.1, 0.3), Quat::from_rotation_x(0.4), fov, 0.01, 48, 48);
        let g = rasterize(&mesh, &cam);
        assert_eq!(g.coverage(), 48 * 48);
        assert!(g.depth.iter().all(|d| d.is_finite() && *d < 0.0));
        assert!(g.normal.iter().all(|n| (n.length() - 1.0).abs() < 1e-4));
    }

    /// Per-vertex colours are interpolated perspective-correctly.
    #[test]
    fn colours_are_interpolated() {
        let cam = Camera::source(32);
        let mut mesh = TriMesh::cuboid(Vec3::new(-0.8, -0.8, -0.1), Vec3::new(0.8, 0.8, 0.1));
        mesh.colors = mesh.positions.iter().map(|p| Vec3::new(p.x * 0.5 + 0.5, p.y * 0.5 + 0.5, 0.25)).collect();
        let g = rasterize(&mesh, &cam);
        let c = g.color.as_ref().unwrap();
        for row in 8..24 {
            for col in 8..24 {
                let ndc = cam.pixel_to_ndc(col as f32 + 0.5, row as f32 + 0.5);
                let expect = Vec3::new(ndc.x * 0.5 + 0.5, ndc.y * 0.5 + 0.5, 0.25);
                assert!(
                    (c[g.index(col, row)] - expect).length() < 1e-4,
                    "{col},{row}: {} vs {expect}",
                    c[g.index(col, row)]
                );
            }
        }
    }

    /// Per-vertex UVs are interpolated like colours, perspective-correctly, with a perspective camera too.
    #[test]
    fn uvs_are_interpolated() {
        use glam::Quat;
        let mut mesh = TriMesh::cuboid(Vec3::new(-0.8, -0.8, -0.1), Vec3::new(0.8, 0.8, 0.1));
        mesh.uvs = mesh.positions.iter().map(|p| Vec2::new(p.x * 0.5 + 0.5, 0.5 - p.y * 0.5)).collect();
        let fov = crate::geometry::Fov::symmetric(0.9, 1.0);
        let cam = Camera::perspective(Vec3::new(0.1, -0.2, 2.0), Quat::IDENTITY, fov, 0.01, 40, 40);
        let g = rasterize(&mesh, &cam);
        let uv = g.uv.as_ref().unwrap();
        let mut checked = 0;
        for row in 0..40 {
            for col in 0..40 {
                let i = g.index(col, row);
                if !g.mask[i] {
                    continue;
                }
                // The front face is z = 0.1: unproject at its depth to get the surface point.
                let p = cam.unproject(col as f32 + 0.5, row as f32 + 0.5, g.depth[i]);
                if (p.z - 0.1).abs() > 1e-3 {
                    continue;
                }
                let expect = Vec2::new(p.x * 0.5 + 0.5, 0.5 - p.y * 0.5);
                assert!((uv[i] - expect).length() < 1e-3, "{col},{row}: {} vs {expect}", uv[i]);
                checked += 1;
            }
        }
        assert!(checked > 500);
        assert!(rasterize(&TriMesh::cuboid(Vec3::ZERO, Vec3::ONE), &cam).uv.is_none());
    }

    /// The triangle channel names the front-most triangle: its depth matches the pixel's.
    #[test]
    fn triangle_ids_name_the_visible_triangle() {
        let mesh = TriMesh::cuboid(Vec3::new(-0.5, -0.6, -0.3), Vec3::new(0.4, 0.5, 0.2));
        let cam = Camera::orbit(30.0, 10.0, 40, 40);
        let g = rasterize_with_triangles(&mesh, &cam);
        let tri = g.triangle.as_ref().unwrap();
        assert!(rasterize(&mesh, &cam).triangle.is_none());
        let mut checked = 0;
        for (i, &ti) in tri.iter().enumerate() {
            if !g.mask[i] {
                assert_eq!(ti, NO_TRIANGLE);
                continue;
            }
            let t =
                mesh.triangles[ti as usize].map(|k| cam.view_from_world.transform_point3(mesh.positions[k as usize]));
            // The pixel's view-space point lies on the named triangle's plane.
            let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
            let p = cam.unproject((i % 40) as f32 + 0.5, (i / 40) as f32 + 0.5, g.depth[i]);
            let pv = cam.view_from_world.transform_point3(p);
            assert!((pv - t[0]).dot(n).abs() < 1e-3, "pixel {i}");
            checked += 1;
        }
        assert!(checked > 300);
    }

    #[test]
    fn skipping_back_faces_of_a_closed_mesh_changes_nothing_seen_from_outside() {
        let mut two = TriMesh::cuboid(Vec3::new(-0.6, -0.8, -0.2), Vec3::new(0.1, 0.7, 0.3));
        let other = TriMesh::cuboid(Vec3::new(0.2, -0.3, -0.5), Vec3::new(0.6, 0.2, 0.1));
        let offset = two.positions.len() as u32;
        two.positions.extend_from_slice(&other.positions);
        two.triangles.extend(other.triangles.iter().map(|t| t.map(|i| i + offset)));
        two.compute_normals();
        assert!(two.is_closed());
        let fov = Fov::symmetric(1.0, 1.2);
        let cameras = [
            Camera::source(96),
            Camera::orbit(137.0, -35.0, 80, 96),
            Camera::orbit(30.0, 89.9, 96, 96),
            Camera::perspective(Vec3::new(0.4, 0.3, 2.5), Quat::from_rotation_y(0.15), fov, 0.05, 96, 80),
        ];
        for cam in cameras {
            let all = rasterize(&two, &cam);
            let mut front = GBuffer::new(0, 0);
            rasterize_front_into(&mut front, &two, &cam);
            assert!(all.mask.iter().filter(|&&m| m).count() > 500);
            assert_eq!(all.mask, front.mask);
            assert_eq!(all.depth, front.depth);
            assert_eq!(all.normal, front.normal);
        }
        // From inside a box every face shows its back: skipping them leaves nothing (the documented limit).
        let inside = Camera::perspective(Vec3::new(-0.2, 0.0, 0.0), Quat::IDENTITY, fov, 0.01, 32, 32);
        let mut front = GBuffer::new(0, 0);
        rasterize_front_into(&mut front, &two, &inside);
        assert!(rasterize(&two, &inside).mask.iter().all(|&m| m));
        assert!(front.mask.iter().all(|&m| !m));
    }
}
