//! The reconstructed person as a textured glTF 2.0 binary (`r2human export`, the E key of `view`, the export
//! action of `xr`).
//!
//! - **Geometry**: the prepared input's mesh (optionally simplified to `--decimate` triangles by meshoptimizer),
//!   moved from the body cube into metres: +Y up, feet (the mesh's lowest point) at y = 0, facing +Z (the photo's
//!   camera looks at the front), x and z centred on the body cube's axis. glTF's own conventions.
//! - **Size**: [`visible_height`] decides how tall the part of the person the photo shows is, from the person's
//!   standing height (`--height`, default [`DEFAULT_HEIGHT_M`]).
//! - **Appearance**: a texture baked from what the pipeline shows. Every vertex's UV is its orthographic
//!   projection into the source view, so at yaw 0 the model shows the photo exactly as the renderer does. With
//!   [`OcclusionFill::MirroredFront`] every surface uses that one image (the back shows the front's colours at the
//!   same place, as the renderer draws it); with [`OcclusionFill::Propagate`] the triangles the photo does not
//!   see get a second image, the colours of the silhouette's rim diffused inward (what the renderer shows from
//!   behind), and their vertices are duplicated onto it; with [`OcclusionFill::Back`] (and an input that has a back
//!   image, [`super::back`]) the triangles the photo does not see and that face away from it
//!   ([`super::warp::back_weight`] at least 0.5: the renderer's blend, decided per triangle) get the back image
//!   as the second image, at the same UVs. Texture pixels outside the person are filled from the
//!   nearest person pixels (push-pull), so filtering never pulls in the background.
//! - Written by [`crate::io::mesh_io::write_glb`] (unlit material, PNG texture, atomic write).

use std::path::Path;

use glam::{Vec2, Vec3};

use super::warp::{push_pull, OcclusionFill};
use super::{PreparedInput, StageTimings};
use crate::buffer::GrayImage;
use crate::geometry::TriMesh;
use crate::io::mesh_io::{linear_to_srgb8, write_glb, MeshIoError, TexturedMesh};

/// Standing height assumed when none is given (`--height`), metres.
pub const DEFAULT_HEIGHT_M: f32 = 1.75;

/// Crown to the narrowest row of the neck in a frontal silhouette, as a fraction of the standing height: the head
/// (crown to chin) is about 1/7.5 of an adult's stature and the neck's narrowest row lies just below the chin, so
/// about 1/7.
pub const CROWN_TO_NECK_FRACTION: f32 = 1.0 / 7.0;

/// Crown to the neck's narrowest row over the head's widest row (with hair) in a frontal silhouette: about
/// 0.25 m over 0.19 m. A portrait's head is taken to be at least this many times as tall as it is wide, which
/// catches a "neck" found too high — at the jaw, when a collar, a scarf or a suit ring hides the real neck.
pub const HEAD_ASPECT: f32 = 1.3;

/// Heights accepted for `--height`, metres.
pub const HEIGHT_RANGE_M: std::ops::RangeInclusive<f32> = 0.3..=3.0;

/// Fewest triangles accepted for `--decimate`.
pub const MIN_TRIANGLES: usize = 100;

/// Errors of the export.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// `--height` outside [`HEIGHT_RANGE_M`] or not finite.
    #[error(
        "a height of {0} m is not a person's standing height: give metres between 0.3 and 3 (default 1.75) to \
         --height (export) or --export-height (view, xr)"
    )]
    Height(f32),
    /// `--decimate` below [`MIN_TRIANGLES`].
    #[error(
        "decimating to {0} triangles leaves too little of the person: give at least {MIN_TRIANGLES} to --decimate \
         (export) or --export-decimate (view, xr)"
    )]
    Decimate(usize),
    /// The mask given does not belong to the input.
    #[error("the person mask is empty, so the photo's framing (and the person's size) is unknown")]
    EmptyMask,
    /// The mesh is empty.
    #[error("the reconstructed mesh is empty; nothing to export")]
    Empty,
    /// Encoding or writing the file failed.
    #[error(transparent)]
    Write(#[from] MeshIoError),
}

/// Settings of [`person_glb`].
#[derive(Clone, Debug, PartialEq)]
pub struct ExportOptions {
    /// The person's standing height in metres.
    pub height_m: f32,
    /// How surfaces the photo does not show are coloured (as `--fill` for the renderer).
    pub fill: OcclusionFill,
    /// Simplify the mesh to about this many triangles.
    pub decimate: Option<usize>,
}

impl ExportOptions {
    /// Checks the height and the triangle budget (before any work is done on the photo).
    pub fn validate(&self) -> Result<(), ExportError> {
        if !self.height_m.is_finite() || !HEIGHT_RANGE_M.contains(&self.height_m) {
            return Err(ExportError::Height(self.height_m));
        }
        match self.decimate {
            Some(t) if t < MIN_TRIANGLES => Err(ExportError::Decimate(t)),
            _ => Ok(()),
        }
    }
}

impl Default for ExportOptions {
    fn default() -> Self {
        Self { height_m: DEFAULT_HEIGHT_M, fill: OcclusionFill::default(), decimate: None }
    }
}

/// What the photo says about how much of the person it shows.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum HeightCue {
    /// The person ends above the photo's bottom edge: the whole person is in view.
    WholePerson,
    /// The person is cut by the bottom edge (a portrait): the visible part is scaled by the head, crown to neck
    /// ([`CROWN_TO_NECK_FRACTION`] of the standing height), taken as `max(neck_rows, HEAD_ASPECT * head_width)`.
    CutAtNeckScale {
        /// Rows from the crown to the bottom of the person.
        visible_rows: usize,
        /// Rows from the crown to the narrowest row of the neck.
        neck_rows: usize,
        /// The head's largest (smoothed) width above the neck, pixels.
        head_width: usize,
        /// The head's height used for the scale, rows: the larger of `neck_rows` and [`HEAD_ASPECT`] `* head_width`.
        head_rows: usize,
    },
    /// Cut by the bottom edge, but no neck was found in the silhouette: assumed to be the whole person.
    CutNoNeck,
}

/// The height of the visible part of the person and why.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VisibleHeight {
    /// Metres from the lowest to the highest visible point of the person.
    pub metres: f32,
    /// The evidence.
    pub cue: HeightCue,
}

impl std::fmt::Display for VisibleHeight {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.cue {
            HeightCue::WholePerson => write!(f, "{:.2} m (the whole person is in the photo)", self.metres),
            HeightCue::CutAtNeckScale { visible_rows, neck_rows, head_width, head_rows } => write!(
                f,
                "{:.2} m (the photo shows the top of the person: {visible_rows} rows; head {head_rows} rows, from \
                 crown to neck {neck_rows} rows and width {head_width} px)",
                self.metres
            ),
            HeightCue::CutNoNeck => {
                write!(f, "{:.2} m (cut at the bottom, no neck found: taken as the whole person)", self.metres)
            }
        }
    }
}

/// How tall the part of the person that `mask` (the photo's person mask, values `>= 0.5` = person) shows is,
/// for a person `standing_m` metres tall. A person that ends above the photo's bottom edge is the whole person. A
/// person cut by the bottom edge is scaled by the head: walking down the silhouette's row widths (smoothed), the
/// first narrowing after the head that the shoulders then exceed is the neck; the head is taken to reach from the
/// crown to the neck, but at least [`HEAD_ASPECT`] times its largest width above the neck (a neck found at the jaw
/// would make it too short), and that height is [`CROWN_TO_NECK_FRACTION`] of the standing height. The result is
/// clamped to `[that, standing_m]`. `None` for an empty mask.
pub fn visible_height(mask: &GrayImage, standing_m: f32) -> Option<VisibleHeight> {
    let (w, h) = (mask.width, mask.height);
    let widths: Vec<f32> =
        (0..h).map(|r| mask.data[r * w..(r + 1) * w].iter().filter(|&&v| v >= 0.5).count() as f32).collect();
    let top = widths.iter().position(|&c| c > 0.0)?;
    let bottom = widths.iter().rposition(|&c| c > 0.0)?;
    let whole = VisibleHeight { metres: standing_m, cue: HeightCue::WholePerson };
    // Cut: the person reaches the last 1 % of the rows.
    if (bottom as f32) < (h as f32 * 0.99 - 1.0) {
        return Some(whole);
    }
    let rows = bottom + 1 - top;
    let radius = (rows / 50).max(1);
    let smooth = |r: usize| {
        let (a, b) = (r.saturating_sub(radius).max(top), (r + radius).min(bottom));
        widths[a..=b].iter().sum::<f32>() / (b + 1 - a) as f32
    };
    let (mut peak, mut valley): (f32, Option<(usize, f32)>) = (0.0, None);
    let mut neck = None;
    for r in top..=bottom {
        let v = smooth(r);
        match valley {
            None if v >= peak => peak = v,
            None if v < 0.9 * peak => valley = Some((r, v)),
            None => {}
            Some((_, vw)) if v < vw => valley = Some((r, v)),
            Some((vr, vw)) if v > peak.max(1.3 * vw) => {
                neck = Some(vr);
                break;
            }
            Some(_) => {}
        }
    }
    let Some(neck) = neck else { return Some(VisibleHeight { metres: standing_m, cue: HeightCue::CutNoNeck }) };
    let neck_rows = neck + 1 - top;
    let head_width = peak.round() as usize;
    let head_rows = neck_rows.max((HEAD_ASPECT * peak).round() as usize);
    let metres = standing_m * CROWN_TO_NECK_FRACTION * rows as f32 / head_rows as f32;
    Some(VisibleHeight {
        metres: metres.clamp(standing_m * CROWN_TO_NECK_FRACTION, standing_m),
        cue: HeightCue::CutAtNeckScale { visible_rows: rows, neck_rows, head_width, head_rows },
    })
}

/// The similarity from body-cube coordinates to the exported metres: `metres = scale * cube + offset`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    /// Metres per body-cube unit.
    pub scale: f32,
    /// Translation in metres.
    pub offset: Vec3,
}

impl Placement {
    /// Body cube to metres.
    pub fn to_metres(&self, p: Vec3) -> Vec3 {
        self.scale * p + self.offset
    }

    /// Metres to body cube.
    pub fn to_body_cube(&self, p: Vec3) -> Vec3 {
        (p - self.offset) / self.scale
    }

    /// The placement that makes a mesh spanning `y_min..y_max` (body cube) `visible_m` tall with its lowest point
    /// at y = 0, x and z on the body cube's axis.
    pub fn standing(y_min: f32, y_max: f32, visible_m: f32) -> Self {
        let scale = visible_m / (y_max - y_min).max(1e-6);
        Self { scale, offset: Vec3::new(0.0, -scale * y_min, 0.0) }
    }
}

/// What [`person_glb`] made.
#[derive(Clone, Debug)]
pub struct ExportReport {
    /// Triangles of the pipeline's mesh.
    pub source_triangles: usize,
    /// Triangles written.
    pub triangles: usize,
    /// Vertices written (the ones on both texture images counted twice).
    pub vertices: usize,
    /// Simplifier error relative to the mesh extent (0 without `--decimate`).
    pub decimation_error: f32,
    /// The visible part's height and the evidence for it.
    pub visible: VisibleHeight,
    /// Body cube to metres.
    pub placement: Placement,
    /// Texture size in pixels (width, height).
    pub texture: (u32, u32),
    /// Triangles textured from the second image ([`OcclusionFill::Propagate`]'s rim colours or
    /// [`OcclusionFill::Back`]'s back image).
    pub back_triangles: usize,
    /// Time of each export stage: "decimate" (with `--decimate`), "UVs + metres" (which texture image each
    /// triangle uses, vertices moved into metres), "texture bake" (push-pull filled photo, rim image, 8-bit sRGB),
    /// and [`person_glb`]'s "encode + write" (glTF binary with its PNG, written atomically).
    pub timings: StageTimings,
}

impl std::fmt::Display for ExportReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} triangles ({} reconstructed), {} vertices, texture {}x{}, {} tall",
            self.triangles, self.source_triangles, self.vertices, self.texture.0, self.texture.1, self.visible
        )
    }
}

/// A texture image of `rgb` (premultiplied by `mask`: the photo, or the back image): straight (un-premultiplied)
/// colour where the mask has weight, the rest filled from the nearest person pixels (push-pull), `resolution^2`,
/// linear RGB.
fn front_image(rgb: &crate::buffer::RgbImage, mask: &GrayImage) -> Vec<Vec3> {
    let (w, h) = (rgb.width, rgb.height);
    let known: Vec<bool> = mask.data.iter().map(|&m| m > 0.05).collect();
    let mut color: Vec<Vec3> =
        rgb.data.iter().zip(&mask.data).map(|(c, &m)| if m > 0.05 { *c / m } else { Vec3::ZERO }).collect();
    push_pull(&mut color, &known, None, w, h);
    color.iter().map(|c| c.clamp(Vec3::ZERO, Vec3::ONE)).collect()
}

/// The texture image for surfaces the photo does not show with [`OcclusionFill::Propagate`]: the person's colours
/// within `rim` pixels of the silhouette (what stays visible from behind), diffused inward and outward.
fn rim_image(front: &[Vec3], mask: &GrayImage, rim: usize) -> Vec<Vec3> {
    let (w, h) = (mask.width, mask.height);
    let inside = crate::buffer::Image { width: w, height: h, data: mask.data.iter().map(|&m| m >= 0.5).collect() };
    let core = crate::capture::morph::erode(&inside, rim);
    let known: Vec<bool> = inside.data.iter().zip(&core.data).map(|(&i, &c)| i && !c).collect();
    let mut color: Vec<Vec3> = front.iter().zip(&known).map(|(c, &k)| if k { *c } else { Vec3::ZERO }).collect();
    push_pull(&mut color, &known, None, w, h);
    color
}

/// Whether the source view sees the point `p` (body cube) on a surface with normal `n`: it faces the camera and
/// lies within `tolerance` of the source depth at its pixel.
fn seen_by_photo(input: &PreparedInput, p: Vec3, n: Vec3, tolerance: f32) -> bool {
    let g = &input.source_gbuffer;
    let (w, h) = (g.width as f32, g.height as f32);
    let (col, row) = ((p.x + 1.0) * 0.5 * w, (1.0 - p.y) * 0.5 * h);
    if n.z <= 0.0 || !(0.0..w).contains(&col) || !(0.0..h).contains(&row) {
        return false;
    }
    let i = row as usize * g.width + col as usize;
    g.mask[i] && (g.depth[i] - p.z).abs() <= tolerance
}

/// The UV of body-cube point `p` in texture image `image` (0 = the photo's, 1 = the rim's) of an atlas `images`
/// wide: its orthographic source-view projection (glTF UVs, origin top-left).
fn project_uv(p: Vec3, image: usize, images: usize) -> Vec2 {
    Vec2::new((image as f32 + (p.x + 1.0) * 0.5) / images as f32, (1.0 - p.y) * 0.5)
}

/// What the second texture image holds, if there is one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Second {
    /// One image: the photo's.
    None,
    /// [`OcclusionFill::Propagate`]: the rim colours, for every triangle the photo does not see.
    Rim,
    /// [`OcclusionFill::Back`]: the back image, for the triangles the photo does not see that face away from it.
    Back,
}

/// The mesh in metres with its UVs: each triangle on the photo's texture image, or on the second image (`second`)
/// when the photo does not see it (and, for the back image, it faces away from the photo), vertices duplicated
/// where they are on both; wound counter-clockwise (glTF's front faces). Returns it and the number of triangles on
/// the second image.
fn uv_mesh(
    input: &PreparedInput,
    mesh: &TriMesh,
    decimation_error: f32,
    placement: Placement,
    second: Second,
) -> (TriMesh, usize) {
    let two = second != Second::None;
    let images = if two { 2 } else { 1 };
    let res = input.normalised.rgb.width;
    // Which triangles the photo sees (Propagate only): centroid against the source depth, with a tolerance of
    // two source pixels plus what simplification may have moved the surface.
    let extent = mesh.bounds().map_or(0.0, |(lo, hi)| (hi - lo).max_element());
    let tolerance = 4.0 / res as f32 + 2.0 * decimation_error * extent;
    let back: Vec<bool> = mesh
        .triangles
        .iter()
        .map(|t| {
            if !two {
                return false;
            }
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            let n = (b - a).cross(c - a);
            // The source camera's view axes are the body cube's: its axis is +z.
            let facing_away = second != Second::Back || super::warp::back_weight(n.normalize_or_zero(), Vec3::Z) >= 0.5;
            facing_away && !seen_by_photo(input, (a + b + c) / 3.0, n, tolerance)
        })
        .collect();
    // Vertices used by triangles on each image, duplicated where a vertex is on both.
    let mut remap = vec![[u32::MAX; 2]; mesh.positions.len()];
    let (mut positions, mut normals, mut uvs, mut triangles) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (t, &on_back) in mesh.triangles.iter().zip(&back) {
        let image = usize::from(on_back);
        triangles.push(t.map(|v| {
            let slot = &mut remap[v as usize][image];
            if *slot == u32::MAX {
                let p = mesh.positions[v as usize];
                *slot = positions.len() as u32;
                positions.push(placement.to_metres(p));
                normals.push(mesh.normals.get(v as usize).copied().unwrap_or(Vec3::Z));
                uvs.push(project_uv(p, image, images));
            }
            *slot
        }));
    }
    let back_triangles = back.iter().filter(|&&b| b).count();
    let mut out = TriMesh { positions, triangles, normals, colors: Vec::new(), uvs };
    // glTF wants counter-clockwise front faces.
    if out.signed_volume() < 0.0 {
        for t in &mut out.triangles {
            t.swap(1, 2);
        }
        out.compute_normals();
    }
    (out, back_triangles)
}

/// The person of `input` as a textured mesh in metres (see the module docs). `photo_mask` is the person mask at
/// the photo's size (it decides [`visible_height`]).
pub fn person_mesh(
    input: &PreparedInput,
    photo_mask: &GrayImage,
    opts: &ExportOptions,
) -> Result<(TexturedMesh, ExportReport), ExportError> {
    opts.validate()?;
    let visible = visible_height(photo_mask, opts.height_m).ok_or(ExportError::EmptyMask)?;
    if input.mesh.is_empty() {
        return Err(ExportError::Empty);
    }
    let mut timings = StageTimings::default();
    let decimated = opts.decimate.map(|t| timings.time("decimate", || input.mesh.simplified(t)));
    let (mesh, decimation_error) = match &decimated {
        Some((m, e)) => (m, *e),
        None => (&input.mesh, 0.0),
    };
    let (lo, hi) = mesh.bounds().ok_or(ExportError::Empty)?;
    let placement = Placement::standing(lo.y, hi.y, visible.metres);

    let res = input.normalised.rgb.width;
    let second = match opts.fill {
        OcclusionFill::Propagate => Second::Rim,
        OcclusionFill::Back if input.back.is_some() => Second::Back,
        _ => Second::None,
    };
    let images = if second == Second::None { 1 } else { 2 };
    let (out, back_triangles) =
        timings.time("UVs + metres", || uv_mesh(input, mesh, decimation_error, placement, second));
    let texture = timings.time("texture bake", || {
        let front = front_image(&input.normalised.rgb, &input.normalised.mask);
        let rim = match (second, &input.back) {
            (Second::Rim, _) => Some(rim_image(&front, &input.normalised.mask, (res / 50).max(2))),
            (Second::Back, Some(back)) => Some(front_image(&back.rgb, &input.normalised.mask)),
            _ => None,
        };
        let mut texture = image::RgbImage::new((res * images) as u32, res as u32);
        for (x, y, px) in texture.enumerate_pixels_mut() {
            let (img, col, row) = (x as usize / res, x as usize % res, y as usize);
            let c = match (&rim, img) {
                (Some(r), 1) => r[row * res + col],
                _ => front[row * res + col],
            };
            *px = image::Rgb(linear_to_srgb8(c));
        }
        texture
    });
    let report = ExportReport {
        source_triangles: input.mesh.triangle_count(),
        triangles: out.triangle_count(),
        vertices: out.positions.len(),
        decimation_error,
        visible,
        placement,
        texture: texture.dimensions(),
        back_triangles,
        timings,
    };
    Ok((TexturedMesh::textured(out, texture), report))
}

/// The file an interactive export (view's `E` key, xr's export action) writes in `dir` at frame `frame`:
/// `r2human-person-NNNNN.glb`.
pub fn numbered_path(dir: &Path, frame: u64) -> std::path::PathBuf {
    dir.join(format!("r2human-person-{frame:05}.glb"))
}

/// [`person_mesh`] written to `path` as glTF 2.0 binary (atomically: a temporary file, then a rename).
pub fn person_glb(
    path: &Path,
    input: &PreparedInput,
    photo_mask: &GrayImage,
    opts: &ExportOptions,
) -> Result<ExportReport, ExportError> {
    let (mesh, mut report) = person_mesh(input, photo_mask, opts)?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|source| MeshIoError::Io { path: dir.to_path_buf(), source })?;
    }
    report.timings.time("encode + write", || write_glb(path, &mesh))?;
    tracing::info!("wrote {}: {report}", path.display());
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::buffer::Image;

    /// A silhouette in a `(w, h)` image: a head disc `(top row, radius)`, a neck `(last row + 1, width)` from the
    /// top, then a body `(width, bottom row + 1)`.
    fn bust(
        (w, h): (usize, usize),
        (top, hr): (usize, f32),
        (neck_end, nw): (usize, f32),
        (sw, bottom): (f32, usize),
    ) -> GrayImage {
        let cx = w as f32 / 2.0;
        Image::from_fn(w, h, |c, r| {
            let (x, y) = (c as f32 + 0.5, r as f32 + 0.5);
            let head = (x - cx).powi(2) + (y - top as f32 - hr).powi(2) <= hr * hr;
            let neck = r >= top && r < neck_end && (x - cx).abs() <= nw / 2.0;
            let body = r >= neck_end && r < bottom && (x - cx).abs() <= sw / 2.0;
            if head || neck || body {
                1.0
            } else {
                0.0
            }
        })
    }

    #[test]
    fn whole_person_takes_the_standing_height() {
        let m = bust((100, 200), (10, 12.0), (40, 8.0), (40.0, 180));
        let v = visible_height(&m, 1.75).unwrap();
        assert_eq!(v, VisibleHeight { metres: 1.75, cue: HeightCue::WholePerson });
        assert!(visible_height(&Image::new(10, 10, 0.0), 1.75).is_none());
    }

    /// A silhouette like [`bust`] whose head is an ellipse `(top row, half width, half height)`.
    fn tall_head_bust((w, h): (usize, usize), (top, rx, ry): (usize, f32, f32), nw: f32, sw: f32) -> GrayImage {
        let cx = w as f32 / 2.0;
        let neck_end = top + (2.0 * ry) as usize + 15;
        Image::from_fn(w, h, |c, r| {
            let (x, y) = (c as f32 + 0.5 - cx, r as f32 + 0.5);
            let head = (x / rx).powi(2) + ((y - top as f32 - ry) / ry).powi(2) <= 1.0;
            let neck = r >= top && r < neck_end && x.abs() <= nw / 2.0;
            let body = r >= neck_end && x.abs() <= sw / 2.0;
            if head || neck || body {
                1.0
            } else {
                0.0
            }
        })
    }

    #[test]
    fn portrait_is_scaled_by_the_head() {
        // Head from row 20 (radius 30: down to row 80), neck 24 px wide to row 100, shoulders to the bottom (300).
        // The narrowest smoothed row is in the neck, just below where the head disc has shrunk to the neck width
        // (row ~76): crown-to-neck ~ 57 rows. The head is 60 px wide, so at least 1.3 * 60 = 78 rows tall: the
        // width decides. Visible 280 rows: 1.75 / 7 * 280 / 78 ~ 0.90 m.
        let m = bust((200, 300), (20, 30.0), (100, 24.0), (160.0, 300));
        let v = visible_height(&m, 1.75).unwrap();
        let HeightCue::CutAtNeckScale { visible_rows, neck_rows, head_width, head_rows } = v.cue else {
            panic!("{v:?}")
        };
        assert_eq!(visible_rows, 280);
        assert!((54..=81).contains(&neck_rows), "{neck_rows}");
        assert!((57..=61).contains(&head_width), "{head_width}");
        assert_eq!(head_rows, (HEAD_ASPECT * head_width as f32).round() as usize);
        let expect = 1.75 / 7.0 * 280.0 / head_rows as f32;
        assert!((v.metres - expect).abs() < 1e-5, "{v:?}");
        // A head taller than 1.3 times its width (an ellipse 50 wide, 90 tall; a hat, a long face): the neck
        // decides. Crown to neck ~ 90 rows > 1.3 * 50 = 65.
        let m = tall_head_bust((200, 400), (10, 25.0, 45.0), 20.0, 150.0);
        let v = visible_height(&m, 1.75).unwrap();
        let HeightCue::CutAtNeckScale { visible_rows, neck_rows, head_width, head_rows } = v.cue else {
            panic!("{v:?}")
        };
        assert_eq!(visible_rows, 390);
        assert!((80..=100).contains(&neck_rows) && (48..=51).contains(&head_width), "{v:?}");
        assert_eq!(head_rows, neck_rows);
        assert!((v.metres - 1.75 / 7.0 * 390.0 / neck_rows as f32).abs() < 1e-5, "{v:?}");
        // Linear in the standing height.
        let v2 = visible_height(&m, 1.5).unwrap();
        assert!((v2.metres / v.metres - 1.5 / 1.75).abs() < 1e-5);
        // A column cut at the bottom with no neck: the whole person.
        let column = Image::from_fn(50, 100, |c, r| if (20..30).contains(&c) && r >= 10 { 1.0 } else { 0.0 });
        assert_eq!(visible_height(&column, 1.75).unwrap().cue, HeightCue::CutNoNeck);
    }

    #[test]
    fn placement_round_trips_and_stands_on_the_floor() {
        let p = Placement::standing(-0.9, 0.9, 1.8);
        assert!((p.scale - 1.0).abs() < 1e-6);
        assert_eq!(p.to_metres(Vec3::new(0.0, -0.9, 0.0)), Vec3::ZERO);
        assert!((p.to_metres(Vec3::new(0.0, 0.9, 0.0)).y - 1.8).abs() < 1e-6);
        let q = Placement::standing(-0.5, 0.7, 0.6);
        let x = Vec3::new(0.3, -0.2, 0.1);
        assert!((q.to_body_cube(q.to_metres(x)) - x).length() < 1e-6);
        assert!(q.to_metres(Vec3::new(0.0, -0.5, 0.0)).length() < 1e-6);
    }

    #[test]
    fn uv_is_the_source_projection() {
        // Pixel centre (col + 0.5) / 256 - 1 of a 512 source maps to u = (col + 0.5) / 512.
        let p = Vec3::new((10.0 + 0.5) / 256.0 - 1.0, 1.0 - (20.0 + 0.5) / 256.0, 0.3);
        let uv = project_uv(p, 0, 1);
        assert!((uv - Vec2::new(10.5 / 512.0, 20.5 / 512.0)).length() < 1e-6);
        let back = project_uv(p, 1, 2);
        assert!((back - Vec2::new(0.5 + 10.5 / 1024.0, 20.5 / 512.0)).length() < 1e-6);
    }
}
