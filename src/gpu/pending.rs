//! What the context tracks of its submissions (below the context, which holds it): the
//! queue counters, the submissions in flight, and buffers dropped while submissions were
//! pending, parked until those complete (see `queue.rs` for submitting and waiting).

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

use ash::vk;
use gpu_allocator::vulkan::{Allocation, Allocator};

/// A submission not yet known complete.
pub(super) struct InFlight {
    pub(super) serial: u64,
    pub(super) fence: vk::Fence,
    pub(super) cmd: vk::CommandBuffer,
}

/// A buffer dropped while submissions were pending, freed once `serial` completed.
pub(crate) struct Parked {
    serial: u64,
    raw: vk::Buffer,
    allocation: Option<Allocation>,
}

/// The context's submissions: counters, the ones in flight, parked buffers.
#[derive(Default)]
pub(crate) struct QueueState {
    pub(super) submits: AtomicU64,
    pub(super) waits: AtomicU64,
    pub(super) wait_ns: AtomicU64,
    pub(super) throttles: AtomicU64,
    pub(super) throttle_ns: AtomicU64,
    /// Serial of the newest submission (0: none yet).
    pub(super) submitted: AtomicU64,
    /// Every submission up to this serial is known complete.
    pub(super) completed: AtomicU64,
    pub(super) flight: Mutex<VecDeque<InFlight>>,
    pub(super) parked: Mutex<Vec<Parked>>,
}

impl QueueState {
    /// Parks a dropped buffer if submissions are pending; gives it back otherwise.
    pub(crate) fn park(
        &self,
        raw: vk::Buffer,
        allocation: Option<Allocation>,
    ) -> Option<(vk::Buffer, Option<Allocation>)> {
        let Ok(mut parked) = self.parked.lock() else {
            return Some((raw, allocation));
        };
        let submitted = self.submitted.load(Ordering::Acquire);
        if self.completed.load(Ordering::Acquire) >= submitted {
            return Some((raw, allocation));
        }
        parked.push(Parked {
            serial: submitted,
            raw,
            allocation,
        });
        None
    }

    /// Buffers parked now (for tests and counters).
    pub(crate) fn parked_count(&self) -> usize {
        self.parked.lock().map_or(0, |p| p.len())
    }
}

/// Frees a buffer now.
pub(crate) fn free_buffer(
    device: &ash::Device,
    allocator: &Mutex<Option<Allocator>>,
    raw: vk::Buffer,
    allocation: Option<Allocation>,
) {
    if let Some(a) = allocation {
        if let Ok(mut guard) = allocator.lock() {
            if let Some(alloc) = guard.as_mut() {
                let _ = alloc.free(a);
            }
        }
    }
    unsafe { device.destroy_buffer(raw, None) };
}

impl QueueState {
    /// Frees the parked buffers whose submissions completed (all with `everything`).
    pub(crate) fn free_parked(
        &self,
        device: &ash::Device,
        allocator: &Mutex<Option<Allocator>>,
        everything: bool,
    ) {
        let done = self.completed.load(Ordering::Acquire);
        let ready: Vec<Parked> = match self.parked.lock() {
            Ok(mut p) => {
                let (ready, keep) = std::mem::take(&mut *p)
                    .into_iter()
                    .partition(|b| everything || b.serial <= done);
                *p = keep;
                ready
            }
            Err(_) => return,
        };
        for b in ready {
            free_buffer(device, allocator, b.raw, b.allocation);
        }
    }

    /// Destroys the fences of every submission still tracked (the device is idle).
    pub(crate) fn destroy_in_flight(&self, device: &ash::Device) {
        if let Ok(mut f) = self.flight.lock() {
            for s in f.drain(..) {
                unsafe { device.destroy_fence(s.fence, None) };
            }
        }
    }
}
