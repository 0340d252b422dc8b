//! Buffers and images: one dedicated allocation each, created once (at renderer creation or when an input
//! changes size), never per frame.

use std::sync::Arc;

use ash::vk;

use super::{Context, GpuError};

/// A storage/transfer buffer in host-visible, coherent memory (device-local too where the device offers
/// it: integrated GPUs, lavapipe, resizable BAR), persistently mapped. This is the host seam: uploads and
/// readbacks are plain memory copies after the frame's fence.
pub struct Buffer {
    ctx: Arc<Context>,
    /// The buffer handle.
    pub buffer: vk::Buffer,
    memory: vk::DeviceMemory,
    /// Size in bytes.
    pub size: u64,
    mapped: *mut u8,
}

// SAFETY: the mapped pointer is only dereferenced through &self / &mut self methods, and the renderer
// synchronises with the GPU through fences before touching it.
unsafe impl Send for Buffer {}
// SAFETY: `&Buffer` only reads the mapping (`read`, `bytes`) — writes need `&mut` — and the GPU side is ordered by
// the owners' fences, so shared references on several threads cannot race.
unsafe impl Sync for Buffer {}

impl Buffer {
    /// Creates a mapped buffer of `size` bytes (at least 16) with `usage`.
    pub fn new(ctx: &Arc<Context>, size: u64, usage: vk::BufferUsageFlags) -> Result<Self, GpuError> {
        let size = size.max(16);
        let device = ctx.device();
        let info = vk::BufferCreateInfo::default().size(size).usage(usage).sharing_mode(vk::SharingMode::EXCLUSIVE);
        // SAFETY: the context keeps the device alive while this `Buffer` holds its `Arc`; `info` outlives the call.
        let buffer = unsafe { device.create_buffer(&info, None) }.map_err(GpuError::vk("create a buffer"))?;
        // SAFETY: `buffer` was just created on this device.
        let req = unsafe { device.get_buffer_memory_requirements(buffer) };
        let host = vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT;
        let type_index = ctx
            .memory_type(req.memory_type_bits, host | vk::MemoryPropertyFlags::DEVICE_LOCAL)
            .or_else(|| ctx.memory_type(req.memory_type_bits, host));
        let Some(type_index) = type_index else {
            // SAFETY: `buffer` was created above, has no memory bound and was never used.
            unsafe { device.destroy_buffer(buffer, None) };
            return Err(GpuError::OutOfMemory("no host-visible memory type for a buffer".into()));
        };
        let alloc = vk::MemoryAllocateInfo::default().allocation_size(req.size).memory_type_index(type_index);
        // SAFETY: the device is alive; `alloc` names a memory type the device reported for this buffer.
        let memory = match unsafe { device.allocate_memory(&alloc, None) } {
            Ok(m) => m,
            Err(e) => {
                // SAFETY: `buffer` was created above and was never used.
                unsafe { device.destroy_buffer(buffer, None) };
                return Err(GpuError::vk("allocate buffer memory")(e));
            }
        };
        // SAFETY: `memory` was allocated for `buffer` (its requirements) and is bound once at offset 0, then mapped
        // whole; host-visible by the chosen type.
        let mapped = unsafe {
            device
                .bind_buffer_memory(buffer, memory, 0)
                .and_then(|_| device.map_memory(memory, 0, vk::WHOLE_SIZE, vk::MemoryMapFlags::empty()))
        };
        match mapped {
            Ok(ptr) => Ok(Self { ctx: ctx.clone(), buffer, memory, size, mapped: ptr as *mut u8 }),
            Err(e) => {
                // SAFETY: both were created above and never used by the GPU; memory is freed after the buffer that
                // used it.
                unsafe {
                    device.destroy_buffer(buffer, None);
                    device.free_memory(memory, None);
                }
                Err(GpuError::vk("map buffer memory")(e))
            }
        }
    }

    /// Copies `data` to the start of the buffer (truncated to the buffer size).
    pub fn write<T: Copy>(&mut self, data: &[T]) {
        let bytes = std::mem::size_of_val(data).min(self.size as usize);
        // SAFETY: the mapping covers `size` bytes; `T: Copy` plain data; the GPU is not using the buffer
        // (callers write between frames, after the fence).
        unsafe { std::ptr::copy_nonoverlapping(data.as_ptr() as *const u8, self.mapped, bytes) };
    }

    /// Copies the start of the buffer into `out` (at most the buffer size).
    pub fn read<T: Copy>(&self, out: &mut [T]) {
        let bytes = std::mem::size_of_val(out).min(self.size as usize);
        // SAFETY: as in `write`; `T` is plain `f32`/`u32` data for which every bit pattern is valid.
        unsafe { std::ptr::copy_nonoverlapping(self.mapped, out.as_mut_ptr() as *mut u8, bytes) };
    }

    /// The mapped bytes (read-only view).
    pub fn bytes(&self) -> &[u8] {
        // SAFETY: the mapping is `size` bytes long and lives as long as `self`.
        unsafe { std::slice::from_raw_parts(self.mapped, self.size as usize) }
    }
}

impl Drop for Buffer {
    fn drop(&mut self) {
        let device = self.ctx.device();
        // SAFETY: owners wait for their last submission before dropping buffers.
        unsafe {
            device.unmap_memory(self.memory);
            device.destroy_buffer(self.buffer, None);
            device.free_memory(self.memory, None);
        }
    }
}

/// A 2-D device-local image with one view (render targets).
pub struct Image2d {
    ctx: Arc<Context>,
    /// The image handle.
    pub image: vk::Image,
    /// A view of the whole image.
    pub view: vk::ImageView,
    memory: vk::DeviceMemory,
    /// Texel format.
    pub format: vk::Format,
    /// Size in pixels.
    pub extent: vk::Extent2D,
}

impl Image2d {
    /// Creates an image of `format` and `usage`; `aspect` selects the view's aspect.
    pub fn new(
        ctx: &Arc<Context>,
        extent: vk::Extent2D,
        format: vk::Format,
        usage: vk::ImageUsageFlags,
        aspect: vk::ImageAspectFlags,
    ) -> Result<Self, GpuError> {
        let device = ctx.device();
        let info = vk::ImageCreateInfo::default()
            .image_type(vk::ImageType::TYPE_2D)
            .format(format)
            .extent(vk::Extent3D { width: extent.width, height: extent.height, depth: 1 })
            .mip_levels(1)
            .array_layers(1)
            .samples(vk::SampleCountFlags::TYPE_1)
            .tiling(vk::ImageTiling::OPTIMAL)
            .usage(usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE)
            .initial_layout(vk::ImageLayout::UNDEFINED);
        // SAFETY: the context keeps the device alive while this `Image` holds its `Arc`; `info` outlives the call.
        let image = unsafe { device.create_image(&info, None) }.map_err(GpuError::vk("create an image"))?;
        // SAFETY: `image` was just created on this device.
        let req = unsafe { device.get_image_memory_requirements(image) };
        let Some(type_index) = ctx
            .memory_type(req.memory_type_bits, vk::MemoryPropertyFlags::DEVICE_LOCAL)
            .or_else(|| ctx.memory_type(req.memory_type_bits, vk::MemoryPropertyFlags::empty()))
        else {
            // SAFETY: `image` was created above, has no memory bound and was never used.
            unsafe { device.destroy_image(image, None) };
            return Err(GpuError::OutOfMemory("no memory type for an image".into()));
        };
        let alloc = vk::MemoryAllocateInfo::default().allocation_size(req.size).memory_type_index(type_index);
        // SAFETY: the device is alive; `alloc` names a memory type the device reported for this image.
        let memory = match unsafe { device.allocate_memory(&alloc, None) } {
            Ok(m) => m,
            Err(e) => {
                // SAFETY: `image` was created above and was never used.
                unsafe { device.destroy_image(image, None) };
                return Err(GpuError::vk("allocate image memory")(e));
            }
        };
        // SAFETY: `memory` was allocated for `image` with its requirements and is bound once at offset 0.
        if let Err(e) = unsafe { device.bind_image_memory(image, memory, 0) } {
            // SAFETY: both were created above and never used by the GPU.
            unsafe {
                device.destroy_image(image, None);
                device.free_memory(memory, None);
            }
            return Err(GpuError::vk("bind image memory")(e));
        }
        let view_info = vk::ImageViewCreateInfo::default()
            .image(image)
            .view_type(vk::ImageViewType::TYPE_2D)
            .format(format)
            .subresource_range(subresource(aspect));
        // SAFETY: `image` is alive and bound to memory; `view_info` matches its format and single mip level and
        // layer.
        let view = match unsafe { device.create_image_view(&view_info, None) } {
            Ok(v) => v,
            Err(e) => {
                // SAFETY: both were created above; the view was not created, so nothing refers to them.
                unsafe {
                    device.destroy_image(image, None);
                    device.free_memory(memory, None);
                }
                return Err(GpuError::vk("create an image view")(e));
            }
        };
        Ok(Self { ctx: ctx.clone(), image, view, memory, format, extent })
    }
}

impl Drop for Image2d {
    fn drop(&mut self) {
        let device = self.ctx.device();
        // SAFETY: owners wait for their last submission before dropping images.
        unsafe {
            device.destroy_image_view(self.view, None);
            device.destroy_image(self.image, None);
            device.free_memory(self.memory, None);
        }
    }
}

/// The whole (single mip, single layer) subresource range of an image.
pub fn subresource(aspect: vk::ImageAspectFlags) -> vk::ImageSubresourceRange {
    vk::ImageSubresourceRange {
        aspect_mask: aspect,
        base_mip_level: 0,
        level_count: 1,
        base_array_layer: 0,
        layer_count: 1,
    }
}

/// A layout transition of a whole colour image (no queue-family transfer).
pub fn color_barrier(
    image: vk::Image,
    (old, new): (vk::ImageLayout, vk::ImageLayout),
    (src_access, dst_access): (vk::AccessFlags, vk::AccessFlags),
) -> vk::ImageMemoryBarrier<'static> {
    vk::ImageMemoryBarrier::default()
        .old_layout(old)
        .new_layout(new)
        .src_access_mask(src_access)
        .dst_access_mask(dst_access)
        .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
        .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
        .image(image)
        .subresource_range(subresource(vk::ImageAspectFlags::COLOR))
}

/// Records one image barrier between two pipeline stages.
///
/// # Safety
/// `cmd` is in the recording state and `barrier` names a valid image of `device`.
pub unsafe fn record_image_barrier(
    device: &ash::Device,
    cmd: vk::CommandBuffer,
    (src, dst): (vk::PipelineStageFlags, vk::PipelineStageFlags),
    barrier: vk::ImageMemoryBarrier<'_>,
) {
    // SAFETY: as the caller guarantees.
    unsafe { device.cmd_pipeline_barrier(cmd, src, dst, vk::DependencyFlags::empty(), &[], &[], &[barrier]) };
}

/// Creates a shader module from SPIR-V bytes produced by build.rs.
pub fn shader_module(ctx: &Context, spv: &[u8]) -> Result<vk::ShaderModule, GpuError> {
    let words = ash::util::read_spv(&mut std::io::Cursor::new(spv))
        .map_err(|e| GpuError::Shader(format!("invalid SPIR-V: {e}")))?;
    let info = vk::ShaderModuleCreateInfo::default().code(&words);
    // SAFETY: the device is alive; `words` is SPIR-V produced and validated by naga in build.rs and outlives the
    // call.
    unsafe { ctx.device().create_shader_module(&info, None) }.map_err(GpuError::vk("create a shader module"))
}
