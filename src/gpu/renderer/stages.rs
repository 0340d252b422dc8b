//! The stage API: one pass per call on given inputs, each the GPU version of one CPU reference function
//! (`rasterize`, `flow_and_zmap` + `visibility`, `warp_features`, `render_from_flow`, `SpatialFusion::fuse`,
//! `compose_vr`, `compose_ar`), for the parity tests and the per-stage benchmarks.

use super::record::Step;
use super::{Pass, Renderer};
use crate::buffer::{RgbImage, RgbaImage};
use crate::geometry::raster::GBuffer;
use crate::geometry::zmap::FlowZ;
use crate::geometry::Camera;
use crate::gpu::GpuError;
use crate::pipeline::fusion::previous_weight;

impl Renderer {
    /// Flow, Z-map (paper Eq. 4) and visibility (Eq. 9, [`crate::geometry::zmap::VISIBILITY_LAMBDA`]) of a given target G-buffer
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
}
