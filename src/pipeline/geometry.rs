//! The per-input geometry: which geometry a mode draws ([`GeometryMode`], [`AUTO_CHOICE`],
//! [`FRAMES_AUTO_CHOICE`]) and how it is computed — the silhouette-inflation prior, the body prior and its FOF, the
//! body-placed inflation with the face relief, and the FOF network with its guard.

use std::sync::atomic::AtomicBool;
use std::time::Duration;

use glam::Vec2;

use crate::body::pose::PoseLandmarks;
use crate::buffer::GrayImage;
use crate::geometry::fof::Fof;
use crate::geometry::inflate::{self};
use crate::geometry::shells::drop_unexplained_shells;
use crate::geometry::TriMesh;

use super::input::NormalisedInput;
use super::{guard, PipelineError, PrepareOptions, SharedBody, SharedPlacementNet, StageTimings};

/// Where the per-input geometry comes from (`--geometry`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum GeometryMode {
    /// Silhouette-inflation prior from the mask (no network needed).
    #[default]
    Inflate,
    /// The FOF network (`models/<tier>/fof.onnx`) correcting the inflation prior; an error when the model or the
    /// ONNX Runtime library cannot be loaded, or when the network fails on an input.
    #[value(name = "fofnet")]
    FofNet,
    /// The geometry that wins the whole evaluation ([`AUTO_CHOICE`]; synthetic subjects in every framing, the
    /// independent scans and the real-photo checks, docs/geometry.md "Which geometry wins where"). The inflation prior stands in,
    /// with one warning, when the model the choice needs does not load (`fof.onnx`, the pose network), and for an
    /// input the FOF network fails on or the body prior finds no pose in.
    Auto,
    /// The body prior: pose landmarks (ONNX) -> the fitted MakeHuman body -> its FOF reconciled with the
    /// silhouette (no FOF network; [`crate::body::prior`]). An input where no pose is found falls back to the
    /// inflation prior with a warning.
    Body,
    /// The silhouette-inflation prior with the face relief from the face mesh the pose landmarks locate
    /// ([`crate::body::face`]), every column moved by the shift of the model folder's `placement.onnx` when it has
    /// one ([`super::load_placement_net`]), else moved toward the fitted body's depth only as far as the fit is
    /// trusted there ([`crate::body::placed::placement_confidence`]: at the prior's depth wherever it is unsure).
    /// An input where no pose is found gets the inflation prior with a warning.
    #[value(name = "body-placed")]
    BodyPlaced,
}

/// What [`GeometryMode::Auto`] draws: the silhouette-inflation prior (docs/geometry.md, "Which geometry wins where"),
/// decided on the held-out half of the UFO: Alien Invasion characters (`scripts/scan-ufoai.sh`, nine people the
/// project had not used, split by name before any number was read). There, against the inflation prior, whole-frame
/// PSNR at close / divergent views: body-placed (the face relief, no column moved) +0.02 / +0.00 dB on the mean
/// but civ_female_body02 −0.10 / −0.16 dB (its face relief off), more than the 0.1 dB of noise it may lose by; the
/// FOF net −0.33 / −0.13 dB; the body prior −2.19 / −1.49 dB. Volumetric IoU: the inflation prior 0.567, the FOF
/// net 0.543, the body prior 0.395. The rule that moved every column halfway toward the fitted body's depth (what
/// auto drew before) lost the dev half by 0.57 / 0.36 dB (docs/geometry.md). The confidence-aware body placement
/// ([`crate::body::placed::placement_confidence`]) held every character of the Nexuiz players' held-out half
/// (`scripts/scan-nexuiz.sh`, worst −0.05 / −0.07 dB) but not their mean (−0.003 / −0.018 dB), so auto stays the
/// inflation prior (docs/geometry.md, "Confidence-aware body placement"). Needs no network.
pub const AUTO_CHOICE: GeometryMode = GeometryMode::Inflate;

/// What [`GeometryMode::Auto`] draws on the frames of a video or camera (`render --video`, and the live frames of
/// `view` and `xr`): what it draws on a still ([`AUTO_CHOICE`]) when that has one shell per column, which the frame
/// path meshes straight from its depth maps; the inflation prior otherwise. Under [`GeometryMode::BodyPlaced`]
/// frames get the body placement at its own rate: the fit and the face relief are made every few frames and carried
/// between, as offsets from each frame's inflation prior ([`super::frame::PLACEMENT_EVERY`]; docs/live.md "Frame
/// path").
pub const FRAMES_AUTO_CHOICE: GeometryMode = match AUTO_CHOICE {
    GeometryMode::Body | GeometryMode::FofNet | GeometryMode::Auto => GeometryMode::Inflate,
    one_shell => one_shell,
};

impl GeometryMode {
    /// The mode frames of a video or camera are prepared with: [`FRAMES_AUTO_CHOICE`] for auto, the mode itself
    /// otherwise (an explicit `--geometry body-placed` still fits a body per frame, warm-started).
    pub fn for_frames(self) -> Self {
        match self {
            GeometryMode::Auto => FRAMES_AUTO_CHOICE,
            other => other,
        }
    }

    /// The mode's `--geometry` value (`auto`, `fofnet`, `inflate`, `body`, `body-placed`).
    pub fn name(self) -> String {
        clap::ValueEnum::to_possible_value(&self).map(|v| v.get_name().to_owned()).unwrap_or_default()
    }

    /// Whether the mode that runs fits a body to the input ([`GeometryMode::Body`], [`GeometryMode::BodyPlaced`]).
    pub fn fits_body(self) -> bool {
        matches!(self.resolved(), GeometryMode::Body | GeometryMode::BodyPlaced)
    }

    /// The mode that runs: [`AUTO_CHOICE`] for [`GeometryMode::Auto`], the mode itself otherwise.
    pub fn resolved(self) -> Self {
        match self {
            GeometryMode::Auto => AUTO_CHOICE,
            other => other,
        }
    }
}

/// The body prior's FOF of a normalised input (see [`GeometryMode::Body`]) and, when it could not be used, why:
/// the inflation prior `prior` is returned instead when no pose is found or the prior fails. This is the one place
/// the body FOF is computed: `--geometry body`, the FOF net's `body` input and the dataset writer's
/// `body_fof.npy` all come through it (`body_prior_fof_or_why`).
pub fn body_prior_fof(
    normalised: &NormalisedInput,
    opts: &PrepareOptions,
    body: &SharedBody,
    prior: Fof,
    timings: &mut StageTimings,
) -> (Fof, Option<String>) {
    match body_prior_fof_or_why(normalised, opts, body, timings) {
        Ok(f) => (f, None),
        Err(why) => (prior, Some(why.to_string())),
    }
}

/// Why the body prior gave no FOF for an input (the caller then uses its fall-back).
#[derive(Debug, thiserror::Error)]
pub enum NoBodyFof {
    /// The pose network found no person.
    #[error("no pose found in this input")]
    NoPose,
    /// The fitted body, reconciled with the silhouette, holds no volume inside the mask.
    #[error("the fitted body covers none of the person")]
    NoVolume,
    /// The pose network, the fit or the body FOF failed on this input.
    #[error("it failed on this input ({0})")]
    Failed(#[source] crate::body::BodyError),
}

/// [`body_prior_fof`] without a fall-back at hand: the body FOF, or why there is none (no pose found, or the prior
/// failed), so the caller computes its fall-back only when it is needed.
fn body_prior_fof_or_why(
    normalised: &NormalisedInput,
    opts: &PrepareOptions,
    body: &SharedBody,
    timings: &mut StageTimings,
) -> Result<Fof, NoBodyFof> {
    let (prior, silhouette) = fitted_body_or_why(normalised, opts, body, timings)?;
    timings
        .time("body FOF", || Fof::from_intervals(&body_intervals(normalised, opts, prior, &silhouette), opts.fof_order))
        .map_err(|e| NoBodyFof::Failed(crate::body::BodyError::Fof(e)))
}

/// The fitted body of an input and its silhouette's own inflation profile (solved beside the pose network and the
/// fit, which is single-threaded: it depends on the mask alone), or why there is no body.
fn fitted_body_or_why(
    normalised: &NormalisedInput,
    opts: &PrepareOptions,
    body: &SharedBody,
    timings: &mut StageTimings,
) -> Result<(crate::body::prior::BodyPrior, crate::body::reconcile::SilhouetteProfile), NoBodyFof> {
    let mut stages: Vec<(&'static str, Duration)> = Vec::new();
    let (found, silhouette) = {
        let mut guard = body.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        let estimator: &mut crate::body::prior::BodyEstimator = &mut guard;
        rayon::join(
            || {
                estimator.estimate(
                    &normalised.rgb,
                    &normalised.mask,
                    Some(normalised.frame),
                    opts.warm_start,
                    &mut |name, d| stages.push((name, d)),
                )
            },
            || crate::body::reconcile::SilhouetteProfile::of(&normalised.mask),
        )
    };
    timings.0.extend(stages);
    match found {
        Ok(Some(p)) => Ok((p, silhouette)),
        Ok(None) => Err(NoBodyFof::NoPose),
        Err(e) => Err(NoBodyFof::Failed(e)),
    }
}

/// The fitted body's intervals reconciled with the silhouette ([`crate::body::prior::body_intervals_with`]), the
/// body placed in depth by [`centre_visible_depth`] first: what the body FOF encodes.
fn body_intervals(
    normalised: &NormalisedInput,
    opts: &PrepareOptions,
    prior: crate::body::prior::BodyPrior,
    silhouette: &crate::body::reconcile::SilhouetteProfile,
) -> crate::buffer::Image<Vec<(f32, f32)>> {
    let frame = prior.frame();
    let mesh = centre_visible_depth(prior.mesh, &normalised.mask);
    crate::body::prior::body_intervals_with(
        &mesh,
        &normalised.mask,
        Some(frame),
        opts.fof_order,
        &opts.inflate,
        Some(silhouette),
    )
}

/// [`GeometryMode::BodyPlaced`]: the inflation prior's surfaces (solved beside the pose network and the fit) with
/// each column moved toward the fitted body's depth as far as the fit is trusted there ([`crate::body::placed`])
/// and the face relief; the inflation prior itself, with
/// one warning per process, when the body prior finds no pose or fails.
fn body_placed_geometry(
    normalised: &NormalisedInput,
    opts: &PrepareOptions,
    body: &SharedBody,
    timings: &mut StageTimings,
) -> Result<Fof, PipelineError> {
    let surfaces = body_placed_surfaces(normalised, opts, body, timings)?;
    Ok(timings.time("geometry (body placement -> FOF)", || {
        Fof::from_depth_maps(&surfaces.front, &surfaces.back, &surfaces.mask, opts.fof_order)
    })?)
}

/// The surfaces of [`GeometryMode::BodyPlaced`] (one shell per column), depth-centred
/// ([`crate::body::placed::centred`]): what the still path encodes as a FOF and the frame path meshes directly
/// ([`super::frame`]).
pub fn body_placed_surfaces(
    normalised: &NormalisedInput,
    opts: &PrepareOptions,
    body: &SharedBody,
    timings: &mut StageTimings,
) -> Result<inflate::InflatedSurfaces, PipelineError> {
    let (mut inflation_times, mut body_times) = (StageTimings::default(), StageTimings::default());
    let frame = crate::body::prior::effective_frame(&normalised.mask, Some(normalised.frame));
    let inflated =
        |frame: (Vec2, Vec2)| inflate::inflate_resolvable(&normalised.mask, opts.fof_order, &opts.inflate, Some(frame));
    let (surfaces, fitted) = rayon::join(
        || inflation_times.time("geometry (inflate)", || inflated(frame)),
        || fitted_body_or_why(normalised, opts, body, &mut body_times),
    );
    timings.0.extend(inflation_times.0.into_iter().chain(body_times.0));
    let mut surfaces = surfaces?;
    let surfaces = match fitted {
        Ok((prior, silhouette)) => {
            let landmarks = prior.landmarks.clone();
            let landmarks = &landmarks;
            if prior.frame() != frame {
                // The pose read stood the person on the straight bottom edge (soles, not a cut): inflate again with
                // the frame the body was fitted in.
                surfaces = timings.time("geometry (inflate, body's frame)", || inflated(prior.frame()))?;
            }
            // The face mesh needs only the pose landmarks: it runs beside the placement (the network's when the
            // model folder has one, else the confidence-aware one of `body::placed`).
            let (mut interval_times, mut face_times) = (StageTimings::default(), StageTimings::default());
            let (shifts, face) = rayon::join(
                || match opts.placement.as_ref() {
                    Some(net) => {
                        let intervals = interval_times
                            .time("body intervals", || body_intervals(normalised, opts, prior.clone(), &silhouette));
                        let learned = interval_times.time("body placement (network)", || {
                            placement_net_shifts(net, &surfaces, &intervals, opts)
                        });
                        learned.or_else(|| {
                            interval_times.time("body placement (confidence)", || {
                                confident_placement(normalised, opts, prior, &surfaces)
                            })
                        })
                    }
                    None => interval_times.time("body placement (confidence)", || {
                        confident_placement(normalised, opts, prior, &surfaces)
                    }),
                },
                || face_times.time("face mesh", || face_mesh(normalised, body, landmarks)),
            );
            timings.0.extend(interval_times.0.into_iter().chain(face_times.0));
            let surfaces = match shifts {
                Some(shifts) => crate::body::placed::place(surfaces, &shifts),
                None => surfaces,
            };
            match face {
                Some(face) => {
                    tracing::debug!(
                        "face mesh: drift {:.3}, pose offset {:.3} of the width",
                        face.drift,
                        face.pose_offset(landmarks)
                    );
                    timings.time("face relief", || with_face_relief(surfaces, &face))
                }
                None => surfaces,
            }
        }
        Err(why) => {
            warn_no_body_fof(&why);
            surfaces
        }
    };
    Ok(timings.time("geometry (surface centring)", || crate::body::placed::centred(surfaces)))
}

/// The shifts of the confidence-aware placement ([`crate::body::placed::placement_confidence`],
/// [`crate::body::placed::confident_shifts`]) of the fitted body `prior` for the inflation prior `surfaces`; `None`
/// when nothing is placed.
fn confident_placement(
    normalised: &NormalisedInput,
    opts: &PrepareOptions,
    prior: crate::body::prior::BodyPrior,
    surfaces: &inflate::InflatedSurfaces,
) -> Option<GrayImage> {
    use crate::body::placed::{confident_shifts, placement_confidence, Reference, PLACEMENT_WEIGHT};
    let (w, h) = (surfaces.mask.width, surfaces.mask.height);
    let mesh = centre_visible_depth(prior.mesh, &normalised.mask);
    let own =
        crate::geometry::fof::intervals_from_mesh(&mesh, w, h, crate::geometry::fof::sheet_thickness(opts.fof_order));
    let confidence = placement_confidence(&own, surfaces, &prior.landmarks)?;
    let shifts = confident_shifts(&own, surfaces, &confidence, PLACEMENT_WEIGHT, Reference::Row)?;
    let inside: Vec<usize> = (0..w * h).filter(|&i| surfaces.mask.data[i] > 0.5).collect();
    let n = inside.len().max(1) as f32;
    tracing::debug!(
        "body placement: mean confidence {:.3}, mean |shift| {:.4}, trusted share {:.3}",
        inside.iter().map(|&i| confidence.data[i]).sum::<f32>() / n,
        inside.iter().map(|&i| shifts.data[i].abs()).sum::<f32>() / n,
        inside.iter().filter(|&&i| confidence.data[i] > 0.0).count() as f32 / n
    );
    Some(shifts)
}

/// The face mesh ([`crate::body::face`]) of the person `pose` was read from; `None` when no face is found (said
/// at debug level) or the face model is not installed (one warning per process).
fn face_mesh(
    normalised: &NormalisedInput,
    body: &SharedBody,
    pose: &PoseLandmarks,
) -> Option<crate::body::face::FaceMesh> {
    let mut guard = body.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    let mesh = guard.face_mesh(&normalised.rgb, pose);
    if mesh.is_none() {
        tracing::debug!("face relief: no face found");
    }
    mesh
}

/// `surfaces` with the front of the face shaped by `face` ([`crate::body::face::with_face_relief`]); as they are
/// when its relief is skipped (said at debug level).
fn with_face_relief(
    surfaces: inflate::InflatedSurfaces,
    face: &crate::body::face::FaceMesh,
) -> inflate::InflatedSurfaces {
    let (surfaces, skipped) = crate::body::face::with_face_relief(surfaces, face);
    match skipped {
        Some(why) => tracing::debug!("face relief skipped: {why:?}"),
        None => tracing::debug!(
            "face relief: width {:.1} px, yaw {:.2} rad, score {:.3}",
            face.width(),
            face.yaw(),
            face.score
        ),
    }
    surfaces
}

/// The placement network's shifts for the inflation prior `surfaces` and the fitted body's reconciled `intervals`
/// (both encoded as FOFs, as the network's training data holds them); `None`, with one warning per process, when
/// the network fails on this input (the confidence-aware placement then stands in).
fn placement_net_shifts(
    net: &SharedPlacementNet,
    surfaces: &inflate::InflatedSurfaces,
    intervals: &crate::buffer::Image<Vec<(f32, f32)>>,
    opts: &PrepareOptions,
) -> Option<GrayImage> {
    let (prior, body) = rayon::join(
        || Fof::from_depth_maps(&surfaces.front, &surfaces.back, &surfaces.mask, opts.fof_order),
        || Fof::from_intervals(intervals, opts.fof_order),
    );
    let shifts: Result<GrayImage, Box<dyn std::error::Error + Send + Sync>> = match (prior, body) {
        (Ok(prior), Ok(body)) => {
            let mut net = net.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
            net.shifts(&surfaces.mask, &prior, &body).map_err(Into::into)
        }
        (Err(e), _) | (_, Err(e)) => Err(e.into()),
    };
    match shifts {
        Ok(s) => Some(s),
        Err(e) => {
            static WARNED: std::sync::Once = std::sync::Once::new();
            WARNED.call_once(|| {
                tracing::warn!("placement network failed ({e}); columns are placed where the body fit is trusted")
            });
            None
        }
    }
}

/// Places a fitted body (a mesh in the body cube seen by the source camera of `mask`'s grid) in depth before it is
/// reconciled with the silhouette, by the depth convention ([`crate::geometry::depth_centre`]) applied to the part
/// the photo shows: the centroid of the body's occupied volume over the mask's pixels (measured on a
/// [`crate::geometry::depth_centre::MESH_GRID`]² grid) goes to z = 0. For a photo cut at the waist the legs fitted
/// below the frame do not count. (The minimal enclosing circle of the xz projection used before followed the
/// extremities: on chest-up crops, whose shoulders and arms are wider than the cube is deep, it put the torso up to
/// 0.4 cube units off centre, the reconciled field then hit the cube's back face and the final centring of
/// [`compute_geometry`], limited to keep the person inside the cube, could not bring it back: volumetric IoU 0.23
/// instead of 0.54 on such a subject, `examples/body_synthetic`.) The mesh is unchanged when no part of it covers
/// the mask.
pub fn centre_visible_depth(mut mesh: TriMesh, mask: &GrayImage) -> TriMesh {
    use crate::geometry::depth_centre::{intervals_centroid_z, MESH_GRID, SHEET_ORDER};
    use crate::geometry::fof::{intervals_from_mesh, sheet_thickness};
    let (w, h) = (mask.width, mask.height);
    if w == 0 || h == 0 {
        return mesh;
    }
    let intervals = intervals_from_mesh(&mesh, MESH_GRID, MESH_GRID, sheet_thickness(SHEET_ORDER));
    // The mask pixel under each grid pixel's centre.
    let visible = (0..MESH_GRID * MESH_GRID).filter_map(|i| {
        let (c, r) = (i % MESH_GRID, i / MESH_GRID);
        let mc = ((c as f32 + 0.5) * w as f32 / MESH_GRID as f32) as usize;
        let mr = ((r as f32 + 0.5) * h as f32 / MESH_GRID as f32) as usize;
        (*mask.get(mc.min(w - 1), mr.min(h - 1)) >= 0.5).then(|| intervals.data[i].as_slice())
    });
    if let Some((centroid, _, _)) = intervals_centroid_z(visible) {
        mesh.positions.iter_mut().for_each(|p| p.z -= centroid);
    }
    mesh
}

/// [`body_prior_fof`] with its fall-back logged (one warning per process, then debug messages); the fall-back,
/// `fallback()`, is computed only when it is used.
fn body_geometry(
    normalised: &NormalisedInput,
    opts: &PrepareOptions,
    body: &SharedBody,
    fallback: impl FnOnce(&mut StageTimings) -> Result<Fof, PipelineError>,
    timings: &mut StageTimings,
) -> Result<Fof, PipelineError> {
    match body_prior_fof_or_why(normalised, opts, body, timings) {
        Ok(fof) => Ok(fof),
        Err(why) => {
            warn_no_body_fof(&why);
            fallback(timings)
        }
    }
}

/// Logs that the body prior gave no FOF and the silhouette-inflation prior stands in (once per process as a
/// warning, then as debug messages).
fn warn_no_body_fof(why: &NoBodyFof) {
    static WARNED: AtomicBool = AtomicBool::new(false);
    warn_once(&WARNED, &format!("body prior: {why}, using the silhouette-inflation prior"));
}

/// The per-input geometry of a normalised input as `opts.geometry` asks (see [`GeometryMode`]), timing its stages
/// into `timings`: the inflation prior, then (FOF net modes) the network's correction at the prior's resolution
/// ([`crate::neural::FofNet::refine`]) or (body mode) the body prior; last, whatever was chosen is placed in depth by the body
/// cube's convention ([`crate::geometry::depth_centre::centre_fof`]: the occupied volume's centroid at z = 0, the
/// rule the ground truth follows too), so every geometry mode turns the person about the same axis.
pub fn compute_geometry(
    normalised: &NormalisedInput,
    opts: &PrepareOptions,
    timings: &mut StageTimings,
) -> Result<Fof, PipelineError> {
    let fof = chosen_geometry(normalised, opts, timings)?;
    Ok(timings.time("geometry (depth centring)", || crate::geometry::depth_centre::centre_fof(fof).0))
}

/// The silhouette-inflation prior of an input, timed: open where the photo cuts the person when `open` (the inflation
/// geometry, in the frame the body prior reads the photo in: [`crate::body::prior::effective_frame`]), closed along
/// the whole outline otherwise (the FOF net's input, as its training data holds it: `eval::dataset::prior_fof`).
fn inflation_prior(
    normalised: &NormalisedInput,
    opts: &PrepareOptions,
    open: bool,
    timings: &mut StageTimings,
) -> Result<Fof, PipelineError> {
    let frame = open.then(|| crate::body::prior::effective_frame(&normalised.mask, Some(normalised.frame)));
    Ok(timings.time("geometry (inflate -> FOF)", || {
        inflate::inflate_to_fof(&normalised.mask, opts.fof_order, &opts.inflate, frame)
    })?)
}

/// The silhouette-inflation prior's surfaces of an input, open where the photo cuts the person (as
/// `inflation_prior` encodes them) and depth-centred ([`crate::body::placed::centred`]): the frame path's
/// geometry under [`GeometryMode::Inflate`].
pub fn inflation_surfaces(
    normalised: &NormalisedInput,
    opts: &PrepareOptions,
    timings: &mut StageTimings,
) -> Result<inflate::InflatedSurfaces, PipelineError> {
    inflation_surfaces_coarse(normalised, opts, 1, timings)
}

/// [`inflation_surfaces`] solved on a grid `factor` times coarser ([`inflate::inflate_resolvable_coarse`]).
pub fn inflation_surfaces_coarse(
    normalised: &NormalisedInput,
    opts: &PrepareOptions,
    factor: usize,
    timings: &mut StageTimings,
) -> Result<inflate::InflatedSurfaces, PipelineError> {
    let frame = crate::body::prior::effective_frame(&normalised.mask, Some(normalised.frame));
    let surfaces = timings.time("geometry (inflate)", || {
        inflate::inflate_resolvable_coarse(&normalised.mask, opts.fof_order, &opts.inflate, Some(frame), factor)
    })?;
    Ok(timings.time("geometry (surface centring)", || crate::body::placed::centred(surfaces)))
}

/// [`compute_geometry`] before the depth centring.
fn chosen_geometry(
    normalised: &NormalisedInput,
    opts: &PrepareOptions,
    timings: &mut StageTimings,
) -> Result<Fof, PipelineError> {
    let inflation = |timings: &mut StageTimings| inflation_prior(normalised, opts, true, timings);
    if opts.geometry.fits_body() {
        let Some(body) = &opts.body else {
            // Auto without the body prior: `load_body` said so once.
            if opts.geometry == GeometryMode::Auto {
                return inflation(timings);
            }
            return Err(PipelineError::NoBody("no body prior was loaded (see load_body)".into()));
        };
        return match opts.geometry.resolved() {
            // The inflation prior only as the fall-back: computed when no body is found.
            GeometryMode::Body => body_geometry(normalised, opts, body, inflation, timings),
            _ => body_placed_geometry(normalised, opts, body, timings),
        };
    }
    fof_net_or_inflation(normalised, opts, timings)
}

/// What [`chosen_geometry`] draws outside the body modes: the FOF net (its body input computed as `--geometry body`
/// computes it, with the pose that body was fitted to), or the inflation prior.
fn fof_net_or_inflation(
    normalised: &NormalisedInput,
    opts: &PrepareOptions,
    timings: &mut StageTimings,
) -> Result<Fof, PipelineError> {
    let inflation = |timings: &mut StageTimings| inflation_prior(normalised, opts, true, timings);
    // The network refines the closed prior it was trained on.
    let net_prior = |timings: &mut StageTimings| inflation_prior(normalised, opts, false, timings);
    let net = match (opts.geometry, &opts.fof_net) {
        // The body modes returned above: what is left is the inflation prior or the FOF net.
        (mode, _) if mode.resolved() != GeometryMode::FofNet => return inflation(timings),
        (GeometryMode::FofNet, None) => {
            return Err(PipelineError::NoFofNet("no FOF network was loaded (see load_fof_net)".into()))
        }
        (_, Some(net)) => net,
        // Auto without a loaded network (and the modes handled above).
        (_, None) => return inflation(timings),
    };
    let takes_body = net.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).takes_body();
    // The body FOF the network takes: the body prior exactly as `--geometry body` computes it (its fall-back, the
    // inflation prior, when no pose is found: what the training data holds for such inputs).
    let (prior, body) = match (takes_body, &opts.body) {
        (false, _) => (net_prior(timings)?, None),
        (true, Some(body)) => {
            // The inflation prior and the body prior do not depend on each other: they run side by side (on two
            // cores the body fit is single-threaded, the pose network and the inflation are not). Their stage
            // times overlap; both are recorded, the inflation prior's first.
            let (mut prior_times, mut body_times) = (StageTimings::default(), StageTimings::default());
            let (prior, body_fof) = rayon::join(
                || net_prior(&mut prior_times),
                || body_prior_fof_or_why(normalised, opts, body, &mut body_times),
            );
            timings.0.extend(prior_times.0.into_iter().chain(body_times.0));
            let prior = prior?;
            let body_fof = body_fof.unwrap_or_else(|why| {
                warn_no_body_fof(&why);
                prior.clone()
            });
            (prior, Some(body_fof))
        }
        (true, None) if opts.geometry == GeometryMode::FofNet => {
            return Err(PipelineError::NoFofNet(
                "the FOF net takes the body FOF, but no body prior was loaded (see load_body_for)".into(),
            ))
        }
        (true, None) => {
            static WARNED: AtomicBool = AtomicBool::new(false);
            warn_once(
                &WARNED,
                "the FOF net takes the body FOF, but no body prior was loaded: using the silhouette-inflation prior",
            );
            return inflation(timings);
        }
    };
    let refined = timings.time("geometry (FOF net)", || {
        net.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).refine_with(
            &normalised.rgb,
            &normalised.mask,
            &prior,
            body.as_ref(),
        )
    });
    // A column keeps no more shells than the silhouette (the inflation prior's one) and the fitted body explain: a
    // surface the network drew twice becomes one (`shells::drop_unexplained_shells`).
    let refined = refined.map(|mut fof| {
        timings.time("geometry (one shell per explained surface)", || {
            let references: Vec<&Fof> = std::iter::once(&prior).chain(body.as_ref()).collect();
            let changed = drop_unexplained_shells(&mut fof, &references, &normalised.mask);
            tracing::debug!("FOF net: {changed} columns lost shells neither prior explains");
        });
        fof
    });
    // What the network refined (its residual base): the guard measures against it and falls back to it.
    let base = match (net.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).base(), body) {
        (crate::neural::FofInput::Body, Some(body)) => body,
        _ => prior,
    };
    match (refined, opts.geometry) {
        (Ok(fof), _) => {
            let (fof, rejected) = timings.time("geometry (guard)", || {
                guard::guarded(fof, base, &normalised.mask, &guard::GuardLimits::default())
            });
            if let Some(why) = rejected {
                static WARNED: AtomicBool = AtomicBool::new(false);
                warn_once(
                    &WARNED,
                    &format!("the FOF net's geometry is not one plausible person ({why}); using the prior it refined"),
                );
            }
            Ok(fof)
        }
        (Err(e), GeometryMode::Auto) => {
            static WARNED: AtomicBool = AtomicBool::new(false);
            warn_once(&WARNED, &format!("the FOF net failed on this input, using the prior it refines: {e}"));
            Ok(base)
        }
        (Err(e), _) => Err(PipelineError::FofNetFailed(e)),
    }
}

/// Logs `message` at warning level the first time `flag` is seen, at debug level afterwards (a video would repeat
/// it every frame).
pub(super) fn warn_once(flag: &AtomicBool, message: &str) {
    if !flag.swap(true, std::sync::atomic::Ordering::Relaxed) {
        tracing::warn!("{message}");
    } else {
        tracing::debug!("{message}");
    }
}
