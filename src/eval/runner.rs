//! `r2human eval`: renders each subject's source view, runs every method on it, and compares the novel views with
//! ground truth, grouped like the paper's Tables 2 and 3: close views (at most 45 degrees from the input) and
//! divergent views (at least 90 degrees). Metrics are those of [`super::metrics`] (read its conventions: sRGB over
//! black, averaged over the union of predicted and true masks; plus the paper's whole-frame PSNR and SSIM). Rows are
//! reported per input set: the synthetic subjects together, and each `--scan` on its own (with several scans also
//! their means over characters, dev / held out / all: [`super::scans`]). LPIPS needs ImageNet-pretrained weights that
//! cannot be fetched here: its column is left empty (`lpips` in the CSV) until a model is shipped.
//!
//! Methods, measured side by side on the same subjects and views:
//! 1. `billboard`: the cut-out on the plane z = 0 (what most VR telepresence shows);
//! 2. `2.5d`: only the visible front surface (the inflation prior's source depth) as a depth mesh;
//! 3. `geometric+inflation`: the project's geometric renderer with the inflation prior;
//! 4. `geometric+gt-fof`: the same with the ground-truth FOF (oracle geometry);
//! 5. `neural+inflation`: the neural renderer (encoder + residual decoder, [`crate::pipeline::NeuralRenderer`]) on
//!    the same inflation geometry as method 3 (per-input time = method 3's plus the encoder);
//! 6. `neural+gt-fof`: the neural renderer on the oracle geometry of method 4.
//!
//! 7. `geometric+fofnet`: the geometric renderer on the FOF net's geometry (the network's correction of the
//!    inflation prior, [`crate::pipeline::compute_geometry`] with [`GeometryMode::FofNet`]; per-input time includes
//!    the prior and the network);
//! 8. `neural+fofnet`: the neural renderer on that geometry;
//! 9. `geometric+body`, 10. `neural+body`: both renderers on the body prior's geometry (pose network, body fit,
//!    body FOF reconciled with the silhouette; an input without a pose falls back to the inflation prior).
//!
//! Methods 5 and 6 run when the neural models load ([`NeuralEvalOptions::models`], default `models/tiny`); otherwise
//! one warning says why and their rows are absent. Methods 7 and 8 run when the folder's `fof.onnx` loads (8 also
//! needs the renderer's models), 9 and 10 when the pose model and body data load; otherwise their rows are absent
//! and `report.md` says why. [`NeuralEvalOptions::skip`] (`--no-neural`) leaves out 5 to 10. The report also gives the
//! geometry alone: the volumetric IoU of each per-input FOF's decoded occupancy against the ground-truth FOF.

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::{Vec3, Vec4};
use rayon::prelude::*;
use serde::Serialize;

use super::ground_truth::{render_ground_truth, GroundTruthView};
use super::memory::{process_peak_mib, PhaseMemory};
use super::metrics::{depth_l1, mask_iou, psnr, psnr_frame, ssim, ssim_frame, union_mask, SrgbImage};
use super::EvalError;
use crate::buffer::{GrayImage, RgbImage, RgbaImage};
use crate::geometry::camera::Camera;
use crate::geometry::fof::Fof;
use crate::geometry::inflate::{inflate_to_fof, InflateParams};
use crate::geometry::mesh::TriMesh;
use crate::geometry::raster::rasterize;
use crate::io::mesh_io::TexturedMesh;
use crate::io::npy::write_atomic;
use crate::neural::{ExecutionProvider, RuntimeOptions};
use crate::pipeline::input::NormalisedInput;
use crate::pipeline::warp::OcclusionFill;
use crate::pipeline::{
    compute_geometry, load_body, load_fof_net, load_renderer, GeometryMode, PrepareOptions, PreparedInput,
    RendererChoice, SharedBody, SharedFofNet, SharedNeural, StageTimings, ViewRenderer,
};
use crate::synth::framing::{self, Framing, FramingChoice};
use crate::synth::{self, SubjectParams, SynthAssets};

/// Options of [`run_eval`] (the CLI's `r2human eval` flags).
#[derive(Clone, Debug, PartialEq)]
pub struct EvalOptions {
    /// Synthetic subjects (`--subjects`).
    pub subjects: usize,
    /// Seed (`--seed`), as for the dataset writer.
    pub seed: u64,
    /// Output folder (`--out`).
    pub out: PathBuf,
    /// User scans (`--scan FILE`, repeatable).
    pub scans: Vec<PathBuf>,
    /// How the scans are turned upright and toward the camera (`--up`, `--facing`; detected when unset).
    pub scan_orientation: synth::scan::ScanOrientation,
    /// Image side (512 like the reference).
    pub size: usize,
    /// Target view yaws in degrees (pitch 0). The input view itself (yaw 0) is not a novel view and is not scored
    /// by default: every method reproduces it up to silhouette edges, and a perfect view has infinite PSNR.
    pub yaws: Vec<f32>,
    /// Texture side of synthetic subjects.
    pub texture_size: usize,
    /// Write each view's ground truth and every method's rendering to `out/views/<subject>/` (sRGB PNGs over
    /// black, as scored).
    pub save_views: bool,
    /// Framing of the synthetic subjects (`--framing`; mixed: full, three-quarter and upper in turn). Each framing
    /// is its own input set in the report (`synthetic/full`, `synthetic/three-quarter`, `synthetic/upper`).
    pub framing: FramingChoice,
}

/// How [`run_eval_with`] runs the network methods (5, 6: the neural renderer; 7, 8: the FOF net).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NeuralEvalOptions {
    /// Model folder; `None`: the project's `models/tiny` when found.
    pub models: Option<PathBuf>,
    /// Leave the network methods out (the neural renderer's, the FOF net's and the body prior's rows).
    pub skip: bool,
    /// Execution provider.
    pub ep: ExecutionProvider,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            subjects: 8,
            seed: 0,
            out: PathBuf::from("eval"),
            scans: Vec::new(),
            scan_orientation: Default::default(),
            size: 512,
            yaws: vec![20.0, 45.0, 90.0, 135.0, 180.0, 225.0, 270.0, 315.0],
            texture_size: 1024,
            save_views: false,
            framing: FramingChoice::Mixed,
        }
    }
}

/// The methods compared.
pub const METHODS: [&str; 14] = [
    "billboard",
    "2.5d",
    "geometric+inflation",
    "geometric+gt-fof",
    "neural+inflation",
    "neural+gt-fof",
    "geometric+fofnet",
    "neural+fofnet",
    "geometric+body",
    "neural+body",
    "geometric+body-placed",
    "neural+body-placed",
    "geometric+frame-path",
    "neural+frame-path",
];

/// The renderer-based methods (indices into [`METHODS`] from 2 on): which prepared geometry they draw (0 inflation,
/// 1 ground-truth FOF, 2 FOF net, 3 body prior, 4 the inflation prior placed by the body, 5 the frame path of a
/// live source as `view` prepares a frame, [`crate::pipeline::frame`]) and whether with the neural renderer.
const RENDERED: [(usize, bool); 12] = [
    (0, false),
    (1, false),
    (0, true),
    (1, true),
    (2, false),
    (2, true),
    (3, false),
    (3, true),
    (4, false),
    (4, true),
    (5, false),
    (5, true),
];

/// Depth samples per column for the volumetric geometry IoU of the report.
const IOU_DEPTH_SAMPLES: usize = 128;

/// One row of the report: a method on a view group.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ReportRow {
    /// The inputs averaged: `synthetic/<framing>` (the synthetic subjects of one framing) or a scan's name (its
    /// file stem).
    pub inputs: String,
    /// The inputs' framing: `full`, `three-quarter` or `upper` (scans are whole characters: `full`).
    pub framing: String,
    /// Method name (see [`METHODS`]).
    pub method: String,
    /// `close` (<= 45 deg) or `divergent` (>= 90 deg).
    pub group: String,
    /// Mean scores over the group's views: PSNR (dB, infinite values, i.e. identical views, skipped), PSNR over the
    /// pixels both the method and the ground truth cover (the appearance error alone, without the silhouette misses
    /// that dominate PSNR), SSIM, PSNR and SSIM over the whole frame on black (the paper's Table 2 convention,
    /// [`psnr_frame`], [`ssim_frame`]), mask IoU, depth L1 (body-cube units) on the union mask.
    #[serde(flatten)]
    pub scores: MeanScores,
    /// Median milliseconds per view.
    pub ms_per_view: f32,
    /// Median milliseconds per input (once per subject).
    pub ms_per_input: f32,
    /// Number of views averaged.
    pub views: usize,
    /// Peak memory the method needs on its own (MiB beyond what was resident before it: per-input work and one
    /// view, probed once on the first subject; [`super::memory::PhaseMemory`]). `None` where not measured.
    pub peak_mib: Option<f32>,
}

/// What [`run_eval`] produced.
#[derive(Clone, Debug, Default)]
pub struct EvalReport {
    /// The table.
    pub rows: Vec<ReportRow>,
    /// Subjects or scans that failed, with the reason.
    pub failed: Vec<(String, String)>,
    /// Peak resident memory of the process (MiB, from `/proc/self/status` VmHWM; 0 where unavailable).
    pub peak_memory_mib: f32,
    /// Views of the neural methods that the decoder failed on and the geometric renderer drew instead.
    pub neural_fallbacks: usize,
    /// Mean volumetric IoU (decoded occupancy at the 0.5 level) of each per-input geometry against the
    /// ground-truth FOF: `("inflation", iou)`, `("fofnet", iou)` when the FOF net ran, over the evaluated inputs.
    pub geometry_iou: Vec<(String, f32)>,
    /// The same per input set (`(inputs, geometry, mean iou)`, sets in report order): what
    /// [`super::scans::ScanSummary`] reads per scan.
    pub set_geometry_iou: Vec<(String, String, f32)>,
    /// Why rows are missing (methods skipped because a model did not load), for the report.
    pub notes: Vec<String>,
}

/// The scores of one method on one view group, view by view (means and medians are taken at the end).
#[derive(Default)]
pub(super) struct Acc {
    pub(super) psnr: Vec<f32>,
    pub(super) psnr_overlap: Vec<f32>,
    pub(super) ssim: Vec<f32>,
    pub(super) psnr_frame: Vec<f32>,
    pub(super) ssim_frame: Vec<f32>,
    pub(super) iou: Vec<f32>,
    pub(super) depth: Vec<f32>,
    pub(super) ms_view: Vec<f32>,
    pub(super) ms_input: Vec<f32>,
}

/// The means of an [`Acc`] over its views (a [`ReportRow`]'s scores).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MeanScores {
    /// Mean PSNR (dB) over the union of the masks.
    pub psnr: f32,
    /// Mean PSNR (dB) over the pixels both masks cover.
    pub psnr_overlap: f32,
    /// Mean SSIM over the union of the masks.
    pub ssim: f32,
    /// Mean PSNR (dB) over the whole frame on black.
    pub psnr_frame: f32,
    /// Mean SSIM over the whole frame on black.
    pub ssim_frame: f32,
    /// Mean mask IoU.
    pub mask_iou: f32,
    /// Mean depth L1 (body-cube units) on the union mask.
    pub depth_l1: f32,
}

impl Acc {
    /// The mean of every score (NaN where no view has a finite one).
    pub(super) fn means(&self) -> MeanScores {
        let m = mean;
        MeanScores {
            psnr: m(&self.psnr),
            psnr_overlap: m(&self.psnr_overlap),
            ssim: m(&self.ssim),
            psnr_frame: m(&self.psnr_frame),
            ssim_frame: m(&self.ssim_frame),
            mask_iou: m(&self.iou),
            depth_l1: m(&self.depth),
        }
    }
}

/// The median (the upper one of an even count; 0 when empty).
pub(super) fn median(v: &[f32]) -> f32 {
    if v.is_empty() {
        return 0.0;
    }
    let mut s = v.to_vec();
    s.sort_by(f32::total_cmp);
    s[s.len() / 2]
}

/// The mean of the finite values (NaN when there is none).
pub(super) fn mean(v: &[f32]) -> f32 {
    let f: Vec<f32> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if f.is_empty() {
        f32::NAN
    } else {
        f.iter().sum::<f32>() / f.len() as f32
    }
}

/// A method's rendering of one view.
pub(super) struct Prediction {
    rgba: RgbaImage,
    mask: Vec<bool>,
    depth: Vec<f32>,
}

impl Prediction {
    /// A renderer's person layer seen by `cam`, with the depth of the geometry it drew (`mesh`, rasterised again:
    /// not part of a timed rendering).
    pub(super) fn of_person(person: RgbaImage, mesh: &TriMesh, cam: &Camera) -> Self {
        let gb = rasterize(mesh, cam);
        let mask: Vec<bool> = person.data.iter().map(|p| p.w > 0.5).collect();
        let depth = gb.depth.iter().zip(&gb.mask).map(|(&d, &c)| if c { d } else { -1.0 }).collect();
        Self { rgba: person, mask, depth }
    }

    /// The rendering (premultiplied linear RGBA).
    pub(super) fn rgba(&self) -> &RgbaImage {
        &self.rgba
    }
}

/// The cut-out on the plane z = 0 seen by `cam`.
fn billboard(rgb: &RgbImage, mask: &GrayImage, cam: &Camera) -> Prediction {
    let (w, h) = (cam.width, cam.height);
    let src = Camera::source(rgb.width);
    let mut rgba = RgbaImage::new(w, h, Vec4::ZERO);
    let mut m = vec![false; w * h];
    let mut depth = vec![-1.0; w * h];
    let rays = cam.ray_grid();
    for row in 0..h {
        for col in 0..w {
            let ray = rays.ray(col as f32 + 0.5, row as f32 + 0.5);
            if ray.direction.z.abs() < 1e-6 {
                continue;
            }
            let t = -ray.origin.z / ray.direction.z;
            let p = ray.origin + t * ray.direction;
            let Some(q) = src.project(p) else { continue };
            // `sample_bilinear` takes continuous pixel coordinates (centres at +0.5), as `project` returns them.
            let a = crate::buffer::sample_bilinear(mask, q.x, q.y, 0.0);
            if a > 0.5 {
                let c = crate::buffer::sample_bilinear(rgb, q.x, q.y, Vec3::ZERO);
                let i = row * w + col;
                rgba.data[i] = (c / a.max(1e-6)).min(Vec3::ONE).extend(1.0);
                m[i] = true;
                depth[i] = cam.view_from_world.transform_point3(p).z;
            }
        }
    }
    Prediction { rgba, mask: m, depth }
}

/// The front surface of a source depth map as a coloured grid mesh (quads between covered neighbours whose depth
/// differs by less than `max_step`).
fn depth_mesh(depth: &[f32], covered: &[bool], rgb: &RgbImage, mask: &GrayImage, max_step: f32) -> TriMesh {
    let (w, h) = (rgb.width, rgb.height);
    let src = Camera::source(w);
    let mut index = vec![u32::MAX; w * h];
    let mut positions = Vec::new();
    let mut colors = Vec::new();
    for row in 0..h {
        for col in 0..w {
            let i = row * w + col;
            if covered[i] {
                index[i] = positions.len() as u32;
                positions.push(src.unproject(col as f32 + 0.5, row as f32 + 0.5, depth[i]));
                colors.push((rgb.data[i] / mask.data[i].max(1e-3)).min(Vec3::ONE));
            }
        }
    }
    let mut triangles = Vec::new();
    for row in 0..h.saturating_sub(1) {
        for col in 0..w.saturating_sub(1) {
            let q = [row * w + col, row * w + col + 1, (row + 1) * w + col + 1, (row + 1) * w + col];
            if q.iter().any(|&i| index[i] == u32::MAX) {
                continue;
            }
            let d = q.map(|i| depth[i]);
            let (lo, hi) = d.iter().fold((f32::MAX, f32::MIN), |(a, b), &x| (a.min(x), b.max(x)));
            if hi - lo > max_step {
                continue;
            }
            // Counter-clockwise seen from +z (image rows go down).
            triangles.push([index[q[0]], index[q[3]], index[q[2]]]);
            triangles.push([index[q[0]], index[q[2]], index[q[1]]]);
        }
    }
    let mut m = TriMesh::new(positions, triangles);
    m.colors = colors;
    m
}

fn raster_prediction(mesh: &TriMesh, cam: &Camera) -> Prediction {
    let g = rasterize(mesh, cam);
    let n = g.width * g.height;
    let mut rgba = RgbaImage::new(g.width, g.height, Vec4::ZERO);
    let mut depth = vec![-1.0; n];
    for i in 0..n {
        if g.mask[i] {
            let c = g.color.as_ref().map(|c| c[i]).unwrap_or(Vec3::splat(0.7));
            rgba.data[i] = c.extend(1.0);
            depth[i] = g.depth[i];
        }
    }
    Prediction { rgba, mask: g.mask, depth }
}

/// Volumetric IoU of two FOFs of the same grid: occupancy decoded at `samples` depths per column, thresholded at
/// the marching-cubes level; 1 when both are empty.
pub fn fof_occupancy_iou(a: &Fof, b: &Fof, samples: usize) -> f32 {
    if (a.width, a.height, a.n) != (b.width, b.height, b.n) || samples == 0 {
        return 0.0;
    }
    let table = crate::geometry::fof::CosineTable::new(a.n, samples);
    let level = crate::geometry::marching::ISO_LEVEL;
    let (inter, union) = (0..a.height)
        .into_par_iter()
        .map(|row| {
            let (mut inter, mut union) = (0u64, 0u64);
            let (mut oa, mut ob) = (vec![0.0f32; samples], vec![0.0f32; samples]);
            for col in 0..a.width {
                if a.is_empty_column(col, row) && b.is_empty_column(col, row) {
                    continue;
                }
                a.decode_column_with(&table, col, row, &mut oa);
                b.decode_column_with(&table, col, row, &mut ob);
                for (x, y) in oa.iter().zip(&ob) {
                    let (x, y) = (*x >= level, *y >= level);
                    inter += (x && y) as u64;
                    union += (x || y) as u64;
                }
            }
            (inter, union)
        })
        .reduce(|| (0, 0), |p, q| (p.0 + q.0, p.1 + q.1));
    if union == 0 {
        1.0
    } else {
        inter as f32 / union as f32
    }
}

/// The accumulators of every method and group.
type MethodAcc = [[Acc; 2]; METHODS.len()];

/// The per-input volumetric IoUs of the predicted geometries, in the order of [`GEOMETRIES`].
type GeometryIou = [Vec<f32>; 5];

/// The predicted geometries whose volumetric IoU the report gives (the oracle's is 1 by construction).
pub const GEOMETRIES: [&str; 5] = ["inflation", "fofnet", "body", "body-placed", "frame-path"];

/// `(geometry, mean IoU)` of the geometries measured at least once.
fn geometry_means(iou: &GeometryIou) -> impl Iterator<Item = (String, f32)> + '_ {
    GEOMETRIES.iter().zip(iou).filter(|(_, v)| !v.is_empty()).map(|(name, v)| (name.to_string(), mean(v)))
}

/// The networks the evaluation runs with (each `None` when its model did not load or `--no-neural`).
#[derive(Clone, Copy)]
struct Nets<'a> {
    neural: Option<&'a SharedNeural>,
    fof_net: Option<&'a SharedFofNet>,
    body: Option<&'a SharedBody>,
    /// The placement network of the body-placed rows (`None`: the confidence-aware placement of `body::placed`).
    placement: Option<&'a crate::pipeline::SharedPlacementNet>,
    /// The pose network that finds the face for the back image (the default fill's).
    back_pose: Option<&'a crate::pipeline::SharedPose>,
}

/// A subject's source view as every method receives it (ground-truth render, already in the body cube).
struct SubjectSource {
    rgb: RgbImage,
    mask: GrayImage,
    prepare: PrepareOptions,
}

impl SubjectSource {
    fn of(mesh: &TexturedMesh, size: usize, nets: Nets<'_>) -> Self {
        let gt_src = render_ground_truth(mesh, &Camera::source(size));
        let rgb: RgbImage = gt_src.to_linear_rgba().map(|p| p.truncate());
        let prepare = PrepareOptions {
            resolution: size,
            depth_samples: size,
            back_pose: nets.back_pose.cloned(),
            ..Default::default()
        };
        Self { rgb, mask: gt_src.mask_image(), prepare }
    }

    fn normalised(&self) -> NormalisedInput {
        NormalisedInput::in_source_view(self.rgb.clone(), self.mask.clone())
    }

    /// The source view prepared as `render` prepares a photo with `o` (geometry, and the back image).
    fn prepared_with(&self, o: &PrepareOptions) -> Result<PreparedInput, crate::pipeline::PipelineError> {
        let mut timings = StageTimings::default();
        let fof = compute_geometry(&self.normalised(), o, &mut timings)?;
        PreparedInput::from_fof(self.normalised(), fof, o, timings)
    }

    /// Per-input geometry `kind` (0 inflation prior, 1 ground-truth FOF, 2 FOF net, 3 body prior, 4 body-placed
    /// inflation prior, 5 the frame path with the geometry live frames draw); `None` for the FOF net when it is not loaded or fails on this input (logged: its rows skip
    /// the subject, never replaced by the prior), and for the body geometries when the body prior is not loaded (an
    /// input where it finds no pose falls back to the inflation prior, as `--geometry body` does).
    fn geometry(
        &self,
        kind: usize,
        mesh: &TexturedMesh,
        nets: Nets<'_>,
        name: &str,
    ) -> Result<Option<PreparedInput>, EvalError> {
        let fof_net = nets.fof_net;
        let popts = &self.prepare;
        let which = if kind == 0 { "inflation prior" } else { "ground-truth FOF" };
        let fof = match kind {
            0 => {
                // Placed in depth like every pipeline geometry (its centroid is at z = 0 by symmetry already).
                let frame = crate::body::prior::effective_frame(&self.mask, None);
                let fof = inflate_to_fof(&self.mask, popts.fof_order, &InflateParams::default(), Some(frame))
                    .map_err(|e| EvalError::stage(which, e))?;
                crate::geometry::depth_centre::centre_fof(fof).0
            }
            1 => {
                Fof::from_mesh(&mesh.mesh, self.mask.width, popts.fof_order).map_err(|e| EvalError::stage(which, e))?
            }
            3 | 4 => {
                let Some(body) = nets.body else { return Ok(None) };
                let o = PrepareOptions {
                    geometry: if kind == 3 { GeometryMode::Body } else { GeometryMode::BodyPlaced },
                    body: Some(std::sync::Arc::clone(body)),
                    placement: nets.placement.cloned(),
                    ..popts.clone()
                };
                let built = self.prepared_with(&o);
                return Ok(built.map_err(|e| tracing::warn!("{name}: the body rows skip this subject: {e}")).ok());
            }
            5 => {
                // A live frame's preparation: `--geometry auto` on frames, with the models it may need.
                let o = PrepareOptions {
                    geometry: GeometryMode::Auto,
                    body: nets.body.cloned(),
                    placement: nets.placement.cloned(),
                    ..popts.clone()
                };
                let built = crate::pipeline::frame::FramePath::new(o)
                    .prepare_normalised(self.normalised(), StageTimings::default());
                return Ok(built
                    .map_err(|e| tracing::warn!("{name}: the frame-path rows skip this subject: {e}"))
                    .ok());
            }
            _ => {
                let Some(net) = fof_net else { return Ok(None) };
                let o = PrepareOptions {
                    geometry: GeometryMode::FofNet,
                    fof_net: Some(std::sync::Arc::clone(net)),
                    body: nets.body.cloned(),
                    ..popts.clone()
                };
                let built = self.prepared_with(&o);
                return Ok(built.map_err(|e| tracing::warn!("{name}: the FOF net rows skip this subject: {e}")).ok());
            }
        };
        PreparedInput::from_fof(self.normalised(), fof, popts, Default::default())
            .map(Some)
            .map_err(|e| EvalError::stage(which, e))
    }
}

/// The renderer of a renderer-based method on prepared geometry `p`: geometric, or neural when the encoder ran on
/// `p` (a failing encoder skips the subject's neural rows; no geometric stand-in is ever scored as neural).
fn method_renderer<'a>(
    p: &'a PreparedInput,
    is_neural: bool,
    neural: Option<&SharedNeural>,
) -> Option<ViewRenderer<'a>> {
    if !is_neural {
        return Some(ViewRenderer::new(p, OcclusionFill::default(), false));
    }
    let n = neural?;
    match n.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).encode(p) {
        Ok(e) => Some(ViewRenderer::with_neural(p, OcclusionFill::default(), false, std::sync::Arc::clone(n), e)),
        Err(e) => {
            tracing::warn!("neural encoder failed, the neural rows skip this subject: {e}");
            None
        }
    }
}

/// Peak memory each method needs on its own (MiB beyond what was resident before it; [`PhaseMemory`]): its
/// per-input work and one view at `yaw`, everything dropped before the next method. `None` for a method that did
/// not run, or where the kernel's peak counter cannot be reset.
fn method_memory(
    mesh: &TexturedMesh,
    opts: &EvalOptions,
    nets: Nets<'_>,
    yaw: f32,
) -> Result<[Option<f32>; METHODS.len()], EvalError> {
    let src = SubjectSource::of(mesh, opts.size, nets);
    let cam = Camera::orbit(yaw, 0.0, opts.size, opts.size);
    let mut out = [None; METHODS.len()];
    for (m, slot) in out.iter_mut().enumerate() {
        let Some(start) = PhaseMemory::start() else { return Ok(out) };
        let ran = match m {
            0 => {
                std::hint::black_box(billboard(&src.rgb, &src.mask, &cam));
                true
            }
            1 => {
                let p = src.geometry(0, mesh, nets, "memory probe")?.expect("the inflation prior always exists");
                let g = &p.source_gbuffer;
                let front = depth_mesh(&g.depth, &g.mask, &src.rgb, &src.mask, 0.03);
                std::hint::black_box(raster_prediction(&front, &cam));
                true
            }
            _ => {
                let (kind, is_neural) = RENDERED[m - 2];
                match src.geometry(kind, mesh, nets, "memory probe")? {
                    Some(p) => match method_renderer(&p, is_neural, nets.neural) {
                        Some(mut r) => r.render_person(&cam).map(std::hint::black_box).is_ok(),
                        None => false,
                    },
                    None => false,
                }
            }
        };
        *slot = start.finish().filter(|_| ran).map(|p| p.extra_mib());
    }
    Ok(out)
}

/// Evaluates one subject; pushes into the accumulators `[method][group]`, the geometry IoUs (inflation, FOF net)
/// and counts neural fallbacks.
fn eval_subject(
    name: &str,
    mesh: &TexturedMesh,
    opts: &EvalOptions,
    nets: Nets<'_>,
    acc: &mut MethodAcc,
    geometry_iou: &mut GeometryIou,
    fallbacks: &mut usize,
) -> Result<(), EvalError> {
    let r = opts.size;
    let src = SubjectSource::of(mesh, r, nets);
    let (rgb, mask) = (&src.rgb, &src.mask);
    let perr = |e: crate::pipeline::PipelineError| EvalError::stage("rendering", e);

    // Per-input work, timed per method.
    let t = Instant::now();
    let inflated = src.geometry(0, mesh, nets, name)?.expect("the inflation prior always exists");
    let ms_inflate = t.elapsed().as_secs_f32() * 1e3;
    let t = Instant::now();
    let g = &inflated.source_gbuffer;
    let front = depth_mesh(&g.depth, &g.mask, rgb, mask, 0.03);
    let ms_25d = ms_inflate + t.elapsed().as_secs_f32() * 1e3;
    let t = Instant::now();
    let oracle = src.geometry(1, mesh, nets, name)?.expect("the ground-truth FOF always exists");
    let ms_oracle = t.elapsed().as_secs_f32() * 1e3;
    // The FOF net's geometry (explicit mode: a network failure on this input is an error of this subject's FOF
    // rows, reported in the log, never silently replaced by the prior).
    let t = Instant::now();
    let with_net = src.geometry(2, mesh, nets, name)?;
    let ms_fofnet = t.elapsed().as_secs_f32() * 1e3;
    // The body prior's geometry (pose landmarks, fit, body FOF).
    let t = Instant::now();
    let with_body = src.geometry(3, mesh, nets, name)?;
    let ms_body = t.elapsed().as_secs_f32() * 1e3;
    // The inflation prior placed in depth by the body (pose landmarks and fit again: timed on its own).
    let t = Instant::now();
    let with_placed = src.geometry(4, mesh, nets, name)?;
    let ms_placed = t.elapsed().as_secs_f32() * 1e3;
    // A live frame through the frame path (mesh and source view straight from the depth maps).
    let t = Instant::now();
    let with_frame = src.geometry(5, mesh, nets, name)?;
    let ms_frame = t.elapsed().as_secs_f32() * 1e3;
    // Every geometry here takes the still path, which keeps its FOF.
    let Some(oracle_fof) = oracle.fof.as_ref() else { return Err(EvalError::stage("ground-truth FOF", "missing")) };
    // The frame path keeps depth maps: their FOF ([`PreparedInput::fof_with`]) is measured the same way.
    let with_fof = [
        (0, Some(&inflated)),
        (1, with_net.as_ref()),
        (2, with_body.as_ref()),
        (3, with_placed.as_ref()),
        (4, with_frame.as_ref()),
    ];
    for (slot, p) in with_fof {
        if let Some(fof) = p.and_then(|p| p.fof_with(oracle_fof.n)) {
            geometry_iou[slot].push(fof_occupancy_iou(&fof, oracle_fof, IOU_DEPTH_SAMPLES));
        }
    }
    // Methods 3..14: geometric and neural renderers on the inflation, oracle, FOF-net, body-prior, body-placed and
    // frame-path geometry.
    let prepared: [Option<&PreparedInput>; 6] = [
        Some(&inflated),
        Some(&oracle),
        with_net.as_ref(),
        with_body.as_ref(),
        with_placed.as_ref(),
        with_frame.as_ref(),
    ];
    let mut renderers: Vec<Option<ViewRenderer<'_>>> = RENDERED
        .iter()
        .map(|&(k, is_neural)| prepared[k].and_then(|p| method_renderer(p, is_neural, nets.neural)))
        .collect();
    let encode_ms = |k: usize| renderers[k].as_ref().and_then(|r| r.encode_time()).map(|d| d.as_secs_f32() * 1e3);
    let fofnet_ms = with_net.as_ref().map(|_| ms_fofnet);
    let body_ms = with_body.as_ref().map(|_| ms_body);
    let placed_ms = with_placed.as_ref().map(|_| ms_placed);
    let frame_ms = with_frame.as_ref().map(|_| ms_frame);
    let per_input = [
        Some(0.0),
        Some(ms_25d),
        Some(ms_inflate),
        Some(ms_oracle),
        encode_ms(2).map(|e| ms_inflate + e),
        encode_ms(3).map(|e| ms_oracle + e),
        fofnet_ms,
        encode_ms(5).and_then(|e| fofnet_ms.map(|f| f + e)),
        body_ms,
        encode_ms(7).and_then(|e| body_ms.map(|f| f + e)),
        placed_ms,
        encode_ms(9).and_then(|e| placed_ms.map(|f| f + e)),
        frame_ms,
        encode_ms(11).and_then(|e| frame_ms.map(|f| f + e)),
    ];
    for (a, ms) in acc.iter_mut().zip(per_input) {
        for g in a.iter_mut() {
            g.ms_input.extend(ms);
        }
    }

    // Saved views (`--save-views`): one folder per subject, made once.
    let views_dir = match opts.save_views {
        true => {
            let dir = opts.out.join("views").join(name);
            std::fs::create_dir_all(&dir).map_err(|e| EvalError::io(&dir, e))?;
            Some(dir)
        }
        false => None,
    };
    for &yaw in &opts.yaws {
        let cam = Camera::orbit(yaw, 0.0, r, r);
        let angle = cam.angle_from_source().to_degrees();
        let group = if angle <= 45.0 + 1e-3 {
            0
        } else if angle >= 90.0 - 1e-3 {
            1
        } else {
            continue;
        };
        let gt = render_ground_truth(mesh, &cam);
        let save = |label: &str, img: &RgbaImage| -> Result<(), EvalError> {
            let Some(dir) = &views_dir else { return Ok(()) };
            let path = dir.join(format!("yaw{:03}_{}.png", yaw.round() as i32, label.replace('+', "_")));
            let over_black = crate::io::image_io::over_background(img, Vec3::ZERO);
            crate::io::image_io::save_rgb_png(&path, &over_black)
                .map_err(|e| EvalError::io(&path, std::io::Error::other(e)))
        };
        save("ground_truth", &gt.to_linear_rgba())?;
        for (m, acc_m) in acc.iter_mut().enumerate() {
            let t = Instant::now();
            let pred = match m {
                0 => billboard(rgb, mask, &cam),
                1 => raster_prediction(&front, &cam),
                _ => {
                    let k = m - 2;
                    let Some(renderer) = renderers[k].as_mut() else { continue };
                    let Some(geometry) = prepared[RENDERED[k].0] else { continue };
                    let before = renderer.neural_fallbacks();
                    let person = renderer.render_person(&cam).map_err(perr)?;
                    let ms = t.elapsed().as_secs_f32() * 1e3;
                    *fallbacks += renderer.neural_fallbacks() - before;
                    // Depth of the method's own geometry (not part of the timed rendering).
                    let pred = Prediction::of_person(person, &geometry.mesh, &cam);
                    save(METHODS[m], &pred.rgba)?;
                    score(&gt, &pred, &mut acc_m[group], ms);
                    continue;
                }
            };
            let ms = t.elapsed().as_secs_f32() * 1e3;
            save(METHODS[m], &pred.rgba)?;
            score(&gt, &pred, &mut acc_m[group], ms);
        }
    }
    Ok(())
}

/// Scores `pred` against `gt` into `acc` (every metric of the report), with `ms` as its time.
pub(super) fn score(gt: &GroundTruthView, pred: &Prediction, acc: &mut Acc, ms: f32) {
    let a = SrgbImage::from_linear_premultiplied(&gt.to_linear_rgba());
    let b = SrgbImage::from_linear_premultiplied(&pred.rgba);
    let region = union_mask(&gt.mask, &pred.mask);
    acc.psnr.push(psnr(&a, &b, &region));
    let overlap: Vec<bool> = gt.mask.iter().zip(&pred.mask).map(|(&x, &y)| x && y).collect();
    acc.psnr_overlap.push(psnr(&a, &b, &overlap));
    acc.ssim.push(ssim(&a, &b, &region));
    acc.psnr_frame.push(psnr_frame(&a, &b));
    acc.ssim_frame.push(ssim_frame(&a, &b));
    acc.iou.push(mask_iou(&gt.mask, &pred.mask));
    acc.depth.push(depth_l1(&gt.depth, &gt.mask, &pred.depth, &pred.mask));
    acc.ms_view.push(ms);
}

/// The networks of the evaluation as `nopts` asks: the neural renderer (`auto` semantics: one warning and `None`
/// when its models do not load) and the folder's FOF net (explicit mode, so the reason it does not load is
/// reported). Why a network is missing goes into `notes` for the report.
pub(super) fn load_networks(
    nopts: &NeuralEvalOptions,
    notes: &mut Vec<String>,
) -> (Option<SharedNeural>, Option<SharedFofNet>) {
    // Methods 5, 6 and 8: `auto` semantics (one warning and no neural rows when the models do not load).
    let options = RuntimeOptions { ep: nopts.ep, ..Default::default() };
    let neural = if nopts.skip {
        None
    } else {
        load_renderer(RendererChoice::Auto, nopts.models.as_deref(), &options).unwrap_or(None)
    };
    // Methods 7 and 8: the folder's fof.onnx (explicit mode, so the reason it does not load can be reported).
    let fof_net = if nopts.skip {
        notes.push("Network methods left out (--no-neural): no neural, FOF-net or body-prior rows.".to_string());
        None
    } else {
        match load_fof_net(GeometryMode::FofNet, nopts.models.as_deref(), PrepareOptions::default().fof_order, &options)
        {
            Ok(net) => net,
            Err(e) => {
                tracing::warn!("the FOF-net rows (geometric+fofnet, neural+fofnet) are skipped: {e}");
                notes.push(format!("The FOF-net rows (geometric+fofnet, neural+fofnet) are skipped: {e}"));
                None
            }
        }
    };
    if !nopts.skip && neural.is_none() {
        notes.push("The neural renderer's models did not load: no neural rows (see the log).".to_string());
    }
    (neural, fof_net)
}

/// The body prior for the `geometric+body` and `neural+body` rows: the pose model through ONNX Runtime and the
/// MakeHuman body data. Left out with `--no-neural` (it runs a network) or when it does not load (noted).
fn load_body_prior(nopts: &NeuralEvalOptions, notes: &mut Vec<String>) -> Option<SharedBody> {
    if nopts.skip {
        return None;
    }
    let options = RuntimeOptions { ep: nopts.ep, ..Default::default() };
    match load_body(GeometryMode::Body, &options) {
        Ok(body) => body,
        Err(e) => {
            tracing::warn!("the body-prior rows (geometric+body, neural+body) are skipped: {e}");
            notes.push(format!("The body-prior rows (geometric+body, neural+body) are skipped: {e}"));
            None
        }
    }
}

/// The placement network of the body-placed rows: the model folder's `placement.onnx` when it has one (noted in
/// the report either way, so its rows say which placement they measure); a file that does not load is noted and
/// the rows take the confidence-aware placement instead.
pub(super) fn load_placement(
    nopts: &NeuralEvalOptions,
    notes: &mut Vec<String>,
) -> Option<crate::pipeline::SharedPlacementNet> {
    if nopts.skip {
        return None;
    }
    let options = RuntimeOptions { ep: nopts.ep, ..Default::default() };
    let fof_order = PrepareOptions::default().fof_order;
    match crate::pipeline::load_placement_net(GeometryMode::BodyPlaced, nopts.models.as_deref(), fof_order, &options) {
        Ok(Some(net)) => {
            let path = net.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).path().display().to_string();
            notes.push(format!("The body-placed rows place each column by the placement network `{path}`."));
            Some(net)
        }
        Ok(None) => {
            notes.push(format!(
                "The body-placed rows move each column toward the fitted body's depth as far as the fit is trusted there \
                 (body::placed::placement_confidence), with the face relief (no {} in the model folder).",
                crate::neural::PLACEMENT_FILE
            ));
            None
        }
        Err(e) => {
            let cause = std::error::Error::source(&e).map(|c| format!(" ({c})")).unwrap_or_default();
            tracing::warn!("the body-placed rows take the confidence-aware placement: {e}{cause}");
            notes.push(format!("The body-placed rows take the confidence-aware placement: {e}{cause}"));
            None
        }
    }
}

/// Runs the evaluation and writes `report.md`, `report.csv` and `error_vs_time.png` into `opts.out`. Subjects
/// and scans that fail are reported (in the summary and the Markdown) and skipped. The neural methods use the
/// project's `models/tiny` when they load ([`run_eval_with`] chooses).
pub fn run_eval(opts: &EvalOptions) -> Result<EvalReport, EvalError> {
    run_eval_with(opts, &NeuralEvalOptions::default())
}

/// [`run_eval`] with explicit settings for the neural methods.
pub fn run_eval_with(opts: &EvalOptions, nopts: &NeuralEvalOptions) -> Result<EvalReport, EvalError> {
    if opts.subjects == 0 && opts.scans.is_empty() {
        return Err(EvalError::InvalidOptions("nothing to evaluate: give --subjects N or --scan FILE".into()));
    }
    if !(32..=2048).contains(&opts.size) {
        return Err(EvalError::InvalidOptions(format!("--size {} must be within 32..=2048", opts.size)));
    }
    std::fs::create_dir_all(&opts.out).map_err(|e| EvalError::io(&opts.out, e))?;
    // One set of accumulators (methods, geometry IoUs) per input set: the synthetic subjects of one framing
    // together, each scan on its own.
    let mut sets: Vec<(String, MethodAcc, GeometryIou)> = Vec::new();
    let mut failed = Vec::new();
    let mut notes = Vec::new();
    let mut fallbacks = 0;
    let (neural, fof_net) = load_networks(nopts, &mut notes);
    let body = load_body_prior(nopts, &mut notes);
    let options = RuntimeOptions { ep: nopts.ep, ..Default::default() };
    let back_pose = crate::pipeline::load_back_pose(OcclusionFill::default(), &options);
    let placement = load_placement(nopts, &mut notes);
    let nets = Nets {
        neural: neural.as_ref(),
        fof_net: fof_net.as_ref(),
        body: body.as_ref(),
        placement: placement.as_ref(),
        back_pose: back_pose.as_ref(),
    };
    // Per-method memory, probed once on the first subject that evaluates (at the most divergent view scored).
    let probe_yaw = opts.yaws.iter().copied().max_by(|a, b| {
        let off = |y: f32| (y.rem_euclid(360.0) - 180.0).abs();
        off(*b).total_cmp(&off(*a))
    });
    let mut memory: Option<[Option<f32>; METHODS.len()]> = None;
    let probe_once = |memory: &mut Option<[Option<f32>; METHODS.len()]>, mesh: &TexturedMesh| {
        if memory.is_none() {
            *memory = Some(method_memory(mesh, opts, nets, probe_yaw.unwrap_or(180.0))?);
        }
        Ok(())
    };
    if opts.subjects > 0 {
        // One input set per framing actually used (a crop that does not fit the cube falls back to a wider one).
        let assets = SynthAssets::shared()?;
        for i in 0..opts.subjects {
            let name = format!("subject_{i:04}");
            let seed = super::dataset::subject_seed(opts.seed, i);
            let r = synth::generate(assets, &SubjectParams::sample(seed), opts.texture_size)
                .and_then(|s| framing::crop(&s, opts.framing.of(i), &assets.rig))
                .map_err(EvalError::from)
                .and_then(|s| {
                    let set = format!("synthetic/{}", s.crop.framing.label());
                    let k = sets.iter().position(|x| x.0 == set).unwrap_or_else(|| {
                        sets.push((set, Default::default(), Default::default()));
                        sets.len() - 1
                    });
                    let (_, acc, iou) = &mut sets[k];
                    eval_subject(&name, &s.mesh, opts, nets, acc, iou, &mut fallbacks)?;
                    probe_once(&mut memory, &s.mesh)
                });
            if let Err(e) = r {
                failed.push((name, e.to_string()));
            }
        }
        let order = |set: &str| Framing::ALL.iter().position(|f| set.ends_with(f.label()));
        sets.sort_by_key(|(set, _, _)| order(set));
    }
    for scan in &opts.scans {
        let stem = scan.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "scan".into());
        // Two scans with the same file name keep separate rows.
        let mut name = stem.clone();
        for k in 2.. {
            if !sets.iter().any(|(n, _, _)| *n == name) {
                break;
            }
            name = format!("{stem} ({k})");
        }
        tracing::debug!("eval: scan {name}");
        let mut acc = MethodAcc::default();
        let mut iou = GeometryIou::default();
        let r = synth::scan::load_scan_with(scan, &opts.scan_orientation).map_err(EvalError::from).and_then(|s| {
            eval_subject(&name, &s.mesh, opts, nets, &mut acc, &mut iou, &mut fallbacks)?;
            probe_once(&mut memory, &s.mesh)
        });
        match r {
            Ok(()) => sets.push((name, acc, iou)),
            Err(e) => failed.push((scan.display().to_string(), e.to_string())),
        }
    }
    let mut rows = Vec::new();
    for ((set, acc, _), (m, name)) in sets.iter().flat_map(|s| std::iter::repeat(s).zip(METHODS.iter().enumerate())) {
        for (g, group) in ["close", "divergent"].iter().enumerate() {
            let a = &acc[m][g];
            if a.psnr.is_empty() {
                continue;
            }
            rows.push(ReportRow {
                inputs: set.clone(),
                framing: set.strip_prefix("synthetic/").unwrap_or(Framing::Full.label()).to_string(),
                method: name.to_string(),
                group: group.to_string(),
                scores: a.means(),
                ms_per_view: median(&a.ms_view),
                ms_per_input: median(&a.ms_input),
                views: a.psnr.len(),
                peak_mib: memory.and_then(|per_method| per_method[m]),
            });
        }
    }
    if rows.is_empty() {
        let first = failed.first().map(|f| format!("{}: {}", f.0, f.1)).unwrap_or_else(|| "no view in a group".into());
        return Err(EvalError::AllFailed(first));
    }
    // Over every input, then per input set.
    let all: GeometryIou = std::array::from_fn(|g| sets.iter().flat_map(|s| s.2[g].iter().copied()).collect());
    let geometry_iou = geometry_means(&all).collect();
    let set_geometry_iou =
        sets.iter().flat_map(|(set, _, iou)| geometry_means(iou).map(move |(g, v)| (set.clone(), g, v))).collect();
    let report = EvalReport {
        rows,
        failed,
        peak_memory_mib: process_peak_mib().unwrap_or(0.0),
        neural_fallbacks: fallbacks,
        geometry_iou,
        set_geometry_iou,
        notes,
    };
    write_reports(&opts.out, opts, &report)?;
    Ok(report)
}

fn write_reports(out: &Path, opts: &EvalOptions, rep: &EvalReport) -> Result<(), EvalError> {
    let mut csv = String::from(
        "method,group,psnr,ssim,lpips,mask_iou,depth_l1,ms_per_view,ms_per_input,views,psnr_overlap,peak_mib,\
         psnr_frame,ssim_frame,inputs,framing\n",
    );
    let mib = |r: &ReportRow| r.peak_mib.map(|m| format!("{m:.0}")).unwrap_or_default();
    for r in &rep.rows {
        csv.push_str(&format!(
            "{},{},{:.3},{:.4},,{:.4},{:.4},{:.2},{:.2},{},{:.3},{},{:.3},{:.4},\"{}\",{}\n",
            r.method,
            r.group,
            r.scores.psnr,
            r.scores.ssim,
            r.scores.mask_iou,
            r.scores.depth_l1,
            r.ms_per_view,
            r.ms_per_input,
            r.views,
            r.scores.psnr_overlap,
            mib(r),
            r.scores.psnr_frame,
            r.scores.ssim_frame,
            r.inputs.replace('"', "\"\""),
            r.framing
        ));
    }
    let p = out.join("report.csv");
    write_atomic(&p, csv.as_bytes()).map_err(|e| EvalError::io(&p, e))?;
    let mut md = format!(
        "# r2human eval\n\n{} synthetic subject(s) (seed {}), {} scan(s), {}x{} views at yaws {:?} (pitch 0).\n\n\
         Close = at most 45 degrees from the input view, divergent = at least 90 degrees. PSNR/SSIM on sRGB over \
         black, averaged over the union of predicted and true masks (a pixel only one of them covers counts against \
         black, so silhouette misses dominate); PSNR overlap: over the pixels both cover (appearance alone). SSIM \
         with an 11x11 Gaussian window (sigma 1.5), averaged over the union. **PSNR frame / SSIM frame**: the same \
         over the whole frame on black, the paper's Table 2 convention (R2Human on THuman2.0: close 26.92 dB / \
         0.9415, divergent 25.36 dB / 0.9221); the background both agree on counts as perfect, so these are higher \
         than the union figures by about 10 log10(frame / person area) dB. Depth L1 in body-cube units on the union \
         mask (uncovered = -1). LPIPS: not measured (needs \
         ImageNet-pretrained weights that cannot be fetched here). Times: median wall-clock ms on this machine, \
         CPU reference. Memory: the peak resident memory each method needs on its own beyond what was already \
         resident (its per-input work and one view, probed once on the first subject; ONNX Runtime's allocations \
         included); peak of the whole run: {:.0} MiB.\n",
        opts.subjects,
        opts.seed,
        opts.scans.len(),
        opts.size,
        opts.size,
        opts.yaws,
        rep.peak_memory_mib
    );
    let mut sets: Vec<&str> = Vec::new();
    for r in &rep.rows {
        if !sets.contains(&r.inputs.as_str()) {
            sets.push(&r.inputs);
        }
    }
    md.push_str(&at_a_glance(rep, &sets));
    for set in sets {
        let title = match set {
            set if set.starts_with("synthetic/") => {
                format!("Synthetic subjects, {} framing", set.trim_start_matches("synthetic/"))
            }
            scan => format!("Scan: {scan}"),
        };
        md.push_str(&format!(
            "\n## {title}\n\n\
             | method | group | PSNR | PSNR overlap | SSIM | PSNR frame | SSIM frame | mask IoU | depth L1 | ms/view | \
             ms/input | MiB | views |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|\n"
        ));
        for r in rep.rows.iter().filter(|r| r.inputs == set) {
            md.push_str(&format!(
                "| {} | {} | {:.2} | {:.2} | {:.4} | {:.2} | {:.4} | {:.4} | {:.4} | {:.1} | {:.1} | {} | {} |\n",
                r.method,
                r.group,
                r.scores.psnr,
                r.scores.psnr_overlap,
                r.scores.ssim,
                r.scores.psnr_frame,
                r.scores.ssim_frame,
                r.scores.mask_iou,
                r.scores.depth_l1,
                r.ms_per_view,
                r.ms_per_input,
                mib(r),
                r.views
            ));
        }
    }
    if !rep.geometry_iou.is_empty() {
        md.push_str(&format!(
            "\nGeometry alone: volumetric IoU of the per-input FOF's decoded occupancy (level {}, {} depth samples per \
             column, {}x{} grid) against the ground-truth FOF, mean over the inputs:\n\n| geometry | volumetric IoU |\n|---|---|\n",
            crate::geometry::marching::ISO_LEVEL,
            IOU_DEPTH_SAMPLES,
            opts.size,
            opts.size
        ));
        for (name, iou) in &rep.geometry_iou {
            md.push_str(&format!("| {name} | {iou:.4} |\n"));
        }
        // Per input set, when there are several.
        let mut sets: Vec<&str> = Vec::new();
        for (set, _, _) in &rep.set_geometry_iou {
            if !sets.contains(&set.as_str()) {
                sets.push(set);
            }
        }
        if sets.len() > 1 {
            md.push_str(&format!(
                "\nPer input set:\n\n| input set | {} |\n|---|{}\n",
                GEOMETRIES.join(" | "),
                "---|".repeat(GEOMETRIES.len())
            ));
            for set in sets {
                md.push_str(&format!("| {set} |"));
                for g in GEOMETRIES {
                    match rep.set_geometry_iou.iter().find(|(s, geometry, _)| s == set && geometry == g) {
                        Some((_, _, iou)) => md.push_str(&format!(" {iou:.4} |")),
                        None => md.push_str(" - |"),
                    }
                }
                md.push('\n');
            }
        }
    }
    if let Some(summary) = super::scans::ScanSummary::of(rep) {
        md.push_str(&summary.markdown());
        summary.write_csv(out)?;
    }
    for note in &rep.notes {
        md.push_str(&format!("\n{note}\n"));
    }
    if rep.neural_fallbacks > 0 {
        md.push_str(&format!(
            "\nThe neural decoder failed on {} view(s); the geometric renderer drew them (scored in the neural rows).\n",
            rep.neural_fallbacks
        ));
    }
    if !rep.failed.is_empty() {
        md.push_str("\n## Failed inputs\n\n");
        for (n, e) in &rep.failed {
            md.push_str(&format!("- {n}: {e}\n"));
        }
    }
    let p = out.join("report.md");
    write_atomic(&p, md.as_bytes()).map_err(|e| EvalError::io(&p, e))?;
    plot(&out.join("error_vs_time.png"), rep)
}

/// One number of a report row, as a column of [`at_a_glance`].
type RowValue = fn(&ReportRow) -> f32;

/// The oracle's method names contain this (it is left out when the best predicted geometry is marked).
pub(super) const ORACLE_TAG: &str = "gt-fof";

/// One table over every input set (`sets`, in order): per method, the paper's whole-frame PSNR at close and
/// divergent views and the divergent mask IoU; the best method without oracle geometry in each column is bold.
fn at_a_glance(rep: &EvalReport, sets: &[&str]) -> String {
    if sets.is_empty() {
        return String::new();
    }
    let mut methods: Vec<&str> = Vec::new();
    for r in &rep.rows {
        if !methods.contains(&r.method.as_str()) {
            methods.push(&r.method);
        }
    }
    let row = |set: &str, method: &str, group: &str| {
        rep.rows.iter().find(|r| r.inputs == set && r.method == method && r.group == group)
    };
    // Columns: per set, PSNR frame close, PSNR frame divergent, mask IoU divergent.
    let columns: Vec<(&str, &str, RowValue)> = sets
        .iter()
        .flat_map(|&set| {
            [
                (set, "close", (|r: &ReportRow| r.scores.psnr_frame) as RowValue),
                (set, "divergent", |r: &ReportRow| r.scores.psnr_frame),
                (set, "divergent", |r: &ReportRow| r.scores.mask_iou),
            ]
        })
        .collect();
    let best: Vec<f32> = columns
        .iter()
        .map(|&(set, group, value)| {
            methods
                .iter()
                .filter(|m| !m.contains(ORACLE_TAG))
                .filter_map(|m| row(set, m, group).map(value))
                .filter(|v| v.is_finite())
                .fold(f32::NEG_INFINITY, f32::max)
        })
        .collect();
    let mut md = String::from(
        "\n## At a glance\n\nPer input set: PSNR frame at close / divergent views (dB) and the divergent views' mask \
         IoU. Bold: the best method without oracle geometry in that column.\n\n| method |",
    );
    for set in sets {
        md.push_str(&format!(" {set}: PSNR frame close | divergent | mask IoU |"));
    }
    md.push_str(&format!("\n|---|{}\n", "---|".repeat(columns.len())));
    for m in &methods {
        md.push_str(&format!("| {m} |"));
        for (&(set, group, value), &b) in columns.iter().zip(&best) {
            let cell = match row(set, m, group).map(value) {
                Some(v) if v == b && !m.contains(ORACLE_TAG) => format!(" **{}** |", fmt_cell(v)),
                Some(v) => format!(" {} |", fmt_cell(v)),
                None => " - |".to_string(),
            };
            md.push_str(&cell);
        }
        md.push('\n');
    }
    md
}

/// A PSNR (above 1) with two decimals, an IoU with three.
pub(super) fn fmt_cell(v: f32) -> String {
    if v > 1.0 {
        format!("{v:.2}")
    } else {
        format!("{v:.3}")
    }
}

/// Draws a `w` x `h` chart with `draw` on a white bitmap and writes it to `path` as a PNG (atomically); `draw`
/// reports plotters' errors as I/O errors on `path`.
pub(super) fn write_chart(
    path: &Path,
    (w, h): (u32, u32),
    draw: impl FnOnce(
        &plotters::drawing::DrawingArea<plotters::prelude::BitMapBackend<'_>, plotters::coord::Shift>,
    ) -> Result<(), EvalError>,
) -> Result<(), EvalError> {
    use plotters::prelude::*;
    let perr = |e: String| EvalError::io(path, std::io::Error::other(e));
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| perr(e.to_string()))?;
        draw(&root)?;
        root.present().map_err(|e| perr(e.to_string()))?;
    }
    let img = image::RgbImage::from_raw(w, h, buf)
        .ok_or_else(|| EvalError::io(path, std::io::Error::other("plot buffer")))?;
    let mut bytes = Vec::new();
    image::DynamicImage::ImageRgb8(img)
        .write_to(&mut std::io::Cursor::new(&mut bytes), image::ImageFormat::Png)
        .map_err(|e| EvalError::io(path, std::io::Error::other(e)))?;
    write_atomic(path, &bytes).map_err(|e| EvalError::io(path, e))
}

fn plot(path: &Path, rep: &EvalReport) -> Result<(), EvalError> {
    use plotters::prelude::*;
    write_chart(path, (800, 500), |root| {
        let perr = |e: String| EvalError::io(path, std::io::Error::other(e));
        // The synthetic framings are merged into one point per method and view group (view-weighted means).
        let mut merged: Vec<ReportRow> = Vec::new();
        for r in rep.rows.iter().filter(|r| r.scores.psnr.is_finite()) {
            let inputs = if r.inputs.starts_with("synthetic/") { "synthetic" } else { r.inputs.as_str() };
            match merged.iter_mut().find(|m| m.inputs == inputs && m.method == r.method && m.group == r.group) {
                Some(m) => {
                    let (a, b) = (m.views as f32, r.views as f32);
                    m.scores.psnr = (m.scores.psnr * a + r.scores.psnr * b) / (a + b);
                    m.ms_per_view = (m.ms_per_view * a + r.ms_per_view * b) / (a + b);
                    m.views += r.views;
                }
                None => merged.push(ReportRow { inputs: inputs.to_string(), ..r.clone() }),
            }
        }
        let pts: Vec<&ReportRow> = merged.iter().collect();
        let xmax = pts.iter().map(|r| r.ms_per_view).fold(1.0f32, f32::max) * 1.2;
        let (ymin, ymax) =
            pts.iter().fold((f32::MAX, f32::MIN), |(a, b), r| (a.min(r.scores.psnr), b.max(r.scores.psnr)));
        let (ymin, ymax) = if ymin <= ymax { (ymin - 1.0, ymax + 1.0) } else { (0.0, 40.0) };
        let mut chart = ChartBuilder::on(root)
            .caption("PSNR against time per view", ("sans-serif", 22))
            .margin(15)
            .x_label_area_size(40)
            .y_label_area_size(50)
            .build_cartesian_2d(0f32..xmax, ymin..ymax)
            .map_err(|e| perr(e.to_string()))?;
        chart.configure_mesh().x_desc("ms per view").y_desc("PSNR (dB)").draw().map_err(|e| perr(e.to_string()))?;
        // One colour per method.
        let colors: [RGBColor; METHODS.len()] = [
            RED,
            BLUE,
            GREEN,
            MAGENTA,
            CYAN,
            BLACK,
            RGBColor(230, 140, 0),
            RGBColor(120, 60, 160),
            RGBColor(0, 128, 128),
            RGBColor(150, 150, 0),
            RGBColor(200, 80, 120),
            RGBColor(110, 110, 110),
            RGBColor(60, 180, 60),
            RGBColor(40, 40, 200),
        ];
        for r in pts {
            let c = colors[METHODS.iter().position(|m| *m == r.method).unwrap_or(0) % colors.len()];
            let marker = if r.group == "close" { 0 } else { 1 };
            let label = match r.inputs.as_str() {
                "synthetic" => format!("{} ({})", r.method, r.group),
                scan => format!("{} ({}, {scan})", r.method, r.group),
            };
            let p = (r.ms_per_view, r.scores.psnr);
            if marker == 0 {
                chart.draw_series(std::iter::once(Circle::new(p, 6, c.filled()))).map_err(|e| perr(e.to_string()))?;
            } else {
                chart
                    .draw_series(std::iter::once(TriangleMarker::new(p, 7, c.filled())))
                    .map_err(|e| perr(e.to_string()))?;
            }
            chart
                .draw_series(std::iter::once(Text::new(label, (p.0 + xmax * 0.01, p.1), ("sans-serif", 13))))
                .map_err(|e| perr(e.to_string()))?;
        }
        Ok(())
    })
}

/// A report row with only the fields the table tests read (for the tests of this module and [`super::scans`]).
#[cfg(test)]
pub(super) fn test_row(inputs: &str, method: &str, group: &str, psnr_frame: f32, mask_iou: f32) -> ReportRow {
    ReportRow {
        inputs: inputs.into(),
        framing: "full".into(),
        method: method.into(),
        group: group.into(),
        scores: MeanScores { psnr_frame, mask_iou, ..Acc::default().means() },
        ms_per_view: 0.0,
        ms_per_input: 0.0,
        views: 1,
        peak_mib: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use super::test_row as row;

    #[test]
    fn at_a_glance_marks_the_best_predicted_geometry_per_column() {
        let (a, b) = ("synthetic/full", "synthetic/upper");
        let rows = vec![
            row(a, "geometric+inflation", "close", 17.0, 0.6),
            row(a, "geometric+inflation", "divergent", 16.0, 0.5),
            row(a, "geometric+fofnet", "close", 18.0, 0.7),
            row(a, "geometric+fofnet", "divergent", 15.0, 0.45),
            row(a, "geometric+gt-fof", "close", 27.0, 0.97),
            row(a, "geometric+gt-fof", "divergent", 24.0, 0.96),
            row(b, "geometric+inflation", "close", 14.0, 0.55),
            row(b, "geometric+inflation", "divergent", 15.0, 0.49),
        ];
        let rep = EvalReport { rows, ..Default::default() };
        let md = at_a_glance(&rep, &[a, b]);
        let line = |m: &str| md.lines().find(|l| l.starts_with(&format!("| {m} |"))).unwrap().to_string();
        // Full framing: fofnet wins close, inflation wins divergent PSNR and IoU; the oracle is never bold.
        assert_eq!(line("geometric+fofnet"), "| geometric+fofnet | **18.00** | 15.00 | 0.450 | - | - | - |");
        assert_eq!(
            line("geometric+inflation"),
            "| geometric+inflation | 17.00 | **16.00** | **0.500** | **14.00** | **15.00** | **0.490** |"
        );
        assert_eq!(line("geometric+gt-fof"), "| geometric+gt-fof | 27.00 | 24.00 | 0.960 | - | - | - |");
        assert!(md.contains("| method | synthetic/full: PSNR frame close | divergent | mask IoU | synthetic/upper:"));
        assert_eq!(at_a_glance(&rep, &[]), "");
    }
}
