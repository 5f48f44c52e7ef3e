//! The radix sort's settings: the pass's look-back (window, spin limit, back-off), the
//! histogram's grid, constant-digit skipping, the generic ranking and the pass probes.
//! Defaults come from the device; tests and `bench sort` set them.

use super::{PassProbe, RadixSort, SortPass};
use crate::error::{Error, Result};
use crate::gpu::Kernel;

/// Back-off rounds one stalled digit may spend in all on a device with a loop limit
/// ([`RadixSort::lookback_backoff`]).
pub const MAX_LOOP_LIMIT_BACKOFF_TRIPS: u32 = 8192;

/// The back-off a pass runs with: `rounds`, capped on loop-limit devices so that
/// `spin × rounds` ≤ [`MAX_LOOP_LIMIT_BACKOFF_TRIPS`].
fn effective_backoff(rounds: u32, spin: u32, loop_limit: bool) -> u32 {
    if loop_limit {
        rounds.min(MAX_LOOP_LIMIT_BACKOFF_TRIPS / spin.max(1))
    } else {
        rounds
    }
}

impl RadixSort {
    /// Runs `probe` in place of every digit pass (None: the pass itself), to time a
    /// part of the pass's work (`bench sort --probe`): while a probe is set, a recorded
    /// "sort" leaves what [`PassProbe`] defines, not sorted keys. The setup, the
    /// histogram and, for reduce-then-scan passes, the tile counts run as before. Only
    /// the coalesced and reduce-then-scan passes have probes.
    pub fn set_probe(&mut self, probe: Option<PassProbe>) -> Result<()> {
        self.probe = match probe {
            None => None,
            Some(p) => {
                let [k64, k32] = p.kernels(self.kind).ok_or_else(|| {
                    Error::Invalid(format!(
                        "pass `{}` has no probes: choose a coalesced or reduce-then-scan \
                         pass (c128, c256, s128, s256)",
                        self.kind.name()
                    ))
                })?;
                Some((
                    p,
                    Kernel::new(&self.ctx, k64)?,
                    Kernel::new(&self.ctx, k32)?,
                ))
            }
        };
        Ok(())
    }

    /// The probe run in place of the passes ([`RadixSort::set_probe`]).
    pub fn probe(&self) -> Option<PassProbe> {
        self.probe.as_ref().map(|p| p.0)
    }

    /// Workgroups of the histogram kernel at most (0: one per 4 096 keys). Each ends
    /// with one global add per digit of every pass (2 048 for 64-bit keys), so at
    /// 2^24 keys one workgroup per 4 096 keys would make 8.4 M contended adds; above
    /// the cap each workgroup takes several blocks. `bench sort --hist-groups` sweeps it.
    pub fn set_hist_groups(&mut self, groups: u32) {
        self.hist_groups = groups;
    }

    /// Look-back status words each digit of a coalesced pass reads at once, 1 to
    /// [`RadixSort::MAX_LOOKBACK_WINDOW`] (default:
    /// [`DeviceInfo::lookback_window`](crate::gpu::DeviceInfo::lookback_window)); the
    /// direct pass reads one. `bench sort --window` sweeps it.
    pub fn set_lookback_window(&mut self, words: Option<u32>) -> Result<()> {
        if let Some(w) = words {
            if !(1..=Self::MAX_LOOKBACK_WINDOW).contains(&w) {
                return Err(Error::Invalid(format!(
                    "look-back window {w}: must be 1 to {}",
                    Self::MAX_LOOKBACK_WINDOW
                )));
            }
        }
        self.lookback_window = words;
        Ok(())
    }

    /// The look-back window the coalesced passes use.
    pub fn lookback_window(&self) -> u32 {
        self.lookback_window
            .unwrap_or_else(|| self.ctx.info().lookback_window())
    }

    /// ALU rounds a coalesced pass spends between two polls of a look-back word that is
    /// not yet published (default 0: polls back to back). CUB's look-back sleeps
    /// between polls so that waiting workgroups leave the memory system to the working
    /// ones; SPIR-V has no sleep, so this is busy work with no memory access. The
    /// direct pass ignores it; `bench sort --backoff` sweeps it (issue 33: does polling
    /// slow the pass on a GPU?).
    pub fn set_lookback_backoff(&mut self, rounds: u32) {
        self.lookback_backoff = rounds;
    }

    /// The back-off the coalesced passes use ([`RadixSort::set_lookback_backoff`]):
    /// on a device with a loop limit ([`DeviceInfo::loop_limit`](crate::gpu::DeviceInfo::loop_limit):
    /// llvmpipe before Mesa 25 stops an invocation after 65 535 loop trips in all and
    /// falls through), at most [`MAX_LOOP_LIMIT_BACKOFF_TRIPS`] rounds per stalled
    /// digit (`spin limit × back-off`), so the rounds of a few stalls stay far below it.
    pub fn lookback_backoff(&self) -> u32 {
        effective_backoff(
            self.lookback_backoff,
            self.spin_limit(),
            self.ctx.info().loop_limit(),
        )
    }

    /// The look-back polls before the fallback the passes use
    /// ([`RadixSort::set_spin_limit`], else the device's).
    pub fn spin_limit(&self) -> u32 {
        self.spin_limit
            .unwrap_or_else(|| self.ctx.info().lookback_spin_limit())
    }

    /// The histogram's workgroup cap ([`RadixSort::set_hist_groups`]).
    pub fn hist_groups(&self) -> u32 {
        self.hist_groups
    }

    /// Look-back polls of a predecessor tile before its digits are recounted (default:
    /// [`DeviceInfo::lookback_spin_limit`](crate::gpu::DeviceInfo::lookback_spin_limit)).
    /// 0 recounts every predecessor that has not published yet, so tests reach the
    /// fallback; `bench sort --spin` sweeps it.
    pub fn set_spin_limit(&mut self, polls: Option<u32>) {
        self.spin_limit = polls;
    }

    /// The pass kernel this sort runs.
    pub fn pass(&self) -> SortPass {
        self.kind
    }

    /// With `on` (the default), a pass whose digit is the same for every key is skipped
    /// on the GPU; off, every pass runs (tests; the full cost in benchmarks).
    pub fn set_skip_constant(&mut self, on: bool) {
        self.skip_constant = on;
    }

    /// With `on`, the passes rank keys with one ballot per digit bit on every subgroup
    /// size instead of the 8-lane shuffle comparison (`glsl/sort/onesweep.glsl`), and the
    /// histogram adds a digit a whole subgroup shares once, so the paths that real GPUs
    /// (32 or 64 lanes) take are exercised on lavapipe. The result is the same; for
    /// tests.
    #[doc(hidden)]
    pub fn set_generic_rank(&mut self, on: bool) {
        self.generic_rank = on;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_is_capped_only_under_a_loop_limit() {
        assert_eq!(effective_backoff(512, 4096, false), 512);
        assert_eq!(effective_backoff(64, 256, true), 32);
        assert_eq!(effective_backoff(16, 256, true), 16);
        // Spin 0 (every stall recounted at once): no polls, nothing to cap by it.
        assert_eq!(
            effective_backoff(64, 0, true),
            64.min(MAX_LOOP_LIMIT_BACKOFF_TRIPS)
        );
        for (rounds, spin) in [(64u32, 256u32), (1 << 20, 1), (7, 5000)] {
            assert!(effective_backoff(rounds, spin, true) * spin <= MAX_LOOP_LIMIT_BACKOFF_TRIPS);
        }
    }
}
