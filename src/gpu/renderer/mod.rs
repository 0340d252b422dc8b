//! The per-view passes on the GPU, behind the CPU reference's data contracts.
//!
//! One [`Renderer`] owns every buffer, image and pipeline for one output size. Inputs that change rarely (mesh,
//! source photo, panorama, encoder features) are uploaded by `set_*` calls; a frame then only writes the
//! cameras into a uniform buffer, records one command buffer and waits on one fence. Per-pixel data lives in
//! host-visible storage buffers (device-local where the device allows), which is also the seam to the neural
//! decoder: its inputs and outputs are plain memory copies from and to these buffers.
//!
//! Data layout (all row-major, row 0 at the top, linear light):
//! - target geometry: `vec4(view normal, view depth)`; target colour: `vec4(vertex colour, coverage)`;
//! - flow: `vec4(source u, source v, Z-map z_src, visibility 0/1)`;
//! - person layers: premultiplied `vec4` RGBA; output: `vec4` (VR: RGB and 1, AR: premultiplied RGBA).
//!
//! Files, by concern: this one holds the types, the renderer's state and its accessors; `bindings` creates the
//! resources, pipelines and descriptor set; `upload` takes the inputs (mesh, source, panorama, features,
//! overlay); `frame` renders whole views (and the neural seam); `stages` runs one pass on given inputs, as the
//! CPU reference's functions do; `record` records and submits a frame's passes; `readback` reads results and
//! GPU timestamps back; `pack` packs host data for upload.

use std::sync::Arc;
use std::time::Duration;

use ash::vk;
use glam::{Mat4, Vec3};

use super::resources::{Buffer, Image2d};
use super::{shaders, CommandSlot, Context, GpuError};
use crate::buffer::RgbaImage;
use crate::geometry::{Camera, Projection};
use crate::pipeline::warp::OcclusionFill;

mod bindings;
mod frame;
mod pack;
mod readback;
mod record;
mod stages;
mod upload;

pub use pack::{f32_to_f16, pack_half2};
use readback::{StageTimer, TIMESTAMPS};
use record::Step;

const GEOMETRY_FORMAT: vk::Format = vk::Format::R32G32B32A32_SFLOAT;
const WORKGROUP: u32 = 8;

/// Binding numbers of descriptor set 0 (must match `shaders/*.comp`).
mod binding {
    pub const FRAME: u32 = 0;
    pub const GEOMETRY: u32 = 1;
    pub const COLOR: u32 = 2;
    pub const FLOW: u32 = 3;
    pub const PERSON: u32 = 4;
    pub const PREV_PERSON: u32 = 5;
    pub const PREV_GEOMETRY: u32 = 6;
    pub const SOURCE_COLOR: u32 = 7;
    pub const SOURCE_GEOMETRY: u32 = 8;
    pub const ENV: u32 = 9;
    pub const OUT: u32 = 10;
    pub const SOURCE_FEATURES: u32 = 11;
    pub const WARPED_FEATURES: u32 = 12;
    pub const ENCODED: u32 = 13;
    pub const CURRENT: u32 = 14;
    pub const PYRAMID: u32 = 15;
    pub const OVERLAY: u32 = 16;
    pub const COUNT: u32 = 17;
}

/// One camera as the shaders see it (std140 layout, see `shaders/common.glsl`).
#[repr(C)]
#[derive(Clone, Copy, Default)]
struct GpuCamera {
    view_from_world: [f32; 16],
    world_from_view: [f32; 16],
    proj: [f32; 4],
    info: [f32; 4],
}

/// The per-frame uniform block (std140, see `shaders/common.glsl`).
#[repr(C)]
#[derive(Clone, Copy, Default)]
struct FrameUniforms {
    target: GpuCamera,
    source: GpuCamera,
    viewer: GpuCamera,
    previous: GpuCamera,
    params: [f32; 4],
    mean_color: [f32; 4],
    sizes: [u32; 4],
    flags: [u32; 4],
    output_format: [u32; 4],
    source_images: [u32; 4],
}

fn gpu_camera(camera: &Camera, bounds: Option<(Vec3, Vec3)>) -> GpuCamera {
    let view_from_world = Mat4::from(camera.view_from_world);
    let world_from_view = Mat4::from(camera.view_from_world.inverse());
    let (proj, kind, near) = match camera.projection {
        Projection::Orthographic { half_width, half_height } => {
            // Depth range of the mesh in this view: the whole mesh is rendered, in front of and behind the view
            // plane (as the CPU rasteriser does), so the depth mapping spans its bounds with a margin.
            let (mut zmin, mut zmax) = (-2.0f32, 2.0f32);
            if let Some((lo, hi)) = bounds {
                zmin = f32::INFINITY;
                zmax = f32::NEG_INFINITY;
                for i in 0..8 {
                    let c = Vec3::new(
                        if i & 1 == 0 { lo.x } else { hi.x },
                        if i & 2 == 0 { lo.y } else { hi.y },
                        if i & 4 == 0 { lo.z } else { hi.z },
                    );
                    let z = camera.view_from_world.transform_point3(c).z;
                    zmin = zmin.min(z);
                    zmax = zmax.max(z);
                }
                let pad = 0.01 * (zmax - zmin) + 1e-3;
                zmin -= pad;
                zmax += pad;
            }
            ([half_width, half_height, zmin, zmax], 0.0, 0.0)
        }
        Projection::Perspective { fov, near } => {
            ([fov.angle_left.tan(), fov.angle_right.tan(), fov.angle_up.tan(), fov.angle_down.tan()], 1.0, near)
        }
    };
    GpuCamera {
        view_from_world: view_from_world.to_cols_array(),
        world_from_view: world_from_view.to_cols_array(),
        proj,
        info: [kind, camera.width as f32, camera.height as f32, near],
    }
}

/// Compute passes (index into the pipeline table).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Pass {
    Panorama = 0,
    Ar = 1,
    Encode = 2,
    Flow = 3,
    Warp = 4,
    Pull = 5,
    Push = 6,
    Resolve = 7,
    Fusion = 8,
    Features = 9,
}

const PASS_SHADERS: [&[u8]; 10] = [
    shaders::PANORAMA,
    shaders::AR,
    shaders::ENCODE,
    shaders::FLOW,
    shaders::WARP,
    shaders::PULL,
    shaders::PUSH,
    shaders::RESOLVE,
    shaders::FUSION,
    shaders::FEATURES,
];

/// Push constants of the pyramid passes (see `Level` in `shaders/common.glsl`).
#[repr(C)]
#[derive(Clone, Copy, Default)]
struct LevelConstants {
    src_offset: u32,
    src_width: u32,
    src_height: u32,
    dst_offset: u32,
    dst_width: u32,
    dst_height: u32,
    top_offset: u32,
    pad: u32,
}

/// The mesh on the device (uploaded once per mesh).
struct GpuMesh {
    positions: Buffer,
    normals: Buffer,
    colors: Buffer,
    indices: Buffer,
    index_count: u32,
    bounds: (Vec3, Vec3),
    has_colors: bool,
}

/// Where a frame goes after rendering, for the window: the encoded sRGB output is copied into `image`
/// (a swapchain image of the renderer's size) after waiting on `wait`, and `signal` is signalled.
#[derive(Clone, Copy, Debug)]
pub struct PresentTarget {
    /// The swapchain image (usage TRANSFER_DST).
    pub image: vk::Image,
    /// Signalled when the image is acquired.
    pub wait: vk::Semaphore,
    /// Signalled when the copy is done (the present waits on it).
    pub signal: vk::Semaphore,
    /// Pack BGRA instead of RGBA (swapchain format `B8G8R8A8_*`).
    pub bgra: bool,
}

/// What a renderer has created and uploaded since it was made: the evidence that frames allocate nothing,
/// create no pipeline and upload no mesh (compare two snapshots around a run of frames).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RendererCounters {
    /// Buffers and images created (at creation, and when an input outgrows its buffer).
    pub resources_created: u64,
    /// Pipelines created (all at creation).
    pub pipelines_created: u64,
    /// Mesh uploads ([`Renderer::set_mesh`]).
    pub mesh_uploads: u64,
    /// Source-view uploads ([`Renderer::set_source`]).
    pub source_uploads: u64,
    /// Frames rendered ([`Renderer::render_frame`], [`Renderer::render_person`]).
    pub frames: u64,
}

/// The Vulkan per-view renderer for one output size. See the module docs.
pub struct Renderer {
    ctx: Arc<Context>,
    width: u32,
    height: u32,
    // Raster pass.
    render_pass: vk::RenderPass,
    framebuffer: vk::Framebuffer,
    geometry_image: Image2d,
    color_image: Image2d,
    /// Kept alive for the framebuffer; only the render pass touches it.
    _depth_image: Image2d,
    raster_pipeline: vk::Pipeline,
    // Compute passes.
    set_layout: vk::DescriptorSetLayout,
    pipeline_layout: vk::PipelineLayout,
    descriptor_pool: vk::DescriptorPool,
    set: vk::DescriptorSet,
    pipelines: Vec<vk::Pipeline>,
    // Buffers.
    frame: Buffer,
    geometry: Buffer,
    color: Buffer,
    flow: Buffer,
    person: Buffer,
    prev_person: Buffer,
    prev_geometry: Buffer,
    source_color: Buffer,
    source_geometry: Buffer,
    env: Buffer,
    out: Buffer,
    source_features: Buffer,
    warped_features: Buffer,
    encoded: Buffer,
    current: Buffer,
    pyramid: Buffer,
    /// Text overlay coverage (one byte per pixel of the overlay rectangle), blended by the encode pass.
    overlay: Buffer,
    levels: Vec<(u32, u32, u32)>,
    // Inputs.
    mesh: Option<GpuMesh>,
    env_size: (u32, u32),
    env_yaw: f32,
    source_size: (u32, u32),
    /// The source colour buffer holds the input's back image after the photo.
    has_back: bool,
    feature_shape: Option<(u32, u32, u32)>,
    fill: OcclusionFill,
    fusion: bool,
    /// Camera of the last frame kept in `prev_*` (spatial fusion), when one is.
    previous: Option<Camera>,
    /// Input of the last `fuse` call (stage API, to recognise a repeated call like the CPU reference).
    last_fused_input: Option<RgbaImage>,
    /// An input changed since the last frame (mesh, source, fill): the cached frame is stale.
    dirty: bool,
    uniforms: FrameUniforms,
    /// The frame's command buffer and fence: `run` records into it, submits and waits. Fields drop after
    /// `Drop::drop`, which has idled the queue, so its pool is never destroyed under a pending submission.
    commands: CommandSlot,
    // Instrumentation.
    timer: Option<StageTimer>,
    counters: RendererCounters,
}

impl std::fmt::Debug for Renderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Renderer").field("width", &self.width).field("height", &self.height).finish()
    }
}

impl Renderer {
    /// The output size `(width, height)`.
    pub fn size(&self) -> (usize, usize) {
        (self.width as usize, self.height as usize)
    }

    /// The device this renderer runs on.
    pub fn context(&self) -> &Arc<Context> {
        &self.ctx
    }

    /// What was created and uploaded so far (see [`RendererCounters`]).
    pub fn counters(&self) -> RendererCounters {
        self.counters
    }

    /// GPU time of each step of the last submission, in order (e.g. `raster`, `flow + Z-map`, `warp`,
    /// `hole fill`, `fusion`, `keep previous`, `compose VR`), measured with timestamp queries. Empty when the
    /// device has no timestamps.
    pub fn stage_times(&self) -> &[(&'static str, Duration)] {
        self.timer.as_ref().map_or(&[], |t| &t.steps[..t.count])
    }

    /// The output buffer (`vec4` per pixel, row-major, linear; VR: RGB and 1, AR: premultiplied RGBA) of the last
    /// frame, for copies into images owned elsewhere (e.g. OpenXR swapchains). It is never reallocated; it is
    /// rewritten by the next frame, so such copies must finish before the renderer is used again.
    pub fn output_buffer(&self) -> vk::Buffer {
        self.out.buffer
    }

    fn check_camera(&self, camera: &Camera) -> Result<(), GpuError> {
        self.check_image(camera.width, camera.height)
    }

    fn check_image(&self, width: usize, height: usize) -> Result<(), GpuError> {
        if (width, height) != self.size() {
            return Err(GpuError::Invalid(format!(
                "image of {width}x{height} given to a renderer of {}x{}",
                self.width, self.height
            )));
        }
        Ok(())
    }
}

impl Drop for Renderer {
    fn drop(&mut self) {
        let device = self.ctx.device();
        // SAFETY: every submission was waited for; the device is idle with respect to these objects.
        unsafe {
            {
                let _queue = self.ctx.lock_queue();
                let _ = device.queue_wait_idle(self.ctx.queue());
            }
            if let Some(t) = self.timer.take() {
                device.destroy_query_pool(t.pool, None);
            }
            for &p in &self.pipelines {
                device.destroy_pipeline(p, None);
            }
            device.destroy_pipeline(self.raster_pipeline, None);
            device.destroy_descriptor_pool(self.descriptor_pool, None);
            device.destroy_pipeline_layout(self.pipeline_layout, None);
            device.destroy_descriptor_set_layout(self.set_layout, None);
            device.destroy_framebuffer(self.framebuffer, None);
            device.destroy_render_pass(self.render_pass, None);
        }
    }
}
