//! The OpenXR swapchains: one per eye ([`EyeSwapchain`]) on the device the runtime asked for
//! ([`super::device`]), filled on the GPU ([`EyeUploader`]): the renderer's float result is copied into a float
//! image and blitted into the swapchain image, which converts it to the swapchain's 8-bit format (sRGB encoding
//! included) in hardware.
//!
//! Colour: eye images are linear, premultiplied RGBA. For `*_SRGB` swapchain formats the blit encodes sRGB (the
//! compositor decodes it back to linear when it samples); for `*_UNORM` formats the runtime takes the values as
//! linear, so the blit quantises them directly. [`SwapchainFormat::decode`] reads read-back bytes the same way.

use std::ffi::{c_char, CStr};
use std::sync::Arc;
use std::time::Duration;

use ash::vk::{self, Handle};
use glam::Vec4;
use openxr as xr;

use super::device::SESSION_QUEUE;
use super::{XrContext, XrError};
use crate::buffer::{linear_to_srgb, srgb_to_linear, RgbaImage};
use crate::gpu::resources::{color_barrier, record_image_barrier, Buffer, Image2d};
use crate::gpu::{self, CommandSlot};

/// The format of the per-eye float images the renderer's output is copied into (its `vec4` layout).
pub const LINEAR_FORMAT: vk::Format = vk::Format::R32G32B32A32_SFLOAT;

/// A swapchain colour format r2human can fill.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SwapchainFormat {
    /// The Vulkan format.
    pub vk: vk::Format,
    /// Bytes are sRGB-encoded (the `*_SRGB` formats).
    pub srgb: bool,
    /// Byte order B, G, R, A instead of R, G, B, A.
    pub bgra: bool,
}

impl SwapchainFormat {
    /// The formats r2human can fill, in order of preference (sRGB first: 8-bit linear bands visibly in the darks).
    pub const PREFERRED: [SwapchainFormat; 4] = [
        SwapchainFormat { vk: vk::Format::R8G8B8A8_SRGB, srgb: true, bgra: false },
        SwapchainFormat { vk: vk::Format::B8G8R8A8_SRGB, srgb: true, bgra: true },
        SwapchainFormat { vk: vk::Format::R8G8B8A8_UNORM, srgb: false, bgra: false },
        SwapchainFormat { vk: vk::Format::B8G8R8A8_UNORM, srgb: false, bgra: true },
    ];

    /// The most preferred of [`SwapchainFormat::PREFERRED`] among the runtime's `offered` formats (raw VkFormat
    /// values, as `xrEnumerateSwapchainFormats` returns them), or `None`.
    pub fn choose(offered: &[u32]) -> Option<Self> {
        Self::choose_where(offered, |_| true)
    }

    /// As [`SwapchainFormat::choose`], among the formats for which `usable` holds (e.g. the device can blit into
    /// them).
    pub fn choose_where(offered: &[u32], usable: impl Fn(vk::Format) -> bool) -> Option<Self> {
        Self::PREFERRED.into_iter().find(|f| offered.contains(&(f.vk.as_raw() as u32)) && usable(f.vk))
    }

    /// Encodes one linear premultiplied RGBA pixel into the 4 bytes of this format.
    #[inline]
    pub fn encode(&self, px: Vec4) -> [u8; 4] {
        let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
        let a = if px.w.is_nan() { 0.0 } else { px.w.clamp(0.0, 1.0) };
        let channel = |v: f32| {
            // Premultiplied colour cannot exceed alpha; NaN reads as 0.
            let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, a) };
            if self.srgb {
                q(linear_to_srgb(v))
            } else {
                q(v)
            }
        };
        let (r, g, b) = (channel(px.x), channel(px.y), channel(px.z));
        if self.bgra {
            [b, g, r, q(a)]
        } else {
            [r, g, b, q(a)]
        }
    }

    /// Decodes 4 bytes of this format back to linear premultiplied RGBA (inverse of [`SwapchainFormat::encode`]
    /// up to quantisation).
    #[inline]
    pub fn decode(&self, bytes: [u8; 4]) -> Vec4 {
        let [c0, c1, c2, a] = bytes;
        let (r, g, b) = if self.bgra { (c2, c1, c0) } else { (c0, c1, c2) };
        let lin = |v: u8| {
            let v = v as f32 / 255.0;
            if self.srgb {
                srgb_to_linear(v)
            } else {
                v
            }
        };
        Vec4::new(lin(r), lin(g), lin(b), a as f32 / 255.0)
    }

    /// Decodes `width x height` pixels of this format into an image.
    pub fn decode_image(&self, bytes: &[u8], width: usize, height: usize) -> RgbaImage {
        RgbaImage::from_fn(width, height, |c, r| {
            let i = (r * width + c) * 4;
            self.decode([bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]])
        })
    }
}

/// One eye's swapchain, the float image the renderer's result is copied into (also the mirror's source), and an
/// optional readback buffer (tests).
pub struct EyeSwapchain {
    /// The OpenXR swapchain.
    pub handle: xr::Swapchain<xr::Vulkan>,
    /// Its Vulkan images (owned by the runtime).
    pub images: Vec<vk::Image>,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// The colour format.
    pub format: SwapchainFormat,
    /// The last eye image in linear float ([`LINEAR_FORMAT`]); in TRANSFER_SRC_OPTIMAL after the first upload.
    pub linear: Image2d,
    readback: Option<Buffer>,
    released_once: bool,
}

impl EyeSwapchain {
    /// Creates a `width x height` swapchain of `format` for one eye. `readback` adds TRANSFER_SRC usage and a
    /// readback buffer so [`EyeUploader`] can read the image back from the swapchain.
    pub fn new(
        ctx: &Arc<gpu::Context>,
        session: &xr::Session<xr::Vulkan>,
        format: SwapchainFormat,
        width: u32,
        height: u32,
        readback: bool,
    ) -> Result<Self, XrError> {
        if !ctx.format_supports(LINEAR_FORMAT, vk::FormatFeatureFlags::BLIT_SRC | vk::FormatFeatureFlags::TRANSFER_DST)
        {
            return Err(XrError::Unsupported(format!(
                "Vulkan device {} cannot blit from {LINEAR_FORMAT:?} images",
                ctx.device_name()
            )));
        }
        let mut usage = xr::SwapchainUsageFlags::COLOR_ATTACHMENT
            | xr::SwapchainUsageFlags::TRANSFER_DST
            | xr::SwapchainUsageFlags::SAMPLED;
        if readback {
            usage |= xr::SwapchainUsageFlags::TRANSFER_SRC;
        }
        let handle = session
            .create_swapchain(&xr::SwapchainCreateInfo {
                create_flags: xr::SwapchainCreateFlags::EMPTY,
                usage_flags: usage,
                format: format.vk.as_raw() as u32,
                sample_count: 1,
                width,
                height,
                face_count: 1,
                array_size: 1,
                mip_count: 1,
            })
            .xr("xrCreateSwapchain")?;
        let images =
            handle.enumerate_images().xr("xrEnumerateSwapchainImages")?.into_iter().map(vk::Image::from_raw).collect();
        let gpu_err = |e: gpu::GpuError| XrError::Unsupported(format!("eye image buffers: {e}"));
        let linear = Image2d::new(
            ctx,
            vk::Extent2D { width, height },
            LINEAR_FORMAT,
            // SAMPLED only because the image comes with a view (gpu::resources::Image2d); it is used by transfers.
            vk::ImageUsageFlags::TRANSFER_DST | vk::ImageUsageFlags::TRANSFER_SRC | vk::ImageUsageFlags::SAMPLED,
            vk::ImageAspectFlags::COLOR,
        )
        .map_err(gpu_err)?;
        let readback = if readback {
            let bytes = u64::from(width) * u64::from(height) * 4;
            Some(Buffer::new(ctx, bytes, vk::BufferUsageFlags::TRANSFER_DST).map_err(gpu_err)?)
        } else {
            None
        };
        Ok(Self { handle, images, width, height, format, linear, readback, released_once: false })
    }

    /// Has an image been released at least once (so a projection layer may reference this swapchain)?
    pub fn has_content(&self) -> bool {
        self.released_once
    }

    /// The last read-back image (valid once the upload that wrote it has finished; see [`EyeUploader`]).
    fn read_back(&self) -> Option<RgbaImage> {
        let rb = self.readback.as_ref()?;
        let n = self.width as usize * self.height as usize * 4;
        let bytes = rb.bytes().get(..n)?;
        Some(self.format.decode_image(bytes, self.width as usize, self.height as usize))
    }
}

/// Fills the eye swapchains from the renderer's result buffers with one GPU submission per frame: buffer -> float
/// image copy, blit into the acquired swapchain image (format conversion), optional readback. Runs on the display
/// thread; it waits only for its own previous submission, which has long finished by the time a new frame exists.
pub struct EyeUploader {
    commands: CommandSlot,
    capture_pending: bool,
}

impl EyeUploader {
    /// Allocates the command buffer and fence on `ctx` (submitting to the session's queue).
    pub fn new(ctx: &Arc<gpu::Context>) -> Result<Self, XrError> {
        Ok(Self { commands: CommandSlot::new(ctx)?, capture_pending: false })
    }

    /// Copies `sources[i]` (the renderer's result for eye `i`, `vec4` per pixel of the eye's size) into the next
    /// image of each eye's swapchain, and with `capture` also back out into the eye's readback buffer. Returns the
    /// fence that signals when the GPU has finished reading `sources`. Time spent waiting for the queue lock is
    /// added to `waited`.
    pub fn upload(
        &mut self,
        ctx: &gpu::Context,
        eyes: &mut [EyeSwapchain],
        sources: &[vk::Buffer],
        capture: bool,
        waited: &mut Duration,
    ) -> Result<vk::Fence, XrError> {
        if sources.len() != eyes.len() {
            return Err(XrError::Render(format!("{} eye images for {} swapchains", sources.len(), eyes.len())));
        }
        self.commands.wait()?;
        let mut indices = Vec::with_capacity(eyes.len());
        for eye in eyes.iter_mut() {
            let index = {
                let _q = ctx.lock_queue_timed(SESSION_QUEUE, waited);
                eye.handle.acquire_image().xr("xrAcquireSwapchainImage")?
            };
            eye.handle.wait_image(xr::Duration::INFINITE).xr("xrWaitSwapchainImage")?;
            indices.push(index as usize);
        }
        let device = ctx.device();
        let layers = vk::ImageSubresourceLayers {
            aspect_mask: vk::ImageAspectFlags::COLOR,
            mip_level: 0,
            base_array_layer: 0,
            layer_count: 1,
        };
        let barrier =
            |image, old, new, src_access, dst_access| color_barrier(image, (old, new), (src_access, dst_access));
        let capture = capture && eyes.iter().all(|e| e.readback.is_some());
        let cmd = self.commands.begin()?;
        // SAFETY: `cmd` is recording (`begin` waited for its previous submission), every handle is valid, each
        // swapchain image is ours between xrWaitSwapchainImage and xrReleaseSwapchainImage, and the source buffers
        // were finished by the render thread (it waited on its own fence before publishing them).
        unsafe {
            for ((eye, &index), &source) in eyes.iter().zip(&indices).zip(sources) {
                let target = eye.images[index];
                let linear = eye.linear.image;
                let extent = vk::Extent3D { width: eye.width, height: eye.height, depth: 1 };
                // Both images are overwritten whole: discard the old contents. Earlier reads of the float image
                // (blits, the mirror) finish first.
                device.cmd_pipeline_barrier(
                    cmd,
                    vk::PipelineStageFlags::TRANSFER,
                    vk::PipelineStageFlags::TRANSFER,
                    vk::DependencyFlags::empty(),
                    &[],
                    &[],
                    &[
                        barrier(
                            linear,
                            vk::ImageLayout::UNDEFINED,
                            vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                            vk::AccessFlags::TRANSFER_READ,
                            vk::AccessFlags::TRANSFER_WRITE,
                        ),
                        barrier(
                            target,
                            vk::ImageLayout::UNDEFINED,
                            vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                            vk::AccessFlags::empty(),
                            vk::AccessFlags::TRANSFER_WRITE,
                        ),
                    ],
                );
                let copy = vk::BufferImageCopy {
                    buffer_offset: 0,
                    buffer_row_length: 0,
                    buffer_image_height: 0,
                    image_subresource: layers,
                    image_offset: vk::Offset3D::default(),
                    image_extent: extent,
                };
                device.cmd_copy_buffer_to_image(cmd, source, linear, vk::ImageLayout::TRANSFER_DST_OPTIMAL, &[copy]);
                record_image_barrier(
                    device,
                    cmd,
                    (vk::PipelineStageFlags::TRANSFER, vk::PipelineStageFlags::TRANSFER),
                    barrier(
                        linear,
                        vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                        vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                        vk::AccessFlags::TRANSFER_WRITE,
                        vk::AccessFlags::TRANSFER_READ,
                    ),
                );
                let corner = vk::Offset3D { x: eye.width as i32, y: eye.height as i32, z: 1 };
                let blit = vk::ImageBlit {
                    src_subresource: layers,
                    src_offsets: [vk::Offset3D::default(), corner],
                    dst_subresource: layers,
                    dst_offsets: [vk::Offset3D::default(), corner],
                };
                device.cmd_blit_image(
                    cmd,
                    linear,
                    vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                    target,
                    vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                    &[blit],
                    vk::Filter::NEAREST,
                );
                let mut last_layout = vk::ImageLayout::TRANSFER_DST_OPTIMAL;
                if let (true, Some(rb)) = (capture, &eye.readback) {
                    record_image_barrier(
                        device,
                        cmd,
                        (vk::PipelineStageFlags::TRANSFER, vk::PipelineStageFlags::TRANSFER),
                        barrier(
                            target,
                            vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                            vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                            vk::AccessFlags::TRANSFER_WRITE,
                            vk::AccessFlags::TRANSFER_READ,
                        ),
                    );
                    device.cmd_copy_image_to_buffer(
                        cmd,
                        target,
                        vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                        rb.buffer,
                        &[copy],
                    );
                    let host = vk::BufferMemoryBarrier::default()
                        .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
                        .dst_access_mask(vk::AccessFlags::HOST_READ)
                        .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                        .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                        .buffer(rb.buffer)
                        .offset(0)
                        .size(vk::WHOLE_SIZE);
                    device.cmd_pipeline_barrier(
                        cmd,
                        vk::PipelineStageFlags::TRANSFER,
                        vk::PipelineStageFlags::HOST,
                        vk::DependencyFlags::empty(),
                        &[],
                        &[host],
                        &[],
                    );
                    last_layout = vk::ImageLayout::TRANSFER_SRC_OPTIMAL;
                }
                // XR_KHR_vulkan_enable: a released colour image must be in COLOR_ATTACHMENT_OPTIMAL.
                record_image_barrier(
                    device,
                    cmd,
                    (vk::PipelineStageFlags::TRANSFER, vk::PipelineStageFlags::ALL_COMMANDS),
                    barrier(
                        target,
                        last_layout,
                        vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL,
                        vk::AccessFlags::TRANSFER_WRITE | vk::AccessFlags::TRANSFER_READ,
                        vk::AccessFlags::COLOR_ATTACHMENT_READ | vk::AccessFlags::SHADER_READ,
                    ),
                );
            }
        }
        let fence = self.commands.submit(SESSION_QUEUE, None, None, waited)?;
        // A read-back not collected yet stays valid: its buffers are only rewritten by uploads with `capture`.
        self.capture_pending |= capture;
        for eye in eyes.iter_mut() {
            let _q = ctx.lock_queue_timed(SESSION_QUEUE, waited);
            eye.handle.release_image().xr("xrReleaseSwapchainImage")?;
            eye.released_once = true;
        }
        Ok(fence)
    }

    /// The read-back eye images of the last upload with `capture`, once the GPU has finished it (never blocks;
    /// `None` while it runs or when there is nothing new).
    pub fn take_captures(&mut self, eyes: &[EyeSwapchain]) -> Option<Vec<RgbaImage>> {
        if !self.capture_pending || !self.commands.is_done() {
            return None;
        }
        self.capture_pending = false;
        eyes.iter().map(EyeSwapchain::read_back).collect()
    }

    /// Waits for the last upload (before re-recording, and at the end of the session).
    pub fn wait(&mut self) -> Result<(), XrError> {
        Ok(self.commands.wait()?)
    }
}

/// The name of a Vulkan format for messages ("R8G8B8A8_SRGB"), or its number.
pub fn format_name(raw: u32) -> String {
    let f = vk::Format::from_raw(raw as i32);
    let name = format!("{f:?}");
    if name.chars().all(|c| c.is_ascii_digit()) {
        format!("VkFormat({raw})")
    } else {
        name
    }
}

/// A `CStr` view of a fixed-size C string array (for Vulkan property names).
pub fn c_array_str(chars: &[c_char]) -> String {
    let bytes: Vec<u8> = chars.iter().take_while(|&&c| c != 0).map(|&c| c as u8).collect();
    CStr::from_bytes_until_nul(&[bytes.as_slice(), &[0]].concat())
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chooses_srgb_first_and_none_when_nothing_fits() {
        let offered = [vk::Format::B8G8R8A8_UNORM.as_raw() as u32, vk::Format::B8G8R8A8_SRGB.as_raw() as u32];
        let f = SwapchainFormat::choose(&offered).unwrap();
        assert_eq!(f.vk, vk::Format::B8G8R8A8_SRGB);
        assert!(f.srgb && f.bgra);
        let only_unorm = [vk::Format::R8G8B8A8_UNORM.as_raw() as u32];
        assert!(!SwapchainFormat::choose(&only_unorm).unwrap().srgb);
        assert!(SwapchainFormat::choose(&[vk::Format::R16G16B16A16_SFLOAT.as_raw() as u32]).is_none());
    }

    #[test]
    fn encode_matches_closed_form_and_round_trips() {
        let srgb = SwapchainFormat::PREFERRED[0];
        let bgra_unorm = SwapchainFormat::PREFERRED[3];
        // Linear 0.5 grey, opaque: sRGB byte round(255 * 0.7354) = 188; UNORM byte 128.
        assert_eq!(srgb.encode(Vec4::new(0.5, 0.5, 0.5, 1.0)), [188, 188, 188, 255]);
        assert_eq!(bgra_unorm.encode(Vec4::new(1.0, 0.5, 0.0, 1.0)), [0, 128, 255, 255]);
        // Premultiplied colour above alpha is clamped to alpha; NaN becomes 0; alpha NaN becomes transparent.
        assert_eq!(bgra_unorm.encode(Vec4::new(0.9, f32::NAN, 0.1, 0.5)), [26, 0, 128, 128]);
        assert_eq!(srgb.encode(Vec4::new(1.0, 1.0, 1.0, f32::NAN)), [0, 0, 0, 0]);
        for f in SwapchainFormat::PREFERRED {
            for &v in &[0.0f32, 0.01, 0.2, 0.5, 0.99, 1.0] {
                let px = Vec4::new(v, v * 0.5, v * 0.25, 1.0);
                let back = f.decode(f.encode(px));
                let tol = if f.srgb { 0.01 } else { 0.5 / 255.0 + 1e-6 };
                assert!((back - px).abs().max_element() <= tol, "{f:?} {px} -> {back}");
            }
        }
    }

    #[test]
    fn image_encoding_is_row_major_top_first() {
        let f = SwapchainFormat::PREFERRED[2];
        let img = RgbaImage::from_fn(2, 2, |c, r| Vec4::new(c as f32, r as f32, 0.0, 1.0));
        let bytes: Vec<u8> = img.data.iter().flat_map(|p| f.encode(*p)).collect();
        assert_eq!(bytes, vec![0, 0, 0, 255, 255, 0, 0, 255, 0, 255, 0, 255, 255, 255, 0, 255]);
        assert_eq!(f.decode_image(&bytes, 2, 2), img);
    }

    #[test]
    fn format_names_are_readable() {
        assert_eq!(format_name(vk::Format::R8G8B8A8_SRGB.as_raw() as u32), "R8G8B8A8_SRGB");
        assert_eq!(c_array_str(&[b'a' as c_char, b'b' as c_char, 0, b'c' as c_char]), "ab");
    }
}
