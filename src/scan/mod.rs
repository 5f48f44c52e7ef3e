//! Exclusive prefix sum of u32 (wrapping) in one pass with decoupled look-back,
//! recorded into any command buffer; the count may come from a GPU buffer.

use ash::vk;
use bytemuck::{Pod, Zeroable};

use crate::error::{Error, Result};
use crate::gpu::kernels::push_constants;
use crate::gpu::{kernels, recorder, Buffer, Context, Kernel, Memory};
use crate::sort::{Count, RunState, ST_ARGS_TILES, ST_N, ST_TOTAL};

/// Elements per scan tile (WG × IPT in scan.comp).
pub const SCAN_TILE: u32 = 256 * 8;

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ScanPush {
    src: u64,
    dst: u64,
    state: u64,
    status: u64,
    total: u64,
    spin_limit: u32,
    pad: u32,
}
push_constants!(SCAN_SCAN, ScanPush);

/// The prefix scan and its state for up to `capacity` elements.
pub struct PrefixScan {
    ctx: Context,
    run: RunState,
    scan: Kernel,
}

impl PrefixScan {
    pub fn new(ctx: &Context, capacity: u32) -> Result<Self> {
        if capacity > u32::MAX - SCAN_TILE {
            return Err(Error::Capacity(format!(
                "scan capacity {capacity} is too large"
            )));
        }
        let tiles = capacity.div_ceil(SCAN_TILE).max(1) as u64;
        Ok(PrefixScan {
            ctx: ctx.clone(),
            run: RunState::new(ctx, "prefix-scan", capacity, tiles)?,
            scan: Kernel::new(ctx, &kernels::SCAN_SCAN)?,
        })
    }

    pub fn capacity(&self) -> u32 {
        self.run.capacity
    }

    /// Records `output[i] = input[0] + … + input[i-1]` for the first `count` elements,
    /// and the total into `total` (a u32 at the given byte offset) if given. `output`
    /// must not alias `input`.
    pub fn record(
        &self,
        cmd: vk::CommandBuffer,
        input: &Buffer,
        output: &Buffer,
        count: Count,
        total: Option<(&Buffer, u64)>,
    ) -> Result<()> {
        if input.raw() == output.raw() {
            return Err(Error::Invalid(
                "prefix scan output must not alias its input".into(),
            ));
        }
        let need = self.run.capacity as u64 * 4;
        for b in [input, output] {
            if b.size() < need {
                return Err(Error::Invalid(format!(
                    "buffer `{}` holds {} bytes; a scan of capacity {} needs {need}",
                    b.name(),
                    b.size(),
                    self.run.capacity
                )));
            }
        }
        let ctx = &self.ctx;
        self.run
            .record_setup(ctx, cmd, count, SCAN_TILE, crate::sort::HistGrid::default());
        let push = ScanPush {
            src: input.address(),
            dst: output.address(),
            state: self.run.state.address(),
            status: self.run.status.address(),
            total: total.map(|(b, o)| b.address() + o).unwrap_or(0),
            spin_limit: ctx.info().lookback_spin_limit(),
            pad: 0,
        };
        self.scan
            .dispatch_indirect(cmd, &push, self.run.state.raw(), ST_ARGS_TILES);
        recorder::barrier(ctx, cmd);
        Ok(())
    }

    /// The run-state buffer (sticky errors at word `ST_ERRORS`), for checks recorded
    /// after a scan.
    pub(crate) fn state_buffer(&self) -> &crate::gpu::Buffer {
        &self.run.state
    }

    /// Reads and clears the sticky error bits (see `sort::ERR_*`).
    pub fn take_errors(&self) -> Result<u32> {
        self.run.take_errors(&self.ctx)
    }

    /// Total of the last run (waits for the device).
    pub fn last_total(&self) -> Result<u32> {
        let s = self.run.read(&self.ctx)?;
        Ok(if s[ST_N] == 0 { 0 } else { s[ST_TOTAL] })
    }

    /// Convenience: uploads, scans, waits; returns the exclusive scan and the total.
    pub fn scan(&self, data: &[u32]) -> Result<(Vec<u32>, u32)> {
        let n = u32::try_from(data.len())
            .ok()
            .filter(|&n| n <= self.run.capacity)
            .ok_or_else(|| {
                Error::Capacity(format!(
                    "{} elements exceed the scan capacity {}",
                    data.len(),
                    self.run.capacity
                ))
            })?;
        let cap = self.run.capacity as u64 * 4;
        let input = self.ctx.buffer("scan.input", cap, Memory::Device)?;
        let output = self.ctx.buffer("scan.output", cap, Memory::Device)?;
        self.ctx.upload(&input, 0, data)?;
        self.ctx
            .submit_and_wait(|cmd| self.record(cmd, &input, &output, Count::Host(n), None))?;
        let errors = self.take_errors()?;
        if errors != 0 {
            return Err(Error::Gpu(format!(
                "prefix scan reported error bits {errors:#x}"
            )));
        }
        Ok((
            self.ctx.download(&output, 0, n as usize)?,
            self.last_total()?,
        ))
    }
}
