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

use std::sync::Arc;
use std::time::Duration;

use ash::vk;
use glam::{Mat4, Vec2, Vec3, Vec4};

use super::overlay::OverlayMask;
use super::resources::{shader_module, Buffer, Image2d};
use super::{present, shaders, Context, GpuError};
use crate::buffer::{Image, RgbImage, RgbaImage};
use crate::compose::{background_camera, Mode, RenderedFrame};
use crate::geometry::raster::{GBuffer, BACKGROUND_DEPTH};
use crate::geometry::zmap::{FlowZ, FLOW_OUTSIDE, VISIBILITY_LAMBDA};
use crate::geometry::{Camera, Projection, TriMesh};
use crate::io::environment::Environment;
use crate::pipeline::fusion::previous_weight;
use crate::pipeline::warp::OcclusionFill;
use crate::pipeline::SourceView;

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

/// Offsets (in texels) and sizes of the hole-filling pyramid levels, finest first, down to 1x1.
fn pyramid_levels(w: u32, h: u32) -> Vec<(u32, u32, u32)> {
    let mut levels = vec![(0, w, h)];
    let (mut lw, mut lh, mut offset) = (w, h, w * h);
    while lw > 1 || lh > 1 {
        lw = lw.div_ceil(2);
        lh = lh.div_ceil(2);
        levels.push((offset, lw, lh));
        offset += lw * lh;
    }
    levels
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

/// Timestamp queries per submission (one before the first step, one after each step).
const TIMESTAMPS: u32 = 10;

/// GPU timestamps around each recorded step (when the queue supports timestamps).
struct StageTimer {
    pool: vk::QueryPool,
    period_ns: f32,
    mask: u64,
    steps: [(&'static str, Duration); TIMESTAMPS as usize],
    count: usize,
}

impl StageTimer {
    fn new(ctx: &Context) -> Result<Option<Self>, GpuError> {
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

fn step_name(step: Step) -> &'static str {
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
    // Submission.
    command_pool: vk::CommandPool,
    command_buffer: vk::CommandBuffer,
    fence: vk::Fence,
    // Instrumentation.
    timer: Option<StageTimer>,
    counters: RendererCounters,
}

impl std::fmt::Debug for Renderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Renderer").field("width", &self.width).field("height", &self.height).finish()
    }
}

fn storage(ctx: &Arc<Context>, bytes: u64) -> Result<Buffer, GpuError> {
    Buffer::new(
        ctx,
        bytes,
        vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::TRANSFER_DST | vk::BufferUsageFlags::TRANSFER_SRC,
    )
}

impl Renderer {
    /// Creates the renderer for `width x height` outputs: all pipelines, images and per-pixel buffers.
    pub fn new(ctx: Arc<Context>, width: usize, height: usize) -> Result<Self, GpuError> {
        if width == 0 || height == 0 || width > 8192 || height > 8192 {
            return Err(GpuError::Invalid(format!("output size {width}x{height} must be between 1 and 8192")));
        }
        let (w, h) = (width as u32, height as u32);
        let px = u64::from(w) * u64::from(h);
        let device = ctx.device().clone();
        let depth_format = pick_depth_format(&ctx)?;
        let extent = vk::Extent2D { width: w, height: h };
        let attachment_usage = vk::ImageUsageFlags::COLOR_ATTACHMENT | vk::ImageUsageFlags::TRANSFER_SRC;
        let geometry_image =
            Image2d::new(&ctx, extent, GEOMETRY_FORMAT, attachment_usage, vk::ImageAspectFlags::COLOR)?;
        let color_image = Image2d::new(&ctx, extent, GEOMETRY_FORMAT, attachment_usage, vk::ImageAspectFlags::COLOR)?;
        let depth_image = Image2d::new(
            &ctx,
            extent,
            depth_format,
            vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT,
            vk::ImageAspectFlags::DEPTH,
        )?;

        // Everything below is destroyed by Drop once `Self` exists; build it in one go and assemble.
        let render_pass = create_render_pass(&device, depth_format)?;
        let views = [geometry_image.view, color_image.view, depth_image.view];
        let fb_info = vk::FramebufferCreateInfo::default()
            .render_pass(render_pass)
            .attachments(&views)
            .width(w)
            .height(h)
            .layers(1);
        // SAFETY: the device is alive: the renderer holds an `Arc` of its `Context`, which destroys the device only
        // after every owner is gone; the render pass and both attachment views are alive and match the framebuffer's
        // size; it is destroyed in `Drop`.
        let framebuffer =
            unsafe { device.create_framebuffer(&fb_info, None) }.map_err(GpuError::vk("create a framebuffer"))?;

        let mut bindings = Vec::new();
        for b in 0..binding::COUNT {
            let (ty, stages) = if b == binding::FRAME {
                (vk::DescriptorType::UNIFORM_BUFFER, vk::ShaderStageFlags::COMPUTE | vk::ShaderStageFlags::VERTEX)
            } else {
                (vk::DescriptorType::STORAGE_BUFFER, vk::ShaderStageFlags::COMPUTE)
            };
            bindings.push(
                vk::DescriptorSetLayoutBinding::default()
                    .binding(b)
                    .descriptor_type(ty)
                    .descriptor_count(1)
                    .stage_flags(stages),
            );
        }
        // SAFETY: the device is alive: the renderer holds an `Arc` of its `Context`, which destroys the device only
        // after every owner is gone; `bindings` outlives the call; the layout is destroyed in `Drop`.
        let set_layout = unsafe {
            device.create_descriptor_set_layout(&vk::DescriptorSetLayoutCreateInfo::default().bindings(&bindings), None)
        }
        .map_err(GpuError::vk("create the descriptor set layout"))?;
        let layouts = [set_layout];
        let push_ranges = [vk::PushConstantRange {
            stage_flags: vk::ShaderStageFlags::COMPUTE,
            offset: 0,
            size: std::mem::size_of::<LevelConstants>() as u32,
        }];
        // SAFETY: the device is alive: the renderer holds an `Arc` of its `Context`, which destroys the device only
        // after every owner is gone; `layouts` and `push_ranges` outlive the call; the layout is destroyed in `Drop`.
        let pipeline_layout = unsafe {
            device.create_pipeline_layout(
                &vk::PipelineLayoutCreateInfo::default().set_layouts(&layouts).push_constant_ranges(&push_ranges),
                None,
            )
        }
        .map_err(GpuError::vk("create the pipeline layout"))?;
        let pool_sizes = [
            vk::DescriptorPoolSize { ty: vk::DescriptorType::UNIFORM_BUFFER, descriptor_count: 1 },
            vk::DescriptorPoolSize { ty: vk::DescriptorType::STORAGE_BUFFER, descriptor_count: binding::COUNT - 1 },
        ];
        // SAFETY: the device is alive: the renderer holds an `Arc` of its `Context`, which destroys the device only
        // after every owner is gone; the pool is destroyed in `Drop`, after the queue is idle (which frees its set).
        let descriptor_pool = unsafe {
            device.create_descriptor_pool(
                &vk::DescriptorPoolCreateInfo::default().max_sets(1).pool_sizes(&pool_sizes),
                None,
            )
        }
        .map_err(GpuError::vk("create the descriptor pool"))?;
        // SAFETY: the pool was just created with `max_sets(1)` and room for every binding of `set_layout`, so one
        // allocation fits.
        let set = unsafe {
            device.allocate_descriptor_sets(
                &vk::DescriptorSetAllocateInfo::default().descriptor_pool(descriptor_pool).set_layouts(&layouts),
            )
        }
        .map_err(GpuError::vk("allocate the descriptor set"))?[0];

        let raster_pipeline = create_raster_pipeline(&ctx, render_pass, pipeline_layout)?;
        let mut pipelines = Vec::new();
        for spv in PASS_SHADERS {
            pipelines.push(create_compute_pipeline(&ctx, pipeline_layout, spv)?);
        }

        // SAFETY: the device is alive: the renderer holds an `Arc` of its `Context`, which destroys the device only
        // after every owner is gone; the pool uses the context's queue family and is destroyed in `Drop`.
        let command_pool = unsafe {
            device.create_command_pool(
                &vk::CommandPoolCreateInfo::default()
                    .queue_family_index(ctx.queue_family())
                    .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER),
                None,
            )
        }
        .map_err(GpuError::vk("create a command pool"))?;
        // SAFETY: the pool was just created on this device; its one buffer is only recorded by `&mut self` methods
        // (one thread).
        let command_buffer = unsafe {
            device.allocate_command_buffers(
                &vk::CommandBufferAllocateInfo::default()
                    .command_pool(command_pool)
                    .level(vk::CommandBufferLevel::PRIMARY)
                    .command_buffer_count(1),
            )
        }
        .map_err(GpuError::vk("allocate a command buffer"))?[0];
        // SAFETY: the device is alive: the renderer holds an `Arc` of its `Context`, which destroys the device only
        // after every owner is gone; the fence is unsignalled, waited for after every submission, and destroyed in
        // `Drop`.
        let fence = unsafe { device.create_fence(&vk::FenceCreateInfo::default(), None) }
            .map_err(GpuError::vk("create a fence"))?;

        let v4 = px * 16;
        let levels = pyramid_levels(w, h);
        let pyramid_texels = levels.last().map_or(0, |&(o, lw, lh)| o + lw * lh);
        let frame =
            Buffer::new(&ctx, std::mem::size_of::<FrameUniforms>() as u64, vk::BufferUsageFlags::UNIFORM_BUFFER)?;
        let mut renderer = Self {
            width: w,
            height: h,
            render_pass,
            framebuffer,
            geometry_image,
            color_image,
            _depth_image: depth_image,
            raster_pipeline,
            set_layout,
            pipeline_layout,
            descriptor_pool,
            set,
            pipelines,
            frame,
            geometry: storage(&ctx, v4)?,
            color: storage(&ctx, v4)?,
            flow: storage(&ctx, v4)?,
            person: storage(&ctx, v4)?,
            prev_person: storage(&ctx, v4)?,
            prev_geometry: storage(&ctx, v4)?,
            source_color: storage(&ctx, 16)?,
            source_geometry: storage(&ctx, 16)?,
            env: storage(&ctx, 16)?,
            out: storage(&ctx, v4)?,
            source_features: storage(&ctx, 16)?,
            warped_features: storage(&ctx, 16)?,
            encoded: storage(&ctx, px * 4)?,
            current: storage(&ctx, v4)?,
            pyramid: storage(&ctx, u64::from(pyramid_texels) * 16)?,
            overlay: storage(&ctx, px.div_ceil(4) * 4)?,
            levels,
            mesh: None,
            env_size: (0, 0),
            env_yaw: 0.0,
            source_size: (0, 0),
            feature_shape: None,
            fill: OcclusionFill::default(),
            fusion: false,
            previous: None,
            last_fused_input: None,
            dirty: true,
            uniforms: FrameUniforms { params: [0.0, 0.0, VISIBILITY_LAMBDA, 0.0], ..Default::default() },
            command_pool,
            command_buffer,
            fence,
            timer: None,
            counters: RendererCounters {
                resources_created: 20,
                pipelines_created: PASS_SHADERS.len() as u64 + 1,
                ..Default::default()
            },
            ctx,
        };
        renderer.timer = StageTimer::new(&renderer.ctx)?;
        renderer.write_all_descriptors();
        Ok(renderer)
    }

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

    /// Sets the text overlay blended into presented images (`None` removes it). Upload only when the text
    /// changes: the mask is copied into a buffer made at creation (no allocation). The overlay is cut to the
    /// renderer's size and never appears in [`Renderer::read_output`].
    pub fn set_overlay(&mut self, mask: Option<&OverlayMask>) {
        let Some(m) = mask.filter(|m| !m.is_empty()) else {
            self.uniforms.output_format[2] = 0;
            self.uniforms.output_format[3] = 0;
            return;
        };
        let (w, h) = (m.width.min(self.width as usize), m.height.min(self.height as usize));
        if w == m.width {
            self.overlay.write(&m.data[..w * h]);
        } else {
            let mut packed = Vec::with_capacity(w * h);
            for row in m.data.chunks(m.width).take(h) {
                packed.extend_from_slice(&row[..w]);
            }
            self.overlay.write(&packed);
        }
        self.uniforms.output_format[2] = w as u32;
        self.uniforms.output_format[3] = h as u32;
    }

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

    /// The output buffer (`vec4` per pixel, row-major, linear; VR: RGB and 1, AR: premultiplied RGBA) of the last
    /// frame, for copies into images owned elsewhere (e.g. OpenXR swapchains). It is never reallocated; it is
    /// rewritten by the next frame, so such copies must finish before the renderer is used again.
    pub fn output_buffer(&self) -> vk::Buffer {
        self.out.buffer
    }

    fn write_all_descriptors(&mut self) {
        let buffers: [(u32, &Buffer); binding::COUNT as usize] = [
            (binding::FRAME, &self.frame),
            (binding::GEOMETRY, &self.geometry),
            (binding::COLOR, &self.color),
            (binding::FLOW, &self.flow),
            (binding::PERSON, &self.person),
            (binding::PREV_PERSON, &self.prev_person),
            (binding::PREV_GEOMETRY, &self.prev_geometry),
            (binding::SOURCE_COLOR, &self.source_color),
            (binding::SOURCE_GEOMETRY, &self.source_geometry),
            (binding::ENV, &self.env),
            (binding::OUT, &self.out),
            (binding::SOURCE_FEATURES, &self.source_features),
            (binding::WARPED_FEATURES, &self.warped_features),
            (binding::ENCODED, &self.encoded),
            (binding::CURRENT, &self.current),
            (binding::PYRAMID, &self.pyramid),
            (binding::OVERLAY, &self.overlay),
        ];
        let infos: Vec<[vk::DescriptorBufferInfo; 1]> = buffers
            .iter()
            .map(|(_, b)| [vk::DescriptorBufferInfo { buffer: b.buffer, offset: 0, range: vk::WHOLE_SIZE }])
            .collect();
        let writes: Vec<vk::WriteDescriptorSet> = buffers
            .iter()
            .zip(&infos)
            .map(|((b, _), info)| {
                vk::WriteDescriptorSet::default()
                    .dst_set(self.set)
                    .dst_binding(*b)
                    .descriptor_type(if *b == binding::FRAME {
                        vk::DescriptorType::UNIFORM_BUFFER
                    } else {
                        vk::DescriptorType::STORAGE_BUFFER
                    })
                    .buffer_info(info)
            })
            .collect();
        // SAFETY: no submission is in flight (every frame waits on its fence before returning).
        unsafe { self.ctx.device().update_descriptor_sets(&writes, &[]) };
    }

    /// Uploads the mesh (once per mesh; frames re-render it for any camera without re-uploading). Buffers are
    /// reused when the new mesh fits in them.
    pub fn set_mesh(&mut self, mesh: &TriMesh) -> Result<(), GpuError> {
        mesh.validate()?;
        let n = mesh.positions.len();
        let normals: Vec<[f32; 3]> = if mesh.normals.len() == n {
            mesh.normals.iter().map(|v| v.to_array()).collect()
        } else {
            let mut m = mesh.clone();
            m.compute_normals();
            m.normals.iter().map(|v| v.to_array()).collect()
        };
        let has_colors = mesh.colors.len() == n && n > 0;
        let colors: Vec<[f32; 3]> =
            if has_colors { mesh.colors.iter().map(|v| v.to_array()).collect() } else { vec![[0.0; 3]; n] };
        let positions: Vec<[f32; 3]> = mesh.positions.iter().map(|v| v.to_array()).collect();
        let indices: Vec<u32> = mesh.triangles.iter().flatten().copied().collect();
        let vbytes = (n * 12) as u64;
        let ibytes = (indices.len() * 4) as u64;
        let reuse = self.mesh.as_ref().is_some_and(|m| m.positions.size >= vbytes && m.indices.size >= ibytes);
        if !reuse {
            self.mesh = None;
            let vusage = vk::BufferUsageFlags::VERTEX_BUFFER;
            self.mesh = Some(GpuMesh {
                positions: Buffer::new(&self.ctx, vbytes, vusage)?,
                normals: Buffer::new(&self.ctx, vbytes, vusage)?,
                colors: Buffer::new(&self.ctx, vbytes, vusage)?,
                indices: Buffer::new(&self.ctx, ibytes, vk::BufferUsageFlags::INDEX_BUFFER)?,
                index_count: 0,
                bounds: (Vec3::ZERO, Vec3::ZERO),
                has_colors: false,
            });
            self.counters.resources_created += 4;
        }
        let m = self.mesh.as_mut().expect("the mesh buffers were just ensured");
        m.positions.write(&positions);
        m.normals.write(&normals);
        m.colors.write(&colors);
        m.indices.write(&indices);
        m.index_count = indices.len() as u32;
        m.bounds = mesh.bounds().unwrap_or((Vec3::ZERO, Vec3::ZERO));
        m.has_colors = has_colors;
        self.counters.mesh_uploads += 1;
        self.dirty = true;
        self.previous = None;
        Ok(())
    }

    /// Uploads the panorama for VR compositing (as half floats; relative error below 2^-11).
    pub fn set_environment(&mut self, env: &Environment) -> Result<(), GpuError> {
        let img = &env.image;
        if img.width < 2 || img.height < 1 || img.data.len() != img.width * img.height {
            return Err(GpuError::Invalid(format!("panorama of {}x{} is too small", img.width, img.height)));
        }
        let bytes = (img.width * img.height * 8) as u64;
        if self.env.size < bytes {
            self.env = storage(&self.ctx, bytes)?;
            self.counters.resources_created += 1;
            self.write_all_descriptors();
        }
        let packed: Vec<[u32; 2]> = img
            .data
            .iter()
            .map(|c| {
                let c = if c.is_finite() { c.max(Vec3::ZERO) } else { Vec3::ZERO };
                [pack_half2(c.x, c.y), pack_half2(c.z, 0.0)]
            })
            .collect();
        self.env.write(&packed);
        self.env_size = (img.width as u32, img.height as u32);
        self.env_yaw = env.yaw;
        Ok(())
    }

    /// Uploads the source view (once per input): its premultiplied linear RGB (mask in alpha), its G-buffer
    /// (depth and normals of the mesh seen by the source camera) and the source camera, all of one size.
    pub fn set_source(&mut self, color: &RgbaImage, gbuffer: &GBuffer, camera: &Camera) -> Result<(), GpuError> {
        let (w, h) = (camera.width, camera.height);
        if w == 0 || h == 0 || (color.width, color.height) != (w, h) || (gbuffer.width, gbuffer.height) != (w, h) {
            return Err(GpuError::Invalid(format!(
                "source image {}x{}, G-buffer {}x{} and camera {w}x{h} must have one size",
                color.width, color.height, gbuffer.width, gbuffer.height
            )));
        }
        let bytes = (w * h * 16) as u64;
        if self.source_color.size < bytes || self.source_geometry.size < bytes {
            self.source_color = storage(&self.ctx, bytes)?;
            self.source_geometry = storage(&self.ctx, bytes)?;
            self.counters.resources_created += 2;
            self.write_all_descriptors();
        }
        self.source_color.write(&color.data);
        self.source_geometry.write(&pack_geometry(gbuffer));
        self.source_size = (w as u32, h as u32);
        self.counters.source_uploads += 1;
        self.uniforms.source = gpu_camera(camera, None);
        self.uniforms.sizes[2] = w as u32;
        self.uniforms.sizes[3] = h as u32;
        self.uniforms.mean_color = mean_masked(color).extend(0.0).to_array();
        self.dirty = true;
        self.previous = None;
        Ok(())
    }

    /// Flow, Z-map (paper Eq. 4) and visibility (Eq. 9, [`VISIBILITY_LAMBDA`]) of a given target G-buffer
    /// rendered by `camera`, against the uploaded source: the GPU version of `geometry::zmap::flow_and_zmap`
    /// followed by `geometry::zmap::visibility`.
    pub fn flow_and_zmap(&mut self, target: &GBuffer, camera: &Camera) -> Result<(FlowZ, Vec<bool>), GpuError> {
        self.check_camera(camera)?;
        self.check_image(target.width, target.height)?;
        self.require_source()?;
        self.upload_target(target);
        self.set_target(camera);
        self.run(&[Step::Compute(Pass::Flow)], None)?;
        Ok(self.read_flow())
    }

    /// How occluded pixels are coloured (as the CPU warp's [`OcclusionFill`]).
    pub fn set_fill(&mut self, fill: OcclusionFill) {
        if fill != self.fill {
            self.fill = fill;
            self.dirty = true;
        }
    }

    /// Turns spatial fusion (Eq. 8) between consecutive frames on or off (off forgets the previous frame).
    pub fn set_fusion(&mut self, on: bool) {
        self.fusion = on;
        if !on {
            self.previous = None;
        }
    }

    /// Uploads encoder features (`channels x height x width`, row-major planes, usually 1/4 of the source
    /// resolution) for [`Renderer::warp_features`]; once per input frame.
    pub fn set_features(
        &mut self,
        features: &[f32],
        channels: usize,
        width: usize,
        height: usize,
    ) -> Result<(), GpuError> {
        let n = channels * width * height;
        if n == 0 || features.len() != n {
            return Err(GpuError::Invalid(format!(
                "features of {} values do not match {channels}x{height}x{width}",
                features.len()
            )));
        }
        let (tw, th) = self.size();
        let out_bytes = (channels * tw * th * 4) as u64;
        if self.source_features.size < (n * 4) as u64 || self.warped_features.size < out_bytes {
            self.source_features = storage(&self.ctx, (n * 4) as u64)?;
            self.warped_features = storage(&self.ctx, out_bytes)?;
            self.counters.resources_created += 2;
            self.write_all_descriptors();
        }
        self.source_features.write(features);
        self.feature_shape = Some((channels as u32, width as u32, height as u32));
        Ok(())
    }

    /// The warped features of the last [`Renderer::warp_features`] call: `channels x H x W`, zero outside the
    /// flow mask — the decoder's input, read straight from host-visible memory (the ONNX seam).
    pub fn warped_features(&self) -> &[f32] {
        let (tw, th) = self.size();
        let c = self.feature_shape.map_or(0, |s| s.0 as usize);
        let bytes = self.warped_features.bytes();
        let n = (c * tw * th).min(bytes.len() / 4);
        // SAFETY: the mapping is 4-byte aligned (Vulkan maps at least at 64-byte alignment) and holds f32s.
        unsafe { std::slice::from_raw_parts(bytes.as_ptr().cast::<f32>(), n) }
    }

    /// Warps the uploaded features by the given flow (the GPU version of `pipeline::warp::warp_features` with
    /// the source resolution of the uploaded source view). The result is in [`Renderer::warped_features`].
    pub fn warp_features(&mut self, flowz: &FlowZ) -> Result<(), GpuError> {
        self.check_image(flowz.flow.width, flowz.flow.height)?;
        self.require_source()?;
        let Some((c, fw, fh)) = self.feature_shape else {
            return Err(GpuError::Invalid("no features were uploaded (set_features)".into()));
        };
        self.upload_flow(flowz, None);
        self.uniforms.flags[1] = c;
        self.uniforms.flags[2] = fw;
        self.uniforms.flags[3] = fh;
        self.run(&[Step::Compute(Pass::Features)], None)
    }

    /// The geometric warp of a given target G-buffer with a given flow and visibility (the GPU version of
    /// `pipeline::warp::render_from_flow` with the uploaded source and the current fill).
    pub fn warp_from_flow(
        &mut self,
        target: &GBuffer,
        flowz: &FlowZ,
        visible: &[bool],
        camera: &Camera,
    ) -> Result<RgbaImage, GpuError> {
        self.check_camera(camera)?;
        self.check_image(target.width, target.height)?;
        self.check_image(flowz.flow.width, flowz.flow.height)?;
        self.require_source()?;
        self.upload_target(target);
        self.upload_flow(flowz, Some(visible));
        self.set_target(camera);
        self.run(&[Step::Compute(Pass::Warp), Step::HoleFill], None)?;
        Ok(self.read_rgba(&self.current))
    }

    /// Spatial fusion of a given rendering with the previous one (the GPU version of
    /// `pipeline::fusion::SpatialFusion::fuse`, including its rules for an unmoved view).
    pub fn fuse(&mut self, current: &RgbaImage, gbuffer: &GBuffer, camera: &Camera) -> Result<RgbaImage, GpuError> {
        self.check_camera(camera)?;
        self.check_image(current.width, current.height)?;
        self.check_image(gbuffer.width, gbuffer.height)?;
        if self.previous == Some(*camera) {
            if self.last_fused_input.as_ref() == Some(current) {
                return Ok(self.read_rgba(&self.prev_person));
            }
            // Unmoved view, new input: remember it unfused.
            self.uniforms.flags[0] = 0;
        } else {
            self.uniforms.flags[0] = u32::from(self.previous.is_some());
        }
        self.current.write(&current.data);
        self.upload_target(gbuffer);
        self.set_target(camera);
        self.set_previous_uniform();
        self.uniforms.params[1] = previous_weight(camera.angle_from_source());
        self.run(&[Step::Compute(Pass::Fusion), Step::SavePrevious], None)?;
        self.previous = Some(*camera);
        self.last_fused_input = Some(current.clone());
        Ok(self.read_rgba(&self.person))
    }

    /// The person alone for `camera` (premultiplied linear RGBA): raster -> flow/Z-map/visibility -> warp ->
    /// hole fill -> spatial fusion (when on), all on the GPU; the GPU version of `ViewRenderer::render_person`.
    pub fn render_person(&mut self, camera: &Camera) -> Result<RgbaImage, GpuError> {
        self.render(camera, None, None)?;
        Ok(self.read_rgba(&self.person))
    }

    /// Renders a finished frame for `camera`: the person, then the panorama composite (VR) or the alpha layer
    /// (AR; no panorama work). With `present`, the frame is also encoded and copied into the swapchain image.
    /// Read it back with [`Renderer::read_output`]. An unmoved camera with unchanged inputs reuses the last
    /// person layer (no per-view work).
    pub fn render_frame(
        &mut self,
        camera: &Camera,
        mode: Mode,
        present: Option<PresentTarget>,
    ) -> Result<(), GpuError> {
        self.render(camera, Some(mode), present)
    }

    /// The neural decoder's seam, first half: rasterises the uploaded mesh for `camera` and computes flow, Z-map
    /// and visibility on the GPU in one submission, then reads the target G-buffer and the flow back into host
    /// memory, where the decoder (ONNX Runtime) takes them. Follow it with [`Renderer::render_frame_from_person`]
    /// for the same camera: the target geometry stays on the GPU for spatial fusion.
    pub fn neural_inputs(&mut self, camera: &Camera) -> Result<(GBuffer, FlowZ), GpuError> {
        self.check_camera(camera)?;
        self.require_source()?;
        self.set_target(camera);
        self.run(&[Step::Raster, Step::Compute(Pass::Flow)], None)?;
        // The person layer on the GPU no longer matches its camera until the host result comes back.
        self.dirty = true;
        Ok((self.read_gbuffer(), self.read_flow().0))
    }

    /// The neural decoder's seam, second half: takes a person layer computed on the host for `camera`
    /// (premultiplied linear RGBA of the renderer's size, e.g. the decoder's output) and finishes the frame on the
    /// GPU as [`Renderer::render_frame`] does: spatial fusion with the previous frame (when on; it needs the target
    /// geometry of [`Renderer::neural_inputs`] for the same camera), the panorama composite (VR) or the alpha
    /// layer (AR), and with `present` the encode and the copy into the swapchain image. `None` reuses the last
    /// person layer (same camera and input: no decoder run needed). Read the frame with [`Renderer::read_output`].
    pub fn render_frame_from_person(
        &mut self,
        person: Option<&RgbaImage>,
        camera: &Camera,
        mode: Mode,
        present: Option<PresentTarget>,
    ) -> Result<(), GpuError> {
        self.check_camera(camera)?;
        if mode == Mode::Vr && self.env_size.0 == 0 {
            return Err(GpuError::Invalid("no panorama was uploaded (set_environment)".into()));
        }
        self.set_target(camera);
        self.uniforms.output_format[1] = u32::from(mode == Mode::Ar);
        self.set_previous_uniform();
        let compose = Step::Compute(if mode == Mode::Vr { Pass::Panorama } else { Pass::Ar });
        match person {
            Some(person) => {
                self.check_image(person.width, person.height)?;
                self.current.write(&person.data);
                let fuse = self.fusion && self.previous.is_some_and(|p| p != *camera);
                self.uniforms.flags[0] = u32::from(fuse);
                self.uniforms.params[1] = if fuse { previous_weight(camera.angle_from_source()) } else { 0.0 };
                self.run(&[Step::Compute(Pass::Fusion), Step::SavePrevious, compose], present)?;
                self.previous = Some(*camera);
            }
            None => {
                if self.previous.is_none() {
                    return Err(GpuError::Invalid("no person layer to reuse: give one first".into()));
                }
                self.run(&[Step::CopyPreviousToPerson, compose], present)?;
            }
        }
        self.counters.frames += 1;
        // The geometric path must not mistake this layer for its own cached one.
        self.dirty = true;
        Ok(())
    }

    fn render(&mut self, camera: &Camera, mode: Option<Mode>, present: Option<PresentTarget>) -> Result<(), GpuError> {
        self.check_camera(camera)?;
        self.require_source()?;
        if mode == Some(Mode::Vr) && self.env_size.0 == 0 {
            return Err(GpuError::Invalid("no panorama was uploaded (set_environment)".into()));
        }
        self.set_target(camera);
        self.uniforms.output_format[1] = u32::from(mode == Some(Mode::Ar));
        self.set_previous_uniform();
        let unchanged = !self.dirty && self.previous == Some(*camera);
        // A fixed-size step list: a frame allocates nothing on the host either.
        let mut steps = [Step::Raster; 7];
        let mut n = 0;
        if unchanged {
            // Same view, same inputs: the person layer of the last frame stands (fusion would return it too).
            steps[0] = Step::CopyPreviousToPerson;
            n = 1;
        } else {
            let fuse = self.fusion && self.previous.is_some();
            self.uniforms.flags[0] = u32::from(fuse);
            self.uniforms.params[1] = if fuse { previous_weight(camera.angle_from_source()) } else { 0.0 };
            for step in [
                Step::Raster,
                Step::Compute(Pass::Flow),
                Step::Compute(Pass::Warp),
                Step::HoleFill,
                Step::Compute(Pass::Fusion),
                Step::SavePrevious,
            ] {
                steps[n] = step;
                n += 1;
            }
        }
        match mode {
            Some(Mode::Vr) => {
                steps[n] = Step::Compute(Pass::Panorama);
                n += 1;
            }
            Some(Mode::Ar) => {
                steps[n] = Step::Compute(Pass::Ar);
                n += 1;
            }
            None => {}
        }
        self.run(&steps[..n], present)?;
        self.counters.frames += 1;
        self.previous = Some(*camera);
        self.dirty = false;
        Ok(())
    }

    fn set_previous_uniform(&mut self) {
        if let Some(p) = self.previous {
            self.uniforms.previous = gpu_camera(&p, None);
        }
    }

    /// [`Renderer::set_source`] from the pipeline's parts: premultiplied linear RGB and its mask.
    pub fn set_source_parts(
        &mut self,
        rgb: &RgbImage,
        mask: &crate::buffer::GrayImage,
        gbuffer: &GBuffer,
        camera: &Camera,
    ) -> Result<(), GpuError> {
        if (rgb.width, rgb.height) != (mask.width, mask.height) {
            return Err(GpuError::Invalid("source colour and mask differ in size".into()));
        }
        let color = Image {
            width: rgb.width,
            height: rgb.height,
            data: rgb.data.iter().zip(&mask.data).map(|(c, m)| c.extend(*m)).collect(),
        };
        self.set_source(&color, gbuffer, camera)
    }

    /// Uploads what the person renderers draw from: the mesh and the source view (colour, mask, G-buffer,
    /// camera). Call once per input frame.
    pub fn set_scene(&mut self, source: &SourceView<'_>) -> Result<(), GpuError> {
        self.set_mesh(source.mesh)?;
        self.set_source_parts(source.rgb, source.mask, source.gbuffer, source.camera)
    }

    fn upload_flow(&mut self, flowz: &FlowZ, visible: Option<&[bool]>) {
        let data: Vec<Vec4> = (0..flowz.mask.len())
            .map(|i| {
                if flowz.mask[i] {
                    let f = flowz.flow.data[i];
                    let vis = visible.is_some_and(|v| v.get(i).copied().unwrap_or(false));
                    Vec4::new(f.x, f.y, flowz.z.data[i], if vis { 2.0 } else { 1.0 })
                } else {
                    Vec4::new(FLOW_OUTSIDE.x, FLOW_OUTSIDE.y, 0.0, 0.0)
                }
            })
            .collect();
        self.flow.write(&data);
    }

    fn require_source(&self) -> Result<(), GpuError> {
        if self.source_size.0 == 0 {
            return Err(GpuError::Invalid("no source view was uploaded (set_source)".into()));
        }
        Ok(())
    }

    fn upload_target(&mut self, target: &GBuffer) {
        self.geometry.write(&pack_geometry(target));
        let colors: Vec<Vec4> = (0..target.mask.len())
            .map(|i| {
                let c = target.color.as_ref().map_or(Vec3::ZERO, |c| c[i]);
                c.extend(if target.mask[i] { 1.0 } else { 0.0 })
            })
            .collect();
        self.color.write(&colors);
    }

    fn read_flow(&self) -> (FlowZ, Vec<bool>) {
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

    /// Rasterises the uploaded mesh for `camera` (of the renderer's size) and reads the G-buffer back: the GPU
    /// version of `geometry::raster::rasterize`.
    pub fn rasterize(&mut self, camera: &Camera) -> Result<GBuffer, GpuError> {
        self.check_camera(camera)?;
        self.set_target(camera);
        self.run(&[Step::Raster], None)?;
        Ok(self.read_gbuffer())
    }

    /// VR composite of a given person layer (premultiplied linear RGBA of the renderer's size) over the
    /// panorama, for the view `camera`: the GPU version of `compose::compose_vr`.
    pub fn compose_vr(&mut self, person: &RgbaImage, camera: &Camera) -> Result<RgbImage, GpuError> {
        self.check_camera(camera)?;
        self.check_image(person.width, person.height)?;
        if self.env_size.0 == 0 {
            return Err(GpuError::Invalid("no panorama was uploaded (set_environment)".into()));
        }
        self.person.write(&person.data);
        self.set_target(camera);
        self.run(&[Step::Compute(Pass::Panorama)], None)?;
        Ok(self.read_rgb(&self.out))
    }

    /// AR layer of a given person layer: the GPU version of `compose::compose_ar`.
    pub fn compose_ar(&mut self, person: &RgbaImage) -> Result<RgbaImage, GpuError> {
        self.check_image(person.width, person.height)?;
        self.person.write(&person.data);
        self.run(&[Step::Compute(Pass::Ar)], None)?;
        Ok(self.read_rgba(&self.out))
    }

    /// Shows a frame rendered elsewhere (e.g. by the CPU reference) in a window: uploads it as the output, encodes
    /// it to 8-bit sRGB and copies it into the swapchain image of `target` (AR layers are shown over grey).
    pub fn present_frame(&mut self, frame: &RenderedFrame, target: PresentTarget) -> Result<(), GpuError> {
        match frame {
            RenderedFrame::Vr(img) => {
                self.check_image(img.width, img.height)?;
                let data: Vec<Vec4> = img.data.iter().map(|c| c.extend(1.0)).collect();
                self.out.write(&data);
                self.uniforms.output_format[1] = 0;
            }
            RenderedFrame::Ar(img) => {
                self.check_image(img.width, img.height)?;
                self.out.write(&img.data);
                self.uniforms.output_format[1] = 1;
            }
        }
        self.run(&[], Some(target))
    }

    /// Reads the current output back (the last frame rendered or presented), e.g. for a screenshot.
    pub fn read_output(&self, mode: Mode) -> RenderedFrame {
        match mode {
            Mode::Vr => RenderedFrame::Vr(self.read_rgb(&self.out)),
            Mode::Ar => RenderedFrame::Ar(self.read_rgba(&self.out)),
        }
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

    fn set_target(&mut self, camera: &Camera) {
        let bounds = self.mesh.as_ref().map(|m| m.bounds);
        self.uniforms.target = gpu_camera(camera, bounds);
        self.uniforms.viewer = gpu_camera(&background_camera(camera), None);
        self.uniforms.params[0] = self.env_yaw;
        self.uniforms.params[3] = if self.fill == OcclusionFill::Propagate { 1.0 } else { 0.0 };
        self.uniforms.sizes[0] = self.env_size.0;
        self.uniforms.sizes[1] = self.env_size.1;
    }

    /// Records `steps`, submits, and waits for completion.
    fn run(&mut self, steps: &[Step], present: Option<PresentTarget>) -> Result<(), GpuError> {
        if let Some(p) = present {
            self.uniforms.output_format[0] = u32::from(p.bgra);
        }
        // Every pass sizes its dispatch from the target camera's image size, which is the renderer's.
        self.uniforms.target.info[1] = self.width as f32;
        self.uniforms.target.info[2] = self.height as f32;
        self.frame.write(std::slice::from_ref(&self.uniforms));
        let device = self.ctx.device();
        let cb = self.command_buffer;
        // SAFETY: `&mut self` makes this the only recording of `cb`; the previous `run` waited for its submission on
        // the fence (or reported the device lost), so the buffer may be reset; every bound set, pipeline, buffer and
        // image belongs to this renderer and outlives the submission, which is waited for below; the queue is used
        // under its lock.
        unsafe {
            device
                .reset_command_buffer(cb, vk::CommandBufferResetFlags::empty())
                .map_err(GpuError::vk("reset the command buffer"))?;
            device
                .begin_command_buffer(
                    cb,
                    &vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT),
                )
                .map_err(GpuError::vk("begin the command buffer"))?;
            if let Some(t) = &self.timer {
                device.cmd_reset_query_pool(cb, t.pool, 0, TIMESTAMPS);
                device.cmd_write_timestamp(cb, vk::PipelineStageFlags::TOP_OF_PIPE, t.pool, 0);
            }
            device.cmd_bind_descriptor_sets(
                cb,
                vk::PipelineBindPoint::COMPUTE,
                self.pipeline_layout,
                0,
                &[self.set],
                &[],
            );
            for (i, step) in steps.iter().enumerate() {
                if i > 0 {
                    self.barrier(cb);
                }
                // Host writes before the submission are visible to it; no barrier before the first step.
                match step {
                    Step::Raster => self.record_raster(cb),
                    Step::Compute(pass) => {
                        device.cmd_bind_pipeline(cb, vk::PipelineBindPoint::COMPUTE, self.pipelines[*pass as usize]);
                        device.cmd_dispatch(cb, self.width.div_ceil(WORKGROUP), self.height.div_ceil(WORKGROUP), 1);
                    }
                    Step::HoleFill => self.record_hole_fill(cb),
                    Step::CopyPreviousToPerson => {
                        let bytes = u64::from(self.width) * u64::from(self.height) * 16;
                        let region = [vk::BufferCopy { src_offset: 0, dst_offset: 0, size: bytes }];
                        device.cmd_copy_buffer(cb, self.prev_person.buffer, self.person.buffer, &region);
                    }
                    Step::SavePrevious => {
                        let bytes = u64::from(self.width) * u64::from(self.height) * 16;
                        let region = [vk::BufferCopy { src_offset: 0, dst_offset: 0, size: bytes }];
                        device.cmd_copy_buffer(cb, self.person.buffer, self.prev_person.buffer, &region);
                        device.cmd_copy_buffer(cb, self.geometry.buffer, self.prev_geometry.buffer, &region);
                    }
                }
                if let Some(t) = self.timer.as_ref().filter(|_| i + 1 < TIMESTAMPS as usize) {
                    device.cmd_write_timestamp(cb, vk::PipelineStageFlags::BOTTOM_OF_PIPE, t.pool, i as u32 + 1);
                }
            }
            if let Some(p) = present {
                if !steps.is_empty() {
                    self.barrier(cb);
                }
                device.cmd_bind_pipeline(cb, vk::PipelineBindPoint::COMPUTE, self.pipelines[Pass::Encode as usize]);
                device.cmd_dispatch(cb, self.width.div_ceil(WORKGROUP), self.height.div_ceil(WORKGROUP), 1);
                self.record_present_copy(cb, p.image);
            }
            device.end_command_buffer(cb).map_err(GpuError::vk("end the command buffer"))?;
            let cbs = [cb];
            let waits = present.map(|p| [p.wait]);
            let signals = present.map(|p| [p.signal]);
            let stages = [vk::PipelineStageFlags::TRANSFER];
            let count = usize::from(present.is_some());
            let submit = vk::SubmitInfo::default()
                .command_buffers(&cbs)
                .wait_semaphores(waits.as_ref().map_or(&[], |w| &w[..]))
                .wait_dst_stage_mask(&stages[..count])
                .signal_semaphores(signals.as_ref().map_or(&[], |s| &s[..]));
            {
                let _queue = self.ctx.lock_queue();
                device.queue_submit(self.ctx.queue(), &[submit], self.fence).map_err(GpuError::vk("submit a frame"))?;
            }
            let waited = device.wait_for_fences(&[self.fence], true, 10_000_000_000);
            device.reset_fences(&[self.fence]).map_err(GpuError::vk("reset the frame fence"))?;
            match waited {
                Ok(()) => {}
                Err(vk::Result::TIMEOUT) => return Err(GpuError::DeviceLost),
                Err(e) => return Err(GpuError::vk("wait for a frame")(e)),
            }
        }
        self.read_timestamps(steps);
        Ok(())
    }

    /// Reads this submission's timestamps into the per-step durations (no allocation: fixed arrays).
    fn read_timestamps(&mut self, steps: &[Step]) {
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

    /// A full memory barrier between passes (compute/transfer/attachment writes before any later read/write).
    ///
    /// # Safety
    /// `cb` is this renderer's command buffer, in the recording state.
    unsafe fn barrier(&self, cb: vk::CommandBuffer) {
        let barrier = vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE)
            .dst_access_mask(
                vk::AccessFlags::SHADER_READ
                    | vk::AccessFlags::SHADER_WRITE
                    | vk::AccessFlags::TRANSFER_READ
                    | vk::AccessFlags::TRANSFER_WRITE,
            );
        // SAFETY: the caller is recording `cb` (see `barrier`'s contract); a global memory barrier names no resource.
        unsafe {
            self.ctx.device().cmd_pipeline_barrier(
                cb,
                vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER,
                vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER,
                vk::DependencyFlags::empty(),
                &[barrier],
                &[],
                &[],
            )
        };
    }

    /// Records the push-pull hole fill over the renderer's pyramid levels.
    ///
    /// # Safety
    /// `cb` is this renderer's command buffer, recording outside a render pass, with its descriptor set bound.
    unsafe fn record_hole_fill(&self, cb: vk::CommandBuffer) {
        let device = self.ctx.device();
        let top = self.levels.last().map_or(0, |l| l.0);
        let constants = |src: (u32, u32, u32), dst: (u32, u32, u32)| LevelConstants {
            src_offset: src.0,
            src_width: src.1,
            src_height: src.2,
            dst_offset: dst.0,
            dst_width: dst.1,
            dst_height: dst.2,
            top_offset: top,
            pad: 0,
        };
        // SAFETY: the closure runs only inside `record_hole_fill`, whose caller is recording `cb`; the pipelines,
        // layout and push-constant range belong to this renderer and `c` matches the `LevelConstants` range size.
        let dispatch = |pass: Pass, c: LevelConstants, first: bool| unsafe {
            if !first {
                self.barrier(cb);
            }
            device.cmd_bind_pipeline(cb, vk::PipelineBindPoint::COMPUTE, self.pipelines[pass as usize]);
            let bytes = std::slice::from_raw_parts(
                (&c as *const LevelConstants).cast::<u8>(),
                std::mem::size_of::<LevelConstants>(),
            );
            device.cmd_push_constants(cb, self.pipeline_layout, vk::ShaderStageFlags::COMPUTE, 0, bytes);
            device.cmd_dispatch(cb, c.dst_width.div_ceil(WORKGROUP), c.dst_height.div_ceil(WORKGROUP), 1);
        };
        let n = self.levels.len();
        let mut first = true;
        for k in 1..n {
            dispatch(Pass::Pull, constants(self.levels[k - 1], self.levels[k]), first);
            first = false;
        }
        for k in (0..n.saturating_sub(1)).rev() {
            dispatch(Pass::Push, constants(self.levels[k + 1], self.levels[k]), first);
            first = false;
        }
        dispatch(Pass::Resolve, constants(self.levels[0], self.levels[0]), first);
    }

    /// Records the target raster (the render pass over the geometry image and depth) of the uploaded mesh.
    ///
    /// # Safety
    /// `cb` is this renderer's command buffer, recording outside a render pass.
    unsafe fn record_raster(&self, cb: vk::CommandBuffer) {
        let device = self.ctx.device();
        let clear = [
            vk::ClearValue { color: vk::ClearColorValue { float32: [0.0, 0.0, 0.0, BACKGROUND_DEPTH] } },
            vk::ClearValue { color: vk::ClearColorValue { float32: [0.0; 4] } },
            vk::ClearValue { depth_stencil: vk::ClearDepthStencilValue { depth: 0.0, stencil: 0 } },
        ];
        let area = vk::Rect2D { offset: vk::Offset2D::default(), extent: self.geometry_image.extent };
        let begin = vk::RenderPassBeginInfo::default()
            .render_pass(self.render_pass)
            .framebuffer(self.framebuffer)
            .render_area(area)
            .clear_values(&clear);
        // SAFETY: the caller is recording `cb` outside any render pass; the render pass, framebuffer, pipeline and
        // the mesh's vertex/index buffers belong to this renderer and live until the submission is waited for;
        // `index_count` is the index buffer's length.
        unsafe {
            device.cmd_begin_render_pass(cb, &begin, vk::SubpassContents::INLINE);
            if let Some(mesh) = self.mesh.as_ref().filter(|m| m.index_count > 0) {
                device.cmd_bind_pipeline(cb, vk::PipelineBindPoint::GRAPHICS, self.raster_pipeline);
                device.cmd_bind_descriptor_sets(
                    cb,
                    vk::PipelineBindPoint::GRAPHICS,
                    self.pipeline_layout,
                    0,
                    &[self.set],
                    &[],
                );
                let viewport = vk::Viewport {
                    x: 0.0,
                    y: 0.0,
                    width: self.width as f32,
                    height: self.height as f32,
                    min_depth: 0.0,
                    max_depth: 1.0,
                };
                device.cmd_set_viewport(cb, 0, &[viewport]);
                device.cmd_set_scissor(cb, 0, &[area]);
                device.cmd_bind_vertex_buffers(
                    cb,
                    0,
                    &[mesh.positions.buffer, mesh.normals.buffer, mesh.colors.buffer],
                    &[0, 0, 0],
                );
                device.cmd_bind_index_buffer(cb, mesh.indices.buffer, 0, vk::IndexType::UINT32);
                device.cmd_draw_indexed(cb, mesh.index_count, 1, 0, 0, 0);
            }
            device.cmd_end_render_pass(cb);
            // Attachments (now TRANSFER_SRC_OPTIMAL) into the storage buffers the compute passes read.
            let region = vk::BufferImageCopy::default()
                .image_subresource(vk::ImageSubresourceLayers {
                    aspect_mask: vk::ImageAspectFlags::COLOR,
                    mip_level: 0,
                    base_array_layer: 0,
                    layer_count: 1,
                })
                .image_extent(vk::Extent3D { width: self.width, height: self.height, depth: 1 });
            device.cmd_copy_image_to_buffer(
                cb,
                self.geometry_image.image,
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                self.geometry.buffer,
                &[region],
            );
            device.cmd_copy_image_to_buffer(
                cb,
                self.color_image.image,
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                self.color.buffer,
                &[region],
            );
        }
    }

    /// Records the copy of the encoded output into the swapchain `image` and its hand-over to presentation.
    ///
    /// # Safety
    /// `cb` is recording; `image` is an acquired swapchain image of the renderer's size.
    unsafe fn record_present_copy(&self, cb: vk::CommandBuffer, image: vk::Image) {
        let device = self.ctx.device();
        let encoded_ready = vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::SHADER_WRITE)
            .dst_access_mask(vk::AccessFlags::TRANSFER_READ);
        let region = vk::BufferImageCopy::default()
            .image_subresource(vk::ImageSubresourceLayers {
                aspect_mask: vk::ImageAspectFlags::COLOR,
                mip_level: 0,
                base_array_layer: 0,
                layer_count: 1,
            })
            .image_extent(vk::Extent3D { width: self.width, height: self.height, depth: 1 });
        // SAFETY: as the caller guarantees; the encoded buffer was written by the encode pass recorded before.
        unsafe {
            device.cmd_pipeline_barrier(
                cb,
                vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER,
                vk::PipelineStageFlags::TRANSFER,
                vk::DependencyFlags::empty(),
                &[encoded_ready],
                &[],
                &[present::to_transfer_dst(image)],
            );
            device.cmd_copy_buffer_to_image(
                cb,
                self.encoded.buffer,
                image,
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                &[region],
            );
            present::record_to_present(device, cb, image);
        }
    }

    fn read_vec4(&self, buffer: &Buffer) -> Vec<Vec4> {
        let mut v = vec![Vec4::ZERO; (self.width * self.height) as usize];
        buffer.read(&mut v);
        v
    }

    fn read_rgb(&self, buffer: &Buffer) -> RgbImage {
        let v = self.read_vec4(buffer);
        Image {
            width: self.width as usize,
            height: self.height as usize,
            data: v.iter().map(|p| p.truncate()).collect(),
        }
    }

    fn read_rgba(&self, buffer: &Buffer) -> RgbaImage {
        Image { width: self.width as usize, height: self.height as usize, data: self.read_vec4(buffer) }
    }

    fn read_gbuffer(&self) -> GBuffer {
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

/// One recorded step of a frame.
#[derive(Clone, Copy, Debug)]
enum Step {
    /// Mesh rasterisation into the target G-buffer.
    Raster,
    /// One full-size compute dispatch.
    Compute(Pass),
    /// Push-pull hole filling over the pyramid, then the warp's resolve into `current`.
    HoleFill,
    /// Keep this frame's output and geometry for the next frame's fusion.
    SavePrevious,
    /// Reuse the last person layer (unmoved view, unchanged inputs).
    CopyPreviousToPerson,
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
            device.destroy_fence(self.fence, None);
            device.destroy_command_pool(self.command_pool, None);
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

fn pick_depth_format(ctx: &Context) -> Result<vk::Format, GpuError> {
    for format in [vk::Format::D32_SFLOAT, vk::Format::X8_D24_UNORM_PACK32] {
        // SAFETY: a read-only format query on the context's physical device of its live instance.
        let props = unsafe { ctx.instance().get_physical_device_format_properties(ctx.physical_device(), format) };
        if props.optimal_tiling_features.contains(vk::FormatFeatureFlags::DEPTH_STENCIL_ATTACHMENT) {
            return Ok(format);
        }
    }
    Err(GpuError::NoDevice("the device offers no 32- or 24-bit depth buffer".into()))
}

fn create_render_pass(device: &ash::Device, depth_format: vk::Format) -> Result<vk::RenderPass, GpuError> {
    let color = |_: ()| {
        vk::AttachmentDescription::default()
            .format(GEOMETRY_FORMAT)
            .samples(vk::SampleCountFlags::TYPE_1)
            .load_op(vk::AttachmentLoadOp::CLEAR)
            .store_op(vk::AttachmentStoreOp::STORE)
            .stencil_load_op(vk::AttachmentLoadOp::DONT_CARE)
            .stencil_store_op(vk::AttachmentStoreOp::DONT_CARE)
            .initial_layout(vk::ImageLayout::UNDEFINED)
            .final_layout(vk::ImageLayout::TRANSFER_SRC_OPTIMAL)
    };
    let attachments = [
        color(()),
        color(()),
        vk::AttachmentDescription::default()
            .format(depth_format)
            .samples(vk::SampleCountFlags::TYPE_1)
            .load_op(vk::AttachmentLoadOp::CLEAR)
            .store_op(vk::AttachmentStoreOp::DONT_CARE)
            .stencil_load_op(vk::AttachmentLoadOp::DONT_CARE)
            .stencil_store_op(vk::AttachmentStoreOp::DONT_CARE)
            .initial_layout(vk::ImageLayout::UNDEFINED)
            .final_layout(vk::ImageLayout::DEPTH_STENCIL_ATTACHMENT_OPTIMAL),
    ];
    let color_refs = [
        vk::AttachmentReference { attachment: 0, layout: vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL },
        vk::AttachmentReference { attachment: 1, layout: vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL },
    ];
    let depth_ref =
        vk::AttachmentReference { attachment: 2, layout: vk::ImageLayout::DEPTH_STENCIL_ATTACHMENT_OPTIMAL };
    let subpasses = [vk::SubpassDescription::default()
        .pipeline_bind_point(vk::PipelineBindPoint::GRAPHICS)
        .color_attachments(&color_refs)
        .depth_stencil_attachment(&depth_ref)];
    let dependencies = [
        // Earlier copies out of the attachments and earlier depth writes finish before this pass writes them.
        vk::SubpassDependency::default()
            .src_subpass(vk::SUBPASS_EXTERNAL)
            .dst_subpass(0)
            .src_stage_mask(vk::PipelineStageFlags::TRANSFER | vk::PipelineStageFlags::LATE_FRAGMENT_TESTS)
            .dst_stage_mask(
                vk::PipelineStageFlags::COLOR_ATTACHMENT_OUTPUT | vk::PipelineStageFlags::EARLY_FRAGMENT_TESTS,
            )
            .src_access_mask(vk::AccessFlags::TRANSFER_READ | vk::AccessFlags::DEPTH_STENCIL_ATTACHMENT_WRITE)
            .dst_access_mask(
                vk::AccessFlags::COLOR_ATTACHMENT_WRITE
                    | vk::AccessFlags::DEPTH_STENCIL_ATTACHMENT_WRITE
                    | vk::AccessFlags::DEPTH_STENCIL_ATTACHMENT_READ,
            ),
        // The attachments are written before the copies into the storage buffers read them.
        vk::SubpassDependency::default()
            .src_subpass(0)
            .dst_subpass(vk::SUBPASS_EXTERNAL)
            .src_stage_mask(vk::PipelineStageFlags::COLOR_ATTACHMENT_OUTPUT)
            .dst_stage_mask(vk::PipelineStageFlags::TRANSFER)
            .src_access_mask(vk::AccessFlags::COLOR_ATTACHMENT_WRITE)
            .dst_access_mask(vk::AccessFlags::TRANSFER_READ),
    ];
    let info =
        vk::RenderPassCreateInfo::default().attachments(&attachments).subpasses(&subpasses).dependencies(&dependencies);
    // SAFETY: the device is alive; `attachments`, `subpasses` and `dependencies` outlive the call; the caller
    // destroys the render pass (in `Drop for Renderer`).
    unsafe { device.create_render_pass(&info, None) }.map_err(GpuError::vk("create the render pass"))
}

fn create_raster_pipeline(
    ctx: &Context,
    render_pass: vk::RenderPass,
    layout: vk::PipelineLayout,
) -> Result<vk::Pipeline, GpuError> {
    let device = ctx.device();
    let vert = shader_module(ctx, shaders::RASTER_VERT)?;
    let frag = match shader_module(ctx, shaders::RASTER_FRAG) {
        Ok(f) => f,
        Err(e) => {
            // SAFETY: `vert` was just created on this device and is not used by any pipeline yet.
            unsafe { device.destroy_shader_module(vert, None) };
            return Err(e);
        }
    };
    let stages = [
        vk::PipelineShaderStageCreateInfo::default().stage(vk::ShaderStageFlags::VERTEX).module(vert).name(c"main"),
        vk::PipelineShaderStageCreateInfo::default().stage(vk::ShaderStageFlags::FRAGMENT).module(frag).name(c"main"),
    ];
    let vbindings: Vec<vk::VertexInputBindingDescription> = (0..3)
        .map(|b| vk::VertexInputBindingDescription { binding: b, stride: 12, input_rate: vk::VertexInputRate::VERTEX })
        .collect();
    let vattrs: Vec<vk::VertexInputAttributeDescription> = (0..3)
        .map(|b| vk::VertexInputAttributeDescription {
            location: b,
            binding: b,
            format: vk::Format::R32G32B32_SFLOAT,
            offset: 0,
        })
        .collect();
    let vertex_input = vk::PipelineVertexInputStateCreateInfo::default()
        .vertex_binding_descriptions(&vbindings)
        .vertex_attribute_descriptions(&vattrs);
    let assembly = vk::PipelineInputAssemblyStateCreateInfo::default().topology(vk::PrimitiveTopology::TRIANGLE_LIST);
    let viewport = vk::PipelineViewportStateCreateInfo::default().viewport_count(1).scissor_count(1);
    // No culling: the nearest surface wins whatever its facing, as in the CPU rasteriser.
    let raster = vk::PipelineRasterizationStateCreateInfo::default()
        .polygon_mode(vk::PolygonMode::FILL)
        .cull_mode(vk::CullModeFlags::NONE)
        .front_face(vk::FrontFace::COUNTER_CLOCKWISE)
        .line_width(1.0);
    let multisample =
        vk::PipelineMultisampleStateCreateInfo::default().rasterization_samples(vk::SampleCountFlags::TYPE_1);
    // Depth is "greater is nearer" for both projections (see raster.vert).
    let depth = vk::PipelineDepthStencilStateCreateInfo::default()
        .depth_test_enable(true)
        .depth_write_enable(true)
        .depth_compare_op(vk::CompareOp::GREATER);
    let blend_attachment =
        vk::PipelineColorBlendAttachmentState::default().color_write_mask(vk::ColorComponentFlags::RGBA);
    let blend_attachments = [blend_attachment, blend_attachment];
    let blend = vk::PipelineColorBlendStateCreateInfo::default().attachments(&blend_attachments);
    let dynamic_states = [vk::DynamicState::VIEWPORT, vk::DynamicState::SCISSOR];
    let dynamic = vk::PipelineDynamicStateCreateInfo::default().dynamic_states(&dynamic_states);
    let info = vk::GraphicsPipelineCreateInfo::default()
        .stages(&stages)
        .vertex_input_state(&vertex_input)
        .input_assembly_state(&assembly)
        .viewport_state(&viewport)
        .rasterization_state(&raster)
        .multisample_state(&multisample)
        .depth_stencil_state(&depth)
        .color_blend_state(&blend)
        .dynamic_state(&dynamic)
        .layout(layout)
        .render_pass(render_pass)
        .subpass(0);
    // SAFETY: `info` and the shader modules it names are alive for the call; the layout and render pass belong to the
    // caller.
    let result = unsafe { device.create_graphics_pipelines(vk::PipelineCache::null(), &[info], None) };
    // SAFETY: pipeline creation has returned, so nothing uses the modules any more (a pipeline keeps its own copy of
    // the code).
    unsafe {
        device.destroy_shader_module(vert, None);
        device.destroy_shader_module(frag, None);
    }
    result.map(|p| p[0]).map_err(|(_, e)| GpuError::vk("create the raster pipeline")(e))
}

fn create_compute_pipeline(ctx: &Context, layout: vk::PipelineLayout, spv: &[u8]) -> Result<vk::Pipeline, GpuError> {
    let device = ctx.device();
    let module = shader_module(ctx, spv)?;
    let stage =
        vk::PipelineShaderStageCreateInfo::default().stage(vk::ShaderStageFlags::COMPUTE).module(module).name(c"main");
    let info = vk::ComputePipelineCreateInfo::default().stage(stage).layout(layout);
    // SAFETY: `info` names a module created above and a layout of the caller; both are alive for the call.
    let result = unsafe { device.create_compute_pipelines(vk::PipelineCache::null(), &[info], None) };
    // SAFETY: pipeline creation has returned; the pipeline does not need the module afterwards.
    unsafe { device.destroy_shader_module(module, None) };
    result.map(|p| p[0]).map_err(|(_, e)| GpuError::vk("create a compute pipeline")(e))
}

/// Mean un-premultiplied colour of the person in a premultiplied source (`sum c / sum min(m, 1)` where `m > 0`),
/// as the CPU warp's fallback when a view sees nothing of the photo; mid grey without a person.
fn mean_masked(color: &RgbaImage) -> Vec3 {
    let (sum, w) = color.data.iter().fold((Vec3::ZERO, 0.0f32), |(s, w), c| {
        if c.w > 0.0 {
            (s + c.truncate(), w + c.w.min(1.0))
        } else {
            (s, w)
        }
    });
    if w > 0.0 {
        (sum / w).clamp(Vec3::ZERO, Vec3::ONE)
    } else {
        Vec3::splat(0.5)
    }
}

/// A G-buffer as `vec4(normal, depth)` per pixel with [`BACKGROUND_DEPTH`] where not covered.
fn pack_geometry(g: &GBuffer) -> Vec<Vec4> {
    (0..g.mask.len())
        .map(|i| if g.mask[i] { g.normal[i].extend(g.depth[i]) } else { Vec4::new(0.0, 0.0, 0.0, BACKGROUND_DEPTH) })
        .collect()
}

/// Packs two f32 into IEEE half floats (round to nearest even), as GLSL `packHalf2x16`.
pub fn pack_half2(a: f32, b: f32) -> u32 {
    u32::from(f32_to_f16(a)) | (u32::from(f32_to_f16(b)) << 16)
}

/// f32 -> IEEE 754 binary16 bits, round to nearest even; overflow gives infinity, NaN stays NaN.
pub fn f32_to_f16(x: f32) -> u16 {
    let bits = x.to_bits();
    let sign = ((bits >> 16) & 0x8000) as u16;
    let exp = ((bits >> 23) & 0xff) as i32;
    let man = bits & 0x7f_ffff;
    if exp == 0xff {
        return sign | 0x7c00 | if man != 0 { 0x200 } else { 0 };
    }
    let e = exp - 127 + 15;
    if e >= 0x1f {
        return sign | 0x7c00;
    }
    if e <= 0 {
        // Subnormal half (or zero).
        if e < -10 {
            return sign;
        }
        let m = man | 0x80_0000;
        let shift = (14 - e) as u32;
        let half = m >> shift;
        let rem = m & ((1 << shift) - 1);
        let halfway = 1 << (shift - 1);
        let round = rem > halfway || (rem == halfway && half & 1 == 1);
        return sign | (half + u32::from(round)) as u16;
    }
    let half = ((e as u32) << 10) | (man >> 13);
    let rem = man & 0x1fff;
    let round = rem > 0x1000 || (rem == 0x1000 && half & 1 == 1);
    sign | (half + u32::from(round)) as u16
}

#[cfg(test)]
mod tests {
    use super::*;

    fn f16_to_f32(h: u16) -> f32 {
        let sign = if h & 0x8000 != 0 { -1.0 } else { 1.0 };
        let exp = i32::from((h >> 10) & 0x1f);
        let man = f32::from(h & 0x3ff);
        match exp {
            0 => sign * man * 2f32.powi(-24),
            0x1f => {
                if man == 0.0 {
                    sign * f32::INFINITY
                } else {
                    f32::NAN
                }
            }
            _ => sign * (1.0 + man / 1024.0) * 2f32.powi(exp - 15),
        }
    }

    #[test]
    fn half_conversion_is_exact_where_representable_and_rounds_otherwise() {
        for &v in &[0.0f32, 1.0, -2.5, 0.5, 65504.0, 6.1035156e-5, 5.9604645e-8, 0.333_251_95] {
            assert_eq!(f16_to_f32(f32_to_f16(v)), v, "{v}");
        }
        assert_eq!(f32_to_f16(1.0e6), 0x7c00);
        assert!(f16_to_f32(f32_to_f16(f32::NAN)).is_nan());
        // Relative error bound 2^-11 over [1e-4, 1]
        let mut x = 1.0e-4f32;
        while x < 1.0 {
            let r = f16_to_f32(f32_to_f16(x));
            assert!(((r - x) / x).abs() <= 1.0 / 2048.0 + 1e-7, "{x} -> {r}");
            x *= 1.0137;
        }
        // Ties to even: 1 + 2^-11 is halfway between 1 and 1 + 2^-10 -> 1.
        assert_eq!(f32_to_f16(1.0 + 1.0 / 2048.0), 0x3c00);
        assert_eq!(f32_to_f16(1.0 + 3.0 / 2048.0), 0x3c02);
    }
}
