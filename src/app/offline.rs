//! Offline rendering (`render`, `render --orbit`, `demo`): the views of a prepared input on the chosen backend —
//! the Vulkan passes ([`crate::gpu::offline`]) or the CPU reference — through the one person-renderer policy.

use std::sync::Arc;

use super::{log_software_device, Backend};
use crate::compose::Mode;
use crate::geometry::Camera;
use crate::gpu::{offline, Context, GpuError};
use crate::io::environment::Environment;
use crate::io::sequence::RenderedFrame;
use crate::pipeline::warp::OcclusionFill;
use crate::pipeline::{NeuralRequest, PreparedInput, SharedNeural, SourceView};

/// `render --backend`: renders one frame per camera on the chosen backend, with the neural renderer when `neural`
/// is given (through the host-memory seam; views the decoder fails on are drawn geometrically, with a warning).
/// `Ok(None)` means "use the CPU path": the CPU was asked for, `auto` found a software rasteriser or no device
/// (logged), or Vulkan was asked for but no device is usable (the reason is printed once on stderr, with the
/// fallback). Other GPU failures are errors.
#[allow(clippy::too_many_arguments)]
pub fn render_on_backend(
    backend: Backend,
    input: &PreparedInput,
    env: &Environment,
    cameras: &[Camera],
    mode: Mode,
    fill: OcclusionFill,
    fusion: bool,
    neural: Option<&SharedNeural>,
) -> anyhow::Result<Option<Vec<RenderedFrame>>> {
    if backend == Backend::Cpu {
        return Ok(None);
    }
    // One headless device for the probe of `auto` and for the views.
    let ctx = match Context::headless() {
        Ok(ctx) => ctx,
        Err(e) if backend == Backend::Auto => {
            tracing::info!("no usable Vulkan device ({e}): rendering on the CPU reference");
            return Ok(None);
        }
        Err(e) => return cpu_without_device(e),
    };
    if backend.resolve(ctx.is_software()) == Backend::Cpu {
        log_software_device(ctx.device_name());
        return Ok(None);
    }
    let ctx = Arc::new(ctx);
    let encoded = match neural {
        Some(shared) => match shared.lock().unwrap_or_else(|p| p.into_inner()).encode(input) {
            Ok(e) => Some(e),
            Err(e) => {
                tracing::warn!("the neural encoder failed on this input ({e}); rendering geometrically");
                None
            }
        },
        None => None,
    };
    // An input the encoder failed on is drawn geometrically (said above), not counted per view.
    let request = match encoded.as_ref() {
        Some(e) => NeuralRequest::from_parts(neural, Some(e)),
        None => NeuralRequest::Off,
    };
    let settings = offline::ViewSettings { mode, fill, fusion };
    match offline::render_views(ctx, SourceView::of(input), request, env, cameras, settings) {
        Ok((frames, counters)) => {
            if counters.fallbacks > 0 {
                tracing::warn!(
                    "the neural decoder failed on {} view(s); the geometric renderer drew them",
                    counters.fallbacks
                );
            }
            Ok(Some(frames))
        }
        Err(e) => cpu_without_device(e),
    }
}

/// `render --backend vulkan` without a usable device: one warning (the reason and the CPU fallback), `Ok(None)`
/// (the CPU path); any other GPU failure is an error.
fn cpu_without_device(e: GpuError) -> anyhow::Result<Option<Vec<RenderedFrame>>> {
    match e {
        GpuError::NoVulkan(_) | GpuError::NoDevice(_) => {
            tracing::warn!("{e}; rendering on the CPU instead (--backend cpu)");
            Ok(None)
        }
        e => Err(anyhow::Error::new(e).context("the Vulkan backend failed")),
    }
}

/// The cameras of an orbit: `n` views evenly spaced in yaw from `start_yaw`, at `pitch`, `size x size` (the
/// same views as `r2human render --orbit`).
pub fn orbit_cameras(n: usize, start_yaw: f32, pitch: f32, size: usize) -> Vec<Camera> {
    (0..n).map(|i| Camera::orbit(start_yaw + 360.0 * i as f32 / n.max(1) as f32, pitch, size, size)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orbit_cameras_match_the_render_orbit_spacing() {
        let cams = orbit_cameras(4, 10.0, -5.0, 32);
        assert_eq!(cams.len(), 4);
        for (i, cam) in cams.iter().enumerate() {
            assert_eq!(*cam, Camera::orbit(10.0 + 90.0 * i as f32, -5.0, 32, 32));
        }
        assert!(orbit_cameras(0, 0.0, 0.0, 32).is_empty());
    }
}
