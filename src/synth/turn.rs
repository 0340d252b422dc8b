//! Turning clips: a person turning once about the vertical axis in place in front of a fixed camera, then facing
//! it again — the ground truth for what a live source shows of a person over a few seconds.
//!
//! Frame `i` of a clip of [`TurnOptions`] turns the person by [`TurnOptions::yaw`] (0 at the first frame, a whole
//! turn over [`TurnOptions::turn_frames`] frames, then [`TurnOptions::hold_frames`] frames facing the camera).
//! Positive yaw turns the person toward their left (+z, the way they face, toward +x), so the camera sees their
//! right side at a quarter turn and their back at half a turn.
//!
//! - A **synthetic subject** ([`super::Dressed`]) turns about the vertical axis through its hip centre; its arms
//!   swing by up to [`TurnOptions::arm_swing`] degrees of elevation ([`TurnOptions::pose`], the two arms in
//!   opposite phase, two swings per turn), and its clothes follow the body by the same skinning as every subject.
//!   One normalisation serves the whole clip (the camera does not move): the first frame's height, centred on the
//!   turning axis, shrunk so every frame stays within the body cube.
//! - A **scan** (already normalised, [`super::scan`]) turns rigidly about the cube's vertical axis (it has no rig).
//!
//! Each frame's mesh is then moved along z by the project's depth convention
//! ([`super::normalize::centre_depth`]), as every subject's ground truth is: an orthographic camera cannot see
//! depth, so every geometry and its ground truth put the person's volume at z = 0.

use glam::{Quat, Vec3};

use super::{normalize, Dressed, PoseParams, SubjectParams, SynthAssets, SynthError};
use crate::io::mesh_io::TexturedMesh;

/// The shape of a turning clip.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TurnOptions {
    /// Frames over which the person turns once (at least 4).
    pub turn_frames: usize,
    /// Frames facing the camera after the turn.
    pub hold_frames: usize,
    /// Largest change of each arm's elevation (degrees, 0 to 45).
    pub arm_swing: f32,
}

impl Default for TurnOptions {
    /// 48 frames of turn (3 s at 16 frames a second), 8 frames facing the camera again, arms swinging 15 degrees.
    fn default() -> Self {
        Self { turn_frames: 48, hold_frames: 8, arm_swing: 15.0 }
    }
}

impl TurnOptions {
    /// Checks the ranges ([`SynthError::InvalidTurn`] names the option otherwise).
    pub fn validate(&self) -> Result<(), SynthError> {
        let bad = |m: String| Err(SynthError::InvalidTurn(m));
        if !(4..=10_000).contains(&self.turn_frames) {
            return bad(format!("{} turn frames: use 4 to 10000", self.turn_frames));
        }
        if self.hold_frames > 10_000 {
            return bad(format!("{} hold frames: use 0 to 10000", self.hold_frames));
        }
        if !(0.0..=45.0).contains(&self.arm_swing) {
            return bad(format!("an arm swing of {} degrees: use 0 to 45", self.arm_swing));
        }
        Ok(())
    }

    /// Frames in the clip.
    pub fn frames(&self) -> usize {
        self.turn_frames + self.hold_frames
    }

    /// The person's turn at frame `i` in degrees, in `[0, 360)`: `360 i / turn_frames` during the turn, 0 after.
    pub fn yaw(&self, i: usize) -> f32 {
        if i < self.turn_frames {
            360.0 * i as f32 / self.turn_frames as f32
        } else {
            0.0
        }
    }

    /// Whether the person has turned once by frame `i` (and faces the camera again).
    pub fn turned(&self, i: usize) -> bool {
        i >= self.turn_frames
    }

    /// `base` with the arms of frame `i`: each arm's elevation moved by `arm_swing sin(4 pi t)` (t = the share of
    /// the turn done; the right arm in opposite phase), clamped to `[0, 175]` degrees; after the turn, `base`.
    pub fn pose(&self, base: &PoseParams, i: usize) -> PoseParams {
        let mut pose = *base;
        if i >= self.turn_frames {
            return pose;
        }
        let t = i as f32 / self.turn_frames as f32;
        let swing = self.arm_swing * (4.0 * std::f32::consts::PI * t).sin();
        for (side, arm) in pose.arms.iter_mut().enumerate() {
            let sign = if side == 0 { 1.0 } else { -1.0 };
            // The rest direction (None) is an A-pose's, about 45 degrees of elevation out to the side.
            let [elevation, azimuth] = arm.direction.unwrap_or([45.0, 0.0]);
            arm.direction = Some([(elevation + sign * swing).clamp(0.0, 175.0), azimuth]);
        }
        pose
    }
}

/// Where a clip's meshes come from.
#[derive(Clone, Debug)]
enum Source {
    /// A synthetic subject, re-posed each frame.
    Synthetic {
        /// Its clothes and texture.
        dressed: Box<Dressed>,
        /// MakeHuman units to the camera's body cube, one for the whole clip.
        scale: f32,
        /// The point mapped to the cube's centre (decimetres): the hip centre in x and z, mid-height in y.
        centre: Vec3,
    },
    /// A normalised scan, turned rigidly.
    Scan(TexturedMesh),
}

/// A person turning in place ([`TurnOptions`]), frame by frame.
#[derive(Clone, Debug)]
pub struct TurningClip {
    source: Source,
    /// The clip's timing and arm swing.
    pub options: TurnOptions,
}

impl TurningClip {
    /// The synthetic subject of `params` turning (its pose at frame 0 is `params.pose`).
    pub fn synthetic(
        assets: &SynthAssets,
        params: &SubjectParams,
        texture_size: usize,
        options: TurnOptions,
    ) -> Result<Self, SynthError> {
        let fail = |message: String| SynthError::Generation { seed: params.seed, message };
        options.validate()?;
        let dressed = Dressed::new(assets, params, texture_size)?;
        let (first, posed) = dressed.posed_positions(assets, &options.pose(&params.pose, 0))?;
        let norm = normalize::compute(&first).ok_or_else(|| fail("degenerate posed mesh".into()))?;
        // The hip centre: midway between the thighs' heads, posed.
        let hip = ["upperleg01.L", "upperleg01.R"]
            .map(|b| assets.rig.bone(b).map(|k| posed.transforms[k].transform_point3(posed.heads[k])));
        let [Some(l), Some(r)] = hip else { return Err(fail("the rig has no thigh bones".into())) };
        let centre = Vec3::new(0.5 * (l.x + r.x), norm.center[1], 0.5 * (l.z + r.z));
        // Every frame within the cube (the turn sweeps the farthest point around the axis).
        let mut scale = norm.scale;
        for i in 0..options.frames() {
            let (p, _) = dressed.posed_positions(assets, &options.pose(&params.pose, i))?;
            let reach = p
                .iter()
                .map(|q| (*q - centre) * scale)
                .fold(0.0f32, |m, q| m.max(glam::Vec2::new(q.x, q.z).length()).max(q.y.abs()));
            if !reach.is_finite() {
                return Err(fail(format!("frame {i}: non-finite posed mesh")));
            }
            if reach > 0.98 {
                scale *= 0.98 / reach;
            }
        }
        Ok(Self { source: Source::Synthetic { dressed: Box::new(dressed), scale, centre }, options })
    }

    /// A normalised scan ([`super::scan::load_scan_with`]) turning rigidly about the cube's vertical axis.
    pub fn scan(mesh: TexturedMesh, options: TurnOptions) -> Result<Self, SynthError> {
        options.validate()?;
        Ok(Self { source: Source::Scan(mesh), options })
    }

    /// Frames in the clip.
    pub fn frames(&self) -> usize {
        self.options.frames()
    }

    /// The person at frame `i` in the camera's body cube (depth-centred).
    pub fn frame(&self, assets: Option<&SynthAssets>, i: usize) -> Result<TexturedMesh, SynthError> {
        let turn = Quat::from_rotation_y(self.options.yaw(i).to_radians());
        let mut mesh = match &self.source {
            Source::Synthetic { dressed, scale, centre } => {
                let assets = match assets {
                    Some(a) => a,
                    None => SynthAssets::shared()?,
                };
                let (p, _) = dressed.posed_positions(assets, &self.options.pose(&dressed.params.pose, i))?;
                dressed.mesh(p.iter().map(|&q| turn * ((q - *centre) * *scale)).collect())?
            }
            Source::Scan(m) => {
                let mut m = m.clone();
                m.mesh.positions.iter_mut().for_each(|p| *p = turn * *p);
                m.mesh.normals.iter_mut().for_each(|n| *n = turn * *n);
                m
            }
        };
        normalize::centre_depth(&mut mesh.mesh);
        Ok(mesh)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_turn_goes_once_round_then_faces_the_camera() {
        let o = TurnOptions { turn_frames: 8, hold_frames: 3, arm_swing: 10.0 };
        assert_eq!(o.frames(), 11);
        let yaws: Vec<f32> = (0..11).map(|i| o.yaw(i)).collect();
        assert_eq!(yaws, [0.0, 45.0, 90.0, 135.0, 180.0, 225.0, 270.0, 315.0, 0.0, 0.0, 0.0]);
        assert!(!o.turned(7) && o.turned(8));
        // Arms: sin(4 pi t) at t = 1/8 is 1: the left arm up by the swing, the right down; after the turn, the base.
        let base = PoseParams::rest();
        let p = o.pose(&base, 1);
        assert_eq!(p.arms[0].direction, Some([55.0, 0.0]));
        assert_eq!(p.arms[1].direction, Some([35.0, 0.0]));
        assert_eq!(o.pose(&base, 9), base);
        assert!(TurnOptions { turn_frames: 3, ..o }.validate().is_err());
        assert!(TurnOptions { arm_swing: f32::NAN, ..o }.validate().is_err());
        assert!(o.validate().is_ok());
    }

    #[test]
    fn a_turning_scan_shows_its_back_at_half_a_turn() {
        // A wedge pointing at the camera (+z): at half a turn it points away, at a quarter turn to +x (yaw turns
        // +z toward +x).
        let positions = vec![
            Vec3::new(-0.2, -0.5, -0.1),
            Vec3::new(0.2, -0.5, -0.1),
            Vec3::new(0.0, -0.5, 0.4),
            Vec3::new(0.0, 0.5, 0.0),
        ];
        let mesh = crate::geometry::TriMesh::new(positions, vec![[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]]);
        let clip = TurningClip::scan(
            TexturedMesh::untextured(mesh),
            TurnOptions { turn_frames: 4, hold_frames: 1, arm_swing: 0.0 },
        )
        .unwrap();
        let tip = |i: usize| {
            let m = clip.frame(None, i).unwrap();
            let c = m.mesh.positions.iter().take(4).copied().sum::<Vec3>() / 4.0;
            m.mesh.positions[2] - c
        };
        let (t0, t1, t2, t4) = (tip(0), tip(1), tip(2), tip(4));
        assert!(t0.z > 0.3 && t0.x.abs() < 1e-5, "{t0:?}");
        assert!(t1.x > 0.3 && t1.z.abs() < 1e-5, "{t1:?}");
        assert!(t2.z < -0.3, "{t2:?}");
        assert!((t4 - t0).length() < 1e-5, "{t4:?}");
    }
}
