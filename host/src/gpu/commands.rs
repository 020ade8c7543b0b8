//! One reusable command buffer with a fence and a timestamp query pool: record dispatches,
//! barriers, fills and copies, submit, wait, and read every labelled GPU timestamp.
use super::{Buffer, Gpu, Kernel, Kernels};
use anyhow::{Context, Result};
use ash::vk;
use shared::types::BuildParams;
use std::sync::Arc;

/// Longest a submission may run before [`Commands::wait`] gives up on it.
pub const GPU_TIMEOUT_NS: u64 = 600_000_000_000;

/// Largest staging buffer [`Commands::read_back`] makes, in bytes.
pub const READ_BACK_CHUNK: u64 = 32 << 20;

/// Timestamps one command buffer can hold (the query pool's size).
pub const MAX_TIMESTAMPS: u32 = 64;

pub struct Commands {
    gpu: Arc<Gpu>,
    pool: vk::CommandPool,
    pub cb: vk::CommandBuffer,
    fence: vk::Fence,
    queries: vk::QueryPool,
    labels: Vec<&'static str>,
}

impl Commands {
    pub fn new(gpu: &Arc<Gpu>) -> Result<Commands> {
        let d = &gpu.device;
        let mut c = Commands::none(gpu);
        // SAFETY (all below): valid create infos on a live device; each object is owned by
        // `c` as soon as it exists.
        c.pool = unsafe {
            d.create_command_pool(
                &vk::CommandPoolCreateInfo::default()
                    .queue_family_index(gpu.queue_family)
                    .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER),
                None,
            )
        }
        .context("creating a command pool")?;
        c.cb = unsafe {
            d.allocate_command_buffers(
                &vk::CommandBufferAllocateInfo::default()
                    .command_pool(c.pool)
                    .command_buffer_count(1),
            )
        }
        .context("allocating a command buffer")?[0];
        c.fence = unsafe { d.create_fence(&vk::FenceCreateInfo::default(), None) }.context("creating a fence")?;
        c.queries = unsafe {
            d.create_query_pool(
                &vk::QueryPoolCreateInfo::default()
                    .query_type(vk::QueryType::TIMESTAMP)
                    .query_count(MAX_TIMESTAMPS),
                None,
            )
        }
        .context("creating a timestamp query pool")?;
        Ok(c)
    }

    /// A stand-in holding no Vulkan objects (destroying null handles does nothing), for the
    /// moment an owner lends its commands out: making real ones for it cost every frame a
    /// command pool, a fence and a query pool.
    pub fn none(gpu: &Arc<Gpu>) -> Commands {
        Commands {
            gpu: gpu.clone(),
            pool: vk::CommandPool::null(),
            cb: vk::CommandBuffer::null(),
            fence: vk::Fence::null(),
            queries: vk::QueryPool::null(),
            labels: Vec::new(),
        }
    }

    /// Starts recording (the previous submission must have been waited for).
    pub fn begin(&mut self) -> Result<()> {
        let d = &self.gpu.device;
        self.labels.clear();
        // SAFETY: the command buffer is not in use (every submit is waited for).
        unsafe {
            d.reset_command_buffer(self.cb, vk::CommandBufferResetFlags::empty())
                .context("resetting the command buffer")?;
            d.begin_command_buffer(self.cb, &vk::CommandBufferBeginInfo::default())
                .context("beginning the command buffer")?;
            d.cmd_reset_query_pool(self.cb, self.queries, 0, MAX_TIMESTAMPS);
        }
        Ok(())
    }

    /// Records a timestamp after all previous work; the time between two timestamps is
    /// reported under the later one's label.
    pub fn timestamp(&mut self, label: &'static str) {
        if self.labels.len() as u32 >= MAX_TIMESTAMPS {
            return;
        }
        // SAFETY: recording into a command buffer in the recording state.
        unsafe {
            self.gpu.device.cmd_write_timestamp(
                self.cb,
                vk::PipelineStageFlags::BOTTOM_OF_PIPE,
                self.queries,
                self.labels.len() as u32,
            )
        };
        self.labels.push(label);
    }

    /// Dispatches `groups` workgroups of a set-0 kernel (split over y beyond the x limit).
    pub fn dispatch(
        &self,
        kernels: &Kernels,
        set: vk::DescriptorSet,
        kernel: Kernel,
        params: &BuildParams,
        groups: u32,
    ) -> Result<()> {
        let (x, y) = shared::types::grid(groups);
        self.dispatch_sets(kernels, &[set], kernel, bytemuck::bytes_of(params), x, y)
    }

    /// Dispatches `x * y` workgroups of `kernel` with descriptor sets `sets` (from set 0)
    /// and 16 bytes of push constants.
    pub fn dispatch_sets(
        &self,
        kernels: &Kernels,
        sets: &[vk::DescriptorSet],
        kernel: Kernel,
        push: &[u8],
        x: u32,
        y: u32,
    ) -> Result<()> {
        self.dispatch_pipeline(kernels, kernels.pipeline(kernel)?, sets, push, x, y);
        Ok(())
    }

    /// Dispatches like [`Commands::dispatch_sets`] with `pipeline`, one of `kernels`' (such
    /// as a specialised one).
    pub fn dispatch_pipeline(
        &self,
        kernels: &Kernels,
        pipeline: vk::Pipeline,
        sets: &[vk::DescriptorSet],
        push: &[u8],
        x: u32,
        y: u32,
    ) {
        if x == 0 || y == 0 {
            return;
        }
        let d = &self.gpu.device;
        // SAFETY: recording state; pipeline, layout and sets belong to this device.
        unsafe {
            d.cmd_bind_pipeline(self.cb, vk::PipelineBindPoint::COMPUTE, pipeline);
            d.cmd_bind_descriptor_sets(self.cb, vk::PipelineBindPoint::COMPUTE, kernels.layout, 0, sets, &[]);
            d.cmd_push_constants(self.cb, kernels.layout, vk::ShaderStageFlags::COMPUTE, 0, push);
            d.cmd_dispatch(self.cb, x, y, 1);
        }
    }

    /// Makes all previous transfer and shader writes visible to later shaders and transfers.
    pub fn barrier(&self) {
        let m = [vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE)
            .dst_access_mask(
                vk::AccessFlags::SHADER_READ
                    | vk::AccessFlags::SHADER_WRITE
                    | vk::AccessFlags::TRANSFER_READ
                    | vk::AccessFlags::TRANSFER_WRITE,
            )];
        let stages = vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER;
        // SAFETY: recording state.
        unsafe {
            self.gpu
                .device
                .cmd_pipeline_barrier(self.cb, stages, stages, vk::DependencyFlags::empty(), &m, &[], &[])
        };
    }

    /// Fills `bytes` bytes of `buf` from `offset` with copies of `word`.
    pub fn fill_range(&self, buf: &Buffer, offset: u64, bytes: u64, word: u32) {
        if bytes == 0 {
            return;
        }
        // SAFETY: recording state; the range is a multiple of 4 within the buffer.
        unsafe { self.gpu.device.cmd_fill_buffer(self.cb, buf.raw, offset, bytes, word) };
    }

    /// Copies `bytes` bytes from `src` at `src_offset` to `dst` at `dst_offset`.
    pub fn copy_range(&self, src: &Buffer, src_offset: u64, dst: &Buffer, dst_offset: u64, bytes: u64) {
        if bytes == 0 {
            return;
        }
        let r = [vk::BufferCopy::default()
            .src_offset(src_offset)
            .dst_offset(dst_offset)
            .size(bytes)];
        // SAFETY: recording state; both buffers hold at least `bytes`.
        unsafe { self.gpu.device.cmd_copy_buffer(self.cb, src.raw, dst.raw, &r) };
    }

    /// Copies `count` values of type `T` from the start of `src` back to the host (records,
    /// submits and waits: the command buffer must not be recording). Large buffers come back
    /// through one staging buffer of at most [`READ_BACK_CHUNK`] bytes, a chunk at a time: a
    /// host-visible copy of the whole (133 MB for a 4K accumulation image) costs more to
    /// allocate and map than the copies themselves.
    pub fn read_back<T: bytemuck::Pod>(&mut self, src: &Buffer, count: usize) -> Result<Vec<T>> {
        let mut out = vec![T::zeroed(); count];
        self.read_back_into(src, &mut out)?;
        Ok(out)
    }

    /// [`Commands::read_back`] into `out` (`out.len()` values from the start of `src`).
    pub fn read_back_into<T: bytemuck::Pod>(&mut self, src: &Buffer, out: &mut [T]) -> Result<()> {
        let size = size_of::<T>();
        if out.is_empty() || size == 0 {
            return Ok(());
        }
        let per_chunk = (READ_BACK_CHUNK as usize / size).clamp(1, out.len());
        let staging = Buffer::new(
            &self.gpu,
            "readback",
            (per_chunk * size) as u64,
            gpu_allocator::MemoryLocation::GpuToCpu,
        )?;
        for (k, part) in out.chunks_mut(per_chunk).enumerate() {
            self.begin()?;
            self.copy_range(
                src,
                (k * per_chunk * size) as u64,
                &staging,
                0,
                std::mem::size_of_val(part) as u64,
            );
            self.submit_wait().context("reading back GPU results")?;
            staging.read_into(part)?;
        }
        Ok(())
    }

    /// Ends recording, submits, and waits for the GPU to finish.
    pub fn submit_wait(&mut self) -> Result<()> {
        self.submit(&[], &[])?;
        self.wait()
    }

    /// Ends recording and submits; the work waits (at the transfer stage) for the semaphores
    /// `wait` and signals `signal` when done. Call [`Commands::wait`] before recording again.
    pub fn submit(&mut self, wait: &[vk::Semaphore], signal: &[vk::Semaphore]) -> Result<()> {
        let d = &self.gpu.device;
        let stages = vec![vk::PipelineStageFlags::TRANSFER; wait.len()];
        // SAFETY: the command buffer is in the recording state and the fence is unsignalled.
        unsafe {
            d.end_command_buffer(self.cb).context("ending the command buffer")?;
            let cbs = [self.cb];
            let submit = [vk::SubmitInfo::default()
                .command_buffers(&cbs)
                .wait_semaphores(wait)
                .wait_dst_stage_mask(&stages)
                .signal_semaphores(signal)];
            d.queue_submit(self.gpu.queue, &submit, self.fence)
                .context("submitting GPU work")?;
        }
        Ok(())
    }

    /// Waits for the last submission to finish; a submission still running after
    /// [`GPU_TIMEOUT_NS`] is an error (a hung kernel), not a hang.
    pub fn wait(&mut self) -> Result<()> {
        let d = &self.gpu.device;
        // SAFETY: the fence belongs to this device and was given to the last submission.
        unsafe {
            let r = d.wait_for_fences(&[self.fence], true, GPU_TIMEOUT_NS);
            if r == Err(vk::Result::TIMEOUT) {
                anyhow::bail!(
                    "the GPU did not finish within {} s: a kernel hangs or the work is far too large",
                    GPU_TIMEOUT_NS / 1_000_000_000
                );
            }
            r.context("waiting for the GPU")?;
            d.reset_fences(&[self.fence]).context("resetting a fence")?;
        }
        Ok(())
    }

    /// Nanoseconds between consecutive timestamps of the last submission, labelled by the later.
    pub fn timings(&self) -> Result<Vec<(&'static str, f64)>> {
        let n = self.labels.len();
        if n < 2 {
            return Ok(Vec::new());
        }
        let mut ticks = vec![0u64; n];
        // SAFETY: the queries were written by the last (waited-for) submission.
        unsafe {
            self.gpu
                .device
                .get_query_pool_results(
                    self.queries,
                    0,
                    &mut ticks,
                    vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
                )
                .context("reading GPU timestamps")?
        };
        Ok((1..n)
            .map(|i| {
                (
                    self.labels[i],
                    ticks[i].wrapping_sub(ticks[i - 1]) as f64 * self.gpu.timestamp_period,
                )
            })
            .collect())
    }
}

impl Drop for Commands {
    fn drop(&mut self) {
        let d = &self.gpu.device;
        // SAFETY: every submission was waited for.
        unsafe {
            d.destroy_query_pool(self.queries, None);
            d.destroy_fence(self.fence, None);
            d.destroy_command_pool(self.pool, None);
        }
    }
}
