//! The per-input and per-view stages as plain functions over images, each with its CPU reference, and the two
//! objects that schedule them:
//! - [`PreparedInput`]: everything computed once per input frame (normalise -> geometry (FOF) -> mesh ->
//!   source depth/normals).
//! - [`ViewRenderer`]: everything computed per view (target raster -> flow/Z-map/visibility -> warp -> spatial
//!   fusion), reusing its buffers from view to view.
//!
//! Two renderers draw the person ([`RendererChoice`]): the geometric warp ([`warp::render_geometric`]) and the
//! neural one ([`NeuralRenderer`]: the encoder once per [`PreparedInput`] ([`NeuralRenderer::encode`]), the
//! residual decoder per view over the target mask's bounding box ([`ViewRenderer::with_neural`])). Spatial
//! fusion applies to both. A decoder failure or non-finite output on a view logs a warning and that view is drawn
//! by the geometric renderer: never a black frame.

pub mod back;
pub mod export;
pub mod fusion;
pub mod guard;
pub mod input;
pub mod person;
pub mod warp;

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use glam::{Vec2, Vec4};
use rayon::prelude::*;

use crate::body::pose::PoseLandmarks;
use crate::body::prior::BodyEstimator;
use crate::buffer::{GrayImage, Image, RgbImage, RgbaImage};
use crate::compose::{self, Mode, RenderedFrame};
use crate::geometry::fof::{Fof, FofError};
use crate::geometry::inflate::{self, InflateError, InflateParams};
use crate::geometry::marching;
use crate::geometry::raster::{self, GBuffer};
use crate::geometry::shells::drop_unexplained_shells;
use crate::geometry::zmap::{flow_and_zmap_into, FlowZ};
use crate::geometry::{Camera, TriMesh, SOURCE_RESOLUTION};
use crate::io::environment::Environment;
use crate::neural::{
    Coefficients, EncoderInput, FeatureMap, FofNet, NeuralError, NeuralRuntime, PlacementNet, RuntimeOptions,
};

use fusion::SpatialFusion;
use input::{InputError, NormalisedInput};
pub use person::{
    Drawn, Neural, NeuralCounters, NeuralPolicy, NeuralRef, NeuralRequest, NeuralViewTimes, PersonBackend, Scene,
    SceneNeural, SourceView,
};
use warp::OcclusionFill;

/// Errors of the pipeline layer.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// The photo or mask cannot be used.
    #[error(transparent)]
    Input(#[from] InputError),
    /// The silhouette-inflation prior failed.
    #[error("cannot build geometry from the mask: {0}")]
    Inflate(#[from] InflateError),
    /// The Fourier occupancy field could not be built.
    #[error("Fourier occupancy field: {0}")]
    Fof(#[from] FofError),
    /// The reconstructed mesh is empty.
    #[error("the reconstructed geometry is empty; the mask may be too thin or fragmented to reconstruct")]
    EmptyGeometry,
    /// A stage produced NaN or infinity (a bug: reported instead of drawing a broken frame).
    #[error("internal error: the {0} stage produced non-finite values; please report this with the input")]
    NonFinite(&'static str),
    /// The neural renderer was requested explicitly and cannot run.
    #[error("neural renderer: {0}")]
    Neural(#[from] NeuralError),
    /// The neural renderer was requested explicitly but no model folder was given or found.
    #[error(
        "neural renderer: no model folder found (looked for models/{0}/encoder.onnx next to the working \
         directory, the executable and the source tree). Pass --models DIR, or use --renderer geometric"
    )]
    NoModels(String),
    /// The FOF network was requested (`--geometry fofnet`) but cannot be used.
    #[error(
        "FOF network: {0}. Pass --models DIR with a fof.onnx (train it with `python -m train fit-fof`, see \
         train/README.md), or use --geometry inflate"
    )]
    NoFofNet(String),
    /// The body prior (`--geometry body`) cannot be used: the pose model or the body model data is missing.
    #[error("body prior: {0}. Install them with `bash scripts/setup.sh`, or use --geometry inflate")]
    NoBody(String),
    /// The FOF network's file is there but cannot be loaded (`--geometry fofnet`): ONNX Runtime is missing, or the
    /// file is corrupt or not a FOF network. Worded as [`PipelineError::NoFofNet`]; the cause is the source.
    #[error(
        "FOF network: {0}. Pass --models DIR with a fof.onnx (train it with `python -m train fit-fof`, see \
         train/README.md), or use --geometry inflate"
    )]
    FofNetLoad(#[source] NeuralError),
    /// The model folder's `placement.onnx` is there but cannot be loaded (`--geometry body-placed`): ONNX Runtime
    /// is missing, or the file is corrupt or not a placement network. The cause is the source.
    #[error(
        "placement network: it does not load. Remove or re-export it (`python -m train export --placement`, see \
         train/README.md), pass --models DIR without it (the fixed placement rule), or use --geometry inflate"
    )]
    PlacementLoad(#[source] NeuralError),
    /// The model folder's `placement.onnx` reads another number of FOF coefficients than `--fof-order`.
    #[error(
        "placement network: {0}. Re-export it for this order, pass --models DIR without it (the fixed placement \
         rule), or use --geometry inflate"
    )]
    PlacementOrder(String),
    /// The body prior's pose model or body data cannot be loaded (`--geometry body`). Worded as
    /// [`PipelineError::NoBody`]; the cause is the source.
    #[error("body prior: {0}. Install them with `bash scripts/setup.sh`, or use --geometry inflate")]
    BodyLoad(#[source] crate::body::BodyError),
    /// The FOF network (`--geometry fofnet`) failed on this input (a run error or non-finite coefficients).
    #[error(
        "FOF network failed on this input: {0}. Use --geometry auto (falls back to the inflation prior) or inflate"
    )]
    FofNetFailed(#[source] NeuralError),
}

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
    /// independent scans and the real-photo checks, README "Which geometry, where"). The inflation prior stands in,
    /// with one warning, when the model the choice needs does not load (`fof.onnx`, the pose network), and for an
    /// input the FOF network fails on or the body prior finds no pose in.
    Auto,
    /// The body prior: pose landmarks (ONNX) -> the fitted MakeHuman body -> its FOF reconciled with the
    /// silhouette (no FOF network; [`crate::body::prior`]). An input where no pose is found falls back to the
    /// inflation prior with a warning.
    Body,
    /// The silhouette-inflation prior with every column moved halfway toward the fitted body's depth there
    /// ([`crate::body::placed`]), or by the shift of the model folder's `placement.onnx` when it has one
    /// ([`load_placement_net`]): the silhouette's thickness, the body's placement in depth. An input where no pose
    /// is found gets the inflation prior with a warning.
    #[value(name = "body-placed")]
    BodyPlaced,
}

/// What [`GeometryMode::Auto`] draws: the body-placed inflation prior (session 13, README "Which geometry, where").
/// Release evaluation, volumetric IoU / divergent mask IoU against the silhouette-inflation prior: 8 clothed synthetic
/// subjects at 512² 0.594 / .766 .763 .788 (full, three-quarter, upper) against 0.560 / .721 .725 .757, better in
/// every framing (the FOF net has more synthetic volume, 0.608, and loses the characters); the ten independent
/// characters of `scripts/scan-check.sh` 0.508 / 0.717 against 0.503 / 0.708 (best of the four predicted geometries
/// in every column; the dev half 0.528 / 0.760 against 0.509 / 0.740) but the held-out half 0.488 / 0.675 against
/// 0.497 / 0.676 (loses beret and tony by 0.03); three characters new to the project (angelyss, ayumi, neko, read
/// once after the decision) 0.455 / 0.591 against 0.446 / 0.575; every photo check passes. It costs the pose network
/// and the fit on every input. Without the body prior's data it draws the inflation prior, with one warning.
pub const AUTO_CHOICE: GeometryMode = GeometryMode::BodyPlaced;

/// What [`GeometryMode::Auto`] draws on the frames of a video or camera (`render --video`, and the live frames of
/// `view` and `xr`): the silhouette-inflation prior. A body geometry follows the pose network's jitter between
/// frames of a person who barely moves. Rendered at yaw 90 (`examples/video_stability`), consecutive-frame mask
/// IoU: one photo copied 20 times, 0.998 with the inflation prior and 0.992 with body-placed (0.942 before
/// session 15 stopped the region tracking that made the body wander); the same photo shifted by up to 1 px, 0.994
/// against 0.975 (the network's landmarks move 2-17 px for a 1-px shift). It also costs about 70 ms more per
/// frame (README "Live frames with a body geometry").
pub const FRAMES_AUTO_CHOICE: GeometryMode = GeometryMode::Inflate;

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

/// A loaded FOF network shared by the inputs that use it (it runs under the lock).
pub type SharedFofNet = Arc<Mutex<FofNet>>;

/// A loaded placement network shared by the inputs that use it (it runs under the lock).
pub type SharedPlacementNet = Arc<Mutex<PlacementNet>>;

/// The body prior's pose network and fitter, shared by the inputs that use it (it runs under the lock; it keeps
/// the last frame's fit for warm starts).
pub type SharedBody = Arc<Mutex<BodyEstimator>>;

/// The pose network that finds the face for the back image, shared by the inputs that use it (it runs under the
/// lock).
#[derive(Clone)]
pub struct SharedPose(pub Arc<Mutex<crate::body::pose::PoseEstimator>>);

impl std::fmt::Debug for SharedPose {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SharedPose").finish_non_exhaustive()
    }
}

/// The pose network for `fill`'s back image ([`OcclusionFill::Back`]; `None` for the other fills): when it does
/// not load, one warning and `None` — the renderers then colour what the photo does not show from the photo, as
/// [`OcclusionFill::MirroredFront`] does.
pub fn load_back_pose(fill: OcclusionFill, options: &RuntimeOptions) -> Option<SharedPose> {
    if fill != OcclusionFill::Back {
        return None;
    }
    match crate::body::pose::PoseEstimator::load(None, options) {
        Ok(p) => Some(SharedPose(Arc::new(Mutex::new(p)))),
        Err(e) => {
            tracing::warn!(
                "fill: no back image ({e}); surfaces the photo does not show take the photo's colours \
                 (--fill mirrored-front). Install the pose model with `bash scripts/setup.sh`, or pass --fill \
                 mirrored-front to silence this"
            );
            None
        }
    }
}

/// The back image of a normalised input ([`back::back_image`]) with the face found by `pose`; `None` (one warning
/// per process, then debug messages) when the pose network finds no person or no usable face, or fails.
pub fn back_image_of(normalised: &NormalisedInput, pose: &SharedPose, timings: &mut StageTimings) -> Option<RgbImage> {
    back_image_with(normalised, pose, None, timings).map(|back| back.rgb)
}

/// [`back_image_of`], with its head weights, from the face of `read` (pose landmarks of the same input, e.g. the
/// body prior's, [`compute_geometry_and_pose`]) when it has a usable one: the pose network runs only without it.
pub fn back_image_with(
    normalised: &NormalisedInput,
    pose: &SharedPose,
    read: Option<&PoseLandmarks>,
    timings: &mut StageTimings,
) -> Option<back::BackImage> {
    let face = read.and_then(back::FacePoints::from_pose).or_else(|| {
        let found = timings.time("back image (face landmarks)", || {
            let mut p = pose.0.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
            p.estimate(&normalised.rgb, &normalised.mask, Some(normalised.frame))
        });
        match found {
            Ok(Some(l)) => back::FacePoints::from_pose(&l),
            Ok(None) => None,
            Err(e) => {
                tracing::debug!("back image: the pose network failed: {e}");
                None
            }
        }
    });
    let back = face
        .and_then(|f| timings.time("back image (filter)", || back::back_image(&normalised.rgb, &normalised.mask, &f)));
    if back.is_none() {
        static WARNED: AtomicBool = AtomicBool::new(false);
        warn_once(
            &WARNED,
            "back image: no face found in this input; surfaces the photo does not show take the photo's colours",
        );
    }
    back
}

/// Settings for [`PreparedInput::prepare`].
#[derive(Clone, Debug)]
pub struct PrepareOptions {
    /// Source (FOF grid) resolution; 512 like the reference.
    pub resolution: usize,
    /// Number of FOF-X coefficients N.
    pub fof_order: usize,
    /// Depth samples for mesh extraction (512 like the reference).
    pub depth_samples: usize,
    /// Geometry source.
    pub geometry: GeometryMode,
    /// Parameters of the inflation prior.
    pub inflate: InflateParams,
    /// The FOF network for [`GeometryMode::FofNet`] (and [`GeometryMode::Auto`] when [`AUTO_CHOICE`] is the FOF
    /// net; [`load_fof_net`]); `None` with `FofNet` is an error, with `Auto` the inflation prior.
    pub fof_net: Option<SharedFofNet>,
    /// The body prior for [`GeometryMode::Body`] ([`load_body`]) and for a FOF net that takes the body FOF
    /// ([`load_body_for`]); `None` with `Body` is an error.
    pub body: Option<SharedBody>,
    /// The placement network of [`GeometryMode::BodyPlaced`] ([`load_placement_net`]); `None`: the fixed rule
    /// ([`crate::body::placed::PLACEMENT_WEIGHT`] of the body's depth).
    pub placement: Option<SharedPlacementNet>,
    /// Live input: warm-start the body prior from the previous frame (its tracking region and fitted pose).
    pub warm_start: bool,
    /// The pose network that finds the face for the back image ([`load_back_pose`]; [`back::back_image`]); `None`:
    /// no back image (the renderers then colour what the photo does not show from the photo itself).
    pub back_pose: Option<SharedPose>,
}

impl Default for PrepareOptions {
    fn default() -> Self {
        Self {
            resolution: SOURCE_RESOLUTION,
            fof_order: 32,
            depth_samples: SOURCE_RESOLUTION,
            geometry: GeometryMode::Inflate,
            inflate: InflateParams::default(),
            fof_net: None,
            body: None,
            placement: None,
            warm_start: false,
            back_pose: None,
        }
    }
}

/// `--models`, or the project's [`DEFAULT_MODEL_TIER`] folder when found.
fn model_folder(models: Option<&Path>) -> Option<PathBuf> {
    models.map(Path::to_path_buf).or_else(|| crate::neural::default_model_dir(DEFAULT_MODEL_TIER))
}

/// Resolves `--geometry` and `--models` into the FOF network to use: `Ok(None)` for the modes that draw no FOF
/// network (inflate, body, body-placed, and auto when [`AUTO_CHOICE`] is one of them); for [`GeometryMode::FofNet`]
/// the loaded `fof.onnx` of the model folder or an error saying how to get one; for [`GeometryMode::Auto`] choosing
/// the FOF net, the network when it loads, else one warning (how to enable it) and `None`. `models` defaults to
/// [`crate::neural::default_model_dir`] of [`DEFAULT_MODEL_TIER`]. Its `N` must be `fof_order`.
pub fn load_fof_net(
    mode: GeometryMode,
    models: Option<&Path>,
    fof_order: usize,
    options: &RuntimeOptions,
) -> Result<Option<SharedFofNet>, PipelineError> {
    if mode.resolved() != GeometryMode::FofNet {
        if mode == GeometryMode::Auto {
            tracing::info!(
                "geometry: auto is `{}` (the evaluation's winner, README \"Which geometry, where\")",
                AUTO_CHOICE.name()
            );
        }
        return Ok(None);
    }
    let dir = model_folder(models);
    let loaded = match dir {
        None => Err(PipelineError::NoFofNet(format!(
            "no model folder found (looked for models/{DEFAULT_MODEL_TIER}/ next to the working directory, the \
             executable and the source tree)"
        ))),
        Some(dir) => {
            let path = dir.join(crate::neural::FOF_FILE);
            if !path.is_file() {
                Err(PipelineError::NoFofNet(format!("`{}` does not exist", path.display())))
            } else {
                FofNet::load(&path, options).map_err(PipelineError::FofNetLoad).and_then(|net| {
                    if net.info().fof_n == fof_order {
                        Ok(net)
                    } else {
                        Err(PipelineError::NoFofNet(format!(
                            "`{}` predicts {} FOF coefficients but --fof-order is {fof_order}",
                            path.display(),
                            net.info().fof_n
                        )))
                    }
                })
            }
        }
    };
    match (loaded, mode) {
        (Ok(net), _) => {
            tracing::info!(
                "geometry: FOF net `{}` ({}, {} px) on {}",
                net.path().display(),
                net.info().tier,
                net.info().resolution,
                net.provider()
            );
            Ok(Some(Arc::new(Mutex::new(net))))
        }
        (Err(e), GeometryMode::Auto) => {
            tracing::warn!(
                "geometry: using the silhouette-inflation prior ({e}). To use the FOF network, install ONNX \
                 Runtime with `bash scripts/setup.d/neural.sh` and pass --models DIR holding fof.onnx (see \
                 train/README.md), or pass --geometry inflate to silence this"
            );
            Ok(None)
        }
        (Err(e), _) => Err(e),
    }
}

/// Resolves `--geometry` and `--models` into the placement network of [`GeometryMode::BodyPlaced`] (also under
/// [`GeometryMode::Auto`] when [`AUTO_CHOICE`] is it): the model folder's `placement.onnx` when it has one,
/// `Ok(None)` (the fixed placement rule) when it has none or for the other modes. A file that does not load (or
/// predicts for another `N` than `fof_order`) is an error under `body-placed` and one warning and the fixed rule
/// under auto.
pub fn load_placement_net(
    mode: GeometryMode,
    models: Option<&Path>,
    fof_order: usize,
    options: &RuntimeOptions,
) -> Result<Option<SharedPlacementNet>, PipelineError> {
    if mode.resolved() != GeometryMode::BodyPlaced {
        return Ok(None);
    }
    let Some(path) = model_folder(models).map(|dir| dir.join(crate::neural::PLACEMENT_FILE)).filter(|p| p.is_file())
    else {
        tracing::info!("geometry: body placement by the fixed rule (no {})", crate::neural::PLACEMENT_FILE);
        return Ok(None);
    };
    let loaded = match PlacementNet::load(&path, options) {
        Ok(net) if net.info().fof_n == fof_order => Ok(net),
        Ok(net) => Err(PipelineError::PlacementOrder(format!(
            "`{}` reads {} FOF coefficients but --fof-order is {fof_order}",
            path.display(),
            net.info().fof_n
        ))),
        Err(e) => Err(PipelineError::PlacementLoad(e)),
    };
    match loaded {
        Ok(net) => {
            tracing::info!(
                "geometry: body placement by `{}` ({} px) on {}",
                path.display(),
                net.info().resolution,
                net.provider()
            );
            Ok(Some(Arc::new(Mutex::new(net))))
        }
        Err(e) if mode == GeometryMode::Auto => {
            let cause = std::error::Error::source(&e).map(|c| format!(" ({c})")).unwrap_or_default();
            tracing::warn!("geometry: {e}{cause}; placing the body by the fixed rule");
            Ok(None)
        }
        Err(e) => Err(e),
    }
}

/// The options a still photo is prepared with when nothing asks for a geometry (`--geometry auto`): the models
/// [`AUTO_CHOICE`] needs, from `models` (the FOF net) and the project's tools (the body prior), each replaced by the
/// inflation prior with one warning when it does not load. `view` and `xr` prepare their stills with these, so a
/// photo looks the same in the headset, the window and `render`.
pub fn auto_still_options(models: Option<&Path>, options: &RuntimeOptions) -> Result<PrepareOptions, PipelineError> {
    let defaults = PrepareOptions::default();
    let fof_net = load_fof_net(GeometryMode::Auto, models, defaults.fof_order, options)?;
    let body = load_body_for(GeometryMode::Auto, fof_net.as_ref(), options)?;
    let placement = load_placement_net(GeometryMode::Auto, models, defaults.fof_order, options)?;
    Ok(PrepareOptions { geometry: GeometryMode::Auto, fof_net, body, placement, ..defaults })
}

/// Loads the body prior for the modes that fit a body ([`GeometryMode::fits_body`]; `Ok(None)` for the others):
/// the pose landmark model (`.tools/models/pose_landmark_full.onnx`) and the MakeHuman body data, or an error saying
/// how to install them (under [`GeometryMode::Auto`]: one warning saying so, and `Ok(None)`).
pub fn load_body(mode: GeometryMode, options: &RuntimeOptions) -> Result<Option<SharedBody>, PipelineError> {
    if !mode.fits_body() {
        return Ok(None);
    }
    let body = match BodyEstimator::load(None, options) {
        Ok(body) => body,
        Err(e) if mode == GeometryMode::Auto => {
            tracing::warn!(
                "geometry: auto draws `{}`, but the body prior does not load ({e}); using the silhouette-inflation \
                 prior. Install it with `bash scripts/setup.sh`",
                AUTO_CHOICE.name()
            );
            return Ok(None);
        }
        Err(e) => return Err(PipelineError::BodyLoad(e)),
    };
    tracing::info!("geometry: body prior (pose model `{}`)", crate::body::pose::MODEL_FILE);
    Ok(Some(Arc::new(Mutex::new(body))))
}

/// The body prior for `mode` and the FOF network it uses: [`load_body`] for [`GeometryMode::Body`]; for the FOF
/// net modes, the body prior when the loaded network takes the body FOF ([`FofNet::takes_body`]) — an error under
/// [`GeometryMode::FofNet`] when it cannot load, one warning and `None` under [`GeometryMode::Auto`] (its inputs
/// then get the inflation prior, see [`compute_geometry`]); `None` otherwise.
pub fn load_body_for(
    mode: GeometryMode,
    fof_net: Option<&SharedFofNet>,
    options: &RuntimeOptions,
) -> Result<Option<SharedBody>, PipelineError> {
    let takes_body = fof_net.is_some_and(|n| n.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).takes_body());
    match mode {
        _ if mode.fits_body() => load_body(mode, options),
        GeometryMode::FofNet | GeometryMode::Auto if takes_body => match BodyEstimator::load(None, options) {
            Ok(body) => Ok(Some(Arc::new(Mutex::new(body)))),
            Err(e) if mode == GeometryMode::FofNet => Err(PipelineError::NoFofNet(format!(
                "the FOF net takes the body FOF, but the body prior does not load ({e}); install it with \
                     `bash scripts/setup.sh`"
            ))),
            Err(e) => {
                tracing::warn!(
                    "geometry: the FOF net takes the body FOF, but the body prior does not load ({e}); using \
                         the silhouette-inflation prior. Install it with `bash scripts/setup.sh`"
                );
                Ok(None)
            }
        },
        _ => Ok(None),
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
    body_prior_fof_and_pose_or_why(normalised, opts, body, timings).map(|(fof, _)| fof)
}

/// [`body_prior_fof_or_why`] with the pose landmarks the body was fitted to.
fn body_prior_fof_and_pose_or_why(
    normalised: &NormalisedInput,
    opts: &PrepareOptions,
    body: &SharedBody,
    timings: &mut StageTimings,
) -> Result<(Fof, PoseLandmarks), NoBodyFof> {
    let (prior, silhouette) = fitted_body_or_why(normalised, opts, body, timings)?;
    let pose = prior.landmarks.clone();
    let fof = timings
        .time("body FOF", || Fof::from_intervals(&body_intervals(normalised, opts, prior, &silhouette), opts.fof_order))
        .map_err(|e| NoBodyFof::Failed(crate::body::BodyError::Fof(e)))?;
    Ok((fof, pose))
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
/// each column moved toward the fitted body's depth there ([`crate::body::placed`]); the inflation prior itself, with
/// one warning per process, when the body prior finds no pose or fails.
fn body_placed_geometry(
    normalised: &NormalisedInput,
    opts: &PrepareOptions,
    body: &SharedBody,
    timings: &mut StageTimings,
) -> Result<GeometryAndPose, PipelineError> {
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
    let mut pose = None;
    let surfaces = match fitted {
        Ok((prior, silhouette)) => {
            let landmarks: &PoseLandmarks = pose.insert(prior.landmarks.clone());
            if prior.frame() != frame {
                // The pose read stood the person on the straight bottom edge (soles, not a cut): inflate again with
                // the frame the body was fitted in.
                surfaces = timings.time("geometry (inflate, body's frame)", || inflated(prior.frame()))?;
            }
            // The face mesh needs only the pose landmarks: it runs beside the body's intervals.
            let (mut interval_times, mut face_times) = (StageTimings::default(), StageTimings::default());
            let (intervals, face) = rayon::join(
                || interval_times.time("body intervals", || body_intervals(normalised, opts, prior, &silhouette)),
                || face_times.time("face mesh", || face_mesh(normalised, body, landmarks)),
            );
            timings.0.extend(interval_times.0.into_iter().chain(face_times.0));
            let learned = opts.placement.as_ref().and_then(|net| {
                timings.time("body placement (network)", || placement_net_shifts(net, &surfaces, &intervals, opts))
            });
            let shifts = learned.or_else(|| {
                crate::body::placed::depth_shifts(&intervals, &surfaces.mask, crate::body::placed::PLACEMENT_WEIGHT)
            });
            let surfaces = match shifts {
                Some(shifts) => crate::body::placed::place(surfaces, &shifts),
                None => {
                    warn_no_body_fof(&NoBodyFof::NoVolume);
                    surfaces
                }
            };
            match face {
                Some(face) => timings.time("face relief", || with_face_relief(surfaces, &face)),
                None => surfaces,
            }
        }
        Err(why) => {
            warn_no_body_fof(&why);
            surfaces
        }
    };
    let fof = timings.time("geometry (body placement -> FOF)", || {
        let surfaces = crate::body::placed::centred(surfaces);
        Fof::from_depth_maps(&surfaces.front, &surfaces.back, &surfaces.mask, opts.fof_order)
    })?;
    Ok((fof, pose))
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
/// the network fails on this input (the caller then places by the fixed rule).
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
            WARNED.call_once(|| tracing::warn!("placement network failed ({e}); placing the body by the fixed rule"));
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
) -> Result<GeometryAndPose, PipelineError> {
    match body_prior_fof_and_pose_or_why(normalised, opts, body, timings) {
        Ok((fof, pose)) => Ok((fof, Some(pose))),
        Err(why) => {
            warn_no_body_fof(&why);
            Ok((fallback(timings)?, None))
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
/// ([`FofNet::refine`]) or (body mode) the body prior; last, whatever was chosen is placed in depth by the body
/// cube's convention ([`crate::geometry::depth_centre::centre_fof`]: the occupied volume's centroid at z = 0, the
/// rule the ground truth follows too), so every geometry mode turns the person about the same axis.
pub fn compute_geometry(
    normalised: &NormalisedInput,
    opts: &PrepareOptions,
    timings: &mut StageTimings,
) -> Result<Fof, PipelineError> {
    compute_geometry_and_pose(normalised, opts, timings).map(|(fof, _)| fof)
}

/// A per-input geometry and the pose landmarks the body prior read on the way (`None` when no body was fitted).
pub type GeometryAndPose = (Fof, Option<PoseLandmarks>);

/// [`compute_geometry`] with the pose landmarks the body was fitted to (`--geometry body`, `body-placed`, a FOF net
/// that takes the body FOF, and `auto` when it is one of them), which the back image reuses for the face instead of running the pose network again
/// ([`PreparedInput::from_fof_and_pose`]).
pub fn compute_geometry_and_pose(
    normalised: &NormalisedInput,
    opts: &PrepareOptions,
    timings: &mut StageTimings,
) -> Result<GeometryAndPose, PipelineError> {
    let (fof, pose) = chosen_geometry(normalised, opts, timings)?;
    Ok((timings.time("geometry (depth centring)", || crate::geometry::depth_centre::centre_fof(fof).0), pose))
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

/// [`compute_geometry_and_pose`] before the depth centring.
fn chosen_geometry(
    normalised: &NormalisedInput,
    opts: &PrepareOptions,
    timings: &mut StageTimings,
) -> Result<GeometryAndPose, PipelineError> {
    let inflation = |timings: &mut StageTimings| inflation_prior(normalised, opts, true, timings);
    if opts.geometry.fits_body() {
        let Some(body) = &opts.body else {
            // Auto without the body prior: `load_body` said so once.
            if opts.geometry == GeometryMode::Auto {
                return Ok((inflation(timings)?, None));
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
) -> Result<GeometryAndPose, PipelineError> {
    let inflation = |timings: &mut StageTimings| inflation_prior(normalised, opts, true, timings);
    // The network refines the closed prior it was trained on.
    let net_prior = |timings: &mut StageTimings| inflation_prior(normalised, opts, false, timings);
    let net = match (opts.geometry, &opts.fof_net) {
        // The body modes returned above: what is left is the inflation prior or the FOF net.
        (mode, _) if mode.resolved() != GeometryMode::FofNet => return Ok((inflation(timings)?, None)),
        (GeometryMode::FofNet, None) => {
            return Err(PipelineError::NoFofNet("no FOF network was loaded (see load_fof_net)".into()))
        }
        (_, Some(net)) => net,
        // Auto without a loaded network (and the modes handled above).
        (_, None) => return Ok((inflation(timings)?, None)),
    };
    let takes_body = net.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).takes_body();
    // The body FOF the network takes: the body prior exactly as `--geometry body` computes it (its fall-back, the
    // inflation prior, when no pose is found: what the training data holds for such inputs).
    let (prior, body, pose) = match (takes_body, &opts.body) {
        (false, _) => (net_prior(timings)?, None, None),
        (true, Some(body)) => {
            // The inflation prior and the body prior do not depend on each other: they run side by side (on two
            // cores the body fit is single-threaded, the pose network and the inflation are not). Their stage
            // times overlap; both are recorded, the inflation prior's first.
            let (mut prior_times, mut body_times) = (StageTimings::default(), StageTimings::default());
            let (prior, body_fof) = rayon::join(
                || net_prior(&mut prior_times),
                || body_prior_fof_and_pose_or_why(normalised, opts, body, &mut body_times),
            );
            timings.0.extend(prior_times.0.into_iter().chain(body_times.0));
            let prior = prior?;
            let (body_fof, pose) = match body_fof {
                Ok((fof, pose)) => (fof, Some(pose)),
                Err(why) => {
                    warn_no_body_fof(&why);
                    (prior.clone(), None)
                }
            };
            (prior, Some(body_fof), pose)
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
            return Ok((inflation(timings)?, None));
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
            Ok((fof, pose))
        }
        (Err(e), GeometryMode::Auto) => {
            static WARNED: AtomicBool = AtomicBool::new(false);
            warn_once(&WARNED, &format!("the FOF net failed on this input, using the prior it refines: {e}"));
            Ok((base, pose))
        }
        (Err(e), _) => Err(PipelineError::FofNetFailed(e)),
    }
}

/// Logs `message` at warning level the first time `flag` is seen, at debug level afterwards (a video would repeat
/// it every frame).
fn warn_once(flag: &AtomicBool, message: &str) {
    if !flag.swap(true, std::sync::atomic::Ordering::Relaxed) {
        tracing::warn!("{message}");
    } else {
        tracing::debug!("{message}");
    }
}

/// Wall-clock time of named stages, in the order they ran.
#[derive(Clone, Debug, Default)]
pub struct StageTimings(pub Vec<(&'static str, Duration)>);

impl StageTimings {
    /// Runs `f`, recording its duration under `name`.
    pub fn time<T>(&mut self, name: &'static str, f: impl FnOnce() -> T) -> T {
        let start = Instant::now();
        let out = f();
        self.0.push((name, start.elapsed()));
        out
    }

    /// Total of all recorded stages.
    pub fn total(&self) -> Duration {
        self.0.iter().map(|(_, d)| *d).sum()
    }

    /// One line: "name 12.3 ms, name 4.5 ms, …" in the order the stages ran.
    pub fn summary(&self) -> String {
        let parts: Vec<String> =
            self.0.iter().map(|(name, d)| format!("{name} {:.1} ms", d.as_secs_f64() * 1e3)).collect();
        parts.join(", ")
    }
}

/// Which renderer draws the person (`--renderer`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum RendererChoice {
    /// The geometric warp of the photo (no network).
    #[default]
    Geometric,
    /// The neural renderer (encoder + residual Z-map decoder through ONNX Runtime); an error when its models or
    /// the ONNX Runtime library cannot be loaded.
    Neural,
    /// The neural renderer when its models and ONNX Runtime load, else the geometric one with one warning.
    Auto,
}

/// The model tier the product ships and looks for by default (`models/tiny`).
pub const DEFAULT_MODEL_TIER: &str = "tiny";

/// A neural renderer shared by every [`ViewRenderer`] that uses it (the two eyes of an XR session, say): the
/// decoder runs under the lock, one view at a time.
pub type SharedNeural = Arc<Mutex<NeuralRenderer>>;

/// Resolves `--renderer`, `--models` and `--ep`: `Ok(None)` for the geometric renderer, `Ok(Some(..))` with loaded
/// models for the neural one. [`RendererChoice::Neural`] fails when the models cannot be loaded;
/// [`RendererChoice::Auto`] then logs one warning (saying how to enable the neural renderer) and returns `None`.
/// `models` defaults to [`crate::neural::default_model_dir`] of [`DEFAULT_MODEL_TIER`].
pub fn load_renderer(
    choice: RendererChoice,
    models: Option<&Path>,
    options: &RuntimeOptions,
) -> Result<Option<SharedNeural>, PipelineError> {
    if choice == RendererChoice::Geometric {
        return Ok(None);
    }
    let dir = model_folder(models);
    let loaded = match dir {
        Some(dir) => NeuralRenderer::load(&dir, options).map_err(PipelineError::from),
        None => Err(PipelineError::NoModels(DEFAULT_MODEL_TIER.to_string())),
    };
    match (loaded, choice) {
        (Ok(n), _) => {
            tracing::info!(
                "neural renderer: {} models from `{}` on {}",
                n.runtime.encoder.info().tier,
                n.runtime.dir.display(),
                n.runtime.decoder.provider()
            );
            Ok(Some(Arc::new(Mutex::new(n))))
        }
        (Err(e), RendererChoice::Auto) => {
            tracing::warn!(
                "using the geometric renderer: {e}. To enable the neural one, install ONNX Runtime with \
                 `bash scripts/setup.d/neural.sh` and pass --models DIR (see train/README.md)"
            );
            Ok(None)
        }
        (Err(e), _) => Err(e),
    }
}

/// The neural renderer: the encoder, residual decoder (and optional FOF net) of one model folder.
pub struct NeuralRenderer {
    /// The loaded, mutually checked models.
    pub runtime: NeuralRuntime,
}

/// The encoder's output for one [`PreparedInput`] (computed once per input frame, shared by every view).
#[derive(Clone, Debug)]
pub struct NeuralInput {
    /// Features at 1/4 of the model's resolution.
    pub features: Arc<FeatureMap>,
    /// How long the encoder took (per-input time, on top of [`PreparedInput::timings`]).
    pub encode_time: Duration,
}

impl NeuralRenderer {
    /// Loads the models of `dir` (see [`NeuralRuntime::load`]).
    pub fn load(dir: &Path, options: &RuntimeOptions) -> Result<Self, NeuralError> {
        Ok(Self { runtime: NeuralRuntime::load(dir, options)? })
    }

    /// Runs the encoder on a prepared input: its normalised photo and mask, the source normals of its geometry,
    /// and its FOF when the model takes the same number of coefficients (zeros otherwise, as the reference's test
    /// script feeds).
    pub fn encode(&mut self, input: &PreparedInput) -> Result<NeuralInput, NeuralError> {
        let start = Instant::now();
        let g = &input.source_gbuffer;
        let normals = Image { width: g.width, height: g.height, data: g.normal.clone() };
        let f = &input.fof;
        let fof = (f.n == self.runtime.encoder.info().fof_n
            && f.width == input.normalised.rgb.width
            && f.height == input.normalised.rgb.height)
            .then_some(Coefficients { width: f.width, height: f.height, n: f.n, data: &f.coeffs });
        let features = self.runtime.encoder.run(&EncoderInput {
            rgb: &input.normalised.rgb,
            mask: &input.normalised.mask,
            fof,
            normals: &normals,
        })?;
        Ok(NeuralInput { features: Arc::new(features), encode_time: start.elapsed() })
    }

    /// Renders one view with the decoder: flow and Z-map of `target` (already rasterised for `camera`), the
    /// colour lookup ([`photo_lookup`]), then the decoder over the target mask's bounding box. `flowz` is scratch
    /// memory reused between views.
    pub fn render_view(
        &mut self,
        input: &PreparedInput,
        encoded: &NeuralInput,
        target: &GBuffer,
        camera: &Camera,
        flowz: &mut FlowZ,
        fill: OcclusionFill,
    ) -> Result<RgbaImage, NeuralError> {
        flow_and_zmap_into(flowz, target, camera, &input.source_camera);
        decode_person_view(
            &mut self.runtime.decoder,
            &encoded.features,
            flowz,
            &SourceView::of(input),
            target,
            camera,
            fill,
        )
    }
}

/// One view of the person by the neural decoder, from the flow and Z-map of `target` (rasterised for `camera`):
/// the colour lookup ([`photo_lookup`], with the back image when [`neural_back_lookup`] says so), the decoder, and
/// then the lookup's colour wherever the source camera sees the surface point or the back image knows the back of the
/// head ([`lookup_kept`], [`keep_lookup_where`]). The
/// CPU pipeline and the Vulkan renderer's host-memory seam both draw through it.
pub fn decode_person_view(
    decoder: &mut crate::neural::Decoder,
    features: &FeatureMap,
    flowz: &FlowZ,
    source: &SourceView<'_>,
    target: &GBuffer,
    camera: &Camera,
    fill: OcclusionFill,
) -> Result<RgbaImage, NeuralError> {
    let mut colours = source.colours();
    if !neural_back_lookup(fill) {
        colours.back = None;
    }
    let lookup = photo_lookup(colours, source.mask, source.camera, flowz, Some((target, camera)));
    let mut person = decoder.render_view(features, flowz, source.camera.width, target, &lookup)?;
    let seen = crate::geometry::zmap::visibility(
        flowz,
        source.gbuffer,
        source.camera,
        crate::geometry::zmap::VISIBILITY_LAMBDA,
    );
    let head = source.back.map(|b| &b.head).filter(|_| colours.back.is_some());
    let axis = warp::source_axis(camera, source.camera);
    let kept = lookup_kept(&seen, flowz, target, axis, head, source.camera.width);
    keep_lookup_where(&mut person, &lookup, &kept);
    Ok(person)
}

/// How much of the back image's colour must be the head top's ([`back::BackImage::head`]) for the neural
/// renderer to keep it on the back of the head ([`lookup_kept`]).
pub const HEAD_KEPT: f32 = 0.5;

/// Which pixels of a neural view take the colour lookup ([`photo_lookup`]) instead of the decoder's output: those
/// whose surface point the source camera sees (`seen`, paper Eq. 9), and, with the back image's `head` weights
/// (source pixels of a camera `source_width` wide, or another size scaled to it), the surfaces that face away from
/// the source camera ([`warp::back_weight`] 1 against `axis`, [`warp::source_axis`]) and whose flow lands where the
/// back image drew the head in the head top's colour (weight at least [`HEAD_KEPT`], nearest pixel). The decoder,
/// trained on synthetic people, painted a pale oval where a face would be on the back of real people's dark heads
/// (README "The back of the head in the neural renderer"); the back image's head colour is what the photo says.
pub fn lookup_kept(
    seen: &[bool],
    flowz: &FlowZ,
    target: &GBuffer,
    axis: glam::Vec3,
    head: Option<&GrayImage>,
    source_width: usize,
) -> Vec<bool> {
    let n = seen.len();
    let Some(head) = head.filter(|_| flowz.mask.len() == n && target.normal.len() == n && flowz.flow.data.len() == n)
    else {
        return seen.to_vec();
    };
    let scale = head.width as f32 / source_width.max(1) as f32;
    let on_head = |i: usize| {
        let p = flowz.flow.data[i] * scale;
        if !p.is_finite() || p.x < 0.0 || p.y < 0.0 {
            return false;
        }
        let (c, r) = (p.x as usize, p.y as usize);
        c < head.width && r < head.height && head.data[r * head.width + c] >= HEAD_KEPT
    };
    (0..n)
        .into_par_iter()
        .map(|i| seen[i] || (flowz.mask[i] && warp::back_weight(target.normal[i], axis) >= 1.0 && on_head(i)))
        .collect()
}

/// Puts the colour lookup (`lookup`, [`photo_lookup`]) back on every covered pixel of the decoder's `person` that
/// `kept` marks ([`lookup_kept`]: the photo sees its surface point, or it is the back of the head the back image
/// knows) and the lookup has a colour for. The decoder is residual on that colour and was trained on synthetic
/// people, where keeping the photo here moves its views by at most 0.15 dB; on real photos it shifted their colours
/// (a blue cast on the astronaut's helmet and gloves, up to 7.5 dB below the geometric renderer at the input view,
/// README "Neural renderer"), so what the photo shows is taken from the photo and the decoder draws only what it
/// does not show. Arrays of another size leave `person` as it is.
pub fn keep_lookup_where(person: &mut RgbaImage, lookup: &RgbaImage, kept: &[bool]) {
    let n = person.data.len();
    if lookup.data.len() != n || kept.len() != n || (lookup.width, lookup.height) != (person.width, person.height) {
        return;
    }
    for ((p, l), &s) in person.data.iter_mut().zip(&lookup.data).zip(kept) {
        if s && l.w >= 1.0 && p.w > 0.0 {
            *p = *l;
        }
    }
}

/// The residual decoder's colour lookup (its `warped_rgb` input): for every target pixel with a flow, the source
/// colour at the flow by the geometric renderer's lookup ([`warp::SourceColours::sample`]: the photo, `rgb` linear
/// premultiplied by `source_mask`, sampled mask-aware and bilinearly), clamped to `[0, 1]`. With `target` (the
/// view's G-buffer, of the flow's size, and camera) its normals blend in the colours' back image on surfaces facing
/// away from the source camera ([`warp::back_weight`]) and their side images on surfaces it sees edge-on
/// ([`warp::side_weight`]), each when the colours have them. Without `target` this is the geometric renderer's
/// `MirroredFront` lookup of the sharp photo without the visibility test and without filling holes: alpha is 1
/// where the photo has a colour and 0 where the flow lands outside the source silhouette (or there is no flow).
pub fn photo_lookup<'a>(
    source_rgb: impl Into<warp::SourceColours<'a>>,
    source_mask: &GrayImage,
    source_cam: &Camera,
    flowz: &FlowZ,
    target: Option<(&GBuffer, &Camera)>,
) -> RgbaImage {
    let colours: warp::SourceColours = source_rgb.into();
    let source_rgb = colours.rgb;
    let (w, h) = (flowz.flow.width, flowz.flow.height);
    let mut out = RgbaImage::new(w, h, Vec4::ZERO);
    if w * h == 0
        || flowz.mask.len() != w * h
        || source_mask.width != source_rgb.width
        || source_mask.height != source_rgb.height
    {
        return out;
    }
    // The normals only from a target G-buffer of the flow's size.
    let target = target.filter(|(g, _)| (g.width, g.height) == (w, h));
    let fill =
        if target.is_some() && colours.back.is_some() { OcclusionFill::Back } else { OcclusionFill::MirroredFront };
    let axis = target.map_or(glam::Vec3::ZERO, |(_, cam)| warp::source_axis(cam, source_cam));
    // Flow is in the source camera's pixels; the photo may have another size.
    let scale = Vec2::new(
        source_rgb.width as f32 / source_cam.width.max(1) as f32,
        source_rgb.height as f32 / source_cam.height.max(1) as f32,
    );
    out.data.par_chunks_mut(w).enumerate().for_each(|(row, line)| {
        for (col, o) in line.iter_mut().enumerate() {
            let i = row * w + col;
            if flowz.mask[i] {
                let (b, s) = target.map_or((0.0, 0.0), |(g, _)| {
                    (warp::back_weight(g.normal[i], axis), warp::side_weight(g.normal[i], axis))
                });
                if let Some(c) = colours.sample(source_mask, flowz.flow.data[i] * scale, b, s, fill) {
                    *o = c.clamp(glam::Vec3::ZERO, glam::Vec3::ONE).extend(1.0);
                }
            }
        }
    });
    out
}

/// Whether the neural decoder's colour lookup ([`photo_lookup`]) uses the back image under `fill` (the decoder is
/// residual on its lookup; the README's fill section has the measurement that decided this).
pub fn neural_back_lookup(fill: OcclusionFill) -> bool {
    fill == OcclusionFill::Back
}

/// Everything computed once per input frame.
#[derive(Clone, Debug)]
pub struct PreparedInput {
    /// The orthographic source camera (`resolution^2`).
    pub source_camera: Camera,
    /// The person normalised into the body cube (premultiplied RGB and mask).
    pub normalised: NormalisedInput,
    /// The Fourier occupancy field.
    pub fof: Fof,
    /// The mesh extracted from the FOF.
    pub mesh: TriMesh,
    /// Source-view depth and normals of the mesh.
    pub source_gbuffer: GBuffer,
    /// The back image and where it drew the head ([`back::back_image`]) when `back_pose` was given and found a
    /// face.
    pub back: Option<back::BackImage>,
    /// The photo and the back image blurred for the surfaces the photo sees edge-on ([`warp::SideImages`]).
    pub side: warp::SideImages,
    /// How long each per-input stage took.
    pub timings: StageTimings,
}

impl PreparedInput {
    /// Runs the per-input stages on a photo (linear RGB, straight colour) and its person mask (`[0, 1]`).
    pub fn prepare(rgb: &RgbImage, mask: &GrayImage, opts: &PrepareOptions) -> Result<Self, PipelineError> {
        let mut timings = StageTimings::default();
        let normalised = timings.time("normalise", || input::normalise(rgb, mask, opts.resolution))?;
        let (fof, pose) = compute_geometry_and_pose(&normalised, opts, &mut timings)?;
        Self::from_fof_and_pose(normalised, fof, pose.as_ref(), opts, timings)
    }

    /// Finishes preparation from an already computed FOF (e.g. a network's, or ground truth). The back image
    /// (with `opts.back_pose`) depends on the photo alone: it is computed beside the mesh and the source raster,
    /// and its stage times are recorded after theirs.
    pub fn from_fof(
        normalised: NormalisedInput,
        fof: Fof,
        opts: &PrepareOptions,
        timings: StageTimings,
    ) -> Result<Self, PipelineError> {
        Self::from_fof_and_pose(normalised, fof, None, opts, timings)
    }

    /// [`PreparedInput::from_fof`] with the pose landmarks the geometry's body prior read
    /// ([`compute_geometry_and_pose`]): the back image takes its face from them instead of running the pose network
    /// again.
    pub fn from_fof_and_pose(
        normalised: NormalisedInput,
        fof: Fof,
        pose: Option<&PoseLandmarks>,
        opts: &PrepareOptions,
        mut timings: StageTimings,
    ) -> Result<Self, PipelineError> {
        let source_camera = Camera::source(opts.resolution);
        let mut back_timings = StageTimings::default();
        // The colours are only read by the back image and the renderers, so their rim is cleaned beside the mesh.
        let rim = input::RIM_FRACTION * opts.resolution as f32;
        let (geometry, (normalised, back, side)) = rayon::join(
            || -> Result<(TriMesh, GBuffer), PipelineError> {
                let mesh =
                    timings.time("mesh (FOF -> marching cubes)", || marching::extract_mesh(&fof, opts.depth_samples));
                if mesh.is_empty() {
                    return Err(PipelineError::EmptyGeometry);
                }
                if mesh.validate().is_err() {
                    return Err(PipelineError::NonFinite("mesh"));
                }
                let source_gbuffer = timings.time("source raster", || raster::rasterize(&mesh, &source_camera));
                Ok((mesh, source_gbuffer))
            },
            || {
                let normalised =
                    back_timings.time("rim colours", || input::interior_colours_at_the_rim(normalised, rim));
                let back =
                    opts.back_pose.as_ref().and_then(|net| back_image_with(&normalised, net, pose, &mut back_timings));
                let side = back_timings.time("side images", || {
                    warp::SideImages::of(&normalised.rgb, back.as_ref().map(|b| &b.rgb), &normalised.mask)
                });
                (normalised, back, side)
            },
        );
        let (mesh, source_gbuffer) = geometry?;
        timings.0.extend(back_timings.0);
        Ok(Self { source_camera, normalised, fof, mesh, source_gbuffer, back, side, timings })
    }
}

/// Renders the person for any number of views of one [`PreparedInput`], keeping buffers and the spatial-fusion
/// state between views.
pub struct ViewRenderer<'a> {
    input: &'a PreparedInput,
    fill: OcclusionFill,
    fusion: Option<SpatialFusion>,
    target: GBuffer,
    neural: Neural<SceneNeural>,
    /// Scratch flow/Z-map of the neural decoder, reused between views.
    flowz: FlowZ,
    policy: NeuralPolicy,
    drawn: Drawn,
    /// Per-view stage times of the last view.
    pub timings: StageTimings,
}

/// The CPU reference as a [`PersonBackend`] for one view whose target is already rasterised.
struct CpuBackend<'r> {
    input: &'r PreparedInput,
    target: &'r GBuffer,
    fill: OcclusionFill,
    flowz: &'r mut FlowZ,
    timings: &'r mut StageTimings,
}

impl PersonBackend<NeuralRef<'_>> for CpuBackend<'_> {
    type Output = RgbaImage;
    type Error = std::convert::Infallible;
    type NeuralFailure = NeuralError;

    fn neural(
        &mut self,
        _source: SourceView<'_>,
        n: &NeuralRef<'_>,
        camera: &Camera,
    ) -> Result<Result<(RgbaImage, NeuralViewTimes), NeuralError>, Self::Error> {
        let (input, target, flowz, fill) = (self.input, self.target, &mut *self.flowz, self.fill);
        let person = self.timings.time("flow + Z-map + decoder", || {
            let mut renderer = n.renderer.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
            renderer.render_view(input, n.encoded, target, camera, flowz, fill)
        });
        Ok(person.map(|p| (p, NeuralViewTimes::default())))
    }

    fn reuse_neural(&mut self, _camera: &Camera) -> Result<Option<RgbaImage>, Self::Error> {
        Ok(None)
    }

    fn geometric(&mut self, source: SourceView<'_>, camera: &Camera) -> Result<RgbaImage, Self::Error> {
        let (target, fill) = (self.target, self.fill);
        Ok(self.timings.time("flow + Z-map + warp", || {
            warp::render_geometric(source.colours(), source.mask, source.gbuffer, source.camera, target, camera, fill)
        }))
    }
}

impl<'a> ViewRenderer<'a> {
    /// A renderer with the given occlusion fill; spatial fusion on when `fuse` is true (for view sequences).
    pub fn new(input: &'a PreparedInput, fill: OcclusionFill, fuse: bool) -> Self {
        Self {
            input,
            fill,
            fusion: fuse.then(SpatialFusion::new),
            target: GBuffer::new(0, 0),
            neural: Neural::Off,
            flowz: FlowZ::default(),
            policy: NeuralPolicy::default(),
            drawn: Drawn::Nothing,
            timings: StageTimings::default(),
        }
    }

    /// A renderer that draws with the neural decoder, given the encoder's output for `input`
    /// ([`NeuralRenderer::encode`], once per input and shared by every view and eye). `fill` is used by the
    /// geometric fallback.
    pub fn with_neural(
        input: &'a PreparedInput,
        fill: OcclusionFill,
        fuse: bool,
        renderer: SharedNeural,
        encoded: NeuralInput,
    ) -> Self {
        let mut r = Self::new(input, fill, fuse);
        r.neural = Neural::On(SceneNeural { renderer, encoded });
        r
    }

    /// [`ViewRenderer::with_neural`] when `neural` is given and its encoder runs on `input`, else
    /// [`ViewRenderer::new`] (an encoder failure logs a warning and the views are drawn geometrically).
    pub fn for_renderer(
        input: &'a PreparedInput,
        fill: OcclusionFill,
        fuse: bool,
        neural: Option<&SharedNeural>,
    ) -> Self {
        let Some(shared) = neural else { return Self::new(input, fill, fuse) };
        let encoded = shared.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).encode(input);
        match encoded {
            Ok(encoded) => Self::with_neural(input, fill, fuse, Arc::clone(shared), encoded),
            Err(e) => {
                tracing::warn!("the neural encoder failed on this input, using the geometric renderer: {e}");
                Self::new(input, fill, fuse)
            }
        }
    }

    /// A renderer for a view's neural request: the neural decoder for [`Neural::On`]; the geometric renderer
    /// for [`Neural::Missing`] (each view counted as a fallback) and [`Neural::Off`].
    pub fn for_request(input: &'a PreparedInput, fill: OcclusionFill, fuse: bool, request: NeuralRequest<'_>) -> Self {
        let mut r = Self::new(input, fill, fuse);
        r.neural = match request {
            Neural::On(n) => Neural::On(SceneNeural { renderer: Arc::clone(n.renderer), encoded: n.encoded.clone() }),
            Neural::Missing => Neural::Missing,
            Neural::Off => Neural::Off,
        };
        r
    }

    /// The encoder's time for this renderer's input, when it draws with the neural decoder.
    pub fn encode_time(&self) -> Option<Duration> {
        match &self.neural {
            Neural::On(n) => Some(n.encoded.encode_time),
            _ => None,
        }
    }

    /// Whether views are drawn by the neural decoder (falling back to the geometric renderer per view on
    /// failure).
    pub fn is_neural(&self) -> bool {
        matches!(self.neural, Neural::On(_))
    }

    /// Which renderer drew the last view.
    pub fn drawn(&self) -> Drawn {
        self.drawn
    }

    /// Views the neural decoder failed on (error or non-finite output) that the geometric renderer drew instead.
    pub fn neural_fallbacks(&self) -> usize {
        self.policy.counters().fallbacks as usize
    }

    /// What the neural renderer did so far (views, decoder runs, fallbacks).
    pub fn neural_counters(&self) -> NeuralCounters {
        self.policy.counters()
    }

    /// The person alone for `camera`: premultiplied linear RGBA.
    pub fn render_person(&mut self, camera: &Camera) -> Result<RgbaImage, PipelineError> {
        self.render_person_drawn(camera).map(|(person, _)| person)
    }

    /// [`ViewRenderer::render_person`], also saying which renderer drew it.
    pub fn render_person_drawn(&mut self, camera: &Camera) -> Result<(RgbaImage, Drawn), PipelineError> {
        let mut timings = StageTimings::default();
        let input = self.input;
        timings.time("target raster", || raster::rasterize_into(&mut self.target, &input.mesh, camera));
        let neural = match &self.neural {
            Neural::On(n) => Neural::On(NeuralRef { renderer: &n.renderer, encoded: &n.encoded }),
            Neural::Missing => Neural::Missing,
            Neural::Off => Neural::Off,
        };
        let mut backend =
            CpuBackend { input, target: &self.target, fill: self.fill, flowz: &mut self.flowz, timings: &mut timings };
        let (person, drawn) = match self.policy.draw(&mut backend, SourceView::of(input), neural, 0, camera) {
            Ok(drawn) => drawn,
            Err(never) => match never {},
        };
        let person = match self.fusion.as_mut() {
            Some(f) => timings.time("spatial fusion", || f.fuse(&person, &self.target, camera)),
            None => person,
        };
        self.timings = timings;
        self.drawn = drawn;
        if person.data.iter().any(|p| !p.is_finite()) {
            return Err(PipelineError::NonFinite("novel view"));
        }
        Ok((person, drawn))
    }

    /// A finished frame for `camera`: composited over the panorama in VR, the bare layer in AR (no panorama
    /// work at all in AR).
    pub fn render_frame(
        &mut self,
        camera: &Camera,
        mode: Mode,
        environment: &Environment,
    ) -> Result<RenderedFrame, PipelineError> {
        let person = self.render_person(camera)?;
        Ok(match mode {
            Mode::Vr => {
                let start = Instant::now();
                let out = compose::compose_vr(&person, environment, camera);
                self.timings.0.push(("compose (panorama)", start.elapsed()));
                RenderedFrame::Vr(out)
            }
            Mode::Ar => RenderedFrame::Ar(compose::compose_ar(&person)),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn the_lookup_is_kept_on_the_back_of_the_head_the_back_image_knows() {
        // Six target pixels, seen from behind the source camera's axis (+z): the flows land on a 4x1 source whose
        // left half is head (weight 1, 0.6) and right half not (0.4, 0).
        let head = GrayImage { width: 4, height: 1, data: vec![1.0, 0.6, 0.4, 0.0] };
        let mut flowz = FlowZ {
            flow: Image::new(6, 1, Vec2::ZERO),
            z: GrayImage::new(6, 1, 0.0),
            mask: vec![true, true, true, true, false, true],
        };
        // Pixel 0 on the head facing away, 1 on the 0.6 head facing away, 2 on 0.4 facing away, 3 on the head but
        // edge-on (back weight below 1), 4 no flow, 5 flowing outside the source.
        for (i, x) in [0.5f32, 1.5, 2.5, 0.5, 0.5, 7.5].into_iter().enumerate() {
            flowz.flow.data[i] = Vec2::new(x, 0.5);
        }
        let mut target = GBuffer::new(6, 1);
        target.normal = vec![-Vec3::Z, -Vec3::Z, -Vec3::Z, Vec3::new(0.99, 0.0, -0.141), -Vec3::Z, -Vec3::Z];
        let axis = Vec3::Z;
        let seen = [false, false, false, false, false, false];
        let kept = lookup_kept(&seen, &flowz, &target, axis, Some(&head), 4);
        assert_eq!(kept, vec![true, true, false, false, false, false]);
        // What the photo sees is kept anyway; without head weights only that.
        let seen = [false, false, true, false, false, false];
        assert_eq!(
            lookup_kept(&seen, &flowz, &target, axis, Some(&head), 4),
            vec![true, true, true, false, false, false]
        );
        assert_eq!(lookup_kept(&seen, &flowz, &target, axis, None, 4), seen.to_vec());
        // Head weights of another size are scaled to the source camera: a 2x wider map read at twice the flow.
        let wide = GrayImage { width: 8, height: 2, data: [[1.0, 1.0, 0.6, 0.6, 0.4, 0.4, 0.0, 0.0]; 2].concat() };
        assert_eq!(
            lookup_kept(&seen, &flowz, &target, axis, Some(&wide), 4),
            vec![true, true, true, false, false, false]
        );
        // Mismatched arrays: only what is seen.
        let short = FlowZ::default();
        assert_eq!(lookup_kept(&seen, &short, &target, axis, Some(&head), 4), seen.to_vec());
    }

    #[test]
    fn the_photo_is_kept_only_where_it_sees_the_surface_and_has_a_colour() {
        let decoded = Vec4::new(0.1, 0.2, 0.3, 1.0);
        let photo = Vec4::new(0.7, 0.6, 0.5, 1.0);
        let mut person = RgbaImage::new(4, 1, decoded);
        person.data[3] = Vec4::ZERO; // not covered
        let mut lookup = RgbaImage::new(4, 1, photo);
        lookup.data[1] = Vec4::ZERO; // the photo has no colour there
        keep_lookup_where(&mut person, &lookup, &[true, true, false, true]);
        assert_eq!(person.data, vec![photo, decoded, decoded, Vec4::ZERO]);
        // Arrays of another size change nothing.
        let before = person.clone();
        keep_lookup_where(&mut person, &RgbaImage::new(2, 1, photo), &[true; 4]);
        keep_lookup_where(&mut person, &lookup, &[true; 3]);
        assert_eq!(person, before);
    }
}
