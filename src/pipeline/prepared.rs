//! What one input frame becomes before any view is drawn ([`PreparedInput`]), the settings it is prepared with
//! ([`PrepareOptions`]) and the stage clock ([`StageTimings`]). The still path (`still`) and the frame path
//! (`frame`) fill it.

use std::time::{Duration, Instant};

use crate::geometry::fof::Fof;
use crate::geometry::inflate::{self, InflateParams};
use crate::geometry::raster::GBuffer;
use crate::geometry::{Camera, TriMesh, SOURCE_RESOLUTION};

use super::input::NormalisedInput;
use super::{back, warp, GeometryMode, SharedBody, SharedFofNet, SharedPlacementNet, SharedPose};

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
    /// The FOF network for [`GeometryMode::FofNet`] (and [`GeometryMode::Auto`] when [`super::AUTO_CHOICE`] is the FOF
    /// net; [`super::load_fof_net`]); `None` with `FofNet` is an error, with `Auto` the inflation prior.
    pub fof_net: Option<SharedFofNet>,
    /// The body prior for [`GeometryMode::Body`] ([`super::load_body`]) and for a FOF net that takes the body FOF
    /// ([`super::load_body_for`]); `None` with `Body` is an error.
    pub body: Option<SharedBody>,
    /// The placement network of [`GeometryMode::BodyPlaced`] ([`super::load_placement_net`]); `None`: every column
    /// stays at the inflation prior's depth ([`crate::body::placed`]).
    pub placement: Option<SharedPlacementNet>,
    /// Live input: warm-start the body prior from the previous frame (its tracking region and fitted pose).
    pub warm_start: bool,
    /// The pose network that finds the face for the back image ([`super::load_back_pose`]; [`back::back_image`]); `None`:
    /// no back image (the renderers then colour what the photo does not show from the photo itself).
    pub back_pose: Option<SharedPose>,
    /// Live sources: keep the person model across frames ([`super::person_model`]; `--person-model`, off by
    /// default). Stills ignore it.
    pub person_model: bool,
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
            person_model: false,
        }
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

/// Everything computed once per input frame.
#[derive(Clone, Debug)]
pub struct PreparedInput {
    /// The orthographic source camera (`resolution^2`).
    pub source_camera: Camera,
    /// The person normalised into the body cube (premultiplied RGB and mask).
    pub normalised: NormalisedInput,
    /// The Fourier occupancy field the still path decoded the mesh from; `None` on the frame path, whose geometry
    /// is `surfaces`.
    pub fof: Option<Fof>,
    /// The one-shell front and back depth maps the frame path meshed directly ([`super::frame`]); `None` on the
    /// still path.
    pub surfaces: Option<inflate::InflatedSurfaces>,
    /// The mesh: extracted from the FOF (still path) or joined from the two depth maps (frame path).
    pub mesh: TriMesh,
    /// Source-view depth and normals of the geometry (the mesh's raster on the still path, the front map on the
    /// frame path).
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
    /// The FOF of this input with `n` coefficients, for the encoder: the still path's own, or on the frame path
    /// the depth maps encoded now ([`Fof::from_depth_maps`]); `None` when neither has `n` coefficients.
    pub fn fof_with(&self, n: usize) -> Option<std::borrow::Cow<'_, Fof>> {
        match (&self.fof, &self.surfaces) {
            (Some(f), _) if f.n == n => Some(std::borrow::Cow::Borrowed(f)),
            (_, Some(s)) => Fof::from_depth_maps(&s.front, &s.back, &s.mask, n).ok().map(std::borrow::Cow::Owned),
            _ => None,
        }
    }
}
