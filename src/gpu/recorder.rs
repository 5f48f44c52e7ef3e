//! Recording helpers: barriers, fills and per-stage timestamps on any command buffer
//! (ours or a host engine's).

use ash::vk;

use super::buffer::Buffer;
use super::context::Context;
use crate::error::{Error, Result, VkContext};

/// Full compute→{compute, indirect, transfer} dependency: every write of earlier
/// dispatches/copies/fills is visible to later dispatches, indirect reads and copies.
pub fn barrier(ctx: &Context, cmd: vk::CommandBuffer) {
    let mb = [vk::MemoryBarrier::default()
        .src_access_mask(vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE)
        .dst_access_mask(
            vk::AccessFlags::SHADER_READ
                | vk::AccessFlags::SHADER_WRITE
                | vk::AccessFlags::INDIRECT_COMMAND_READ
                | vk::AccessFlags::TRANSFER_READ
                | vk::AccessFlags::TRANSFER_WRITE,
        )];
    unsafe {
        ctx.device().cmd_pipeline_barrier(
            cmd,
            vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER,
            vk::PipelineStageFlags::COMPUTE_SHADER
                | vk::PipelineStageFlags::DRAW_INDIRECT
                | vk::PipelineStageFlags::TRANSFER,
            vk::DependencyFlags::empty(),
            &mb,
            &[],
            &[],
        )
    };
}

/// Device writes (dispatches, copies, fills) → host reads: recorded last in a command
/// buffer whose results the host reads from mapped memory once its fence signalled.
pub fn host_barrier(ctx: &Context, cmd: vk::CommandBuffer) {
    let mb = [vk::MemoryBarrier::default()
        .src_access_mask(vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE)
        .dst_access_mask(vk::AccessFlags::HOST_READ)];
    unsafe {
        ctx.device().cmd_pipeline_barrier(
            cmd,
            vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER,
            vk::PipelineStageFlags::HOST,
            vk::DependencyFlags::empty(),
            &mb,
            &[],
            &[],
        )
    };
}

/// Starts a region whose dispatches run only if the u32 at `offset` in `predicate` is
/// non-zero when the region starts (VK_EXT_conditional_rendering; the predicate must be
/// written before, behind a barrier to [`conditional_barrier`]'s stage). Fills, copies
/// and buffer updates inside the region always run. Fails where the context has no
/// conditional rendering ([`DeviceInfo::conditional_rendering`](super::DeviceInfo)).
pub fn begin_conditional(
    ctx: &Context,
    cmd: vk::CommandBuffer,
    predicate: &Buffer,
    offset: u64,
) -> Result<()> {
    let ext = ctx
        .inner
        .conditional
        .as_ref()
        .ok_or_else(|| Error::Invalid("the device has no conditional rendering".into()))?;
    let info = vk::ConditionalRenderingBeginInfoEXT::default()
        .buffer(predicate.raw())
        .offset(offset);
    unsafe { (ext.fp().cmd_begin_conditional_rendering_ext)(cmd, &info) };
    Ok(())
}

/// Ends the region begun by [`begin_conditional`].
pub fn end_conditional(ctx: &Context, cmd: vk::CommandBuffer) -> Result<()> {
    let ext = ctx
        .inner
        .conditional
        .as_ref()
        .ok_or_else(|| Error::Invalid("the device has no conditional rendering".into()))?;
    unsafe { (ext.fp().cmd_end_conditional_rendering_ext)(cmd) };
    Ok(())
}

/// Compute writes → the conditional-rendering predicate read.
pub fn conditional_barrier(ctx: &Context, cmd: vk::CommandBuffer) {
    let mb = [vk::MemoryBarrier::default()
        .src_access_mask(vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE)
        .dst_access_mask(vk::AccessFlags::CONDITIONAL_RENDERING_READ_EXT)];
    unsafe {
        ctx.device().cmd_pipeline_barrier(
            cmd,
            vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER,
            vk::PipelineStageFlags::CONDITIONAL_RENDERING_EXT,
            vk::DependencyFlags::empty(),
            &mb,
            &[],
            &[],
        )
    };
}

/// Records a fill of `size` bytes (multiple of 4, or `vk::WHOLE_SIZE`) with `value`.
pub fn fill(
    ctx: &Context,
    cmd: vk::CommandBuffer,
    buf: &Buffer,
    offset: u64,
    size: u64,
    value: u32,
) {
    unsafe {
        ctx.device()
            .cmd_fill_buffer(cmd, buf.raw(), offset, size, value)
    };
}

/// Records zeroing the whole of `buf`.
pub fn zero(ctx: &Context, cmd: vk::CommandBuffer, buf: &Buffer) {
    fill(ctx, cmd, buf, 0, vk::WHOLE_SIZE, 0);
}

/// Records a buffer-to-buffer copy.
pub fn copy(
    ctx: &Context,
    cmd: vk::CommandBuffer,
    src: &Buffer,
    dst: &Buffer,
    src_off: u64,
    dst_off: u64,
    size: u64,
) {
    if size == 0 {
        return;
    }
    let region = [vk::BufferCopy {
        src_offset: src_off,
        dst_offset: dst_off,
        size,
    }];
    unsafe {
        ctx.device()
            .cmd_copy_buffer(cmd, src.raw(), dst.raw(), &region)
    };
}

/// Timestamps written between stages; `stages()` turns them into per-stage durations.
pub struct Timestamps {
    ctx: Context,
    pool: vk::QueryPool,
    capacity: u32,
    labels: Vec<String>,
    /// Marks past `capacity` since `begin` (then `stages()` is an error, not a report
    /// that silently lacks its last stages).
    dropped: u32,
}

impl Timestamps {
    pub fn new(ctx: &Context, capacity: u32) -> Result<Self> {
        let pool = unsafe {
            ctx.device().create_query_pool(
                &vk::QueryPoolCreateInfo::default()
                    .query_type(vk::QueryType::TIMESTAMP)
                    .query_count(capacity),
                None,
            )
        }
        .vk("vkCreateQueryPool")?;
        Ok(Timestamps {
            ctx: ctx.clone(),
            pool,
            capacity,
            labels: Vec::new(),
            dropped: 0,
        })
    }

    /// Resets the pool and writes the starting timestamp.
    pub fn begin(&mut self, cmd: vk::CommandBuffer) {
        self.labels.clear();
        self.dropped = 0;
        unsafe {
            self.ctx
                .device()
                .cmd_reset_query_pool(cmd, self.pool, 0, self.capacity)
        };
        self.write(cmd, "start");
    }

    /// Marks the end of stage `label` (the time since the previous mark).
    pub fn mark(&mut self, cmd: vk::CommandBuffer, label: &str) {
        self.write(cmd, label);
    }

    fn write(&mut self, cmd: vk::CommandBuffer, label: &str) {
        if self.labels.len() as u32 >= self.capacity {
            self.dropped += 1;
            return;
        }
        let q = self.labels.len() as u32;
        unsafe {
            self.ctx.device().cmd_write_timestamp(
                cmd,
                vk::PipelineStageFlags::BOTTOM_OF_PIPE,
                self.pool,
                q,
            )
        };
        self.labels.push(label.to_string());
    }

    /// Per-stage durations in milliseconds, in recording order (after the work finished).
    pub fn stages(&self) -> Result<Vec<(String, f64)>> {
        if self.dropped > 0 {
            return Err(Error::Invalid(format!(
                "{} timestamp marks after `{}` were dropped: the pool holds {} \
                 (Timestamps::new)",
                self.dropped,
                self.labels.last().map_or("", |l| l.as_str()),
                self.capacity
            )));
        }
        let n = self.labels.len();
        if n < 2 {
            return Ok(Vec::new());
        }
        let mut raw = vec![0u64; n];
        unsafe {
            self.ctx.device().get_query_pool_results(
                self.pool,
                0,
                &mut raw,
                vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
            )
        }
        .map_err(|e| Error::Vulkan {
            call: "vkGetQueryPoolResults",
            result: e,
        })?;
        let period = self.ctx.info().timestamp_period_ns as f64;
        Ok((1..n)
            .map(|i| {
                let dt = raw[i].wrapping_sub(raw[i - 1]) as f64 * period * 1e-6;
                (self.labels[i].clone(), dt)
            })
            .collect())
    }
}

impl Drop for Timestamps {
    fn drop(&mut self) {
        unsafe { self.ctx.device().destroy_query_pool(self.pool, None) };
    }
}
