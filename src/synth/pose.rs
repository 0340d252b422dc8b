//! Seeded, plausible body poses for the MPFB2 rig: torso twist/lean, head turn, arm placement (including arms
//! folded across the body, which self-occlude from the front), elbows, hips and knees.
//!
//! Angles are in degrees and rotations are built in the rest-pose world frame (MakeHuman axes: +Y up, +Z
//! forward, +X the model's left), about each bone's head (see [`super::rig`]).

use std::collections::HashMap;

use glam::{Quat, Vec3};
use serde::{Deserialize, Serialize};

use super::rig::Rig;
use super::Rng;

/// Placement of one arm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ArmPose {
    /// Upper-arm direction as `[elevation, azimuth]`: elevation 0 hangs straight down, 90 is horizontal;
    /// azimuth 0 points sideways away from the body, 90 forward, above 90 across the front of the body.
    /// `None` keeps the rest (A-pose) direction.
    pub direction: Option<[f32; 2]>,
    /// Twist of the upper arm about its own axis.
    pub twist: f32,
    /// Elbow flexion (0 straight, positive bends the forearm forward).
    pub elbow: f32,
    /// Wrist flexion.
    pub wrist: f32,
}

/// Placement of one leg.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LegPose {
    /// Hip flexion (positive swings the leg forward).
    pub flexion: f32,
    /// Hip abduction (positive moves the leg away from the midline).
    pub abduction: f32,
    /// Knee flexion (positive bends the shin backward).
    pub knee: f32,
}

/// A full pose. [`PoseParams::rest`] is the identity (the base mesh's A-pose).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoseParams {
    /// Torso rotation about the vertical axis (positive turns the chest toward the model's left).
    pub torso_twist: f32,
    /// Forward lean of the torso.
    pub torso_lean: f32,
    /// Sideways bend of the torso (positive toward the model's right).
    pub torso_side: f32,
    /// Head yaw, pitch (positive nods down) and roll.
    pub head: [f32; 3],
    /// Left and right arm.
    pub arms: [ArmPose; 2],
    /// Left and right leg.
    pub legs: [LegPose; 2],
    /// Whether an arm was placed across the body (self-occluding from the front).
    pub arm_across: bool,
}

impl PoseParams {
    /// The rest pose: no rotation anywhere.
    pub fn rest() -> Self {
        let arm = ArmPose { direction: None, twist: 0.0, elbow: 0.0, wrist: 0.0 };
        let leg = LegPose { flexion: 0.0, abduction: 0.0, knee: 0.0 };
        Self {
            torso_twist: 0.0,
            torso_lean: 0.0,
            torso_side: 0.0,
            head: [0.0; 3],
            arms: [arm; 2],
            legs: [leg; 2],
            arm_across: false,
        }
    }

    /// A random plausible pose. About a third of the poses fold one arm across the body.
    pub fn sample(rng: &mut Rng) -> Self {
        let across_side = if rng.uniform() < 0.35 { Some(rng.below(2)) } else { None };
        let mut arms = [PoseParams::rest().arms[0]; 2];
        for (side, arm) in arms.iter_mut().enumerate() {
            let kind = if across_side == Some(side) { 2 } else { [0, 0, 1, 3, 4][rng.below(5)] };
            let (elev, azim, elbow) = match kind {
                0 => (rng.range(10.0, 45.0), rng.range(-20.0, 40.0), rng.range(0.0, 45.0)), // relaxed
                1 => (rng.range(40.0, 95.0), rng.range(55.0, 100.0), rng.range(0.0, 70.0)), // reaching forward
                2 => (rng.range(55.0, 80.0), rng.range(108.0, 128.0), rng.range(75.0, 115.0)), // across the body
                3 => (rng.range(60.0, 100.0), rng.range(-10.0, 35.0), rng.range(0.0, 50.0)), // raised sideways
                _ => (rng.range(20.0, 40.0), rng.range(70.0, 95.0), rng.range(80.0, 120.0)), // hand to chest
            };
            *arm = ArmPose {
                direction: Some([elev, azim]),
                twist: rng.range(-25.0, 25.0),
                elbow,
                wrist: rng.range(-25.0, 25.0),
            };
        }
        let mut legs = [PoseParams::rest().legs[0]; 2];
        let step = rng.uniform() < 0.5;
        for (side, leg) in legs.iter_mut().enumerate() {
            let forward = step && side == 0;
            let flexion = if forward { rng.range(10.0, 35.0) } else { rng.range(-12.0, 10.0) };
            let knee = rng.range(0.0, if forward { 40.0 } else { 20.0 }).max(0.0);
            *leg = LegPose { flexion, abduction: rng.range(-4.0, 12.0), knee };
        }
        if step && rng.uniform() < 0.5 {
            legs.swap(0, 1);
        }
        Self {
            torso_twist: rng.range(-25.0, 25.0),
            torso_lean: rng.range(-5.0, 15.0),
            torso_side: rng.range(-8.0, 8.0),
            head: [rng.range(-40.0, 40.0), rng.range(-15.0, 20.0), rng.range(-10.0, 10.0)],
            arms,
            legs,
            arm_across: across_side.is_some(),
        }
    }

    /// Per-bone rotations for this pose on a rig with the given rest heads and tails (decimetres). Bones whose
    /// rotation is the identity are left out, so [`PoseParams::rest`] yields an empty map.
    pub fn rotations(&self, rig: &Rig, heads: &[Vec3], _tails: &[Vec3]) -> HashMap<usize, Quat> {
        let mut out = HashMap::new();
        let mut put = |name: &str, q: Quat| {
            if let Some(b) = rig.bone(name) {
                if q.w.abs() < 1.0 - 1e-9 {
                    let e = out.entry(b).or_insert(Quat::IDENTITY);
                    *e = (q * *e).normalize();
                }
            }
        };
        let r = f32::to_radians;
        // Torso: twist spread over three spine joints, lean over two, side bend over one.
        for name in ["spine04", "spine03", "spine02"] {
            put(name, Quat::from_rotation_y(r(self.torso_twist / 3.0)));
        }
        for name in ["spine04", "spine02"] {
            put(name, Quat::from_rotation_x(r(self.torso_lean / 2.0)));
        }
        put("spine03", Quat::from_rotation_z(r(-self.torso_side)));
        // Head: half at the neck, half at the skull.
        let [yaw, pitch, roll] = self.head;
        let q_head = Quat::from_rotation_y(r(yaw)) * Quat::from_rotation_x(r(pitch)) * Quat::from_rotation_z(r(roll));
        let half = Quat::IDENTITY.slerp(q_head, 0.5);
        put("neck02", half);
        put("head", half);

        let dir = |a: &str, b: &str| -> Option<Vec3> {
            let (i, j) = (rig.bone(a)?, rig.bone(b)?);
            (heads[j] - heads[i]).try_normalize()
        };
        let flex_axis = |d: Vec3| d.cross(Vec3::Z).try_normalize().unwrap_or(Vec3::X);
        for (side, (s, sign)) in [("L", 1.0f32), ("R", -1.0f32)].into_iter().enumerate() {
            let arm = self.arms[side];
            let upper = format!("upperarm01.{s}");
            let lower = format!("lowerarm01.{s}");
            let wrist = format!("wrist.{s}");
            if let (Some(d_up), Some(d_fore)) = (dir(&upper, &lower), dir(&lower, &wrist)) {
                let mut q = Quat::from_axis_angle(d_up, r(arm.twist));
                if let Some([elev, azim]) = arm.direction {
                    let (e, a) = (r(elev), r(azim));
                    let target = Vec3::new(sign * a.cos() * e.sin(), -e.cos(), a.sin() * e.sin());
                    q = Quat::from_rotation_arc(d_up, target) * q;
                }
                put(&upper, q);
                put(&lower, Quat::from_axis_angle(flex_axis(d_fore), r(arm.elbow)));
                put(&wrist, Quat::from_axis_angle(flex_axis(d_fore), r(arm.wrist)));
            }
            let leg = self.legs[side];
            let hip = format!("upperleg01.{s}");
            let knee = format!("lowerleg01.{s}");
            let foot = format!("foot.{s}");
            if let (Some(d_thigh), Some(d_shin)) = (dir(&hip, &knee), dir(&knee, &foot)) {
                let q = Quat::from_rotation_z(r(sign * leg.abduction))
                    * Quat::from_axis_angle(flex_axis(d_thigh), r(leg.flexion));
                put(&hip, q);
                put(&knee, Quat::from_axis_angle(flex_axis(d_shin), r(-leg.knee)));
                // Keep the foot roughly level: undo the net sagittal rotation of the shin.
                put(&foot, Quat::from_axis_angle(flex_axis(d_shin), r(leg.knee - leg.flexion)));
            }
        }
        out
    }
}
