//! The neural decoder on the Vulkan paths (window, XR eyes, `render --backend vulkan`): the host-memory seam
//! between the Vulkan renderer and ONNX Runtime, one view at a time.
//!
//! 1. [`Renderer::neural_inputs`]: target raster and flow/Z-map on the GPU in one submission, read back.
//! 2. On the host: the decoder's colour lookup ([`photo_lookup`]) and the decoder, which samples the encoder's
//!    features at the flow inside the target mask's box (ONNX Runtime; a GPU execution provider copies its own
//!    inputs).
//! 3. [`Renderer::render_frame_from_person`]: the result uploaded for spatial fusion, the panorama composite or
//!    the AR layer, and presentation.
//!
//! The seam is plain host memory on both sides, so a zero-copy path (the GPU feature warp
//! [`Renderer::warp_features`] feeding an ONNX Runtime device binding) can replace step 2's inputs without
//! changing the callers.

use std::time::{Duration, Instant};

use super::Renderer;
use crate::buffer::{GrayImage, RgbImage, RgbaImage};
use crate::geometry::Camera;
use crate::pipeline::{photo_lookup, NeuralInput, PreparedInput, SharedNeural};

/// The source view the decoder's colour lookup samples (premultiplied linear RGB, its mask, the source camera).
#[derive(Clone, Copy, Debug)]
pub struct SourceView<'a> {
    /// Premultiplied linear RGB.
    pub rgb: &'a RgbImage,
    /// Person mask in `[0, 1]`.
    pub mask: &'a GrayImage,
    /// The orthographic source camera.
    pub camera: &'a Camera,
}

impl<'a> SourceView<'a> {
    /// The source view of a prepared input.
    pub fn of(input: &'a PreparedInput) -> Self {
        Self { rgb: &input.normalised.rgb, mask: &input.normalised.mask, camera: &input.source_camera }
    }
}

/// Host-side times of one neural view through the seam.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NeuralViewTimes {
    /// GPU raster + flow/Z-map, including the read-back into host memory.
    pub gpu_inputs: Duration,
    /// Colour lookup, feature sampling and decoder (ONNX Runtime).
    pub decoder: Duration,
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
) -> Result<(RgbaImage, NeuralViewTimes), String> {
    let start = Instant::now();
    let (target, flowz) = renderer.neural_inputs(camera).map_err(|e| format!("GPU raster/flow: {e}"))?;
    let gpu_inputs = start.elapsed();
    let start = Instant::now();
    let lookup = photo_lookup(source.rgb, source.mask, source.camera, &flowz);
    let person = {
        let mut n = neural.lock().unwrap_or_else(|p| p.into_inner());
        n.runtime.decoder.render_view(&encoded.features, &flowz, source.camera.width, &target, &lookup)
    }
    .map_err(|e| e.to_string())?;
    if person.data.iter().any(|p| !p.is_finite()) {
        return Err("the decoder output is not finite".into());
    }
    Ok((person, NeuralViewTimes { gpu_inputs, decoder: start.elapsed() }))
}
