//! Reading results back to the host: images and G-buffers out of the mapped storage buffers, the presented
//! frame, and the GPU timestamps of each recorded step.

use std::time::Duration;

use ash::vk;
use glam::{Vec2, Vec3, Vec4};

use super::{Pass, Renderer, Step};
use crate::buffer::{Image, RgbImage, RgbaImage};
use crate::compose::{Mode, RenderedFrame};
use crate::geometry::raster::GBuffer;
use crate::geometry::zmap::{FlowZ, FLOW_OUTSIDE};
use crate::gpu::resources::Buffer;
use crate::gpu::{Context, GpuError};

impl Renderer {
    /// The 8-bit sRGB image of the last presented frame, overlay included (what the window shows), as RGB.
    pub fn read_presented(&self) -> image::RgbImage {
        let mut words = vec![0u32; (self.width * self.height) as usize];
        self.encoded.read(&mut words);
        let bgra = self.uniforms.output_format[0] != 0;
        image::RgbImage::from_fn(self.width, self.height, |x, y| {
            let [a, b, c, _] = words[(y * self.width + x) as usize].to_le_bytes();
            image::Rgb(if bgra { [c, b, a] } else { [a, b, c] })
        })
    }

    pub(super) fn read_flow(&self) -> (FlowZ, Vec<bool>) {
        let raw = self.read_vec4(&self.flow);
        let (w, h) = self.size();
        let mut f = FlowZ { flow: Image::new(w, h, FLOW_OUTSIDE), z: Image::new(w, h, 0.0), mask: vec![false; w * h] };
        let mut visible = vec![false; w * h];
        for (i, v) in raw.iter().enumerate() {
            if v.w > 0.5 {
                f.flow.data[i] = Vec2::new(v.x, v.y);
                f.z.data[i] = v.z;
                f.mask[i] = true;
                visible[i] = v.w > 1.5;
            }
        }
        (f, visible)
    }

    /// Reads the current output back (the last frame rendered or presented), e.g. for a screenshot.
    pub fn read_output(&self, mode: Mode) -> RenderedFrame {
        match mode {
            Mode::Vr => RenderedFrame::Vr(self.read_rgb(&self.out)),
            Mode::Ar => RenderedFrame::Ar(self.read_rgba(&self.out)),
        }
    }

    /// Reads this submission's timestamps into the per-step durations (no allocation: fixed arrays).
    pub(super) fn read_timestamps(&mut self, steps: &[Step]) {
        let Some(t) = self.timer.as_mut() else { return };
        let n = (steps.len() + 1).min(TIMESTAMPS as usize);
        let mut ticks = [0u64; TIMESTAMPS as usize];
        // SAFETY: the fence was waited for, so every written query is available; only written ones are read.
        let ok = unsafe {
            self.ctx.device().get_query_pool_results(t.pool, 0, &mut ticks[..n], vk::QueryResultFlags::TYPE_64)
        };
        t.count = 0;
        if ok.is_err() {
            return;
        }
        for i in 1..n {
            let dt = ticks[i].wrapping_sub(ticks[i - 1]) & t.mask;
            let ns = (dt as f64 * f64::from(t.period_ns)).max(0.0);
            t.steps[i - 1] = (step_name(steps[i - 1]), Duration::from_nanos(ns as u64));
        }
        t.count = n - 1;
    }

    pub(super) fn read_vec4(&self, buffer: &Buffer) -> Vec<Vec4> {
        let mut v = vec![Vec4::ZERO; (self.width * self.height) as usize];
        buffer.read(&mut v);
        v
    }

    pub(super) fn read_rgb(&self, buffer: &Buffer) -> RgbImage {
        let v = self.read_vec4(buffer);
        Image {
            width: self.width as usize,
            height: self.height as usize,
            data: v.iter().map(|p| p.truncate()).collect(),
        }
    }

    pub(super) fn read_rgba(&self, buffer: &Buffer) -> RgbaImage {
        Image { width: self.width as usize, height: self.height as usize, data: self.read_vec4(buffer) }
    }

    pub(super) fn read_gbuffer(&self) -> GBuffer {
        let geometry = self.read_vec4(&self.geometry);
        let color = self.read_vec4(&self.color);
        let mut g = GBuffer::new(self.width as usize, self.height as usize);
        let has_colors = self.mesh.as_ref().is_some_and(|m| m.has_colors);
        let mut colors = has_colors.then(|| vec![Vec3::ZERO; geometry.len()]);
        for (i, (geo, col)) in geometry.iter().zip(&color).enumerate() {
            if col.w > 0.5 {
                g.mask[i] = true;
                g.depth[i] = geo.w;
                g.normal[i] = geo.truncate();
                if let Some(c) = colors.as_mut() {
                    c[i] = col.truncate();
                }
            }
        }
        g.color = colors;
        g
    }
}

/// Timestamp queries per submission (one before the first step, one after each step).
pub(super) const TIMESTAMPS: u32 = 10;

/// GPU timestamps around each recorded step (when the queue supports timestamps).
pub(super) struct StageTimer {
    pub(super) pool: vk::QueryPool,
    pub(super) period_ns: f32,
    pub(super) mask: u64,
    pub(super) steps: [(&'static str, Duration); TIMESTAMPS as usize],
    pub(super) count: usize,
}

impl StageTimer {
    pub(super) fn new(ctx: &Context) -> Result<Option<Self>, GpuError> {
        let instance = ctx.instance();
        let pd = ctx.physical_device();
        // SAFETY: `pd` is the context's physical device, enumerated from this live instance; the query only reads its
        // properties.
        let period_ns = unsafe { instance.get_physical_device_properties(pd) }.limits.timestamp_period;
        // SAFETY: the same physical device of the same live instance; a read-only query.
        let families = unsafe { instance.get_physical_device_queue_family_properties(pd) };
        let bits = families.get(ctx.queue_family() as usize).map_or(0, |f| f.timestamp_valid_bits);
        if bits == 0 || period_ns.is_nan() || period_ns <= 0.0 {
            return Ok(None);
        }
        let info = vk::QueryPoolCreateInfo::default().query_type(vk::QueryType::TIMESTAMP).query_count(TIMESTAMPS);
        // SAFETY: the device is alive: the renderer holds an `Arc` of its `Context`, which destroys the device only
        // after every owner is gone; the pool is destroyed in `Drop for Renderer` after the queue is idle.
        let pool =
            unsafe { ctx.device().create_query_pool(&info, None) }.map_err(GpuError::vk("create a query pool"))?;
        let mask = if bits >= 64 { u64::MAX } else { (1u64 << bits) - 1 };
        Ok(Some(Self { pool, period_ns, mask, steps: [("", Duration::ZERO); TIMESTAMPS as usize], count: 0 }))
    }
}

pub(super) fn step_name(step: Step) -> &'static str {
    match step {
        Step::Raster => "raster",
        Step::Compute(Pass::Flow) => "flow + Z-map",
        Step::Compute(Pass::Warp) => "warp",
        Step::HoleFill => "hole fill",
        Step::Compute(Pass::Fusion) => "fusion",
        Step::SavePrevious => "keep previous",
        Step::CopyPreviousToPerson => "reuse previous",
        Step::Compute(Pass::Panorama) => "compose VR",
        Step::Compute(Pass::Ar) => "compose AR",
        Step::Compute(Pass::Features) => "feature warp",
        Step::Compute(Pass::Encode) => "encode",
        Step::Compute(Pass::Pull | Pass::Push | Pass::Resolve) => "hole fill",
    }
}
