//! Does the fit's cost tell which way the legs go in depth? For each input the body prior is fitted as
//! `--geometry body` fits it (A), and again to the same landmarks with the legs' depths (knees, ankles, heels,
//! toes; image and world) mirrored about the hips (B), and with the arms' (elbows to fingers) mirrored about the
//! shoulders (C). Prints the fits' final costs and the volumetric IoU of `body-placed` drawn with each body, with
//! the lower-cost of A and B, and with the mean of A's and B's placements (a hedge that leaves the legs where the
//! two disagree): `cargo run --release --example fit_ambiguity -- [SUBJECTS] [SEED]
//! [SIZE]` or `-- --scans [--size N] FILE...`. Only volume; a diagnostic for docs/geometry.md, "Which geometry wins
//! where".

// Only the inputs of the shared harness are used here.
#[allow(dead_code)]
#[path = "common/cases.rs"]
mod cases;

use r2human::body::fit::{fit_body, FitTarget};
use r2human::body::placed::{centred, depth_shifts, place, PLACEMENT_WEIGHT};
use r2human::body::pose::{index, PoseLandmarks};
use r2human::body::prior::{body_intervals_with, centre_depth, limbs_seen, BodyEstimator};
use r2human::body::reconcile::SilhouetteProfile;
use r2human::buffer::GrayImage;
use r2human::eval::runner::fof_occupancy_iou;
use r2human::geometry::depth_centre::centre_fof;
use r2human::geometry::fof::Fof;
use r2human::geometry::inflate::{inflate_resolvable, InflateParams};
use r2human::pipeline::centre_visible_depth;

/// `landmarks` with the depths of `parts` (landmark indices) mirrored about the mean depth of `pivot` (image depth
/// and world z).
fn mirrored(landmarks: &PoseLandmarks, parts: std::ops::Range<usize>, pivot: [usize; 2]) -> PoseLandmarks {
    let mut out = landmarks.clone();
    let centre = 0.5 * (landmarks.landmarks[pivot[0]].depth + landmarks.landmarks[pivot[1]].depth);
    let centre_world = 0.5 * (landmarks.world[pivot[0]].z + landmarks.world[pivot[1]].z);
    let count = out.landmarks.len().min(out.world.len());
    for i in parts.filter(|&i| i < count) {
        out.landmarks[i].depth = 2.0 * centre - out.landmarks[i].depth;
        out.world[i].z = 2.0 * centre_world - out.world[i].z;
    }
    out
}

/// The legs (knees to toes) mirrored about the hips.
fn legs_mirrored(landmarks: &PoseLandmarks) -> PoseLandmarks {
    mirrored(landmarks, index::LEFT_KNEE..33, [index::LEFT_HIP, index::RIGHT_HIP])
}

/// The arms (elbows to fingers) mirrored about the shoulders.
fn arms_mirrored(landmarks: &PoseLandmarks) -> PoseLandmarks {
    mirrored(landmarks, index::LEFT_ELBOW..index::LEFT_HIP, [index::LEFT_SHOULDER, index::RIGHT_SHOULDER])
}

fn main() -> anyhow::Result<()> {
    let (cases, _) = cases::from_args("fit_ambiguity")?;
    let mut estimator = BodyEstimator::load(None, &Default::default())?;
    let model = estimator.model();
    let params = InflateParams::default();
    println!(
        "{:<20}{:>10}{:>10}{:>8}{:>8}{:>8}{:>8}{:>10}{:>8}",
        "input", "cost A", "cost B", "A", "B", "min", "hedge", "cost C", "C"
    );
    let mut sums = [0.0f64; 5];
    let mut n = 0;
    for c in &cases {
        let (mask, rgb) = (&c.input.mask, &c.input.rgb);
        let Some(prior) = estimator.estimate(rgb, mask, Some(c.input.frame), false, &mut |_, _| {})? else {
            println!("{:<20} no pose", c.label);
            continue;
        };
        let frame = prior.frame();
        let silhouette = SilhouetteProfile::of(mask);
        let surfaces = inflate_resolvable(mask, cases::N, &params, Some(frame))?;
        let min_visibility = estimator.options.min_visibility;
        let shifts = |landmarks: &PoseLandmarks| -> anyhow::Result<(f64, GrayImage)> {
            let fit = fit_body(model, &FitTarget::new(landmarks, mask), None, &estimator.options);
            let (_, mesh) = centre_depth(model, &fit.pose);
            let mesh = centre_visible_depth(model.mesh_seen(&mesh, &limbs_seen(landmarks, min_visibility)), mask);
            let intervals = body_intervals_with(&mesh, mask, Some(frame), cases::N, &params, Some(&silhouette));
            let s =
                depth_shifts(&intervals, &surfaces.mask, PLACEMENT_WEIGHT).ok_or_else(|| anyhow::anyhow!("no body"))?;
            Ok((fit.cost, s))
        };
        let ((cost_a, a), (cost_b, b)) = (shifts(&prior.landmarks)?, shifts(&legs_mirrored(&prior.landmarks))?);
        let (cost_c, arms) = shifts(&arms_mirrored(&prior.landmarks))?;
        let iou = |s: &GrayImage| -> anyhow::Result<f64> {
            let placed = centred(place(surfaces.clone(), s));
            let fof = centre_fof(Fof::from_depth_maps(&placed.front, &placed.back, &placed.mask, cases::N)?).0;
            Ok(f64::from(fof_occupancy_iou(&fof, &c.truth, cases::IOU_SAMPLES)))
        };
        let mut hedge = a.clone();
        hedge.data.iter_mut().zip(&b.data).for_each(|(x, y)| *x = 0.5 * (*x + *y));
        let (ia, ib, ih, ic) = (iou(&a)?, iou(&b)?, iou(&hedge)?, iou(&arms)?);
        let im = if cost_a <= cost_b { ia } else { ib };
        for (s, v) in sums.iter_mut().zip([ia, ib, im, ih, ic]) {
            *s += v;
        }
        n += 1;
        println!(
            "{:<20}{cost_a:>10.4}{cost_b:>10.4}{ia:>8.3}{ib:>8.3}{im:>8.3}{ih:>8.3}{cost_c:>10.4}{ic:>8.3}",
            c.label
        );
    }
    let m = |s: f64| s / n.max(1) as f64;
    let [a, b, min, hedge, c] = sums.map(m);
    println!("{:<20}{:>10}{:>10}{a:>8.3}{b:>8.3}{min:>8.3}{hedge:>8.3}{:>10}{c:>8.3}", "mean", "", "", "");
    Ok(())
}
