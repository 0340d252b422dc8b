//! The frame API: a whole view per call (raster -> flow/Z-map/visibility -> warp -> hole fill -> fusion ->
//! compose, one submission), the neural decoder's two-part seam around it, and presenting a frame rendered
//! elsewhere.

use super::record::Step;
use super::{gpu_camera, Pass, PresentTarget, Renderer};
use glam::Vec4;

use crate::buffer::RgbaImage;
use crate::compose::{Mode, RenderedFrame};
use crate::geometry::raster::GBuffer;
use crate::geometry::zmap::FlowZ;
use crate::geometry::Camera;
use crate::gpu::GpuError;
use crate::pipeline::fusion::previous_weight;

impl Renderer {
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

    pub(super) fn set_previous_uniform(&mut self) {
        if let Some(p) = self.previous {
            self.uniforms.previous = gpu_camera(&p, None);
        }
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
}
