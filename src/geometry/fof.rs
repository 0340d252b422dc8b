//! Fourier occupancy field (FOF-X cosine form): a per-pixel cosine series of the occupancy along the source
//! camera's viewing ray.
//!
//! # Conventions
//! - The pixel grid is the orthographic source camera [`Camera::source`](super::Camera::source) over the body
//!   cube: pixel `(col, row)` has its centre at `x = (col+0.5)/(W/2) - 1`, `y = 1 - (row+0.5)/(H/2)`.
//! - Along the ray, `t = z + 1` in `[0, 2]` and `s = t / 2` in `[0, 1]` (`s = 0` is the back of the cube,
//!   `s = 1` the face toward the camera).
//! - A pixel's ray crosses the body in sorted intervals `[z_lo, z_hi]` (z ascending). With `t = z + 1`:
//!   `c_0 = sum(t_hi - t_lo)`, `c_k = sum[sin(k pi t_hi / 2) - sin(k pi t_lo / 2)] / (k pi / 2)`, `k = 1..N-1`.
//! - Decoding: `occ(s) = 0.5 c_0 + sum_{k>=1} c_k cos(k pi s)`; the surface is the `occ = 0.5` level set. Depth
//!   sample `d` of `D` sits at `s_d = (d + 0.5) / D`, i.e. `z_d = 2 s_d - 1`.
//!
//! These are exactly the formulas of the public FOF-X code (see the project's reference facts).

use rayon::prelude::*;

use super::mesh::TriMesh;
use crate::buffer::{zeroed_f32, GrayImage, Image};

/// Largest grid side accepted by the encoders (keeps memory bounded on bad input).
pub const MAX_RESOLUTION: usize = 8192;
/// Largest number of coefficients per pixel accepted by the encoders.
pub const MAX_ORDER: usize = 1024;

/// Errors of the FOF layer.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FofError {
    /// The number of coefficients per pixel must be at least 1.
    #[error("the FOF order N must be between 1 and {MAX_ORDER}, got {0}")]
    BadOrder(usize),
    /// The grid is empty or larger than [`MAX_RESOLUTION`].
    #[error("the FOF grid must be between 1x1 and {MAX_RESOLUTION}x{MAX_RESOLUTION} pixels, got {width}x{height}")]
    BadSize {
        /// Requested width.
        width: usize,
        /// Requested height.
        height: usize,
    },
    /// Inputs that must share a size do not.
    #[error("size mismatch: {what} is {got_width}x{got_height} but {want_width}x{want_height} was expected")]
    SizeMismatch {
        /// Which input is wrong.
        what: &'static str,
        /// Its width.
        got_width: usize,
        /// Its height.
        got_height: usize,
        /// The expected width.
        want_width: usize,
        /// The expected height.
        want_height: usize,
    },
    /// The coefficient buffer does not hold `n * width * height` values.
    #[error("the coefficient buffer holds {got} values but N x W x H = {want}")]
    CoefficientCount {
        /// Values supplied.
        got: usize,
        /// Values expected.
        want: usize,
    },
    /// A NaN or infinity in the input (a mesh vertex, a depth, a mask value or a coefficient).
    #[error("non-finite value in {what} at index {index}; check the upstream stage for NaN/inf")]
    NonFinite {
        /// Which input holds it.
        what: &'static str,
        /// Flat index of the first offending value.
        index: usize,
    },
}

/// A Fourier occupancy field: `n` cosine coefficients per pixel of a `width x height` source grid.
#[derive(Clone, Debug, PartialEq)]
pub struct Fof {
    /// Coefficients per pixel (`N`; 32 in R²Human).
    pub n: usize,
    /// Grid width in pixels.
    pub width: usize,
    /// Grid height in pixels.
    pub height: usize,
    /// The coefficients of pixel `(col, row)` are contiguous at `[(row * width + col) * n .. + n]`.
    pub coeffs: Vec<f32>,
}

/// A precomputed cosine basis for decoding columns at `samples` depths: entry `[k * samples + d]` is
/// `cos(k pi s_d)` with `s_d = (d + 0.5) / samples`, except row `k = 0` which holds the DC weight `0.5`.
#[derive(Clone, Debug, PartialEq)]
pub struct CosineTable {
    /// Number of coefficients (rows).
    pub n: usize,
    /// Number of depth samples (columns).
    pub samples: usize,
    /// `n * samples` basis values, row-major by coefficient.
    pub values: Vec<f32>,
}

impl CosineTable {
    /// Builds the table for `n` coefficients and `samples` depth samples (computed in f64, stored in f32).
    pub fn new(n: usize, samples: usize) -> Self {
        let mut values = Vec::with_capacity(n * samples);
        for k in 0..n {
            for d in 0..samples {
                if k == 0 {
                    values.push(0.5);
                } else {
                    let s = (d as f64 + 0.5) / samples as f64;
                    values.push((k as f64 * std::f64::consts::PI * s).cos() as f32);
                }
            }
        }
        Self { n, samples, values }
    }

    /// Decodes one column's coefficients `coeffs` at the table's depths into `out[..samples]` (fewer if `out` is
    /// shorter; see [`Fof::decode_column_with`]).
    pub fn decode(&self, coeffs: &[f32], out: &mut [f32]) {
        let m = self.samples.min(out.len());
        self.decode_range(coeffs, 0, &mut out[..m]);
    }

    /// Decodes one column's coefficients `coeffs` at the table's depth samples `lo..lo + out.len()` (which must lie
    /// in the table): `out[i] = sum_k c_k table[k][lo + i]`, summed over k in ascending order (a coefficient that is
    /// exactly 0 changes no bit), so values decoded piecewise are bit-identical to a whole-column decode. On a CPU
    /// with AVX2 the same code runs compiled for it, with the same bits (measured: mesh extraction of a 512²
    /// portrait 125 -> 113 ms CPU).
    pub fn decode_range(&self, coeffs: &[f32], lo: usize, out: &mut [f32]) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked just above), the only requirement of `decode_range_avx2`.
            return unsafe { self.decode_range_avx2(coeffs, lo, out) };
        }
        self.decode_range_portable(coeffs, lo, out)
    }

    /// [`CosineTable::decode_range`] compiled for AVX2 (eight-lane registers). The same operations in the same
    /// order as the portable build (no fused multiply-add: Rust never contracts `a += c * b`), so the same bits.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn decode_range_avx2(&self, coeffs: &[f32], lo: usize, out: &mut [f32]) {
        self.decode_range_portable(coeffs, lo, out)
    }

    /// [`CosineTable::decode_range`] for any CPU (inlined into the AVX2 build).
    ///
    /// Eight samples (a group) at a time, their sums held in registers across all coefficients: the spans the mesh
    /// decodes are 16 samples long, too short for the compiler's own vectorisation of a loop over samples
    /// (measured: mesh extraction of a 512² body 58 -> 46 ms CPU, the same bits). Up to four groups share one pass
    /// over the coefficients, so their sums are independent chains of additions the CPU overlaps, rather than one
    /// chain waiting on each addition (measured: the `astronaut` portrait's 512² mesh 113 -> 96 ms CPU). A last
    /// partial group is computed as the eight table samples that end with it (or start with it) and only its own
    /// lanes are kept.
    /// Each lane is its own sum, in ascending k, so the bits are those of a sample-by-sample decode; a zero
    /// coefficient adds +0 or -0 to a sum that is never -0 (it starts at +0, and an exact cancellation gives +0),
    /// which leaves it unchanged, as skipping it would.
    #[inline(always)]
    fn decode_range_portable(&self, coeffs: &[f32], lo: usize, out: &mut [f32]) {
        let mut done = 0;
        while out.len() - done >= 4 * LANES {
            self.fill::<4>(coeffs, lo + done, &mut out[done..]);
            done += 4 * LANES;
        }
        match (out.len() - done) / LANES {
            3 => self.fill::<3>(coeffs, lo + done, &mut out[done..]),
            2 => self.fill::<2>(coeffs, lo + done, &mut out[done..]),
            1 => self.fill::<1>(coeffs, lo + done, &mut out[done..]),
            _ => {}
        }
        done += (out.len() - done) / LANES * LANES;
        let (start, rest) = (lo + done, &mut out[done..]);
        if rest.is_empty() {
            return;
        }
        if self.samples >= LANES {
            // The group of eight table samples that holds the rest, inside the table.
            let first = start.min(self.samples - LANES);
            let [acc] = self.groups::<1>(coeffs, first);
            rest.copy_from_slice(&acc[start - first..start - first + rest.len()]);
            return;
        }
        let n = coeffs.len().min(self.n);
        for (i, o) in rest.iter_mut().enumerate() {
            let mut acc = 0.0f32;
            for (k, &ck) in coeffs[..n].iter().enumerate() {
                acc += ck * self.values[k * self.samples + start + i];
            }
            *o = acc;
        }
    }

    /// Decodes `G` groups of eight samples from `start` into the start of `out`.
    #[inline(always)]
    fn fill<const G: usize>(&self, coeffs: &[f32], start: usize, out: &mut [f32]) {
        let acc = self.groups::<G>(coeffs, start);
        out[..G * LANES].iter_mut().zip(acc.iter().flatten()).for_each(|(o, &a)| *o = a);
    }

    /// The sums of `G` groups of eight samples from `start`: `acc[g][l] = sum_k c_k table[k][start + 8 g + l]`, k
    /// ascending.
    #[inline(always)]
    fn groups<const G: usize>(&self, coeffs: &[f32], start: usize) -> [[f32; LANES]; G] {
        let (n, samples) = (coeffs.len().min(self.n), self.samples);
        let mut acc = [[0.0f32; LANES]; G];
        for (k, &ck) in coeffs[..n].iter().enumerate() {
            let row = &self.values[k * samples + start..k * samples + start + G * LANES];
            for (a, basis) in acc.iter_mut().zip(row.chunks_exact(LANES)) {
                for (s, &b) in a.iter_mut().zip(basis) {
                    *s += ck * b;
                }
            }
        }
        acc
    }
}

/// Samples per group of [`CosineTable::decode_range`] (one AVX2 register of f32).
const LANES: usize = 8;

fn check_size(width: usize, height: usize) -> Result<(), FofError> {
    if width == 0 || height == 0 || width > MAX_RESOLUTION || height > MAX_RESOLUTION {
        return Err(FofError::BadSize { width, height });
    }
    Ok(())
}

fn check_order(n: usize) -> Result<(), FofError> {
    if n == 0 || n > MAX_ORDER {
        return Err(FofError::BadOrder(n));
    }
    Ok(())
}

/// Adds the FOF coefficients of one interval `[z_lo, z_hi]` (z in `[-1, 1]`) to `out` (length N).
///
/// `sin(k theta)` comes from the Chebyshev recurrence in f64, exact to ~1e-14 for any N used here.
pub fn accumulate_interval(z_lo: f32, z_hi: f32, out: &mut [f32]) {
    let lo = (z_lo.clamp(-1.0, 1.0) as f64) + 1.0;
    let hi = (z_hi.clamp(-1.0, 1.0) as f64) + 1.0;
    if hi <= lo {
        return;
    }
    out[0] += (hi - lo) as f32;
    let half_pi = std::f64::consts::FRAC_PI_2;
    let (th_hi, th_lo) = (half_pi * hi, half_pi * lo);
    let (two_cos_hi, two_cos_lo) = (2.0 * th_hi.cos(), 2.0 * th_lo.cos());
    // s_{k-1}, s_k for both ends, starting at k = 0 -> (0, sin theta) for k = 1.
    let (mut hi_prev, mut hi_cur) = (0.0f64, th_hi.sin());
    let (mut lo_prev, mut lo_cur) = (0.0f64, th_lo.sin());
    for (k, c) in out.iter_mut().enumerate().skip(1) {
        *c += ((hi_cur - lo_cur) / (k as f64 * half_pi)) as f32;
        let hi_next = two_cos_hi * hi_cur - hi_prev;
        let lo_next = two_cos_lo * lo_cur - lo_prev;
        (hi_prev, hi_cur) = (hi_cur, hi_next);
        (lo_prev, lo_cur) = (lo_cur, lo_next);
    }
}

impl Fof {
    /// A field with every coefficient zero (empty everywhere).
    pub fn zeros(n: usize, width: usize, height: usize) -> Result<Self, FofError> {
        check_order(n)?;
        check_size(width, height)?;
        Ok(Self { n, width, height, coeffs: zeroed_f32(n * width * height) })
    }

    /// Wraps coefficients from elsewhere (e.g. a network), checking their count and that all are finite.
    pub fn new(n: usize, width: usize, height: usize, coeffs: Vec<f32>) -> Result<Self, FofError> {
        check_order(n)?;
        check_size(width, height)?;
        let want = n * width * height;
        if coeffs.len() != want {
            return Err(FofError::CoefficientCount { got: coeffs.len(), want });
        }
        if let Some(index) = coeffs.iter().position(|c| !c.is_finite()) {
            return Err(FofError::NonFinite { what: "FOF coefficients", index });
        }
        Ok(Self { n, width, height, coeffs })
    }

    /// Encodes a triangle mesh (body-cube coordinates) on a `resolution x resolution` source grid with `n`
    /// coefficients, using [`intervals_from_mesh`] (robust to non-watertight meshes) with single-sided sheets
    /// given [`sheet_thickness`]`(n)`.
    pub fn from_mesh(mesh: &TriMesh, resolution: usize, n: usize) -> Result<Self, FofError> {
        check_order(n)?;
        check_size(resolution, resolution)?;
        if let Some(index) = mesh.positions.iter().position(|p| !p.is_finite()) {
            return Err(FofError::NonFinite { what: "mesh vertices", index });
        }
        if let Err(msg) = mesh.validate() {
            // Only out-of-range indices remain possible here; report them as a size problem of the mesh.
            tracing::warn!("FOF from mesh: {msg}; offending triangles are skipped");
        }
        Self::from_intervals(&intervals_from_mesh(mesh, resolution, resolution, sheet_thickness(n)), n)
    }

    /// Encodes per-pixel intervals `(z_lo, z_hi)` (z in `[-1, 1]`, clamped; empty or reversed intervals are
    /// ignored) with `n` coefficients.
    pub fn from_intervals(intervals: &Image<Vec<(f32, f32)>>, n: usize) -> Result<Self, FofError> {
        check_order(n)?;
        check_size(intervals.width, intervals.height)?;
        for (i, list) in intervals.data.iter().enumerate() {
            if list.iter().any(|&(a, b)| !(a.is_finite() && b.is_finite())) {
                return Err(FofError::NonFinite { what: "intervals", index: i });
            }
        }
        let mut coeffs = zeroed_f32(n * intervals.width * intervals.height);
        coeffs.par_chunks_mut(n * intervals.width).zip(intervals.data.par_chunks(intervals.width)).for_each(
            |(row_out, row_in)| {
                for (out, list) in row_out.chunks_exact_mut(n).zip(row_in) {
                    for &(lo, hi) in list {
                        accumulate_interval(lo, hi, out);
                    }
                }
            },
        );
        Ok(Self { n, width: intervals.width, height: intervals.height, coeffs })
    }

    /// Encodes front/back depth maps: one interval `[back, front]` per pixel whose mask is above 0.5 (depth =
    /// body-cube z in `[-1, 1]`, clamped; pixels with `front <= back` stay empty).
    pub fn from_depth_maps(front: &GrayImage, back: &GrayImage, mask: &GrayImage, n: usize) -> Result<Self, FofError> {
        check_order(n)?;
        check_size(mask.width, mask.height)?;
        for (what, img) in [("front depth map", front), ("back depth map", back)] {
            if img.width != mask.width || img.height != mask.height {
                return Err(FofError::SizeMismatch {
                    what,
                    got_width: img.width,
                    got_height: img.height,
                    want_width: mask.width,
                    want_height: mask.height,
                });
            }
        }
        if let Some(index) = mask.data.iter().position(|m| !m.is_finite()) {
            return Err(FofError::NonFinite { what: "mask", index });
        }
        for (what, img) in [("front depth map", front), ("back depth map", back)] {
            if let Some(index) = (0..img.data.len()).find(|&i| mask.data[i] > 0.5 && !img.data[i].is_finite()) {
                return Err(FofError::NonFinite { what, index });
            }
        }
        let (w, h) = (mask.width, mask.height);
        let mut coeffs = zeroed_f32(n * w * h);
        coeffs.par_chunks_mut(n * w).enumerate().for_each(|(row, row_out)| {
            for (col, out) in row_out.chunks_exact_mut(n).enumerate() {
                let i = row * w + col;
                if mask.data[i] > 0.5 {
                    accumulate_interval(back.data[i], front.data[i], out);
                }
            }
        });
        Ok(Self { n, width: w, height: h, coeffs })
    }

    /// The field on a grid of half the resolution (`ceil(w / 2) x ceil(h / 2)`): each column the mean of the
    /// coefficients of the 2x2 block it covers (fewer at an odd border). Decoding is linear in the coefficients,
    /// so the coarse column's occupancy is the block's mean occupancy at every depth: a surface half as finely
    /// sampled across, for views whose pixels are larger than two of this grid's.
    pub fn halved(&self) -> Fof {
        let (w, h, n) = (self.width.div_ceil(2), self.height.div_ceil(2), self.n);
        let mut coeffs = vec![0.0f32; n * w * h];
        coeffs.par_chunks_mut(n * w).enumerate().for_each(|(r, row)| {
            for (c, out) in row.chunks_mut(n).enumerate() {
                let rows = 2 * r..(2 * r + 2).min(self.height);
                let cols = 2 * c..(2 * c + 2).min(self.width);
                let count = (rows.len() * cols.len()) as f32;
                for rr in rows {
                    for cc in cols.clone() {
                        for (o, &v) in out.iter_mut().zip(self.column(cc, rr)) {
                            *o += v;
                        }
                    }
                }
                for o in out.iter_mut() {
                    *o /= count;
                }
            }
        });
        Fof { n, width: w, height: h, coeffs }
    }

    /// The `n` coefficients of pixel `(col, row)`.
    #[inline]
    pub fn column(&self, col: usize, row: usize) -> &[f32] {
        let i = (row * self.width + col) * self.n;
        &self.coeffs[i..i + self.n]
    }

    /// Occupancy of pixel `(col, row)` at ray parameter `s` in `[0, 1]` (`z = 2 s - 1`).
    pub fn occupancy(&self, col: usize, row: usize, s: f32) -> f32 {
        let c = self.column(col, row);
        let theta = std::f64::consts::PI * s as f64;
        let mut sum = 0.5 * c[0] as f64;
        for (k, &ck) in c.iter().enumerate().skip(1) {
            sum += ck as f64 * (k as f64 * theta).cos();
        }
        sum as f32
    }

    /// Decodes pixel `(col, row)` at `samples` depths `s_d = (d + 0.5) / samples` into `out[..samples]`
    /// (fewer if `out` is shorter). Builds a [`CosineTable`] on every call: in loops, build the table once and
    /// use [`Fof::decode_column_with`].
    pub fn decode_column(&self, col: usize, row: usize, samples: usize, out: &mut [f32]) {
        let table = CosineTable::new(self.n, samples);
        self.decode_column_with(&table, col, row, out);
    }

    /// Decodes pixel `(col, row)` with a precomputed table into `out[..table.samples]` (fewer if `out` is
    /// shorter). Coefficients past the table's order are ignored; a smaller table order truncates the series.
    pub fn decode_column_with(&self, table: &CosineTable, col: usize, row: usize, out: &mut [f32]) {
        table.decode(self.column(col, row), out);
    }

    /// Whether pixel `(col, row)`'s occupancy stays strictly below 0.5 at every depth, proven by the bound
    /// `occ(s) <= 0.5 c_0 + sum_{k>=1} |c_k|` (exact for all-zero columns; conservative otherwise).
    pub fn is_empty_column(&self, col: usize, row: usize) -> bool {
        Self::is_empty_coefficients(self.column(col, row))
    }

    /// [`Fof::is_empty_column`] of one column's coefficients `c` (at least one).
    #[inline]
    pub fn is_empty_coefficients(c: &[f32]) -> bool {
        let bound = 0.5 * c[0] + c[1..].iter().map(|v| v.abs()).sum::<f32>();
        bound < 0.5
    }
}

/// One ray hit for the interval automaton: depth and whether the surface is entered there.
#[derive(Clone, Copy, Debug)]
struct Hit {
    pixel: u32,
    z: f32,
    entering: bool,
}

/// Edge function of the 2-D edge `a -> b` at `p`, computed in a canonical vertex order so the two
/// triangles sharing an edge get exactly opposite values (no pixel is hit twice or missed on a shared edge).
#[inline]
fn edge_fn(a: [f32; 2], b: [f32; 2], p: [f32; 2]) -> f32 {
    let orient = |a: [f32; 2], b: [f32; 2]| (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]);
    if (a[0], a[1]) <= (b[0], b[1]) {
        orient(a, b)
    } else {
        -orient(b, a)
    }
}

/// Top-left fill rule for a counter-clockwise (y up) triangle: an edge owns the points exactly on it when it
/// goes down, or is horizontal going left.
#[inline]
fn owns_boundary(a: [f32; 2], b: [f32; 2]) -> bool {
    b[1] < a[1] || (b[1] == a[1] && b[0] < a[0])
}

/// Rows per rasterisation band (the unit of parallel work).
const BAND_ROWS: usize = 8;

/// Thickness (body-cube z units) given to a single-sided sheet by [`intervals_from_mesh`] when the field has `n`
/// coefficients: `2 / n` (0.0625 for N = 32, about 6 cm on a 1.8 m person).
///
/// A zero-thickness sheet cannot be represented: an interval of length `t` decodes (at the sheet) to an
/// occupancy of about `t n / 2`, which stays below the surface level 0.5 for `t <= 1 / n` and vanishes from the
/// mesh. At `2 / n` the decoded bump peaks at about 0.85 and its 0.5 level set is about `2.4 / n` thick, for every
/// `n` from 8 to 64 (tested): the thinnest sheet the series resolves with margin. (Depth sampling is much finer —
/// 512 samples over the cube are 0.004 apart — so the coefficient count, not the sampling, sets the scale.)
pub fn sheet_thickness(n: usize) -> f32 {
    2.0 / n.max(1) as f32
}

/// Per-pixel intervals `(z_lo, z_hi)` (ascending, z in `[-1, 1]`) of a mesh on the `width x height` source
/// grid.
///
/// Every triangle is rasterised at pixel centres (top-left rule, so shared edges are hit once); each hit is
/// tagged *entering* when the triangle faces the camera (normal z > 0) and *leaving* otherwise; edge-on and
/// non-finite triangles are skipped. Hits are sorted from the camera inward and paired by the reference's
/// automaton: wait for an entering hit; a leaving hit closes the interval; further leaving hits extend it; an
/// entering hit after a close opens a new one. Non-watertight scans (holes, duplicated faces, inner shells)
/// therefore still give usable intervals, and watertight meshes give exactly the reference's intervals.
///
/// Hits the reference drops are single-sided sheets (hair cards, capes, a skirt modelled as one surface, a scan
/// with a hole behind a surface): an entering hit never followed by a leaving one, and a leaving hit with nothing
/// open (the back of a sheet facing the camera). With `sheet_thickness > 0` each becomes the interval
/// `(z - sheet_thickness, z)`: thickened away from the camera, so the surface the source camera sees keeps its
/// depth. Overlapping intervals are merged. `sheet_thickness = 0` drops them like the reference; [`Fof::from_mesh`]
/// uses [`sheet_thickness`]. Depths are clamped to the cube.
pub fn intervals_from_mesh(
    mesh: &TriMesh,
    width: usize,
    height: usize,
    sheet_thickness: f32,
) -> Image<Vec<(f32, f32)>> {
    let sheet = if sheet_thickness.is_finite() { sheet_thickness.clamp(0.0, 2.0) } else { 0.0 };
    let mut result = Image::new(width, height, Vec::new());
    if width == 0 || height == 0 {
        return result;
    }
    let nv = mesh.positions.len();
    let (sx, sy) = (width as f32 * 0.5, height as f32 * 0.5);
    let bands = height.div_ceil(BAND_ROWS);
    // Bin the triangles into row bands.
    let mut binned: Vec<Vec<u32>> = vec![Vec::new(); bands];
    for (ti, t) in mesh.triangles.iter().enumerate() {
        if t.iter().any(|&i| i as usize >= nv) {
            continue;
        }
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        if !(a.is_finite() && b.is_finite() && c.is_finite()) {
            continue;
        }
        // Rows whose centre y lies within the triangle's y range.
        let (ymin, ymax) = (a.y.min(b.y).min(c.y), a.y.max(b.y).max(c.y));
        let row_lo = ((1.0 - ymax) * sy - 0.5).ceil().max(0.0);
        let row_hi = ((1.0 - ymin) * sy - 0.5).floor().min(height as f32 - 1.0);
        if row_hi < row_lo {
            continue;
        }
        for list in &mut binned[row_lo as usize / BAND_ROWS..=row_hi as usize / BAND_ROWS] {
            list.push(ti as u32);
        }
    }
    result.data.par_chunks_mut(BAND_ROWS * width).zip(binned.par_iter()).enumerate().for_each(|(band, (out, tris))| {
        let row0 = band * BAND_ROWS;
        let rows = out.len() / width;
        let mut hits: Vec<Hit> = Vec::new();
        for &ti in tris {
            let t = mesh.triangles[ti as usize];
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            let nz = (b - a).cross(c - a).z;
            if nz == 0.0 || !nz.is_finite() {
                continue;
            }
            let entering = nz > 0.0;
            // Counter-clockwise in (x, y) so the inside test is "all edge functions positive".
            let (p0, mut p1, mut p2) = (a, b, c);
            if nz < 0.0 {
                std::mem::swap(&mut p1, &mut p2);
            }
            let v = [[p0.x, p0.y], [p1.x, p1.y], [p2.x, p2.y]];
            let (xmin, xmax) = (p0.x.min(p1.x).min(p2.x), p0.x.max(p1.x).max(p2.x));
            let (ymin, ymax) = (p0.y.min(p1.y).min(p2.y), p0.y.max(p1.y).max(p2.y));
            let col_lo = ((xmin + 1.0) * sx - 0.5).ceil().max(0.0) as usize;
            let col_hi = ((xmax + 1.0) * sx - 0.5).floor().min(width as f32 - 1.0);
            let r_lo = (((1.0 - ymax) * sy - 0.5).ceil().max(row0 as f32)) as usize;
            let r_hi = ((1.0 - ymin) * sy - 0.5).floor().min((row0 + rows) as f32 - 1.0);
            if col_hi < col_lo as f32 || r_hi < r_lo as f32 {
                continue;
            }
            let area = edge_fn(v[0], v[1], v[2]);
            if area <= 0.0 {
                continue;
            }
            let owns = [owns_boundary(v[1], v[2]), owns_boundary(v[2], v[0]), owns_boundary(v[0], v[1])];
            for row in r_lo..=r_hi as usize {
                let y = 1.0 - (row as f32 + 0.5) / sy;
                for col in col_lo..=col_hi as usize {
                    let p = [(col as f32 + 0.5) / sx - 1.0, y];
                    let w = [edge_fn(v[1], v[2], p), edge_fn(v[2], v[0], p), edge_fn(v[0], v[1], p)];
                    let inside = (0..3).all(|e| w[e] > 0.0 || (w[e] == 0.0 && owns[e]));
                    if !inside {
                        continue;
                    }
                    let z = (w[0] * p0.z + w[1] * p1.z + w[2] * p2.z) / area;
                    if !z.is_finite() {
                        continue;
                    }
                    hits.push(Hit { pixel: ((row - row0) * width + col) as u32, z: z.clamp(-1.0, 1.0), entering });
                }
            }
        }
        // From the camera inward: z descending; at equal depth, leaving before entering so touching solids
        // give two adjacent intervals.
        hits.sort_unstable_by(|p, q| p.pixel.cmp(&q.pixel).then(q.z.total_cmp(&p.z)).then(p.entering.cmp(&q.entering)));
        for group in hits.chunk_by(|p, q| p.pixel == q.pixel) {
            out[group[0].pixel as usize] = pair_hits(group, sheet);
        }
    });
    result
}

/// The reference's interval automaton over hits sorted from the camera inward, with unmatched hits turned into
/// sheets of thickness `sheet` (none when 0; see [`intervals_from_mesh`]); returns ascending, disjoint intervals.
fn pair_hits(hits: &[Hit], sheet: f32) -> Vec<(f32, f32)> {
    enum State {
        Outside,
        /// Inside an interval opened at depth `start` by hit `from`; the reference ignores the entering hits that
        /// follow, and they all become sheets if no leaving hit ever closes the interval.
        Inside {
            start: f32,
            from: usize,
        },
        Closed,
    }
    let mut state = State::Outside;
    let mut intervals: Vec<(f32, f32)> = Vec::new();
    let mut sheets: Vec<(f32, f32)> = Vec::new();
    for (i, h) in hits.iter().enumerate() {
        state = match (state, h.entering) {
            (State::Outside, true) | (State::Closed, true) => State::Inside { start: h.z, from: i },
            (State::Outside, false) => {
                sheets.push((h.z - sheet, h.z));
                State::Outside
            }
            (inside @ State::Inside { .. }, true) => inside,
            (State::Inside { start, .. }, false) => {
                intervals.push((h.z, start));
                State::Closed
            }
            (State::Closed, false) => {
                if let Some(last) = intervals.last_mut() {
                    last.0 = h.z;
                }
                State::Closed
            }
        };
    }
    if let State::Inside { from, .. } = state {
        // No leaving hit after the opening one: every entering hit since is an unmatched sheet.
        sheets.extend(hits[from..].iter().filter(|h| h.entering).map(|h| (h.z - sheet, h.z)));
    }
    if sheet > 0.0 {
        intervals.extend(sheets.into_iter().map(|(lo, hi)| (lo.max(-1.0), hi)));
    }
    intervals.retain(|&(lo, hi)| hi > lo);
    intervals.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut merged: Vec<(f32, f32)> = Vec::with_capacity(intervals.len());
    for (lo, hi) in intervals {
        match merged.last_mut() {
            Some(last) if lo < last.1 => last.1 = last.1.max(hi),
            _ => merged.push((lo, hi)),
        }
    }
    merged
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;
    use std::f32::consts::PI;

    #[test]
    fn decode_range_gives_the_bits_of_a_sample_by_sample_sum() {
        // Whatever build `decode_range` picks for this CPU (AVX2 or not) and however it groups the samples (whole
        // groups of eight, a last partial group taken from the table's neighbouring samples), every range of every
        // column decodes to the bits of the plain sum over k in ascending order, zero coefficients skipped.
        let mut seed = 7u32;
        let mut next = || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (seed >> 8) as f32 / (1u32 << 24) as f32 - 0.5
        };
        for (samples, ranges) in [
            (512, &[(0, 512), (0, 33), (16, 17), (16, 16), (496, 15), (493, 19), (100, 7), (511, 1)][..]),
            (33, &[(0, 33), (30, 3), (0, 5)][..]),
            (5, &[(0, 5), (2, 3)][..]),
        ] {
            let table = CosineTable::new(32, samples);
            for column in 0..20 {
                let coeffs: Vec<f32> = (0..32).map(|k| if (k + column) % 5 == 0 { 0.0 } else { next() }).collect();
                for &(lo, len) in ranges {
                    let mut got = vec![0.0f32; len];
                    table.decode_range(&coeffs, lo, &mut got);
                    for (i, g) in got.iter().enumerate() {
                        let mut want = 0.0f32;
                        for (k, &c) in coeffs.iter().enumerate() {
                            if c != 0.0 {
                                want += c * table.values[k * samples + lo + i];
                            }
                        }
                        assert_eq!(g.to_bits(), want.to_bits(), "{samples} samples, column {column}, {lo}+{i}");
                    }
                }
            }
        }
    }

    /// Closed-form FOF of one interval [lo, hi] in z.
    fn closed_form(lo: f32, hi: f32, n: usize) -> Vec<f32> {
        let (tl, th) = (lo as f64 + 1.0, hi as f64 + 1.0);
        (0..n)
            .map(|k| {
                if k == 0 {
                    (th - tl) as f32
                } else {
                    let w = k as f64 * std::f64::consts::FRAC_PI_2;
                    (((w * th).sin() - (w * tl).sin()) / w) as f32
                }
            })
            .collect()
    }

    fn centre(col: usize, w: usize) -> f32 {
        (col as f32 + 0.5) / (w as f32 * 0.5) - 1.0
    }

    #[test]
    fn sphere_matches_closed_form() {
        let (res, n, r) = (48usize, 16usize, 0.6f32);
        let mesh = TriMesh::uv_sphere(Vec3::ZERO, r, 96, 192);
        let fof = Fof::from_mesh(&mesh, res, n).unwrap();
        let mut checked = 0;
        for row in 0..res {
            for col in 0..res {
                let (x, y) = (centre(col, res), -centre(row, res));
                let rho2 = x * x + y * y;
                let c = fof.column(col, row);
                if rho2 > (r * 0.97).powi(2) {
                    if rho2 > r * r * 1.01 {
                        assert!(c.iter().all(|&v| v == 0.0), "outside pixel has coefficients");
                    }
                    continue;
                }
                let h = (r * r - rho2).sqrt();
                // Analytic: c_0 = 2h, c_k = 2 cos(k pi/2) sin(k pi h/2) / (k pi/2).
                let want: Vec<f32> = (0..n)
                    .map(|k| {
                        if k == 0 {
                            2.0 * h
                        } else {
                            let w = k as f32 * PI / 2.0;
                            2.0 * w.cos() * (w * h).sin() / w
                        }
                    })
                    .collect();
                for k in 0..n {
                    assert!((c[k] - want[k]).abs() < 4e-3, "pixel ({col},{row}) k={k}: {} vs {}", c[k], want[k]);
                }
                checked += 1;
            }
        }
        assert!(checked > 500);
    }

    #[test]
    fn box_matches_closed_form_exactly() {
        let (res, n) = (40usize, 12usize);
        let (lo, hi) = (Vec3::new(-0.43, -0.61, -0.37), Vec3::new(0.52, 0.29, 0.58));
        let fof = Fof::from_mesh(&TriMesh::cuboid(lo, hi), res, n).unwrap();
        let want = closed_form(lo.z, hi.z, n);
        for row in 0..res {
            for col in 0..res {
                let (x, y) = (centre(col, res), -centre(row, res));
                let inside = x > lo.x && x < hi.x && y > lo.y && y < hi.y;
                let c = fof.column(col, row);
                for k in 0..n {
                    let w = if inside { want[k] } else { 0.0 };
                    assert!((c[k] - w).abs() < 1e-5, "({col},{row}) k={k}: {} vs {w}", c[k]);
                }
            }
        }
    }

    #[test]
    fn decode_reproduces_occupancy_away_from_the_boundary() {
        let n = 32;
        let mut intervals = Image::new(1, 1, Vec::new());
        intervals.data[0] = vec![(-0.6, -0.1), (0.2, 0.7)];
        let fof = Fof::from_intervals(&intervals, n).unwrap();
        let samples = 256;
        let mut out = vec![0.0; samples];
        fof.decode_column(0, 0, samples, &mut out);
        for (d, &v) in out.iter().enumerate() {
            let z = 2.0 * (d as f32 + 0.5) / samples as f32 - 1.0;
            assert!((v - fof.occupancy(0, 0, (z + 1.0) / 2.0)).abs() < 1e-4);
            let dist = [-0.6f32, -0.1, 0.2, 0.7].iter().map(|b| (z - b).abs()).fold(f32::MAX, f32::min);
            if dist > 0.12 {
                let inside = (-0.6..-0.1).contains(&z) || (0.2..0.7).contains(&z);
                let want = if inside { 1.0 } else { 0.0 };
                assert!((v - want).abs() < 0.08, "z={z}: {v} vs {want}");
            }
        }
    }

    #[test]
    fn non_watertight_and_duplicated_meshes_still_give_intervals() {
        let res = 32;
        let sheet = 0.05;
        let sphere = TriMesh::uv_sphere(Vec3::ZERO, 0.7, 24, 48);
        let mut holed = sphere.clone();
        // Remove the back faces around the -z pole region: a hole in the back.
        holed.triangles.retain(|t| {
            let c = t.iter().map(|&i| holed.positions[i as usize]).sum::<Vec3>() / 3.0;
            !(c.z < -0.5 && c.x.abs() < 0.2 && c.y.abs() < 0.2)
        });
        let mut doubled = sphere.clone();
        doubled.triangles.extend(sphere.triangles.clone());
        let full = intervals_from_mesh(&sphere, res, res, sheet);
        let dup = intervals_from_mesh(&doubled, res, res, sheet);
        let hole = intervals_from_mesh(&holed, res, res, sheet);
        let hole_reference = intervals_from_mesh(&holed, res, res, 0.0);
        assert_eq!(full, dup, "duplicated faces must not change the intervals");
        assert_eq!(full, intervals_from_mesh(&sphere, res, res, 0.0), "a closed mesh has no sheets");
        let (mut with_interval, mut sheets) = (0, 0);
        for i in 0..res * res {
            assert!(full.data[i].len() <= 1);
            if hole_reference.data[i].is_empty() && !full.data[i].is_empty() {
                // Behind the hole the leaving hit is missing: the reference drops the column, the sheet rule keeps
                // the front surface with the sheet thickness behind it.
                let (col, row) = (i % res, i / res);
                assert!(centre(col, res).abs() < 0.3 && centre(row, res).abs() < 0.3);
                let front = full.data[i][0].1;
                assert_eq!(hole.data[i], vec![(front - sheet, front)]);
                sheets += 1;
            } else {
                assert_eq!(hole.data[i], full.data[i]);
                with_interval += !full.data[i].is_empty() as usize;
            }
        }
        assert!(with_interval > 300 && sheets > 0);
    }

    #[test]
    fn automaton_pairs_like_the_reference() {
        let h = |z: f32, entering: bool| Hit { pixel: 0, z, entering };
        // leave (dropped), enter, enter (ignored), leave, leave (extends), enter, leave, enter (unmatched).
        let hits = [
            h(0.9, false),
            h(0.8, true),
            h(0.7, true),
            h(0.5, false),
            h(0.4, false),
            h(0.1, true),
            h(-0.2, false),
            h(-0.5, true),
        ];
        assert_eq!(pair_hits(&hits, 0.0), vec![(-0.2, 0.1), (0.4, 0.8)]);
        // With sheets: the lone leaving hit at 0.9 and the unmatched entering hit at -0.5 become sheets.
        assert_eq!(pair_hits(&hits, 0.05), vec![(-0.5 - 0.05, -0.5), (-0.2, 0.1), (0.4, 0.8), (0.9 - 0.05, 0.9)]);
        // Two stacked front-facing sheets (hair cards): both kept; overlapping sheets merge.
        assert_eq!(pair_hits(&[h(0.3, true), h(0.1, true)], 0.05), vec![(0.1 - 0.05, 0.1), (0.3 - 0.05, 0.3)]);
        assert_eq!(pair_hits(&[h(0.3, true), h(0.28, true)], 0.05), vec![(0.28 - 0.05, 0.3)]);
        // A sheet at the back of the cube is clamped to it.
        assert_eq!(pair_hits(&[h(-0.98, false)], 0.05), vec![(-1.0, -0.98)]);
        assert!(pair_hits(&[], 0.05).is_empty());
    }

    /// A square sheet `|x|, |y| <= a` at depth `z`, facing +z (toward the source camera) or -z.
    fn plane(a: f32, z: f32, facing_camera: bool) -> TriMesh {
        let p = vec![Vec3::new(-a, -a, z), Vec3::new(a, -a, z), Vec3::new(a, a, z), Vec3::new(-a, a, z)];
        let t = if facing_camera { vec![[0, 1, 2], [0, 2, 3]] } else { vec![[0, 2, 1], [0, 3, 2]] };
        TriMesh::new(p, t)
    }

    /// An open cone frustum (a one-sided skirt, no caps): radius `r_top` at `y_top` widening to `r_hem` at
    /// `y_hem`, `segments` around; outward normals unless `inward`.
    fn skirt(y_top: f32, r_top: f32, y_hem: f32, r_hem: f32, segments: usize, inward: bool) -> TriMesh {
        let mut p = Vec::new();
        for i in 0..segments {
            let a = i as f32 / segments as f32 * std::f32::consts::TAU;
            let (s, c) = a.sin_cos();
            p.push(Vec3::new(r_top * s, y_top, r_top * c));
            p.push(Vec3::new(r_hem * s, y_hem, r_hem * c));
        }
        let mut t = Vec::new();
        for i in 0..segments as u32 {
            let j = (i + 1) % segments as u32;
            let (a, b, c, d) = (2 * i, 2 * i + 1, 2 * j, 2 * j + 1);
            // Counter-clockwise from outside: top_i, hem_i, hem_j and top_i, hem_j, top_j.
            let (t0, t1) = ([a, b, d], [a, d, c]);
            if inward {
                t.extend([[t0[0], t0[2], t0[1]], [t1[0], t1[2], t1[1]]]);
            } else {
                t.extend([t0, t1]);
            }
        }
        TriMesh::new(p, t)
    }

    #[test]
    fn open_plane_becomes_a_sheet_in_closed_form() {
        let (res, n, z) = (32usize, 32usize, 0.2f32);
        let t = sheet_thickness(n);
        assert!((t - 0.0625).abs() < 1e-7);
        let want = closed_form(z - t, z, n);
        for facing in [true, false] {
            let m = plane(0.5, z, facing);
            assert!(intervals_from_mesh(&m, res, res, 0.0).data.iter().all(Vec::is_empty), "reference drops it");
            let fof = Fof::from_mesh(&m, res, n).unwrap();
            for row in 0..res {
                for col in 0..res {
                    let inside = centre(col, res).abs() < 0.5 && centre(row, res).abs() < 0.5;
                    let c = fof.column(col, row);
                    for k in 0..n {
                        let w = if inside { want[k] } else { 0.0 };
                        assert!((c[k] - w).abs() < 1e-5, "facing {facing} ({col},{row}) k={k}: {} vs {w}", c[k]);
                    }
                }
            }
            // The sheet survives decoding: occupancy above the surface level in the middle of the sheet.
            let s_mid = (z - 0.5 * t + 1.0) / 2.0;
            assert!(fof.occupancy(res / 2, res / 2, s_mid) > 0.8);
        }
    }

    #[test]
    fn sheet_thickness_survives_decoding_at_every_order() {
        for n in [8usize, 16, 32, 64] {
            let t = sheet_thickness(n);
            let mut intervals = Image::new(1, 1, Vec::new());
            intervals.data[0] = vec![(0.1 - t, 0.1)];
            let fof = Fof::from_intervals(&intervals, n).unwrap();
            let mut occ = vec![0.0f32; 2048];
            fof.decode_column(0, 0, occ.len(), &mut occ);
            let peak = occ.iter().copied().fold(f32::MIN, f32::max);
            // Decoded level-set thickness in z units.
            let width = occ.iter().filter(|&&v| v >= 0.5).count() as f32 * 2.0 / occ.len() as f32;
            assert!(peak > 0.75 && peak < 1.0, "n={n}: peak {peak}");
            assert!(width > t && width < 1.5 * t, "n={n}: level-set width {width} for thickness {t}");
            // Half the thickness would vanish from the mesh.
            intervals.data[0] = vec![(0.1 - 0.5 * t, 0.1)];
            let thin = Fof::from_intervals(&intervals, n).unwrap();
            thin.decode_column(0, 0, occ.len(), &mut occ);
            assert!(occ.iter().all(|&v| v < 0.5), "n={n}");
        }
    }

    #[test]
    fn one_sided_skirt_in_closed_form() {
        let (res, n) = (64usize, 32usize);
        let (y_top, r_top, y_hem, r_hem) = (0.3f32, 0.25f32, -0.7f32, 0.6f32);
        let t = sheet_thickness(n);
        // Radius of the cone at height y.
        let radius = |y: f32| r_top + (r_hem - r_top) * (y_top - y) / (y_top - y_hem);
        for inward in [false, true] {
            let m = skirt(y_top, r_top, y_hem, r_hem, 512, inward);
            let iv = intervals_from_mesh(&m, res, res, t);
            let mut checked = 0;
            for row in 0..res {
                for col in 0..res {
                    let (x, y) = (centre(col, res), -centre(row, res));
                    let got = &iv.data[row * res + col];
                    if y > y_top || y < y_hem {
                        assert!(got.is_empty(), "({col},{row}) outside the skirt: {got:?}");
                        continue;
                    }
                    let r = radius(y);
                    if x.abs() > 0.97 * r {
                        continue; // the polygon's silhouette
                    }
                    let h = (r * r - x * x).sqrt();
                    // Outward normals: the front wall enters, the back wall leaves, so the reference's interval
                    // fills the skirt. Inward normals: a lone leaving hit at the front, a lone entering hit at the
                    // back: two sheets, each thickened away from the camera.
                    let want = if inward { vec![(-h - t, -h), (h - t, h)] } else { vec![(-h, h)] };
                    assert_eq!(got.len(), want.len(), "({col},{row}): {got:?} vs {want:?}");
                    for (g, w) in got.iter().zip(&want) {
                        assert!((g.0 - w.0).abs() < 2e-3 && (g.1 - w.1).abs() < 2e-3, "{got:?} vs {want:?}");
                    }
                    checked += 1;
                }
            }
            assert!(checked > 600, "{checked}");
            // Without sheets the inward skirt vanishes entirely (the reference's behaviour).
            let none = intervals_from_mesh(&m, res, res, 0.0);
            assert_eq!(none.data.iter().all(Vec::is_empty), inward);
        }
    }

    #[test]
    fn from_mesh_and_from_depth_maps_agree_for_a_convex_shape() {
        let (res, n, r) = (32usize, 16usize, 0.55f32);
        let mesh = TriMesh::uv_sphere(Vec3::new(0.1, 0.0, 0.05), r, 48, 96);
        let intervals = intervals_from_mesh(&mesh, res, res, sheet_thickness(n));
        let front = intervals.map(|v| v.first().map_or(-1.0, |i| i.1));
        let back = intervals.map(|v| v.first().map_or(-1.0, |i| i.0));
        let mask = intervals.map(|v| if v.is_empty() { 0.0 } else { 1.0 });
        let a = Fof::from_mesh(&mesh, res, n).unwrap();
        let b = Fof::from_depth_maps(&front, &back, &mask, n).unwrap();
        for (x, y) in a.coeffs.iter().zip(&b.coeffs) {
            assert!((x - y).abs() < 1e-6);
        }
        assert!(a.coeffs.iter().any(|&v| v != 0.0));
    }

    #[test]
    fn empty_columns_and_bounds() {
        let mut fof = Fof::zeros(8, 2, 1).unwrap();
        assert!(fof.is_empty_column(0, 0));
        fof.coeffs[8..16].copy_from_slice(&closed_form(-0.2, 0.3, 8));
        assert!(!fof.is_empty_column(1, 0));
        // A tiny network-like column: bound below 0.5, so provably empty.
        fof.coeffs[..8].copy_from_slice(&[0.1, 0.05, -0.05, 0.02, 0.0, 0.0, 0.0, 0.01]);
        assert!(fof.is_empty_column(0, 0));
        let mut out = [9.0f32; 64];
        fof.decode_column(0, 0, 64, &mut out);
        assert!(out.iter().all(|&v| v < 0.5));
    }

    #[test]
    fn bad_input_gives_errors() {
        assert_eq!(Fof::zeros(0, 4, 4), Err(FofError::BadOrder(0)));
        assert!(matches!(Fof::new(2, 2, 2, vec![0.0; 7]), Err(FofError::CoefficientCount { .. })));
        assert!(matches!(Fof::new(1, 1, 1, vec![f32::NAN]), Err(FofError::NonFinite { .. })));
        let img = GrayImage::new(4, 4, 0.0);
        let small = GrayImage::new(3, 4, 0.0);
        assert!(matches!(Fof::from_depth_maps(&small, &img, &img, 4), Err(FofError::SizeMismatch { .. })));
        let mut bad = img.clone();
        bad.data[5] = f32::INFINITY;
        let mask = GrayImage::new(4, 4, 1.0);
        assert!(matches!(Fof::from_depth_maps(&bad, &img, &mask, 4), Err(FofError::NonFinite { .. })));
        let mut mesh = TriMesh::cuboid(Vec3::splat(-0.5), Vec3::splat(0.5));
        mesh.positions[0].x = f32::NAN;
        assert!(matches!(Fof::from_mesh(&mesh, 8, 4), Err(FofError::NonFinite { .. })));
    }

    #[test]
    fn gibbs_ringing_at_n128_stays_finite() {
        let mut intervals = Image::new(3, 1, Vec::new());
        intervals.data[0] = vec![(0.1, 0.1 + 1e-4)];
        intervals.data[1] = vec![(-1.0, 1.0)];
        intervals.data[2] = vec![(-2.0, -0.999), (0.999, 3.0)];
        let fof = Fof::from_intervals(&intervals, 128).unwrap();
        assert!(fof.coeffs.iter().all(|c| c.is_finite()));
        let mut out = vec![0.0; 512];
        for col in 0..3 {
            fof.decode_column(col, 0, 512, &mut out);
            assert!(out.iter().all(|v| v.is_finite() && v.abs() < 2.0));
        }
        // Whole ray occupied: c_0 = 2, every c_k = 0 (sin(k pi) - sin 0).
        let c = fof.column(1, 0);
        assert!((c[0] - 2.0).abs() < 1e-6 && c[1..].iter().all(|v| v.abs() < 1e-5));
    }

    #[test]
    fn a_halved_field_holds_each_blocks_mean_occupancy() {
        // A 3 x 3 grid: one interval per column, different per column, so every block mixes columns.
        let mut intervals = Image::new(3, 3, Vec::new());
        for (i, v) in intervals.data.iter_mut().enumerate() {
            if i != 4 {
                v.push((-0.6 + 0.05 * i as f32, 0.2 + 0.03 * i as f32));
            }
        }
        let fof = Fof::from_intervals(&intervals, 16).unwrap();
        let half = fof.halved();
        assert_eq!((half.width, half.height, half.n), (2, 2, 16));
        for (col, row, block) in
            [(0, 0, vec![(0, 0), (1, 0), (0, 1), (1, 1)]), (1, 0, vec![(2, 0), (2, 1)]), (1, 1, vec![(2, 2)])]
        {
            for s in [0.1f32, 0.35, 0.5, 0.8] {
                let mean = block.iter().map(|&(c, r)| fof.occupancy(c, r, s)).sum::<f32>() / block.len() as f32;
                assert!((half.occupancy(col, row, s) - mean).abs() < 1e-5, "({col}, {row}) at {s}");
            }
        }
        // An empty field stays empty.
        let empty = Fof::zeros(8, 5, 4).unwrap().halved();
        assert_eq!((empty.width, empty.height), (3, 2));
        assert!(empty.coeffs.iter().all(|&c| c == 0.0));
    }
}
