//! The per-input and per-view stages as plain functions over images, each with its CPU reference, and the two
//! objects that schedule them:
//! - [`PreparedInput`]: everything computed once per input frame (normalise -> geometry (FOF) -> mesh ->
//!   source depth/normals).
//! - [`ViewRenderer`]: everything computed per view (target raster -> flow/Z-map/visibility -> warp -> spatial
//!   fusion), reusing its buffers from view to view.

pub mod fusion;
pub mod input;
pub mod warp;

use std::time::{Duration, Instant};

use crate::buffer::{GrayImage, RgbImage, RgbaImage};
use crate::compose::{self, Mode};
use crate::geometry::fof::{Fof, FofError};
use crate::geometry::inflate::{self, InflateError, InflateParams};
use crate::geometry::marching;
use crate::geometry::raster::{self, GBuffer};
use crate::geometry::{Camera, TriMesh, SOURCE_RESOLUTION};
use crate::io::environment::Environment;
use crate::io::sequence::Frame;

use fusion::SpatialFusion;
use input::{InputError, NormalisedInput};
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
}

/// Where the per-input geometry comes from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum GeometryMode {
    /// Silhouette-inflation prior from the mask (no network needed).
    #[default]
    Inflate,
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
}

impl Default for PrepareOptions {
    fn default() -> Self {
        Self {
            resolution: SOURCE_RESOLUTION,
            fof_order: 32,
            depth_samples: SOURCE_RESOLUTION,
            geometry: GeometryMode::Inflate,
            inflate: InflateParams::default(),
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
    /// How long each per-input stage took.
    pub timings: StageTimings,
}

impl PreparedInput {
    /// Runs the per-input stages on a photo (linear RGB, straight colour) and its person mask (`[0, 1]`).
    pub fn prepare(rgb: &RgbImage, mask: &GrayImage, opts: &PrepareOptions) -> Result<Self, PipelineError> {
        let mut timings = StageTimings::default();
        let normalised = timings.time("normalise", || input::normalise(rgb, mask, opts.resolution))?;
        let fof = match opts.geometry {
            GeometryMode::Inflate => timings.time("geometry (inflate -> FOF)", || {
                inflate::inflate_to_fof(&normalised.mask, opts.fof_order, &opts.inflate)
            })?,
        };
        Self::from_fof(normalised, fof, opts, timings)
    }

    /// Finishes preparation from an already computed FOF (e.g. a network's, or ground truth).
    pub fn from_fof(
        normalised: NormalisedInput,
        fof: Fof,
        opts: &PrepareOptions,
        mut timings: StageTimings,
    ) -> Result<Self, PipelineError> {
        let mesh = timings.time("mesh (FOF -> marching cubes)", || marching::extract_mesh(&fof, opts.depth_samples));
        if mesh.is_empty() {
            return Err(PipelineError::EmptyGeometry);
        }
        if mesh.validate().is_err() {
            return Err(PipelineError::NonFinite("mesh"));
        }
        let source_camera = Camera::source(opts.resolution);
        let source_gbuffer = timings.time("source raster", || raster::rasterize(&mesh, &source_camera));
        Ok(Self { source_camera, normalised, fof, mesh, source_gbuffer, timings })
    }
}

/// Renders the person for any number of views of one [`PreparedInput`], keeping buffers and the spatial-fusion
/// state between views.
pub struct ViewRenderer<'a> {
    input: &'a PreparedInput,
    fill: OcclusionFill,
    fusion: Option<SpatialFusion>,
    target: GBuffer,
    /// Per-view stage times of the last view.
    pub timings: StageTimings,
}

impl<'a> ViewRenderer<'a> {
    /// A renderer with the given occlusion fill; spatial fusion on when `fuse` is true (for view sequences).
    pub fn new(input: &'a PreparedInput, fill: OcclusionFill, fuse: bool) -> Self {
        Self {
            input,
            fill,
            fusion: fuse.then(SpatialFusion::new),
            target: GBuffer::new(0, 0),
            timings: StageTimings::default(),
        }
    }

    /// The person alone for `camera`: premultiplied linear RGBA.
    pub fn render_person(&mut self, camera: &Camera) -> Result<RgbaImage, PipelineError> {
        let mut timings = StageTimings::default();
        let input = self.input;
        timings.time("target raster", || raster::rasterize_into(&mut self.target, &input.mesh, camera));
        let person = timings.time("flow + Z-map + warp", || {
            warp::render_geometric(
                &input.normalised.rgb,
                &input.normalised.mask,
                &input.source_gbuffer,
                &input.source_camera,
                &self.target,
                camera,
                self.fill,
            )
        });
        let person = match self.fusion.as_mut() {
            Some(f) => timings.time("spatial fusion", || f.fuse(&person, &self.target, camera)),
            None => person,
        };
        self.timings = timings;
        if person.data.iter().any(|p| !p.is_finite()) {
            return Err(PipelineError::NonFinite("novel view"));
        }
        Ok(person)
    }

    /// A finished frame for `camera`: composited over the panorama in VR, the bare layer in AR (no panorama
    /// work at all in AR).
    pub fn render_frame(
        &mut self,
        camera: &Camera,
        mode: Mode,
        environment: &Environment,
    ) -> Result<Frame, PipelineError> {
        let person = self.render_person(camera)?;
        Ok(match mode {
            Mode::Vr => {
                let start = Instant::now();
                let out = compose::compose_vr(&person, environment, camera);
                self.timings.0.push(("compose (panorama)", start.elapsed()));
                Frame::Vr(out)
            }
            Mode::Ar => Frame::Ar(compose::compose_ar(&person)),
        })
    }
}
