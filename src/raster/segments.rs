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
        self.seg_size = entries.min(self.segment_bound());
        self.seg_auto = false;
    }

    /// Lets every frame choose its segment length from its tile count, at most
    /// `longest` entries ([`auto_segment_entries`]; what GPUs do by default).
    pub fn set_segment_entries_auto(&mut self, longest: u32) {
        self.seg_size = longest.min(self.segment_bound());
        self.seg_auto = self.seg_size > 0;
    }

    /// The backward walks the same segments in one dispatch: its chunk bounds them too.
    fn segment_bound(&self) -> u32 {
        let info = self.ctx.info();
        info.forward_chunk_entries()
            .min(info.backward_chunk_entries(false))
    }

    /// Entries per segment of the last recorded frame (else of the next one when fixed,
    /// or the longest allowed when chosen per frame); 0: off.
    pub fn segment_entries(&self) -> u32 {
        self.last.map_or(self.seg_size, |p| p.seg_size)
    }

    /// The segment length of a frame with `tiles` tiles and `entry_cap` entry slots:
    /// fixed, or chosen from the tile count, then doubled while the segments' state
    /// would not fit in half of one allocation.
    pub(super) fn frame_segment_entries(&self, tiles: u32) -> u32 {
        if self.seg_size == 0 {
            return 0;
        }
        let mut s = if self.seg_auto {
            auto_segment_entries(tiles, self.seg_size)
        } else {
            return self.seg_size;
        };
        let limit = self.ctx.info().max_memory_allocation_size / 2;
        while s < self.seg_size {
            let slots = u64::from(tiles) + u64::from(self.entry_cap / s) + 1;
            if slots * u64::from(glsl::SEG_CHANNELS) * 256 * 4 <= limit {
                break;
            }
            s *= 2;
        }
        s
    }
}

/// A tile count at which a GPU is full without segments: measured on an NVIDIA H200
/// (132 SMs; `bench train`, lego, 262 144 voxels, docs/NVIDIA.md): 400² (625 tiles) was
/// as fast unsegmented as with 2 048-entry segments and slower with shorter ones, while
/// 100² (49 tiles) and 200² (169) were fastest with 256 and 512.
const FULL_TILES: f64 = 640.0;

/// Segment length for a frame of `tiles` tiles, at most `longest`: `longest` scaled by
/// the frame's share of 640 tiles (a full H200), to the nearest power of two, at least 256 (or
/// `longest` if that is less). Fewer tiles → shorter segments → more workgroups per
/// tile. A frame with enough tiles keeps `longest`, which still splits the few very
/// long lists of a trained scene (its longest tile lists run to 20× the mean).
pub fn auto_segment_entries(tiles: u32, longest: u32) -> u32 {
    if longest == 0 {
        return 0;
    }
    let want = f64::from(longest) * f64::from(tiles) / FULL_TILES;
    let p = want.max(1.0).log2().round().min(31.0) as u32;
    (1u32 << p).clamp(256.min(longest), longest)
}
