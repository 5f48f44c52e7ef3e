//! The reduce-then-scan passes' extra kernels ([`super::SortPass::Scan128`],
//! [`super::SortPass::Scan256`]): per digit pass, every tile's digit counts
//! (`glsl/sort/tile_count.glsl`) and their prefixes over the tiles
//! (`glsl/sort/tile_scan.comp`), written into the status words the pass then reads.

use ash::vk;
use bytemuck::{Pod, Zeroable};

use super::run_state::{RunState, ST_PASS_ARGS};
use super::KeyWidth;
use crate::error::Result;
use crate::gpu::kernels::push_constants;
use crate::gpu::{kernels, recorder, Buffer, Context, Kernel, KernelSource};

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct TileCountPush {
    keys_in: u64,
    keys_out: u64,
    state: u64,
    counts: u64,
    shift: u32,
    bits: u32,
    pass_index: u32,
    generic_rank: u32,
}
push_constants!(SORT_TILE_COUNT_S128_VARIANTS, TileCountPush);
push_constants!(SORT_TILE_COUNT_S256_VARIANTS, TileCountPush);

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct TileScanPush {
    state: u64,
    counts: u64,
    pass_index: u32,
    tile_size: u32,
}
push_constants!(SORT_TILE_SCAN, TileScanPush);

/// One digit pass as the count needs it.
pub(super) struct Digit<'a> {
    /// The pass's input and output key buffers (a skipped pass before swaps them).
    pub keys: (&'a Buffer, &'a Buffer),
    pub width: KeyWidth,
    pub shift: u32,
    pub bits: u32,
    pub pass_index: u32,
    /// Keys per tile of the pass.
    pub tile: u32,
}

/// The kernels a reduce-then-scan pass adds: tile counts (u64, u32 keys), their scan.
pub(super) struct ScanKernels {
    count: Kernel,
    count32: Kernel,
    scan: Kernel,
}

impl ScanKernels {
    pub(super) fn new(ctx: &Context, [count, count32]: [&'static KernelSource; 2]) -> Result<Self> {
        Ok(ScanKernels {
            count: Kernel::new(ctx, count)?,
            count32: Kernel::new(ctx, count32)?,
            scan: Kernel::new(ctx, &kernels::SORT_TILE_SCAN)?,
        })
    }

    /// Records the count and the scan of one digit pass, each followed by a barrier.
    pub(super) fn record(
        &self,
        ctx: &Context,
        cmd: vk::CommandBuffer,
        run: &RunState,
        d: &Digit,
        generic_rank: bool,
    ) {
        let count = match d.width {
            KeyWidth::U64 => &self.count,
            KeyWidth::U32 => &self.count32,
        };
        let state = run.state.address();
        count.dispatch_indirect(
            cmd,
            &TileCountPush {
                keys_in: d.keys.0.address(),
                keys_out: d.keys.1.address(),
                state,
                counts: run.status.address(),
                shift: d.shift,
                bits: d.bits,
                pass_index: d.pass_index,
                generic_rank: generic_rank as u32,
            },
            run.state.raw(),
            ST_PASS_ARGS + 12 * d.pass_index as u64,
        );
        recorder::barrier(ctx, cmd);
        self.scan.dispatch(
            cmd,
            &TileScanPush {
                state,
                counts: run.status.address(),
                pass_index: d.pass_index,
                tile_size: d.tile,
            },
            [256, 1, 1],
        );
        recorder::barrier(ctx, cmd);
    }
}
