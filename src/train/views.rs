//! The training views on the device.
//!
//! Each view is stored planar (all red, then green, then blue; f32, output resolution)
//! so the loss kernels read it by buffer device address. Views are packed, whole, into
//! chunks of at most [`TrainViews::default_chunk_bytes`] (a quarter of a GiB, or less
//! where the device's `maxMemoryAllocationSize` is smaller), so a capture of any length
//! fits as long as the device memory holds it: a 185-view Mip-NeRF 360 scene at 1297×840
//! is 2.4 GB, more than one allocation may be on most drivers (lavapipe: 2 GiB).

use crate::data::Dataset;
use crate::error::{Error, Result};
use crate::gpu::{Buffer, Context};

/// Largest chunk [`TrainViews::upload`] allocates by default.
pub const MAX_CHUNK_BYTES: u64 = 256 << 20;

/// The ground-truth images of the training views, on the device.
pub struct TrainViews {
    chunks: Vec<Buffer>,
    /// Per view: chunk index and byte offset in it.
    slots: Vec<(usize, u64)>,
}

impl TrainViews {
    /// Chunk size used by [`Trainer`](super::trainer::Trainer): [`MAX_CHUNK_BYTES`], or the device's
    /// largest allocation where that is smaller.
    pub fn default_chunk_bytes(ctx: &Context) -> u64 {
        MAX_CHUNK_BYTES.min(ctx.info().max_memory_allocation_size)
    }

    /// Uploads every frame of `data` (each at its camera's size), packing whole views
    /// into chunks of at most `chunk_bytes` (a view larger than that gets a chunk of its
    /// own).
    pub fn upload(ctx: &Context, data: &Dataset, chunk_bytes: u64) -> Result<TrainViews> {
        let mut sizes = Vec::with_capacity(data.frames.len());
        for f in &data.frames {
            let np = f.camera.width as usize * f.camera.height as usize;
            if f.rgb.len() != np || np == 0 {
                return Err(Error::Invalid(format!(
                    "training image {} has {} pixels, but its camera is {}×{}",
                    f.name,
                    f.rgb.len(),
                    f.camera.width,
                    f.camera.height
                )));
            }
            sizes.push(np);
        }
        let total: u64 = sizes.iter().map(|&np| (3 * np * 4) as u64).sum();
        let mut views = TrainViews {
            chunks: Vec::new(),
            slots: Vec::with_capacity(data.frames.len()),
        };
        let mut start = 0;
        while start < data.frames.len() {
            // Whole views, in order, up to `chunk_bytes` (at least one).
            let mut end = start;
            let mut bytes = 0u64;
            while end < data.frames.len() {
                let b = (3 * sizes[end] * 4) as u64;
                if end > start && bytes + b > chunk_bytes {
                    break;
                }
                bytes += b;
                end += 1;
            }
            let c = views.chunks.len();
            let mut planar = vec![0f32; (bytes / 4) as usize];
            let mut offset = 0usize;
            for (f, &np) in data.frames[start..end].iter().zip(&sizes[start..end]) {
                for (p, rgb) in f.rgb.iter().enumerate() {
                    for ch in 0..3 {
                        planar[offset + ch * np + p] = rgb[ch];
                    }
                }
                views.slots.push((c, offset as u64 * 4));
                offset += 3 * np;
            }
            let name = format!("train.views[{c}]");
            let buf = ctx.buffer_from(&name, &planar).map_err(|e| match e {
                Error::OutOfMemory { .. } => Error::Invalid(format!(
                    "the {} training views ({:.1} GiB as f32) do not fit in device memory \
                     ({e}); train at a lower resolution (--downscale) or on fewer views",
                    data.frames.len(),
                    total as f64 / (1u64 << 30) as f64
                )),
                e => e,
            })?;
            views.chunks.push(buf);
            start = end;
        }
        Ok(views)
    }

    /// Number of views.
    pub fn len(&self) -> usize {
        self.slots.len()
    }

    /// Whether there are no views.
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// Number of device buffers the views are packed into.
    pub fn chunks(&self) -> usize {
        self.chunks.len()
    }

    /// Device bytes held.
    pub fn bytes(&self) -> u64 {
        self.chunks.iter().map(Buffer::size).sum()
    }

    /// The buffer holding `view` and the view's byte offset in it.
    pub fn locate(&self, view: usize) -> (&Buffer, u64) {
        let (c, offset) = self.slots[view];
        (&self.chunks[c], offset)
    }

    /// Device address of `view`'s planar RGB.
    pub fn address(&self, view: usize) -> u64 {
        let (buf, offset) = self.locate(view);
        buf.address() + offset
    }
}
