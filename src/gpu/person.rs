//! The person renderer on the Vulkan renderer: [`GpuView`] is the [`PersonBackend`] the window, the XR eyes and
//! `render --backend vulkan` draw through (with [`crate::pipeline::NeuralPolicy`] deciding neural, reuse or
//! geometric), and [`gpu_neural_person`] is its neural hand-off — the host-memory seam between the Vulkan renderer
//! and ONNX Runtime, one view at a time:
//!
//! 1. [`Renderer::neural_inputs`]: target raster and flow/Z-map on the GPU in one submission, read back.
//! 2. On the host: [`decode_person_view`], the decoder's colour lookup and the decoder, which samples the encoder's
//!    features at the flow inside the target mask's box (ONNX Runtime; a GPU execution provider copies its own
//!    inputs), and the photo's colour where the source camera sees the surface.
//! 3. [`Renderer::render_frame_from_person`]: the result uploaded for spatial fusion, the panorama composite or
//!    the AR layer, and presentation.
//!
//! The seam is plain host memory on both sides, so a zero-copy path (the GPU feature warp
//! [`Renderer::warp_features`] feeding an ONNX Runtime device binding) can replace step 2's inputs without
//! changing the callers.

use std::time::Instant;

use super::{GpuError, PresentTarget, Renderer};
use crate::buffer::RgbaImage;
use crate::compose::Mode;
use crate::geometry::Camera;
use crate::neural::NeuralError;
use crate::pipeline::{
    decode_person_view, NeuralInput, NeuralRef, NeuralViewTimes, PersonBackend, SharedNeural, SourceView,
};

/// Why [`gpu_neural_person`] could not draw a view (the person-renderer policy then draws it geometrically).
#[derive(Debug, thiserror::Error)]
pub enum NeuralViewError {
    /// The GPU raster or flow/Z-map pass (or its read-back) failed.
    #[error("GPU raster/flow: {0}")]
    Inputs(#[source] GpuError),
    /// The decoder failed (ONNX Runtime, shapes).
    #[error(transparent)]
    Decoder(#[from] NeuralError),
    /// The decoder returned NaN or infinite values.
    #[error("the decoder output is not finite")]
    NotFinite,
}

/// Renders the person for `camera` with the neural decoder through the host-memory seam (see the module docs):
/// the Vulkan renderer (with the input's mesh and source view uploaded) rasterises the target and computes the
/// flow and Z-map; the lookup and the decoder run on the host. Returns the person layer (premultiplied linear
/// RGBA of the renderer's size) for [`Renderer::render_frame_from_person`]. The decoder runs under the shared
/// lock (one view at a time).
pub fn gpu_neural_person(
    renderer: &mut Renderer,
    neural: &SharedNeural,
    source: SourceView<'_>,
    encoded: &NeuralInput,
    camera: &Camera,
) -> Result<(RgbaImage, NeuralViewTimes), NeuralViewError> {
    let start = Instant::now();
    let (target, flowz) = renderer.neural_inputs(camera).map_err(NeuralViewError::Inputs)?;
    let gpu_inputs = start.elapsed();
    let start = Instant::now();
    let fill = renderer.fill();
    let person = {
        let mut n = neural.lock().unwrap_or_else(|p| p.into_inner());
        decode_person_view(&mut n.runtime.decoder, &encoded.features, &flowz, &source, &target, camera, fill)
    }?;
    if person.data.iter().any(|p| !p.is_finite()) {
        return Err(NeuralViewError::NotFinite);
    }
    Ok((person, NeuralViewTimes { gpu_inputs, decoder: start.elapsed() }))
}

/// One view on a [`Renderer`] whose scene is uploaded ([`Renderer::set_scene`]): composited as `mode` says and,
/// with `target`, presented into that swapchain image. The frame stays on the renderer ([`Renderer::read_output`],
/// [`Renderer::output_buffer`]).
pub struct GpuView<'r> {
    /// The renderer.
    pub renderer: &'r mut Renderer,
    /// VR or AR.
    pub mode: Mode,
    /// Where to present the frame, if anywhere.
    pub target: Option<PresentTarget>,
}

impl PersonBackend<NeuralRef<'_>> for GpuView<'_> {
    type Output = ();
    type Error = GpuError;
    type NeuralFailure = NeuralViewError;

    fn neural(
        &mut self,
        source: SourceView<'_>,
        n: &NeuralRef<'_>,
        camera: &Camera,
    ) -> Result<Result<((), NeuralViewTimes), NeuralViewError>, GpuError> {
        match gpu_neural_person(self.renderer, n.renderer, source, n.encoded, camera) {
            Ok((person, times)) => {
                self.renderer.render_frame_from_person(Some(&person), camera, self.mode, self.target)?;
                Ok(Ok(((), times)))
            }
            Err(e) => Ok(Err(e)),
        }
    }

    fn reuse_neural(&mut self, camera: &Camera) -> Result<Option<()>, GpuError> {
        // Same pose, same input: the layer on the GPU stands (as the geometric path reuses its own).
        self.renderer.render_frame_from_person(None, camera, self.mode, self.target).map(Some)
    }

    fn geometric(&mut self, _source: SourceView<'_>, camera: &Camera) -> Result<(), GpuError> {
        self.renderer.render_frame(camera, self.mode, self.target)
    }
}
