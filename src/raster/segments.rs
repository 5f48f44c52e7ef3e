//! Segmented frames ("Segments" in glsl/lib/raster_params.glsl): a tile's sorted list cut
//! into segments of S entries, each composited (and in training back-propagated) by its
//! own workgroup, so an image with few tiles still fills a GPU.

use ash::vk;

use super::params::{ChunkPush, ParamsPush, SegComposePush};
use super::{Renderer, STAT_SEG_ARGS};
use crate::gpu::{glsl, recorder};

impl Renderer {
    /// The segmented composite ("Segments" in raster_params.glsl): slots planned per
    /// tile, every segment's own transmittance, the state in front of each segment, the
    /// exact walk of every segment, the merge.
    pub(super) fn record_segments(
        &self,
        cmd: vk::CommandBuffer,
        k: &crate::gpu::Kernel,
        tiles_xy: [u32; 3],
        tiles: u32,
    ) {
        let ctx = &self.ctx;
        let params = self.params.address();
        self.k
            .seg_plan
            .dispatch_1d(cmd, &ParamsPush { frame: params }, tiles);
        recorder::barrier(ctx, cmd);
        let args = STAT_SEG_ARGS * 4;
        for (mode, compose) in [
            (glsl::SEG_TRANSMIT, glsl::SEG_PREFIX),
            (glsl::SEG_EXACT, glsl::SEG_MERGE),
        ] {
            let push = ChunkPush {
                frame: params,
                chunk: 0,
                mode,
            };
            k.dispatch_indirect(cmd, &push, self.stats.raw(), args);
            recorder::barrier(ctx, cmd);
            let push = SegComposePush {
                frame: params,
                mode: compose,
                pad: 0,
            };
            self.k.seg_compose.dispatch(cmd, &push, tiles_xy);
            recorder::barrier(ctx, cmd);
        }
    }

    /// Entries per segment of a tile's list (0: segments off, every tile walked by one
    /// workgroup per chunk). Segments let many workgroups share a long list, so small
    /// images with few tiles still fill a GPU. Default:
    /// [`crate::gpu::DeviceInfo::segment_entries`].
    /// Under a loop limit ([`crate::gpu::DeviceInfo::loop_limit`]) segments are at most
    /// a forward or backward chunk long.
    pub fn set_segment_entries(&mut self, entries: u32) {
        let info = self.ctx.info();
        // The backward walks the same segments in one dispatch: its chunk bounds them too.
        let most = info
            .forward_chunk_entries()
            .min(info.backward_chunk_entries(false));
        self.seg_size = entries.min(most);
    }

    /// Entries per segment (0: off).
    pub fn segment_entries(&self) -> u32 {
        self.seg_size
    }
}
