//! The GPU side of a topology change: the kernels' push-constant blocks, the
//! per-candidate buffers (with the sort and scan of the same capacity) and the byte
//! layout of the structure upload.

use bytemuck::{Pod, Zeroable};

use crate::error::Result;
use crate::gpu::kernels::push_constants;
use crate::gpu::{Buffer, Context, Memory};
use crate::scan::PrefixScan;
use crate::sort::RadixSort;

/// Bit of the dedup flags: more than 8 candidates share a grid point.
pub(super) const FLAG_LONG_RUN: u32 = 1;

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(super) struct CandidatesPush {
    pub(super) path: u64,
    pub(super) info: u64,
    pub(super) src: u64,
    pub(super) old_corners: u64,
    pub(super) old_geo: u64,
    pub(super) old_m: u64,
    pub(super) old_v: u64,
    pub(super) keys: u64,
    pub(super) vals: u64,
    pub(super) cand: u64,
    pub(super) voxels: u32,
    pub(super) shift: u32,
    pub(super) bits: u32,
    pub(super) planes: u32,
}
push_constants!(ADAPT_TOPOLOGY_CANDIDATES, CandidatesPush);

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(super) struct HeadsPush {
    pub(super) keys: u64,
    pub(super) heads: u64,
    pub(super) flags: u64,
    pub(super) count: u32,
    pub(super) pad: u32,
}
push_constants!(ADAPT_DEDUP_HEADS, HeadsPush);

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(super) struct MergePush {
    pub(super) keys: u64,
    pub(super) vals: u64,
    pub(super) heads: u64,
    pub(super) scan: u64,
    pub(super) cand: u64,
    pub(super) corners: u64,
    pub(super) out_keys: u64,
    pub(super) out_vals: u64,
    pub(super) count: u32,
    pub(super) shift: u32,
    pub(super) bits: u32,
    pub(super) planes: u32,
}
push_constants!(ADAPT_DEDUP_MERGE, MergePush);

/// Per-candidate device buffers with the sort and scan of the same capacity.
pub(super) struct CandidateBuffers {
    pub(super) capacity: u32,
    pub(super) sort: RadixSort,
    pub(super) scan: PrefixScan,
    pub(super) keys: Buffer,
    pub(super) vals: Buffer,
    pub(super) keys_alt: Buffer,
    pub(super) vals_alt: Buffer,
    /// Candidate values, `[capacity][planes]` (geo, geo m, geo v).
    pub(super) cand: Buffer,
    pub(super) heads: Buffer,
    pub(super) scan_out: Buffer,
    pub(super) corners: Buffer,
    /// Unique values, `[planes][capacity]`.
    pub(super) out_vals: Buffer,
}

impl CandidateBuffers {
    pub(super) fn new(ctx: &Context, capacity: u32) -> Result<Self> {
        let c = u64::from(capacity);
        let dev = |name: &str, bytes: u64| ctx.buffer(name, bytes, Memory::Device);
        Ok(CandidateBuffers {
            capacity,
            sort: RadixSort::new(ctx, capacity)?,
            scan: PrefixScan::new(ctx, capacity)?,
            keys: dev("topology.keys", c * 8)?,
            vals: dev("topology.vals", c * 4)?,
            keys_alt: dev("topology.keys_alt", c * 8)?,
            vals_alt: dev("topology.vals_alt", c * 4)?,
            cand: dev("topology.cand", c * 12)?,
            heads: dev("topology.heads", c * 4)?,
            scan_out: dev("topology.scan", c * 4)?,
            corners: dev("topology.corners", c * 4)?,
            out_vals: dev("topology.out_vals", c * 12)?,
        })
    }
}

/// Byte layout of the upload (host → device input) buffer: the new voxels' structure.
pub(super) struct InputLayout {
    pub(super) path: u64,
    pub(super) info: u64,
    pub(super) src: u64,
    pub(super) level: u64,
    pub(super) end: u64,
}

impl InputLayout {
    pub(super) fn new(voxels: u64) -> Self {
        let path = 0;
        let info = (path + voxels * 8).next_multiple_of(16);
        let src = (info + voxels * 4).next_multiple_of(16);
        let level = (src + voxels * 4).next_multiple_of(16);
        let end = level + voxels * 4;
        InputLayout {
            path,
            info,
            src,
            level,
            end,
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(super) struct GatherPush {
    pub(super) index: u64,
    pub(super) src: u64,
    pub(super) dst: u64,
    pub(super) rows: u32,
    pub(super) width: u32,
    /// 1: both sides in the blocked SH layout ([`crate::scene::SHS_BLOCK`]).
    pub(super) blocked: u32,
    pub(super) pad: u32,
}
push_constants!(ADAPT_GATHER_ROWS, GatherPush);

pub(super) fn write_bytes(dst: &mut [u8], offset: u64, src: &[u8]) {
    let o = offset as usize;
    dst[o..o + src.len()].copy_from_slice(src);
}
