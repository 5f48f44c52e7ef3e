//! Submitting to the engine's queue from the host, and counting what it costs: every
//! submission and blocking fence wait made through a [`Context`] (a round trip that is
//! microseconds on lavapipe and a queue drain on a GPU).

use std::sync::atomic::{AtomicU64, Ordering};

use ash::vk;

use super::context::Context;
use crate::error::{Error, Result, VkContext};

/// Queue traffic since the context was made ([`Context::queue_counters`]): what a
/// training iteration or a frame costs the host besides its kernels.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct QueueCounters {
    /// vkQueueSubmit calls.
    pub submits: u64,
    /// Blocking fence waits (each a round trip: the host stops until the queue drains).
    pub fence_waits: u64,
    /// Milliseconds the host spent blocked in those waits.
    pub wait_ms: f64,
}

impl std::ops::Sub for QueueCounters {
    type Output = QueueCounters;
    fn sub(self, o: QueueCounters) -> QueueCounters {
        QueueCounters {
            submits: self.submits - o.submits,
            fence_waits: self.fence_waits - o.fence_waits,
            wait_ms: self.wait_ms - o.wait_ms,
        }
    }
}

#[derive(Default)]
pub(crate) struct QueueStats {
    submits: AtomicU64,
    waits: AtomicU64,
    wait_ns: AtomicU64,
}

impl Context {
    /// Records commands with `f` into a fresh primary command buffer, submits it and
    /// waits for it; device writes are then visible to the host (a host barrier ends
    /// the command buffer). For tools, tests and uploads; an embedding engine records into its
    /// own command buffers instead.
    pub fn submit_and_wait<R>(&self, f: impl FnOnce(vk::CommandBuffer) -> Result<R>) -> Result<R> {
        let dev = &self.inner.device;
        let pool = self
            .inner
            .submit
            .lock()
            .map_err(|_| Error::Gpu("submit lock poisoned".into()))?;
        let cmd = unsafe {
            dev.allocate_command_buffers(
                &vk::CommandBufferAllocateInfo::default()
                    .command_pool(*pool)
                    .level(vk::CommandBufferLevel::PRIMARY)
                    .command_buffer_count(1),
            )
        }
        .vk("vkAllocateCommandBuffers")?[0];
        let fence = match unsafe { dev.create_fence(&vk::FenceCreateInfo::default(), None) } {
            Ok(f) => f,
            Err(e) => {
                unsafe { dev.free_command_buffers(*pool, &[cmd]) };
                return Err(Error::Vulkan {
                    call: "vkCreateFence",
                    result: e,
                });
            }
        };
        let run = || -> Result<R> {
            unsafe {
                dev.begin_command_buffer(
                    cmd,
                    &vk::CommandBufferBeginInfo::default()
                        .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT),
                )
            }
            .vk("vkBeginCommandBuffer")?;
            let r = f(cmd)?;
            // Whatever the commands wrote to host-visible memory is readable once the
            // wait returns (counters, checks: Buffer::read_word, mapped copies).
            super::recorder::host_barrier(self, cmd);
            unsafe { dev.end_command_buffer(cmd) }.vk("vkEndCommandBuffer")?;
            let cmds = [cmd];
            let submit = [vk::SubmitInfo::default().command_buffers(&cmds)];
            unsafe { dev.queue_submit(self.inner.queue, &submit, fence) }.vk("vkQueueSubmit")?;
            let q = &self.inner.queue_stats;
            q.submits.fetch_add(1, Ordering::Relaxed);
            let t0 = std::time::Instant::now();
            unsafe { dev.wait_for_fences(&[fence], true, u64::MAX) }.vk("vkWaitForFences")?;
            q.waits.fetch_add(1, Ordering::Relaxed);
            q.wait_ns
                .fetch_add(t0.elapsed().as_nanos() as u64, Ordering::Relaxed);
            Ok(r)
        };
        let r = run();
        unsafe {
            dev.destroy_fence(fence, None);
            dev.free_command_buffers(*pool, &[cmd]);
        }
        r
    }

    /// Submissions and blocking fence waits made through this context so far (all
    /// threads). Take two readings and subtract them to cost a piece of work.
    pub fn queue_counters(&self) -> QueueCounters {
        let q = &self.inner.queue_stats;
        QueueCounters {
            submits: q.submits.load(Ordering::Relaxed),
            fence_waits: q.waits.load(Ordering::Relaxed),
            wait_ms: q.wait_ns.load(Ordering::Relaxed) as f64 * 1e-6,
        }
    }
}
