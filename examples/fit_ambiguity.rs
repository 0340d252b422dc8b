//! Does the fit's cost tell which way the legs go in depth? For each input the body prior is fitted as
//! `--geometry body` fits it (A), and again to the same landmarks with the legs' depths (knees, ankles, heels,
//! toes; image and world) mirrored about the hips (B). Prints both fits' final costs and the volumetric IoU of
//! `body-placed` drawn with each body, with the min-cost body, and with the mean of the two placements (a hedge
//! that leaves the legs where the two disagree): `cargo run --release --example fit_ambiguity -- [SUBJECTS] [SEED]
//! [SIZE]` or `-- --scans [--size N] FILE...`. Only volume; a diagnostic for the README's "a steadier fit".

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

/// `landmarks` with the legs' depths mirrored about the hips' (image depth and world z).
fn legs_mirrored(landmarks: &PoseLandmarks) -> PoseLandmarks {
    let mut out = landmarks.clone();
    let hip = 0.5 * (landmarks.landmarks[index::LEFT_HIP].depth + landmarks.landmarks[index::RIGHT_HIP].depth);
    let hip_world = 0.5 * (landmarks.world[index::LEFT_HIP].z + landmarks.world[index::RIGHT_HIP].z);
    for i in index::LEFT_KNEE..out.landmarks.len().min(33) {
        out.landmarks[i].depth = 2.0 * hip - out.landmarks[i].depth;
        out.world[i].z = 2.0 * hip_world - out.world[i].z;
    }
    out
}

fn main() -> anyhow::Result<()> {
    let (cases, _) = cases::from_args("fit_ambiguity")?;
    let mut estimator = BodyEstimator::load(None, &Default::default())?;
    let model = estimator.model();
    let params = InflateParams::default();
    println!("{:<20}{:>10}{:>10}{:>8}{:>8}{:>8}{:>8}", "input", "cost A", "cost B", "A", "B", "min", "hedge");
    let mut sums = [0.0f64; 4];
    let mut n = 0;
    for c in &cases {
        let (mask, rgb) = (&c.input.mask, &c.input.rgb);
        let Some(prior) = estimator.estimate(rgb, mask, Some(c.input.frame), false, &mut |_, _| {})? else {
            println!("{:<20} no pose", c.label);
            continue;
        };
        let frame = prior.frame();
        let silhouette = SilhouetteProfile::of(mask);
        let surfaces = inflate_resolvable(mask, cases::N, &params)?;
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
        let iou = |s: &GrayImage| -> anyhow::Result<f64> {
            let placed = centred(place(surfaces.clone(), s));
            let fof = centre_fof(Fof::from_depth_maps(&placed.front, &placed.back, &placed.mask, cases::N)?).0;
            Ok(f64::from(fof_occupancy_iou(&fof, &c.truth, cases::IOU_SAMPLES)))
        };
        let mut hedge = a.clone();
        hedge.data.iter_mut().zip(&b.data).for_each(|(x, y)| *x = 0.5 * (*x + *y));
        let (ia, ib, ih) = (iou(&a)?, iou(&b)?, iou(&hedge)?);
        let im = if cost_a <= cost_b { ia } else { ib };
        for (s, v) in sums.iter_mut().zip([ia, ib, im, ih]) {
            *s += v;
        }
        n += 1;
        println!("{:<20}{cost_a:>10.4}{cost_b:>10.4}{ia:>8.3}{ib:>8.3}{im:>8.3}{ih:>8.3}", c.label);
    }
    let m = |s: f64| s / n.max(1) as f64;
    println!(
        "{:<20}{:>10}{:>10}{:>8.3}{:>8.3}{:>8.3}{:>8.3}",
        "mean",
        "",
        "",
        m(sums[0]),
        m(sums[1]),
        m(sums[2]),
        m(sums[3])
    );
    Ok(())
}
