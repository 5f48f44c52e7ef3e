//! Submitting to the engine's queue from the host, and counting what it costs: every
//! submission and blocking fence wait made through a [`Context`] (a round trip that is
//! microseconds on lavapipe and a queue drain on a GPU).
//!
//! A submission returns a [`Ticket`]; the host waits for it when it needs the results
//! and may record and submit more work first (the trainer keeps one iteration queued
//! behind the one running). A buffer dropped while submissions are pending is not freed
//! at once: it is parked until the submissions made before its drop completed, so a
//! buffer grown for the next iteration never pulls memory from under the running one.

use std::sync::atomic::Ordering;

use ash::vk;

use super::context::Context;
use super::pending::InFlight;
use crate::error::{Error, Result, VkContext};

/// Queue traffic since the context was made ([`Context::queue_counters`]): what a
/// training iteration or a frame costs the host besides its kernels.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct QueueCounters {
    /// vkQueueSubmit calls.
    pub submits: u64,
    /// Blocking waits for the newest submission: round trips, the queue drains and the
    /// device idles until the host submits again.
    pub fence_waits: u64,
    /// Milliseconds the host spent blocked in those waits.
    pub wait_ms: f64,
    /// Blocking waits for an older submission while newer ones are queued
    /// (back-pressure: the device stays busy with the queued work).
    pub throttle_waits: u64,
    /// Milliseconds the host spent blocked in those.
    pub throttle_ms: f64,
}

impl std::ops::Sub for QueueCounters {
    type Output = QueueCounters;
    fn sub(self, o: QueueCounters) -> QueueCounters {
        QueueCounters {
            submits: self.submits - o.submits,
            fence_waits: self.fence_waits - o.fence_waits,
            wait_ms: self.wait_ms - o.wait_ms,
            throttle_waits: self.throttle_waits - o.throttle_waits,
            throttle_ms: self.throttle_ms - o.throttle_ms,
        }
    }
}

/// A submission made with [`Context::submit`], to wait for with [`Context::wait`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct Ticket(u64);

impl Context {
    /// Records commands with `f` into a fresh primary command buffer and submits it
    /// without waiting; [`Context::wait`] on the ticket makes its device writes visible
    /// to the host (a host barrier ends the command buffer). The command buffer starts
    /// with a barrier, so it sees everything submitted before it.
    pub fn submit<R>(&self, f: impl FnOnce(vk::CommandBuffer) -> Result<R>) -> Result<(R, Ticket)> {
        let inner = &*self.inner;
        let dev = &inner.device;
        let q = &inner.queue_state;
        let pool = inner
            .submit
            .lock()
            .map_err(|_| Error::Gpu("submit lock poisoned".into()))?;
        // Submissions that finished meanwhile give back their fences and parked buffers.
        self.retire_finished(*pool)?;
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
            // Earlier submissions' writes → this one's reads (a pipeline barrier's first
            // scope reaches back across submissions in queue order).
            super::recorder::barrier(self, cmd);
            let r = f(cmd)?;
            // Whatever the commands wrote to host-visible memory is readable once the
            // wait returns (counters, checks: Buffer::read_word, mapped copies).
            super::recorder::host_barrier(self, cmd);
            unsafe { dev.end_command_buffer(cmd) }.vk("vkEndCommandBuffer")?;
            let cmds = [cmd];
            let submit = [vk::SubmitInfo::default().command_buffers(&cmds)];
            unsafe { dev.queue_submit(inner.queue, &submit, fence) }.vk("vkQueueSubmit")?;
            Ok(r)
        };
        match run() {
            Ok(r) => {
                let mut flight = q
                    .flight
                    .lock()
                    .map_err(|_| Error::Gpu("queue lock poisoned".into()))?;
                let serial = q.submitted.load(Ordering::Acquire) + 1;
                flight.push_back(InFlight { serial, fence, cmd });
                q.submitted.store(serial, Ordering::Release);
                q.submits.fetch_add(1, Ordering::Relaxed);
                Ok((r, Ticket(serial)))
            }
            Err(e) => {
                unsafe {
                    dev.destroy_fence(fence, None);
                    dev.free_command_buffers(*pool, &[cmd]);
                }
                Err(e)
            }
        }
    }

    /// Blocks until the submission `t` (and every one before it) completed. Counted as
    /// a fence wait when `t` is the newest submission (the queue drains), as a throttle
    /// wait when newer ones are queued behind it.
    pub fn wait(&self, t: Ticket) -> Result<()> {
        let inner = &*self.inner;
        let q = &inner.queue_state;
        if q.completed.load(Ordering::Acquire) >= t.0 {
            return Ok(());
        }
        let fence = {
            let flight = q
                .flight
                .lock()
                .map_err(|_| Error::Gpu("queue lock poisoned".into()))?;
            flight.iter().find(|s| s.serial == t.0).map(|s| s.fence)
        };
        if let Some(fence) = fence {
            let drain = t.0 == q.submitted.load(Ordering::Acquire);
            let t0 = std::time::Instant::now();
            unsafe { inner.device.wait_for_fences(&[fence], true, u64::MAX) }
                .vk("vkWaitForFences")?;
            let ns = t0.elapsed().as_nanos() as u64;
            if drain {
                q.waits.fetch_add(1, Ordering::Relaxed);
                q.wait_ns.fetch_add(ns, Ordering::Relaxed);
            } else {
                q.throttles.fetch_add(1, Ordering::Relaxed);
                q.throttle_ns.fetch_add(ns, Ordering::Relaxed);
            }
        }
        // A fence signal covers every submission before it in queue order.
        q.completed.fetch_max(t.0, Ordering::AcqRel);
        let pool = inner
            .submit
            .lock()
            .map_err(|_| Error::Gpu("submit lock poisoned".into()))?;
        self.retire_finished(*pool)
    }

    /// Whether submission `t` completed (no blocking).
    pub fn is_done(&self, t: Ticket) -> bool {
        self.inner.queue_state.completed.load(Ordering::Acquire) >= t.0
            || self.poll().is_ok_and(|done| done >= t.0)
    }

    /// Completed submissions learnt from their fences (no blocking); the newest serial
    /// known complete.
    fn poll(&self) -> Result<u64> {
        let q = &self.inner.queue_state;
        let flight = q
            .flight
            .lock()
            .map_err(|_| Error::Gpu("queue lock poisoned".into()))?;
        for s in flight.iter() {
            if s.serial <= q.completed.load(Ordering::Acquire) {
                continue;
            }
            match unsafe { self.inner.device.get_fence_status(s.fence) } {
                Ok(true) => {
                    q.completed.fetch_max(s.serial, Ordering::AcqRel);
                }
                Ok(false) => break,
                Err(e) => {
                    return Err(Error::Vulkan {
                        call: "vkGetFenceStatus",
                        result: e,
                    })
                }
            }
        }
        Ok(q.completed.load(Ordering::Acquire))
    }

    /// Frees the fences, command buffers and parked buffers of completed submissions
    /// (`pool`: the locked command pool).
    fn retire_finished(&self, pool: vk::CommandPool) -> Result<()> {
        let inner = &*self.inner;
        let done = self.poll()?;
        {
            let mut flight = inner
                .queue_state
                .flight
                .lock()
                .map_err(|_| Error::Gpu("queue lock poisoned".into()))?;
            while flight.front().is_some_and(|s| s.serial <= done) {
                let s = flight.pop_front().expect("front exists");
                unsafe {
                    inner.device.destroy_fence(s.fence, None);
                    inner.device.free_command_buffers(pool, &[s.cmd]);
                }
            }
        }
        inner
            .queue_state
            .free_parked(&inner.device, &inner.allocator, false);
        Ok(())
    }

    /// Records commands with `f`, submits them and waits ([`Context::submit`], then
    /// [`Context::wait`]); device writes are then visible to the host. For tools, tests
    /// and uploads; an embedding engine records into its own command buffers instead.
    pub fn submit_and_wait<R>(&self, f: impl FnOnce(vk::CommandBuffer) -> Result<R>) -> Result<R> {
        let (r, t) = self.submit(f)?;
        self.wait(t)?;
        Ok(r)
    }

    /// Blocks until every submission made through this context completed.
    pub fn wait_all(&self) -> Result<()> {
        let newest = self.inner.queue_state.submitted.load(Ordering::Acquire);
        self.wait(Ticket(newest))
    }

    /// Buffers dropped while submissions were pending and not yet freed.
    pub fn parked_buffers(&self) -> usize {
        self.inner.queue_state.parked_count()
    }

    /// Submissions and blocking fence waits made through this context so far (all
    /// threads). Take two readings and subtract them to cost a piece of work.
    pub fn queue_counters(&self) -> QueueCounters {
        let q = &self.inner.queue_state;
        QueueCounters {
            submits: q.submits.load(Ordering::Relaxed),
            fence_waits: q.waits.load(Ordering::Relaxed),
            wait_ms: q.wait_ns.load(Ordering::Relaxed) as f64 * 1e-6,
            throttle_waits: q.throttles.load(Ordering::Relaxed),
            throttle_ms: q.throttle_ns.load(Ordering::Relaxed) as f64 * 1e-6,
        }
    }
}
