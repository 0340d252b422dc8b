//! How often the pose network reads a person seen from the front as facing away, and what each way of turning its
//! landmarks to the front does to their depths: `cargo run --release --example body_facing -- [SUBJECTS] [SEED]`
//! (defaults 120, 7).
//!
//! Per synthetic subject (whole body, seen from the front at 512², as the photo pipeline assumes), the network reads
//! the source view and its left-right mirror image (brought back, [`PoseLandmarks::mirrored_left_right`]). Printed:
//! both reads' facing ([`PoseLandmarks::facing`]) and the mean depth error, against the subject's own joints, of
//! the shoulders, elbows, wrists, hips, knees and ankles (relative to the hip centre; the world landmarks' metres
//! scaled to cube units by their x, y extent against the joints'; cube units, a person about 1.8 tall) of: the
//! first read turned by `facing_the_camera` (mirrored in depth when it faces away); the first read with its sides
//! swapped but its depths kept when it faces away; and `front_read` (the body prior's choice: the mirror image's
//! read where the first faces away and the mirror read faces the camera).

use anyhow::Context;
use glam::Vec3;
use r2human::body::model::{BodyModel, ModelPoint};
use r2human::body::pose::{PoseEstimator, PoseLandmarks};
use r2human::body::prior::{facing_the_camera, front_read, mirrored_left_right, says_back};
use r2human::buffer::{GrayImage, RgbImage};
use r2human::eval::dataset::subject_seed;
use r2human::eval::ground_truth::render_ground_truth;
use r2human::geometry::camera::Camera;
use r2human::neural::RuntimeOptions;
use r2human::synth::{self, SubjectParams, SynthAssets};

/// Shoulders, elbows, wrists, hips, knees, ankles (left, right).
const JOINTS: [usize; 12] = [11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28];
const SIZE: usize = 512;

/// Mean depth error of `JOINTS` of `l` against `truth` (cube positions in `JOINTS` order), both about their hip
/// centre.
fn depth_error(l: &PoseLandmarks, truth: &[Vec3]) -> f32 {
    let w = &l.world;
    let (wh, th) = ((w[23] + w[24]) * 0.5, (truth[6] + truth[7]) * 0.5);
    let (mut a, mut b) = (0.0, 0.0);
    for (k, &i) in JOINTS.iter().enumerate() {
        a += (truth[k] - th).truncate().length();
        b += (w[i] - wh).truncate().length();
    }
    let scale = a / b.max(1e-6);
    let e: f32 = JOINTS.iter().enumerate().map(|(k, &i)| ((w[i].z - wh.z) * scale - (truth[k].z - th.z)).abs()).sum();
    e / JOINTS.len() as f32
}

/// `l` with left and right swapped but positions and depths kept when it faces away (the other way to turn it).
fn sides_swapped(l: &PoseLandmarks) -> PoseLandmarks {
    if !says_back(l) {
        return l.clone();
    }
    // Mirrored in depth (sides swapped, depths negated), then the depths negated back.
    let mut out = l.mirrored_in_depth();
    out.landmarks.iter_mut().for_each(|m| m.depth = -m.depth);
    out.world.iter_mut().for_each(|w| w.z = -w.z);
    out
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: body_facing [SUBJECTS] [SEED]";
    let subjects: usize = args.first().map(|s| s.parse()).transpose().context(usage)?.unwrap_or(120);
    let seed: u64 = args.get(1).map(|s| s.parse()).transpose().context(usage)?.unwrap_or(7);
    let mut pose = PoseEstimator::load(None, &RuntimeOptions::default())?;
    let model = BodyModel::shared()?;
    let assets = SynthAssets::shared()?;
    let (mut sums, mut count, mut back, mut mirror_front) = ([0.0f32; 3], 0usize, 0usize, 0usize);
    println!("subject  facing first / mirror   depth error: turned  sides swapped  front_read");
    for i in 0..subjects {
        let s = synth::generate(assets, &SubjectParams::sample(subject_seed(seed, i)), 256)?;
        let truth: Vec<Vec3> = JOINTS
            .iter()
            .map(|&k| match model.landmark_points[k] {
                Some(ModelPoint::Joint(b)) => Ok(s.joints[b]),
                _ => anyhow::bail!("landmark {k} is not a joint of the body model"),
            })
            .collect::<anyhow::Result<_>>()?;
        let view = render_ground_truth(&s.mesh, &Camera::source(SIZE));
        let rgb: RgbImage = view.to_linear_rgba().map(|p| p.truncate());
        let mask: GrayImage = view.mask_image();
        let first = pose.estimate(&rgb, &mask, None)?;
        let mirror = pose.estimate(&mirrored_left_right(&rgb), &mirrored_left_right(&mask), None)?;
        let (Some(first), Some(mirror)) = (first, mirror.map(|m| m.mirrored_left_right(SIZE as f32))) else {
            println!("{i:7}  (no pose)");
            continue;
        };
        if says_back(&first) {
            back += 1;
            mirror_front += usize::from(!says_back(&mirror) && mirror.facing().is_some_and(|f| f > 0.5));
        }
        let e = [
            depth_error(&facing_the_camera(first.clone()), &truth),
            depth_error(&sides_swapped(&first), &truth),
            depth_error(&front_read(first.clone(), Some(mirror.clone())), &truth),
        ];
        let f = |l: &PoseLandmarks| l.facing().unwrap_or(f32::NAN);
        println!(
            "{i:7}  {:+.2} / {:+.2}              {:.3}   {:.3}          {:.3}",
            f(&first),
            f(&mirror),
            e[0],
            e[1],
            e[2]
        );
        sums.iter_mut().zip(e).for_each(|(s, e)| *s += e);
        count += 1;
    }
    let n = count.max(1) as f32;
    println!(
        "mean over {count}: turned {:.4}, sides swapped {:.4}, front_read {:.4}; first read faces away on {back}, \
         of those the mirror read faces the camera on {mirror_front}",
        sums[0] / n,
        sums[1] / n,
        sums[2] / n
    );
    Ok(())
}
