//! The person-renderer seam: what every renderer of the person draws from ([`SourceView`], owned as a [`Scene`]
//! by the feeds that hand scenes between threads) and the one policy every backend follows ([`NeuralPolicy`]):
//! the neural decoder when it is available, the last neural layer reused while camera and input stay, the
//! geometric renderer when the decoder fails (one warning, then counted), and the counters that say which
//! renderer drew what ([`NeuralCounters`], [`Drawn`]).
//!
//! Two backends implement [`PersonBackend`]: the CPU reference ([`super::ViewRenderer`]) and the Vulkan renderer
//! with the neural hand-off through host memory (`crate::gpu::person`). The window, the XR eyes, offline
//! `render` and `eval` only choose a backend and call it.

use std::time::Duration;

use crate::buffer::{GrayImage, RgbImage};
use crate::geometry::raster::GBuffer;
use crate::geometry::{Camera, TriMesh};

use super::back::BackImage;
use super::warp::SideImages;
use super::{CoarseMesh, NeuralInput, PreparedInput, SharedNeural};

/// The person as every renderer receives it: the mesh in body-cube coordinates and the source view it warps
/// (premultiplied linear RGB, its mask in `[0, 1]`, the source G-buffer and the orthographic source camera).
#[derive(Clone, Copy, Debug)]
pub struct SourceView<'a> {
    /// The person's mesh.
    pub mesh: &'a TriMesh,
    /// Whether `mesh` is known to be closed and consistently wound ([`PreparedInput::mesh_closed`]).
    pub mesh_closed: bool,
    /// The same person sampled half as finely across, for views whose pixels are that large
    /// ([`super::mesh_for_view`]); `None`: every view draws `mesh`.
    pub coarse: Option<&'a CoarseMesh>,
    /// Source colour, premultiplied linear RGB.
    pub rgb: &'a RgbImage,
    /// Source mask in `[0, 1]`.
    pub mask: &'a GrayImage,
    /// Depth and normals of the mesh seen by the source camera.
    pub gbuffer: &'a GBuffer,
    /// The orthographic source camera.
    pub camera: &'a Camera,
    /// The input's back image and where it drew the head ([`super::back`]), when it has one.
    pub back: Option<&'a BackImage>,
    /// The photo and the back image blurred for surfaces seen edge-on ([`super::warp::SideImages`]), when given.
    pub side: Option<&'a SideImages>,
}

impl<'a> SourceView<'a> {
    /// The source view of a prepared input.
    pub fn of(input: &'a PreparedInput) -> Self {
        Self {
            mesh: &input.mesh,
            mesh_closed: input.mesh_closed,
            coarse: input.coarse.as_ref(),
            rgb: &input.normalised.rgb,
            mask: &input.normalised.mask,
            gbuffer: &input.source_gbuffer,
            camera: &input.source_camera,
            back: input.back.as_ref(),
            side: Some(&input.side),
        }
    }

    /// The colours the renderers sample: the photo, the back image and the side images.
    pub fn colours(&self) -> super::warp::SourceColours<'a> {
        super::warp::SourceColours { rgb: self.rgb, back: self.back.map(|b| &b.rgb), side: self.side }
    }
}

/// The neural renderer of a scene: the shared decoder and the encoder's features of the scene's input (computed
/// once per input frame, never per view).
#[derive(Clone)]
pub struct SceneNeural {
    /// The decoder (run under its lock, one view at a time).
    pub renderer: SharedNeural,
    /// The encoder's output for the scene's input.
    pub encoded: NeuralInput,
}

impl std::fmt::Debug for SceneNeural {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SceneNeural").field("encoded", &self.encoded).finish_non_exhaustive()
    }
}

/// An owned [`SourceView`] with its neural renderer: what a feed hands to a render thread (the XR eyes) for one
/// input frame.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The person's mesh.
    pub mesh: TriMesh,
    /// Whether `mesh` is known to be closed and consistently wound ([`PreparedInput::mesh_closed`]).
    pub mesh_closed: bool,
    /// Its coarse copy for views with large pixels, when the input was prepared with one.
    pub coarse: Option<CoarseMesh>,
    /// Source colour, premultiplied linear RGB.
    pub rgb: RgbImage,
    /// Source mask in `[0, 1]`.
    pub mask: GrayImage,
    /// Depth and normals of the mesh seen by the source camera.
    pub gbuffer: GBuffer,
    /// The source camera.
    pub camera: Camera,
    /// The input's back image and where it drew the head, when it has one.
    pub back: Option<BackImage>,
    /// The side images ([`SideImages`]), when given.
    pub side: Option<SideImages>,
    /// The neural renderer and the encoder's output for this input; `None` draws geometrically.
    pub neural: Option<SceneNeural>,
}

impl Scene {
    /// The scene of a prepared input (copied), drawn by `neural` when given.
    pub fn from_prepared(input: &PreparedInput, neural: Option<SceneNeural>) -> Self {
        Self {
            mesh: input.mesh.clone(),
            mesh_closed: input.mesh_closed,
            coarse: input.coarse.clone(),
            rgb: input.normalised.rgb.clone(),
            mask: input.normalised.mask.clone(),
            gbuffer: input.source_gbuffer.clone(),
            camera: input.source_camera,
            back: input.back.clone(),
            side: Some(input.side.clone()),
            neural,
        }
    }

    /// The view the renderers take.
    pub fn source(&self) -> SourceView<'_> {
        SourceView {
            mesh: &self.mesh,
            mesh_closed: self.mesh_closed,
            coarse: self.coarse.as_ref(),
            rgb: &self.rgb,
            mask: &self.mask,
            gbuffer: &self.gbuffer,
            camera: &self.camera,
            back: self.back.as_ref(),
            side: self.side.as_ref(),
        }
    }

    /// The neural request of this scene (drawn neurally when it has a neural renderer).
    pub fn neural(&self) -> NeuralRequest<'_> {
        match &self.neural {
            Some(n) => Neural::On(NeuralRef { renderer: &n.renderer, encoded: &n.encoded }),
            None => Neural::Off,
        }
    }
}

/// The neural decoder and the encoder's output of one input, as a view borrows them.
#[derive(Clone, Copy)]
pub struct NeuralRef<'a> {
    /// The shared decoder (run under its lock, one view at a time).
    pub renderer: &'a SharedNeural,
    /// The encoder's output for the input.
    pub encoded: &'a NeuralInput,
}

impl std::fmt::Debug for NeuralRef<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NeuralRef").field("encoded", self.encoded).finish_non_exhaustive()
    }
}

/// Whether a view is to be drawn by the neural decoder `N` ([`NeuralRef`] in the renderers).
#[derive(Clone, Copy, Debug)]
pub enum Neural<N> {
    /// The geometric renderer was asked for.
    Off,
    /// The neural renderer was asked for but this input has no encoder output (the encoder failed on it): the
    /// view is drawn geometrically and counted as a fallback.
    Missing,
    /// The neural decoder with the encoder's output of the input.
    On(N),
}

/// A view's neural request in the renderers.
pub type NeuralRequest<'a> = Neural<NeuralRef<'a>>;

impl<'a> NeuralRequest<'a> {
    /// `On` with `encoded` when `renderer` is given and the input was encoded, `Missing` when a renderer is given
    /// but the input has no encoder output, `Off` without a renderer.
    pub fn from_parts(renderer: Option<&'a SharedNeural>, encoded: Option<&'a NeuralInput>) -> Self {
        match (renderer, encoded) {
            (Some(renderer), Some(encoded)) => Neural::On(NeuralRef { renderer, encoded }),
            (Some(_), None) => Neural::Missing,
            (None, _) => Neural::Off,
        }
    }
}

/// Which renderer drew a view (shown in the window's overlay and title).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Drawn {
    /// No view yet, or no person yet (a live source before its first frame).
    #[default]
    Nothing,
    /// The geometric warp.
    Geometric,
    /// The neural decoder (a fresh run or its reused layer).
    Neural,
    /// The geometric warp because the neural renderer failed on this view (decoder error, or no encoder output).
    GeometricFallback,
}

impl Drawn {
    /// The overlay's label.
    pub fn label(self) -> &'static str {
        match self {
            Drawn::Nothing => "NO PERSON YET",
            Drawn::Geometric => "GEOMETRIC",
            Drawn::Neural => "NEURAL",
            Drawn::GeometricFallback => "GEOMETRIC (NEURAL FAILED)",
        }
    }
}

/// What the neural renderer did over a sequence of views.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NeuralCounters {
    /// Views drawn by the neural decoder (fresh runs and reused layers).
    pub views: u64,
    /// Decoder runs.
    pub decoder_runs: u64,
    /// Views whose neural layer was reused (same camera, same input: no decoder run).
    pub reused: u64,
    /// Views the neural renderer failed on (drawn geometrically instead).
    pub fallbacks: u64,
}

impl NeuralCounters {
    /// What happened since `before` (an earlier reading of the same counters).
    pub fn since(self, before: Self) -> Self {
        Self {
            views: self.views.saturating_sub(before.views),
            decoder_runs: self.decoder_runs.saturating_sub(before.decoder_runs),
            reused: self.reused.saturating_sub(before.reused),
            fallbacks: self.fallbacks.saturating_sub(before.fallbacks),
        }
    }
}

impl std::ops::AddAssign for NeuralCounters {
    fn add_assign(&mut self, o: Self) {
        self.views += o.views;
        self.decoder_runs += o.decoder_runs;
        self.reused += o.reused;
        self.fallbacks += o.fallbacks;
    }
}

/// Host-side times of one neural view on a GPU backend (zero on the CPU one).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NeuralViewTimes {
    /// GPU raster + flow/Z-map, including the read-back into host memory.
    pub gpu_inputs: Duration,
    /// Colour lookup, feature sampling and decoder (ONNX Runtime).
    pub decoder: Duration,
}

/// One backend's three ways of drawing the person for a camera, with the neural decoder `N` ([`NeuralRef`]);
/// [`NeuralPolicy::draw`] decides which runs.
pub trait PersonBackend<N> {
    /// What a drawn view is (the CPU's person layer; nothing for the GPU, whose result stays on the device).
    type Output;
    /// A failure that ends the view (device lost, a broken stage); a neural failure is not one.
    type Error;
    /// Why the neural decoder could not draw a view (the policy logs it and draws the view geometrically).
    type NeuralFailure: std::fmt::Display;
    /// Draws the view with the neural decoder: `Ok(Err(reason))` when the decoder failed (the policy then draws
    /// geometrically), `Err` on a failure of the backend itself.
    #[allow(clippy::type_complexity)]
    fn neural(
        &mut self,
        source: SourceView<'_>,
        neural: &N,
        camera: &Camera,
    ) -> Result<Result<(Self::Output, NeuralViewTimes), Self::NeuralFailure>, Self::Error>;
    /// Draws the view again from the last neural layer (same camera and input); `None` when the backend keeps
    /// no layer (the decoder then runs again).
    fn reuse_neural(&mut self, camera: &Camera) -> Result<Option<Self::Output>, Self::Error>;
    /// Draws the view with the geometric renderer.
    fn geometric(&mut self, source: SourceView<'_>, camera: &Camera) -> Result<Self::Output, Self::Error>;
}

/// "Neural when available, layer reuse, geometric fallback, counters": the one policy of every person renderer.
#[derive(Clone, Debug, Default)]
pub struct NeuralPolicy {
    /// Camera and input of the neural layer the backend holds (reused while both stay).
    layer: Option<(Camera, u64)>,
    counters: NeuralCounters,
    times: NeuralViewTimes,
}

impl NeuralPolicy {
    /// Draws `source` (input number `input`: a new number invalidates the neural layer) for `camera` on
    /// `backend`, as `neural` asks. Returns the backend's output and which renderer drew it.
    pub fn draw<N, B: PersonBackend<N>>(
        &mut self,
        backend: &mut B,
        source: SourceView<'_>,
        neural: Neural<N>,
        input: u64,
        camera: &Camera,
    ) -> Result<(B::Output, Drawn), B::Error> {
        let wants_neural = !matches!(neural, Neural::Off);
        match neural {
            Neural::On(n) => {
                if self.layer == Some((*camera, input)) {
                    if let Some(out) = backend.reuse_neural(camera)? {
                        self.counters.views += 1;
                        self.counters.reused += 1;
                        return Ok((out, Drawn::Neural));
                    }
                }
                match backend.neural(source, &n, camera)? {
                    Ok((out, times)) => {
                        self.layer = Some((*camera, input));
                        self.counters.views += 1;
                        self.counters.decoder_runs += 1;
                        self.times = times;
                        return Ok((out, Drawn::Neural));
                    }
                    Err(e) => {
                        // One warning per renderer; later failures are counted and logged at debug level.
                        if self.counters.fallbacks == 0 {
                            tracing::warn!("neural renderer failed on a view, drawing it with the geometric one: {e}");
                        } else {
                            tracing::debug!("neural renderer failed again (geometric fallback): {e}");
                        }
                        self.counters.fallbacks += 1;
                    }
                }
            }
            // The encoder failed on this input: drawn geometrically, and said so.
            Neural::Missing => self.counters.fallbacks += 1,
            Neural::Off => {}
        }
        self.layer = None;
        let out = backend.geometric(source, camera)?;
        Ok((out, if wants_neural { Drawn::GeometricFallback } else { Drawn::Geometric }))
    }

    /// Forgets the neural layer (the backend's buffers were replaced, or the renderer switched).
    pub fn forget_layer(&mut self) {
        self.layer = None;
    }

    /// The counters so far.
    pub fn counters(&self) -> NeuralCounters {
        self.counters
    }

    /// Host times of the last decoder run.
    pub fn last_times(&self) -> NeuralViewTimes {
        self.times
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::buffer::Image;
    use glam::Vec3;

    /// A backend that records what ran; its decoder fails when `fail` is set, and it keeps its neural layer when
    /// `keeps_layer` is.
    #[derive(Default)]
    struct Probe {
        fail: bool,
        keeps_layer: bool,
        ran: Vec<&'static str>,
    }

    impl PersonBackend<()> for Probe {
        type Output = &'static str;
        type Error = ();
        type NeuralFailure = &'static str;
        fn neural(
            &mut self,
            _: SourceView<'_>,
            _: &(),
            _: &Camera,
        ) -> Result<Result<(&'static str, NeuralViewTimes), &'static str>, ()> {
            self.ran.push("neural");
            let times = NeuralViewTimes { gpu_inputs: Duration::from_millis(2), decoder: Duration::from_millis(3) };
            Ok(if self.fail { Err("decoder failed") } else { Ok(("n", times)) })
        }
        fn reuse_neural(&mut self, _: &Camera) -> Result<Option<&'static str>, ()> {
            self.ran.push("reuse");
            Ok(self.keeps_layer.then_some("r"))
        }
        fn geometric(&mut self, _: SourceView<'_>, _: &Camera) -> Result<&'static str, ()> {
            self.ran.push("geometric");
            Ok("g")
        }
    }

    fn scene() -> Scene {
        Scene {
            mesh: TriMesh::cuboid(Vec3::splat(-0.5), Vec3::splat(0.5)),
            mesh_closed: true,
            coarse: None,
            rgb: Image::new(4, 4, Vec3::ONE),
            mask: Image::new(4, 4, 1.0),
            gbuffer: GBuffer::new(4, 4),
            camera: Camera::source(4),
            back: None,
            side: None,
            neural: None,
        }
    }

    #[test]
    fn geometric_and_missing_requests_never_run_the_decoder() {
        let s = scene();
        let cam = Camera::orbit(30.0, 0.0, 4, 4);
        let mut policy = NeuralPolicy::default();
        let mut probe = Probe::default();
        assert_eq!(policy.draw(&mut probe, s.source(), Neural::<()>::Off, 0, &cam), Ok(("g", Drawn::Geometric)));
        let missing = policy.draw(&mut probe, s.source(), Neural::<()>::Missing, 0, &cam);
        assert_eq!(missing, Ok(("g", Drawn::GeometricFallback)));
        assert_eq!(probe.ran, ["geometric", "geometric"]);
        assert_eq!(policy.counters(), NeuralCounters { fallbacks: 1, ..Default::default() });
    }

    #[test]
    fn the_neural_layer_is_reused_only_for_the_same_camera_and_input() {
        let s = scene();
        let (a, b) = (Camera::orbit(30.0, 0.0, 4, 4), Camera::orbit(31.0, 0.0, 4, 4));
        let mut policy = NeuralPolicy::default();
        let mut probe = Probe { keeps_layer: true, ..Default::default() };
        let mut draw = |p: &mut Probe, cam: &Camera, input: u64| policy.draw(p, s.source(), Neural::On(()), input, cam);
        assert_eq!(draw(&mut probe, &a, 0), Ok(("n", Drawn::Neural)));
        assert_eq!(draw(&mut probe, &a, 0), Ok(("r", Drawn::Neural)));
        assert_eq!(draw(&mut probe, &b, 0), Ok(("n", Drawn::Neural)));
        assert_eq!(draw(&mut probe, &b, 1), Ok(("n", Drawn::Neural)));
        assert_eq!(probe.ran, ["neural", "reuse", "neural", "neural"]);
        assert_eq!(policy.counters(), NeuralCounters { views: 4, decoder_runs: 3, reused: 1, fallbacks: 0 });
        assert_eq!(policy.last_times().decoder, Duration::from_millis(3));
        // A backend without a layer (the CPU reference) runs the decoder again for the same view.
        let mut cpu = Probe::default();
        let mut policy = NeuralPolicy::default();
        for _ in 0..2 {
            assert_eq!(policy.draw(&mut cpu, s.source(), Neural::On(()), 0, &a), Ok(("n", Drawn::Neural)));
        }
        assert_eq!(cpu.ran, ["neural", "reuse", "neural"]);
    }

    #[test]
    fn a_failing_decoder_falls_back_to_geometric_and_drops_the_layer() {
        let s = scene();
        let cam = Camera::orbit(90.0, 0.0, 4, 4);
        let mut policy = NeuralPolicy::default();
        let mut probe = Probe { keeps_layer: true, ..Default::default() };
        assert_eq!(policy.draw(&mut probe, s.source(), Neural::On(()), 0, &cam), Ok(("n", Drawn::Neural)));
        probe.fail = true;
        policy.forget_layer();
        for _ in 0..3 {
            let drawn = policy.draw(&mut probe, s.source(), Neural::On(()), 0, &cam);
            assert_eq!(drawn, Ok(("g", Drawn::GeometricFallback)));
        }
        // No reuse after a failure: every view tries the decoder again.
        assert_eq!(probe.ran, ["neural", "neural", "geometric", "neural", "geometric", "neural", "geometric"]);
        assert_eq!(policy.counters(), NeuralCounters { views: 1, decoder_runs: 1, reused: 0, fallbacks: 3 });
    }
}
