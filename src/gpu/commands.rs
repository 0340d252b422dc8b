//! One re-recorded command buffer with its own pool and fence ([`CommandSlot`]): the one submission pattern of the
//! GPU work — wait for the previous submission, record, submit to one of the context's queues under its lock, and
//! (for the renderer's frames) wait for it with a timeout. Used by `gpu::Renderer`, the XR eye upload and the
//! desktop mirror.

use std::sync::Arc;
use std::time::Duration;

use ash::vk;

use super::{Context, GpuError};

/// A primary command buffer, its pool and the fence of its last submission. Dropping it waits for that submission.
pub struct CommandSlot {
    ctx: Arc<Context>,
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
    submitted: bool,
}

impl std::fmt::Debug for CommandSlot {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CommandSlot").field("submitted", &self.submitted).finish()
    }
}

impl CommandSlot {
    /// Allocates the pool, the command buffer and the fence on `ctx`'s queue family.
    pub fn new(ctx: &Arc<Context>) -> Result<Self, GpuError> {
        let device = ctx.device();
        let pool_info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(ctx.queue_family())
            .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER);
        // SAFETY: valid device and create info.
        let pool =
            unsafe { device.create_command_pool(&pool_info, None) }.map_err(GpuError::vk("create a command pool"))?;
        let alloc = vk::CommandBufferAllocateInfo::default()
            .command_pool(pool)
            .level(vk::CommandBufferLevel::PRIMARY)
            .command_buffer_count(1);
        // SAFETY: valid device and pool; on failure the pool (and the buffer) are destroyed before returning.
        let created = unsafe {
            device.allocate_command_buffers(&alloc).map_err(GpuError::vk("allocate a command buffer")).and_then(|c| {
                device
                    .create_fence(&vk::FenceCreateInfo::default(), None)
                    .map(|f| (c[0], f))
                    .map_err(GpuError::vk("create a fence"))
            })
        };
        match created {
            Ok((cmd, fence)) => Ok(Self { ctx: Arc::clone(ctx), pool, cmd, fence, submitted: false }),
            Err(e) => {
                // SAFETY: nothing was submitted; destroying the pool frees its command buffers.
                unsafe { device.destroy_command_pool(pool, None) };
                Err(e)
            }
        }
    }

    /// The fence of the last submission (signalled when the GPU has finished it).
    pub fn fence(&self) -> vk::Fence {
        self.fence
    }

    /// Waits for the last submission, if any.
    pub fn wait(&mut self) -> Result<(), GpuError> {
        if self.submitted {
            // SAFETY: our own fence, submitted once since its last reset.
            unsafe { self.ctx.device().wait_for_fences(&[self.fence], true, u64::MAX) }
                .map_err(GpuError::vk("wait for a submission"))?;
        }
        Ok(())
    }

    /// Has the last submission finished (or was there none)? Never blocks.
    pub fn is_done(&self) -> bool {
        // SAFETY: our own fence.
        !self.submitted || unsafe { self.ctx.device().get_fence_status(self.fence) }.unwrap_or(false)
    }

    /// Waits for the last submission, resets the fence and begins recording a one-time submission; returns the
    /// command buffer to record into.
    pub fn begin(&mut self) -> Result<vk::CommandBuffer, GpuError> {
        self.wait()?;
        let device = self.ctx.device();
        // SAFETY: the previous submission has finished (waited above), so the buffer and the fence are unused.
        unsafe {
            device.reset_fences(&[self.fence]).map_err(GpuError::vk("reset a fence"))?;
            self.submitted = false;
            device
                .reset_command_buffer(self.cmd, vk::CommandBufferResetFlags::empty())
                .map_err(GpuError::vk("reset a command buffer"))?;
            let begin = vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
            device.begin_command_buffer(self.cmd, &begin).map_err(GpuError::vk("begin a command buffer"))?;
        }
        Ok(self.cmd)
    }

    /// Ends the recording and submits it to queue `queue` of the context (see [`Context::queue_at`]), waiting on
    /// `wait` (semaphore, stage) and signalling `signal`. The time spent waiting for the queue's lock is added to
    /// `waited`. Returns the fence that signals completion. Allocates nothing (the per-frame paths count heap
    /// allocations).
    pub fn submit(
        &mut self,
        queue: usize,
        wait: Option<(vk::Semaphore, vk::PipelineStageFlags)>,
        signal: Option<vk::Semaphore>,
        waited: &mut Duration,
    ) -> Result<vk::Fence, GpuError> {
        let device = self.ctx.device();
        let semaphores = wait.map(|w| [w.0]);
        let stages = wait.map(|w| [w.1]);
        let signals = signal.map(|s| [s]);
        let cmds = [self.cmd];
        let submit = vk::SubmitInfo::default()
            .wait_semaphores(semaphores.as_ref().map_or(&[], |s| &s[..]))
            .wait_dst_stage_mask(stages.as_ref().map_or(&[], |s| &s[..]))
            .command_buffers(&cmds)
            .signal_semaphores(signals.as_ref().map_or(&[], |s| &s[..]));
        // SAFETY: the buffer is in the recording state (`begin`); the queue is locked for the submission.
        unsafe {
            device.end_command_buffer(self.cmd).map_err(GpuError::vk("end a command buffer"))?;
            let _queue = self.ctx.lock_queue_timed(queue, waited);
            device.queue_submit(self.ctx.queue_at(queue), &[submit], self.fence).map_err(GpuError::vk("submit"))?;
        }
        self.submitted = true;
        Ok(self.fence)
    }

    /// [`CommandSlot::submit`], then waits for the submission at most `timeout`: a device that does not finish
    /// in that time is reported as lost ([`GpuError::DeviceLost`]; the submission stays pending, so the next
    /// [`CommandSlot::begin`] waits for it again rather than reset a buffer the GPU may still read).
    pub fn submit_and_wait(
        &mut self,
        queue: usize,
        wait: Option<(vk::Semaphore, vk::PipelineStageFlags)>,
        signal: Option<vk::Semaphore>,
        timeout: Duration,
    ) -> Result<(), GpuError> {
        let mut lock_wait = Duration::ZERO;
        self.submit(queue, wait, signal, &mut lock_wait)?;
        let nanos = u64::try_from(timeout.as_nanos()).unwrap_or(u64::MAX);
        // SAFETY: our own fence, submitted once since its last reset (just above).
        match unsafe { self.ctx.device().wait_for_fences(&[self.fence], true, nanos) } {
            Ok(()) => {
                self.submitted = false;
                Ok(())
            }
            Err(vk::Result::TIMEOUT) => Err(GpuError::DeviceLost),
            Err(e) => Err(GpuError::vk("wait for a submission")(e)),
        }
    }
}

impl Drop for CommandSlot {
    fn drop(&mut self) {
        let _ = self.wait();
        // SAFETY: the last submission has finished; nothing else uses these objects.
        unsafe {
            self.ctx.device().destroy_fence(self.fence, None);
            self.ctx.device().destroy_command_pool(self.pool, None);
        }
    }
}
