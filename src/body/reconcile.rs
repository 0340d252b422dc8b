//! Reconciling the fitted body with the person's silhouette: one closed surface per person, whatever the mask adds
//! to the body (hair, a hat, loose clothes, a helmet held in front) or takes from it (the photo's frame, a limb the
//! photo does not show).
//!
//! Every column of the source view falls in one of four classes:
//! - **body**: inside the mask and crossed by the posed body: the body's own intervals (arms in front of the torso
//!   stay separate shells);
//! - **free**: inside the mask, missed by the body: one interval `[c - h, c + h]` from two smooth fields solved
//!   over the free columns;
//! - **outside** the mask, inside the photo: empty; the silhouette's outline;
//! - **cut**: outside the photo's frame (a portrait cut at the chest): empty, but not an outline — the person
//!   continues there, so the free surfaces meet it with zero slope instead of closing.
//!
//! The fields, on the pixel grid in body-cube units (spacing `2/width`, `2/height`):
//! - the **centre** `c` solves the screened equation `-Δc + (c - m) / ρ² = 0`, equal to the middle of the body's
//!   outermost interval on body columns, free (zero normal slope) at the outline and the cut; `m` is the median of
//!   those middles over all body columns (the torso's depth, whatever a limb does) and `ρ`
//!   ([`ReconcileParams::centre_reach`], 0.1 cube units) how far the body's depth carries: hair and clothes next to
//!   the body join it without steps, while a large region the body does not explain (a tripod, a held helmet, a
//!   coat below the fitted body) settles within about `ρ` on the body's median depth instead of carrying one
//!   (possibly mis-fitted) limb's depth across the whole region, which drew it as a long sheet from the side. In a
//!   strip away from a body column at depth `d` the centre is `m + (d - m) e^(-x/ρ)`. Measured with `cargo run
//!   --example body_synthetic` (9 clothed subjects, mean volumetric IoU of the fitted body prior): harmonic
//!   (ρ = ∞) 0.536, ρ = 0.4 0.538, 0.2 0.542, **0.1 0.546**, 0.05 0.549; the oracle body (a perfect fit) 0.674,
//!   0.674, 0.674, 0.671, 0.665;
//! - the **half thickness** is the silhouette-inflation profile ([`crate::geometry::inflate`]) with the body as a
//!   boundary: `-Δu = 4`, `u = 0` on the outline (half a pixel outside the last mask pixel), `u = (h_b / κ)²` on
//!   body columns (`h_b` the half depth of the body's outermost interval), zero slope at the cut, and
//!   `h = κ sqrt(u)`. A free region touching no body is exactly the inflation prior there (centred on the body's
//!   median depth); one between the body and the outline bulges like the inflation of the gap, starting from the
//!   body's own thickness, so the surface is continuous where body and silhouette meet.
//!
//! - the **silhouette floor**: the inflation profile of the silhouette alone, as the inflation prior has it
//!   (`-Δu_s = 4` over the whole mask, `u_s = 0` on the outline and at the cut), `h_s = κ sqrt(u_s)`, times [`ReconcileParams::silhouette_floor`]. Every
//!   column is at least that thick about its own centre: body columns get the union of their intervals with
//!   `[c - h_s, c + h_s]` (`c` the middle of their envelope, averaged with the body columns' around it over
//!   [`FLOOR_CENTRE_SPAN`] of the grid: a limb in front of the trunk does not carry a slab as thick as the
//!   silhouette forward with it, one that jumps from column to column; release `eval --subjects 8`: body
//!   volumetric IoU 0.5853 -> 0.5875 over 1/32 of the grid, 0.5941 over 1/8 (the default: a forearm is wider
//!   than 1/32), the Mr. Fixit scan 0.566 -> 0.570 -> 0.586), free columns `max(h, h_s)`. Clothes make
//!   the person thicker than the bare body wherever the silhouette is wider than it; the silhouette's own inflation
//!   is what the photo says about that thickness. Measured on the evaluation's clothed subjects
//!   (`cargo run --example body_synthetic`): the volumetric IoU of a perfectly posed bare body rises from 0.55 to
//!   0.68 with the floor, the fitted body's from 0.39 to 0.53 (both with depth aligned).
//!
//! All three are solved with Jacobi-preconditioned conjugate gradients on the 5-point stencil, started from the
//! solution of the same problem on a grid half as fine (a cascade down to about 64 pixels a side, bilinear in
//! between), with a fixed small number of iterations on the finer levels: they remove the interpolation's local
//! error; what remains is a smooth offset of a few hundredths of a unit. A tiny screening term pulls `u` toward 0 so
//! a region with no fixed value has a unique solution (`c` has its own, above).

use glam::Vec2;
use rayon::prelude::*;

use super::pose::PhotoFrame;
use crate::buffer::{GrayImage, Image};

/// What one column of the source view is (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cell {
    /// Outside the mask, inside the photo: the outline.
    Outside,
    /// Outside the photo's frame: the person may continue there.
    Cut,
    /// Inside the mask and crossed by the body: a fixed value.
    Body,
    /// Inside the mask, not crossed by the body: solved for.
    Free,
}

/// Settings of [`reconcile`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReconcileParams {
    /// κ of the inflation profile `h = κ sqrt(u)` ([`crate::geometry::inflate::InflateParams::thickness`]).
    pub thickness: f32,
    /// Smallest half thickness of a free column, in pixels.
    pub min_half_thickness: f32,
    /// Smallest half thickness of a free column, in cube units: the resolving limit of the FOF the intervals go
    /// into (half of [`crate::geometry::fof::sheet_thickness`]); a thinner interval decodes below the iso level
    /// and drops out of the mesh, so a thin free part (a tripod's leg) broke into pieces. 0: none.
    pub min_half_depth: f32,
    /// Every column is at least this fraction of the silhouette's own inflation thickness (see the module docs;
    /// 0 turns the floor off).
    pub silhouette_floor: f32,
    /// How far (cube units) a free column's centre follows the body columns next to it before it settles on the
    /// body's median depth (the screening length of the centre field, see the module docs; 0 or infinite: harmonic).
    pub centre_reach: f32,
}

impl Default for ReconcileParams {
    fn default() -> Self {
        let p = crate::geometry::inflate::InflateParams::default();
        Self {
            thickness: p.thickness,
            min_half_thickness: p.min_half_thickness,
            min_half_depth: 0.0,
            silhouette_floor: 1.0,
            centre_reach: CENTRE_REACH,
        }
    }
}

/// The side of the square (a fraction of the grid's side) over which the silhouette floor's centre on body columns
/// averages their envelope centres.
pub const FLOOR_CENTRE_SPAN: f64 = 1.0 / 8.0;

/// [`ReconcileParams::centre_reach`] by default (cube units).
pub const CENTRE_REACH: f32 = 0.1;
/// Screening weight (per cube unit²): a screening length of about 30 cube units, far beyond the cube, so it only
/// decides the value of regions that nothing else fixes.
const SCREEN: f64 = 1e-3;
/// Below this many free cells (or this side) a level is solved directly, without a coarser start.
const DIRECT_CELLS: usize = 4096;
/// Relative residual at which the conjugate gradients stop.
const TOLERANCE: f64 = 1e-6;
/// Conjugate-gradient iterations on a level started from the coarser one (sides up to 256), and on finer levels.
/// Measured on the Grace Hopper portrait (94 000 free columns at 512²) against the fully converged solve: 40 and 15
/// leave a smooth offset of at most 0.026 cube units (99 % of columns under 0.021), in about a tenth of the time.
const LEVEL_ITERATIONS: usize = 40;
/// See [`LEVEL_ITERATIONS`].
const FINE_ITERATIONS: usize = 15;

/// A Poisson problem `-Δx + s (x - t) = f` over the free cells of a grid (see the module docs).
#[derive(Clone, Debug)]
struct GridProblem {
    width: usize,
    height: usize,
    cells: Vec<Cell>,
    /// The value of body cells (unused elsewhere).
    fixed: Vec<f64>,
    /// `Some(v)`: the outline holds `x = v` half a pixel outside the mask; `None`: zero slope there.
    outline: Option<f64>,
    /// `f`.
    source: f64,
    /// `t`.
    target: f64,
    /// `s` (per cube unit²).
    screen: f64,
    /// `1 / spacing²` across columns and rows.
    inv_dx2: f64,
    inv_dy2: f64,
}

impl GridProblem {
    fn free_count(&self) -> usize {
        self.cells.iter().filter(|&&c| c == Cell::Free).count()
    }

    /// The same problem on a grid half as fine: a 2x2 block is body if any of its cells is (the mean of their
    /// values), else free if any is, else outside if any is, else cut.
    fn coarsen(&self) -> Self {
        let (cw, ch) = (self.width.div_ceil(2), self.height.div_ceil(2));
        let mut cells = vec![Cell::Cut; cw * ch];
        let mut fixed = vec![0.0; cw * ch];
        for r in 0..ch {
            for c in 0..cw {
                let (mut body, mut sum, mut free, mut outside) = (0usize, 0.0, false, false);
                for (dc, dr) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let (fc, fr) = (2 * c + dc, 2 * r + dr);
                    if fc >= self.width || fr >= self.height {
                        continue;
                    }
                    let i = fr * self.width + fc;
                    match self.cells[i] {
                        Cell::Body => {
                            body += 1;
                            sum += self.fixed[i];
                        }
                        Cell::Free => free = true,
                        Cell::Outside => outside = true,
                        Cell::Cut => {}
                    }
                }
                let k = r * cw + c;
                cells[k] = if body > 0 {
                    fixed[k] = sum / body as f64;
                    Cell::Body
                } else if free {
                    Cell::Free
                } else if outside {
                    Cell::Outside
                } else {
                    Cell::Cut
                };
            }
        }
        Self { width: cw, height: ch, cells, fixed, inv_dx2: self.inv_dx2 / 4.0, inv_dy2: self.inv_dy2 / 4.0, ..*self }
    }

    /// The solution on every cell: solved on free cells, the fixed value on body cells, `target` elsewhere.
    /// Solved from the coarser level's solution when the grid is large.
    fn solve_cascade(&self) -> Vec<f64> {
        let free = self.free_count();
        let cascaded = free > DIRECT_CELLS && self.width.min(self.height) > 64;
        let guess: Vec<f64> = if cascaded {
            let coarse = self.coarsen();
            let xs = coarse.solve_cascade();
            self.prolong(&coarse, &xs)
        } else {
            vec![self.target; self.width * self.height]
        };
        let cap = if !cascaded {
            usize::MAX
        } else if self.width.max(self.height) > 256 {
            FINE_ITERATIONS
        } else {
            LEVEL_ITERATIONS
        };
        self.solve_from(&guess, cap)
    }

    /// Bilinear interpolation of the coarser level's solution `xs` (a value per coarse cell) at this level's free
    /// cell centres (the only values [`GridProblem::solve_from`] reads as its start), over the coarse cells that
    /// have a value (free or body); `target` where none around has one, and on the cells that are not free.
    fn prolong(&self, coarse: &GridProblem, xs: &[f64]) -> Vec<f64> {
        let valued = |k: usize| matches!(coarse.cells[k], Cell::Free | Cell::Body);
        // Every cell on its own: in parallel.
        (0..self.width * self.height)
            .into_par_iter()
            .map(|i| {
                if self.cells[i] != Cell::Free {
                    return self.target;
                }
                let (c, r) = (i % self.width, i / self.width);
                // Fine centre c + 0.5 sits at coarse coordinate (c + 0.5) / 2 - 0.5.
                let (x, y) = ((c as f64 + 0.5) * 0.5 - 0.5, (r as f64 + 0.5) * 0.5 - 0.5);
                let (x0, y0) = (x.floor(), y.floor());
                let (tx, ty) = (x - x0, y - y0);
                let (mut sum, mut weight) = (0.0, 0.0);
                for (dx, dy, wt) in
                    [(0, 0, (1.0 - tx) * (1.0 - ty)), (1, 0, tx * (1.0 - ty)), (0, 1, (1.0 - tx) * ty), (1, 1, tx * ty)]
                {
                    let (cx, cy) = (x0 as i64 + dx, y0 as i64 + dy);
                    if cx < 0 || cy < 0 || cx >= coarse.width as i64 || cy >= coarse.height as i64 {
                        continue;
                    }
                    let k = cy as usize * coarse.width + cx as usize;
                    if valued(k) && wt > 0.0 {
                        sum += wt * xs[k];
                        weight += wt;
                    }
                }
                if weight > 0.0 {
                    sum / weight
                } else {
                    self.target
                }
            })
            .collect()
    }

    /// Conjugate gradients (Jacobi preconditioner) from `guess` (a value per cell).
    ///
    /// Laid out for memory traffic, with the arithmetic of the textbook loop in the same order (the same bits):
    /// a missing neighbour points at a padding unknown that is always 0 (`s - w * 0 = s`), the products `p·Ap`,
    /// `r·z` and `r·r` are summed in the passes that produce their factors (sequentially, from -0 as `Iterator::sum`
    /// does), and `z = r / diag` is recomputed where it is read instead of stored.
    fn solve_from(&self, guess: &[f64], cap: usize) -> Vec<f64> {
        let (w, h) = (self.width, self.height);
        let mut index = vec![u32::MAX; w * h];
        let mut order: Vec<usize> = Vec::new();
        for (i, c) in self.cells.iter().enumerate() {
            if *c == Cell::Free {
                index[i] = order.len() as u32;
                order.push(i);
            }
        }
        let n = order.len();
        // The padding unknown that missing neighbours point at.
        let pad = n as u32;
        // Per unknown: diagonal, right-hand side, and four neighbour unknowns (left, right: weight `inv_dx2`; up,
        // down: `inv_dy2`).
        let mut diag = vec![self.screen; n];
        let mut rhs = vec![self.source + self.screen * self.target; n];
        let mut links = vec![[pad; 4]; n];
        for (k, &i) in order.iter().enumerate() {
            let (c, r) = (i % w, i / w);
            let neighbours = [
                (c > 0).then(|| i - 1).map(|j| (j, self.inv_dx2)),
                (c + 1 < w).then(|| i + 1).map(|j| (j, self.inv_dx2)),
                (r > 0).then(|| i - w).map(|j| (j, self.inv_dy2)),
                (r + 1 < h).then(|| i + w).map(|j| (j, self.inv_dy2)),
            ];
            for (slot, nb) in neighbours.into_iter().enumerate() {
                let Some((j, wt)) = nb else { continue };
                match self.cells[j] {
                    Cell::Free => {
                        diag[k] += wt;
                        links[k][slot] = index[j];
                    }
                    Cell::Body => {
                        diag[k] += wt;
                        rhs[k] += wt * self.fixed[j];
                    }
                    Cell::Outside => {
                        if let Some(v) = self.outline {
                            diag[k] += 2.0 * wt;
                            rhs[k] += 2.0 * wt * v;
                        }
                    }
                    Cell::Cut => {}
                }
            }
        }
        let weights = [self.inv_dx2, self.inv_dx2, self.inv_dy2, self.inv_dy2];
        // `(A x)_k` for a vector with the padding unknown (`x[n] = 0`).
        let row = |x: &[f64], k: usize| -> f64 {
            let l = &links[k];
            let mut s = diag[k] * x[k];
            for slot in 0..4 {
                s -= weights[slot] * x[l[slot] as usize];
            }
            s
        };
        let mut x: Vec<f64> = order
            .iter()
            .map(|&i| if guess[i].is_finite() { guess[i] } else { self.target })
            .chain(std::iter::once(0.0))
            .collect();
        let mut r: Vec<f64> = (0..n).map(|k| rhs[k] - row(&x, k)).collect();
        let mut p: Vec<f64> = r.iter().zip(&diag).map(|(r, d)| r / d).chain(std::iter::once(0.0)).collect();
        let mut ap = vec![0.0; n];
        let (mut rz, mut rr) = (-0.0f64, -0.0f64);
        for k in 0..n {
            rz += r[k] * p[k];
            rr += r[k] * r[k];
        }
        let b_norm = rhs.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300);
        for _ in 0..(4 * n + 100).min(cap) {
            if rr.sqrt() <= TOLERANCE * b_norm {
                break;
            }
            let mut pap = -0.0f64;
            for k in 0..n {
                let s = row(&p, k);
                ap[k] = s;
                pap += p[k] * s;
            }
            if pap.is_nan() || pap <= 0.0 {
                break;
            }
            let alpha = rz / pap;
            let (mut rz_new, mut rr_new) = (-0.0f64, -0.0f64);
            for k in 0..n {
                x[k] += alpha * p[k];
                r[k] -= alpha * ap[k];
                rz_new += r[k] * (r[k] / diag[k]);
                rr_new += r[k] * r[k];
            }
            let beta = rz_new / rz;
            rz = rz_new;
            rr = rr_new;
            for k in 0..n {
                p[k] = r[k] / diag[k] + beta * p[k];
            }
        }
        let mut out: Vec<f64> =
            (0..w * h).map(|i| if self.cells[i] == Cell::Body { self.fixed[i] } else { self.target }).collect();
        for (k, &i) in order.iter().enumerate() {
            out[i] = if x[k].is_finite() { x[k] } else { self.target };
        }
        out
    }
}

/// The class of every column (see the module docs): `body` intervals on the mask's grid, `mask` in `[0, 1]`
/// (threshold 0.5), `frame` where the photo lies (`None`: the whole grid).
pub fn classify(body: &Image<Vec<(f32, f32)>>, mask: &GrayImage, frame: Option<PhotoFrame>) -> Vec<Cell> {
    let (w, h) = (mask.width, mask.height);
    let (lo, hi) = frame.unwrap_or((Vec2::ZERO, Vec2::new(w as f32, h as f32)));
    (0..w * h)
        .map(|i| {
            let (c, r) = ((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
            let in_photo = c >= lo.x && c <= hi.x && r >= lo.y && r <= hi.y;
            match (mask.data[i] >= 0.5, body.data.get(i).is_some_and(|l| !l.is_empty())) {
                (true, true) => Cell::Body,
                (true, false) => Cell::Free,
                (false, _) if in_photo => Cell::Outside,
                (false, _) => Cell::Cut,
            }
        })
        .collect()
}

/// The silhouette's own inflation profile `u_s` of a mask (the **silhouette floor** of the module docs: `-Δu_s = 4`
/// over every mask column, `u_s = 0` on the outline and at the cut). It depends on the mask alone, so it can be
/// solved before the body is known: the pipeline solves it beside the pose network and the fit and hands it to
/// [`reconcile_with`].
#[derive(Clone, Debug)]
pub struct SilhouetteProfile {
    width: usize,
    height: usize,
    u: Vec<f64>,
}

impl SilhouetteProfile {
    /// The profile of `mask` (`[0, 1]`, threshold 0.5).
    pub fn of(mask: &GrayImage) -> Self {
        let (w, h) = (mask.width, mask.height);
        Self { width: w, height: h, u: silhouette_problem(mask).solve_cascade() }
    }
}

/// The problem [`SilhouetteProfile`] solves: every mask column free, the outline everywhere (the cut too: a region
/// the frame closes on every side would otherwise have nothing to hold it), like the inflation prior.
fn silhouette_problem(mask: &GrayImage) -> GridProblem {
    let (w, h) = (mask.width, mask.height);
    GridProblem {
        width: w,
        height: h,
        cells: mask.data.iter().map(|&m| if m >= 0.5 { Cell::Free } else { Cell::Outside }).collect(),
        fixed: vec![0.0; w * h],
        outline: Some(0.0),
        source: 4.0,
        target: 0.0,
        screen: SCREEN,
        inv_dx2: (w as f64 / 2.0).powi(2),
        inv_dy2: (h as f64 / 2.0).powi(2),
    }
}

/// The body's intervals reconciled with the silhouette (see the module docs), on the mask's grid. `body` must be
/// on that grid (`intervals_from_mesh` at the mask's size); intervals are sorted by depth, each `(back, front)`.
/// Non-finite body values are ignored; every output interval lies in `[-1, 1]`.
pub fn reconcile(
    body: &Image<Vec<(f32, f32)>>,
    mask: &GrayImage,
    frame: Option<PhotoFrame>,
    params: &ReconcileParams,
) -> Image<Vec<(f32, f32)>> {
    reconcile_with(body, mask, frame, params, None)
}

/// [`reconcile`] with the silhouette's profile solved beforehand (`silhouette`, [`SilhouetteProfile::of`] the same
/// mask; solved here when `None` or of another size): the same result.
pub fn reconcile_with(
    body: &Image<Vec<(f32, f32)>>,
    mask: &GrayImage,
    frame: Option<PhotoFrame>,
    params: &ReconcileParams,
    silhouette: Option<&SilhouetteProfile>,
) -> Image<Vec<(f32, f32)>> {
    let (w, h) = (mask.width, mask.height);
    let mut out: Image<Vec<(f32, f32)>> = Image::new(w, h, Vec::new());
    if w == 0 || h == 0 || body.width != w || body.height != h {
        return out;
    }
    let clean = |l: &[(f32, f32)]| -> Vec<(f32, f32)> {
        l.iter()
            .filter(|(a, b)| a.is_finite() && b.is_finite() && b >= a)
            .map(|&(a, b)| (a.clamp(-1.0, 1.0), b.clamp(-1.0, 1.0)))
            .collect()
    };
    let body = Image { width: w, height: h, data: body.data.par_iter().map(|l| clean(l)).collect() };
    let cells = classify(&body, mask, frame);
    let kappa = if params.thickness.is_finite() && params.thickness > 0.0 { params.thickness as f64 } else { 0.7 };
    let envelope = |l: &[(f32, f32)]| -> (f64, f64) {
        let (back, front) = (l[0].0 as f64, l[l.len() - 1].1 as f64);
        (0.5 * (back + front), 0.5 * (front - back).max(0.0))
    };
    let mut centres = Vec::new();
    let mut centre_fixed = vec![0.0; w * h];
    let mut u_fixed = vec![0.0; w * h];
    for i in 0..w * h {
        if cells[i] == Cell::Body {
            let (c, half) = envelope(&body.data[i]);
            centre_fixed[i] = c;
            u_fixed[i] = (half / kappa).powi(2);
            centres.push(c);
        }
    }
    let floor = if params.silhouette_floor.is_finite() { params.silhouette_floor.max(0.0) as f64 } else { 0.0 };
    // The floor's centre on body columns: their envelope centres averaged over a square of FLOOR_CENTRE_SPAN of
    // the grid's side (body columns only), so a limb in front of or behind the trunk does not carry a slab as thick
    // as the silhouette with it, one that jumps from column to column.
    let radius = (w.max(h) as f64 * FLOOR_CENTRE_SPAN * 0.5).round().max(1.0) as usize;
    let floor_centre = box_mean(&centre_fixed, &cells, w, h, radius);
    let reach = params.centre_reach as f64;
    let centre_screen = if reach.is_finite() && reach > 0.0 { (1.0 / (reach * reach)).max(SCREEN) } else { SCREEN };
    let base = GridProblem {
        width: w,
        height: h,
        cells,
        fixed: centre_fixed,
        outline: None,
        source: 0.0,
        target: median(&mut centres).unwrap_or(0.0),
        screen: centre_screen,
        inv_dx2: (w as f64 / 2.0).powi(2),
        inv_dy2: (h as f64 / 2.0).powi(2),
    };
    let u_problem =
        GridProblem { fixed: u_fixed, outline: Some(0.0), source: 4.0, target: 0.0, screen: SCREEN, ..base.clone() };
    let any_free = base.cells.contains(&Cell::Free);
    let solve = |p: &GridProblem, needed: bool| if needed { p.solve_cascade() } else { vec![p.target; w * h] };
    let silhouette = silhouette.filter(|s| (s.width, s.height) == (w, h));
    let floor_profile = || -> std::borrow::Cow<'_, [f64]> {
        match silhouette {
            _ if floor <= 0.0 => vec![0.0; w * h].into(),
            Some(s) => s.u.as_slice().into(),
            None => silhouette_problem(mask).solve_cascade().into(),
        }
    };
    let (centre, (u, u_s)) =
        rayon::join(|| solve(&base, any_free), || rayon::join(|| solve(&u_problem, any_free), floor_profile));
    let h_min = (params.min_half_thickness.max(0.0) as f64 * 2.0 / w.max(h) as f64)
        .max(if params.min_half_depth.is_finite() { params.min_half_depth.max(0.0) as f64 } else { 0.0 });
    // Every column on its own (the same values in any order): in parallel.
    out.data.par_iter_mut().enumerate().for_each(|(i, column)| {
        let h_s = floor * kappa * u_s[i].max(0.0).sqrt();
        match base.cells[i] {
            Cell::Free => {
                let half = (kappa * u[i].max(0.0).sqrt()).max(h_s).max(h_min);
                let c = centre[i];
                let (a, b) = ((c - half).clamp(-1.0, 1.0) as f32, (c + half).clamp(-1.0, 1.0) as f32);
                if a.is_finite() && b.is_finite() && b > a {
                    *column = vec![(a, b)];
                }
            }
            Cell::Body => {
                let c = if floor_centre[i].is_finite() { floor_centre[i] } else { base.fixed[i] };
                let floor_interval = ((c - h_s).clamp(-1.0, 1.0) as f32, (c + h_s).clamp(-1.0, 1.0) as f32);
                *column = union_with(&body.data[i], floor_interval);
            }
            Cell::Outside | Cell::Cut => {}
        }
    });
    out
}

/// The median of `values` (the mean of the two middle ones for an even count); `None` when empty.
fn median(values: &mut [f64]) -> Option<f64> {
    let n = values.len();
    if n == 0 {
        return None;
    }
    let (_, &mut upper, _) = values.select_nth_unstable_by(n / 2, f64::total_cmp);
    if n % 2 == 1 {
        return Some(upper);
    }
    let lower = values[..n / 2].iter().copied().fold(f64::NEG_INFINITY, f64::max);
    Some(0.5 * (lower + upper))
}

/// Sorted disjoint intervals `list` united with `extra` (ignored when empty or not finite).
/// The mean of `values` over the body cells (`cells[i] == Cell::Body`) in the `(2 radius + 1)²` square about each
/// pixel of a `w x h` grid (NaN where the square holds none): separable running sums, O(w h) whatever the radius
/// (a box filter of twenty lines; no image crate here does masked means).
fn box_mean(values: &[f64], cells: &[Cell], w: usize, h: usize, radius: usize) -> Vec<f64> {
    let body = |i: usize| cells[i] == Cell::Body && values[i].is_finite();
    let sum: Vec<(f64, f64)> = (0..w * h).map(|i| if body(i) { (values[i], 1.0) } else { (0.0, 0.0) }).collect();
    // One pass along rows (step 1, n = w, lines = h) or columns (step w, n = h, lines = w).
    let pass = |input: &[(f64, f64)], step: usize, n: usize, lines: usize, line_step: usize| {
        let mut out = vec![(0.0, 0.0); w * h];
        for line in 0..lines {
            let at = |k: usize| line * line_step + k * step;
            let mut acc = (0.0, 0.0);
            for k in 0..radius.min(n) {
                acc.0 += input[at(k)].0;
                acc.1 += input[at(k)].1;
            }
            for k in 0..n {
                if k + radius < n {
                    acc.0 += input[at(k + radius)].0;
                    acc.1 += input[at(k + radius)].1;
                }
                if k > radius {
                    acc.0 -= input[at(k - radius - 1)].0;
                    acc.1 -= input[at(k - radius - 1)].1;
                }
                out[at(k)] = acc;
            }
        }
        out
    };
    let rows = pass(&sum, 1, w, h, w);
    let both = pass(&rows, w, h, w, 1);
    both.iter().map(|&(s, n)| if n > 0.5 { s / n } else { f64::NAN }).collect()
}

fn union_with(list: &[(f32, f32)], extra: (f32, f32)) -> Vec<(f32, f32)> {
    let mut all = list.to_vec();
    if extra.0.is_finite() && extra.1.is_finite() && extra.1 > extra.0 {
        all.push(extra);
        all.sort_by(|a, b| a.0.total_cmp(&b.0));
    }
    let mut merged: Vec<(f32, f32)> = Vec::with_capacity(all.len());
    for (a, b) in all {
        match merged.last_mut() {
            Some(m) if a <= m.1 => m.1 = m.1.max(b),
            _ => merged.push((a, b)),
        }
    }
    merged
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mask_of(w: usize, h: usize, f: impl Fn(usize, usize) -> bool) -> GrayImage {
        Image::from_fn(w, h, |c, r| if f(c, r) { 1.0 } else { 0.0 })
    }

    /// Whether pixel `(c, r)` of an `n` x `n` grid lies in the disc of `radius` pixels about the grid's centre.
    fn in_disc(n: usize, radius: f32) -> impl Fn(usize, usize) -> bool + Copy {
        let half = n as f32 / 2.0;
        move |c, r| {
            let (x, y) = (c as f32 + 0.5 - half, r as f32 + 0.5 - half);
            x * x + y * y <= radius * radius
        }
    }

    #[test]
    fn a_free_region_without_body_is_the_inflation_profile() {
        // A disc of radius R pixels: u = R² - r² (cube units), h = κ sqrt(u), centred on the body's median
        // depth (no body: 0).
        let (n, radius) = (96usize, 30.0f32);
        let mask = mask_of(n, n, in_disc(n, radius));
        let body = Image::new(n, n, Vec::new());
        let params =
            ReconcileParams { thickness: 1.0, min_half_thickness: 0.0, silhouette_floor: 1.0, ..Default::default() };
        let out = reconcile(&body, &mask, None, &params);
        let px = 2.0 / n as f32;
        for (c, r) in [(48usize, 48usize), (60, 48), (48, 70), (30, 40)] {
            let (x, y) = (c as f32 + 0.5 - 48.0, r as f32 + 0.5 - 48.0);
            let expected = (radius * radius - x * x - y * y).max(0.0).sqrt() * px;
            let (a, b) = out.get(c, r)[0];
            assert!((a + b).abs() < 1e-5, "centred on 0: {a} {b}");
            // The pixel outline approximates the circle to about half a pixel.
            assert!(
                (0.5 * (b - a) - expected).abs() < 0.03 * radius * px,
                "({c},{r}): {} vs {expected}",
                0.5 * (b - a)
            );
        }
        assert!(out.get(5, 5).is_empty());
    }

    /// The exact solution of the 5-point screened equation along a row of free cells `k = 1..n-1` between fixed
    /// values `y0` (k = 0) and `yn` (k = n), the screening `1/ρ²` on spacing `dx`: `y_{k-1} - 2 cosh θ y_k + y_{k+1}
    /// = 0` with `2 cosh θ = 2 + dx²/ρ²` (about the target 0); `ρ = ∞` gives the straight line.
    fn screened_row(y0: f64, yn: f64, n: usize, k: usize, dx: f64, rho: f64) -> f64 {
        let (n, k) = (n as f64, k as f64);
        if !rho.is_finite() {
            return y0 + (yn - y0) * k / n;
        }
        let theta = (1.0 + 0.5 * (dx / rho).powi(2)).acosh();
        (y0 * (theta * (n - k)).sinh() + yn * (theta * k).sinh()) / (theta * n).sinh()
    }

    #[test]
    fn the_centre_between_body_columns_settles_on_their_median() {
        // A strip between two body columns at depths -0.2 and 0.4 (as many cells each: median 0.1), the photo's
        // frame around it (so its ends and sides are cut, zero slope): the centre is the exact solution of the
        // screened equation across it (the straight line when harmonic), and the thickness follows the inflation
        // of the gap from the body's thickness at both ends, exactly (the 5-point stencil is exact on quadratics).
        let (w, h) = (40usize, 12usize);
        let (first, last) = (10usize, 29usize);
        let mask = mask_of(w, h, |c, _| (first..=last).contains(&c));
        let mut body = Image::new(w, h, Vec::new());
        for r in 0..h {
            body.set(first, r, vec![(-0.3, -0.1)]);
            body.set(last, r, vec![(0.3, 0.5)]);
        }
        let frame = Some((Vec2::new(first as f32, 0.0), Vec2::new(last as f32 + 1.0, h as f32)));
        let kappa = ReconcileParams::default().thickness as f64;
        let dx = 2.0 / w as f64;
        let l = (last - first) as f64 * dx;
        for rho in [0.1f64, 0.3, f64::INFINITY] {
            let params = ReconcileParams { silhouette_floor: 0.0, centre_reach: rho as f32, ..Default::default() };
            let out = reconcile(&body, &mask, frame, &params);
            for c in first + 1..last {
                let x = (c - first) as f64 * dx;
                let centre = 0.1 + screened_row(-0.3, 0.3, last - first, c - first, dx, rho);
                // u = u_b + 2 x (L - x), u_b = (0.1 / κ)².
                let half = kappa * ((0.1 / kappa).powi(2) + 2.0 * x * (l - x)).sqrt();
                for r in [0usize, 5, 11] {
                    let (a, b) = out.get(c, r)[0];
                    let (got_c, got_h) = (0.5 * (a + b) as f64, 0.5 * (b - a) as f64);
                    assert!((got_c - centre).abs() < 1e-4, "ρ {rho}, column {c}: centre {got_c} vs {centre}");
                    assert!((got_h - half).abs() < 1e-4, "ρ {rho}, column {c}: half thickness {got_h} vs {half}");
                }
            }
            assert_eq!(out.get(first, 3), &vec![(-0.3, -0.1)]);
            assert!(out.get(first - 1, 3).is_empty() && out.get(last + 1, 3).is_empty());
        }
    }

    #[test]
    fn a_region_the_body_does_not_explain_does_not_follow_one_limb() {
        // A torso block at depth 0 (20 columns), one limb column beside it at depth 0.6 (a mis-fitted leg), and a
        // long free strip (a tripod) that touches only the limb, open at its far end (the grid's edge: zero slope).
        // The strip's centre is `0.6 cosh(θ (k - n - 1/2)) / cosh(θ (n + 1/2))` about the median 0 (k = 0 the limb,
        // n = 39 free cells): within a few ρ it is back at the torso's depth. Harmonic, the whole strip took the
        // limb's depth 0.6. (Rows 26..34 only, so that the outline holds the thickness; the centre's zero slope
        // there keeps it one-dimensional.)
        let (w, h) = (60usize, 60usize);
        let rows = 26..34;
        let mask = mask_of(w, h, |_, r| rows.contains(&r));
        let mut body = Image::new(w, h, Vec::new());
        for r in rows.clone() {
            for c in 0..20 {
                body.set(c, r, vec![(-0.1, 0.1)]);
            }
            body.set(20, r, vec![(0.5, 0.7)]);
        }
        let dx = 2.0 / w as f64;
        let n = w - 21;
        let rho = CENTRE_REACH as f64;
        let theta = (1.0 + 0.5 * (dx / rho).powi(2)).acosh();
        let params = ReconcileParams { silhouette_floor: 0.0, ..Default::default() };
        let out = reconcile(&body, &mask, None, &params);
        for k in 1..=n {
            let expected = 0.6 * (theta * (k as f64 - n as f64 - 0.5)).cosh() / (theta * (n as f64 + 0.5)).cosh();
            for r in [26usize, 33] {
                let (a, b) = out.get(20 + k, r)[0];
                let got = 0.5 * (a + b) as f64;
                assert!((got - expected).abs() < 1e-4, "cell {k}: centre {got} vs {expected}");
            }
        }
        let far = out.get(w - 1, 30)[0];
        assert!((0.5 * (far.0 + far.1)).abs() < 0.01, "{far:?}");
        let harmonic = reconcile(&body, &mask, None, &ReconcileParams { centre_reach: f32::INFINITY, ..params });
        let far = harmonic.get(w - 1, 30)[0];
        assert!(0.5 * (far.0 + far.1) > 0.55, "{far:?}");
    }

    #[test]
    fn a_body_outside_the_mask_or_covering_all_of_it_stays_finite() {
        // A body that covers none of the mask (columns only outside the disc) is no body: the inflation profile
        // about depth 0, exactly as without a body. A body covering the whole mask leaves nothing free: its own
        // intervals, with the floor. Extreme and reversed body values change neither.
        let (n, radius) = (64usize, 20.0f32);
        let inside = in_disc(n, radius);
        let mask = mask_of(n, n, inside);
        let params = ReconcileParams::default();
        let alone = reconcile(&Image::new(n, n, Vec::new()), &mask, None, &params);
        let mut outside = Image::new(n, n, Vec::new());
        for r in 0..n {
            for c in 0..n {
                if !inside(c, r) {
                    outside.set(c, r, vec![(0.9, 0.95), (3.0, 1.0)]);
                }
            }
        }
        assert_eq!(reconcile(&outside, &mask, None, &params).data, alone.data);
        for r in 0..n {
            for c in 0..n {
                assert_eq!(alone.get(c, r).len(), usize::from(inside(c, r)), "({c},{r})");
            }
        }
        let covering = Image::from_fn(n, n, |_, _| vec![(-0.05f32, 0.15f32)]);
        let out = reconcile(&covering, &mask, None, &params);
        for (i, l) in out.data.iter().enumerate() {
            let (c, r) = (i % n, i / n);
            if !inside(c, r) {
                assert!(l.is_empty());
                continue;
            }
            assert_eq!(l.len(), 1, "({c},{r})");
            let (a, b) = l[0];
            assert!(a.is_finite() && b.is_finite() && a <= -0.05 && b >= 0.15 && (a + b - 0.1).abs() < 1e-5);
        }
    }

    #[test]
    fn the_median_of_body_depths() {
        assert_eq!(median(&mut []), None);
        assert_eq!(median(&mut [3.0]), Some(3.0));
        assert_eq!(median(&mut [5.0, -1.0, 0.5]), Some(0.5));
        assert_eq!(median(&mut [0.4, -0.2, 9.0, -7.0]), Some(0.1));
    }

    #[test]
    fn every_column_is_at_least_as_thick_as_the_silhouettes_inflation() {
        // A disc of radius R with a thin body slab (half depth 0.02 about z = 0.1) over its middle third and one
        // thick body column: the slab's columns become the inflation sphere's interval about their own centre,
        // u_s = R² - r², h = κ sqrt(u_s); the thick column keeps its own interval; free columns are at least the
        // sphere. Without the floor the slab stays as thin as the body.
        let (n, radius) = (96usize, 30.0f32);
        let inside = in_disc(n, radius);
        let mask = mask_of(n, n, inside);
        let mut body = Image::new(n, n, Vec::new());
        for r in 0..n {
            for c in 38..58 {
                if inside(c, r) {
                    body.set(c, r, vec![(0.08, 0.12)]);
                }
            }
        }
        body.set(48, 48, vec![(-0.9, 0.9)]);
        let kappa = 0.7f32;
        let params =
            ReconcileParams { thickness: kappa, min_half_thickness: 0.0, silhouette_floor: 1.0, ..Default::default() };
        let out = reconcile(&body, &mask, None, &params);
        let px = 2.0 / n as f32;
        let sphere = |c: usize, r: usize| {
            let (x, y) = (c as f32 + 0.5 - 48.0, r as f32 + 0.5 - 48.0);
            kappa * (radius * radius - x * x - y * y).max(0.0).sqrt() * px
        };
        for (c, r) in [(40usize, 48usize), (50, 30), (45, 60)] {
            let (a, b) = out.get(c, r)[0];
            assert_eq!(out.get(c, r).len(), 1);
            assert!((0.5 * (a + b) - 0.1).abs() < 1e-5, "({c},{r}) centred on the slab: {a} {b}");
            let expected = sphere(c, r);
            assert!((0.5 * (b - a) - expected).abs() < 0.03 * expected, "({c},{r}): {} vs {expected}", 0.5 * (b - a));
        }
        assert_eq!(out.get(48, 48), &vec![(-0.9, 0.9)]);
        for (c, r) in [(25usize, 48usize), (70, 40)] {
            let (a, b) = out.get(c, r)[0];
            assert!(0.5 * (b - a) >= sphere(c, r) * 0.97, "free ({c},{r}): {} vs {}", 0.5 * (b - a), sphere(c, r));
        }
        let bare = reconcile(&body, &mask, None, &ReconcileParams { silhouette_floor: 0.0, ..params });
        assert_eq!(bare.get(40, 48), &vec![(0.08, 0.12)]);
        // The silhouette's profile solved beforehand gives the same bits; one of another mask's size is not used,
        // nor one at all without the floor; one of another mask of the same size is (the caller's contract).
        let profile = SilhouetteProfile::of(&mask);
        assert_eq!(reconcile_with(&body, &mask, None, &params, Some(&profile)).data, out.data);
        let other_size = SilhouetteProfile::of(&mask_of(n / 2, n / 2, in_disc(n / 2, 10.0)));
        assert_eq!(reconcile_with(&body, &mask, None, &params, Some(&other_size)).data, out.data);
        let smaller = SilhouetteProfile::of(&mask_of(n, n, in_disc(n, 20.0)));
        let no_floor = ReconcileParams { silhouette_floor: 0.0, ..params };
        assert_eq!(reconcile_with(&body, &mask, None, &no_floor, Some(&smaller)).data, bare.data);
        assert_ne!(reconcile_with(&body, &mask, None, &params, Some(&smaller)).data, out.data);
    }

    #[test]
    fn thin_free_parts_keep_the_fofs_resolving_thickness() {
        // A free strip two pixels wide on a 256² grid (a tripod's leg; no body): its inflation is a quarter of
        // what a 32-term FOF resolves (the 5-point stencil with the outline at the mask's edge: 2 u / dx² = 4, so
        // u = 2 px², h = κ √2 px = 0.0077); with `min_half_depth` every column of it is exactly that thick about
        // the centre 0, the thick block beside it is not touched, and a NaN or negative `min_half_depth` is no
        // floor.
        let (w, h) = (256usize, 256usize);
        let mask = mask_of(w, h, |c, r| (127..129).contains(&c) && (32..224).contains(&r) || (c < 96 && r < 96));
        let body = Image::new(w, h, Vec::new());
        let floor = 0.5 * crate::geometry::fof::sheet_thickness(32);
        let base = ReconcileParams { min_half_thickness: 0.0, silhouette_floor: 0.0, ..Default::default() };
        let thin = reconcile(&body, &mask, None, &base);
        let (a, b) = thin.get(127, 128)[0];
        let px = 2.0 / w as f32;
        assert!((0.5 * (b - a) - base.thickness * 2f32.sqrt() * px).abs() < 1e-5, "{a} {b}");
        let out = reconcile(&body, &mask, None, &ReconcileParams { min_half_depth: floor, ..base });
        for r in 40..216 {
            for c in 127..129 {
                let (a, b) = out.get(c, r)[0];
                assert!((0.5 * (b - a) - floor).abs() < 1e-6 && (a + b).abs() < 1e-6, "({c},{r}): {a} {b}");
            }
        }
        assert_eq!(out.get(48, 48), thin.get(48, 48));
        assert!(0.5 * (thin.get(48, 48)[0].1 - thin.get(48, 48)[0].0) > 5.0 * floor);
        for bad in [f32::NAN, -1.0] {
            assert_eq!(reconcile(&body, &mask, None, &ReconcileParams { min_half_depth: bad, ..base }).data, thin.data);
        }
    }

    #[test]
    fn intervals_unite_with_the_floor() {
        assert_eq!(union_with(&[(0.0, 0.1), (0.5, 0.6)], (0.05, 0.55)), vec![(0.0, 0.6)]);
        assert_eq!(union_with(&[(0.0, 0.1), (0.5, 0.6)], (0.2, 0.3)), vec![(0.0, 0.1), (0.2, 0.3), (0.5, 0.6)]);
        assert_eq!(union_with(&[(0.0, 0.1)], (f32::NAN, 0.3)), vec![(0.0, 0.1)]);
        assert_eq!(union_with(&[(0.0, 0.1)], (0.3, 0.3)), vec![(0.0, 0.1)]);
    }

    #[test]
    fn box_mean_averages_body_cells_only() {
        // 4 x 3 grid, body cells (0,0) = 1, (1,0) = 3, (3,2) = 5, every other value ignored; radius 1.
        let (w, h) = (4, 3);
        let mut cells = vec![Cell::Free; w * h];
        let mut values = vec![100.0; w * h];
        for (i, v) in [(0, 1.0), (1, 3.0), (11, 5.0)] {
            cells[i] = Cell::Body;
            values[i] = v;
        }
        cells[5] = Cell::Body;
        values[5] = f64::NAN; // a non-finite body value counts as none
        let m = box_mean(&values, &cells, w, h, 1);
        for (i, want) in [(0, 2.0), (2, 3.0), (4, 2.0), (6, 4.0), (11, 5.0)] {
            assert!((m[i] - want).abs() < 1e-12, "{i}: {} vs {want}", m[i]);
        }
        assert!(m[8].is_nan() && m[3].is_nan());
        // A radius beyond the grid: the mean of all three everywhere.
        assert!(box_mean(&values, &cells, w, h, 10).iter().all(|&v| (v - 3.0).abs() < 1e-12));
    }

    #[test]
    fn a_limb_in_front_of_the_trunk_carries_no_slab_of_the_floors_thickness() {
        // A disc mask (radius 20 px on 64²) covered by a trunk slab (-0.1, 0.1) everywhere except one column whose
        // body also holds a forearm far in front (0.5, 0.6). With the floor (half thickness about 0.44 there), the
        // forearm's column gets about the trunk's floor (its centre the mean of the 3 x 3 envelope centres about it,
        // 0.25 / 9) plus the forearm, not a floor about its own envelope centre (0.25) reaching the forearm.
        let (w, h) = (64usize, 64usize);
        let inside = in_disc(w, 20.0);
        let mask = mask_of(w, h, inside);
        let limb = |c: usize, r: usize| (c, r) == (32, 32);
        let body = Image::from_fn(w, h, |c, r| match (inside(c, r), limb(c, r)) {
            (false, _) => Vec::new(),
            (true, false) => vec![(-0.1, 0.1)],
            (true, true) => vec![(-0.1, 0.1), (0.5, 0.6)],
        });
        let params = ReconcileParams { thickness: 0.7, min_half_thickness: 0.0, ..Default::default() };
        let out = reconcile(&body, &mask, None, &params);
        let (trunk, arm) = (out.get(30, 32).clone(), out.get(32, 32).clone());
        assert_eq!(trunk.len(), 1);
        assert_eq!(arm.len(), 2, "{arm:?}");
        let floor_back = trunk[0].0;
        assert!(floor_back < -0.2, "the floor is thicker than the trunk slab: {trunk:?}");
        // The forearm's column: the floor about the same centre (its back within a few hundredths of the
        // neighbour's), the forearm itself untouched.
        assert!((arm[0].0 - floor_back).abs() < 0.05, "{arm:?} vs {trunk:?}");
        assert!((arm[1].0 - 0.5).abs() < 1e-6 && (arm[1].1 - 0.6).abs() < 1e-6, "{arm:?}");
    }

    #[test]
    fn the_cut_is_not_an_outline_and_outside_the_mask_is_empty() {
        // A strip of half width a whose bottom is the photo's frame: far from the top the thickness is the infinite
        // strip's (u = 2 (a² - x²)) right down to the cut, instead of closing there.
        let (w, h) = (64usize, 64usize);
        let a_px = 8.0f32;
        let mask = mask_of(w, h, |c, r| (8..56).contains(&r) && (c as f32 + 0.5 - 32.0).abs() <= a_px);
        let body = Image::new(w, h, Vec::new());
        let frame = Some((Vec2::ZERO, Vec2::new(64.0, 56.0)));
        let params =
            ReconcileParams { thickness: 1.0, min_half_thickness: 0.0, silhouette_floor: 0.0, ..Default::default() };
        let out = reconcile(&body, &mask, frame, &params);
        let px = 2.0 / w as f32;
        let expected = (2.0f32).sqrt() * a_px * px;
        let (a, b) = out.get(32, 55)[0];
        assert!((0.5 * (b - a) - expected).abs() < 0.05 * expected, "{} vs {expected}", 0.5 * (b - a));
        // Without the frame the bottom is an outline: the last row is thin.
        let closed = reconcile(&body, &mask, None, &params);
        let (a, b) = closed.get(32, 55)[0];
        assert!(0.5 * (b - a) < 0.5 * expected);
        assert!(out.get(2, 30).is_empty() && out.get(32, 60).is_empty());
    }

    #[test]
    fn degenerate_inputs_stay_finite() {
        let mask = mask_of(16, 16, |c, _| c > 3);
        let mut body = Image::new(16, 16, Vec::new());
        body.set(8, 8, vec![(f32::NAN, 0.2)]);
        body.set(9, 8, vec![(-5.0, 5.0)]);
        let out = reconcile(&body, &mask, None, &ReconcileParams::default());
        for l in &out.data {
            assert!(l.iter().all(|&(a, b)| a.is_finite() && b.is_finite() && (-1.0..=1.0).contains(&a) && b <= 1.0));
        }
        assert_eq!(out.get(9, 8), &vec![(-1.0, 1.0)]);
        // A grid mismatch or an empty grid gives nothing, not a panic.
        assert!(reconcile(&Image::new(3, 3, Vec::new()), &mask, None, &ReconcileParams::default())
            .data
            .iter()
            .all(|l| l.is_empty()));
        let empty = Image::new(0, 0, 0.0f32);
        assert!(reconcile(&Image::new(0, 0, Vec::new()), &empty, None, &ReconcileParams::default()).data.is_empty());
    }
}
