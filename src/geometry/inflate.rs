//! Geometry without a FOF network: a silhouette-inflation prior.
//!
//! From the person's source mask (already normalised into the body cube, at the FOF resolution):
//! 1. threshold at 0.5, drop foreground specks and fill small holes ([`InflateParams::min_component_pixels`]);
//! 2. trace every boundary (outer outlines and holes, several components) as closed loops along pixel edges,
//!    foreground 4-connected (diagonal-only contacts stay separate);
//! 3. simplify the loops (Douglas–Peucker) and triangulate the region with a constrained Delaunay
//!    triangulation (spade), refined inside (area and angle limits);
//! 4. solve the Poisson problem `-Δu = 4` on the triangles (P1 finite elements, conjugate gradients) with
//!    `u = 0` on the outline, and set the half thickness `h = κ sqrt(u)` (κ = [`InflateParams::thickness`]);
//! 5. rasterise `h` per pixel: `front = c + h`, `back = c - h` with `c` the centre plane
//!    ([`InflateParams::centre_z`], z = 0 by default), clamped to the cube.
//!
//! # Why this profile
//! For a disc of radius R the solution is `u = R² - r²`, so `h = κ sqrt(R² - r²)`: a sphere for κ = 1 and a
//! round cross-section at the outline (vertical tangent) for any κ. For a long strip of half width a (a limb),
//! `u = 2 (a² - x²)`, so the cross-section is an ellipse with depth semi-axis `κ √2 a`. The default
//! κ = 0.7 makes limbs round (`≈ 0.99 a`) and wide blobs (torso, a disc) flatter than a ball (`0.7 R`), which
//! is the plausible shape of a body seen from the front. Thickness thus follows the local width everywhere.
//! Pixels inside the mask always get at least [`InflateParams::min_half_thickness`], so one-pixel limbs keep
//! a thin but valid interval (the FOF may still be too band-limited to show them in the mesh).

use std::collections::HashMap;

use glam::Vec2;
use rayon::prelude::*;
use spade::{AngleLimit, ConstrainedDelaunayTriangulation, Point2, RefinementParameters, Triangulation};

use super::fof::{sheet_thickness, CosineTable, Fof, FofError, MAX_RESOLUTION};
use crate::buffer::GrayImage;

/// Errors of the inflation prior; every message says what to do next.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum InflateError {
    /// The mask is too small to hold a person.
    #[error("the mask is {width}x{height} pixels; inflation needs at least 4x4 and at most {MAX_RESOLUTION}x{MAX_RESOLUTION}")]
    BadSize {
        /// Mask width.
        width: usize,
        /// Mask height.
        height: usize,
    },
    /// A NaN or infinity in the mask.
    #[error("the mask holds a non-finite value at pixel index {index}; check the segmentation output")]
    NonFinite {
        /// Flat pixel index.
        index: usize,
    },
    /// No pixel above 0.5.
    #[error("the mask is empty (no pixel above 0.5): supply a mask that marks the person, or check the segmentation")]
    EmptyMask,
    /// Every pixel above 0.5.
    #[error(
        "the mask covers the whole image: the person must be separated from the background (check the alpha or --mask)"
    )]
    FullMask,
    /// Only regions below the speck size remain.
    #[error("no foreground region has {min} pixels or more (largest: {largest}); the mask is noise or the person is too small in the frame")]
    OnlySpecks {
        /// Size of the largest region found.
        largest: usize,
        /// The speck threshold.
        min: usize,
    },
    /// The outline has too many vertices (a noisy, fragmented mask).
    #[error("the mask outline has {vertices} vertices after simplification (limit {max}); clean the mask (fewer fragments) or raise the limit")]
    TooFragmented {
        /// Outline vertices.
        vertices: usize,
        /// The limit.
        max: usize,
    },
    /// A parameter is out of range.
    #[error("bad inflation parameter: {0}")]
    BadParams(String),
    /// The triangulation library refused the outline.
    #[error("triangulating the mask outline failed: {0}")]
    Triangulation(String),
    /// The solved surface left most of the mask flat (a triangulation fault), even on the exact pixel outline.
    #[error(
        "the inflation prior covers only {:.1} % of the mask's interior (a triangulation fault on this outline); \
         use --geometry body, or report the mask so that the fault can be fixed",
        100.0 * fraction
    )]
    NotInflated {
        /// The inflated fraction of the interior ([`MIN_INFLATED_FRACTION`] is the least accepted).
        fraction: f32,
    },
    /// Encoding the surfaces as FOF failed.
    #[error(transparent)]
    Fof(#[from] FofError),
}

/// Parameters of the inflation prior (see the module docs for the profile).
#[derive(Clone, Debug, PartialEq)]
pub struct InflateParams {
    /// κ in `h = κ sqrt(u)`: 1 turns a disc into a sphere; the default 0.7 makes limbs round. Measured
    /// (`cargo run --release --example inflate_thickness`, volumetric IoU against the ground truth at 256²): 0.7 is
    /// the best of 0.4…1.0 in steps of 0.1 on 30 clothed synthetic subjects in full and three-quarter framings
    /// (tied with 0.6) and on the Mr. Fixit scan; upper-body crops prefer 0.8 (0.553 vs 0.544).
    pub thickness: f32,
    /// The centre plane `c` (body-cube z) around which front and back are symmetric.
    pub centre_z: f32,
    /// Foreground regions smaller than this many pixels are dropped; background holes smaller are filled.
    pub min_component_pixels: usize,
    /// Douglas–Peucker tolerance for the outline, in pixels.
    pub simplify_tolerance: f32,
    /// Largest triangle area after refinement, in square pixels.
    pub max_triangle_area: f32,
    /// Smallest half thickness inside the mask, in pixels.
    pub min_half_thickness: f32,
    /// Largest number of outline vertices accepted (guards against noise masks).
    pub max_outline_vertices: usize,
}

impl Default for InflateParams {
    fn default() -> Self {
        Self {
            thickness: 0.7,
            centre_z: 0.0,
            min_component_pixels: 16,
            simplify_tolerance: 0.75,
            max_triangle_area: 24.0,
            min_half_thickness: 1.0,
            max_outline_vertices: 50_000,
        }
    }
}

impl InflateParams {
    fn validate(&self) -> Result<(), InflateError> {
        let bad = |what: &str, v: f32| InflateError::BadParams(format!("{what} = {v}"));
        if !(self.thickness.is_finite() && self.thickness > 0.0 && self.thickness <= 10.0) {
            return Err(bad("thickness must be in (0, 10]", self.thickness));
        }
        if !(self.centre_z.is_finite() && self.centre_z.abs() < 1.0) {
            return Err(bad("centre_z must be inside (-1, 1)", self.centre_z));
        }
        if !(self.simplify_tolerance.is_finite() && (0.0..=8.0).contains(&self.simplify_tolerance)) {
            return Err(bad("simplify_tolerance must be in [0, 8] pixels", self.simplify_tolerance));
        }
        if !(self.max_triangle_area.is_finite() && self.max_triangle_area >= 1.0) {
            return Err(bad("max_triangle_area must be at least 1 square pixel", self.max_triangle_area));
        }
        if !(self.min_half_thickness.is_finite() && self.min_half_thickness >= 0.0) {
            return Err(bad("min_half_thickness must be >= 0", self.min_half_thickness));
        }
        Ok(())
    }
}

/// Front and back surfaces of the inflated body: depth = body-cube z, `-1` (the background depth) outside.
#[derive(Clone, Debug, PartialEq)]
pub struct InflatedSurfaces {
    /// Front surface z (toward the camera).
    pub front: GrayImage,
    /// Back surface z.
    pub back: GrayImage,
    /// The cleaned mask (1 inside, 0 outside).
    pub mask: GrayImage,
}

/// Inflates the person mask (values in `[0, 1]`, threshold 0.5) into front/back depth maps, closed along the
/// whole outline.
pub fn inflate(mask: &GrayImage, params: &InflateParams) -> Result<InflatedSurfaces, InflateError> {
    inflate_at_least(mask, params, 0.0, None)
}

/// [`inflate`] open where the photo cuts the person: `frame` is where the photo lies on the mask's grid, `(min, max)`
/// corners in pixels (the pipeline's `NormalisedInput::frame`, with a straight cut of the mask as its bottom edge
/// where the body prior's `effective_frame` finds one); `None` is [`inflate`]. The mask's outline along a side of
/// the frame ([`CUT_TOLERANCE`]) is not where the person ends but where the photo cuts them: there the surfaces stay
/// open (zero slope, a natural boundary of the Poisson problem) instead of closing to zero thickness, as the body
/// prior's reconciliation treats the cut. Without it a portrait's chest came out egg-shaped from the side, thinning
/// to nothing at the photo's bottom edge. No column gets thicker than the thickest of the closed problem: open, a
/// wide part would take an endless strip's depth (about its width).
pub fn inflate_in_frame(
    mask: &GrayImage,
    params: &InflateParams,
    frame: Option<(Vec2, Vec2)>,
) -> Result<InflatedSurfaces, InflateError> {
    inflate_at_least(mask, params, 0.0, frame)
}

/// [`inflate_in_frame`] with every masked column's half thickness at least `min_half_depth` (body-cube units) as well
/// as `params.min_half_thickness` pixels: the one floor of the inflated height. A non-finite or negative
/// `min_half_depth` adds no floor.
fn inflate_at_least(
    mask: &GrayImage,
    params: &InflateParams,
    min_half_depth: f32,
    frame: Option<(Vec2, Vec2)>,
) -> Result<InflatedSurfaces, InflateError> {
    params.validate()?;
    let (w, h) = (mask.width, mask.height);
    if w < 4 || h < 4 || w > MAX_RESOLUTION || h > MAX_RESOLUTION || mask.data.len() != w * h {
        return Err(InflateError::BadSize { width: w, height: h });
    }
    if let Some(index) = mask.data.iter().position(|v| !v.is_finite()) {
        return Err(InflateError::NonFinite { index });
    }
    let mut fg: Vec<bool> = mask.data.iter().map(|&v| v > 0.5).collect();
    let count = fg.iter().filter(|&&b| b).count();
    if count == 0 {
        return Err(InflateError::EmptyMask);
    }
    if count == w * h {
        return Err(InflateError::FullMask);
    }
    clean_mask(&mut fg, w, h, params.min_component_pixels)?;
    if fg.iter().all(|&b| b) {
        return Err(InflateError::FullMask);
    }

    let loops = trace_loops(&fg, w, h);
    let mut u = solve_inflation(&loops, w, h, params, frame)?;
    let mut inflated = inflated_fraction(&fg, &u, w, h);
    if inflated < MIN_INFLATED_FRACTION && params.simplify_tolerance > 0.0 {
        // A fault of the triangulation on the simplified outline (the kind that once emptied the prior): the exact
        // pixel outline is slower to triangulate but has no simplification artefacts.
        tracing::warn!(
            "inflate: only {:.1} % of the mask's interior was inflated on the simplified outline; solving again on \
             the exact pixel outline",
            100.0 * inflated
        );
        let exact = InflateParams { simplify_tolerance: 0.0, ..params.clone() };
        if let Ok(again) = solve_inflation(&loops, w, h, &exact, frame) {
            let fraction = inflated_fraction(&fg, &again, w, h);
            if fraction > inflated {
                (u, inflated) = (again, fraction);
            }
        }
    }
    if inflated < MIN_INFLATED_FRACTION {
        return Err(InflateError::NotInflated { fraction: inflated });
    }
    let (sx, sy) = (2.0 / w as f32, 2.0 / h as f32);
    let depth_floor = if min_half_depth.is_finite() { min_half_depth.max(0.0) } else { 0.0 };
    let h_min = (params.min_half_thickness * sx.min(sy)).max(depth_floor);
    let mut front = GrayImage::new(w, h, -1.0);
    let mut back = GrayImage::new(w, h, -1.0);
    let mut out_mask = GrayImage::new(w, h, 0.0);
    for i in 0..w * h {
        if fg[i] {
            let half = (params.thickness * u[i].max(0.0).sqrt()).max(h_min);
            front.data[i] = (params.centre_z + half).clamp(-1.0, 1.0);
            back.data[i] = (params.centre_z - half).clamp(-1.0, 1.0);
            out_mask.data[i] = 1.0;
        }
    }
    Ok(InflatedSurfaces { front, back, mask: out_mask })
}

/// The fewest of a mask's interior pixels (`inflated_fraction`) that [`inflate`] accepts as inflated; below it
/// the triangulation went wrong and the prior would be an empty or partial person. The decoded prior of every one
/// of 3,120 synthetic masks (clothed and unclothed, three framings, 128-512 px, seeds 0 and 5;
/// `cargo run --release --example inflate_sweep`) covers 0.993 or more of the interior ([`mask_coverage`]).
pub const MIN_INFLATED_FRACTION: f32 = 0.9;

/// Whether pixel `(c, r)` of a `w` x `h` image lies in the interior of the foreground `fg(c, r)`: it and every
/// pixel within `margin` pixels (a square window) are inside the image and foreground.
fn is_interior(fg: impl Fn(usize, usize) -> bool, c: usize, r: usize, w: usize, h: usize, margin: usize) -> bool {
    c >= margin
        && r >= margin
        && c + margin < w
        && r + margin < h
        && (r - margin..=r + margin).all(|rr| (c - margin..=c + margin).all(|cc| fg(cc, rr)))
}

/// The fraction of the mask's interior pixels (foreground with every pixel within 2 pixels, a 5x5 window, also
/// foreground) where the solved height `u` is positive, or 1 when the mask has no interior pixel (a sliver has
/// nothing to inflate and nothing to miss).
fn inflated_fraction(fg: &[bool], u: &[f32], w: usize, h: usize) -> f32 {
    let (mut total, mut inflated) = (0usize, 0usize);
    for r in 0..h {
        for c in (0..w).filter(|&c| is_interior(|cc, rr| fg[rr * w + cc], c, r, w, h, 2)) {
            total += 1;
            inflated += usize::from(u[r * w + c] > 0.0);
        }
    }
    if total == 0 {
        1.0
    } else {
        inflated as f32 / total as f32
    }
}

/// [`inflate_in_frame`], then [`Fof::from_depth_maps`] with `n` coefficients. Every masked column is at least
/// [`sheet_thickness`]`(n)` thick about the centre plane: the inflated height of a part narrower than about 16 px at
/// 512² (a finger, a tripod leg, a strap, the outline's rim) is thinner than `n` coefficients can show, and such a
/// part vanished from the mesh.
pub fn inflate_to_fof(
    mask: &GrayImage,
    n: usize,
    params: &InflateParams,
    frame: Option<(Vec2, Vec2)>,
) -> Result<Fof, InflateError> {
    let s = inflate_resolvable(mask, n, params, frame)?;
    Ok(Fof::from_depth_maps(&s.front, &s.back, &s.mask, n)?)
}

/// The surfaces [`inflate_to_fof`] encodes: [`inflate_in_frame`] with every masked column at least
/// [`sheet_thickness`]`(n)` thick, so that `n` coefficients resolve it.
pub fn inflate_resolvable(
    mask: &GrayImage,
    n: usize,
    params: &InflateParams,
    frame: Option<(Vec2, Vec2)>,
) -> Result<InflatedSurfaces, InflateError> {
    inflate_at_least(mask, params, 0.5 * sheet_thickness(n), frame)
}

/// [`inflate_resolvable`] solved on a grid `factor` times coarser (the mask box-averaged) and read back at the mask's
/// own pixels (bilinear over the coarse person's pixels; a mask pixel with none of them within one coarse pixel
/// is left out). The inflated height is smooth, so the coarse solve keeps its shape at a fraction of the cost
/// (the triangulation and the Poisson problem shrink with the area): what a video frame can afford. The outline
/// stays the full-resolution mask's. `factor` 1 is [`inflate_resolvable`]; the parameters given in pixels are
/// scaled to the coarse grid, except the triangles' largest area, which stays as many coarse pixels (the
/// triangulation is where the time goes).
pub fn inflate_resolvable_coarse(
    mask: &GrayImage,
    n: usize,
    params: &InflateParams,
    frame: Option<(Vec2, Vec2)>,
    factor: usize,
) -> Result<InflatedSurfaces, InflateError> {
    let (w, h) = (mask.width, mask.height);
    if factor <= 1 || w < 4 * factor || h < 4 * factor || mask.data.len() != w * h {
        return inflate_resolvable(mask, n, params, frame);
    }
    let (cw, ch) = (w.div_ceil(factor), h.div_ceil(factor));
    let coarse = GrayImage::from_fn(cw, ch, |c, r| {
        let (mut sum, mut count) = (0.0f32, 0u32);
        for rr in r * factor..((r + 1) * factor).min(h) {
            for cc in c * factor..((c + 1) * factor).min(w) {
                sum += mask.data[rr * w + cc];
                count += 1;
            }
        }
        sum / count.max(1) as f32
    });
    let f = factor as f32;
    let coarse_params = InflateParams {
        min_component_pixels: (params.min_component_pixels / (factor * factor)).max(1),
        simplify_tolerance: params.simplify_tolerance / f,
        min_half_thickness: params.min_half_thickness / f,
        ..params.clone()
    };
    let coarse_frame = frame.map(|(lo, hi)| (lo / f, hi / f));
    let s = inflate_resolvable(&coarse, n, &coarse_params, coarse_frame)?;
    let mut out = InflatedSurfaces {
        front: GrayImage::new(w, h, -1.0),
        back: GrayImage::new(w, h, -1.0),
        mask: GrayImage::new(w, h, 0.0),
    };
    let inside = |c: i64, r: i64| {
        (0..cw as i64).contains(&c) && (0..ch as i64).contains(&r) && s.mask.data[r as usize * cw + c as usize] > 0.5
    };
    // Coarse pixel centres around each column's and row's centre, worked out once.
    let cell = |k: usize| {
        let u = (k as f32 + 0.5) / f - 0.5;
        let k0 = u.floor() as i64;
        (k0, u - k0 as f32)
    };
    let columns: Vec<(i64, f32)> = (0..w).map(cell).collect();
    for r in 0..h {
        let (r0, fv) = cell(r);
        for (c, &(c0, fu)) in columns.iter().enumerate() {
            let i = r * w + c;
            if mask.data[i] <= 0.5 {
                continue;
            }
            let (mut front, mut back, mut weight) = (0.0f32, 0.0f32, 0.0f32);
            for (dc, dr, wt) in
                [(0, 0, (1.0 - fu) * (1.0 - fv)), (1, 0, fu * (1.0 - fv)), (0, 1, (1.0 - fu) * fv), (1, 1, fu * fv)]
            {
                if wt > 0.0 && inside(c0 + dc, r0 + dr) {
                    let k = (r0 + dr) as usize * cw + (c0 + dc) as usize;
                    front += wt * s.front.data[k];
                    back += wt * s.back.data[k];
                    weight += wt;
                }
            }
            if weight <= 1e-6 {
                // Beside the coarse outline: the nearest coarse person pixel within one coarse pixel.
                let nearest = (-1..=2)
                    .flat_map(|dr| (-1..=2).map(move |dc| (dc, dr)))
                    .filter(|&(dc, dr)| inside(c0 + dc, r0 + dr))
                    .min_by(|a, b| {
                        let d = |(dc, dr): (i64, i64)| (dc as f32 - fu).powi(2) + (dr as f32 - fv).powi(2);
                        d(*a).total_cmp(&d(*b))
                    });
                let Some((dc, dr)) = nearest else { continue };
                let k = (r0 + dr) as usize * cw + (c0 + dc) as usize;
                (front, back, weight) = (s.front.data[k], s.back.data[k], 1.0);
            }
            out.front.data[i] = front / weight;
            out.back.data[i] = back / weight;
            out.mask.data[i] = 1.0;
        }
    }
    Ok(out)
}

/// The fraction of the mask's interior pixels whose FOF column reaches occupancy 0.5 at some depth (decoded at
/// `4 n` depths), or `None` when the mask has no interior pixel. Interior: above 0.5 with every pixel within
/// `margin` pixels (a square window) inside the image and above 0.5 too; the rim of the outline is left out
/// because a band-limited FOF cannot show a sliver thinner than its depth resolution. An inflation prior that
/// covers the person scores 1; an empty one 0.
pub fn mask_coverage(fof: &Fof, mask: &GrayImage, margin: usize) -> Option<f32> {
    let (w, h) = (mask.width, mask.height);
    if fof.width != w || fof.height != h || mask.data.len() != w * h {
        return None;
    }
    let fg = |c: usize, r: usize| mask.data[r * w + c] > 0.5;
    let interior = |c: usize, r: usize| is_interior(fg, c, r, w, h, margin);
    let table = CosineTable::new(fof.n, 4 * fof.n);
    let (covered, total) = (0..h)
        .into_par_iter()
        .map(|r| {
            let mut out = vec![0.0f32; table.samples];
            let (mut covered, mut total) = (0usize, 0usize);
            for c in (0..w).filter(|&c| interior(c, r)) {
                total += 1;
                fof.decode_column_with(&table, c, r, &mut out);
                if out.iter().any(|&o| o >= 0.5) {
                    covered += 1;
                }
            }
            (covered, total)
        })
        .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    (total > 0).then(|| covered as f32 / total as f32)
}

/// Connected components of `value` pixels (4-connected if `four`, else 8-connected): labels and sizes.
fn components(fg: &[bool], w: usize, h: usize, value: bool, four: bool) -> (Vec<u32>, Vec<usize>) {
    let mut label = vec![u32::MAX; w * h];
    let mut sizes = Vec::new();
    let mut stack = Vec::new();
    for start in 0..w * h {
        if fg[start] != value || label[start] != u32::MAX {
            continue;
        }
        let id = sizes.len() as u32;
        let mut size = 0;
        label[start] = id;
        stack.push(start);
        while let Some(p) = stack.pop() {
            size += 1;
            let (c, r) = ((p % w) as i64, (p / w) as i64);
            for dr in -1i64..=1 {
                for dc in -1i64..=1 {
                    if (dr == 0 && dc == 0) || (four && dr != 0 && dc != 0) {
                        continue;
                    }
                    let (cc, rr) = (c + dc, r + dr);
                    if cc < 0 || rr < 0 || cc >= w as i64 || rr >= h as i64 {
                        continue;
                    }
                    let q = rr as usize * w + cc as usize;
                    if fg[q] == value && label[q] == u32::MAX {
                        label[q] = id;
                        stack.push(q);
                    }
                }
            }
        }
        sizes.push(size);
    }
    (label, sizes)
}

/// Drops foreground specks and fills small enclosed holes.
fn clean_mask(fg: &mut [bool], w: usize, h: usize, min: usize) -> Result<(), InflateError> {
    // Foreground is 4-connected (as the outline tracing treats it).
    let (label, sizes) = components(fg, w, h, true, true);
    let largest = sizes.iter().copied().max().unwrap_or(0);
    if largest < min.max(1) {
        return Err(InflateError::OnlySpecks { largest, min });
    }
    for i in 0..w * h {
        if fg[i] && sizes[label[i] as usize] < min {
            fg[i] = false;
        }
    }
    // Background is 8-connected (the dual connectivity); fill small holes not touching the border.
    let (label, sizes) = components(fg, w, h, false, false);
    let mut touches = vec![false; sizes.len()];
    for r in 0..h {
        for c in 0..w {
            if (r == 0 || c == 0 || r == h - 1 || c == w - 1) && !fg[r * w + c] {
                touches[label[r * w + c] as usize] = true;
            }
        }
    }
    for i in 0..w * h {
        if !fg[i] {
            let l = label[i] as usize;
            if !touches[l] && sizes[l] < min {
                fg[i] = true;
            }
        }
    }
    Ok(())
}

// Directions on the pixel-corner lattice (j grows downward): E, S, W, N.
const DIRS: [(i64, i64); 4] = [(1, 0), (0, 1), (-1, 0), (0, -1)];
const E: u8 = 0;
const S: u8 = 1;
const W: u8 = 2;
const N: u8 = 3;

/// Traces the boundaries between foreground and background pixels as closed loops of lattice corners
/// `(i, j)` (corner `(i, j)` is the top-left corner of pixel `(i, j)`), foreground on the left in body-cube
/// orientation (outer outlines counter-clockwise, holes clockwise). Only corners where the direction changes
/// are kept. At a corner where two foreground pixels touch diagonally the loop turns around its own pixel, so
/// diagonal contacts stay separate and loops never cross (they may share such a corner).
fn trace_loops(fg: &[bool], w: usize, h: usize) -> Vec<Vec<(i64, i64)>> {
    let lw = w + 1;
    let at =
        |c: i64, r: i64| c >= 0 && r >= 0 && (c as usize) < w && (r as usize) < h && fg[r as usize * w + c as usize];
    // Outgoing crack directions per lattice corner (bit per direction).
    let mut out = vec![0u8; lw * (h + 1)];
    for r in 0..h as i64 {
        for c in 0..w as i64 {
            if !at(c, r) {
                continue;
            }
            let idx = |i: i64, j: i64| j as usize * lw + i as usize;
            if !at(c, r - 1) {
                out[idx(c + 1, r)] |= 1 << W;
            }
            if !at(c, r + 1) {
                out[idx(c, r + 1)] |= 1 << E;
            }
            if !at(c - 1, r) {
                out[idx(c, r)] |= 1 << S;
            }
            if !at(c + 1, r) {
                out[idx(c + 1, r + 1)] |= 1 << N;
            }
        }
    }
    // The successor of an edge arriving at a corner with direction `incoming`.
    let next_dir = |v: usize, incoming: u8| -> u8 {
        let bits = out[v];
        if bits.count_ones() == 1 {
            bits.trailing_zeros() as u8
        } else {
            // Saddle: turn left on screen (E->N, N->W, W->S, S->E), around the pixel being followed.
            (incoming + 3) % 4
        }
    };
    let mut visited = vec![0u8; out.len()];
    let mut loops = Vec::new();
    for v0 in 0..out.len() {
        let mut remaining = out[v0] & !visited[v0];
        while remaining != 0 {
            let d0 = remaining.trailing_zeros() as u8;
            let mut ring = Vec::new();
            let (mut v, mut d) = (v0, d0);
            loop {
                visited[v] |= 1 << d;
                let (i, j) = ((v % lw) as i64, (v / lw) as i64);
                let (ni, nj) = (i + DIRS[d as usize].0, j + DIRS[d as usize].1);
                let nv = nj as usize * lw + ni as usize;
                let nd = next_dir(nv, d);
                if nd != d {
                    ring.push((ni, nj));
                }
                if nv == v0 && nd == d0 {
                    break;
                }
                if visited[nv] & (1 << nd) != 0 || out[nv] & (1 << nd) == 0 {
                    // Cannot happen for a consistent crack graph; stop rather than loop forever.
                    break;
                }
                (v, d) = (nv, nd);
            }
            if ring.len() >= 3 {
                loops.push(ring);
            }
            remaining = out[v0] & !visited[v0];
        }
    }
    loops
}

/// Douglas–Peucker simplification of a closed loop (keeps at least 3 points).
fn simplify_loop(ring: &[(i64, i64)], tol: f64) -> Vec<(i64, i64)> {
    let n = ring.len();
    if n <= 4 || tol <= 0.0 {
        return ring.to_vec();
    }
    // Split at vertex 0 and the vertex farthest from it.
    let p0 = ring[0];
    let far = (1..n)
        .max_by_key(|&i| {
            let (dx, dy) = (ring[i].0 - p0.0, ring[i].1 - p0.1);
            dx * dx + dy * dy
        })
        .unwrap_or(n / 2);
    let mut keep = vec![false; n];
    keep[0] = true;
    keep[far] = true;
    let mut stack = vec![(0usize, far), (far, n)];
    while let Some((a, b)) = stack.pop() {
        if b - a < 2 {
            continue;
        }
        let pa = ring[a];
        let pb = ring[b % n];
        let (dx, dy) = ((pb.0 - pa.0) as f64, (pb.1 - pa.1) as f64);
        let len = (dx * dx + dy * dy).sqrt();
        let mut best = (0.0f64, a);
        for (i, p) in ring.iter().enumerate().take(b).skip(a + 1) {
            let (px, py) = ((p.0 - pa.0) as f64, (p.1 - pa.1) as f64);
            let dist = if len > 0.0 { (dx * py - dy * px).abs() / len } else { (px * px + py * py).sqrt() };
            if dist > best.0 {
                best = (dist, i);
            }
        }
        if best.0 > tol {
            keep[best.1] = true;
            stack.push((a, best.1));
            stack.push((best.1, b));
        }
    }
    let out: Vec<(i64, i64)> = ring.iter().zip(&keep).filter(|(_, &k)| k).map(|(p, _)| *p).collect();
    let out = remove_spikes(out);
    if out.len() >= 3 {
        out
    } else {
        ring.to_vec()
    }
}

/// Removes zero-area spikes from a closed loop: a vertex whose neighbours are the same point (`a, b, a`, the
/// edge walked out and back) and repeated consecutive points. Simplification makes them where the traced outline
/// passes a corner twice (a lobe attached through a diagonal pixel touch) and the lobe collapses to one point;
/// the doubled edge breaks the triangulation's inside/outside parity (every face then counted as outside, an
/// empty inflation). The lobe's pixels stay in the mask at the minimum thickness.
fn remove_spikes(mut ring: Vec<(i64, i64)>) -> Vec<(i64, i64)> {
    loop {
        let n = ring.len();
        if n < 3 {
            return ring;
        }
        let at = (0..n).find(|&i| {
            let (prev, next) = (ring[(i + n - 1) % n], ring[(i + 1) % n]);
            ring[i] == next || prev == next
        });
        let Some(i) = at else { return ring };
        if ring[i] == ring[(i + 1) % n] {
            ring.remove(i);
        } else {
            // `prev, b, prev`: drop `b` and the second `prev`.
            let (first, second) = (i, (i + 1) % n);
            ring.remove(first.max(second));
            ring.remove(first.min(second));
        }
    }
}

type Cdt = ConstrainedDelaunayTriangulation<Point2<f64>>;

/// Builds the CDT of the loops (lattice corners mapped to body-cube x, y).
fn build_cdt(loops: &[Vec<(i64, i64)>], w: usize, h: usize, max_vertices: usize) -> Result<(Cdt, bool), InflateError> {
    let mut index: HashMap<(i64, i64), usize> = HashMap::new();
    let mut vertices = Vec::new();
    let mut edges = Vec::new();
    for ring in loops {
        let ids: Vec<usize> = ring
            .iter()
            .map(|&p| {
                *index.entry(p).or_insert_with(|| {
                    vertices.push(Point2::new(p.0 as f64 * 2.0 / w as f64 - 1.0, 1.0 - p.1 as f64 * 2.0 / h as f64));
                    vertices.len() - 1
                })
            })
            .collect();
        for k in 0..ids.len() {
            let (a, b) = (ids[k], ids[(k + 1) % ids.len()]);
            if a != b {
                edges.push([a, b]);
            }
        }
    }
    if vertices.len() > max_vertices {
        return Err(InflateError::TooFragmented { vertices: vertices.len(), max: max_vertices });
    }
    let mut conflict = false;
    let cdt = Cdt::try_bulk_load_cdt(vertices, edges, |_| conflict = true)
        .map_err(|e| InflateError::Triangulation(format!("{e:?}")))?;
    Ok((cdt, conflict))
}

/// Winding numbers of points with respect to closed loops on the pixel-corner lattice (Sunday's crossing
/// rule), the loop edges bucketed by the lattice row they span so that a query reads one row's edges.
struct Winding {
    rows: Vec<Vec<[(i64, i64); 2]>>,
}

impl Winding {
    fn new(loops: &[Vec<(i64, i64)>], h: usize) -> Self {
        let mut rows = vec![Vec::new(); h];
        for ring in loops {
            for k in 0..ring.len() {
                let (a, b) = (ring[k], ring[(k + 1) % ring.len()]);
                let (lo, hi) = (a.1.min(b.1).max(0), a.1.max(b.1).min(h as i64));
                for row in lo..hi {
                    rows[row as usize].push([a, b]);
                }
            }
        }
        Self { rows }
    }

    /// The winding number of lattice point `(x, y)` (0 outside every loop; 0 inside a hole).
    fn at(&self, x: f64, y: f64) -> i32 {
        let row = y.floor();
        if !(row >= 0.0 && (row as usize) < self.rows.len()) {
            return 0;
        }
        let mut wn = 0;
        for &[a, b] in &self.rows[row as usize] {
            let (ax, ay, bx, by) = (a.0 as f64, a.1 as f64, b.0 as f64, b.1 as f64);
            let left = (bx - ax) * (y - ay) - (x - ax) * (by - ay);
            if ay <= y {
                if by > y && left > 0.0 {
                    wn += 1;
                }
            } else if by <= y && left < 0.0 {
                wn -= 1;
            }
        }
        wn
    }
}

/// Labels every face of the CDT as inside (`true`) or outside, indexed by the face's fixed index: inside where
/// the winding number of the face's centroid with respect to the triangulated (oriented) loops is not zero.
///
/// The triangulation's own parity rule (crossing a constraint edge flips inside/outside) breaks on outlines
/// that are simple as curves but degenerate as edge sets: an edge walked out and back, two collinear pieces that
/// overlap, or an edge that passes through another vertex of the outline (a hand touching the arm through a
/// diagonal pixel contact, after simplification). Each such crossing flips every face behind it, and the prior
/// comes out empty or inverted. The winding number does not depend on how the CDT splits or merges those
/// edges: an edge walked both ways cancels, so it cannot flip.
fn label_faces(cdt: &Cdt, winding: &Winding, w: usize, h: usize) -> Vec<bool> {
    let mut inside = vec![false; cdt.num_all_faces()];
    for face in cdt.inner_faces() {
        let p = face.positions();
        let (cx, cy) = ((p[0].x + p[1].x + p[2].x) / 3.0, (p[0].y + p[1].y + p[2].y) / 3.0);
        let (i, j) = ((cx + 1.0) * 0.5 * w as f64, (1.0 - cy) * 0.5 * h as f64);
        inside[face.fix().index()] = winding.at(i, j) != 0;
    }
    inside
}

/// Unmarks every constraint edge whose two sides carry the same label ([`label_faces`]): such an edge is not
/// part of the boundary between person and background (an out-and-back spike, an overlapping piece). Afterwards
/// every constraint edge separates inside from outside, so the parity rule that the refinement uses to skip
/// outer faces agrees with the winding labels, and no vertex inside the person is pinned to `u = 0`. Returns how
/// many edges were unmarked.
fn drop_spurious_constraints(cdt: &mut Cdt, winding: &Winding, w: usize, h: usize) -> usize {
    let label = label_faces(cdt, winding, w, h);
    let side = |f: spade::handles::FaceHandle<'_, spade::handles::PossiblyOuterTag, _, _, _, _>| {
        f.as_inner().is_some_and(|f| label[f.fix().index()])
    };
    let spurious: Vec<_> = cdt
        .undirected_edges()
        .filter(|e| cdt.is_constraint_edge(e.fix()))
        .filter(|e| {
            let d = e.as_directed();
            side(d.face()) == side(d.rev().face())
        })
        .map(|e| e.fix())
        .collect();
    for &e in &spurious {
        cdt.remove_constraint_edge(e);
    }
    spurious.len()
}

/// How far an outline edge may lie from a side of the photo's frame and still be a cut (the `frame` of
/// [`inflate_in_frame`]), as a fraction of the grid's larger side (at least one pixel): the mask's outline runs on the
/// pixel lattice, up to half a pixel from a frame side at a fractional position, and a segmentation often stops a
/// pixel or two short of the image's edge (frames of a video moved by a pixel left the chest 1-3 px above it, and the
/// bust closed and opened from frame to frame). Half the margin the normalisation leaves beside a person as wide as
/// the grid (`pipeline::input::MAX_WIDTH_FRACTION`), so a person touching no side of the photo is never cut.
pub const CUT_TOLERANCE: f64 = 0.005;

/// Whether the outline edge from `a` to `b` (body-cube x and y, on a `w` x `h` grid) lies along one side of `frame`
/// (`(min, max)` corners in pixels), within [`CUT_TOLERANCE`].
fn along_frame_side((lo, hi): (Vec2, Vec2), a: [f64; 2], b: [f64; 2], w: usize, h: usize) -> bool {
    let px = |p: [f64; 2]| [(p[0] + 1.0) * 0.5 * w as f64, (1.0 - p[1]) * 0.5 * h as f64];
    let (a, b) = (px(a), px(b));
    let tolerance = (CUT_TOLERANCE * w.max(h) as f64).max(1.0);
    let near = |v: f64, side: f32| (v - side as f64).abs() <= tolerance;
    (near(a[1], hi.y) && near(b[1], hi.y))
        || (near(a[1], lo.y) && near(b[1], lo.y))
        || (near(a[0], lo.x) && near(b[0], lo.x))
        || (near(a[0], hi.x) && near(b[0], hi.x))
}

/// The vertices held at `u = 0`: every vertex of an outline edge, and the cut vertices of a region of `faces` that
/// touches no outline at all (a person filling the whole frame), whose problem would otherwise have no solution.
/// A vertex only on cut edges is an unknown with the natural (zero-slope) boundary.
fn dirichlet_vertices(faces: &[[usize; 3]], mut outline: Vec<bool>, cut: &[bool]) -> Vec<bool> {
    if !cut.iter().any(|&c| c) {
        return outline;
    }
    let mut parent: Vec<usize> = (0..outline.len()).collect();
    fn root(parent: &mut [usize], mut v: usize) -> usize {
        while parent[v] != v {
            parent[v] = parent[parent[v]];
            v = parent[v];
        }
        v
    }
    for f in faces {
        for k in 1..3 {
            let (a, b) = (root(&mut parent, f[0]), root(&mut parent, f[k]));
            if a != b {
                parent[a] = b;
            }
        }
    }
    let mut held = vec![false; outline.len()];
    for v in (0..outline.len()).filter(|&v| outline[v]) {
        let r = root(&mut parent, v);
        held[r] = true;
    }
    for v in (0..outline.len()).filter(|&v| cut[v]) {
        let r = root(&mut parent, v);
        if !held[r] {
            outline[v] = true;
        }
    }
    outline
}

/// Solves `-Δu = 4`, `u = 0` on the outline (zero slope along the `frame`'s sides, [`inflate_in_frame`]) over the
/// refined CDT and samples `u` at every pixel centre (0 where no inner triangle covers the centre). Inside and outside come from the loops' winding numbers
/// ([`label_faces`]), not from the parity of constraint edges. Where the frame cuts the person, no column is thicker
/// than the closed problem's thickest (solved on the same triangles).
fn solve_inflation(
    loops: &[Vec<(i64, i64)>],
    w: usize,
    h: usize,
    params: &InflateParams,
    frame: Option<(Vec2, Vec2)>,
) -> Result<Vec<f32>, InflateError> {
    let tol = params.simplify_tolerance as f64;
    let simplified: Vec<Vec<(i64, i64)>> = loops.par_iter().map(|l| simplify_loop(l, tol)).collect();
    let (mut cdt, conflict) = build_cdt(&simplified, w, h, params.max_outline_vertices)?;
    let mut outline: &[Vec<(i64, i64)>] = &simplified;
    if conflict {
        // Simplification made two outlines cross: the exact pixel outlines never cross, use them.
        tracing::debug!("inflate: simplified outline self-intersects, using the exact outline");
        let (exact, conflict) = build_cdt(loops, w, h, params.max_outline_vertices)?;
        if conflict {
            return Err(InflateError::Triangulation("the mask outline crosses itself".into()));
        }
        cdt = exact;
        outline = loops;
    }
    let winding = Winding::new(outline, h);
    let dropped = drop_spurious_constraints(&mut cdt, &winding, w, h);
    if dropped > 0 {
        tracing::debug!("inflate: {dropped} outline edges do not separate the person from the background; unmarked");
    }
    let px_area = (2.0 / w as f64) * (2.0 / h as f64);
    let initial = cdt.num_vertices();
    cdt.refine(
        RefinementParameters::<f64>::new()
            .exclude_outer_faces(true)
            .with_angle_limit(AngleLimit::from_deg(20.0))
            .with_max_allowed_area(params.max_triangle_area as f64 * px_area)
            .with_min_required_area(0.02 * px_area)
            .with_max_additional_vertices(initial * 20 + 20_000),
    );
    let inside = label_faces(&cdt, &winding, w, h);
    let nv = cdt.num_vertices();
    let pos: Vec<[f64; 2]> = cdt.vertices().map(|v| [v.position().x, v.position().y]).collect();
    let faces: Vec<[usize; 3]> =
        cdt.inner_faces().filter(|f| inside[f.fix().index()]).map(|f| f.vertices().map(|v| v.fix().index())).collect();
    let (mut outline_vertex, mut cut_vertex) = (vec![false; nv], vec![false; nv]);
    for e in cdt.undirected_edges().filter(|e| e.is_constraint_edge()) {
        let [a, b] = e.vertices().map(|v| v.fix().index());
        let on_cut = frame.is_some_and(|f| along_frame_side(f, pos[a], pos[b], w, h));
        for v in [a, b] {
            if on_cut {
                cut_vertex[v] = true;
            } else {
                outline_vertex[v] = true;
            }
        }
    }
    let mut u_vertex =
        solve_poisson(&faces, &pos, &dirichlet_vertices(&faces, outline_vertex.clone(), &cut_vertex), 1e-9);
    if cut_vertex.iter().any(|&c| c) {
        // Open at the cut, a wide part would take the thickness of an endless strip (depth about its width, a chest
        // as deep as the shoulders are wide). The cut only keeps a part from closing: no column gets thicker than
        // the thickest the closed silhouette makes anywhere (solved on the same triangles).
        let closed: Vec<bool> = outline_vertex.iter().zip(&cut_vertex).map(|(&o, &c)| o || c).collect();
        // Only its maximum is needed, and that settles long before the residual does (Grace Hopper and the
        // astronaut: the same to six digits at a relative residual of 1e-4 as at 1e-9, 2-3 ms sooner).
        let cap = solve_poisson(&faces, &pos, &closed, CAP_TOLERANCE).into_iter().fold(0.0f64, f64::max);
        u_vertex.iter_mut().for_each(|u| *u = u.min(cap));
    }
    Ok(rasterise(&faces, &pos, &u_vertex, w, h))
}

/// The conjugate gradients' relative residual for the closed problem that caps the thickness at a cut.
const CAP_TOLERANCE: f64 = 1e-5;

/// `-Δu = 4` on the triangles `faces` (P1 elements, conjugate gradients to a relative residual of `rel_tol`) with
/// `u = 0` on the vertices `held`: the value at every vertex, 0 on the held ones and on vertices of no face, never
/// negative.
fn solve_poisson(faces: &[[usize; 3]], pos: &[[f64; 2]], held: &[bool], rel_tol: f64) -> Vec<f64> {
    let nv = pos.len();
    let mut unknown = vec![usize::MAX; nv];
    let mut count = 0;
    for f in faces {
        for &v in f {
            if !held[v] && unknown[v] == usize::MAX {
                unknown[v] = count;
                count += 1;
            }
        }
    }
    let mut u_vertex = vec![0.0f64; nv];
    if count > 0 {
        let (matrix, rhs) = assemble(faces, pos, &unknown, count);
        let x = conjugate_gradient(&matrix, &rhs, rel_tol, 10 * count + 100);
        for v in 0..nv {
            if unknown[v] != usize::MAX {
                u_vertex[v] = x[unknown[v]].max(0.0);
            }
        }
    }
    u_vertex
}

/// A symmetric sparse matrix in compressed rows.
struct Csr {
    row_start: Vec<usize>,
    cols: Vec<usize>,
    vals: Vec<f64>,
    diag: Vec<f64>,
}

/// P1 stiffness matrix (cotangent weights) and lumped load `4 * area / 3` per vertex, interior rows only.
fn assemble(faces: &[[usize; 3]], pos: &[[f64; 2]], unknown: &[usize], n: usize) -> (Csr, Vec<f64>) {
    let mut triplets: Vec<(usize, usize, f64)> = Vec::with_capacity(faces.len() * 9);
    let mut rhs = vec![0.0; n];
    for f in faces {
        let p = f.map(|v| pos[v]);
        let cross = (p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[1][1] - p[0][1]) * (p[2][0] - p[0][0]);
        let area = 0.5 * cross.abs();
        if area.is_nan() || area <= 1e-18 {
            continue;
        }
        // Gradients of the barycentric basis: grad phi_i = perp(p_k - p_j) / (2A); K_ij = A grad_i . grad_j.
        let g: Vec<[f64; 2]> = (0..3)
            .map(|i| {
                let (j, k) = ((i + 1) % 3, (i + 2) % 3);
                [(p[j][1] - p[k][1]) / cross, (p[k][0] - p[j][0]) / cross]
            })
            .collect();
        for i in 0..3 {
            let ui = unknown[f[i]];
            if ui == usize::MAX {
                continue;
            }
            rhs[ui] += 4.0 * area / 3.0;
            for j in 0..3 {
                let uj = unknown[f[j]];
                if uj == usize::MAX {
                    continue;
                }
                let k = area * (g[i][0] * g[j][0] + g[i][1] * g[j][1]);
                triplets.push((ui, uj, k));
            }
        }
    }
    triplets.sort_unstable_by_key(|a| (a.0, a.1));
    let mut row_start = vec![0usize; n + 1];
    let mut cols = Vec::new();
    let mut vals: Vec<f64> = Vec::new();
    let mut diag = vec![0.0; n];
    let mut last: Option<(usize, usize)> = None;
    for (i, j, v) in triplets {
        if last == Some((i, j)) {
            *vals.last_mut().expect("entry exists") += v;
        } else {
            cols.push(j);
            vals.push(v);
            row_start[i + 1] = cols.len();
            last = Some((i, j));
        }
        if i == j {
            diag[i] += v;
        }
        row_start[i + 1] = cols.len();
    }
    // Rows without entries (impossible for interior vertices, kept safe) inherit the previous end.
    for i in 1..=n {
        row_start[i] = row_start[i].max(row_start[i - 1]);
    }
    (Csr { row_start, cols, vals, diag }, rhs)
}

fn mat_vec(m: &Csr, x: &[f64], y: &mut [f64]) {
    for (i, yi) in y.iter_mut().enumerate() {
        let mut s = 0.0;
        for k in m.row_start[i]..m.row_start[i + 1] {
            s += m.vals[k] * x[m.cols[k]];
        }
        *yi = s;
    }
}

/// Jacobi-preconditioned conjugate gradients for `m x = b` (symmetric positive definite).
fn conjugate_gradient(m: &Csr, b: &[f64], rel_tol: f64, max_iter: usize) -> Vec<f64> {
    let n = b.len();
    let inv_diag: Vec<f64> = m.diag.iter().map(|&d| if d > 0.0 { 1.0 / d } else { 0.0 }).collect();
    let mut x = vec![0.0; n];
    let mut r = b.to_vec();
    let mut z: Vec<f64> = r.iter().zip(&inv_diag).map(|(r, d)| r * d).collect();
    let mut p = z.clone();
    let mut ap = vec![0.0; n];
    let mut rz: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
    let b_norm = b.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300);
    for _ in 0..max_iter {
        mat_vec(m, &p, &mut ap);
        let pap: f64 = p.iter().zip(&ap).map(|(a, b)| a * b).sum();
        if pap.is_nan() || pap <= 0.0 {
            break;
        }
        let alpha = rz / pap;
        for i in 0..n {
            x[i] += alpha * p[i];
            r[i] -= alpha * ap[i];
        }
        if r.iter().map(|v| v * v).sum::<f64>().sqrt() <= rel_tol * b_norm {
            break;
        }
        for i in 0..n {
            z[i] = r[i] * inv_diag[i];
        }
        let rz_new: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
        let beta = rz_new / rz;
        rz = rz_new;
        for i in 0..n {
            p[i] = z[i] + beta * p[i];
        }
    }
    if x.iter().any(|v| !v.is_finite()) {
        x.iter_mut().for_each(|v| *v = 0.0);
    }
    x
}

/// Interpolation of the vertex values over the inner triangles at every pixel centre (0 where uncovered).
fn rasterise(faces: &[[usize; 3]], pos: &[[f64; 2]], u: &[f64], w: usize, h: usize) -> Vec<f32> {
    let mut img = vec![0.0f32; w * h];
    let to_px = |p: [f64; 2]| [(p[0] + 1.0) * 0.5 * w as f64, (1.0 - p[1]) * 0.5 * h as f64];
    let (sx, sy) = (2.0 / w as f64, 2.0 / h as f64);
    for f in faces {
        let q = f.map(|v| to_px(pos[v]));
        let area = (q[1][0] - q[0][0]) * (q[2][1] - q[0][1]) - (q[1][1] - q[0][1]) * (q[2][0] - q[0][0]);
        if area.abs() < 1e-12 {
            continue;
        }
        let xmin = q.iter().map(|p| p[0]).fold(f64::MAX, f64::min);
        let xmax = q.iter().map(|p| p[0]).fold(f64::MIN, f64::max);
        let ymin = q.iter().map(|p| p[1]).fold(f64::MAX, f64::min);
        let ymax = q.iter().map(|p| p[1]).fold(f64::MIN, f64::max);
        let c0 = (xmin - 0.5).ceil().max(0.0) as usize;
        let c1 = ((xmax - 0.5).floor()).min(w as f64 - 1.0);
        let r0 = (ymin - 0.5).ceil().max(0.0) as usize;
        let r1 = ((ymax - 0.5).floor()).min(h as f64 - 1.0);
        if c1 < c0 as f64 || r1 < r0 as f64 {
            continue;
        }
        let vals = f.map(|v| u[v]);
        for row in r0..=r1 as usize {
            for col in c0..=c1 as usize {
                let p = [col as f64 + 0.5, row as f64 + 0.5];
                let l =
                    |a: [f64; 2], b: [f64; 2]| ((b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])) / area;
                let (b0, b1, b2) = (l(q[1], q[2]), l(q[2], q[0]), l(q[0], q[1]));
                let eps = -1e-9;
                if b0 >= eps && b1 >= eps && b2 >= eps {
                    // Linear interpolation under-estimates the concave solution between vertices. For -Δu = 4
                    // with an isotropic Hessian (-2 I), u = I(u) + sum_i b_i |p - p_i|^2 exactly; adding that
                    // term makes the profile independent of the triangle size.
                    let d2 = |a: [f64; 2]| {
                        let (dx, dy) = ((p[0] - a[0]) * sx, (p[1] - a[1]) * sy);
                        dx * dx + dy * dy
                    };
                    let bubble = b0 * d2(q[0]) + b1 * d2(q[1]) + b2 * d2(q[2]);
                    img[row * w + col] = (b0 * vals[0] + b1 * vals[1] + b2 * vals[2] + bubble) as f32;
                }
            }
        }
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    fn disc_mask(size: usize, cx: f32, cy: f32, r: f32) -> GrayImage {
        GrayImage::from_fn(size, size, |c, row| {
            let (x, y) = (c as f32 + 0.5 - cx, row as f32 + 0.5 - cy);
            if x * x + y * y < r * r {
                1.0
            } else {
                0.0
            }
        })
    }

    fn half_thickness(s: &InflatedSurfaces, c: usize, r: usize) -> f32 {
        let i = r * s.front.width + c;
        0.5 * (s.front.data[i] - s.back.data[i])
    }

    #[test]
    fn the_photos_cut_is_open_not_an_outline() {
        // A strip of half width a (pixels) from row 8 down to the frame's bottom edge at row 56: with the frame, the
        // cut is a natural boundary, so far from the top the thickness is the infinite strip's (u = 2 (a² - x²),
        // h = κ √2 a at the centre) right down to the last row; without it the bottom is an outline and the last
        // row is thin.
        let (size, a_px) = (64usize, 8.0f32);
        let mask = GrayImage::from_fn(size, size, |c, r| {
            f32::from((8..56).contains(&r) && (c as f32 + 0.5 - 32.0).abs() <= a_px)
        });
        let params = InflateParams { thickness: 1.0, min_half_thickness: 0.0, ..Default::default() };
        let frame = (glam::Vec2::ZERO, glam::Vec2::new(64.0, 56.0));
        let open = inflate_in_frame(&mask, &params, Some(frame)).unwrap();
        let closed = inflate(&mask, &params).unwrap();
        let expected = 2.0f32.sqrt() * a_px * 2.0 / size as f32;
        for r in [32, 40, 50, 55] {
            let got = half_thickness(&open, 32, r);
            assert!((got - expected).abs() < 0.07 * expected, "row {r}: {got} vs {expected}");
            // Across the strip, the strip's ellipse √2 sqrt(a² - x²) down to the cut, to the solver's accuracy off
            // the centre line (within 8 % anywhere along a strip, closed or open; the cut adds nothing to that).
            for c in [25, 28, 36, 38] {
                let x = c as f32 + 0.5 - 32.0;
                let ellipse = 2.0f32.sqrt() * (a_px * a_px - x * x).sqrt() * 2.0 / size as f32;
                let got = half_thickness(&open, c, r);
                assert!((got - ellipse).abs() < 0.1 * ellipse, "row {r}, column {c}: {got} vs {ellipse}");
            }
        }
        assert!(half_thickness(&closed, 32, 55) < 0.5 * expected, "closed: {}", half_thickness(&closed, 32, 55));
        // The sides and the top are still outlines, and above the cut's reach both agree.
        assert!(half_thickness(&open, 32, 8) < 0.5 * expected);
        assert!((half_thickness(&open, 32, 20) - half_thickness(&closed, 32, 20)).abs() < 0.05 * expected);
        assert_eq!(open.mask, closed.mask);
        assert!(open.front.data.iter().chain(&open.back.data).all(|v| v.is_finite()));
    }

    #[test]
    fn a_mask_a_pixel_or_two_short_of_the_frame_is_still_cut() {
        // At 512² the tolerance is 2.56 px: a strip ending 2 px above the frame's bottom edge (a segmentation that
        // stops short of the image's edge) stays open; one ending 8 px above it is a person ending there.
        let size = 512usize;
        let strip = |gap: usize| {
            GrayImage::from_fn(size, size, |c, r| f32::from((100..size - gap).contains(&r) && (216..296).contains(&c)))
        };
        let frame = (glam::Vec2::ZERO, glam::Vec2::splat(size as f32));
        let params = InflateParams::default();
        let short = inflate_in_frame(&strip(2), &params, Some(frame)).unwrap();
        let (mid, last) = (half_thickness(&short, 256, 400), half_thickness(&short, 256, size - 3));
        assert!(last > 0.9 * mid, "2 px short: {last} vs {mid}");
        let ends = inflate_in_frame(&strip(8), &params, Some(frame)).unwrap();
        assert!(half_thickness(&ends, 256, size - 9) < 0.5 * mid);
    }

    #[test]
    fn a_frame_that_cuts_nothing_changes_nothing_and_one_that_cuts_everywhere_stays_closed() {
        let mask = disc_mask(64, 32.0, 32.0, 20.0);
        let params = InflateParams::default();
        let closed = inflate(&mask, &params).unwrap();
        let far = (glam::Vec2::ZERO, glam::Vec2::new(64.0, 64.0));
        assert_eq!(inflate_in_frame(&mask, &params, Some(far)).unwrap(), closed);
        // A person filling the whole photo (the mask is the frame): every outline edge lies on the frame, and with no
        // outline left to hold the surface the cut closes (a finite, closed result instead of a singular problem).
        let boxed = GrayImage::from_fn(64, 64, |c, r| f32::from((10..50).contains(&c) && (12..40).contains(&r)));
        let frame = (glam::Vec2::new(10.0, 12.0), glam::Vec2::new(50.0, 40.0));
        let framed = inflate_in_frame(&boxed, &params, Some(frame)).unwrap();
        assert_eq!(framed, inflate(&boxed, &params).unwrap());
        // Cut on three sides (the mask runs off the frame's left, right and bottom): open there, closed at the top.
        let frame = (glam::Vec2::new(10.0, 0.0), glam::Vec2::new(50.0, 40.0));
        let framed = inflate_in_frame(&boxed, &params, Some(frame)).unwrap();
        assert!(half_thickness(&framed, 10, 39) > 2.0 * half_thickness(&inflate(&boxed, &params).unwrap(), 10, 39));
        assert!(half_thickness(&framed, 30, 12) < half_thickness(&framed, 30, 30));
        assert!(framed.front.data.iter().chain(&framed.back.data).all(|v| v.is_finite()));
    }

    #[test]
    fn a_coarse_solve_keeps_the_shape_and_the_outline() {
        // A disc and an ellipse side by side: solved at 256² and on the 128² grid, read back at 256².
        let mut mask = disc_mask(256, 80.0, 128.0, 60.0);
        let other = disc_mask(256, 190.0, 120.0, 40.0);
        mask.data.iter_mut().zip(&other.data).for_each(|(a, b)| *a = a.max(*b));
        let n = 32;
        let params = InflateParams::default();
        let fine = inflate_resolvable(&mask, n, &params, None).unwrap();
        let coarse = inflate_resolvable_coarse(&mask, n, &params, None, 2).unwrap();
        assert_eq!(inflate_resolvable_coarse(&mask, n, &params, None, 1).unwrap(), fine);
        // The outline is the mask's own: every person pixel keeps its depths.
        let person = |s: &InflatedSurfaces| s.mask.data.iter().filter(|&&m| m > 0.5).count();
        assert_eq!(person(&coarse), person(&fine));
        // Depths within 0.03 cube units inside (measured 0.021: 6 % of the disc's half thickness), 0.06 at the rim
        // (0.035; the profile is steepest there).
        let (mut inner, mut rim) = (0f32, 0f32);
        for r in 0..256 {
            for c in 0..256 {
                let i = r * 256 + c;
                if fine.mask.data[i] <= 0.5 {
                    continue;
                }
                assert!(coarse.back.data[i] <= coarse.front.data[i] && coarse.front.data[i].is_finite());
                let d = (coarse.front.data[i] - fine.front.data[i])
                    .abs()
                    .max((coarse.back.data[i] - fine.back.data[i]).abs());
                let interior = (r.saturating_sub(3)..=(r + 3).min(255))
                    .all(|rr| (c.saturating_sub(3)..=(c + 3).min(255)).all(|cc| fine.mask.data[rr * 256 + cc] > 0.5));
                if interior {
                    inner = inner.max(d);
                } else {
                    rim = rim.max(d);
                }
            }
        }
        assert!(inner < 0.03 && rim < 0.06, "largest depth difference: inside {inner}, at the rim {rim}");
    }

    #[test]
    fn disc_inflates_to_a_sphere_with_thickness_one() {
        let (size, r_px) = (128usize, 40.0f32);
        let mask = disc_mask(size, 64.0, 64.0, r_px);
        let params = InflateParams { thickness: 1.0, ..Default::default() };
        let s = inflate(&mask, &params).unwrap();
        let r = r_px * 2.0 / size as f32; // radius in cube units
                                          // Closed form: h(rho) = sqrt(R^2 - rho^2); check the centre and a ring of pixels.
        let mut worst = 0.0f32;
        for row in 0..size {
            for col in 0..size {
                let (x, y) = (col as f32 + 0.5 - 64.0, row as f32 + 0.5 - 64.0);
                let rho = (x * x + y * y).sqrt() * 2.0 / size as f32;
                let i = row * size + col;
                assert!(s.front.data[i].is_finite() && s.back.data[i].is_finite());
                if rho < 0.85 * r {
                    let want = (r * r - rho * rho).sqrt();
                    let got = 0.5 * (s.front.data[i] - s.back.data[i]);
                    worst = worst.max((got - want).abs() / r);
                    assert!((s.front.data[i] + s.back.data[i]).abs() < 1e-6, "symmetric about z = 0");
                } else if rho > r + 0.05 {
                    assert_eq!(s.mask.data[i], 0.0);
                    assert_eq!(s.front.data[i], -1.0);
                }
            }
        }
        assert!(worst < 0.025, "worst relative error {worst}");
        let centre = 64 * size + 64;
        assert!(((s.front.data[centre] - s.back.data[centre]) - 2.0 * r).abs() < 0.02 * r);
    }

    #[test]
    fn default_thickness_makes_a_strip_round() {
        // A long horizontal strip of half width a: depth semi-axis kappa * sqrt(2) * a ~ 0.99 a.
        let size = 128;
        let mask =
            GrayImage::from_fn(
                size,
                size,
                |c, r| if (8..120).contains(&c) && (54..74).contains(&r) { 1.0 } else { 0.0 },
            );
        let s = inflate(&mask, &InflateParams::default()).unwrap();
        let a = 10.0 * 2.0 / size as f32;
        let mid = 64 * size + 64;
        let half = 0.5 * (s.front.data[mid] - s.back.data[mid]);
        assert!((half - 0.7 * 2f32.sqrt() * a).abs() < 0.05 * a, "{half} vs {}", 0.7 * 2f32.sqrt() * a);
    }

    #[test]
    fn degenerate_masks_give_clear_errors() {
        let p = InflateParams::default();
        assert_eq!(inflate(&GrayImage::new(32, 32, 0.0), &p), Err(InflateError::EmptyMask));
        assert_eq!(inflate(&GrayImage::new(32, 32, 1.0), &p), Err(InflateError::FullMask));
        assert!(matches!(inflate(&GrayImage::new(2, 2, 1.0), &p), Err(InflateError::BadSize { .. })));
        let mut nan = GrayImage::new(16, 16, 0.0);
        nan.data[7] = f32::NAN;
        assert_eq!(inflate(&nan, &p), Err(InflateError::NonFinite { index: 7 }));
        // Isolated specks (single pixels, checkerboard): nothing big enough.
        let specks = GrayImage::from_fn(64, 64, |c, r| if (c + r) % 2 == 0 { 1.0 } else { 0.0 });
        assert!(matches!(inflate(&specks, &p), Err(InflateError::OnlySpecks { largest: 1, .. })));
        let bad = InflateParams { thickness: f32::NAN, ..Default::default() };
        assert!(matches!(inflate(&disc_mask(32, 16.0, 16.0, 8.0), &bad), Err(InflateError::BadParams(_))));
        // Foreground everywhere except a speck that gets filled: still "full".
        let mut almost = GrayImage::new(32, 32, 1.0);
        almost.data[100] = 0.0;
        assert_eq!(inflate(&almost, &p), Err(InflateError::FullMask));
    }

    #[test]
    fn thin_limbs_holes_and_many_components_stay_valid() {
        let size = 96;
        let mask = GrayImage::from_fn(size, size, |c, r| {
            let (x, y) = (c as f32 - 30.0, r as f32 - 30.0);
            let ring = (x * x + y * y).sqrt();
            let annulus = (8.0..20.0).contains(&ring);
            let limb = r == 30 && (50..90).contains(&c); // one pixel wide, touching nothing else
            let limb2 = c == 70 && (5..25).contains(&r);
            let blobs = r >= 60 && c >= 8 && (c % 8) < 5 && (r % 8) < 5; // many 5x5 components
            let diagonal = (56..60).contains(&r) && c >= 60 && ((c / 2) + (r / 2)) % 2 == 0; // saddle contacts
            if annulus || limb || limb2 || blobs || diagonal {
                1.0
            } else {
                0.0
            }
        });
        let s = inflate(&mask, &InflateParams::default()).unwrap();
        let h_min = 2.0 / size as f32;
        for i in 0..size * size {
            let (f, b) = (s.front.data[i], s.back.data[i]);
            assert!(f.is_finite() && b.is_finite() && (-1.0..=1.0).contains(&f) && (-1.0..=1.0).contains(&b));
            if s.mask.data[i] > 0.5 {
                assert!(f - b >= 2.0 * h_min - 1e-6, "inside pixels keep a thin valid interval");
            }
        }
        // The hole stays empty; the one-pixel limb is kept.
        assert_eq!(s.mask.data[30 * size + 30], 0.0);
        assert_eq!(s.mask.data[30 * size + 70], 1.0);
        // The annulus is thicker in the middle of its width than at its edges.
        let mid = 30 * size + 30 + 14;
        let edge = 30 * size + 30 + 19;
        assert!(s.front.data[mid] > s.front.data[edge]);
        let fof = inflate_to_fof(&mask, 32, &InflateParams::default(), None).unwrap();
        assert!(fof.coeffs.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn thin_parts_are_at_least_a_sheet_thick_and_stay_in_the_mesh() {
        // A 96 px disc (the body) with a 2 px bar beside it (a tripod leg) at 256²: the bar's inflated half height,
        // about 0.7 sqrt(2 a^2) with half width a = 1 px = 0.0078 cube units, is under 1/64: its interval is under
        // the 1/32 = 0.031 that 32 coefficients decode above 0.5. With a floor of half a sheet every bar column is
        // exactly 2/32 thick about 0 and decodes above 0.5 at z = 0; the disc's centre keeps its own height.
        let size = 256;
        let mut mask = disc_mask(size, 90.0, 128.0, 48.0);
        for r in 60..200 {
            for c in 200..202 {
                mask.data[r * size + c] = 1.0;
            }
        }
        let p = InflateParams::default();
        let raw = inflate(&mask, &p).unwrap();
        let bar = 128 * size + 201;
        assert!(raw.front.data[bar] < 0.5 / 32.0, "the bar is thinner than a sheet: {}", raw.front.data[bar]);
        let widened = inflate_at_least(&mask, &p, 0.5 * sheet_thickness(32), None).unwrap();
        assert_eq!(widened.front.data[bar], 1.0 / 32.0);
        assert_eq!(widened.back.data[bar], -1.0 / 32.0);
        let centre = 128 * size + 90;
        assert_eq!(widened.front.data[centre], raw.front.data[centre]);
        assert!(raw.front.data[centre] > 0.2);
        assert!(widened.front.data.iter().zip(&widened.mask.data).all(|(f, m)| *m < 0.5 || *f >= 1.0 / 32.0));
        // Outside the mask nothing changes; bad floors change nothing.
        assert_eq!(widened.front.data[0], raw.front.data[0]);
        for bad in [f32::NAN, -1.0, 0.0, f32::INFINITY, f32::NEG_INFINITY] {
            assert_eq!(inflate_at_least(&mask, &p, bad, None).unwrap(), raw);
        }
        // End to end: the bar decodes above 0.5 at the centre plane (before: below, absent from the mesh).
        let fof = inflate_to_fof(&mask, 32, &p, None).unwrap();
        let table = CosineTable::new(32, 128);
        let mut out = vec![0.0f32; 128];
        fof.decode_column_with(&table, 201, 128, &mut out);
        assert!(out.iter().any(|&o| o >= 0.5), "{:?}", out.iter().cloned().fold(0.0f32, f32::max));
        let old = Fof::from_depth_maps(&raw.front, &raw.back, &raw.mask, 32).unwrap();
        old.decode_column_with(&table, 201, 128, &mut out);
        assert!(out.iter().all(|&o| o < 0.5), "the bar was already in the mesh before");
    }

    #[test]
    fn spikes_are_removed_from_loops() {
        let square = vec![(0, 0), (4, 0), (4, 4), (0, 4)];
        assert_eq!(remove_spikes(square.clone()), square);
        // An edge walked out and back from (4, 4), anywhere in the cycle, and repeated points.
        assert_eq!(remove_spikes(vec![(0, 0), (4, 0), (4, 4), (7, 7), (4, 4), (0, 4)]), square);
        assert_eq!(
            remove_spikes(vec![(7, 7), (0, 0), (4, 0), (4, 4), (0, 4), (0, 0)]),
            vec![(4, 0), (4, 4), (0, 4), (0, 0)]
        );
        assert_eq!(remove_spikes(vec![(0, 0), (0, 0), (4, 0), (4, 4), (0, 4)]), square);
        assert!(remove_spikes(vec![(0, 0), (1, 1), (0, 0)]).len() < 3, "a loop that is only a spike vanishes");
    }

    #[test]
    fn a_lobe_touching_diagonally_does_not_empty_the_inflation() {
        // A synthetic subject's source mask at 128 px (`eval --size 128 --framing full`, subject 0): the traced
        // outline passes one corner twice (a lobe attached through a diagonal pixel touch) and simplification
        // collapsed the lobe into an out-and-back edge that made every triangle count as outside: an empty
        // inflation prior.
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/inflate/lobe_on_a_diagonal_touch_128.png");
        let img = image::open(path).expect("test mask").to_luma8();
        let mask = GrayImage {
            width: img.width() as usize,
            height: img.height() as usize,
            data: img.pixels().map(|p| p.0[0] as f32 / 255.0).collect(),
        };
        let s = inflate(&mask, &InflateParams::default()).unwrap();
        let inside: Vec<usize> = (0..s.mask.data.len()).filter(|&i| s.mask.data[i] > 0.5).collect();
        let min_half = 2.0 / mask.width as f32;
        let thick = inside.iter().filter(|&&i| s.front.data[i] - s.back.data[i] > 4.0 * min_half).count();
        let area = inside.len();
        assert!(thick * 2 > area, "most of the person is inflated: {thick} of {area} pixels");
    }

    fn load_mask(name: &str) -> GrayImage {
        let path = format!("{}/tests/data/inflate/{name}", env!("CARGO_MANIFEST_DIR"));
        let img = image::open(&path).expect("test mask").to_luma8();
        GrayImage {
            width: img.width() as usize,
            height: img.height() as usize,
            data: img.pixels().map(|p| p.0[0] as f32 / 255.0).collect(),
        }
    }

    #[test]
    fn a_hand_touching_the_arm_diagonally_does_not_empty_the_inflation() {
        // The unclothed synthetic subject of seed 9293172410827453255 at 256 px, arm raised with a hanging hand:
        // a two-pixel fingertip lobe hangs on two diagonal pixel touches. Simplified, the outline runs
        // (195,65) -> (193,63) -> (196,66): the way back passes through (195,65) and overlaps the way out, so the
        // CDT holds one constraint edge that the outline walks twice, which flipped the parity of every face
        // (an empty prior, every FOF column empty). Faces are now labelled by winding number.
        let mask = load_mask("arm_raised_seed9293172410827453255_256.png");
        let s = inflate(&mask, &InflateParams::default()).unwrap();
        let inside: Vec<usize> = (0..s.mask.data.len()).filter(|&i| s.mask.data[i] > 0.5).collect();
        let min_half = 2.0 / mask.width as f32;
        let thick = inside.iter().filter(|&&i| s.front.data[i] - s.back.data[i] > 4.0 * min_half).count();
        assert!(thick * 10 > inside.len() * 8, "most of the person is inflated: {thick} of {}", inside.len());
        let fof = inflate_to_fof(&mask, 32, &InflateParams::default(), None).unwrap();
        let coverage = mask_coverage(&fof, &mask, 2).unwrap();
        assert!(coverage >= 0.99, "the decoded prior covers the person: {coverage}");
    }

    #[test]
    fn winding_numbers_of_loops_with_holes_spikes_and_overlaps() {
        // A square 0..4 and a hole 1..3 of opposite orientation (inside: a non-zero winding number; its sign is the
        // orientation, which does not matter).
        let outer = vec![(0, 0), (0, 4), (4, 4), (4, 0)];
        let hole = vec![(1, 1), (3, 1), (3, 3), (1, 3)];
        let wn = Winding::new(&[outer.clone(), hole], 4);
        assert_eq!(wn.at(0.5, 0.5).abs(), 1);
        assert_eq!(wn.at(2.0, 2.0).abs(), 0, "inside the hole");
        assert_eq!(wn.at(3.5, 2.0).abs(), 1);
        assert_eq!(wn.at(5.0, 2.0).abs(), 0);
        assert_eq!(wn.at(2.0, -1.0).abs(), 0);
        assert_eq!(wn.at(2.0, 9.0).abs(), 0);
        // An out-and-back spike, and a return edge through a vertex overlapping the way out (the shape that
        // emptied the prior): the region's winding number is unchanged, on either side of the doubled piece.
        let spike = vec![(0, 0), (0, 4), (4, 4), (4, 2), (6, 2), (4, 2), (4, 0)];
        let overlap = vec![(0, 0), (0, 4), (4, 4), (4, 2), (6, 2), (5, 2), (4, 0)];
        for l in [spike, overlap] {
            let wn = Winding::new(&[l], 4);
            assert_eq!(wn.at(2.0, 2.5).abs(), 1);
            assert_eq!(wn.at(2.0, 1.5).abs(), 1);
            assert_eq!(wn.at(5.0, 1.5).abs(), 0);
            assert_eq!(wn.at(5.0, 2.5).abs(), 0);
        }
    }

    #[test]
    fn inflated_fraction_counts_the_interior_only() {
        // A 10x10 square inside 16x16: interior pixels are 2..=7 from the square's first row/column, 6x6 = 36.
        let (w, h) = (16, 16);
        let fg: Vec<bool> = (0..w * h).map(|i| (3..13).contains(&(i % w)) && (3..13).contains(&(i / w))).collect();
        let interior = |i: usize| (5..11).contains(&(i % w)) && (5..11).contains(&(i / w));
        let all: Vec<f32> = (0..w * h).map(|i| if fg[i] { 1.0 } else { 0.0 }).collect();
        assert_eq!(inflated_fraction(&fg, &all, w, h), 1.0);
        // Rim pixels at zero do not count; half the interior rows at zero give one half.
        let rim_flat: Vec<f32> = (0..w * h).map(|i| if interior(i) { 1.0 } else { 0.0 }).collect();
        assert_eq!(inflated_fraction(&fg, &rim_flat, w, h), 1.0);
        let half: Vec<f32> = (0..w * h).map(|i| if interior(i) && i / w < 8 { 1.0 } else { 0.0 }).collect();
        assert_eq!(inflated_fraction(&fg, &half, w, h), 0.5);
        assert_eq!(inflated_fraction(&fg, &vec![0.0; w * h], w, h), 0.0);
        // A sliver (no interior pixel) has nothing to miss.
        let line: Vec<bool> = (0..w * h).map(|i| i / w == 8).collect();
        assert_eq!(inflated_fraction(&line, &vec![0.0; w * h], w, h), 1.0);
    }

    #[test]
    fn the_exact_outline_inflates_what_the_simplified_one_does() {
        // The retry path of `inflate`: the exact pixel outline (tolerance 0) must inflate the person as fully as
        // the simplified one, on the mask that once emptied the prior and on a disc.
        for mask in [load_mask("arm_raised_seed9293172410827453255_256.png"), disc_mask(64, 32.0, 32.0, 20.0)] {
            let fg: Vec<bool> = mask.data.iter().map(|&v| v > 0.5).collect();
            let loops = trace_loops(&fg, mask.width, mask.height);
            let exact = InflateParams { simplify_tolerance: 0.0, ..InflateParams::default() };
            for params in [InflateParams::default(), exact] {
                let u = solve_inflation(&loops, mask.width, mask.height, &params, None).unwrap();
                let f = inflated_fraction(&fg, &u, mask.width, mask.height);
                assert!(f >= 0.99, "tolerance {}: {f}", params.simplify_tolerance);
            }
        }
    }

    #[test]
    fn coverage_of_full_empty_and_half_priors() {
        let mask = disc_mask(64, 32.0, 32.0, 20.0);
        let full = inflate_to_fof(&mask, 32, &InflateParams::default(), None).unwrap();
        assert_eq!(mask_coverage(&full, &mask, 2), Some(1.0));
        let empty = Fof::zeros(32, 64, 64).unwrap();
        assert_eq!(mask_coverage(&empty, &mask, 2), Some(0.0));
        // Zero the columns of the left half (x < 32): about half the interior is covered.
        let mut half = full.clone();
        for r in 0..64 {
            for c in 0..32 {
                let i = (r * 64 + c) * 32;
                half.coeffs[i..i + 32].fill(0.0);
            }
        }
        let got = mask_coverage(&half, &mask, 2).unwrap();
        assert!((got - 0.5).abs() < 0.03, "{got}");
        // No interior pixel (a one-pixel line), or a prior of another size: no measure.
        let line = GrayImage::from_fn(64, 64, |c, r| if r == 30 && c > 5 && c < 60 { 1.0 } else { 0.0 });
        assert_eq!(mask_coverage(&full, &line, 1), None);
        assert_eq!(mask_coverage(&Fof::zeros(32, 32, 32).unwrap(), &mask, 2), None);
    }

    #[test]
    fn loops_follow_holes_and_saddles() {
        // Two pixels touching diagonally: two separate loops sharing a corner.
        let (w, h) = (4, 4);
        let mut fg = vec![false; w * h];
        fg[w + 1] = true;
        fg[2 * w + 2] = true;
        let loops = trace_loops(&fg, w, h);
        assert_eq!(loops.len(), 2);
        assert!(loops.iter().all(|l| l.len() == 4));
        // A 3x3 ring with a hole: an outer and an inner loop of opposite orientation.
        let mut fg = vec![true; 9];
        fg[4] = false;
        let loops = trace_loops(&fg, 3, 3);
        assert_eq!(loops.len(), 2);
        let signed = |l: &Vec<(i64, i64)>| {
            (0..l.len())
                .map(|k| {
                    let (a, b) = (l[k], l[(k + 1) % l.len()]);
                    (a.0 * b.1 - b.0 * a.1) as f64
                })
                .sum::<f64>()
        };
        let areas: Vec<f64> = loops.iter().map(signed).collect();
        assert!(
            areas[0] * areas[1] < 0.0 && (areas[0].abs() - 18.0).abs() < 1e-9 || (areas[1].abs() - 18.0).abs() < 1e-9
        );
    }
}
