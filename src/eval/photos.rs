//! `r2human eval --photos DIR`: real photos have no ground truth, but they show what a user sees. For each photo
//! in a folder (its alpha when it has a real one, else the project's segmentation model) every method renders the
//! views at yaws 0, 30, 60, 90, 135 and 180; the report carries a contact sheet per photo (rows: methods, columns:
//! the input and the yaws) and three checks that need no ground truth:
//!
//! - **input-view PSNR**: the method's yaw-0 view against the normalised photo, sRGB over black over the whole
//!   frame (what the paper's Table 2 measures, here against the input itself);
//! - **detached fragments**: the rendered mask's connected components at each yaw; a person is one body, so the
//!   area outside the largest component, as a fraction of the person's pixels, is reported (the worst yaw). Pixels
//!   closer than one pixel (diagonal neighbours) are one component ([`detached_fraction`]);
//! - **doubled surfaces**: source columns where the decoded occupancy has more separate intervals than the
//!   silhouette and the pose explain, as a fraction of the person's pixels
//!   ([`crate::geometry::shells::doubled_fraction_beyond`]): a column is explained up to the larger interval count
//!   of the silhouette-inflation prior (one shell) and of the fitted body's FOF when the body prior loaded (an arm
//!   in front of the torso: two). A face or torso drawn as two shells, one behind the other, shows here. The body
//!   prior's own rows are explained by construction (0), so only their detached check says something; without the
//!   body prior, an arm really in front of the torso counts too (an upper bound on photos with crossed limbs).
//!
//! Outputs: `photos.md`, `photos.csv` and `photos/<name>.png` (contact sheets) in the eval output folder.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use glam::{Vec3, Vec4};

use super::metrics::{psnr, SrgbImage};
use super::EvalError;
use crate::buffer::{GrayImage, Image, RgbImage, RgbaImage};
use crate::capture::morph::{dilate, largest_component, BinaryMask};
use crate::capture::segment::SegmentMethod;
use crate::geometry::camera::Camera;
use crate::geometry::fof::Fof;
use crate::geometry::shells::{doubled_fraction_beyond, INTERVAL_SAMPLES, MIN_RUN_SAMPLES};
use crate::io::npy::write_atomic;
use crate::pipeline::input::{normalise, NormalisedInput};
use crate::pipeline::warp::OcclusionFill;
use crate::pipeline::{
    compute_geometry, GeometryMode, PrepareOptions, PreparedInput, SharedBody, SharedFofNet, SharedNeural,
    StageTimings, ViewRenderer,
};

/// The yaws every photo is rendered at (degrees; pitch 0).
pub const PHOTO_YAWS: [f32; 6] = [0.0, 30.0, 60.0, 90.0, 135.0, 180.0];

/// The area outside the largest component above which a view counts as having a detached fragment (fraction of
/// the person's pixels).
pub const FRAGMENT_TOLERANCE: f32 = 0.005;

/// The fraction of the person's columns with unexplained extra shells above which a geometry counts as doubled.
pub const DOUBLED_TOLERANCE: f32 = 0.01;

/// Options of [`run_photo_eval`].
#[derive(Clone, Debug)]
pub struct PhotoEvalOptions {
    /// The folder of photos (PNG, JPEG; alpha used when it is a real mask).
    pub dir: PathBuf,
    /// Output folder (`photos.md`, `photos.csv`, `photos/`).
    pub out: PathBuf,
    /// Source and view resolution.
    pub size: usize,
    /// How the person is told from the background.
    pub segment: SegmentMethod,
}

/// One method of the photo checks: a geometry and a renderer.
#[derive(Clone, Debug, PartialEq)]
pub struct PhotoMethod {
    /// Label in the report, e.g. `geometric+inflation`.
    pub label: String,
    /// Where the geometry comes from (explicit modes only: a network failure is reported, never replaced).
    pub geometry: GeometryMode,
    /// Neural renderer (else geometric).
    pub neural: bool,
}

/// The networks the photo checks may use (each `None` when it did not load).
#[derive(Clone, Copy, Default)]
pub struct PhotoNets<'a> {
    /// The neural renderer.
    pub neural: Option<&'a SharedNeural>,
    /// The FOF net.
    pub fof_net: Option<&'a SharedFofNet>,
    /// The body prior (pose network and fitter).
    pub body: Option<&'a SharedBody>,
    /// The placement network of the body-placed rows (`None`: the confidence-aware placement of `body::placed`).
    pub placement: Option<&'a crate::pipeline::SharedPlacementNet>,
    /// The pose network that finds the face for the back image (the default fill's); also what the plausibility
    /// check reads the views with ([`super::plausible`]).
    pub back_pose: Option<&'a crate::pipeline::SharedPose>,
}

/// The methods that can run with `nets`: geometric and neural renderers on every geometry whose model loaded.
pub fn photo_methods(nets: PhotoNets<'_>) -> Vec<PhotoMethod> {
    let mut geometries = vec![(GeometryMode::Inflate, "inflation")];
    if nets.fof_net.is_some() {
        geometries.push((GeometryMode::FofNet, "fofnet"));
    }
    if nets.body.is_some() {
        geometries.push((GeometryMode::Body, "body"));
        geometries.push((GeometryMode::BodyPlaced, "body-placed"));
    }
    let mut out = Vec::new();
    for neural in [false, true] {
        if neural && nets.neural.is_none() {
            continue;
        }
        for &(geometry, name) in &geometries {
            let renderer = if neural { "neural" } else { "geometric" };
            out.push(PhotoMethod { label: format!("{renderer}+{name}"), geometry, neural });
        }
    }
    out
}

/// The checks of one method on one photo.
#[derive(Clone, Debug, PartialEq)]
pub struct PhotoRow {
    /// Photo file name.
    pub photo: String,
    /// Method label.
    pub method: String,
    /// How the person was segmented (`alpha` or the model's name).
    pub segmentation: String,
    /// PSNR (dB) of the yaw-0 view against the normalised photo, whole frame over black.
    pub input_psnr: f32,
    /// Per yaw of [`PHOTO_YAWS`]: the rendered mask's area outside its largest component, as a fraction of the
    /// rendered person's pixels.
    pub detached: Vec<f32>,
    /// Fraction of the person's source columns with more occupancy intervals than the silhouette (inflation prior)
    /// and the fitted body explain.
    pub doubled: f32,
    /// Per-input milliseconds (normalise, geometry, mesh, source raster, encoder when neural).
    pub ms_per_input: f32,
    /// True when the geometry's network output was rejected by the pipeline's guard
    /// ([`crate::pipeline::guard`]) and the prior it refined was used instead.
    pub guard_fallback: bool,
    /// What the pose network sees in the views ([`super::plausible`]); `None` when the pose network is not
    /// loaded.
    pub plausibility: Option<super::plausible::Plausibility>,
}

impl PhotoRow {
    /// The worst yaw's detached area.
    pub fn worst_detached(&self) -> f32 {
        self.detached.iter().copied().fold(0.0, f32::max)
    }

    /// True when no check fails: no detached fragment at any yaw and no doubled surface.
    pub fn passes(&self) -> bool {
        self.worst_detached() <= FRAGMENT_TOLERANCE && self.doubled <= DOUBLED_TOLERANCE
    }
}

/// The plausibility check's CSV columns of one row: pass, views passing of all, the worst pose error, the head's
/// width at each yaw of [`PHOTO_YAWS`], the back of the head's likeness to the face (empty where not measured).
fn plausibility_columns(p: Option<&super::plausible::Plausibility>) -> Vec<String> {
    let Some(p) = p else { return vec![String::new(); 4 + PHOTO_YAWS.len()] };
    let f = |x: Option<f32>| x.map_or(String::new(), |x| format!("{x:.3}"));
    let (pass, n) = p.passing_views();
    let worst =
        p.views.iter().filter_map(|v| v.pose_error).fold(None, |m: Option<f32>, e| Some(m.map_or(e, |m| m.max(e))));
    let mut out = vec![p.passes().to_string(), format!("{pass}/{n}"), f(worst)];
    out.extend(PHOTO_YAWS.iter().map(|&y| f(p.views.iter().find(|v| v.yaw == y).and_then(|v| v.head_width))));
    out.push(f(p.views.iter().find_map(|v| v.back_likeness)));
    out
}

/// The plausibility check's cell in `photos.md`: `pass (k/n views)` or `FAIL (k/n views): ` and the failures.
fn plausibility_cell(p: Option<&super::plausible::Plausibility>) -> String {
    match p {
        None => "-".to_string(),
        Some(p) => {
            let (pass, n) = p.passing_views();
            match p.failures() {
                f if f.is_empty() => format!("pass ({pass}/{n} views)"),
                f => format!("FAIL ({pass}/{n} views): {}", f.join("; ")),
            }
        }
    }
}

/// What [`run_photo_eval`] produced.
#[derive(Clone, Debug, Default)]
pub struct PhotoReport {
    /// One row per photo and method.
    pub rows: Vec<PhotoRow>,
    /// Photos or methods that failed, with the reason.
    pub failed: Vec<(String, String)>,
    /// The contact sheets written (one per photo).
    pub sheets: Vec<PathBuf>,
    /// Why methods are missing (a network that did not load), for the report.
    pub notes: Vec<String>,
}

/// The image files of a folder, sorted by name (PNG, JPEG).
pub fn photo_files(dir: &Path) -> Result<Vec<PathBuf>, EvalError> {
    let entries = std::fs::read_dir(dir).map_err(|e| EvalError::io(dir, e))?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            let ext = p.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
            matches!(ext.as_deref(), Some("png" | "jpg" | "jpeg"))
        })
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(EvalError::InvalidOptions(format!(
            "{} holds no photo (PNG or JPEG): give --photos a folder of photos",
            dir.display()
        )));
    }
    Ok(files)
}

/// A photo and its person mask under `method` (linear straight RGB, mask in `[0, 1]`), and where the mask came
/// from ([`crate::capture::segment::MaskOrigin::short_name`]): the still-photo policy of `--image`
/// ([`crate::capture::segment::segment_photo`]).
pub fn segment_photo(path: &Path, method: &SegmentMethod) -> Result<(RgbImage, GrayImage, String), EvalError> {
    let p = crate::capture::segment::segment_photo(path, None, method)
        .map_err(|e| EvalError::Photo { path: path.to_path_buf(), source: Box::new(e) })?;
    Ok((p.photo.rgb, p.mask, p.origin.short_name()))
}

/// The rendered mask's area outside its largest component, as a fraction of the mask's pixels (0 for an empty
/// mask). Components are taken after a one-pixel dilation, so pixels touching diagonally or across a one-pixel
/// crack are one body; what is left is a fragment the viewer sees floating apart.
pub fn detached_fraction(mask: &BinaryMask) -> f32 {
    let total = mask.data.iter().filter(|&&m| m).count();
    if total == 0 {
        return 0.0;
    }
    let body = largest_component(&dilate(mask, 1));
    let outside = mask.data.iter().zip(&body.data).filter(|&(&m, &b)| m && !b).count();
    outside as f32 / total as f32
}

/// What every method of one photo shares: the normalised photo, and the geometries the doubled-surface check
/// takes as explained (the silhouette-inflation prior; the fitted body's FOF when the body prior loaded and found a
/// pose), with the time each took.
struct PhotoReference {
    normalised: NormalisedInput,
    /// `normalise` stage time.
    normalise: StageTimings,
    /// The inflation prior and its stage times.
    inflation: Reused,
    /// The body prior's FOF (the inflation prior where it found no pose) and its stage times (the inflation prior's
    /// included, as `--geometry body` computes both).
    body: Option<Reused>,
}

/// A geometry computed once per photo and reused by the methods that draw it: its FOF and its stage times.
type Reused = (Fof, StageTimings);

impl PhotoReference {
    fn of(rgb: &RgbImage, mask: &GrayImage, opts: &PhotoEvalOptions, nets: PhotoNets<'_>) -> Result<Self, EvalError> {
        let mut timings = StageTimings::default();
        let normalised = timings
            .time("normalise", || normalise(rgb, mask, opts.size))
            .map_err(|e| EvalError::stage("normalise", e))?;
        let geometry = |mode: GeometryMode| -> Result<Reused, EvalError> {
            let o = PrepareOptions { body: nets.body.cloned(), ..photo_prepare_options(opts, mode) };
            let mut t = StageTimings::default();
            let fof = compute_geometry(&normalised, &o, &mut t).map_err(|e| {
                EvalError::stage(if mode == GeometryMode::Body { "body prior" } else { "inflation prior" }, e)
            })?;
            Ok((fof, t))
        };
        let inflation = geometry(GeometryMode::Inflate)?;
        let body = if nets.body.is_some() { Some(geometry(GeometryMode::Body)?) } else { None };
        Ok(Self { normalised, normalise: timings, inflation, body })
    }

    /// The geometries a column's intervals may come from without counting as doubled.
    fn explained(&self) -> Vec<&Fof> {
        std::iter::once(&self.inflation.0).chain(self.body.as_ref().map(|b| &b.0)).collect()
    }
}

/// The pipeline options of the photo checks for `geometry` (no network attached).
fn photo_prepare_options(opts: &PhotoEvalOptions, geometry: GeometryMode) -> PrepareOptions {
    PrepareOptions { resolution: opts.size, depth_samples: opts.size, geometry, ..Default::default() }
}

/// Runs one method on a segmented photo: returns its row and its views (yaw 0 first, as in [`PHOTO_YAWS`]).
fn run_method(
    name: &str,
    reference: &PhotoReference,
    segmentation: &str,
    method: &PhotoMethod,
    opts: &PhotoEvalOptions,
    nets: PhotoNets<'_>,
) -> Result<(PhotoRow, Vec<RgbaImage>), EvalError> {
    let fail = |e: Box<dyn std::error::Error + Send + Sync>| EvalError::Method {
        path: PathBuf::from(name),
        method: method.label.clone(),
        source: e,
    };
    let prepare = PrepareOptions {
        fof_net: nets.fof_net.cloned(),
        body: nets.body.cloned(),
        placement: nets.placement.cloned(),
        back_pose: nets.back_pose.cloned(),
        ..photo_prepare_options(opts, method.geometry)
    };
    let t = Instant::now();
    // The priors were computed once per photo; their time counts as this method's (it needs them).
    let ((fof, mut timings), reused) = match (method.geometry, &reference.body) {
        (GeometryMode::Inflate, _) => (reference.inflation.clone(), true),
        (GeometryMode::Body, Some(body)) => (body.clone(), true),
        _ => {
            let mut timings = StageTimings::default();
            let fof = compute_geometry(&reference.normalised, &prepare, &mut timings).map_err(|e| fail(e.into()))?;
            ((fof, timings), false)
        }
    };
    let reused = reference.normalise.total() + if reused { timings.total() } else { Duration::ZERO };
    timings.0.splice(0..0, reference.normalise.0.iter().copied());
    let input =
        PreparedInput::from_fof(reference.normalised.clone(), fof, &prepare, timings).map_err(|e| fail(e.into()))?;
    let mut renderer = if method.neural {
        let net = nets.neural.ok_or_else(|| fail("the neural renderer did not load".into()))?;
        let encoded = net.lock().unwrap_or_else(|p| p.into_inner()).encode(&input).map_err(|e| fail(e.into()))?;
        ViewRenderer::with_neural(&input, OcclusionFill::default(), false, std::sync::Arc::clone(net), encoded)
    } else {
        ViewRenderer::new(&input, OcclusionFill::default(), false)
    };
    let ms_per_input = (t.elapsed() + reused).as_secs_f32() * 1e3;
    let mut views = Vec::with_capacity(PHOTO_YAWS.len());
    let mut detached = Vec::with_capacity(PHOTO_YAWS.len());
    for &yaw in &PHOTO_YAWS {
        let person =
            renderer.render_person(&Camera::orbit(yaw, 0.0, opts.size, opts.size)).map_err(|e| fail(e.into()))?;
        let m =
            Image { width: person.width, height: person.height, data: person.data.iter().map(|p| p.w > 0.5).collect() };
        detached.push(detached_fraction(&m));
        views.push(person);
    }
    // Against the photo as normalised, not the input's colours (whose rim `from_fof` replaced).
    let photo = SrgbImage::from_linear_premultiplied(&reference.normalised.rgb.map(|c| c.extend(1.0)));
    let front = SrgbImage::from_linear_premultiplied(&views[0]);
    let input_psnr = psnr(&photo, &front, &vec![true; photo.data.len()]);
    // Photos take the still path, whose input always holds its FOF.
    let doubled = input
        .fof
        .as_ref()
        .map_or(0.0, |fof| doubled_fraction_beyond(fof, &reference.explained(), &input.normalised.mask, 1));
    let guard_fallback = method.geometry != GeometryMode::Inflate && input.fof.as_ref() == Some(&reference.inflation.0);
    let plausibility = match nets.back_pose {
        Some(pose) => {
            let yaws_and_views: Vec<(f32, &RgbaImage)> = PHOTO_YAWS.iter().copied().zip(&views).collect();
            let mut net = pose.0.lock().unwrap_or_else(|p| p.into_inner());
            // The photo's frame in the views (the normalised input's, scaled to the views' size).
            let scale = opts.size as f32 / reference.normalised.rgb.width.max(1) as f32;
            let (lo, hi) = reference.normalised.frame;
            let frame = Some((lo * scale, hi * scale));
            Some(super::plausible::check(&mut net, &yaws_and_views, frame).map_err(|e| fail(e.into()))?)
        }
        None => None,
    };
    let row = PhotoRow {
        photo: name.to_string(),
        method: method.label.clone(),
        segmentation: segmentation.to_string(),
        input_psnr,
        detached,
        doubled,
        ms_per_input,
        guard_fallback,
        plausibility,
    };
    Ok((row, views))
}

/// A contact sheet: one row per method (`views[m]`, yaws left to right), the normalised input in the first
/// column, over mid grey so dark clothes stay visible; rows are labelled in the report, in the same order.
fn contact_sheet(input: &RgbImage, input_mask: &GrayImage, views: &[Vec<RgbaImage>], thumb: usize) -> RgbImage {
    let grey = Vec3::splat(0.18);
    let gap = 4;
    let columns = PHOTO_YAWS.len() + 1;
    let rows = views.len().max(1);
    let mut sheet = Image::new(columns * (thumb + gap) + gap, rows * (thumb + gap) + gap, Vec3::splat(0.02));
    let blit = |sheet: &mut RgbImage, x0: usize, y0: usize, px: &dyn Fn(usize, usize) -> Vec4, size: usize| {
        for r in 0..thumb {
            for c in 0..thumb {
                let p = px(c * size / thumb, r * size / thumb);
                sheet.set(x0 + c, y0 + r, p.truncate() + grey * (1.0 - p.w));
            }
        }
    };
    let size = input.width;
    for row in 0..rows {
        let y0 = gap + row * (thumb + gap);
        let photo = |c: usize, r: usize| input.get(c, r).extend(*input_mask.get(c, r));
        blit(&mut sheet, gap, y0, &photo, size);
        for (k, view) in views.get(row).map(Vec::as_slice).unwrap_or(&[]).iter().enumerate() {
            let x0 = gap + (k + 1) * (thumb + gap);
            blit(&mut sheet, x0, y0, &|c, r| *view.get(c, r), view.width);
        }
    }
    sheet
}

/// Runs every method of `nets` on every photo of `opts.dir`, writes `photos.md`, `photos.csv` and one contact
/// sheet per photo into `opts.out`. A photo that cannot be read or segmented, or a method that fails on it, is
/// reported and skipped.
pub fn run_photo_eval(opts: &PhotoEvalOptions, nets: PhotoNets<'_>) -> Result<PhotoReport, EvalError> {
    let report = evaluate_photos(opts, nets)?;
    write_photo_reports(opts, &photo_methods(nets), &report)?;
    Ok(report)
}

/// The rows and contact sheets of [`run_photo_eval`], without the report files.
fn evaluate_photos(opts: &PhotoEvalOptions, nets: PhotoNets<'_>) -> Result<PhotoReport, EvalError> {
    let files = photo_files(&opts.dir)?;
    let sheets_dir = opts.out.join("photos");
    std::fs::create_dir_all(&sheets_dir).map_err(|e| EvalError::io(&sheets_dir, e))?;
    let methods = photo_methods(nets);
    let mut report = PhotoReport::default();
    for path in &files {
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let (rgb, mask, segmentation) = match segment_photo(path, &opts.segment) {
            Ok(s) => s,
            Err(e) => {
                report.failed.push((name, e.to_string()));
                continue;
            }
        };
        tracing::info!("{name}: person from {segmentation}");
        let reference = match PhotoReference::of(&rgb, &mask, opts, nets) {
            Ok(r) => r,
            Err(e) => {
                report.failed.push((name, e.to_string()));
                continue;
            }
        };
        let mut views = Vec::new();
        for method in &methods {
            match run_method(&name, &reference, &segmentation, method, opts, nets) {
                Ok((row, v)) => {
                    report.rows.push(row);
                    views.push(v);
                }
                Err(e) => report.failed.push((format!("{name} ({})", method.label), e.to_string())),
            }
        }
        if !views.is_empty() {
            let n = &reference.normalised;
            let sheet = contact_sheet(&n.rgb, &n.mask, &views, 160);
            let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
            let p = sheets_dir.join(format!("{stem}.png"));
            crate::io::image_io::save_rgb_png(&p, &sheet).map_err(|e| EvalError::io(&p, std::io::Error::other(e)))?;
            report.sheets.push(p);
        }
    }
    Ok(report)
}

/// [`run_photo_eval`] with the networks `nopts` asks for (the same as the synthetic evaluation's: the neural
/// renderer and the FOF net when they load; the report says which are missing).
pub fn run_photo_eval_with(
    opts: &PhotoEvalOptions,
    nopts: &super::runner::NeuralEvalOptions,
) -> Result<PhotoReport, EvalError> {
    if !(32..=2048).contains(&opts.size) {
        return Err(EvalError::InvalidOptions(format!("--size {} must be within 32..=2048", opts.size)));
    }
    let mut notes = Vec::new();
    let (neural, fof_net) = super::runner::load_networks(nopts, &mut notes);
    let options = crate::neural::RuntimeOptions { ep: nopts.ep, ..Default::default() };
    let body = match crate::pipeline::load_body(GeometryMode::Body, &options) {
        _ if nopts.skip => None,
        Ok(body) => body,
        Err(e) => {
            tracing::warn!("the body-prior rows are skipped: {e}");
            notes.push(format!("The body-prior rows are skipped: {e}"));
            None
        }
    };
    let back_pose = crate::pipeline::load_back_pose(OcclusionFill::default(), &options);
    let placement = super::runner::load_placement(nopts, &mut notes);
    let nets = PhotoNets {
        neural: neural.as_ref(),
        fof_net: fof_net.as_ref(),
        body: body.as_ref(),
        placement: placement.as_ref(),
        back_pose: back_pose.as_ref(),
    };
    let mut report = evaluate_photos(opts, nets)?;
    report.notes = notes;
    write_photo_reports(opts, &photo_methods(nets), &report)?;
    Ok(report)
}

fn write_photo_reports(opts: &PhotoEvalOptions, methods: &[PhotoMethod], rep: &PhotoReport) -> Result<(), EvalError> {
    let yaw_cols: Vec<String> = PHOTO_YAWS.iter().map(|y| format!("detached_yaw{}", *y as i32)).collect();
    let head_cols: Vec<String> = PHOTO_YAWS.iter().map(|y| format!("head_width_yaw{}", *y as i32)).collect();
    let mut csv = format!(
        "photo,method,segmentation,input_psnr,doubled,{},ms_per_input,passes,guard_fallback,plausible,\
         plausible_views,worst_pose_error,{},back_likeness\n",
        yaw_cols.join(","),
        head_cols.join(",")
    );
    for r in &rep.rows {
        let detached: Vec<String> = r.detached.iter().map(|d| format!("{d:.5}")).collect();
        let plausible = plausibility_columns(r.plausibility.as_ref());
        csv.push_str(&format!(
            "{},{},{},{:.3},{:.5},{},{:.1},{},{},{}\n",
            r.photo,
            r.method,
            r.segmentation,
            r.input_psnr,
            r.doubled,
            detached.join(","),
            r.ms_per_input,
            r.passes(),
            r.guard_fallback,
            plausible.join(",")
        ));
    }
    let p = opts.out.join("photos.csv");
    write_atomic(&p, csv.as_bytes()).map_err(|e| EvalError::io(&p, e))?;

    let mut md = format!(
        "# r2human eval --photos\n\n{} photo(s) from `{}`, {}x{} views at yaws {:?} (pitch 0). No ground truth: the \
         checks are what a viewer notices.\n\n\
         - **input PSNR**: the yaw-0 view against the normalised photo, sRGB over black, whole frame (dB).\n\
         - **detached**: the worst yaw's rendered-mask area outside its largest component (one-pixel gaps bridged), \
         as a fraction of the person; a view counts as broken above {:.1} %.\n\
         - **doubled**: the fraction of the person's source columns whose decoded occupancy has more intervals \
         (runs over {} depth samples, gaps under {} samples merged) than the silhouette and the pose explain: the \
         larger count of the silhouette-inflation prior (one shell) and of the fitted body's FOF {}; a geometry \
         counts as doubled above {:.0} %. The body prior's own rows are explained by construction.\n\
         - **guard**: `prior` where the pipeline's guard rejected the network's geometry (doubled shells or detached \
         volume, `pipeline::guard`) and the method drew the prior it refined instead.\n\
         - **plausible** (not part of **checks**; `eval::plausible`, docs/evaluation.md): the pose network reads \
         every view; it must find a person (score at least {:.1}) whose body landmarks lie on the rows of the yaw-0 \
         view's (an orbit keeps rows) within {:.1} shoulder widths (RMS); the head's width between \
         the eyes and the mouth over its width at yaw 0 must fit a head {:.1}-{:.1} times as deep as wide, turned \
         within {:.0}° of the face's direction (±{:.0} %); the back of the head at yaw {:.0} must not look like \
         the mirrored face (likeness at most {:.2}). Views passing of all, and the failures; `-` without the pose network.\n\n\
         | photo | method | segmentation | input PSNR | detached (worst yaw) | doubled | guard | ms/input | checks | \
         plausible |\n\
         |---|---|---|---|---|---|---|---|---|---|\n",
        rep.sheets.len(),
        opts.dir.display(),
        opts.size,
        opts.size,
        PHOTO_YAWS,
        FRAGMENT_TOLERANCE * 100.0,
        INTERVAL_SAMPLES,
        MIN_RUN_SAMPLES,
        if methods.iter().any(|m| m.geometry == GeometryMode::Body) {
            "(an arm in front of the torso has two)"
        } else {
            "(not loaded in this run: an arm really in front of the torso counts as doubled, an upper bound)"
        },
        DOUBLED_TOLERANCE * 100.0,
        super::plausible::MIN_PERSON_SCORE,
        super::plausible::MAX_POSE_ERROR,
        super::plausible::HEAD_DEPTH_RATIO.0,
        super::plausible::HEAD_DEPTH_RATIO.1,
        super::plausible::HEAD_TURN,
        super::plausible::HEAD_TOLERANCE * 100.0,
        super::plausible::BACK_YAW,
        super::plausible::MAX_BACK_LIKENESS,
    );
    for r in &rep.rows {
        let (worst_i, worst) =
            r.detached
                .iter()
                .copied()
                .enumerate()
                .fold((0, 0.0f32), |best, (i, d)| if d > best.1 { (i, d) } else { best });
        md.push_str(&format!(
            "| {} | {} | {} | {:.2} | {:.2} % (yaw {}) | {:.2} % | {} | {:.0} | {} | {} |\n",
            r.photo,
            r.method,
            r.segmentation,
            r.input_psnr,
            worst * 100.0,
            PHOTO_YAWS[worst_i],
            r.doubled * 100.0,
            if r.guard_fallback { "prior" } else { "-" },
            r.ms_per_input,
            if r.passes() { "pass" } else { "FAIL" },
            plausibility_cell(r.plausibility.as_ref())
        ));
    }
    let labels: Vec<&str> = methods.iter().map(|m| m.label.as_str()).collect();
    md.push_str(&format!(
        "\nContact sheets (rows: {}; columns: the segmented input, then yaws {:?}; over grey):\n\n",
        labels.join(", "),
        PHOTO_YAWS
    ));
    for s in &rep.sheets {
        let rel = s.strip_prefix(&opts.out).unwrap_or(s);
        md.push_str(&format!("![{}]({})\n\n", rel.display(), rel.display()));
    }
    for note in &rep.notes {
        md.push_str(&format!("{note}\n\n"));
    }
    if !rep.failed.is_empty() {
        md.push_str("## Failed\n\n");
        for (n, e) in &rep.failed {
            md.push_str(&format!("- {n}: {e}\n"));
        }
    }
    let p = opts.out.join("photos.md");
    write_atomic(&p, md.as_bytes()).map_err(|e| EvalError::io(&p, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mask_from(rows: &[&str]) -> BinaryMask {
        let (w, h) = (rows[0].len(), rows.len());
        Image { width: w, height: h, data: rows.iter().flat_map(|r| r.chars().map(|c| c == '#')).collect() }
    }

    #[test]
    fn one_body_has_no_detached_area() {
        let m = mask_from(&["......", ".###..", ".####.", "..#...", "......"]);
        assert_eq!(detached_fraction(&m), 0.0);
        // Diagonal contact and a one-pixel crack are still one body.
        let m = mask_from(&["##....", "##....", "..#.##", "....##"]);
        assert_eq!(detached_fraction(&m), 0.0);
        assert_eq!(detached_fraction(&mask_from(&["...."])), 0.0, "empty mask");
    }

    #[test]
    fn a_floating_fragment_is_its_area_over_the_person() {
        // 8 body pixels, 2 fragment pixels three columns away: 2 / 10.
        let m = mask_from(&["####....##", "####......"]);
        assert!((detached_fraction(&m) - 0.2).abs() < 1e-6);
    }
}
