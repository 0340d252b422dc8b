//! Offline rendering on the GPU (`r2human render --backend vulkan`): one headless device (the caller's), one
//! [`Renderer`], the input uploaded once, then one frame per camera read back from host-visible memory. Same contract as
//! `pipeline::ViewRenderer::render_frame` (VR: the person over the panorama; AR: premultiplied RGBA). With the
//! neural renderer, each view goes through the host-memory seam of [`super::neural`].

use std::sync::Arc;

use super::{Context, GpuError, Renderer};
use crate::compose::Mode;
use crate::geometry::Camera;
use crate::io::environment::Environment;
use crate::io::sequence::Frame;
use crate::pipeline::warp::OcclusionFill;
use crate::pipeline::{NeuralInput, PreparedInput, SharedNeural};

/// Uploads a prepared input into `renderer`: mesh, source view (colour, mask, G-buffer, camera), panorama
/// (VR only; AR needs none), fill and fusion. Call once per input (and again on a new renderer).
pub fn upload_input(
    renderer: &mut Renderer,
    input: &PreparedInput,
    env: Option<&Environment>,
    fill: OcclusionFill,
    fusion: bool,
) -> Result<(), GpuError> {
    renderer.set_mesh(&input.mesh)?;
    renderer.set_source_parts(
        &input.normalised.rgb,
        &input.normalised.mask,
        &input.source_gbuffer,
        &input.source_camera,
    )?;
    if let Some(env) = env {
        renderer.set_environment(env)?;
    }
    renderer.set_fill(fill);
    renderer.set_fusion(fusion);
    Ok(())
}

/// Renders one frame per camera on `ctx`'s device (a headless one: [`Context::headless`]). All cameras must have one
/// size. With `fusion`, consecutive views are fused (paper Eq. 8) as in an orbit; without, each view stands alone.
pub fn render_views(
    ctx: Arc<Context>,
    input: &PreparedInput,
    env: &Environment,
    cameras: &[Camera],
    mode: Mode,
    fill: OcclusionFill,
    fusion: bool,
) -> Result<Vec<Frame>, GpuError> {
    let Some(mut renderer) = headless_for(ctx, input, env, cameras, mode, fill, fusion)? else { return Ok(Vec::new()) };
    let mut frames = Vec::with_capacity(cameras.len());
    for cam in cameras {
        renderer.render_frame(cam, mode, None)?;
        frames.push(renderer.read_output(mode));
    }
    Ok(frames)
}

/// [`render_views`] with the neural decoder: each view through the host-memory seam
/// ([`super::neural::gpu_neural_person`]: GPU raster and flow read back, decoder on ONNX Runtime, the result
/// uploaded for fusion and compositing), given the neural renderer and the encoder's output for `input`. A view the decoder fails on is
/// drawn by the geometric GPU passes with one warning; returns the frames and how many views fell back.
#[allow(clippy::too_many_arguments)]
pub fn render_views_neural(
    ctx: Arc<Context>,
    input: &PreparedInput,
    env: &Environment,
    cameras: &[Camera],
    mode: Mode,
    fill: OcclusionFill,
    fusion: bool,
    (neural, encoded): (&SharedNeural, &NeuralInput),
) -> Result<(Vec<Frame>, usize), GpuError> {
    let Some(mut renderer) = headless_for(ctx, input, env, cameras, mode, fill, fusion)? else {
        return Ok((Vec::new(), 0));
    };
    let source = super::neural::SourceView::of(input);
    let mut frames = Vec::with_capacity(cameras.len());
    let mut fallbacks = 0;
    for cam in cameras {
        match super::neural::gpu_neural_person(&mut renderer, neural, source, encoded, cam) {
            Ok((person, _)) => renderer.render_frame_from_person(Some(&person), cam, mode, None)?,
            Err(e) => {
                if fallbacks == 0 {
                    tracing::warn!("the neural decoder failed on a view, drawing it geometrically: {e}");
                }
                fallbacks += 1;
                renderer.render_frame(cam, mode, None)?;
            }
        }
        frames.push(renderer.read_output(mode));
    }
    Ok((frames, fallbacks))
}

/// A renderer on `ctx` for `cameras` (all of one size), with `input` uploaded; `None` for no cameras.
fn headless_for(
    ctx: Arc<Context>,
    input: &PreparedInput,
    env: &Environment,
    cameras: &[Camera],
    mode: Mode,
    fill: OcclusionFill,
    fusion: bool,
) -> Result<Option<Renderer>, GpuError> {
    let Some(first) = cameras.first() else { return Ok(None) };
    let (w, h) = (first.width, first.height);
    if let Some(c) = cameras.iter().find(|c| (c.width, c.height) != (w, h)) {
        return Err(GpuError::Invalid(format!(
            "views of {}x{} and {w}x{h} cannot share a renderer",
            c.width, c.height
        )));
    }
    tracing::info!("rendering {} view(s) on {}", cameras.len(), ctx.device_name());
    let mut renderer = Renderer::new(ctx, w, h)?;
    upload_input(&mut renderer, input, (mode == Mode::Vr).then_some(env), fill, fusion)?;
    Ok(Some(renderer))
}
