//! Moving data between the host and device buffers: buffers created with contents
//! (uploaded, zeroed, or host-visible counters), uploads and downloads through staging
//! buffers, each a submission the host waits for.

use ash::vk;

use super::buffer::{Buffer, Memory};
use super::context::Context;
use super::recorder;
use crate::error::{Error, Result};

impl Context {
    /// A device buffer holding `data`.
    pub fn buffer_from<T: bytemuck::Pod>(&self, name: &str, data: &[T]) -> Result<Buffer> {
        let buf = self.buffer(name, std::mem::size_of_val(data) as u64, Memory::Device)?;
        self.upload(&buf, 0, data)?;
        Ok(buf)
    }

    /// A host-visible buffer of `words` u32 counters, zeroed: kernels add to them
    /// rarely (error and give-up counts), the host reads them with
    /// [`Buffer::read_word`] without a submission once the work that wrote them
    /// completed (behind a [`recorder::host_barrier`]).
    pub fn counter_buffer(&self, name: &str, words: u64) -> Result<Buffer> {
        let mut buf = self.buffer(name, words.max(1) * 4, Memory::Readback)?;
        buf.mapped_mut()
            .ok_or_else(|| Error::Gpu(format!("{name} is not host-visible")))?
            .fill(0);
        Ok(buf)
    }

    /// A device buffer of `size` bytes (at least 4) filled with zeros before it is returned.
    pub fn zeroed_buffer(&self, name: &str, size: u64) -> Result<Buffer> {
        let buf = self.buffer(name, size.max(4), Memory::Device)?;
        self.submit_and_wait(|cmd| {
            recorder::zero(self, cmd, &buf);
            Ok(())
        })?;
        Ok(buf)
    }

    /// Copies `data` into `dst` at byte `offset` through a staging buffer and waits.
    pub fn upload<T: bytemuck::Pod>(&self, dst: &Buffer, offset: u64, data: &[T]) -> Result<()> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        if bytes.is_empty() {
            return Ok(());
        }
        if offset + bytes.len() as u64 > dst.size() {
            return Err(Error::Invalid(format!(
                "upload of {} bytes at {offset} overruns buffer `{}` ({} bytes)",
                bytes.len(),
                dst.name(),
                dst.size()
            )));
        }
        let mut staging = self.buffer("staging-upload", bytes.len() as u64, Memory::Upload)?;
        staging
            .mapped_mut()
            .ok_or_else(|| Error::Gpu("upload staging buffer is not host-visible".into()))?
            .copy_from_slice(bytes);
        self.submit_and_wait(|cmd| {
            let region = [vk::BufferCopy {
                src_offset: 0,
                dst_offset: offset,
                size: bytes.len() as u64,
            }];
            unsafe {
                self.device()
                    .cmd_copy_buffer(cmd, staging.raw(), dst.raw(), &region)
            };
            Ok(())
        })
    }

    /// Reads `count` elements of `T` from `src` at byte `offset` (waits for the copy).
    pub fn download<T: bytemuck::Pod>(
        &self,
        src: &Buffer,
        offset: u64,
        count: usize,
    ) -> Result<Vec<T>> {
        let nbytes = (count * std::mem::size_of::<T>()) as u64;
        if offset + nbytes > src.size() {
            return Err(Error::Invalid(format!(
                "download of {nbytes} bytes at {offset} overruns buffer `{}` ({} bytes)",
                src.name(),
                src.size()
            )));
        }
        if count == 0 {
            return Ok(Vec::new());
        }
        let staging = self.buffer("staging-readback", nbytes, Memory::Readback)?;
        self.submit_and_wait(|cmd| {
            let region = [vk::BufferCopy {
                src_offset: offset,
                dst_offset: 0,
                size: nbytes,
            }];
            unsafe {
                self.device()
                    .cmd_copy_buffer(cmd, src.raw(), staging.raw(), &region)
            };
            Ok(())
        })?;
        let bytes = staging
            .mapped()
            .ok_or_else(|| Error::Gpu("readback staging buffer is not host-visible".into()))?;
        let mut out = vec![T::zeroed(); count];
        bytemuck::cast_slice_mut::<T, u8>(&mut out).copy_from_slice(bytes);
        Ok(out)
    }

    /// Reads a whole buffer as `T`s.
    pub fn download_all<T: bytemuck::Pod>(&self, src: &Buffer) -> Result<Vec<T>> {
        self.download(src, 0, src.size() as usize / std::mem::size_of::<T>())
    }
}
