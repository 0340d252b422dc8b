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
//! Files, by concern: this one holds the types and the public API (uploads, frames); [`bindings`] creates the
//! resources, pipelines and descriptor set; [`record`] records and submits a frame's passes; [`readback`] reads
//! results and GPU timestamps back; [`pack`] packs host data for upload.

use std::sync::Arc;
use std::time::Duration;

use ash::vk;
use glam::{Mat4, Vec3, Vec4};

use super::overlay::OverlayMask;
use super::resources::{Buffer, Image2d};
use super::{shaders, CommandSlot, Context, GpuError};
use crate::buffer::{Image, RgbImage, RgbaImage};
use crate::compose::{Mode, RenderedFrame};
use crate::geometry::raster::GBuffer;
use crate::geometry::zmap::{FlowZ, FLOW_OUTSIDE};
use crate::geometry::{Camera, Projection, TriMesh};
use crate::io::environment::Environment;
use crate::pipeline::fusion::previous_weight;
use crate::pipeline::warp::OcclusionFill;
use crate::pipeline::SourceView;

mod bindings;
mod pack;
mod readback;
mod record;

use bindings::storage;
pub use pack::{f32_to_f16, pack_half2};
use pack::{mean_masked, pack_geometry};
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

    /// The output buffer (`vec4` per pixel, row-major, linear; VR: RGB and 1, AR: premultiplied RGBA) of the last
    /// frame, for copies into images owned elsewhere (e.g. OpenXR swapchains). It is never reallocated; it is
    /// rewritten by the next frame, so such copies must finish before the renderer is used again.
    pub fn output_buffer(&self) -> vk::Buffer {
        self.out.buffer
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
