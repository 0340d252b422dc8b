//! Offline rendering on the GPU (`r2human render --backend vulkan`): one headless device (the caller's), one
//! [`Renderer`], the scene uploaded once, then one frame per camera read back from host-visible memory. Same
//! contract as `pipeline::ViewRenderer::render_frame` (VR: the person over the panorama; AR: premultiplied RGBA),
//! and the same person-renderer policy ([`NeuralPolicy`]: a view the decoder fails on is drawn by the geometric
//! passes, with one warning, and counted).

use std::sync::Arc;

use super::{Context, GpuError, GpuView, Renderer};
use crate::compose::{Mode, RenderedFrame};
use crate::geometry::Camera;
use crate::io::environment::Environment;
use crate::pipeline::warp::OcclusionFill;
use crate::pipeline::{NeuralCounters, NeuralPolicy, NeuralRequest, SourceView};

/// How the views of one offline render are drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ViewSettings {
    /// VR (over the panorama) or AR (premultiplied alpha layer).
    pub mode: Mode,
    /// How surfaces the photo does not show are coloured.
    pub fill: OcclusionFill,
    /// Fuse consecutive views (paper Eq. 8) as in an orbit; without, each view stands alone.
    pub fusion: bool,
}

/// Uploads a scene into `renderer`: mesh, source view, panorama (VR only; AR needs none), fill and fusion. Call
/// once per input (and again on a new renderer).
pub fn upload_scene(
    renderer: &mut Renderer,
    source: &SourceView<'_>,
    env: Option<&Environment>,
    fill: OcclusionFill,
    fusion: bool,
) -> Result<(), GpuError> {
    renderer.set_scene(source)?;
    if let Some(env) = env {
        renderer.set_environment(env)?;
    }
    renderer.set_fill(fill);
    renderer.set_fusion(fusion);
    Ok(())
}

/// Renders one frame per camera on `ctx`'s device (a headless one: [`Context::headless`]), with the neural
/// decoder when `neural` asks for it (through the host-memory seam of [`super::person`]). All cameras must have
/// one size. Returns the frames and what the neural renderer did (fallbacks included).
pub fn render_views(
    ctx: Arc<Context>,
    source: SourceView<'_>,
    neural: NeuralRequest<'_>,
    env: &Environment,
    cameras: &[Camera],
    settings: ViewSettings,
) -> Result<(Vec<RenderedFrame>, NeuralCounters), GpuError> {
    let Some(first) = cameras.first() else { return Ok((Vec::new(), NeuralCounters::default())) };
    let (w, h) = (first.width, first.height);
    if let Some(c) = cameras.iter().find(|c| (c.width, c.height) != (w, h)) {
        return Err(GpuError::Invalid(format!(
            "views of {}x{} and {w}x{h} cannot share a renderer",
            c.width, c.height
        )));
    }
    tracing::info!("rendering {} view(s) on {}", cameras.len(), ctx.device_name());
    let mut renderer = Renderer::new(ctx, w, h)?;
    let mode = settings.mode;
    upload_scene(&mut renderer, &source, (mode == Mode::Vr).then_some(env), settings.fill, settings.fusion)?;
    let mut policy = NeuralPolicy::default();
    let mut frames = Vec::with_capacity(cameras.len());
    for cam in cameras {
        policy.draw(&mut GpuView { renderer: &mut renderer, mode, target: None }, source, neural, 0, cam)?;
        frames.push(renderer.read_output(mode));
    }
    Ok((frames, policy.counters()))
}
