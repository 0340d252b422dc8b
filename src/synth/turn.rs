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

/// Something that happens during a clip, from frame `at` on (the ground truth of forgetting: what the camera saw
/// before no longer holds).
#[derive(Clone, Debug)]
pub enum TurnEvent {
    /// Another person stands in the first one's place and goes on turning at the same angle (a cut).
    Cut {
        /// The first frame of the other person.
        at: usize,
        /// The other person's clip (same options).
        other: Box<TurningClip>,
    },
    /// The person's top (top, dress, sleeves) is off: the body (and what else they wear) shows where it was.
    TakeOff {
        /// The first frame without it.
        at: usize,
        /// The mesh's triangles without the top's.
        triangles: Vec<[u32; 3]>,
    },
}

impl TurnEvent {
    /// The first frame the event holds for.
    pub fn at(&self) -> usize {
        match self {
            TurnEvent::Cut { at, .. } | TurnEvent::TakeOff { at, .. } => *at,
        }
    }
}

/// The labels of the garment pieces [`TurnEvent::TakeOff`] takes off.
pub fn is_top(label: &str) -> bool {
    ["top", "dress", "sleeve."].iter().any(|t| label == *t || (t.ends_with('.') && label.starts_with(t)))
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
    /// What happens during the clip, if anything.
    pub event: Option<TurnEvent>,
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
        Ok(Self { source: Source::Synthetic { dressed: Box::new(dressed), scale, centre }, options, event: None })
    }

    /// A normalised scan ([`super::scan::load_scan_with`]) turning rigidly about the cube's vertical axis.
    pub fn scan(mesh: TexturedMesh, options: TurnOptions) -> Result<Self, SynthError> {
        options.validate()?;
        Ok(Self { source: Source::Scan(mesh), options, event: None })
    }

    /// Frames in the clip.
    pub fn frames(&self) -> usize {
        self.options.frames()
    }

    /// This clip cut at frame `at` to `other` (which must have the same options).
    pub fn cut_to(self, other: TurningClip, at: usize) -> Result<Self, SynthError> {
        if other.options != self.options || at == 0 || at >= self.frames() {
            return Err(SynthError::InvalidTurn(format!(
                "a cut at frame {at} of {} to a clip of other options",
                self.frames()
            )));
        }
        Ok(Self { event: Some(TurnEvent::Cut { at, other: Box::new(other) }), ..self })
    }

    /// This synthetic clip with the top ([`is_top`]) taken off from frame `at` on; an error for a scan or a
    /// person without one.
    pub fn take_off_top(self, at: usize) -> Result<Self, SynthError> {
        let Source::Synthetic { dressed, .. } = &self.source else {
            return Err(SynthError::InvalidTurn("a scan has no garment to take off".into()));
        };
        if at == 0 || at >= self.frames() {
            return Err(SynthError::InvalidTurn(format!("a garment taken off at frame {at} of {}", self.frames())));
        }
        let off: Vec<std::ops::Range<usize>> =
            dressed.pieces.iter().filter(|p| is_top(&p.label)).map(|p| p.vertices.clone()).collect();
        if off.is_empty() {
            return Err(SynthError::InvalidTurn("the person wears no top to take off".into()));
        }
        let triangles = dressed
            .triangles
            .iter()
            .copied()
            .filter(|t| !t.iter().any(|&v| off.iter().any(|r| r.contains(&(v as usize)))))
            .collect();
        Ok(Self { event: Some(TurnEvent::TakeOff { at, triangles }), ..self })
    }

    /// The person at frame `i` in the camera's body cube (depth-centred).
    pub fn frame(&self, assets: Option<&SynthAssets>, i: usize) -> Result<TexturedMesh, SynthError> {
        let event = self.event.as_ref().filter(|e| i >= e.at());
        if let Some(TurnEvent::Cut { other, .. }) = event {
            return other.frame(assets, i);
        }
        let turn = Quat::from_rotation_y(self.options.yaw(i).to_radians());
        let mut mesh = match &self.source {
            Source::Synthetic { dressed, scale, centre } => {
                let assets = match assets {
                    Some(a) => a,
                    None => SynthAssets::shared()?,
                };
                let (p, _) = dressed.posed_positions(assets, &self.options.pose(&dressed.params.pose, i))?;
                let mut m = dressed.mesh(p.iter().map(|&q| turn * ((q - *centre) * *scale)).collect())?;
                if let Some(TurnEvent::TakeOff { triangles, .. }) = event {
                    m.mesh.triangles = triangles.clone();
                    m.mesh.compute_normals();
                }
                m
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

    /// A wedge pointing at the camera, `size` wide.
    fn wedge(size: f32) -> TexturedMesh {
        let positions = vec![
            Vec3::new(-0.2, -0.5, -0.1) * size,
            Vec3::new(0.2, -0.5, -0.1) * size,
            Vec3::new(0.0, -0.5, 0.4) * size,
            Vec3::new(0.0, 0.5, 0.0) * size,
        ];
        TexturedMesh::untextured(crate::geometry::TriMesh::new(
            positions,
            vec![[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]],
        ))
    }

    #[test]
    fn a_cut_shows_the_other_person_from_its_frame_on() {
        let o = TurnOptions { turn_frames: 4, hold_frames: 2, arm_swing: 0.0 };
        let clip =
            TurningClip::scan(wedge(1.0), o).unwrap().cut_to(TurningClip::scan(wedge(0.5), o).unwrap(), 3).unwrap();
        let width = |i: usize| {
            let m = clip.frame(None, i).unwrap();
            let ys: Vec<f32> = m.mesh.positions.iter().map(|p| p.y).collect();
            ys.iter().fold(f32::MIN, |a, &b| a.max(b)) - ys.iter().fold(f32::MAX, |a, &b| a.min(b))
        };
        assert!((width(2) - 1.0).abs() < 1e-5 && (width(3) - 0.5).abs() < 1e-5 && (width(5) - 0.5).abs() < 1e-5);
        // A cut needs the same options and a frame inside the clip; a scan has nothing to take off.
        let other = TurningClip::scan(wedge(0.5), TurnOptions { turn_frames: 5, ..o }).unwrap();
        assert!(TurningClip::scan(wedge(1.0), o).unwrap().cut_to(other, 3).is_err());
        assert!(TurningClip::scan(wedge(1.0), o)
            .unwrap()
            .cut_to(TurningClip::scan(wedge(0.5), o).unwrap(), 6)
            .is_err());
        assert!(TurningClip::scan(wedge(1.0), o).unwrap().take_off_top(2).is_err());
        assert!(is_top("top") && is_top("sleeve.L") && is_top("dress") && !is_top("hair") && !is_top("topknot"));
    }

    #[test]
    fn taking_the_top_off_removes_its_triangles_and_nothing_else() {
        let assets = SynthAssets::shared().expect("synthetic-subject data (bash scripts/setup.d/synth.sh)");
        let o = TurnOptions { turn_frames: 4, hold_frames: 1, arm_swing: 0.0 };
        let clip = (0..40)
            .find_map(|seed| {
                TurningClip::synthetic(assets, &SubjectParams::sample(seed), 16, o).ok()?.take_off_top(2).ok()
            })
            .expect("a subject with a top among 40 seeds");
        let Source::Synthetic { dressed, .. } = &clip.source else { unreachable!("a synthetic clip") };
        let top: Vec<std::ops::Range<usize>> =
            dressed.pieces.iter().filter(|p| is_top(&p.label)).map(|p| p.vertices.clone()).collect();
        let on_top = |t: &[u32; 3]| t.iter().any(|&v| top.iter().any(|r| r.contains(&(v as usize))));
        let (before, after) = (clip.frame(Some(assets), 1).unwrap(), clip.frame(Some(assets), 2).unwrap());
        assert_eq!(before.mesh.triangles, dressed.triangles);
        let kept: Vec<[u32; 3]> = dressed.triangles.iter().copied().filter(|t| !on_top(t)).collect();
        assert_eq!(after.mesh.triangles, kept);
        assert!(kept.len() < dressed.triangles.len() && after.mesh.positions.len() == before.mesh.positions.len());
    }

    #[test]
    fn a_turning_scan_shows_its_back_at_half_a_turn() {
        // A wedge pointing at the camera (+z): at half a turn it points away, at a quarter turn to +x (yaw turns
        // +z toward +x).
        let clip =
            TurningClip::scan(wedge(1.0), TurnOptions { turn_frames: 4, hold_frames: 1, arm_swing: 0.0 }).unwrap();
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
