//! The body prior of one input: pose landmarks ([`super::pose`]) -> fitted body ([`super::fit`]) -> the posed
//! body's FOF (the **body FOF**), reconciled with the person's silhouette.
//!
//! What the network only guesses is left out before the fit and the FOF: legs it draws shorter than a person's
//! ([`legs_it_sees`]), hands whose elbow it does not see ([`arms_it_sees`]), and every limb segment whose far end it
//! does not see draws no body columns ([`limbs_seen`], [`BodyModel::mesh_seen`]).
//!
//! Reconciliation ([`body_fof`], [`super::reconcile`]): the FOF intervals of the posed body mesh where the mask
//! covers the pixel; none outside the mask (so whatever the photo does not show, past its frame or beyond the
//! silhouette, is cut); mask pixels the body does not cover (hair, loose clothes, a held object) get one interval
//! from a smooth centre field (the body's depths next to them, settling on the body's median depth further away) and the inflation profile with the body as its
//! boundary, so they join the body without steps. The body is placed in depth like the reference's
//! preprocessing: its xz minimal enclosing circle centred on z = 0.

use std::path::Path;

use glam::{DVec3, Vec2};

use super::fit::{fit_body, BodyFit, FitOptions, FitTarget};
use super::model::{BodyModel, Pose, LIMB_SEGMENTS};
use super::pose::{cut_frame, PhotoFrame, PoseEstimator, PoseLandmarks};
use super::reconcile::{reconcile_with, ReconcileParams, SilhouetteProfile};
use super::BodyError;
use crate::buffer::{GrayImage, Image, RgbImage};
use crate::geometry::circle::min_enclosing_circle;
use crate::geometry::fof::{intervals_from_mesh, sheet_thickness, Fof};
use crate::geometry::inflate::InflateParams;
use crate::geometry::mesh::TriMesh;
use crate::neural::RuntimeOptions;

/// The fitted body of one input.
#[derive(Clone, Debug)]
pub struct BodyPrior {
    /// The pose landmarks it was fitted to (source-view pixels).
    pub landmarks: PoseLandmarks,
    /// The fit.
    pub fit: BodyFit,
    /// The posed body surface in the body cube.
    pub mesh: TriMesh,
}

impl BodyPrior {
    /// The photo's frame the prior was fitted in (the landmarks'): the given frame, its bottom raised to a straight
    /// cut of the mask unless the person stands there ([`stands_on`]).
    pub fn frame(&self) -> PhotoFrame {
        (self.landmarks.frame_min, self.landmarks.frame_max)
    }
}

/// Places a pose in depth like the reference's preprocessing: the posed mesh's xz minimal enclosing circle
/// centred on z = 0 (x stays where the photo put it). Returns the shifted pose and its mesh.
pub fn centre_depth(model: &BodyModel, pose: &Pose) -> (Pose, TriMesh) {
    let mut mesh = model.mesh(pose);
    let xz: Vec<Vec2> = mesh.positions.iter().map(|p| Vec2::new(p.x, p.z)).collect();
    let (centre, _) = min_enclosing_circle(&xz);
    let dz = if centre.y.is_finite() { centre.y } else { 0.0 };
    mesh.positions.iter_mut().for_each(|p| p.z -= dz);
    let pose = Pose { translation: pose.translation - DVec3::Z * dz as f64, ..*pose };
    (pose, mesh)
}

/// The pose network, the body model and the last frame's result (for warm starts on live input).
pub struct BodyEstimator {
    pose: PoseEstimator,
    model: &'static BodyModel,
    /// Fit settings.
    pub options: FitOptions,
    /// Whether the pose network reads the mirror image of an input it sees facing away ([`front_read`]; on by
    /// default).
    pub mirror_read: bool,
    /// The last frame's fitted pose (the next warm fit's start).
    previous: Option<Pose>,
    /// MediaPipe's face mesh ([`super::face`]), or why it could not be loaded (said once, on first use).
    face: Result<super::face::FaceEstimator, BodyError>,
}

impl std::fmt::Debug for BodyEstimator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BodyEstimator")
            .field("pose_model", &self.pose.path())
            .field("options", &self.options)
            .field("mirror_read", &self.mirror_read)
            .field("has_previous", &self.previous.is_some())
            .finish()
    }
}

impl BodyEstimator {
    /// Loads the pose model (see [`super::pose::model_path`]) and the shared body model.
    pub fn load(pose_model: Option<&Path>, options: &RuntimeOptions) -> Result<Self, BodyError> {
        let model = BodyModel::shared()?;
        let pose = PoseEstimator::load(pose_model, options)?;
        let face = super::face::FaceEstimator::load(None, options);
        Ok(Self { pose, model, options: FitOptions::default(), mirror_read: true, previous: None, face })
    }

    /// The body model.
    pub fn model(&self) -> &'static BodyModel {
        self.model
    }

    /// The face mesh ([`super::face::FaceEstimator::estimate`]) of the person whose landmarks `pose` were read
    /// from `rgb` (linear RGB, the same pixels). `None` when no face is found, and, with one warning per process,
    /// when the face model is not installed or fails.
    pub fn face_mesh(&mut self, rgb: &RgbImage, pose: &PoseLandmarks) -> Option<super::face::FaceMesh> {
        static WARNED: std::sync::Once = std::sync::Once::new();
        let warn = |why: &BodyError| WARNED.call_once(|| tracing::warn!("no face relief: {why}"));
        match &mut self.face {
            Ok(face) => face.estimate(rgb, pose).unwrap_or_else(|why| {
                warn(&why);
                None
            }),
            Err(why) => {
                warn(why);
                None
            }
        }
    }

    /// Forgets the previous frame (the next [`BodyEstimator::estimate`] with `warm` starts cold).
    pub fn reset(&mut self) {
        self.previous = None;
    }

    /// Landmarks and the fitted body of the person in a normalised source view (`rgb` linear, `mask` in
    /// `[0, 1]`, `frame` where the photo lies in it). With `warm` (live input) the fit starts from the previous
    /// frame's pose. The network reads every frame as it reads a still, in the region of that frame's mask: reading
    /// the region the previous frame's landmarks give instead (MediaPipe's tracking) lets the region wander on a
    /// still person, and the body with it (docs/live.md, "Ideas measured and not kept"). `None` when no pose is
    /// found.
    pub fn estimate(
        &mut self,
        rgb: &RgbImage,
        mask: &GrayImage,
        frame: Option<PhotoFrame>,
        warm: bool,
        timings: &mut dyn FnMut(&'static str, std::time::Duration),
    ) -> Result<Option<BodyPrior>, BodyError> {
        let t = std::time::Instant::now();
        // The reads below share network inputs (uncut and cut frames); an earlier photo's runs are not reused.
        self.pose.forget_runs();
        let given = frame.unwrap_or((Vec2::ZERO, Vec2::new(mask.width as f32, mask.height as f32)));
        let cut = effective_frame(mask, Some(given));
        let start = if warm { self.previous } else { None };
        // A straight bottom edge of the mask inside the photo is a cut, unless the person stands on it: read the
        // photo as it is first, and take the cut only when that read does not stand on the edge.
        let mut frame = Some(cut);
        let mut landmarks = None;
        if cut != given {
            let uncut = self.pose.estimate(rgb, mask, Some(given))?;
            if uncut.as_ref().is_some_and(|l| stands_on(l, mask, cut.1.y, self.options.min_visibility)) {
                frame = Some(given);
                landmarks = uncut;
            }
        }
        let landmarks = match landmarks {
            Some(l) => Some(l),
            None => self.pose.estimate(rgb, mask, frame)?,
        };
        let Some(landmarks) = landmarks else {
            timings("pose landmarks", t.elapsed());
            self.previous = None;
            return Ok(None);
        };
        // A read that faces away is asked again on the mirror image; see `front_read`.
        let mirrored = if self.mirror_read && says_back(&landmarks) {
            let width = rgb.width as f32;
            self.pose
                .estimate(
                    &mirrored_left_right(rgb),
                    &mirrored_left_right(mask),
                    frame.map(|f| mirrored_frame(f, width)),
                )?
                .map(|m| m.mirrored_left_right(width))
        } else {
            None
        };
        let landmarks = front_read(landmarks, mirrored);
        self.pose.forget_runs();
        timings("pose landmarks", t.elapsed());
        let min_visibility = self.options.min_visibility;
        let landmarks = arms_it_sees(standing_legs(legs_it_sees(landmarks), min_visibility), min_visibility);
        let t = std::time::Instant::now();
        let target = FitTarget::new(&landmarks, mask);
        let fit = fit_body(self.model, &target, start.as_ref(), &self.options);
        // The next warm fit starts from the fit's own pose: the depth centring moves the body along z, which the fit's
        // depth terms see (started from the centred pose, a still person's next fit began 5 % above this one's cost
        // and moved on every frame).
        self.previous = Some(fit.pose);
        let (pose, mesh) = centre_depth(self.model, &fit.pose);
        let mesh = self.model.mesh_seen(&mesh, &limbs_seen(&landmarks, min_visibility));
        timings("body fit", t.elapsed());
        Ok(Some(BodyPrior { landmarks, fit: BodyFit { pose, ..fit }, mesh }))
    }
}

/// [`facing_the_camera`] mirrors landmarks whose torso faces away from the camera more than this
/// ([`PoseLandmarks::facing`] below it: within 60° of straight away).
pub const FACING_AWAY: f32 = -0.5;

/// The landmarks of a person who faces the camera: when the network's landmarks say the torso faces away
/// ([`FACING_AWAY`]), the same landmarks mirrored in depth ([`PoseLandmarks::mirrored_in_depth`]: left and right
/// swapped, depths negated; the 2-D positions unchanged); profiles and everything between are kept.
///
/// The photo is taken to show the person's front, as the whole pipeline takes it (the back is drawn with the
/// front's colours by default), and the network's front/back call is no evidence against that:
/// on the evaluation's synthetic subjects seen from the front it says "front" every time, but seen from behind it
/// says "front" for a third of them, with the face landmarks' visibility about 1 either way; on the independent scan
/// (Mr. Fixit, a game character in T-pose, seen from the front) it says "back" (facing -0.98). A body fitted to
/// landmarks that face away is turned around, with its knees and feet pointing away from the camera and its legs
/// leaning where the network's depths say.
pub fn facing_the_camera(landmarks: PoseLandmarks) -> PoseLandmarks {
    match landmarks.facing() {
        Some(f) if f < FACING_AWAY => landmarks.mirrored_in_depth(),
        _ => landmarks,
    }
}

/// Whether the network's landmarks say the torso faces away from the camera ([`FACING_AWAY`]).
pub fn says_back(landmarks: &PoseLandmarks) -> bool {
    landmarks.facing().is_some_and(|f| f < FACING_AWAY)
}

/// The landmarks of a person seen from the front, from the network's read of the input (`first`) and, when that
/// read says the person faces away ([`says_back`]), its read of the input's left-right mirror image (`mirror_read`,
/// already brought back to the input, [`PoseLandmarks::mirrored_left_right`]): the mirror read when it says the
/// person faces the camera (facing above `-FACING_AWAY`), otherwise `first` turned to face the camera
/// ([`facing_the_camera`]: mirrored in depth).
///
/// The network's front/back call is a weak cue both ways: seen from the front, 12 of 119 synthetic people of seed 7
/// were read as facing away, and on 4 of those its read of the mirror image faces the camera. Mirroring a read that faces away is right about as often as keeping its depths and only swapping its
/// sides (0.093 vs 0.095 mean depth error, below); where the mirror image's read says "front" its depths are
/// better than either. Mean depth error of the shoulders, elbows, wrists, hips, knees and ankles against the
/// subjects' own joints (cube units, a person 1.8 units tall), those 119 front views: first read turned by
/// [`facing_the_camera`] 0.0934; with the mirror read where it says front 0.0915 (`cargo run --release --example
/// body_facing`). The
/// independent scan (Mr. Fixit, seen from the front) is read as facing away in both.
pub fn front_read(first: PoseLandmarks, mirror_read: Option<PoseLandmarks>) -> PoseLandmarks {
    match mirror_read {
        Some(m) if says_back(&first) && m.facing().is_some_and(|f| f > -FACING_AWAY) => m,
        _ => facing_the_camera(first),
    }
}

/// The left-right mirror image of `image`.
pub fn mirrored_left_right<T: Copy>(image: &crate::buffer::Image<T>) -> crate::buffer::Image<T> {
    crate::buffer::Image::from_fn(image.width, image.height, |c, r| image.data[r * image.width + image.width - 1 - c])
}

/// A photo's frame in the left-right mirror image of a `width`-pixel-wide picture.
pub fn mirrored_frame((lo, hi): PhotoFrame, width: f32) -> PhotoFrame {
    (Vec2::new(width - hi.x, lo.y), Vec2::new(width - lo.x, hi.y))
}

/// [`stands_on`]: how far above the mask's bottom edge a foot may lie, as a fraction of the mask's height (the
/// fold check's margin, [`super::pose::FOLD_MARGIN`]).
pub const FEET_MARGIN: f32 = super::pose::FOLD_MARGIN;

/// Whether `landmarks` (read in the photo's own frame) stand the person on the mask's bottom edge at row
/// `bottom` (pixels): both legs are legs the network sees ([`legs_it_sees`]: thighs of a person's length in its
/// world landmarks) and each has its ankle, heel or foot point seen (visibility at least `min_visibility`) within
/// [`FEET_MARGIN`] of the mask's height above that edge (or below it). Then a straight bottom edge is the person's
/// soles, not a cut ([`super::pose::cut_frame`]): a character in flat, wide boots seen from the front at 256²
/// (the Mr. Fixit scan) ends in a row of sole as wide as the rows above it, and taken as a cut the network was
/// asked for a body continuing below it, folded by the fold check into hips at the boots. A folded body (the
/// network's explanation of a person cut at the waist) draws thighs shorter than a person's and is not standing.
pub fn stands_on(landmarks: &PoseLandmarks, mask: &GrayImage, bottom: f32, min_visibility: f32) -> bool {
    let Some(top) = mask.rows().position(|row| row.iter().any(|&m| m >= 0.5)) else { return false };
    let height = bottom - top as f32;
    if height.is_nan() || height <= 0.0 {
        return false;
    }
    let seen = legs_it_sees(landmarks.clone());
    let on_edge = |i: usize| {
        let l = &seen.landmarks[i];
        l.visibility >= min_visibility && l.pixel.y.is_finite() && l.pixel.y >= bottom - FEET_MARGIN * height
    };
    // Ankle, heel, foot index of each leg.
    [[27usize, 29, 31], [28, 30, 32]].iter().all(|leg| leg.iter().any(|&i| on_edge(i)))
}

/// [`legs_it_sees`]: the shortest thigh (hip to knee, metres) of the network's world landmarks that it draws for a
/// leg it sees. MakeHuman adults and the shipped photos' visible legs: 0.33–0.40.
pub const MIN_THIGH_M: f32 = 0.3;

/// The landmarks with the legs the network does not see set invisible: a leg whose thigh in the network's own
/// metric world landmarks is shorter than [`MIN_THIGH_M`] (knee, ankle, heel and foot of that side). The network
/// draws the legs it sees with a person's proportions (thighs 0.33–0.40 m on the evaluation's full-body subjects
/// and the full-body photo) and shrinks the ones it guesses toward the hip: 0.19–0.29 m on upper-body crops,
/// 0.27 m on the astronaut's (a knee on the held helmet, visibility 0.78), 0.20 m on the profile's (a knee on the
/// tripod, visibility 0.65). A guessed knee inside the photo turned the fitted thigh toward the camera, and its
/// columns drew a long sheet from the side.
pub fn legs_it_sees(mut landmarks: PoseLandmarks) -> PoseLandmarks {
    use super::pose::index::{LEFT_HIP, LEFT_KNEE, RIGHT_HIP, RIGHT_KNEE};
    // Knee, ankle, heel, foot of each side after its hip: (hip, knee, [the leg's landmarks]).
    for (hip, knee, leg) in [(LEFT_HIP, LEFT_KNEE, [25usize, 27, 29, 31]), (RIGHT_HIP, RIGHT_KNEE, [26, 28, 30, 32])] {
        let thigh = (landmarks.world[knee] - landmarks.world[hip]).length();
        // A NaN thigh (no world landmarks) is not a leg it sees.
        if thigh.is_nan() || thigh < MIN_THIGH_M {
            for i in leg {
                landmarks.landmarks[i].visibility = 0.0;
            }
        }
    }
    landmarks
}

/// The landmarks of a person standing on the feet the photo shows: when both ankles and both hips are seen
/// (visibility at least `min_visibility`, inside the photo's frame) and the ankles lie below the hips, the legs'
/// landmarks (knees, ankles, heels, feet) are sheared in depth about the hips so that the ankles' mean depth is the
/// hip centre's (world and image depths; each point moved in proportion to its drop below the hips). One foot
/// ahead of the other stays so; only the legs' common lean goes. A standing person's centre of mass (in the pelvis)
/// lies over the feet; the network's world landmarks lean the legs of the full-body photo 0.2 m back at the ankles
/// (fitted: 0.4 cube units), which drew the player's legs leaning back from the side.
pub fn standing_legs(mut landmarks: PoseLandmarks, min_visibility: f32) -> PoseLandmarks {
    use super::pose::index::{LEFT_ANKLE, LEFT_HIP, LEFT_KNEE, RIGHT_ANKLE, RIGHT_FOOT, RIGHT_HIP};
    let seen = |l: &PoseLandmarks, i: usize| {
        l.landmarks[i].visibility >= min_visibility
            && l.in_frame(i, 0.0)
            && l.world.get(i).is_some_and(|w| w.is_finite())
            && l.landmarks[i].depth.is_finite()
    };
    if ![LEFT_HIP, RIGHT_HIP, LEFT_ANKLE, RIGHT_ANKLE].iter().all(|&i| seen(&landmarks, i)) {
        return landmarks;
    }
    let (w, l) = (&landmarks.world, &landmarks.landmarks);
    let (hip, ankle) = ((w[LEFT_HIP] + w[RIGHT_HIP]) * 0.5, (w[LEFT_ANKLE] + w[RIGHT_ANKLE]) * 0.5);
    let hip_depth = 0.5 * (l[LEFT_HIP].depth + l[RIGHT_HIP].depth);
    let ankle_depth = 0.5 * (l[LEFT_ANKLE].depth + l[RIGHT_ANKLE].depth);
    let drop = hip.y - ankle.y;
    if drop.is_nan() || drop <= 0.1 {
        return landmarks;
    }
    let (lean, lean_image) = (ankle.z - hip.z, ankle_depth - hip_depth);
    for i in LEFT_KNEE..=RIGHT_FOOT {
        let share = ((hip.y - landmarks.world[i].y) / drop).clamp(0.0, 1.5);
        if share.is_finite() {
            landmarks.world[i].z -= share * lean;
            landmarks.landmarks[i].depth -= share * lean_image;
        }
    }
    landmarks
}

/// The landmarks with the hands the network only guesses set invisible: the wrist and hand points of an arm whose
/// elbow is below `min_visibility` or outside the photo's frame. A hand is seen through its elbow: on a portrait
/// cut at the chest the network put both wrists crossed in front of the coat (visibility 0.53 and 0.79, elbows
/// below the cut) where the photo shows a plain coat, and the fitted forearms drew a slab toward the camera at the
/// cut. A real hand raised into a chest-up crop is lost to it (its columns take the trunk's or the silhouette's
/// depth), which costs far less than an invented forearm.
pub fn arms_it_sees(mut landmarks: PoseLandmarks, min_visibility: f32) -> PoseLandmarks {
    use super::pose::index::{LEFT_ELBOW, RIGHT_ELBOW};
    for (elbow, hand) in [(LEFT_ELBOW, [15usize, 17, 19, 21]), (RIGHT_ELBOW, [16, 18, 20, 22])] {
        let seen = landmarks.landmarks[elbow].visibility >= min_visibility && landmarks.in_frame(elbow, 0.0);
        if !seen {
            for i in hand {
                landmarks.landmarks[i].visibility = 0.0;
            }
        }
    }
    landmarks
}

/// Which [`LIMB_SEGMENTS`] the network sees: those whose far-end landmark has at least `min_visibility` (a NaN
/// visibility is not seen). A segment it does not see may lie anywhere the pose prior put it (a hidden arm of a
/// person in profile came to rest on the tripod in front of him), so the body prior leaves it out of the body's
/// columns ([`BodyModel::mesh_seen`]) and the silhouette decides what is there.
pub fn limbs_seen(landmarks: &PoseLandmarks, min_visibility: f32) -> [bool; LIMB_SEGMENTS.len()] {
    LIMB_SEGMENTS.map(|(_, far)| landmarks.landmarks.get(far).is_some_and(|l| l.visibility >= min_visibility))
}

/// The photo's frame the body prior works in: `frame` (the whole grid when `None`) with a straight cut of the mask
/// as its bottom edge ([`super::pose::cut_frame`]), so a person cropped out of a larger picture is fitted and
/// reconciled as cut there, like one the photo's own edge cuts.
pub fn effective_frame(mask: &GrayImage, frame: Option<PhotoFrame>) -> PhotoFrame {
    let whole = (glam::Vec2::ZERO, glam::Vec2::new(mask.width as f32, mask.height as f32));
    cut_frame(mask, frame.unwrap_or(whole))
}

/// The body FOF reconciled with the silhouette ([`super::reconcile`]): `mesh` (body cube) and `mask` (`[0, 1]`,
/// threshold 0.5) on the mask's grid, `frame` where the photo lies in it (`None`: the whole grid), `n`
/// coefficients; the inflation profile's κ and smallest thickness from `inflate_params`.
pub fn body_fof(
    mesh: &TriMesh,
    mask: &GrayImage,
    frame: Option<PhotoFrame>,
    n: usize,
    inflate_params: &InflateParams,
) -> Result<Fof, BodyError> {
    body_fof_with(mesh, mask, Some(effective_frame(mask, frame)), n, inflate_params, None)
}

/// [`body_fof`] in the frame the body prior worked in (`frame` as it is: [`BodyPrior::frame`], which already
/// decided whether a straight bottom edge is a cut), with the mask's [`SilhouetteProfile`] solved beforehand (the
/// pipeline solves it beside the pose and the fit); solved here when `None`.
pub fn body_fof_with(
    mesh: &TriMesh,
    mask: &GrayImage,
    frame: Option<PhotoFrame>,
    n: usize,
    inflate_params: &InflateParams,
    silhouette: Option<&SilhouetteProfile>,
) -> Result<Fof, BodyError> {
    let out = body_intervals_with(mesh, mask, frame, n, inflate_params, silhouette);
    Fof::from_intervals(&out, n).map_err(BodyError::Fof)
}

/// The per-column intervals (body cube z, ascending) [`body_fof_with`] encodes: the body's own where it covers the
/// mask, the reconciliation's elsewhere in the mask, none outside it.
pub fn body_intervals_with(
    mesh: &TriMesh,
    mask: &GrayImage,
    frame: Option<PhotoFrame>,
    n: usize,
    inflate_params: &InflateParams,
    silhouette: Option<&SilhouetteProfile>,
) -> Image<Vec<(f32, f32)>> {
    let body = intervals_from_mesh(mesh, mask.width, mask.height, sheet_thickness(n));
    let params = ReconcileParams {
        thickness: inflate_params.thickness,
        min_half_thickness: inflate_params.min_half_thickness,
        min_half_depth: 0.5 * sheet_thickness(n),
        ..Default::default()
    };
    reconcile_with(&body, mask, frame, &params, silhouette)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::pose::tests::torso;
    use glam::{Vec2, Vec3};

    #[test]
    fn landmarks_facing_away_are_mirrored_profiles_are_kept() {
        // Within 60° of straight away: mirrored; a profile or anything nearer the camera: kept.
        for yaw in [std::f32::consts::PI, 2.2, -2.2] {
            let l = torso(yaw);
            let kept = facing_the_camera(l.clone());
            assert_eq!(kept, l.mirrored_in_depth(), "yaw {yaw}");
            assert!(kept.facing().unwrap() > 0.5);
        }
        for yaw in [0.0f32, 1.0, -1.5, 2.0] {
            let l = torso(yaw);
            assert_eq!(facing_the_camera(l.clone()), l, "yaw {yaw}");
        }
    }

    #[test]
    fn a_read_facing_away_takes_the_mirror_images_read_when_that_faces_the_camera() {
        let front = torso(0.3);
        let away = front.mirrored_in_depth();
        assert!(says_back(&away) && !says_back(&front));
        // Facing the camera: kept, whatever the mirror image's read.
        assert_eq!(front_read(front.clone(), Some(away.clone())), front);
        assert_eq!(front_read(front.clone(), None), front);
        // Facing away, the mirror image's read facing the camera: that read.
        let other = torso(-0.2);
        assert_eq!(front_read(away.clone(), Some(other.clone())), other);
        // Facing away and no better read (none, facing away too, or a profile): the first turned in depth.
        assert_eq!(front_read(away.clone(), None), front);
        assert_eq!(front_read(away.clone(), Some(torso(2.8))), front);
        assert_eq!(front_read(away.clone(), Some(torso(std::f32::consts::FRAC_PI_2))), front);
        // A read without a facing (NaN torso) is never taken.
        let mut nan = torso(0.0);
        nan.world[11] = Vec3::NAN;
        assert_eq!(front_read(away, Some(nan)), front);
    }

    #[test]
    fn mirror_images_of_pictures_and_frames() {
        let image = crate::buffer::Image::from_fn(3, 2, |c, r| (10 * r + c) as u8);
        assert_eq!(mirrored_left_right(&image).data, vec![2, 1, 0, 12, 11, 10]);
        assert_eq!(mirrored_left_right(&mirrored_left_right(&image)), image);
        let frame = (Vec2::new(10.0, 20.0), Vec2::new(300.0, 400.0));
        assert_eq!(mirrored_frame(frame, 512.0), (Vec2::new(212.0, 20.0), Vec2::new(502.0, 400.0)));
        assert_eq!(mirrored_frame(mirrored_frame(frame, 512.0), 512.0), frame);
    }

    #[test]
    fn standing_legs_lose_their_common_lean_and_keep_their_stride() {
        // Hips at y 0, knees at -0.4, ankles at -0.8 (m); the legs lean back: left ankle 0.3 m behind the hips, right
        // 0.1 m (mean 0.2), knees 0.1 behind, feet like their ankles; image depths 100 pixels per metre. Sheared about
        // the hips by the mean lean per metre of drop (0.25): knees move 0.1, ankles 0.2 forward, the stride (left
        // 0.2 behind right) stays; hips and everything above them untouched.
        let mut l = torso(0.0);
        l.landmarks.iter_mut().for_each(|m| m.visibility = 0.9);
        let legs = [(25, -0.4, -0.1), (26, -0.4, -0.1), (27, -0.8, -0.3), (28, -0.8, -0.1)];
        for (i, y, z) in
            legs.into_iter().chain([(29, -0.8, -0.3), (30, -0.8, -0.1), (31, -0.85, -0.3), (32, -0.85, -0.1)])
        {
            l.world[i] = Vec3::new(0.0, y, z);
            l.landmarks[i].pixel = Vec2::new(256.0, 256.0 - 100.0 * y);
            l.landmarks[i].depth = 100.0 * z;
        }
        let out = standing_legs(l.clone(), 0.5);
        for (i, y, z) in [(25, -0.4, 0.0), (26, -0.4, 0.0), (27, -0.8, -0.1), (28, -0.8, 0.1)] {
            assert!((out.world[i] - Vec3::new(0.0, y, z)).length() < 1e-5, "{i}: {:?}", out.world[i]);
            assert!((out.landmarks[i].depth - 100.0 * z).abs() < 1e-3, "{i}");
        }
        assert!((out.world[31].z - (-0.3 + 0.2 * 0.85 / 0.8)).abs() < 1e-5);
        let mean = 0.5 * (out.world[27].z + out.world[28].z);
        assert!(mean.abs() < 1e-6);
        for i in 0..25 {
            assert_eq!(out.world[i], l.world[i], "{i}");
            assert_eq!(out.landmarks[i], l.landmarks[i], "{i}");
        }
        // Not standing on feet it sees: an ankle not seen or outside the frame, ankles not below the hips, or NaN.
        let mut hidden = l.clone();
        hidden.landmarks[27].visibility = 0.3;
        assert_eq!(standing_legs(hidden, 0.5), hidden_copy(&l, 27));
        let mut cut = l.clone();
        cut.frame_max.y = 300.0;
        assert_eq!(standing_legs(cut.clone(), 0.5), cut);
        let mut raised = l.clone();
        raised.world[27].y = 0.1;
        raised.world[28].y = 0.1;
        assert_eq!(standing_legs(raised.clone(), 0.5), raised);
        let mut nan = l.clone();
        nan.world[28].z = f32::NAN;
        let out = standing_legs(nan, 0.5);
        assert_eq!((out.world[27].z, out.world[25].z, out.landmarks[27].depth), (-0.3, -0.1, l.landmarks[27].depth));
    }

    fn hidden_copy(l: &PoseLandmarks, i: usize) -> PoseLandmarks {
        let mut out = l.clone();
        out.landmarks[i].visibility = 0.3;
        out
    }

    #[test]
    fn a_hand_is_seen_only_through_its_elbow() {
        // Every landmark visible 0.9 inside a 512² frame; the left elbow at visibility 0.4, the right elbow below
        // the frame: both hands (wrist, pinky, index, thumb) become invisible, nothing else changes. With both
        // elbows seen and inside, nothing changes.
        let mut l = torso(0.0);
        l.landmarks.iter_mut().for_each(|m| m.visibility = 0.9);
        l.frame_min = Vec2::ZERO;
        l.frame_max = Vec2::splat(512.0);
        assert_eq!(arms_it_sees(l.clone(), 0.5), l);
        l.landmarks[13].visibility = 0.4;
        l.landmarks[14].pixel = Vec2::new(200.0, 530.0);
        let out = arms_it_sees(l.clone(), 0.5);
        for i in 0..l.landmarks.len() {
            let hidden = (15..=22).contains(&i);
            let expected = if hidden { 0.0 } else { l.landmarks[i].visibility };
            assert_eq!(out.landmarks[i].visibility, expected, "{i}");
        }
        // A NaN elbow visibility is not seen either.
        l.landmarks[14].pixel = Vec2::new(200.0, 300.0);
        l.landmarks[14].visibility = f32::NAN;
        assert_eq!(arms_it_sees(l, 0.5).landmarks[16].visibility, 0.0);
    }

    #[test]
    fn limbs_are_seen_by_their_far_end() {
        // Elbows 13/14, wrists 15/16, knees 25/26, ankles 27/28 in LIMB_SEGMENTS order; at the threshold counts as
        // seen, below it or NaN does not.
        let mut l = torso(0.0);
        l.landmarks.iter_mut().for_each(|m| m.visibility = 1.0);
        assert_eq!(limbs_seen(&l, 0.5), [true; 8]);
        l.landmarks[13].visibility = 0.5;
        l.landmarks[16].visibility = 0.49;
        l.landmarks[26].visibility = f32::NAN;
        l.landmarks[27].visibility = 0.0;
        assert_eq!(limbs_seen(&l, 0.5), [true, true, true, false, true, false, false, true]);
    }

    #[test]
    fn a_leg_drawn_shorter_than_a_persons_is_not_seen() {
        // Left thigh 0.25 m (a guess), right thigh 0.4 m (a leg): the left knee, ankle, heel and foot become
        // invisible, the rest is untouched; a NaN knee counts as not seen.
        let mut l = torso(0.0);
        l.world[25] = l.world[23] + Vec3::new(0.0, -0.25, 0.0);
        l.world[26] = l.world[24] + Vec3::new(0.0, -0.3, 0.265);
        l.landmarks.iter_mut().for_each(|m| m.visibility = 0.9);
        let out = legs_it_sees(l.clone());
        for i in 0..l.landmarks.len() {
            let hidden = [25, 27, 29, 31].contains(&i);
            assert_eq!(out.landmarks[i].visibility, if hidden { 0.0 } else { 0.9 }, "{i}");
        }
        assert_eq!(out.world, l.world);
        l.world[26].x = f32::NAN;
        assert_eq!(legs_it_sees(l).landmarks[28].visibility, 0.0);
    }

    #[test]
    fn a_straight_bottom_edge_is_the_soles_of_a_person_standing_on_it() {
        // Mask rows 10..90 (height 80 above the edge at row 90): a foot point counts within 0.1 x 80 = 8 pixels above
        // the edge (or below it). Thighs 0.4 m (legs the network sees).
        let mask = crate::buffer::Image::from_fn(100, 100, |_, r| if (10..90).contains(&r) { 1.0 } else { 0.0 });
        let mut l = torso(0.0);
        l.world[25] = l.world[23] + Vec3::new(0.0, -0.4, 0.0);
        l.world[26] = l.world[24] + Vec3::new(0.0, -0.4, 0.0);
        l.landmarks.iter_mut().for_each(|m| m.visibility = 0.9);
        for i in 25..33 {
            l.landmarks[i].pixel.y = 70.0;
        }
        let standing = |l: &PoseLandmarks| stands_on(l, &mask, 90.0, 0.5);
        assert!(!standing(&l), "feet 20 pixels above the edge");
        l.landmarks[27].pixel.y = 82.5;
        assert!(!standing(&l), "one foot on the edge");
        l.landmarks[32].pixel.y = 93.0;
        assert!(standing(&l), "left ankle and right foot index on the edge");
        l.landmarks[32].pixel.y = 81.5;
        assert!(!standing(&l), "just above the margin");
        l.landmarks[32].pixel.y = 82.0;
        assert!(standing(&l), "on the margin");
        let mut hidden = l.clone();
        hidden.landmarks[27].visibility = 0.4;
        assert!(!standing(&hidden), "an ankle it does not see");
        let mut folded = l.clone();
        folded.world[26] = folded.world[24] + Vec3::new(0.0, -0.25, 0.0);
        assert!(!standing(&folded), "a folded body's short thigh");
        let mut nan = l.clone();
        nan.landmarks[27].pixel.y = f32::NAN;
        assert!(!standing(&nan));
        assert!(!stands_on(&l, &crate::buffer::Image::new(100, 100, 0.0), 90.0, 0.5), "empty mask");
        assert!(!stands_on(&l, &mask, 5.0, 0.5), "edge above the mask's top");
    }
}
