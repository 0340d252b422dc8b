//! A renderer's resources and descriptor bindings: the buffers, images, pipelines and descriptor set made once
//! by [`Renderer::new`] for one output size, the descriptor writes that bind them, and the pipeline builders.

use std::sync::Arc;

use ash::vk;

use super::{
    binding, FrameUniforms, LevelConstants, Renderer, RendererCounters, StageTimer, GEOMETRY_FORMAT, PASS_SHADERS,
};
use crate::geometry::zmap::VISIBILITY_LAMBDA;
use crate::gpu::resources::{shader_module, Buffer, Image2d};
use crate::gpu::{shaders, CommandSlot, Context, GpuError};
use crate::pipeline::warp::OcclusionFill;

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

        let commands = CommandSlot::new(&ctx)?;

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
            has_back: false,
            feature_shape: None,
            fill: OcclusionFill::default(),
            fusion: false,
            previous: None,
            last_fused_input: None,
            dirty: true,
            uniforms: FrameUniforms { params: [0.0, 0.0, VISIBILITY_LAMBDA, 0.0], ..Default::default() },
            commands,
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

    pub(super) fn write_all_descriptors(&mut self) {
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
}

pub(super) fn storage(ctx: &Arc<Context>, bytes: u64) -> Result<Buffer, GpuError> {
    Buffer::new(
        ctx,
        bytes,
        vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::TRANSFER_DST | vk::BufferUsageFlags::TRANSFER_SRC,
    )
}

/// Offsets (in texels) and sizes of the hole-filling pyramid levels, finest first, down to 1x1.
pub(super) fn pyramid_levels(w: u32, h: u32) -> Vec<(u32, u32, u32)> {
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

pub(super) fn pick_depth_format(ctx: &Context) -> Result<vk::Format, GpuError> {
    for format in [vk::Format::D32_SFLOAT, vk::Format::X8_D24_UNORM_PACK32] {
        // SAFETY: a read-only format query on the context's physical device of its live instance.
        let props = unsafe { ctx.instance().get_physical_device_format_properties(ctx.physical_device(), format) };
        if props.optimal_tiling_features.contains(vk::FormatFeatureFlags::DEPTH_STENCIL_ATTACHMENT) {
            return Ok(format);
        }
    }
    Err(GpuError::NoDevice("the device offers no 32- or 24-bit depth buffer".into()))
}

pub(super) fn create_render_pass(device: &ash::Device, depth_format: vk::Format) -> Result<vk::RenderPass, GpuError> {
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

pub(super) fn create_raster_pipeline(
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

pub(super) fn create_compute_pipeline(
    ctx: &Context,
    layout: vk::PipelineLayout,
    spv: &[u8],
) -> Result<vk::Pipeline, GpuError> {
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
