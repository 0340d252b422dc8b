//! What the pose network reads of a person turning once (`eval --turn`'s clips): `cargo run --release --example
//! turn_pose -- [SUBJECTS] [SEED] [SIZE] [track] > turn_pose.csv` (defaults 3, 0, 512).
//!
//! Per clip and frame: the true turn (degrees), the pose score, then for the network's read of the frame (`r`) and
//! of its left-right mirror image brought back (`m`; with `track`, the one-run tracked read the person model makes,
//! `PoseEstimator::track`), every landmark's world
//! position (x, y, z), visibility and pixel x. The CSV is for studying the orientation cues; the person model's
//! tracker is tested in `person_model::tests` and measured by `eval --turn` (`turn_model.csv`).

use anyhow::Context;
use r2human::body::pose::{PoseEstimator, PoseLandmarks, LANDMARK_COUNT};
use r2human::body::prior::mirrored_left_right;
use r2human::buffer::{GrayImage, RgbImage};
use r2human::eval::dataset::subject_seed;
use r2human::eval::ground_truth::render_ground_truth;
use r2human::geometry::camera::Camera;
use r2human::neural::RuntimeOptions;
use r2human::synth::turn::{TurnOptions, TurningClip};
use r2human::synth::{SubjectParams, SynthAssets};

fn columns(prefix: &str, l: Option<&PoseLandmarks>) -> String {
    let mut out = Vec::new();
    for i in 0..LANDMARK_COUNT {
        match l {
            Some(l) => {
                let w = l.world[i];
                out.push(format!(
                    "{:.4},{:.4},{:.4},{:.3},{:.1}",
                    w.x, w.y, w.z, l.landmarks[i].visibility, l.landmarks[i].pixel.x
                ));
            }
            None => out.push(",,,,".to_string()),
        }
    }
    let _ = prefix;
    out.join(",")
}

fn header(prefix: &str) -> String {
    (0..LANDMARK_COUNT)
        .map(|i| format!("{prefix}{i}x,{prefix}{i}y,{prefix}{i}z,{prefix}{i}v,{prefix}{i}px"))
        .collect::<Vec<_>>()
        .join(",")
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: turn_pose [SUBJECTS] [SEED] [SIZE] [track]";
    let subjects: usize = args.first().map(|s| s.parse()).transpose().context(usage)?.unwrap_or(3);
    let seed: u64 = args.get(1).map(|s| s.parse()).transpose().context(usage)?.unwrap_or(0);
    let size: usize = args.get(2).map(|s| s.parse()).transpose().context(usage)?.unwrap_or(512);
    // `track` as 4th argument: the `m` columns are the one-run tracked read the person model makes instead.
    let track = args.get(3).is_some_and(|a| a == "track");
    let mut pose = PoseEstimator::load(None, &RuntimeOptions::default())?;
    let assets = SynthAssets::shared()?;
    println!("seed,subject,frame,truth,score,{},{}", header("r"), header("m"));
    for s in 0..subjects {
        let options = TurnOptions::default();
        let clip = TurningClip::synthetic(assets, &SubjectParams::sample(subject_seed(seed, s)), 1024, options)?;
        let mut region = None;
        for i in 0..clip.frames() {
            let mesh = clip.frame(Some(assets), i)?;
            let view = render_ground_truth(&mesh, &Camera::source(size));
            let rgb: RgbImage = view.to_linear_rgba().map(|p| p.truncate());
            let mask: GrayImage = view.mask_image();
            let first = pose.estimate(&rgb, &mask, None)?;
            let mirror = if track {
                let t = pose.track(&rgb, &mask, region)?;
                region = t.as_ref().and_then(|t| t.next_region);
                t
            } else {
                pose.estimate(&mirrored_left_right(&rgb), &mirrored_left_right(&mask), None)?
                    .map(|m| m.mirrored_left_right(size as f32))
            };
            println!(
                "{seed},{s},{i},{},{:.3},{},{}",
                options.yaw(i),
                first.as_ref().map_or(0.0, |f| f.score),
                columns("r", first.as_ref()),
                columns("m", mirror.as_ref())
            );
        }
    }
    Ok(())
}
