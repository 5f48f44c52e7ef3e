//! The kernels that run a digit pass of the sort, and which one a device takes.

use super::SORT_TILE;
use crate::gpu::{kernels, DeviceInfo, KernelSource};

/// Keys per invocation of the coalesced pass (KPT in build.rs's variant table).
const COALESCED_KPT: u32 = 15;
/// The smallest tile of any pass (sizes the look-back status words).
pub(super) const MIN_TILE: u32 = 128 * COALESCED_KPT;

/// Which kernel runs the digit passes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum SortPass {
    /// `onesweep.glsl`: 128 invocations × 16 keys, each key written straight to its
    /// destination. The fastest on lavapipe.
    Direct,
    /// `onesweep_coalesced.glsl` with 128 invocations × 15 keys: any subgroup size.
    Coalesced128,
    /// `onesweep_coalesced.glsl` with 256 invocations × 15 keys: subgroups of ≥ 16
    /// lanes and 32 768 bytes of shared memory (32 KiB exactly).
    Coalesced256,
    /// Reduce-then-scan with `Coalesced128`'s tiles: per digit pass `tile_count.glsl`
    /// counts every tile's digits, `tile_scan.comp` sums them over the tiles, and the
    /// coalesced pass reads its offsets instead of looking back (no workgroup waits on
    /// another; the keys are read twice per pass). Any subgroup size.
    Scan128,
    /// Reduce-then-scan with `Coalesced256`'s tiles.
    Scan256,
}

impl SortPass {
    /// Every pass kernel, for tests and `bench sort --pass`.
    pub const ALL: [SortPass; 5] = [
        SortPass::Direct,
        SortPass::Coalesced128,
        SortPass::Coalesced256,
        SortPass::Scan128,
        SortPass::Scan256,
    ];

    /// The pass for a device: the direct one on CPU devices (a write there is a store
    /// to the CPU's caches; staging the tile only adds work), else the widest coalesced
    /// one the subgroup size and shared memory allow.
    pub fn for_device(info: &DeviceInfo) -> SortPass {
        if info.is_cpu {
            SortPass::Direct
        } else if SortPass::Coalesced256.supported(info) {
            SortPass::Coalesced256
        } else if SortPass::Coalesced128.supported(info) {
            SortPass::Coalesced128
        } else {
            SortPass::Direct
        }
    }

    /// The pass every sort of this process takes ([`crate::sort::RadixSort::new`]): the
    /// one `SVRASTER_SORT_PASS` names, if set (to measure frames and training with
    /// another pass kernel), else [`SortPass::for_device`].
    pub fn for_run(info: &DeviceInfo) -> Result<SortPass, String> {
        match std::env::var("SVRASTER_SORT_PASS") {
            Ok(name) if !name.trim().is_empty() => name
                .trim()
                .parse::<SortPass>()
                .map_err(|e| format!("SVRASTER_SORT_PASS={name}: {e}")),
            _ => Ok(SortPass::for_device(info)),
        }
    }

    /// Name in reports and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            SortPass::Direct => "direct",
            SortPass::Coalesced128 => "c128",
            SortPass::Coalesced256 => "c256",
            SortPass::Scan128 => "s128",
            SortPass::Scan256 => "s256",
        }
    }

    fn invocations(self) -> u32 {
        match self {
            SortPass::Direct | SortPass::Coalesced128 | SortPass::Scan128 => 128,
            SortPass::Coalesced256 | SortPass::Scan256 => 256,
        }
    }

    /// Whether the pass takes its offsets from a count and a scan over the tiles
    /// (no decoupled look-back).
    pub fn reduce_then_scan(self) -> bool {
        matches!(self, SortPass::Scan128 | SortPass::Scan256)
    }

    /// Keys per workgroup (tile).
    pub fn tile(self) -> u32 {
        match self {
            SortPass::Direct => SORT_TILE,
            _ => self.invocations() * COALESCED_KPT,
        }
    }

    /// Smallest subgroup size the kernel supports (its shared histogram rows).
    pub fn min_subgroup(self) -> u32 {
        match self {
            SortPass::Direct | SortPass::Coalesced128 | SortPass::Scan128 => 8,
            SortPass::Coalesced256 | SortPass::Scan256 => 16,
        }
    }

    /// Bytes of shared memory its kernels declare (reflected from their SPIR-V; the
    /// largest of the pass and, for reduce-then-scan, the tile count).
    pub fn shared_bytes(self) -> u32 {
        let count = self.count_kernels().into_iter().flatten();
        self.kernels()
            .into_iter()
            .chain(count)
            .map(|k| k.shared_size)
            .max()
            .unwrap_or(0)
    }

    /// Whether the device can run it.
    pub fn supported(self, info: &DeviceInfo) -> bool {
        info.subgroup_size >= self.min_subgroup()
            && self.shared_bytes() <= info.max_compute_shared_memory_size
            && self.invocations() <= info.max_compute_work_group_invocations
    }

    pub(super) fn kernels(self) -> [&'static KernelSource; 2] {
        match self {
            SortPass::Direct => kernels::SORT_ONESWEEP_VARIANTS,
            SortPass::Coalesced128 => kernels::SORT_ONESWEEP_C128_VARIANTS,
            SortPass::Coalesced256 => kernels::SORT_ONESWEEP_C256_VARIANTS,
            SortPass::Scan128 => kernels::SORT_SCANPASS_S128_VARIANTS,
            SortPass::Scan256 => kernels::SORT_SCANPASS_S256_VARIANTS,
        }
    }

    /// The tile-count kernels of a reduce-then-scan pass (u64, u32 keys).
    pub(super) fn count_kernels(self) -> Option<[&'static KernelSource; 2]> {
        match self {
            SortPass::Scan128 => Some(kernels::SORT_TILE_COUNT_S128_VARIANTS),
            SortPass::Scan256 => Some(kernels::SORT_TILE_COUNT_S256_VARIANTS),
            _ => None,
        }
    }
}

impl std::str::FromStr for SortPass {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        SortPass::ALL
            .into_iter()
            .find(|p| p.name() == s)
            .ok_or_else(|| {
                let names: Vec<&str> = SortPass::ALL.iter().map(|p| p.name()).collect();
                format!("unknown sort pass `{s}`: one of {}", names.join(", "))
            })
    }
}

/// A part of a coalesced pass's work, run in its place to time that part
/// (`bench sort --probe`; [`crate::sort::RadixSort::set_probe`]). Each probe is the
/// pass's own kernel body with steps left out (`PROBE` in
/// glsl/sort/onesweep_coalesced.glsl), so the differences between the probes and the
/// pass are the costs of the steps: with a probe a "sort" is not a sort, and its result
/// is what the probe defines.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum PassProbe {
    /// Loads every tile and writes it back through shared memory at the same
    /// positions: the pass's memory traffic in coalesced runs, with no ranking and no
    /// look-back. The result is the input.
    Copy,
    /// Ranks and stages every tile as the pass does, with no look-back, and writes its
    /// keys back into the tile's own slots in their tile-local order: over the passes,
    /// an LSD sort within every tile. The result is each tile (the pass's tile size,
    /// [`SortPass::tile`]) sorted, stably, by the bits sorted.
    Tile,
}

impl PassProbe {
    pub const ALL: [PassProbe; 2] = [PassProbe::Copy, PassProbe::Tile];

    pub fn name(self) -> &'static str {
        match self {
            PassProbe::Copy => "copy",
            PassProbe::Tile => "tile",
        }
    }

    /// The probe's kernels (u64, u32 keys) for a pass kind; only the coalesced passes
    /// have probes (the reduce-then-scan passes are the same kernel body, and their
    /// probe is the coalesced pass's of the same size).
    pub(super) fn kernels(self, pass: SortPass) -> Option<[&'static KernelSource; 2]> {
        use PassProbe::*;
        use SortPass::*;
        Some(match (self, pass) {
            (Copy, Coalesced128 | Scan128) => kernels::SORT_PROBE_COPY_C128_VARIANTS,
            (Tile, Coalesced128 | Scan128) => kernels::SORT_PROBE_TILE_C128_VARIANTS,
            (Copy, Coalesced256 | Scan256) => kernels::SORT_PROBE_COPY_C256_VARIANTS,
            (Tile, Coalesced256 | Scan256) => kernels::SORT_PROBE_TILE_C256_VARIANTS,
            (_, Direct) => return None,
        })
    }
}

impl std::str::FromStr for PassProbe {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        PassProbe::ALL
            .into_iter()
            .find(|p| p.name() == s)
            .ok_or_else(|| format!("unknown pass probe `{s}`: copy or tile"))
    }
}

#[cfg(test)]
mod tests {
    use super::SortPass;

    /// build.rs reflects each kernel's shared memory from its SPIR-V; the direct pass's
    /// arrays counted by hand check that reflection, and the 256-invocation passes must
    /// stay within 32 KiB, lavapipe's limit, so that its 16-lane subgroups run them in
    /// tests (the GPU default has no other check off a GPU).
    #[test]
    fn shared_memory_is_reflected_and_the_256_passes_fit_32_kib() {
        // s_tile, 16 subgroup rows of 256 digits, s_base, s_fallback, lb_vote
        assert_eq!(
            SortPass::Direct.shared_bytes(),
            (1 + 16 * 256 + 2 * 256 + 1) * 4
        );
        // s_mem (the staged tile: 2 words per key), s_local, s_base; the rest aliased
        let c256 = 2 * SortPass::Coalesced256.tile() + 2 * 256;
        assert_eq!(SortPass::Coalesced256.shared_bytes(), c256 * 4);
        for p in [SortPass::Coalesced256, SortPass::Scan256] {
            assert!(
                p.shared_bytes() <= 32 * 1024,
                "{}: {} bytes",
                p.name(),
                p.shared_bytes()
            );
        }
    }
}
