//! Buffers: gpu-allocator memory, always addressable by device address
//! (GL_EXT_buffer_reference), so arrays are not limited by `maxStorageBufferRange`.

use ash::vk;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};
use gpu_allocator::MemoryLocation;

use super::context::{Context, Inner};
use crate::error::{Error, Result};
use std::sync::Arc;

/// Where a buffer lives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Memory {
    /// Device-local; reached from the host only through copies.
    Device,
    /// Host-visible, written by the host (uploads, parameters).
    Upload,
    /// Host-visible, read by the host (results, counters).
    Readback,
}

/// A buffer usable as storage buffer (by device address), transfer source/destination
/// and indirect-dispatch argument source. Freed on drop.
pub struct Buffer {
    inner: Arc<Inner>,
    raw: vk::Buffer,
    allocation: Option<Allocation>,
    size: u64,
    address: u64,
    name: String,
}

impl Buffer {
    pub fn raw(&self) -> vk::Buffer {
        self.raw
    }
    /// Size in bytes as requested.
    pub fn size(&self) -> u64 {
        self.size
    }
    /// Device address of byte 0.
    pub fn address(&self) -> u64 {
        self.address
    }
    pub fn name(&self) -> &str {
        &self.name
    }
    /// The mapped bytes when the buffer is host-visible.
    pub fn mapped(&self) -> Option<&[u8]> {
        self.allocation
            .as_ref()
            .and_then(|a| a.mapped_slice())
            .map(|s| &s[..self.size as usize])
    }
    /// The u32 at word `i` of a host-visible buffer (no submission; the work that wrote
    /// it must have completed).
    pub fn read_word(&self, i: usize) -> Result<u32> {
        let bytes = self
            .mapped()
            .ok_or_else(|| Error::Gpu(format!("`{}` is not host-visible", self.name)))?;
        let b = bytes
            .get(4 * i..4 * i + 4)
            .ok_or_else(|| Error::Invalid(format!("word {i} is past `{}`", self.name)))?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    pub fn mapped_mut(&mut self) -> Option<&mut [u8]> {
        let size = self.size as usize;
        self.allocation
            .as_mut()
            .and_then(|a| a.mapped_slice_mut())
            .map(|s| &mut s[..size])
    }
}

impl Drop for Buffer {
    /// Frees the buffer, or parks it until the submissions pending now completed (they
    /// may use it; see [`Context::submit`]).
    fn drop(&mut self) {
        let allocation = self.allocation.take();
        if let Some((raw, allocation)) = self.inner.queue_state.park(self.raw, allocation) {
            super::pending::free_buffer(&self.inner.device, &self.inner.allocator, raw, allocation);
        }
    }
}

impl Context {
    /// Creates a buffer of `size` bytes (a zero size is rounded up to 16 bytes, Vulkan
    /// forbids empty buffers). Fails with a clear error past the device's allocation
    /// limit or when memory runs out; the device is never lost over it.
    pub fn buffer(&self, name: &str, size: u64, memory: Memory) -> Result<Buffer> {
        let inner = &self.inner;
        let alloc_size = size.max(16).next_multiple_of(16);
        let limit = inner.info.max_memory_allocation_size;
        if limit > 0 && alloc_size > limit {
            return Err(Error::TooLarge {
                name: name.into(),
                bytes: size,
                limit,
            });
        }
        let usage = vk::BufferUsageFlags::STORAGE_BUFFER
            | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS
            | vk::BufferUsageFlags::TRANSFER_SRC
            | vk::BufferUsageFlags::TRANSFER_DST
            | vk::BufferUsageFlags::INDIRECT_BUFFER
            | if inner.conditional.is_some() {
                vk::BufferUsageFlags::CONDITIONAL_RENDERING_EXT
            } else {
                vk::BufferUsageFlags::empty()
            };
        let raw = unsafe {
            inner.device.create_buffer(
                &vk::BufferCreateInfo::default()
                    .size(alloc_size)
                    .usage(usage)
                    .sharing_mode(vk::SharingMode::EXCLUSIVE),
                None,
            )
        }
        .map_err(|e| match e {
            vk::Result::ERROR_OUT_OF_DEVICE_MEMORY | vk::Result::ERROR_OUT_OF_HOST_MEMORY => {
                Error::OutOfMemory {
                    name: name.into(),
                    bytes: size,
                    detail: e.to_string(),
                }
            }
            e => Error::Vulkan {
                call: "vkCreateBuffer",
                result: e,
            },
        })?;
        let mut requirements = unsafe { inner.device.get_buffer_memory_requirements(raw) };
        // Kernels may access any buffer through 16-byte vector views (glsl/lib/common.glsl,
        // V4s; the Adam step asserts it): every buffer starts 16-byte aligned.
        requirements.alignment = requirements.alignment.max(16);
        let location = match memory {
            Memory::Device => MemoryLocation::GpuOnly,
            Memory::Upload => MemoryLocation::CpuToGpu,
            Memory::Readback => MemoryLocation::GpuToCpu,
        };
        let allocation = {
            let mut guard = inner
                .allocator
                .lock()
                .map_err(|_| Error::Gpu("allocator lock poisoned".into()))?;
            let alloc = guard
                .as_mut()
                .ok_or_else(|| Error::Gpu("allocator gone".into()))?;
            alloc.allocate(&AllocationCreateDesc {
                name,
                requirements,
                location,
                linear: true,
                allocation_scheme: AllocationScheme::GpuAllocatorManaged,
            })
        };
        let allocation = match allocation {
            Ok(a) => a,
            Err(e) => {
                unsafe { inner.device.destroy_buffer(raw, None) };
                return Err(Error::OutOfMemory {
                    name: name.into(),
                    bytes: size,
                    detail: e.to_string(),
                });
            }
        };
        if let Err(e) = unsafe {
            inner
                .device
                .bind_buffer_memory(raw, allocation.memory(), allocation.offset())
        } {
            if let Ok(mut g) = inner.allocator.lock() {
                if let Some(a) = g.as_mut() {
                    let _ = a.free(allocation);
                }
            }
            unsafe { inner.device.destroy_buffer(raw, None) };
            return Err(Error::Vulkan {
                call: "vkBindBufferMemory",
                result: e,
            });
        }
        let address = unsafe {
            inner
                .device
                .get_buffer_device_address(&vk::BufferDeviceAddressInfo::default().buffer(raw))
        };
        self.set_name(raw, name);
        Ok(Buffer {
            inner: inner.clone(),
            raw,
            allocation: Some(allocation),
            size,
            address,
            name: name.into(),
        })
    }

    /// Bytes currently allocated by this context's allocator.
    pub fn allocated_bytes(&self) -> u64 {
        self.inner
            .allocator
            .lock()
            .ok()
            .and_then(|g| {
                g.as_ref()
                    .map(|a| a.generate_report().total_allocated_bytes)
            })
            .unwrap_or(0)
    }
}

/// A buffer that grows on demand, with the engine's one growth policy: a request of `n`
/// bytes that does not fit allocates 1.25·n (a slowly growing need — voxels after each
/// subdivision, entries per view — does not reallocate at every step, and the slack of
/// the largest per-voxel buffers stays a quarter), capped at the device's largest
/// allocation, at least 16 bytes; the contents are not kept.
pub struct GrowBuffer {
    name: &'static str,
    memory: Memory,
    buf: Option<Buffer>,
}

impl GrowBuffer {
    /// An empty device-local buffer (nothing allocated until [`Self::ensure`]).
    pub fn new(name: &'static str) -> GrowBuffer {
        Self::with_memory(name, Memory::Device)
    }

    /// An empty buffer in `memory` (e.g. [`Memory::Upload`] staging).
    pub fn with_memory(name: &'static str, memory: Memory) -> GrowBuffer {
        GrowBuffer {
            name,
            memory,
            buf: None,
        }
    }

    /// The size a request of `bytes` allocates.
    pub fn grown_size(ctx: &Context, bytes: u64) -> u64 {
        let bytes = bytes.max(16);
        let want = bytes.saturating_add(bytes / 4);
        let limit = ctx.info().max_memory_allocation_size;
        if want > limit && bytes <= limit {
            limit
        } else {
            want
        }
    }

    /// Makes the buffer hold at least `bytes`; returns whether it was reallocated. The
    /// old buffer is freed first (peak memory is the new size alone), so no recorded
    /// command buffer that uses it may still be pending.
    pub fn ensure(&mut self, ctx: &Context, bytes: u64) -> Result<bool> {
        if self.fits(bytes) {
            return Ok(false);
        }
        self.buf = None;
        self.buf = Some(ctx.buffer(self.name, Self::grown_size(ctx, bytes), self.memory)?);
        Ok(true)
    }

    /// Like [`Self::ensure`], but the old buffer is moved to `retired` instead of freed
    /// (for buffers that command buffers recorded earlier, not yet completed, still use).
    pub fn ensure_retiring(
        &mut self,
        ctx: &Context,
        bytes: u64,
        retired: &mut Vec<Buffer>,
    ) -> Result<bool> {
        if self.fits(bytes) {
            return Ok(false);
        }
        let new = ctx.buffer(self.name, Self::grown_size(ctx, bytes), self.memory)?;
        if let Some(old) = self.buf.replace(new) {
            retired.push(old);
        }
        Ok(true)
    }

    /// The buffer, if allocated.
    pub fn buffer(&self) -> Option<&Buffer> {
        self.buf.as_ref()
    }

    /// The buffer, mutably (to write a host-visible one), if allocated.
    pub fn buffer_mut(&mut self) -> Option<&mut Buffer> {
        self.buf.as_mut()
    }

    /// Frees the buffer now (the next [`Self::ensure`] allocates afresh).
    pub fn release(&mut self) {
        self.buf = None;
    }

    fn fits(&self, bytes: u64) -> bool {
        self.buf.as_ref().is_some_and(|b| b.size() >= bytes.max(16))
    }

    /// The buffer (panics if [`Self::ensure`] was never called: a recording bug).
    pub fn get(&self) -> &Buffer {
        self.buf.as_ref().expect("buffer ensured before use")
    }

    /// Device address of the buffer (see [`Self::get`]).
    pub fn address(&self) -> u64 {
        self.get().address()
    }

    /// Bytes allocated (0 before the first [`Self::ensure`]).
    pub fn bytes(&self) -> u64 {
        self.buf.as_ref().map_or(0, |b| b.size())
    }
}
