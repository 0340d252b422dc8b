//! `r2human dataset`: synthetic subjects with every view known, in a format numpy alone can read (PNG + `.npy`
//! + JSON; see docs/dataset.md).
//!
//! Each subject is written into a hidden temporary folder next to its destination and renamed into place when
//! complete, so a failed or interrupted subject leaves no half-written files; `dataset.json` is written last
//! (atomically) and lists only complete subjects. Subjects run in parallel (rayon).
//!
//! Next to the ground-truth `fof.npy`, each subject has `prior_fof.npy` ([`prior_fof`]): the silhouette-inflation
//! prior exactly as the pipeline feeds it to the FOF net, the input the residual FOF net corrects; and, unless
//! [`DatasetOptions::body_fof`] is off, `body_fof.npy` ([`body_fof`]): the body prior's FOF as inference computes it
//! (pose network + fitter on the rendered source image, not the ground-truth pose), the reference FOF net's other
//! input. A subject whose body prior falls back (no pose found, fit failed) gets the fall-back the pipeline uses
//! at run time (the inflation prior), and the fall-back is recorded in its `subject.json` (`body_fof.fallback`) and
//! in `dataset.json` (`body_fof_fallbacks`), never dropped silently.
//!
//! With the body FOF comes `source_back.png` ([`back_image`]): the back image `--fill back` colours hidden
//! surfaces from, computed on the rendered source as inference computes it on a photo, so the neural decoder trains
//! on the colour lookup it gets at run time ([`crate::pipeline::neural_back_lookup`]). A subject where the pose
//! network finds no face has none (inference then looks up the photo alone) and `subject.json` says so.

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Mat4;
use rayon::prelude::*;
use serde_json::json;

use super::ground_truth::{render_ground_truth, GroundTruthView};
use super::EvalError;
use crate::geometry::camera::{Camera, Projection, SOURCE_RESOLUTION};
use crate::geometry::fof::Fof;
use crate::geometry::inflate::{inflate_to_fof, InflateParams};
use crate::io::mesh_io::TexturedMesh;
use crate::io::npy::{write_atomic, NpyArray, NpyData};
use crate::pipeline::input::NormalisedInput;
use crate::pipeline::{back_image_of, body_prior_fof, PrepareOptions, SharedBody, SharedPose, StageTimings};
use crate::synth::framing::{self, FramingChoice};
use crate::synth::{self, Rng, SubjectParams, SynthAssets};

/// Options of [`write_dataset`] (the CLI's `r2human dataset` flags).
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetOptions {
    /// Number of subjects (`--subjects`).
    pub subjects: usize,
    /// Dataset seed (`--seed`); subject `i` uses [`subject_seed`]`(seed, i)`.
    pub seed: u64,
    /// Output folder (`--out`), created if missing.
    pub out: PathBuf,
    /// Target views per subject (`--views`, default 8).
    pub views: usize,
    /// Image side in pixels (`--size`, default 512).
    pub size: usize,
    /// FOF coefficients per pixel (32, as R²Human).
    pub fof_n: usize,
    /// Texture side of the subjects' albedo maps (1024).
    pub texture_size: usize,
    /// Show a progress bar on stderr.
    pub progress: bool,
    /// Framing of each subject (`--framing`; mixed: full, three-quarter and upper in turn).
    pub framing: FramingChoice,
    /// Write `body_fof.npy` and `source_back.png` per subject (needs the pose model: `bash scripts/setup.sh`;
    /// `--no-body-fof` skips both).
    pub body_fof: bool,
}

impl Default for DatasetOptions {
    fn default() -> Self {
        Self {
            subjects: 10,
            seed: 0,
            out: PathBuf::from("dataset"),
            views: 8,
            size: 512,
            fof_n: 32,
            texture_size: synth::DEFAULT_TEXTURE_SIZE,
            progress: true,
            framing: FramingChoice::Mixed,
            body_fof: true,
        }
    }
}

/// What [`write_dataset`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetSummary {
    /// Names of the subjects written (`subject_0000`...).
    pub written: Vec<String>,
    /// Subjects that failed, with the reason; they left no files behind.
    pub failed: Vec<(String, String)>,
    /// Wall-clock seconds.
    pub seconds: f64,
    /// Written subjects whose `body_fof.npy` is the body prior's fall-back (the inflation prior), with the reason.
    pub body_fallbacks: Vec<(String, String)>,
}

/// The generator seed of subject `index` in a dataset with seed `seed`.
pub fn subject_seed(seed: u64, index: usize) -> u64 {
    let mut r = Rng::new(seed ^ (index as u64).wrapping_mul(0xD1B5_4A32_D192_ED03));
    r.next_u64()
}

/// Orbit angles `(yaw_deg, pitch_deg)` of the `views` target views of a subject: yaws evenly spread over 360
/// degrees from a random offset, pitches in `[-10, 20]` degrees.
pub fn view_angles(subject_seed: u64, views: usize) -> Vec<(f32, f32)> {
    let mut r = Rng::new(subject_seed ^ 0x7669_6577);
    let step = 360.0 / views.max(1) as f32;
    let offset = r.range(0.0, step);
    (0..views).map(|k| (offset + step * k as f32, r.range(-10.0, 20.0))).collect()
}

/// Whether subject `index` is in the test split (every tenth subject: indices 9, 19, ...).
pub fn is_test(index: usize) -> bool {
    index % 10 == 9
}

fn check(opts: &DatasetOptions) -> Result<(), EvalError> {
    let bad = |m: String| Err(EvalError::InvalidOptions(m));
    if opts.subjects == 0 {
        return bad("--subjects must be at least 1".into());
    }
    if opts.subjects > 100_000 {
        return bad(format!("--subjects {} is more than 100000", opts.subjects));
    }
    if !(16..=4096).contains(&opts.size) {
        return bad(format!("--size {} must be within 16..=4096 pixels", opts.size));
    }
    if opts.views > 360 {
        return bad(format!("--views {} is more than 360", opts.views));
    }
    if !(1..=256).contains(&opts.fof_n) {
        return bad(format!("the FOF order {} must be within 1..=256", opts.fof_n));
    }
    if !(16..=8192).contains(&opts.texture_size) {
        return bad(format!("the texture size {} must be within 16..=8192", opts.texture_size));
    }
    Ok(())
}

/// Writes a dataset (see the module docs). Failed subjects are reported in the summary and skipped; the call
/// fails only for invalid options, missing generator data, an unwritable output folder, or when every subject
/// failed.
pub fn write_dataset(opts: &DatasetOptions) -> Result<DatasetSummary, EvalError> {
    check(opts)?;
    let start = Instant::now();
    let assets = SynthAssets::shared()?;
    let options = crate::neural::RuntimeOptions::default();
    let (body, back_pose) = if opts.body_fof {
        let body = crate::pipeline::load_body(crate::pipeline::GeometryMode::Body, &options)
            .map_err(EvalError::NoBodyPrior)?;
        (body, crate::pipeline::load_back_pose(crate::pipeline::warp::OcclusionFill::Back, &options))
    } else {
        (None, None)
    };
    std::fs::create_dir_all(&opts.out).map_err(|e| EvalError::io(&opts.out, e))?;
    let bar = if opts.progress {
        let b = indicatif::ProgressBar::new(opts.subjects as u64);
        if let Ok(style) = indicatif::ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} subjects ({per_sec}, eta {eta}) {msg}",
        ) {
            b.set_style(style);
        }
        b
    } else {
        indicatif::ProgressBar::hidden()
    };
    let results: Vec<(String, Result<Written, EvalError>)> = (0..opts.subjects)
        .into_par_iter()
        .map(|i| {
            let name = format!("subject_{i:04}");
            let r = write_subject(assets, opts, body.as_ref(), back_pose.as_ref(), i, &name);
            if let Err(e) = &r {
                bar.println(format!("{name}: {e}"));
            }
            bar.inc(1);
            (name, r)
        })
        .collect();
    bar.finish_and_clear();
    let mut written = Vec::new();
    let mut failed = Vec::new();
    let mut framings = serde_json::Map::new();
    let mut sheet = Vec::new();
    let mut body_fallbacks = Vec::new();
    for (name, r) in results {
        match r {
            Ok(w) => {
                framings.insert(name.clone(), json!(w.framing.label()));
                if let Some(why) = w.body_fallback {
                    body_fallbacks.push((name.clone(), why));
                }
                sheet.extend(w.mesh);
                written.push(name);
            }
            Err(e) => failed.push((name, e.to_string())),
        }
    }
    if written.is_empty() {
        let first = failed.first().map(|f| format!("{}: {}", f.0, f.1)).unwrap_or_default();
        return Err(EvalError::AllFailed(first));
    }
    let (train, test): (Vec<&String>, Vec<&String>) =
        written.iter().partition(|n| !is_test(n.trim_start_matches("subject_").parse().unwrap_or(0)));
    let manifest = json!({
        "format": "r2human-dataset",
        "version": 1,
        "resolution": opts.size,
        "fof_n": opts.fof_n,
        "seed": opts.seed,
        "subjects": written,
        "views_per_subject": opts.views,
        "framing": opts.framing.label(),
        "framings": framings,
        "contact_sheet": "contact_sheet.png",
        "split": {"train": train, "test": test},
        "failed": failed.iter().map(|(n, e)| json!({"subject": n, "error": e})).collect::<Vec<_>>(),
        "body_fof": opts.body_fof,
        "back_image": back_pose.is_some(),
        "body_fof_fallbacks": body_fallbacks.iter().map(|(n, e)| json!({"subject": n, "reason": e})).collect::<Vec<_>>(),
    });
    let path = opts.out.join("dataset.json");
    let text = serde_json::to_vec_pretty(&manifest).map_err(|e| EvalError::io(&path, std::io::Error::other(e)))?;
    write_atomic(&path, &text).map_err(|e| EvalError::io(&path, e))?;
    let meshes: Vec<&TexturedMesh> = sheet.iter().collect();
    super::ground_truth::write_contact_sheet(&opts.out.join("contact_sheet.png"), &meshes, &SHEET_YAWS, SHEET_SIZE)?;
    Ok(DatasetSummary { written, failed, seconds: start.elapsed().as_secs_f64(), body_fallbacks })
}

/// Subjects shown in `contact_sheet.png` (the first ones), the yaws and the view size of the sheet.
pub const SHEET_SUBJECTS: usize = 6;
/// See [`SHEET_SUBJECTS`].
pub const SHEET_YAWS: [f32; 3] = [0.0, 90.0, 180.0];
/// See [`SHEET_SUBJECTS`].
pub const SHEET_SIZE: usize = 256;

/// What [`write_subject`] returns: the framing used and, for the first [`SHEET_SUBJECTS`], the mesh for the sheet.
struct Written {
    framing: synth::Framing,
    mesh: Option<TexturedMesh>,
    /// Why `body_fof.npy` holds the body prior's fall-back (the inflation prior), when it does.
    body_fallback: Option<String>,
}

fn write_subject(
    assets: &SynthAssets,
    opts: &DatasetOptions,
    body: Option<&SharedBody>,
    back_pose: Option<&SharedPose>,
    index: usize,
    name: &str,
) -> Result<Written, EvalError> {
    let seed = subject_seed(opts.seed, index);
    let params = SubjectParams::sample(seed);
    let subject = synth::generate(assets, &params, opts.texture_size)?;
    let subject = framing::crop(&subject, opts.framing.of(index), &assets.rig)?;
    let dest = opts.out.join(name);
    // Everything goes into a hidden temporary folder first; it is removed on drop unless renamed into place.
    let tmp = tempfile::Builder::new()
        .prefix(&format!(".{name}-"))
        .suffix(".part")
        .tempdir_in(&opts.out)
        .map_err(|e| EvalError::io(&opts.out, e))?;
    let dir = tmp.path();
    let r = opts.size;

    crate::io::mesh_io::write_glb(&dir.join("mesh.glb"), &subject.mesh).map_err(synth::SynthError::from)?;
    let hi_source = render_ground_truth(&subject.mesh, &Camera::source(fof_grid(r)));
    let prior = prior_from_render(&hi_source, r, opts.fof_n)?;
    // The rendered source as the pipeline holds a photo: read by the body prior and the back image alike.
    let hi_input = (body.is_some() || back_pose.is_some()).then(|| source_input(&hi_source));
    let body_fof = match (body, &hi_input) {
        (Some(b), Some(input)) => Some(body_fof(input, b, r, opts.fof_n)?),
        _ => None,
    };
    let body_info = match &body_fof {
        None => serde_json::Value::Null,
        Some((_, None)) => json!({"source": "fitted body (pose network + fitter on the rendered source)"}),
        Some((_, Some(why))) => json!({"source": "inflation prior (the body prior's fall-back)", "fallback": why}),
    };
    let mut info = json!({
        "name": name,
        "index": index,
        "dataset_seed": opts.seed,
        "seed": seed,
        "params": params,
        "normalization": {
            "description": "p_cube = scale * (p_makehuman_dm - center); MakeHuman units are decimetres, +Y up, +Z forward; a cropped subject's includes its crop",
            "scale": subject.normalization.scale,
            "center": subject.normalization.center,
            "xz_radius": subject.normalization.xz_radius,
        },
        "framing": subject.crop,
        "garments": subject.garments,
        "mesh": {
            "vertices": subject.mesh.mesh.positions.len(),
            "triangles": subject.mesh.mesh.triangles.len(),
            "texture_size": opts.texture_size,
        },
        "test": is_test(index),
    });
    if body.is_some() {
        info["body_fof"] = body_info;
    }
    if let (Some(pose), Some(input)) = (back_pose, &hi_input) {
        let back = back_image(input, pose, r);
        info["back_image"] = json!(back.is_some());
        if let Some(back) = back {
            write_png(&dir.join("source_back.png"), &back)?;
        }
    }
    write_json(&dir.join("subject.json"), &info)?;

    let source = Camera::source(r);
    let gt = render_ground_truth(&subject.mesh, &source);
    write_view(dir, "source_", &gt)?;
    let fof = Fof::from_mesh(&subject.mesh.mesh, r, opts.fof_n).map_err(|e| EvalError::stage("ground-truth FOF", e))?;
    write_npy(&dir.join("fof.npy"), vec![r, r, opts.fof_n], fof.coeffs)?;
    write_npy(&dir.join("prior_fof.npy"), vec![r, r, opts.fof_n], prior)?;
    let mut body_fallback = None;
    if let Some((coeffs, fallback)) = body_fof {
        write_npy(&dir.join("body_fof.npy"), vec![r, r, opts.fof_n], coeffs)?;
        body_fallback = fallback;
    }

    if opts.views > 0 {
        let views_dir = dir.join("views");
        std::fs::create_dir_all(&views_dir).map_err(|e| EvalError::io(&views_dir, e))?;
        for (k, (yaw, pitch)) in view_angles(seed, opts.views).into_iter().enumerate() {
            let vdir = views_dir.join(format!("view_{k:02}"));
            std::fs::create_dir_all(&vdir).map_err(|e| EvalError::io(&vdir, e))?;
            let cam = Camera::orbit(yaw, pitch, r, r);
            let gt = render_ground_truth(&subject.mesh, &cam);
            write_view(&vdir, "", &gt)?;
            write_json(&vdir.join("camera.json"), &camera_json(&cam, yaw, pitch))?;
        }
    }
    // Replace a previous run's subject, then move the finished folder into place.
    if dest.exists() {
        std::fs::remove_dir_all(&dest).map_err(|e| EvalError::io(&dest, e))?;
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o755)).map_err(|e| EvalError::io(dir, e))?;
    }
    let tmp_path = tmp.keep();
    std::fs::rename(&tmp_path, &dest).map_err(|e| {
        let _ = std::fs::remove_dir_all(&tmp_path);
        EvalError::io(&dest, e)
    })?;
    Ok(Written { framing: subject.crop.framing, mesh: (index < SHEET_SUBJECTS).then_some(subject.mesh), body_fallback })
}

/// The silhouette-inflation prior of a subject's source view as the FOF net sees it at inference
/// (`prior_fof.npy`): the pipeline inflates the source mask at its FOF resolution
/// ([`SOURCE_RESOLUTION`], 512) and the network reads the coefficients box-averaged to its own resolution. So the
/// source mask is rendered at `k * size` with `k = max(1, 512 / size)`, inflated with the default
/// [`InflateParams`] ([`inflate_to_fof`]) and box-averaged by `k` to `size x size` (pixel-major `HWN`).
pub fn prior_fof(mesh: &TexturedMesh, size: usize, n: usize) -> Result<Vec<f32>, EvalError> {
    prior_from_render(&render_ground_truth(mesh, &Camera::source(fof_grid(size))), size, n)
}

/// The side of the grid the pipeline computes a per-input FOF on for a dataset of `size` pixels:
/// `k * size` with `k = max(1, 512 / size)` (see [`prior_fof`]).
fn fof_grid(size: usize) -> usize {
    size * (SOURCE_RESOLUTION / size.max(1)).max(1)
}

/// [`prior_fof`] of an already rendered source view at `fof_grid(size)`.
fn prior_from_render(gt: &GroundTruthView, size: usize, n: usize) -> Result<Vec<f32>, EvalError> {
    let hi = gt.width;
    let mask = gt.mask_image();
    // Closed along the whole outline: the prior the FOF net refines (`pipeline`'s network input), not the inflation
    // geometry, which stays open where the photo cuts the person.
    let fof = inflate_to_fof(&mask, n, &InflateParams::default(), None)
        .map_err(|e| EvalError::stage("inflation prior", e))?;
    Ok(box_downsample(&fof.coeffs, hi, n, hi / size.max(1)))
}

/// A rendered source view as the pipeline holds a normalised photo (premultiplied linear RGB and the mask, the
/// person already in the body cube): the input [`body_fof`] and [`back_image`] read.
pub fn source_input(gt: &GroundTruthView) -> NormalisedInput {
    NormalisedInput::in_source_view(gt.to_linear_rgba().map(|p| p.truncate()), gt.mask_image())
}

/// The body FOF of a rendered source view as inference computes it (`body_fof.npy`): the rendered source
/// (`normalised`, [`source_input`] of the source rendered at `fof_grid(size)`) goes through the pipeline's body prior
/// ([`crate::pipeline::body_prior_fof`]: pose network, fitter, body FOF reconciled with the silhouette; cold start)
/// and is box-averaged to `size` like [`prior_fof`]. Returns the coefficients (pixel-major `HWN`) and, when the body
/// prior fell back to the inflation prior (the pipeline's run-time fall-back), why.
pub fn body_fof(
    normalised: &NormalisedInput,
    body: &SharedBody,
    size: usize,
    n: usize,
) -> Result<(Vec<f32>, Option<String>), EvalError> {
    let hi = normalised.mask.width;
    let opts = PrepareOptions { resolution: hi, fof_order: n, ..Default::default() };
    let prior =
        inflate_to_fof(&normalised.mask, n, &opts.inflate, None).map_err(|e| EvalError::stage("inflation prior", e))?;
    let mut timings = StageTimings::default();
    let (fof, fallback) = body_prior_fof(normalised, &opts, body, prior, &mut timings);
    Ok((box_downsample(&fof.coeffs, hi, n, hi / size.max(1)), fallback))
}

/// The back image of a rendered source view (`normalised`, [`source_input`] of the source rendered at
/// `fof_grid(size)`) as inference computes it on a photo ([`back_image_of`]: the pose network's face, the clothing filter), box-averaged
/// to `size` and stored as 8-bit sRGB with straight alpha (alpha = the share of the box the back image covers, so
/// with the mask). `None` when the pose network finds no usable face (inference then has no back image either).
pub fn back_image(normalised: &NormalisedInput, pose: &SharedPose, size: usize) -> Option<image::RgbaImage> {
    let hi = normalised.mask.width;
    let back = back_image_of(normalised, pose, &mut StageTimings::default())?;
    let k = (hi / size.max(1)).max(1);
    let small = hi / k;
    // Premultiplied colour and coverage, box-averaged; straight colour where the box has any person.
    let flat: Vec<f32> =
        back.data.iter().zip(&normalised.mask.data).flat_map(|(c, &m)| [c.x, c.y, c.z, m.clamp(0.0, 1.0)]).collect();
    let boxed = box_downsample(&flat, hi, 4, k);
    let mut out = image::RgbaImage::new(small as u32, small as u32);
    for (p, v) in out.pixels_mut().zip(boxed.chunks_exact(4)) {
        if v[3] > 1e-6 {
            let [r, g, b] = crate::io::mesh_io::linear_to_srgb8(glam::Vec3::new(v[0], v[1], v[2]) / v[3]);
            *p = image::Rgba([r, g, b, (v[3] * 255.0).round() as u8]);
        }
    }
    Some(out)
}

/// Box-averages pixel-major (`HWN`) coefficients of a `side x side` grid by an integer factor `k`.
fn box_downsample(coeffs: &[f32], side: usize, n: usize, k: usize) -> Vec<f32> {
    if k == 1 {
        return coeffs.to_vec();
    }
    let small = side / k;
    let mut out = vec![0.0f32; small * small * n];
    let norm = 1.0 / (k * k) as f32;
    for row in 0..small {
        for col in 0..small {
            let o = &mut out[(row * small + col) * n..(row * small + col + 1) * n];
            for y in row * k..(row + 1) * k {
                for x in col * k..(col + 1) * k {
                    for (a, v) in o.iter_mut().zip(&coeffs[(y * side + x) * n..(y * side + x + 1) * n]) {
                        *a += v * norm;
                    }
                }
            }
        }
    }
    out
}

/// The `camera.json` of an orbit view (SPEC: kind, angles, 4x4 row-major view-from-world, projection, size).
pub fn camera_json(cam: &Camera, yaw_deg: f32, pitch_deg: f32) -> serde_json::Value {
    let m = Mat4::from(cam.view_from_world);
    let rows: Vec<[f32; 4]> = (0..4).map(|i| m.row(i).to_array()).collect();
    let projection = match cam.projection {
        Projection::Orthographic { half_width, half_height } => {
            json!({"orthographic": {"half_width": half_width, "half_height": half_height}})
        }
        Projection::Perspective { fov, near } => json!({"perspective": {
            "angle_left": fov.angle_left, "angle_right": fov.angle_right,
            "angle_up": fov.angle_up, "angle_down": fov.angle_down, "near": near}}),
    };
    json!({"kind": "orbit", "yaw_deg": yaw_deg, "pitch_deg": pitch_deg, "view_from_world": rows,
           "projection": projection, "width": cam.width, "height": cam.height})
}

fn write_json(path: &Path, value: &serde_json::Value) -> Result<(), EvalError> {
    let text = serde_json::to_vec_pretty(value).map_err(|e| EvalError::io(path, std::io::Error::other(e)))?;
    write_atomic(path, &text).map_err(|e| EvalError::io(path, e))
}

fn write_npy(path: &Path, shape: Vec<usize>, data: Vec<f32>) -> Result<(), EvalError> {
    let arr = NpyArray::new(shape, NpyData::F32(data)).map_err(|e| EvalError::io(path, std::io::Error::other(e)))?;
    write_atomic(path, &arr.to_bytes()).map_err(|e| EvalError::io(path, e))
}

/// Writes `{prefix}rgba.png`, `{prefix}depth.npy` and `{prefix}normal.npy` of a view.
fn write_view(dir: &Path, prefix: &str, gt: &GroundTruthView) -> Result<(), EvalError> {
    write_png(&dir.join(format!("{prefix}rgba.png")), &gt.to_srgba8())?;
    let (w, h) = (gt.width, gt.height);
    write_npy(&dir.join(format!("{prefix}depth.npy")), vec![h, w], gt.depth.clone())?;
    let normals: Vec<f32> = gt.normal.iter().flat_map(|n| n.to_array()).collect();
    write_npy(&dir.join(format!("{prefix}normal.npy")), vec![h, w, 3], normals)?;
    Ok(())
}

/// Writes an 8-bit RGBA PNG (fast compression) through a temporary file.
fn write_png(png: &Path, img: &image::RgbaImage) -> Result<(), EvalError> {
    let mut bytes = Vec::new();
    let enc = image::codecs::png::PngEncoder::new_with_quality(
        &mut bytes,
        image::codecs::png::CompressionType::Fast,
        image::codecs::png::FilterType::Adaptive,
    );
    image::ImageEncoder::write_image(enc, img.as_raw(), img.width(), img.height(), image::ExtendedColorType::Rgba8)
        .map_err(|e| EvalError::io(png, std::io::Error::other(e)))?;
    write_atomic(png, &bytes).map_err(|e| EvalError::io(png, e))
}

#[cfg(test)]
mod tests {
    use super::box_downsample;

    #[test]
    fn box_downsample_averages_blocks_per_coefficient() {
        // 4x4 grid, 2 coefficients: c0 = col + 4*row, c1 = 1 -> 2x2 blocks average their c0, keep c1.
        let coeffs: Vec<f32> = (0..16).flat_map(|i| [i as f32, 1.0]).collect();
        let out = box_downsample(&coeffs, 4, 2, 2);
        let want = [2.5f32, 1.0, 4.5, 1.0, 10.5, 1.0, 12.5, 1.0];
        assert_eq!(out.len(), want.len());
        for (a, b) in out.iter().zip(want) {
            assert!((a - b).abs() < 1e-6, "{out:?}");
        }
        assert_eq!(box_downsample(&coeffs, 4, 2, 1), coeffs);
    }
}
