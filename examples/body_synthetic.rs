//! Where the body prior's shape goes wrong on the evaluation's synthetic subjects:
//! `cargo run --example body_synthetic -- OUT_DIR [SUBJECTS] [SIZE] [SEED] [--whole-view]` (defaults 9, 256, 0:
//! the subjects, framings and source views of `r2human eval --subjects 9 --size 256`), or on a scan as
//! `r2human eval --scan FILE` sees it: `cargo run --example body_synthetic -- OUT_DIR --scan FILE [SIZE]` (one
//! picture `OUT_DIR/scan.png`; a scan has no body of its own apart from its clothes, so no oracle columns and no
//! joint errors).
//!
//! The photo frame is the one a photo of the subject would have ([`r2human::synth::Subject::source_frame`]: a
//! cropped subject's photo ends at the cut); `--whole-view` gives the body prior the whole source view instead.
//! Per subject, volumetric IoU against the ground-truth FOF of four geometries: the inflation prior; the body
//! prior as `--geometry body` computes it (pose network, fit, body FOF); the **oracle body** (the subject's own
//! body surface, garments left out, through the same reconciliation with the silhouette: what a perfect fit
//! would give); and the oracle body without the silhouette floor (`body::reconcile`). Each as `centred -> aligned
//! (shift)`: centred is the geometry placed in depth as `pipeline::compute_geometry` places it (the depth
//! convention, [`r2human::geometry::depth_centre::centre_fof`]: what `r2human eval` scores); aligned then shifts it
//! (whole depth samples) so that the centroids of the two thresholded occupancies agree. Then the fitted joints' 3-D error
//! against the subject's own (mean depth offset removed) for joints above the cut ("in") and below it ("out").
//! Pictures `OUT_DIR/subject_NNNN.png`: the source view with the landmarks the network sees (magenta) and the
//! fitted body's points for every landmark (cyan), then per geometry the side projection (depth across, the
//! camera on the left; height down) and the top projection (x across, depth down, the camera at the top) of the
//! occupancy after the alignment, ground truth green, the geometry red, both yellow.

use std::path::PathBuf;

use anyhow::Context;
use glam::Vec3;
use r2human::body::fit::world_scale;
use r2human::body::model::{BodyModel, ModelPoint};
use r2human::body::prior::{body_fof, BodyPrior};
use r2human::body::reconcile::{reconcile, ReconcileParams};
use r2human::buffer::{GrayImage, Image, RgbImage};
use r2human::eval::dataset::subject_seed;
use r2human::eval::ground_truth::render_ground_truth;
use r2human::geometry::camera::Camera;
use r2human::geometry::depth_centre::centre_fof;
use r2human::geometry::fof::{intervals_from_mesh, sheet_thickness};
use r2human::geometry::fof::{CosineTable, Fof};
use r2human::geometry::inflate::{inflate_to_fof, InflateParams};
use r2human::geometry::marching::ISO_LEVEL;
use r2human::geometry::mesh::TriMesh;
use r2human::io::image_io::save_rgb_png;
use r2human::neural::RuntimeOptions;
use r2human::pipeline::input::NormalisedInput;
use r2human::pipeline::{body_prior_fof, load_body, GeometryMode, PrepareOptions, SharedBody, StageTimings};
use r2human::synth::framing::{self, FramingChoice};
use r2human::synth::scan::load_scan;
use r2human::synth::{self, Subject, SubjectParams, SynthAssets};

const SAMPLES: usize = 128;

/// Decoded occupancy `[row][col][sample]` thresholded at the marching level.
struct Occupancy {
    w: usize,
    h: usize,
    cells: Vec<bool>,
}

impl Occupancy {
    fn of(fof: &Fof) -> Self {
        let table = CosineTable::new(fof.n, SAMPLES);
        let mut cells = vec![false; fof.width * fof.height * SAMPLES];
        let mut col = vec![0.0f32; SAMPLES];
        for r in 0..fof.height {
            for c in 0..fof.width {
                if fof.is_empty_column(c, r) {
                    continue;
                }
                fof.decode_column_with(&table, c, r, &mut col);
                let base = (r * fof.width + c) * SAMPLES;
                for (k, v) in col.iter().enumerate() {
                    cells[base + k] = *v >= ISO_LEVEL;
                }
            }
        }
        Self { w: fof.width, h: fof.height, cells }
    }

    fn at(&self, r: usize, c: usize, k: isize) -> bool {
        k >= 0 && (k as usize) < SAMPLES && self.cells[(r * self.w + c) * SAMPLES + k as usize]
    }

    /// Mean depth sample of the occupied cells.
    fn centroid(&self) -> f64 {
        let (mut s, mut n) = (0.0, 0.0);
        for (i, &o) in self.cells.iter().enumerate() {
            if o {
                s += (i % SAMPLES) as f64;
                n += 1.0;
            }
        }
        if n > 0.0 {
            s / n
        } else {
            SAMPLES as f64 * 0.5
        }
    }

    /// IoU with `truth` when this occupancy is read `shift` samples further back.
    fn iou(&self, truth: &Occupancy, shift: isize) -> f64 {
        let (mut inter, mut union) = (0u64, 0u64);
        for r in 0..self.h {
            for c in 0..self.w {
                for k in 0..SAMPLES as isize {
                    let (a, b) = (self.at(r, c, k - shift), truth.at(r, c, k));
                    inter += (a && b) as u64;
                    union += (a || b) as u64;
                }
            }
        }
        if union == 0 {
            1.0
        } else {
            inter as f64 / union as f64
        }
    }

    /// The side projection (depth across, rows down) and the top projection (columns across, depth down) of this
    /// (red) and `truth` (green), `shift` as in [`Occupancy::iou`].
    fn panels(&self, truth: &Occupancy, shift: isize) -> (RgbImage, RgbImage) {
        let mut side = Image { width: SAMPLES, height: self.h, data: vec![Vec3::ZERO; SAMPLES * self.h] };
        let mut top = Image { width: self.w, height: SAMPLES, data: vec![Vec3::ZERO; SAMPLES * self.w] };
        for r in 0..self.h {
            for c in 0..self.w {
                for k in 0..SAMPLES as isize {
                    let (a, b) = (self.at(r, c, k - shift), truth.at(r, c, k));
                    // Depth sample 0 is the back: the camera side is on the left (side view) and at the top (top view).
                    let sp = &mut side.data[r * SAMPLES + (SAMPLES - 1 - k as usize)];
                    let tp = &mut top.data[(SAMPLES - 1 - k as usize) * self.w + c];
                    for p in [sp, tp] {
                        if a {
                            p.x = 1.0;
                        }
                        if b {
                            p.y = 0.8;
                        }
                    }
                }
            }
        }
        (side, top)
    }
}

/// The triangles of `mesh` whose vertices all lie before `end` (the body of a subject: garments come after it).
fn body_only(mesh: &TriMesh, end: usize) -> TriMesh {
    let triangles = mesh.triangles.iter().filter(|t| t.iter().all(|&i| (i as usize) < end)).copied().collect();
    TriMesh::new(mesh.positions.clone(), triangles)
}

/// The fitted body's point for every landmark drawn on `source` (cyan; the landmarks the network sees magenta);
/// returns the fitted body's joints (body cube) with the landmark each belongs to.
fn draw_landmarks(prior: &BodyPrior, source: &mut RgbImage) -> anyhow::Result<Vec<(Vec3, usize)>> {
    let model = BodyModel::shared()?;
    let size = source.width;
    let heads = model.rest_heads(&prior.fit.pose.shape);
    let g = model.skinning(&prior.fit.pose, &heads);
    let mut dot = |x: f32, y: f32, colour: Vec3| {
        for dy in -1..=1i64 {
            for dx in -1..=1i64 {
                let (c, r) = (x as i64 + dx, y as i64 + dy);
                if c >= 0 && r >= 0 && (c as usize) < size && (r as usize) < source.height {
                    source.set(c as usize, r as usize, colour);
                }
            }
        }
    };
    let mut joints = Vec::new();
    for (k, l) in prior.landmarks.landmarks.iter().enumerate() {
        let Some(point) = model.landmark_points[k] else { continue };
        let fitted = model.point(point, &prior.fit.pose.shape, &heads, &g).as_vec3();
        if l.visibility >= 0.5 {
            dot(l.pixel.x, l.pixel.y, Vec3::new(1.0, 0.0, 1.0));
        }
        dot((fitted.x + 1.0) * 0.5 * size as f32, (1.0 - fitted.y) * 0.5 * size as f32, Vec3::new(0.0, 1.0, 1.0));
        if let ModelPoint::Joint(b) = point {
            joints.push((fitted, b));
        }
    }
    Ok(joints)
}

/// [`draw_landmarks`], and the mean 3-D error of the fitted joints against the subject's own, the mean depth offset
/// of the joints above the cut removed: `(above the cut, below it)`.
fn fitted_joints(prior: &BodyPrior, s: &Subject, source: &mut RgbImage) -> anyhow::Result<(f32, f32)> {
    let cut = s.crop.scale * (s.crop.cut_y - s.crop.center[1]);
    let pairs: Vec<(Vec3, Vec3, bool)> = draw_landmarks(prior, source)?
        .into_iter()
        .map(|(fitted, b)| (fitted, s.joints[b], s.joints[b].y >= cut))
        .collect();
    let above: Vec<_> = pairs.iter().filter(|p| p.2).collect();
    let dz = above.iter().map(|p| p.1.z - p.0.z).sum::<f32>() / above.len().max(1) as f32;
    let err = |wanted: bool| {
        let e: Vec<f32> = pairs.iter().filter(|p| p.2 == wanted).map(|p| (p.0 + Vec3::Z * dz - p.1).length()).collect();
        e.iter().sum::<f32>() / e.len().max(1) as f32
    };
    Ok((err(true), err(false)))
}

/// Side by side, left to right, on a dark grey ground, written to `path`.
fn save_sheet(path: &std::path::Path, panels: &[RgbImage]) -> anyhow::Result<()> {
    let width: usize = panels.iter().map(|p| p.width).sum();
    let height = panels.iter().map(|p| p.height).max().unwrap_or(1);
    let mut sheet = Image { width, height, data: vec![Vec3::splat(0.15); width * height] };
    let mut x0 = 0;
    for p in panels {
        for r in 0..p.height {
            for c in 0..p.width {
                sheet.data[r * width + x0 + c] = p.data[r * p.width + c];
            }
        }
        x0 += p.width;
    }
    save_rgb_png(path, &sheet).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// The body prior's (deterministic, cold-started) estimate of `input` once more, as `body_prior_fof` made it: for
/// its landmarks and pose.
fn estimate_again(body: &SharedBody, input: &NormalisedInput) -> anyhow::Result<Option<BodyPrior>> {
    let mut estimator = body.lock().map_err(|_| anyhow::anyhow!("body prior lock poisoned"))?;
    Ok(estimator.estimate(&input.rgb, &input.mask, Some(input.frame), false, &mut |_, _| {})?)
}

/// Per limb landmark the fit used: the network's 2-D point and relative depth (world landmarks scaled to cube
/// units by [`world_scale`]) against the fitted body's, depths about the hip centre (cube units, + toward the camera).
fn print_joints(prior: &BodyPrior, size: usize) -> anyhow::Result<()> {
    let model = BodyModel::shared()?;
    let lm = &prior.landmarks;
    let used: Vec<usize> = prior.fit.used.iter().map(|u| u.0).collect();
    let Some(kappa) = world_scale(lm, &used, size) else { return Ok(()) };
    let heads = model.rest_heads(&prior.fit.pose.shape);
    let g = model.skinning(&prior.fit.pose, &heads);
    let fitted = |i: usize| model.landmark_points[i].map(|p| model.point(p, &prior.fit.pose.shape, &heads, &g));
    let (Some(lh), Some(rh)) = (fitted(23), fitted(24)) else { return Ok(()) };
    let hip_z = 0.5 * (lh.z + rh.z);
    let net_hip = 0.5 * (lm.world[23].z + lm.world[24].z) as f64;
    println!("landmark  vis    network x, y, z       fitted x, y, z   (cube; z about the hip centre)");
    for i in 11..29 {
        let Some(f) = fitted(i) else { continue };
        let c = lm.cube(i, size);
        let nz = kappa * (lm.world[i].z as f64 - net_hip);
        println!(
            "{:9} {:.2}  {:+.3} {:+.3} {:+.3}   {:+.3} {:+.3} {:+.3}{}",
            r2human::body::pose::NAMES[i],
            lm.landmarks[i].visibility,
            c.x,
            c.y,
            nz,
            f.x,
            f.y,
            f.z - hip_z,
            if used.contains(&i) { "" } else { "  (not used)" }
        );
    }
    Ok(())
}

/// `--scan FILE`: the inflation prior and the body prior of the scan's source view against its ground truth.
fn scan(out: &std::path::Path, file: &std::path::Path, size: usize, body: &SharedBody) -> anyhow::Result<()> {
    let scan = load_scan(file)?;
    let view = render_ground_truth(&scan.mesh, &Camera::source(size));
    let rgb: RgbImage = view.to_linear_rgba().map(|p| p.truncate());
    let mask: GrayImage = view.mask_image();
    let input = NormalisedInput::in_source_view(rgb.clone(), mask.clone());
    let opts = PrepareOptions { resolution: size, depth_samples: size, ..Default::default() };
    let n = opts.fof_order;
    let truth = Occupancy::of(&Fof::from_mesh(&scan.mesh.mesh, size, n)?);
    let prior =
        inflate_to_fof(&mask, n, &InflateParams::default(), Some(r2human::body::prior::effective_frame(&mask, None)))?;
    let (fitted, fallback) = body_prior_fof(&input, &opts, body, prior.clone(), &mut StageTimings::default());
    let estimate = estimate_again(body, &input)?;
    let mut source = rgb;
    if let Some(p) = &estimate {
        draw_landmarks(p, &mut source)?;
        println!(
            "fit: cost {:.2}, {} evaluations, shape {:?}; landmarks' facing {:?} (after body::prior::facing_the_camera)",
            p.fit.cost,
            p.fit.evaluations,
            p.fit.pose.shape,
            p.landmarks.facing()
        );
        print_joints(p, size)?;
    }
    let mut panels = vec![source];
    for (name, fof) in [("inflation", &prior), ("body", &fitted)] {
        let o = Occupancy::of(&centre_fof(fof.clone()).0);
        let shift = (truth.centroid() - o.centroid()).round() as isize;
        println!(
            "{name:10} volumetric IoU {:.3} (aligned {:.3}, shift {shift:+})",
            o.iou(&truth, 0),
            o.iou(&truth, shift)
        );
        let (side, top) = o.panels(&truth, 0);
        panels.push(side);
        panels.push(top);
    }
    if let Some(why) = fallback {
        println!("[body: {why}]");
    }
    save_sheet(&out.join("scan.png"), &panels)
}

fn main() -> anyhow::Result<()> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let whole_view = args.iter().any(|a| a == "--whole-view");
    args.retain(|a| a != "--whole-view");
    let usage = "usage: body_synthetic OUT_DIR [SUBJECTS] [SIZE] [SEED] [--whole-view] | OUT_DIR --scan FILE [SIZE]";
    let out = PathBuf::from(args.first().context(usage)?);
    if args.get(1).is_some_and(|a| a == "--scan") {
        let file = PathBuf::from(args.get(2).context(usage)?);
        let size: usize = args.get(3).map(|s| s.parse()).transpose().context(usage)?.unwrap_or(256);
        std::fs::create_dir_all(&out)?;
        let body = load_body(GeometryMode::Body, &RuntimeOptions::default())?.context("body prior")?;
        return scan(&out, &file, size, &body);
    }
    let subjects: usize = args.get(1).map(|s| s.parse()).transpose().context(usage)?.unwrap_or(9);
    let size: usize = args.get(2).map(|s| s.parse()).transpose().context(usage)?.unwrap_or(256);
    let seed: u64 = args.get(3).map(|s| s.parse()).transpose().context(usage)?.unwrap_or(0);
    std::fs::create_dir_all(&out)?;
    let assets = SynthAssets::shared()?;
    let body = load_body(GeometryMode::Body, &RuntimeOptions::default())?.context("body prior")?;
    let opts = PrepareOptions { resolution: size, depth_samples: size, ..Default::default() };
    let inflate_params = InflateParams::default();
    let bare = ReconcileParams {
        thickness: inflate_params.thickness,
        min_half_thickness: inflate_params.min_half_thickness,
        silhouette_floor: 0.0,
        ..Default::default()
    };
    let names = ["inflation", "body", "oracle body", "oracle, no floor"];
    let mut sums = [[0.0f64; 2]; 4];
    println!("subject framing      {}   joints in / out", names.map(|n| format!("{n:>22}")).join(""));
    for i in 0..subjects {
        let s = synth::generate(assets, &SubjectParams::sample(subject_seed(seed, i)), 256)?;
        let s = framing::crop(&s, FramingChoice::Mixed.of(i), &assets.rig)?;
        let view = render_ground_truth(&s.mesh, &Camera::source(size));
        let rgb: RgbImage = view.to_linear_rgba().map(|p| p.truncate());
        let mask: GrayImage = view.mask_image();
        let mut input = NormalisedInput::in_source_view(rgb.clone(), mask.clone());
        if !whole_view {
            input.frame = s.source_frame(size);
        }
        let n = opts.fof_order;
        let truth = Fof::from_mesh(&s.mesh.mesh, size, n)?;
        let prior =
            inflate_to_fof(&mask, n, &inflate_params, Some(r2human::body::prior::effective_frame(&mask, None)))?;
        let (fitted, fallback) = body_prior_fof(&input, &opts, &body, prior.clone(), &mut StageTimings::default());
        let estimate = estimate_again(&body, &input)?;
        let end = s.garments.first().map(|g| g.vertices.start).unwrap_or(s.mesh.mesh.positions.len());
        let own = body_only(&s.mesh.mesh, end);
        let oracle = body_fof(&own, &mask, Some(input.frame), n, &inflate_params)?;
        let own_intervals = intervals_from_mesh(&own, size, size, sheet_thickness(n));
        let oracle_bare = Fof::from_intervals(&reconcile(&own_intervals, &mask, Some(input.frame), &bare), n)?;
        let t = Occupancy::of(&truth);
        let mut source = rgb;
        let joints = match &estimate {
            Some(p) => {
                let (a, b) = fitted_joints(p, &s, &mut source)?;
                format!("   {a:.3} / {b:.3}")
            }
            None => String::new(),
        };
        let mut panels = vec![source];
        let mut line = format!("{i:7} {:13}", s.crop.framing.label());
        for (k, fof) in [&prior, &fitted, &oracle, &oracle_bare].into_iter().enumerate() {
            // Placed in depth as `pipeline::compute_geometry` places every geometry.
            let o = Occupancy::of(&centre_fof(fof.clone()).0);
            let shift = (t.centroid() - o.centroid()).round() as isize;
            let (raw, aligned) = (o.iou(&t, 0), o.iou(&t, shift));
            sums[k][0] += raw;
            sums[k][1] += aligned;
            line += &format!("  {raw:.3} -> {aligned:.3} ({shift:+3})");
            let (side, top) = o.panels(&t, shift);
            panels.push(side);
            panels.push(top);
        }
        line += &joints;
        if let Some(why) = fallback {
            line += &format!("  [body: {why}]");
        }
        println!("{line}");
        save_sheet(&out.join(format!("subject_{i:04}.png")), &panels)?;
    }
    let m = subjects.max(1) as f64;
    let means: Vec<String> = sums.iter().map(|s| format!("  {:.3} -> {:.3}      ", s[0] / m, s[1] / m)).collect();
    println!("mean                 {}", means.join(""));
    Ok(())
}
