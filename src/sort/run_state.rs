//! The per-run state the sort and the scan share: the state buffer's layout (ST_* in
//! glsl/lib/pass_state.glsl), `sort/setup.comp` that starts a run on the GPU, and the
//! look-back status words.

use ash::vk;
use bytemuck::{Pod, Zeroable};

use super::Count;
use crate::error::Result;
use crate::gpu::kernels::push_constants;
use crate::gpu::{glsl, kernels, recorder, Buffer, Context, Kernel};

// Words of the state buffer (ST_* in pass_state.glsl).
/// Words of the state buffer (ST_WORDS in pass_state.glsl).
pub(crate) const STATE_WORDS: usize = glsl::ST_WORDS as usize;
pub(crate) const ST_N: usize = glsl::ST_N as usize;
pub(crate) const ST_REQUESTED: usize = glsl::ST_REQUESTED as usize;
pub(crate) const ST_ERRORS: usize = glsl::ST_ERRORS as usize;
pub(crate) const ST_TOTAL: usize = glsl::ST_TOTAL as usize;
/// Byte offsets of the indirect dispatch arguments in the state buffer.
pub(crate) const ST_ARGS_TILES: u64 = glsl::ST_ARGS_TILES as u64 * 4;
pub(super) const ST_ARGS_CHUNKS: u64 = glsl::ST_ARGS_CHUNKS as u64 * 4;
pub(super) const ST_PASS_ARGS: u64 = glsl::ST_PASS_ARGS as u64 * 4;
pub(super) const ST_ARGS_COPY: u64 = glsl::ST_ARGS_COPY as u64 * 4;
pub(super) const ST_SKIPPED: usize = glsl::ST_SKIPPED as usize;
/// Error bits of the state buffer (ERR_* in pass_state.glsl).
pub use crate::gpu::glsl::{ERR_LOOKBACK, ERR_OVERFLOW};

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub(crate) struct SetupPush {
    pub count: u64,
    pub state: u64,
    pub n: u32,
    pub capacity: u32,
    pub tile_size: u32,
    pub chunk_size: u32,
    pub max_groups_x: u32,
    pub hist_words: u32,
    pub max_chunk_groups: u32,
    pub pad: u32,
}
push_constants!(SORT_SETUP, SetupPush);

/// The histogram grid `sort/setup.comp` sizes (all zero for the scan, which has none).
#[derive(Clone, Copy, Default)]
pub(crate) struct HistGrid {
    /// Keys per block of a histogram workgroup.
    pub chunk: u32,
    /// Workgroups at most (0: one per block); above it each takes several blocks.
    pub max_groups: u32,
    /// Histogram words to zero (passes × 256).
    pub words: u32,
}

/// The per-run state shared by sort and scan: a state buffer (counts, dispatch
/// arguments, histograms, errors) and the look-back status words.
pub(crate) struct RunState {
    pub state: Buffer,
    pub status: Buffer,
    pub setup: Kernel,
    pub capacity: u32,
}

impl RunState {
    pub fn new(ctx: &Context, name: &str, capacity: u32, status_words: u64) -> Result<Self> {
        // Zeroed once: epoch 0 never matches a run's tag, so status words need no clearing.
        let state = ctx.zeroed_buffer(&format!("{name}.state"), (STATE_WORDS * 4) as u64)?;
        let status = ctx.zeroed_buffer(&format!("{name}.status"), status_words.max(1) * 8)?;
        let setup = Kernel::new(ctx, &kernels::SORT_SETUP)?;
        Ok(RunState {
            state,
            status,
            setup,
            capacity,
        })
    }

    pub fn record_setup(
        &self,
        ctx: &Context,
        cmd: vk::CommandBuffer,
        count: Count,
        tile: u32,
        hist: HistGrid,
    ) {
        let (count_addr, n) = match count {
            Count::Host(n) => (0, n),
            Count::Device { buffer, offset } => (buffer.address() + offset, 0),
        };
        let push = SetupPush {
            count: count_addr,
            state: self.state.address(),
            n,
            capacity: self.capacity,
            tile_size: tile,
            chunk_size: hist.chunk,
            max_groups_x: ctx.info().max_compute_work_group_count[0].min(65535),
            hist_words: hist.words,
            max_chunk_groups: hist.max_groups,
            pad: 0,
        };
        self.setup.dispatch(cmd, &push, [1, 1, 1]);
        recorder::barrier(ctx, cmd);
    }

    /// Reads the state words (waits for the device).
    pub fn read(&self, ctx: &Context) -> Result<Vec<u32>> {
        ctx.download(&self.state, 0, 8)
    }

    /// Reads and clears the sticky error bits.
    pub fn take_errors(&self, ctx: &Context) -> Result<u32> {
        let e = self.read(ctx)?[ST_ERRORS];
        if e != 0 {
            ctx.submit_and_wait(|cmd| {
                recorder::fill(ctx, cmd, &self.state, (ST_ERRORS * 4) as u64, 4, 0);
                Ok(())
            })?;
        }
        Ok(e)
    }
}
