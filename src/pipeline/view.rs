//! Per-view rendering on the CPU ([`CpuView`], and [`ViewRenderer`] over one [`PreparedInput`]): target raster,
//! flow/Z-map, warp or decoder, spatial fusion, compositing.

use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::buffer::RgbaImage;
use crate::compose::{self, Mode, RenderedFrame};
use crate::geometry::raster::{self, GBuffer};
use crate::geometry::zmap::FlowZ;
use crate::geometry::Camera;
use crate::io::environment::Environment;
use crate::neural::NeuralError;

use super::fusion::SpatialFusion;
use super::person::{
    Drawn, Neural, NeuralCounters, NeuralPolicy, NeuralRef, NeuralRequest, NeuralViewTimes, PersonBackend, SceneNeural,
    SourceView,
};
use super::warp::OcclusionFill;
use super::{warp, NeuralInput, PipelineError, PreparedInput, SharedNeural, StageTimings};

/// Renders the person for any number of views of one [`PreparedInput`], keeping buffers and the spatial-fusion
/// state between views (a [`CpuView`] over the input's source view).
pub struct ViewRenderer<'a> {
    input: &'a PreparedInput,
    neural: Neural<SceneNeural>,
    view: CpuView,
    /// Per-view stage times of the last view.
    pub timings: StageTimings,
}

/// The CPU reference for one sequence of views (an orbit, one XR eye): the target buffers, the spatial-fusion
/// state and the neural policy, kept from view to view; each view may come from another source view (the frames
/// of a live source).
pub struct CpuView {
    fill: OcclusionFill,
    fusion: Option<SpatialFusion>,
    target: GBuffer,
    /// Scratch flow/Z-map of the neural decoder, reused between views.
    flowz: FlowZ,
    policy: NeuralPolicy,
    drawn: Drawn,
    /// Per-view stage times of the last view.
    pub timings: StageTimings,
}

impl CpuView {
    /// A view sequence with the given occlusion fill; spatial fusion on when `fuse` is true.
    pub fn new(fill: OcclusionFill, fuse: bool) -> Self {
        Self {
            fill,
            fusion: fuse.then(SpatialFusion::new),
            target: GBuffer::new(0, 0),
            flowz: FlowZ::default(),
            policy: NeuralPolicy::default(),
            drawn: Drawn::Nothing,
            timings: StageTimings::default(),
        }
    }

    /// The person alone for `camera` from `source` (premultiplied linear RGBA), drawn by the neural decoder when
    /// `neural` asks for it (the geometric renderer on a decoder failure), and which renderer drew it. `scene`
    /// identifies the source for the policy's reuse of a neural layer (any number that changes with the source).
    pub fn draw(
        &mut self,
        source: SourceView<'_>,
        neural: NeuralRequest<'_>,
        scene: u64,
        camera: &Camera,
    ) -> Result<(RgbaImage, Drawn), PipelineError> {
        let mut timings = StageTimings::default();
        let view = super::mesh_for_view(source.mesh, source.mesh_closed, source.coarse, camera);
        timings.time("target raster", || match view.front_only {
            true => raster::rasterize_front_into(&mut self.target, view.mesh, camera),
            false => raster::rasterize_into(&mut self.target, view.mesh, camera),
        });
        let mut backend =
            CpuBackend { target: &self.target, fill: self.fill, flowz: &mut self.flowz, timings: &mut timings };
        let (person, drawn) = match self.policy.draw(&mut backend, source, neural, scene, camera) {
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

    /// What the neural renderer did so far (views, decoder runs, fallbacks).
    pub fn neural_counters(&self) -> NeuralCounters {
        self.policy.counters()
    }
}

/// The CPU reference as a [`PersonBackend`] for one view whose target is already rasterised.
struct CpuBackend<'r> {
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
        source: SourceView<'_>,
        n: &NeuralRef<'_>,
        camera: &Camera,
    ) -> Result<Result<(RgbaImage, NeuralViewTimes), NeuralError>, Self::Error> {
        let (target, flowz, fill) = (self.target, &mut *self.flowz, self.fill);
        let person = self.timings.time("flow + Z-map + decoder", || {
            let mut renderer = n.renderer.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
            renderer.render_view(&source, n.encoded, target, camera, flowz, fill)
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
        Self { input, neural: Neural::Off, view: CpuView::new(fill, fuse), timings: StageTimings::default() }
    }

    /// A renderer that draws with the neural decoder, given the encoder's output for `input`
    /// ([`super::NeuralRenderer::encode`], once per input and shared by every view and eye). `fill` is used by the
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
        self.view.drawn
    }

    /// Views the neural decoder failed on (error or non-finite output) that the geometric renderer drew instead.
    pub fn neural_fallbacks(&self) -> usize {
        self.view.neural_counters().fallbacks as usize
    }

    /// What the neural renderer did so far (views, decoder runs, fallbacks).
    pub fn neural_counters(&self) -> NeuralCounters {
        self.view.neural_counters()
    }

    /// The person alone for `camera`: premultiplied linear RGBA.
    pub fn render_person(&mut self, camera: &Camera) -> Result<RgbaImage, PipelineError> {
        self.render_person_drawn(camera).map(|(person, _)| person)
    }

    /// [`ViewRenderer::render_person`], also saying which renderer drew it.
    pub fn render_person_drawn(&mut self, camera: &Camera) -> Result<(RgbaImage, Drawn), PipelineError> {
        let neural = match &self.neural {
            Neural::On(n) => Neural::On(NeuralRef { renderer: &n.renderer, encoded: &n.encoded }),
            Neural::Missing => Neural::Missing,
            Neural::Off => Neural::Off,
        };
        let drawn = self.view.draw(SourceView::of(self.input), neural, 0, camera);
        self.timings = std::mem::take(&mut self.view.timings);
        drawn
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
