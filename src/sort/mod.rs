//! Onesweep radix sort of u64 keys (or u32 keys, [`KeyWidth::U32`], for bit ranges below
//! 32: 8 instead of 12 bytes moved per pair and pass) with u32 values (stable, any bit
//! range), recorded into any command buffer with no host read-back; the element count
//! can come from a GPU buffer (indirect dispatch). See `glsl/sort/onesweep.glsl` for the
//! algorithm.
//!
//! Per sort: `setup` (count, dispatch arguments, epoch) → `histogram` (all digits at
//! once) → `hist_scan` (global digit offsets; a digit that is the same for every key
//! skips its pass) → one `onesweep` pass per 8-bit digit, ping-ponging between the
//! caller's primary and alternate buffers → a copy when an odd number of passes was
//! skipped, so the result is where the recorded passes say.
//!
//! Pass kernels ([`SortPass`]): `glsl/sort/onesweep.glsl` scatters each key straight
//! to its destination (the fastest on lavapipe, where a write is a CPU store), and
//! `glsl/sort/onesweep_coalesced.glsl` stages the tile in shared memory in sorted order
//! and writes runs (what a GPU's memory system needs). [`SortPass::for_device`] picks
//! from the device's type, subgroup size and shared memory. The reduce-then-scan passes
//! (`s128`, `s256`: [`SortPass::reduce_then_scan`]) run the coalesced pass without
//! look-back, after a count of every tile's digits and a scan of the counts over the
//! tiles (`glsl/sort/tile_count.glsl`, `tile_scan.comp`): two more dispatches and one
//! more read of the keys per pass, and no workgroup ever waits on another.

use std::ops::Range;

use ash::vk;
use bytemuck::{Pod, Zeroable};

use crate::error::{Error, Result};
use crate::gpu::kernels::push_constants;
use crate::gpu::{glsl, kernels, recorder, Buffer, Context, Kernel, Memory, Timestamps};

mod pass;
mod run_state;
mod scan_pass;
mod settings;
use pass::MIN_TILE;
pub use pass::{PassProbe, SortPass};
pub(crate) use run_state::{
    HistGrid, RunState, ST_ARGS_TILES, ST_ERRORS, ST_N, ST_REQUESTED, ST_TOTAL,
};
pub use run_state::{ERR_LOOKBACK, ERR_OVERFLOW};
use run_state::{ST_ARGS_CHUNKS, ST_ARGS_COPY, ST_PASS_ARGS, ST_SKIPPED};
use scan_pass::ScanKernels;
pub use settings::MAX_LOOP_LIMIT_BACKOFF_TRIPS;

/// Elements per tile of the direct pass (WG × KPT in onesweep.glsl).
pub const SORT_TILE: u32 = glsl::WG * glsl::KPT;
/// Keys per histogram workgroup (HIST_WG × HIST_KPT in glsl/sort/histogram.glsl).
const HIST_CHUNK: u32 = glsl::HIST_WG * glsl::HIST_KPT;
/// Default cap on the histogram's workgroups ([`RadixSort::set_hist_groups`]): the
/// grid of 2^22 keys (4 M, lavapipe's benchmark size) is unchanged, larger sorts give
/// each workgroup several blocks.
const HIST_GROUPS: u32 = 1024;
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct HistPush {
    keys: u64,
    state: u64,
    lo: u32,
    hi: u32,
    passes: u32,
    aggregate: u32,
}
push_constants!(SORT_HISTOGRAM_VARIANTS, HistPush);

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct HistScanPush {
    state: u64,
    passes: u32,
    skip_constant: u32,
}
push_constants!(SORT_HIST_SCAN, HistScanPush);

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct CopyPush {
    keys_src: u64,
    vals_src: u64,
    keys_dst: u64,
    vals_dst: u64,
    state: u64,
    key_words: u32,
    tile_size: u32,
}
push_constants!(SORT_COPY, CopyPush);

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PassPush {
    keys_in: u64,
    vals_in: u64,
    keys_out: u64,
    vals_out: u64,
    state: u64,
    status: u64,
    shift: u32,
    bits: u32,
    pass_index: u32,
    spin_limit: u32,
    generic_rank: u32,
    /// Coalesced passes: look-back words read at once per digit (the direct pass
    /// ignores it).
    lb_window: u32,
    /// Coalesced passes: ALU rounds between two polls of an unpublished look-back word
    /// (the direct pass ignores it).
    lb_backoff: u32,
    pad0: u32,
}
push_constants!(SORT_ONESWEEP_VARIANTS, PassPush);
push_constants!(SORT_ONESWEEP_C128_VARIANTS, PassPush);
push_constants!(SORT_ONESWEEP_C256_VARIANTS, PassPush);
push_constants!(SORT_SCANPASS_S128_VARIANTS, PassPush);
push_constants!(SORT_SCANPASS_S256_VARIANTS, PassPush);
push_constants!(SORT_PROBE_COPY_C128_VARIANTS, PassPush);
push_constants!(SORT_PROBE_TILE_C128_VARIANTS, PassPush);
push_constants!(SORT_PROBE_COPY_C256_VARIANTS, PassPush);
push_constants!(SORT_PROBE_TILE_C256_VARIANTS, PassPush);

/// Where the element count of a run comes from.
#[derive(Clone, Copy)]
pub enum Count<'a> {
    /// Known when recording.
    Host(u32),
    /// A u32 at byte `offset` of `buffer`, written by earlier GPU work.
    Device { buffer: &'a Buffer, offset: u64 },
}

/// Keys and values to sort, and same-sized scratch buffers for the ping-pong.
pub struct SortBuffers<'a> {
    pub keys: &'a Buffer,
    pub values: &'a Buffer,
    pub keys_alt: &'a Buffer,
    pub values_alt: &'a Buffer,
}

/// Width of the keys in a sort's key buffers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KeyWidth {
    /// u64 keys, any bit range within 0..64.
    U64,
    /// u32 keys: bit ranges within 0..32.
    U32,
}

impl KeyWidth {
    /// Bytes per key.
    pub fn bytes(self) -> u64 {
        match self {
            KeyWidth::U64 => 8,
            KeyWidth::U32 => 4,
        }
    }

    /// Bits a key holds.
    pub fn bits(self) -> u32 {
        match self {
            KeyWidth::U64 => 64,
            KeyWidth::U32 => 32,
        }
    }
}

/// Which pair of buffers holds the sorted result.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sorted {
    Primary,
    Alternate,
}

/// Number of 8-bit digit passes for a bit range.
pub fn passes_for(bits: &Range<u32>) -> u32 {
    (bits.end - bits.start).div_ceil(8)
}

/// The decoupled look-back of a sort run, summed over its passes and tiles.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct LookbackCounters {
    /// Status words read that carried a flag: per digit, one per predecessor tile
    /// walked (at least one per digit of every tile but the first).
    pub steps: u32,
    /// Extra polls of status words not yet published (waiting on a predecessor).
    pub waits: u32,
    /// Rounds in which a workgroup gave up waiting and recounted a predecessor's keys.
    pub fallbacks: u32,
}

/// The radix sort: kernels plus the state and look-back buffers for up to `capacity`
/// elements. One instance serves one sort at a time on the queue (record several sorts
/// one after another into a command buffer freely; they are ordered by barriers).
pub struct RadixSort {
    ctx: Context,
    run: RunState,
    hist: Kernel,
    hist32: Kernel,
    hist_scan: Kernel,
    copy: Kernel,
    kind: SortPass,
    pass: Kernel,
    pass32: Kernel,
    /// Reduce-then-scan passes only.
    scan: Option<ScanKernels>,
    generic_rank: bool,
    skip_constant: bool,
    spin_limit: Option<u32>,
    hist_groups: u32,
    lookback_window: Option<u32>,
    lookback_backoff: u32,
    /// A probe run in place of the pass kernel, with its kernels (u64, u32 keys).
    probe: Option<(PassProbe, Kernel, Kernel)>,
}

impl RadixSort {
    /// Largest capacity: look-back values and indices are 32-bit, and a count rounded
    /// up to whole tiles of any pass (≤ 3 840 keys) must fit too.
    pub const MAX_CAPACITY: u32 = u32::MAX - 4096;
    /// Largest look-back window (LB_WINDOW in glsl/sort/onesweep_coalesced.glsl).
    pub const MAX_LOOKBACK_WINDOW: u32 = glsl::LB_WINDOW;

    /// The sort with the device's pass kernel ([`SortPass::for_device`]), or the one
    /// `SVRASTER_SORT_PASS` names (`direct`, `c128`, `c256`, `s128`, `s256`), so that
    /// every sort of a run — frames, training, `bench` — can be measured with another
    /// pass kernel.
    pub fn new(ctx: &Context, capacity: u32) -> Result<Self> {
        let pass = SortPass::for_run(ctx.info()).map_err(Error::Invalid)?;
        Self::with_pass(ctx, capacity, pass)
    }

    /// The sort with a chosen pass kernel (tests, `bench sort --pass`).
    pub fn with_pass(ctx: &Context, capacity: u32, kind: SortPass) -> Result<Self> {
        if capacity > Self::MAX_CAPACITY {
            return Err(Error::Capacity(format!(
                "sort capacity {capacity} exceeds the maximum {}",
                Self::MAX_CAPACITY
            )));
        }
        if !kind.supported(ctx.info()) {
            let i = ctx.info();
            return Err(Error::Invalid(format!(
                "sort pass `{}` needs subgroups of ≥ {} lanes and {} bytes of shared memory;                  {} has {} lanes and {} bytes",
                kind.name(),
                kind.min_subgroup(),
                kind.shared_bytes(),
                i.name,
                i.subgroup_size,
                i.max_compute_shared_memory_size
            )));
        }
        let tiles = capacity.div_ceil(MIN_TILE).max(1) as u64;
        let [pass, pass32] = kind.kernels();
        let scan = kind
            .count_kernels()
            .map(|k| ScanKernels::new(ctx, k))
            .transpose()?;
        Ok(RadixSort {
            ctx: ctx.clone(),
            run: RunState::new(ctx, "radix-sort", capacity, tiles * 256)?,
            hist: Kernel::new(ctx, kernels::SORT_HISTOGRAM_VARIANTS[0])?,
            hist32: Kernel::new(ctx, kernels::SORT_HISTOGRAM_VARIANTS[1])?,
            hist_scan: Kernel::new(ctx, &kernels::SORT_HIST_SCAN)?,
            copy: Kernel::new(ctx, &kernels::SORT_COPY)?,
            kind,
            pass: Kernel::new(ctx, pass)?,
            pass32: Kernel::new(ctx, pass32)?,
            scan,
            generic_rank: false,
            skip_constant: true,
            spin_limit: None,
            hist_groups: HIST_GROUPS,
            lookback_window: None,
            lookback_backoff: 0,
            probe: None,
        })
    }

    pub fn capacity(&self) -> u32 {
        self.run.capacity
    }

    /// Records a sort of the first `count` pairs of `bufs` by key bits `bits`
    /// (`lo..hi`, 0 ≤ lo < hi ≤ 64; an empty range sorts nothing). Returns which buffer
    /// pair holds the result: `Primary` after an even number of passes. The caller must
    /// make earlier writes to the inputs (and the count) visible to compute shaders and
    /// must not read the result before a compute→consumer barrier. A count above the
    /// capacity is clamped and flagged (see [`RadixSort::take_errors`]).
    ///
    /// With `ts`, a timestamp is written after each stage.
    pub fn record(
        &self,
        cmd: vk::CommandBuffer,
        bufs: &SortBuffers,
        count: Count,
        bits: Range<u32>,
        ts: Option<&mut Timestamps>,
    ) -> Result<Sorted> {
        self.record_keys(cmd, bufs, count, bits, KeyWidth::U64, ts)
    }

    /// [`Self::record`] with keys of `width` (u32 keys: `bits` within 0..32, key buffers
    /// of 4 bytes per pair).
    pub fn record_keys(
        &self,
        cmd: vk::CommandBuffer,
        bufs: &SortBuffers,
        count: Count,
        bits: Range<u32>,
        width: KeyWidth,
        mut ts: Option<&mut Timestamps>,
    ) -> Result<Sorted> {
        if bits.start > bits.end || bits.end > width.bits() {
            return Err(Error::Invalid(format!(
                "bit range {bits:?} is not within 0..{} ({width:?} keys)",
                width.bits()
            )));
        }
        let need = self.run.capacity as u64;
        let kw = width.bytes();
        for (b, w) in [
            (bufs.keys, kw),
            (bufs.keys_alt, kw),
            (bufs.values, 4),
            (bufs.values_alt, 4),
        ] {
            if b.size() < need * w {
                return Err(Error::Invalid(format!(
                    "buffer `{}` holds {} bytes; a sort of capacity {} needs {}",
                    b.name(),
                    b.size(),
                    need,
                    need * w
                )));
            }
        }
        let passes = passes_for(&bits);
        if passes == 0 {
            return Ok(Sorted::Primary);
        }
        let ctx = &self.ctx;
        let tile = self.kind.tile();
        let hist = HistGrid {
            chunk: HIST_CHUNK,
            max_groups: self.hist_groups,
            words: passes * 256,
        };
        self.run.record_setup(ctx, cmd, count, tile, hist);
        if let Some(t) = ts.as_deref_mut() {
            t.mark(cmd, "sort.setup");
        }
        let state = self.run.state.address();
        let (hist, pass) = match (width, &self.probe) {
            (KeyWidth::U64, None) => (&self.hist, &self.pass),
            (KeyWidth::U32, None) => (&self.hist32, &self.pass32),
            (KeyWidth::U64, Some((_, p, _))) => (&self.hist, p),
            (KeyWidth::U32, Some((_, _, p))) => (&self.hist32, p),
        };
        hist.dispatch_indirect(
            cmd,
            &HistPush {
                keys: bufs.keys.address(),
                state,
                lo: bits.start,
                hi: bits.end,
                passes,
                aggregate: (ctx.info().subgroup_size > 8 || self.generic_rank) as u32,
            },
            self.run.state.raw(),
            ST_ARGS_CHUNKS,
        );
        recorder::barrier(ctx, cmd);
        self.hist_scan.dispatch(
            cmd,
            &HistScanPush {
                state,
                passes,
                skip_constant: self.skip_constant as u32,
            },
            [1, 1, 1],
        );
        recorder::barrier(ctx, cmd);
        if let Some(t) = ts.as_deref_mut() {
            t.mark(cmd, "sort.histogram");
        }
        let spin = self.spin_limit();
        let window = self.lookback_window();
        for p in 0..passes {
            let shift = bits.start + 8 * p;
            let (ki, vi, ko, vo) = if p % 2 == 0 {
                (bufs.keys, bufs.values, bufs.keys_alt, bufs.values_alt)
            } else {
                (bufs.keys_alt, bufs.values_alt, bufs.keys, bufs.values)
            };
            let bits_p = (bits.end - shift).min(8);
            if let Some(sk) = &self.scan {
                // Reduce-then-scan: every tile's digit counts, then their prefixes over
                // the tiles, into the status words the pass reads.
                let digit = scan_pass::Digit {
                    keys: (ki, ko),
                    width,
                    shift,
                    bits: bits_p,
                    pass_index: p,
                    tile,
                };
                sk.record(ctx, cmd, &self.run, &digit, self.generic_rank);
                if let Some(t) = ts.as_deref_mut() {
                    t.mark(cmd, &format!("sort.count{p}"));
                }
            }
            let push = PassPush {
                keys_in: ki.address(),
                vals_in: vi.address(),
                keys_out: ko.address(),
                vals_out: vo.address(),
                state,
                status: self.run.status.address(),
                shift,
                bits: bits_p,
                pass_index: p,
                spin_limit: spin,
                generic_rank: self.generic_rank as u32,
                lb_window: window,
                lb_backoff: self.lookback_backoff(),
                pad0: 0,
            };
            pass.dispatch_indirect(
                cmd,
                &push,
                self.run.state.raw(),
                ST_PASS_ARGS + 12 * p as u64,
            );
            recorder::barrier(ctx, cmd);
            if let Some(t) = ts.as_deref_mut() {
                t.mark(cmd, &format!("sort.pass{p}"));
            }
        }
        // An odd number of skipped passes left the result in the other pair: move it
        // (0 workgroups otherwise).
        let (result, other) = if passes.is_multiple_of(2) {
            (
                (bufs.keys, bufs.values, Sorted::Primary),
                (bufs.keys_alt, bufs.values_alt),
            )
        } else {
            (
                (bufs.keys_alt, bufs.values_alt, Sorted::Alternate),
                (bufs.keys, bufs.values),
            )
        };
        self.copy.dispatch_indirect(
            cmd,
            &CopyPush {
                keys_src: other.0.address(),
                vals_src: other.1.address(),
                keys_dst: result.0.address(),
                vals_dst: result.1.address(),
                state,
                key_words: (kw / 4) as u32,
                tile_size: tile,
            },
            self.run.state.raw(),
            ST_ARGS_COPY,
        );
        recorder::barrier(ctx, cmd);
        if let Some(t) = ts {
            t.mark(cmd, "sort.copy");
        }
        Ok(result.2)
    }

    /// The run-state buffer (counts, dispatch arguments, sticky errors at word
    /// `ST_ERRORS`), for checks recorded after a sort.
    pub(crate) fn state_buffer(&self) -> &Buffer {
        &self.run.state
    }

    /// Reads and clears the sticky error bits (`ERR_OVERFLOW`, `ERR_LOOKBACK`).
    pub fn take_errors(&self) -> Result<u32> {
        self.run.take_errors(&self.ctx)
    }

    /// `(count used, count requested)` of the last recorded run (waits for the device).
    pub fn last_count(&self) -> Result<(u32, u32)> {
        let s = self.run.read(&self.ctx)?;
        Ok((s[ST_N], s[ST_REQUESTED]))
    }

    /// What the last run's decoupled look-back did, over all its passes (waits for the
    /// device): where a pass's time goes on a GPU (`bench sort --json`).
    pub fn last_lookback(&self) -> Result<LookbackCounters> {
        let s = self.run.read(&self.ctx)?;
        Ok(LookbackCounters {
            steps: s[glsl::ST_LB_STEPS as usize],
            waits: s[glsl::ST_LB_WAITS as usize],
            fallbacks: s[glsl::ST_LB_FALLBACKS as usize],
        })
    }

    /// Bit p set: pass p of the last run was skipped (its digit was the same for every
    /// key). Waits for the device.
    pub fn last_skipped(&self) -> Result<u32> {
        Ok(self
            .ctx
            .download::<u32>(&self.run.state, ST_SKIPPED as u64 * 4, 1)?[0])
    }

    /// Convenience: uploads, sorts by `bits`, waits and returns the sorted pairs.
    pub fn sort(
        &self,
        keys: &[u64],
        values: &[u32],
        bits: Range<u32>,
    ) -> Result<(Vec<u64>, Vec<u32>)> {
        self.sort_keys(keys, values, bits, KeyWidth::U64)
    }

    /// [`Self::sort`] of u32 keys (`bits` within 0..32).
    pub fn sort_u32(
        &self,
        keys: &[u32],
        values: &[u32],
        bits: Range<u32>,
    ) -> Result<(Vec<u32>, Vec<u32>)> {
        self.sort_keys(keys, values, bits, KeyWidth::U32)
    }

    fn sort_keys<K: Pod>(
        &self,
        keys: &[K],
        values: &[u32],
        bits: Range<u32>,
        width: KeyWidth,
    ) -> Result<(Vec<K>, Vec<u32>)> {
        if keys.len() != values.len() {
            return Err(Error::Invalid(format!(
                "{} keys but {} values",
                keys.len(),
                values.len()
            )));
        }
        let n = u32::try_from(keys.len())
            .ok()
            .filter(|&n| n <= self.run.capacity)
            .ok_or_else(|| {
                Error::Capacity(format!(
                    "{} keys exceed the sort capacity {}",
                    keys.len(),
                    self.run.capacity
                ))
            })?;
        let b = SortScratch::new(&self.ctx, self.run.capacity)?;
        self.ctx.upload(&b.keys, 0, keys)?;
        self.ctx.upload(&b.values, 0, values)?;
        let which = self.ctx.submit_and_wait(|cmd| {
            self.record_keys(
                cmd,
                &b.as_buffers(),
                Count::Host(n),
                bits.clone(),
                width,
                None,
            )
        })?;
        let errors = self.take_errors()?;
        if errors != 0 {
            return Err(Error::Gpu(format!(
                "radix sort reported error bits {errors:#x}"
            )));
        }
        let (k, v) = b.result(which);
        Ok((
            self.ctx.download(k, 0, n as usize)?,
            self.ctx.download(v, 0, n as usize)?,
        ))
    }
}

/// Owned key/value buffers (primary + alternate) for a sort of `capacity` pairs.
pub struct SortScratch {
    pub keys: Buffer,
    pub values: Buffer,
    pub keys_alt: Buffer,
    pub values_alt: Buffer,
}

impl SortScratch {
    pub fn new(ctx: &Context, capacity: u32) -> Result<Self> {
        let c = capacity as u64;
        Ok(SortScratch {
            keys: ctx.buffer("sort.keys", c * 8, Memory::Device)?,
            values: ctx.buffer("sort.values", c * 4, Memory::Device)?,
            keys_alt: ctx.buffer("sort.keys_alt", c * 8, Memory::Device)?,
            values_alt: ctx.buffer("sort.values_alt", c * 4, Memory::Device)?,
        })
    }
    pub fn as_buffers(&self) -> SortBuffers<'_> {
        SortBuffers {
            keys: &self.keys,
            values: &self.values,
            keys_alt: &self.keys_alt,
            values_alt: &self.values_alt,
        }
    }
    pub fn result(&self, which: Sorted) -> (&Buffer, &Buffer) {
        match which {
            Sorted::Primary => (&self.keys, &self.values),
            Sorted::Alternate => (&self.keys_alt, &self.values_alt),
        }
    }
}
