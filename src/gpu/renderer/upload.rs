//! Inputs of the frames, uploaded when they change (not per frame): the mesh, the source view, the panorama,
//! the encoder features, the text overlay and the fill/fusion settings; and the per-call uploads of the stage
//! API (a given target G-buffer or flow).

use ash::vk;
use glam::{Vec3, Vec4};

use super::bindings::storage;
use super::pack::{mean_masked, pack_geometry, pack_half2};
use super::{gpu_camera, GpuMesh, Renderer};
use crate::buffer::{Image, RgbImage, RgbaImage};
use crate::geometry::raster::GBuffer;
use crate::geometry::zmap::{FlowZ, FLOW_OUTSIDE};
use crate::geometry::{Camera, TriMesh};
use crate::gpu::overlay::OverlayMask;
use crate::gpu::resources::Buffer;
use crate::gpu::GpuError;
use crate::io::environment::Environment;
use crate::pipeline::warp::OcclusionFill;
use crate::pipeline::SourceView;

impl Renderer {
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
        self.set_source_with_back(color, None, None, gbuffer, camera)
    }

    /// [`Renderer::set_source`] with the input's back image ([`crate::pipeline::back`]; premultiplied linear RGB,
    /// the same mask in alpha, the photo's size), which [`OcclusionFill::Back`] samples on surfaces facing away from
    /// the source camera, and its side images (the photo and the back image blurred,
    /// [`crate::pipeline::warp::SideImages`], same layout), which surfaces seen edge-on blend in. One source colour
    /// buffer holds them at fixed offsets: the photo, the back image, the side photo, the side back image.
    pub fn set_source_with_back(
        &mut self,
        color: &RgbaImage,
        back: Option<&RgbaImage>,
        side: Option<(&RgbaImage, Option<&RgbaImage>)>,
        gbuffer: &GBuffer,
        camera: &Camera,
    ) -> Result<(), GpuError> {
        let (w, h) = (camera.width, camera.height);
        if w == 0 || h == 0 || (color.width, color.height) != (w, h) || (gbuffer.width, gbuffer.height) != (w, h) {
            return Err(GpuError::Invalid(format!(
                "source image {}x{}, G-buffer {}x{} and camera {w}x{h} must have one size",
                color.width, color.height, gbuffer.width, gbuffer.height
            )));
        }
        let wrong = |img: Option<&RgbaImage>| img.is_some_and(|b| (b.width, b.height) != (w, h));
        if wrong(back) || wrong(side.map(|s| s.0)) || wrong(side.and_then(|s| s.1)) {
            return Err(GpuError::Invalid("the back or side images and the source image differ in size".into()));
        }
        let bytes = (w * h * 16) as u64;
        // Room for the photo, the back image and their side images.
        if self.source_color.size < 4 * bytes || self.source_geometry.size < bytes {
            self.source_color = storage(&self.ctx, 4 * bytes)?;
            self.source_geometry = storage(&self.ctx, bytes)?;
            self.counters.resources_created += 2;
            self.write_all_descriptors();
        }
        // Each image at its fixed offset, up to the last one present (a missing one in between stays zero).
        let parts = [Some(color), back, side.map(|s| s.0), side.and_then(|s| s.1)];
        let last = parts.iter().rposition(Option::is_some).unwrap_or(0);
        let mut packed = Vec::with_capacity((last + 1) * w * h);
        for part in &parts[..=last] {
            match part {
                Some(img) => packed.extend_from_slice(&img.data),
                None => packed.resize(packed.len() + w * h, glam::Vec4::ZERO),
            }
        }
        self.source_color.write(&packed);
        self.has_back = back.is_some();
        self.uniforms.source_images[0] = u32::from(side.is_some());
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

    /// [`Renderer::set_source_with_back`] from the pipeline's parts: premultiplied linear RGB, its mask, the back
    /// image and the side images (premultiplied by the same mask), when the input has them.
    pub fn set_source_parts(
        &mut self,
        colours: crate::pipeline::warp::SourceColours<'_>,
        mask: &crate::buffer::GrayImage,
        gbuffer: &GBuffer,
        camera: &Camera,
    ) -> Result<(), GpuError> {
        let rgb = colours.rgb;
        if (rgb.width, rgb.height) != (mask.width, mask.height) {
            return Err(GpuError::Invalid("source colour and mask differ in size".into()));
        }
        let with_mask = |img: &RgbImage| Image {
            width: img.width,
            height: img.height,
            data: img.data.iter().zip(&mask.data).map(|(c, m)| c.extend(*m)).collect(),
        };
        let fits = |b: &RgbImage| (b.width, b.height) == (rgb.width, rgb.height);
        let back = colours.back.filter(|b| fits(b)).map(with_mask);
        let side = colours.side.filter(|s| fits(&s.rgb));
        let side_photo = side.map(|s| with_mask(&s.rgb));
        // The side back image only beside a back image, as the CPU lookup pairs them.
        let side_back = back.as_ref().and(side).and_then(|s| s.back.as_ref()).filter(|b| fits(b)).map(with_mask);
        self.set_source_with_back(
            &with_mask(rgb),
            back.as_ref(),
            side_photo.as_ref().map(|p| (p, side_back.as_ref())),
            gbuffer,
            camera,
        )
    }

    /// Uploads what the person renderers draw from: the mesh and the source view (colour, mask, back image,
    /// G-buffer, camera). Call once per input frame.
    pub fn set_scene(&mut self, source: &SourceView<'_>) -> Result<(), GpuError> {
        self.set_mesh(source.mesh)?;
        self.set_source_parts(source.colours(), source.mask, source.gbuffer, source.camera)
    }

    /// How occluded pixels are coloured (as the CPU warp's [`OcclusionFill`]).
    pub fn fill(&self) -> OcclusionFill {
        self.fill
    }

    /// Sets how occluded pixels are coloured (as the CPU warp's [`OcclusionFill`]).
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

    pub(super) fn upload_flow(&mut self, flowz: &FlowZ, visible: Option<&[bool]>) {
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

    pub(super) fn upload_target(&mut self, target: &GBuffer) {
        self.geometry.write(&pack_geometry(target));
        let colors: Vec<Vec4> = (0..target.mask.len())
            .map(|i| {
                let c = target.color.as_ref().map_or(Vec3::ZERO, |c| c[i]);
                c.extend(if target.mask[i] { 1.0 } else { 0.0 })
            })
            .collect();
        self.color.write(&colors);
    }

    pub(super) fn require_source(&self) -> Result<(), GpuError> {
        if self.source_size.0 == 0 {
            return Err(GpuError::Invalid("no source view was uploaded (set_source)".into()));
        }
        Ok(())
    }
}
