//! Recording and submission of a frame: the [`Step`]s of a frame recorded into the renderer's one command
//! buffer (raster, compute passes, hole fill, present copy) with the barriers between them, submitted and waited
//! for through the renderer's [`CommandSlot`](crate::gpu::CommandSlot).

use std::time::Duration;

use ash::vk;

use super::{gpu_camera, LevelConstants, Pass, PresentTarget, Renderer, TIMESTAMPS, WORKGROUP};
use crate::compose::background_camera;
use crate::geometry::raster::BACKGROUND_DEPTH;
use crate::geometry::Camera;
use crate::gpu::{present, Context, GpuError};
use crate::pipeline::warp::OcclusionFill;

/// How long a frame may take on the GPU before the device is reported lost.
const FRAME_TIMEOUT: Duration = Duration::from_secs(10);

impl Renderer {
    pub(super) fn set_target(&mut self, camera: &Camera) {
        let bounds = self.mesh.as_ref().map(|m| m.bounds);
        self.uniforms.target = gpu_camera(camera, bounds);
        self.uniforms.viewer = gpu_camera(&background_camera(camera), None);
        self.uniforms.params[0] = self.env_yaw;
        self.uniforms.params[3] = match self.fill {
            OcclusionFill::Propagate => 1.0,
            OcclusionFill::Back if self.has_back => 2.0,
            _ => 0.0,
        };
        self.uniforms.sizes[0] = self.env_size.0;
        self.uniforms.sizes[1] = self.env_size.1;
    }

    /// Records `steps`, submits, and waits for completion.
    pub(super) fn run(&mut self, steps: &[Step], present: Option<PresentTarget>) -> Result<(), GpuError> {
        // Waits for the previous frame first: it may still read the uniforms written below.
        let cb = self.commands.begin()?;
        if let Some(p) = present {
            self.uniforms.output_format[0] = u32::from(p.bgra);
        }
        // Every pass sizes its dispatch from the target camera's image size, which is the renderer's.
        self.uniforms.target.info[1] = self.width as f32;
        self.uniforms.target.info[2] = self.height as f32;
        self.frame.write(std::slice::from_ref(&self.uniforms));
        let device = self.ctx.device();
        // SAFETY: `begin` waited for the previous submission and put `cb` in the recording state; `&mut self` makes
        // this the only recording of it; every bound set, pipeline, buffer and image belongs to this renderer and
        // outlives the submission, which `submit_and_wait` waits for (or reports the device lost, leaving the
        // submission pending for the next `begin` to wait on).
        unsafe {
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
        }
        let wait = present.map(|p| (p.wait, vk::PipelineStageFlags::TRANSFER));
        self.commands.submit_and_wait(Context::RENDER_QUEUE, wait, present.map(|p| p.signal), FRAME_TIMEOUT)?;
        self.read_timestamps(steps);
        Ok(())
    }

    /// A full memory barrier between passes (compute/transfer/attachment writes before any later read/write).
    ///
    /// # Safety
    /// `cb` is this renderer's command buffer, in the recording state.
    pub(super) unsafe fn barrier(&self, cb: vk::CommandBuffer) {
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
    pub(super) unsafe fn record_hole_fill(&self, cb: vk::CommandBuffer) {
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
    pub(super) unsafe fn record_raster(&self, cb: vk::CommandBuffer) {
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
            let region = self.full_color_region();
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

    /// A buffer <-> image copy of a whole colour image of the renderer's size (tightly packed rows).
    fn full_color_region(&self) -> vk::BufferImageCopy {
        vk::BufferImageCopy::default()
            .image_subresource(vk::ImageSubresourceLayers {
                aspect_mask: vk::ImageAspectFlags::COLOR,
                mip_level: 0,
                base_array_layer: 0,
                layer_count: 1,
            })
            .image_extent(vk::Extent3D { width: self.width, height: self.height, depth: 1 })
    }

    /// Records the copy of the encoded output into the swapchain `image` and its hand-over to presentation.
    ///
    /// # Safety
    /// `cb` is recording; `image` is an acquired swapchain image of the renderer's size.
    pub(super) unsafe fn record_present_copy(&self, cb: vk::CommandBuffer, image: vk::Image) {
        let device = self.ctx.device();
        let encoded_ready = vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::SHADER_WRITE)
            .dst_access_mask(vk::AccessFlags::TRANSFER_READ);
        let region = self.full_color_region();
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
}

/// One recorded step of a frame.
#[derive(Clone, Copy, Debug)]
pub(super) enum Step {
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
