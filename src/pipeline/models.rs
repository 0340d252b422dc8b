//! Loading the networks the pipeline runs (FOF net, placement net, body prior, the back image's pose network),
//! each shared behind a lock by the inputs that use it.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use crate::body::prior::BodyEstimator;
use crate::neural::{FofNet, PlacementNet, RuntimeOptions};

use super::warp::OcclusionFill;
use super::{GeometryMode, PipelineError, PrepareOptions, AUTO_CHOICE, DEFAULT_MODEL_TIER, FRAMES_AUTO_CHOICE};

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

/// `--models`, or the project's [`DEFAULT_MODEL_TIER`] folder when found.
pub(super) fn model_folder(models: Option<&Path>) -> Option<PathBuf> {
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
                "geometry: auto is `{}` (the evaluation's winner, docs/geometry.md \"Which geometry wins where\")",
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
/// `Ok(None)` (the confidence-aware placement of [`crate::body::placed`]) when it has none or for the other modes. A file that does
/// not load (or predicts for another `N` than `fof_order`) is an error under `body-placed` and one warning (the confidence-aware
/// placement) under auto.
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
        tracing::info!(
            "geometry: no placement network (no {}): columns are placed where the body fit is trusted",
            crate::neural::PLACEMENT_FILE
        );
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
            tracing::warn!("geometry: {e}{cause}; columns are placed where the body fit is trusted");
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

/// The options the frames of a video or camera are prepared with when nothing asks for a geometry (`view`, `xr`,
/// `bench-live`): the models [`FRAMES_AUTO_CHOICE`] needs (each replaced by the inflation prior with one warning
/// when it does not load) and the back image's pose network ([`load_back_pose`]; the frame path reads the face with
/// it every [`super::frame::BACK_FACE_EVERY`] frames), at `resolution`.
pub fn auto_frame_options(
    models: Option<&Path>,
    resolution: usize,
    options: &RuntimeOptions,
) -> Result<PrepareOptions, PipelineError> {
    let defaults = PrepareOptions { resolution, depth_samples: resolution, ..PrepareOptions::default() };
    let body = load_body(FRAMES_AUTO_CHOICE, options)?;
    let placement = load_placement_net(FRAMES_AUTO_CHOICE, models, defaults.fof_order, options)?;
    let back_pose = load_back_pose(OcclusionFill::default(), options);
    Ok(PrepareOptions { geometry: GeometryMode::Auto, body, placement, back_pose, ..defaults })
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
/// then get the inflation prior, see [`super::compute_geometry`]); `None` otherwise.
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
