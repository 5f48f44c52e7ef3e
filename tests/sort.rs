//! Radix sort and prefix scan against Rust's stable sort / a plain scan, on every size
//! class and key distribution the issue lists, with stability checked through values.

use crate::common;

use common::Rng;
use svraster::gpu::{recorder, Context, Memory, Timestamps};
use svraster::scan::PrefixScan;
use svraster::sort::{
    Count, KeyWidth, PassProbe, RadixSort, SortPass, SortScratch, Sorted, ERR_OVERFLOW,
};

/// The pass kernels the pass-by-pass tests run: every one the device supports (those it
/// does not are named), or only those `SVRASTER_TEST_SORT_PASSES` lists (comma-separated
/// names; CI's 16-lane run takes `c256,s256`, the GPU's passes, which lavapipe runs only
/// at 16 lanes). A listed pass the device cannot run fails the test instead of skipping.
fn passes(ctx: &Context) -> Vec<SortPass> {
    let info = ctx.info();
    match std::env::var("SVRASTER_TEST_SORT_PASSES") {
        Ok(list) if !list.trim().is_empty() => list
            .split(',')
            .map(|name| {
                let pass: SortPass = name.trim().parse().unwrap();
                assert!(
                    pass.supported(info),
                    "SVRASTER_TEST_SORT_PASSES lists `{}`, which {} cannot run ({} lanes, \
                     {} bytes of shared memory; the pass needs {} lanes and {} bytes)",
                    pass.name(),
                    info.name,
                    info.subgroup_size,
                    info.max_compute_shared_memory_size,
                    pass.min_subgroup(),
                    pass.shared_bytes()
                );
                pass
            })
            .collect(),
        _ => SortPass::ALL
            .into_iter()
            .filter(|p| {
                let ok = p.supported(info);
                if !ok {
                    println!(
                        "sort pass {}: not supported by {}, skipped",
                        p.name(),
                        info.name
                    );
                }
                ok
            })
            .collect(),
    }
}

const SIZES: &[usize] = &[
    0,
    1,
    2,
    255,
    256,
    257,
    4095,
    4096,
    4097,
    65_537,
    1_000_000,
    1 << 22,
];
const RANGES: &[(u32, u32)] = &[(0, 64), (0, 16), (13, 61)];

#[derive(Clone, Copy, Debug)]
enum Dist {
    Uniform,
    AllEqual,
    Sorted,
    Reversed,
    ThreeValues,
    HighBitsOnly,
    LowByteOnly,
}

fn keys_for(dist: Dist, n: usize, rng: &mut Rng) -> Vec<u64> {
    let c = rng.next_u64();
    let three = [rng.next_u64(), rng.next_u64(), rng.next_u64()];
    let mut k: Vec<u64> = (0..n)
        .map(|_| match dist {
            Dist::AllEqual => c,
            Dist::ThreeValues => three[rng.below(3) as usize],
            Dist::HighBitsOnly => rng.next_u64() & 0xffff_0000_0000_0000,
            Dist::LowByteOnly => rng.next_u64() & 0xff,
            _ => rng.next_u64(),
        })
        .collect();
    match dist {
        Dist::Sorted => k.sort_unstable(),
        Dist::Reversed => k.sort_unstable_by(|a, b| b.cmp(a)),
        _ => {}
    }
    k
}

/// Sorts with buffers reused across cases; returns the GPU result.
struct Harness {
    ctx: Context,
    sort: RadixSort,
    buf: SortScratch,
}

impl Harness {
    fn new(capacity: u32) -> Self {
        Self::with_rank(capacity, false)
    }
    /// `generic`: rank with ballots (the any-subgroup-size path) instead of the 8-lane
    /// shuffle comparison.
    fn with_rank(capacity: u32, generic: bool) -> Self {
        let ctx = common::context();
        let mut sort = RadixSort::new(&ctx, capacity).unwrap();
        sort.set_generic_rank(generic);
        let buf = SortScratch::new(&ctx, capacity).unwrap();
        Harness { ctx, sort, buf }
    }
    /// A chosen pass kernel on `ctx`.
    fn with_pass(ctx: &Context, capacity: u32, pass: SortPass) -> Self {
        let sort = RadixSort::with_pass(ctx, capacity, pass).unwrap();
        let buf = SortScratch::new(ctx, capacity).unwrap();
        Harness {
            ctx: ctx.clone(),
            sort,
            buf,
        }
    }
    /// Sorts keys of `width` (u64 or u32) by bits `lo..hi`; returns the GPU result.
    fn run_keys<K: bytemuck::Pod>(
        &self,
        keys: &[K],
        vals: &[u32],
        lo: u32,
        hi: u32,
        width: KeyWidth,
    ) -> (Vec<K>, Vec<u32>) {
        let ctx = &self.ctx;
        let n = keys.len() as u32;
        ctx.upload(&self.buf.keys, 0, keys).unwrap();
        ctx.upload(&self.buf.values, 0, vals).unwrap();
        let which = ctx
            .submit_and_wait(|cmd| {
                self.sort.record_keys(
                    cmd,
                    &self.buf.as_buffers(),
                    Count::Host(n),
                    lo..hi,
                    width,
                    None,
                )
            })
            .unwrap();
        assert_eq!(self.sort.take_errors().unwrap(), 0);
        let (k, v) = self.buf.result(which);
        (
            ctx.download(k, 0, keys.len()).unwrap(),
            ctx.download(v, 0, keys.len()).unwrap(),
        )
    }
    fn run(&self, keys: &[u64], vals: &[u32], lo: u32, hi: u32) -> (Vec<u64>, Vec<u32>) {
        self.run_keys(keys, vals, lo, hi, KeyWidth::U64)
    }
    fn run32(&self, keys: &[u32], vals: &[u32], lo: u32, hi: u32) -> (Vec<u32>, Vec<u32>) {
        self.run_keys(keys, vals, lo, hi, KeyWidth::U32)
    }
}

fn check_dist(dist: Dist, seed: u64) {
    let h = Harness::new(1 << 22);
    let mut rng = Rng(seed);
    for &n in SIZES {
        let keys = keys_for(dist, n, &mut rng);
        let vals: Vec<u32> = (0..n as u32).collect();
        for &(lo, hi) in RANGES {
            let (gk, gv) = h.run(&keys, &vals, lo, hi);
            let (rk, rv) = common::reference_sort(&keys, &vals, lo, hi);
            if let Some(i) = (0..n).find(|&i| gk[i] != rk[i] || gv[i] != rv[i]) {
                panic!(
                    "{dist:?} n={n} bits {lo}..{hi}: first mismatch at {i}: got ({:#x}, {}), want ({:#x}, {})",
                    gk[i], gv[i], rk[i], rv[i]
                );
            }
        }
    }
    common::finish(&h.ctx);
}

/// The ballot ranking that subgroups of other sizes than 8 take (forced here; lavapipe
/// takes the shuffle comparison otherwise), u64 and u32 keys, against the reference.
#[test]
fn sort_generic_rank() {
    let h = Harness::with_rank(1 << 20, true);
    let mut rng = Rng(31);
    for dist in [
        Dist::Uniform,
        Dist::ThreeValues,
        Dist::LowByteOnly,
        Dist::Reversed,
    ] {
        for &n in &[1usize, 257, 4097, 65_537, 1 << 20] {
            let keys = keys_for(dist, n, &mut rng);
            let vals: Vec<u32> = (0..n as u32).collect();
            for (lo, hi) in [(0, 64), (5, 12)] {
                let (gk, gv) = h.run(&keys, &vals, lo, hi);
                let (rk, rv) = common::reference_sort(&keys, &vals, lo, hi);
                assert!(gk == rk && gv == rv, "{dist:?} n={n} bits {lo}..{hi}");
            }
            let k32: Vec<u32> = keys.iter().map(|&k| k as u32).collect();
            let wide: Vec<u64> = k32.iter().map(|&k| k as u64).collect();
            let (gk, gv) = h.run32(&k32, &vals, 0, 26);
            let (rk, rv) = common::reference_sort(&wide, &vals, 0, 26);
            let rk: Vec<u32> = rk.iter().map(|&k| k as u32).collect();
            assert!(gk == rk && gv == rv, "{dist:?} n={n} u32 bits 0..26");
        }
    }
    common::finish(&h.ctx);
}

#[test]
fn sort_uniform() {
    check_dist(Dist::Uniform, 1);
}
#[test]
fn sort_all_equal() {
    check_dist(Dist::AllEqual, 2);
}
#[test]
fn sort_already_sorted() {
    check_dist(Dist::Sorted, 3);
}
#[test]
fn sort_reversed() {
    check_dist(Dist::Reversed, 4);
}
#[test]
fn sort_three_values() {
    check_dist(Dist::ThreeValues, 5);
}
#[test]
fn sort_high_bits_only() {
    check_dist(Dist::HighBitsOnly, 6);
}
#[test]
fn sort_low_byte_only() {
    check_dist(Dist::LowByteOnly, 7);
}

/// Every pass kernel this device runs (all five on a GPU; on lavapipe, whose 8-lane
/// subgroups `c256` and `s256` do not support, `direct`, `c128` and `s128`, which are
/// the 256-invocation kernels' bodies with 128 invocations), with the shuffle and the
/// ballot ranking, u64 and u32 keys, the look-back's recount fallback forced (spin limit
/// 0) and not, look-back windows of 1, 3 and 8 words and a back-off between polls
/// (coalesced passes), against the
/// reference; 2^20 keys with the device's settings and the last combination.
#[test]
fn sort_every_pass_kernel() {
    let ctx = common::context();
    let mut rng = Rng(77);
    for pass in passes(&ctx) {
        let mut h = Harness::with_pass(&ctx, 1 << 20, pass);
        assert_eq!(h.sort.pass(), pass);
        // Look-back windows (coalesced passes; the direct pass reads one word at a
        // time): the device's, and 8 words with and without the recount fallback; the
        // back-off between polls once (coalesced passes).
        let windows: &[(bool, Option<u32>, Option<u32>, u32)] = match pass {
            SortPass::Direct => &[
                (false, None, None, 0),
                (true, None, None, 0),
                (false, Some(0), None, 0),
            ],
            // No look-back: its settings change nothing.
            SortPass::Scan128 | SortPass::Scan256 => {
                &[(false, None, None, 0), (true, None, None, 0)]
            }
            _ => &[
                (false, None, None, 0),
                (true, None, None, 0),
                (false, Some(0), None, 0),
                (false, None, Some(8), 64),
                (true, Some(0), Some(3), 0),
            ],
        };
        for (i, &(generic, spin, window, backoff)) in windows.iter().enumerate() {
            // 2^20 keys (hundreds of tiles: long look-back walks) with the device's
            // settings and the last, most adverse combination; the others up to 65 537
            // keys (17-35 tiles), which is where they differ (CI time: the test took
            // 83 s alone on 2 cores with 2^20 keys in every combination, 50 s now).
            let big = i == 0 || i + 1 == windows.len();
            h.sort.set_generic_rank(generic);
            h.sort.set_spin_limit(spin);
            h.sort.set_lookback_window(window).unwrap();
            h.sort.set_lookback_backoff(backoff);
            for dist in [
                Dist::Uniform,
                Dist::ThreeValues,
                Dist::LowByteOnly,
                Dist::Sorted,
                Dist::Reversed,
            ] {
                for &n in &[1usize, 255, 1921, 3841, 65_537, 1 << 20] {
                    if n == 1 << 20 && !big {
                        continue;
                    }
                    let keys = keys_for(dist, n, &mut rng);
                    let vals: Vec<u32> = (0..n as u32).collect();
                    let what = |bits: &str| {
                        format!(
                            "pass {} generic {generic} spin {spin:?} window {window:?} backoff {backoff} {dist:?} n={n} {bits}",
                            pass.name()
                        )
                    };
                    for (lo, hi) in [(0, 64), (5, 12), (13, 61)] {
                        let (gk, gv) = h.run(&keys, &vals, lo, hi);
                        let (rk, rv) = common::reference_sort(&keys, &vals, lo, hi);
                        assert!(
                            gk == rk && gv == rv,
                            "{}",
                            what(&format!("bits {lo}..{hi}"))
                        );
                    }
                    let k32: Vec<u32> = keys.iter().map(|&k| k as u32).collect();
                    let wide: Vec<u64> = k32.iter().map(|&k| k as u64).collect();
                    let (gk, gv) = h.run32(&k32, &vals, 0, 26);
                    let (rk, rv) = common::reference_sort(&wide, &vals, 0, 26);
                    let rk: Vec<u32> = rk.iter().map(|&k| k as u32).collect();
                    assert!(gk == rk && gv == rv, "{}", what("u32 bits 0..26"));
                }
            }
        }
    }
    common::finish(&ctx);
}

/// The reduce-then-scan passes with more tiles than one round of their scan over the
/// tiles covers (2 048 tiles per round, glsl/sort/tile_scan.comp): 2 rounds and a partial
/// third, so each round must carry the sum of the ones before.
#[test]
fn reduce_then_scan_over_several_scan_rounds() {
    let ctx = common::context();
    let mut rng = Rng(79);
    for pass in passes(&ctx).into_iter().filter(|p| p.reduce_then_scan()) {
        let n = pass.tile() as usize * (2 * 2048 + 100) + 77;
        let h = Harness::with_pass(&ctx, n as u32, pass);
        let keys: Vec<u64> = (0..n).map(|_| rng.next_u64()).collect();
        let vals: Vec<u32> = (0..n as u32).collect();
        let (gk, gv) = h.run(&keys, &vals, 20, 36);
        let (rk, rv) = common::reference_sort(&keys, &vals, 20, 36);
        assert!(gk == rk && gv == rv, "{}: n = {n}", pass.name());
    }
    common::finish(&ctx);
}

/// A sort's stage timestamps (`bench sort`): every pass kernel marks setup, histogram,
/// each pass (reduce-then-scan passes their count too) and the copy, in order; a pool too
/// small for them is an error, not a report that lacks its last stages.
#[test]
fn sort_stage_timestamps_are_complete_or_an_error() {
    let ctx = common::context();
    let n = 5_000u32;
    let mut rng = Rng(80);
    let keys: Vec<u64> = (0..n).map(|_| rng.next_u64()).collect();
    let vals: Vec<u32> = (0..n).collect();
    for pass in passes(&ctx) {
        let h = Harness::with_pass(&ctx, n, pass);
        let passes = 3u32; // bits 0..24
        let mut want = vec!["sort.setup".to_string(), "sort.histogram".to_string()];
        for p in 0..passes {
            if pass.reduce_then_scan() {
                want.push(format!("sort.count{p}"));
            }
            want.push(format!("sort.pass{p}"));
        }
        want.push("sort.copy".to_string());
        for capacity in [want.len() as u32 + 1, want.len() as u32] {
            let mut ts = Timestamps::new(&ctx, capacity).unwrap();
            ctx.upload(&h.buf.keys, 0, &keys).unwrap();
            ctx.upload(&h.buf.values, 0, &vals).unwrap();
            ctx.submit_and_wait(|cmd| {
                ts.begin(cmd);
                h.sort.record(
                    cmd,
                    &h.buf.as_buffers(),
                    Count::Host(n),
                    0..24,
                    Some(&mut ts),
                )
            })
            .unwrap();
            let stages = ts.stages();
            if capacity > want.len() as u32 {
                let names: Vec<String> = stages.unwrap().into_iter().map(|(k, _)| k).collect();
                assert_eq!(names, want, "{}", pass.name());
            } else {
                let e = stages
                    .expect_err("a mark past the pool's capacity")
                    .to_string();
                assert!(
                    e.contains("1 timestamp marks after `sort.pass2`"),
                    "{}: {e}",
                    pass.name()
                );
            }
        }
    }
    common::finish(&ctx);
}

/// The histogram's workgroup cap (`set_hist_groups`): with fewer workgroups than
/// 4 096-key blocks each workgroup counts several consecutive blocks, the last one
/// partial; every key is counted once (a missed or doubled block gives wrong offsets,
/// so a wrong order), for caps that divide the blocks evenly and not, u64 and u32 keys.
#[test]
fn sort_histogram_with_capped_workgroups() {
    let ctx = common::context();
    let mut rng = Rng(91);
    let mut h = Harness::with_pass(&ctx, 1 << 17, SortPass::for_device(ctx.info()));
    for groups in [1u32, 3, 4, 7, 0] {
        h.sort.set_hist_groups(groups);
        assert_eq!(h.sort.hist_groups(), groups);
        for &n in &[1usize, 4095, 4097, 16_384, 50_001, 1 << 17] {
            let keys = keys_for(Dist::Uniform, n, &mut rng);
            let vals: Vec<u32> = (0..n as u32).collect();
            let (gk, gv) = h.run(&keys, &vals, 0, 64);
            let (rk, rv) = common::reference_sort(&keys, &vals, 0, 64);
            assert!(gk == rk && gv == rv, "hist groups {groups}, n={n}");
            let k32: Vec<u32> = keys.iter().map(|&k| k as u32).collect();
            let wide: Vec<u64> = k32.iter().map(|&k| k as u64).collect();
            let (gk, gv) = h.run32(&k32, &vals, 3, 30);
            let (rk, rv) = common::reference_sort(&wide, &vals, 3, 30);
            let rk: Vec<u32> = rk.iter().map(|&k| k as u32).collect();
            assert!(gk == rk && gv == rv, "hist groups {groups}, n={n}, u32");
        }
    }
    common::finish(&ctx);
}

/// The look-back counters `bench sort` reports count each run afresh: a multi-tile
/// sort reads at least one status word per digit of every tile but the first (unless a
/// fallback recounted it) and at most every predecessor's; a one-tile sort after it
/// reads none.
#[test]
fn lookback_counters_count_each_run() {
    let ctx = common::context();
    let mut rng = Rng(78);
    for pass in passes(&ctx) {
        let h = Harness::with_pass(&ctx, 1 << 17, pass);
        let n = 65_537usize;
        let tiles = n.div_ceil(pass.tile() as usize) as u64;
        let keys: Vec<u64> = (0..n).map(|_| rng.below(1 << 16)).collect();
        let vals: Vec<u32> = (0..n as u32).collect();
        let (gk, gv) = h.run(&keys, &vals, 0, 16);
        assert_eq!((gk, gv), common::reference_sort(&keys, &vals, 0, 16));
        let c = h.sort.last_lookback().unwrap();
        println!("{}: {tiles} tiles x 2 passes: {c:?}", pass.name());
        if pass.reduce_then_scan() {
            assert_eq!(c, Default::default(), "{}: no look-back", pass.name());
            continue;
        }
        let (least, most) = ((tiles - 1) * 256 * 2, tiles * (tiles - 1) / 2 * 256 * 2);
        assert!(u64::from(c.steps) <= most, "{}: {c:?}", pass.name());
        assert!(c.steps > 0, "{}: {c:?}", pass.name());
        if c.fallbacks == 0 {
            assert!(u64::from(c.steps) >= least, "{}: {c:?}", pass.name());
        }
        let few: Vec<u64> = keys[..255].to_vec();
        h.run(&few, &vals[..255], 0, 16);
        assert_eq!(
            h.sort.last_lookback().unwrap(),
            Default::default(),
            "{}: one tile walks back nowhere",
            pass.name()
        );
    }
    common::finish(&ctx);
}

/// Passes whose digit is the same for every key are skipped on the GPU, whichever
/// passes they are and whether an odd or even number is skipped (the result is then
/// copied to where the recorded passes end); with skipping off every pass runs. The
/// mask of skipped passes is what the keys say, and the result is the reference's.
#[test]
fn sort_skips_constant_digits() {
    let ctx = common::context();
    let mut rng = Rng(91);
    let n = 70_001usize;
    for pass in passes(&ctx) {
        let mut h = Harness::with_pass(&ctx, n as u32, pass);
        // Bits that vary, as a mask over the 64 key bits.
        for vary in [
            u64::MAX,
            0xff00,                // only digit 1 varies: 7 of 8 skipped (odd)
            0x00ff_0000_0000_00ff, // digits 0 and 6: 6 skipped (even)
            0x0fff_ffff_ffff_fff0, // digit 7 partly, digit 0 partly: none skipped
            0x0000_ffff_0000_0000, // digits 4 and 5: 6 skipped
            0x0000_0000_0000_0100, // one bit of digit 1
            0,                     // all equal: all skipped
        ] {
            let base = rng.next_u64() & !vary;
            let keys: Vec<u64> = (0..n).map(|_| base | (rng.next_u64() & vary)).collect();
            let vals: Vec<u32> = (0..n as u32).collect();
            for skip in [true, false] {
                h.sort.set_skip_constant(skip);
                for (lo, hi) in [(0u32, 64u32), (8, 48), (3, 60)] {
                    let (gk, gv) = h.run(&keys, &vals, lo, hi);
                    let (rk, rv) = common::reference_sort(&keys, &vals, lo, hi);
                    let what = format!(
                        "pass {} vary {vary:#x} skip {skip} bits {lo}..{hi}",
                        pass.name()
                    );
                    assert!(gk == rk && gv == rv, "{what}: wrong result");
                    let mut want = 0u32;
                    if skip {
                        for p in 0..(hi - lo).div_ceil(8) {
                            let shift = lo + 8 * p;
                            let width = (hi - shift).min(8);
                            let digit_mask = ((1u64 << width) - 1) << shift;
                            if vary & digit_mask == 0 {
                                want |= 1 << p;
                            }
                        }
                    }
                    assert_eq!(
                        h.sort.last_skipped().unwrap(),
                        want,
                        "{what}: skipped passes"
                    );
                }
            }
        }
    }
    common::finish(&ctx);
}

/// The pass probes (`bench sort --probe`: a part of a pass run in its place, to time
/// it) leave what they define: `copy` the input, `tile` every tile of the pass sorted
/// stably by the bits sorted. Each coalesced and reduce-then-scan pass the device runs,
/// u64 and u32 keys, counts that end inside a tile, a single tile and one key, every
/// pass run and constant digits skipped (an odd number of skips swaps the ping-pong);
/// the direct pass has none.
#[test]
fn pass_probes_leave_what_they_define() {
    let ctx = common::context();
    let mut rng = Rng(57);
    let mut ran = 0;
    for pass in passes(&ctx) {
        let mut h = Harness::with_pass(&ctx, 100_000, pass);
        if pass == SortPass::Direct {
            assert!(h.sort.set_probe(Some(PassProbe::Tile)).is_err());
            continue;
        }
        let tile = pass.tile() as usize;
        for probe in PassProbe::ALL {
            h.sort.set_probe(Some(probe)).unwrap();
            assert_eq!(h.sort.probe(), Some(probe));
            for n in [3 * tile + 77, tile, 1] {
                // Digit 1 constant in the second case: 1 of the 6 passes skipped.
                for (vary, lo, hi) in [(u64::MAX, 0, 64), (!0xff00, 0, 48), (u64::MAX, 13, 61)] {
                    let base = rng.next_u64() & !vary;
                    let keys: Vec<u64> = (0..n).map(|_| base | (rng.next_u64() & vary)).collect();
                    let vals: Vec<u32> = (0..n as u32).map(|i| i ^ 0x5a5a).collect();
                    let what = format!(
                        "pass {} probe {} n {n} bits {lo}..{hi}",
                        pass.name(),
                        probe.name()
                    );
                    let got = h.run(&keys, &vals, lo, hi);
                    let want = probe_result(probe, tile, &keys, &vals, lo, hi);
                    assert!(got == want, "{what}, u64 keys: wrong result");
                    // u32 keys: the low word, bits within 0..32.
                    let (lo, hi) = (lo.min(31), hi.min(32));
                    let k32: Vec<u32> = keys.iter().map(|&k| k as u32).collect();
                    let wide: Vec<u64> = k32.iter().map(|&k| u64::from(k)).collect();
                    let (gk, gv) = h.run32(&k32, &vals, lo, hi);
                    let got = (gk.into_iter().map(u64::from).collect(), gv);
                    let want = probe_result(probe, tile, &wide, &vals, lo, hi);
                    assert!(
                        got == want,
                        "{what}, u32 keys (bits {lo}..{hi}): wrong result"
                    );
                    ran += 1;
                }
            }
        }
        // Without a probe the pass sorts again.
        h.sort.set_probe(None).unwrap();
        let keys: Vec<u64> = (0..5000).map(|_| rng.next_u64()).collect();
        let vals: Vec<u32> = (0..5000).collect();
        let got = h.run(&keys, &vals, 0, 64);
        assert!(got == common::reference_sort(&keys, &vals, 0, 64));
    }
    println!("{ran} probe runs");
    common::finish(&ctx);
}

/// What a pass probe leaves ([`PassProbe`]): the input (`copy`), or every `tile` keys
/// sorted stably by bits `lo..hi` (`tile`).
fn probe_result(
    probe: PassProbe,
    tile: usize,
    keys: &[u64],
    vals: &[u32],
    lo: u32,
    hi: u32,
) -> (Vec<u64>, Vec<u32>) {
    match probe {
        PassProbe::Copy => (keys.to_vec(), vals.to_vec()),
        PassProbe::Tile => {
            let (mut k, mut v) = (Vec::new(), Vec::new());
            for (kc, vc) in keys.chunks(tile).zip(vals.chunks(tile)) {
                let (a, b) = common::reference_sort(kc, vc, lo, hi);
                k.extend(a);
                v.extend(b);
            }
            (k, v)
        }
    }
}

/// Odd bit ranges: one-bit digits, a last digit narrower than 8 bits, a single bit,
/// the top bit alone, and an empty range (a no-op that leaves the input in place).
#[test]
fn sort_odd_bit_ranges() {
    let h = Harness::new(100_000);
    let mut rng = Rng(11);
    let keys: Vec<u64> = (0..100_000).map(|_| rng.next_u64()).collect();
    let vals: Vec<u32> = (0..100_000).collect();
    for (lo, hi) in [
        (0, 1),
        (63, 64),
        (5, 12),
        (1, 63),
        (32, 41),
        (56, 64),
        (60, 63),
    ] {
        let (gk, gv) = h.run(&keys, &vals, lo, hi);
        let (rk, rv) = common::reference_sort(&keys, &vals, lo, hi);
        assert!(gk == rk && gv == rv, "bits {lo}..{hi}");
    }
    // Empty range: nothing to do, result in the primary buffers, unchanged.
    h.ctx.upload(&h.buf.keys, 0, &keys).unwrap();
    let w = h
        .ctx
        .submit_and_wait(|cmd| {
            h.sort
                .record(cmd, &h.buf.as_buffers(), Count::Host(100_000), 7..7, None)
        })
        .unwrap();
    assert_eq!(w, Sorted::Primary);
    assert_eq!(
        h.ctx.download::<u64>(&h.buf.keys, 0, 100_000).unwrap(),
        keys
    );
    assert!(h
        .sort
        .record(vk_null(), &h.buf.as_buffers(), Count::Host(1), 9..65, None)
        .is_err());
    common::finish(&h.ctx);
}

/// u32 keys (the raster's keys when tile and Morton bits fit in 32): every distribution
/// (low 32 bits of the u64 generators, high bits moved down), sizes across the tile
/// boundaries, bit ranges with narrow and single-bit digits; against the stable
/// reference; and a range past bit 32 is refused.
#[test]
fn sort_u32_keys() {
    let h = Harness::new(1 << 20);
    let mut rng = Rng(21);
    for dist in [
        Dist::Uniform,
        Dist::AllEqual,
        Dist::Sorted,
        Dist::Reversed,
        Dist::ThreeValues,
        Dist::HighBitsOnly,
        Dist::LowByteOnly,
    ] {
        for &n in &[0usize, 1, 257, 4097, 65_537, 1 << 20] {
            let keys: Vec<u32> = keys_for(dist, n, &mut rng)
                .iter()
                .map(|&k| {
                    if matches!(dist, Dist::HighBitsOnly) {
                        (k >> 32) as u32 & 0xffff_0000
                    } else {
                        k as u32
                    }
                })
                .collect();
            let vals: Vec<u32> = (0..n as u32).collect();
            let wide: Vec<u64> = keys.iter().map(|&k| k as u64).collect();
            for (lo, hi) in [(0, 32), (0, 26), (5, 12), (31, 32), (8, 24), (0, 1)] {
                let (gk, gv) = h.run32(&keys, &vals, lo, hi);
                let (rk, rv) = common::reference_sort(&wide, &vals, lo, hi);
                let rk: Vec<u32> = rk.iter().map(|&k| k as u32).collect();
                if let Some(i) = (0..n).find(|&i| gk[i] != rk[i] || gv[i] != rv[i]) {
                    panic!(
                        "{dist:?} n={n} bits {lo}..{hi}: first mismatch at {i}: got ({:#x}, {}), want ({:#x}, {})",
                        gk[i], gv[i], rk[i], rv[i]
                    );
                }
            }
        }
    }
    let refused = h.sort.record_keys(
        vk_null(),
        &h.buf.as_buffers(),
        Count::Host(1),
        0..33,
        KeyWidth::U32,
        None,
    );
    assert!(refused.is_err());
    // The convenience call agrees.
    let (k, v) = h
        .sort
        .sort_u32(&[3, 1, 2, 1], &[0, 1, 2, 3], 0..32)
        .unwrap();
    assert_eq!((k, v), (vec![1, 1, 2, 3], vec![1, 3, 2, 0]));
    common::finish(&h.ctx);
}

fn vk_null() -> ash::vk::CommandBuffer {
    ash::vk::CommandBuffer::null()
}

/// Past maxStorageBufferRange, reachable only through buffer device addresses: the
/// fewest u64 keys whose buffer exceeds the device's range (2^24 + 3 keys, 128 MiB + 24 B,
/// on lavapipe). Skipped, saying why, where that buffer exceeds one allocation
/// (maxMemoryAllocationSize) or more keys than this test sorts on the host (2^26).
#[test]
fn sort_beyond_storage_buffer_range() {
    let ctx = common::context();
    let info = ctx.info();
    let range = info.max_storage_buffer_range;
    let n = (range / 8 + 1).max(1 << 20) + 2;
    let bytes = n * 8;
    const HOST_LIMIT: u64 = 1 << 26;
    if info.max_memory_allocation_size > 0 && bytes > info.max_memory_allocation_size {
        eprintln!(
            "skipped: {} keys ({bytes} B) exceed maxStorageBufferRange ({range} B) but also \
             maxMemoryAllocationSize ({} B) on {}: no buffer can pass the range",
            n, info.max_memory_allocation_size, info.name
        );
        return;
    }
    if n > HOST_LIMIT {
        eprintln!(
            "skipped: passing maxStorageBufferRange ({range} B) on {} takes {n} keys, more \
             than the {HOST_LIMIT} this test sorts on the host",
            info.name
        );
        return;
    }
    drop(ctx);
    let h = Harness::new(n as u32);
    assert!(h.buf.keys.size() > h.ctx.info().max_storage_buffer_range);
    let n = n as usize;
    let mut rng = Rng(12);
    let keys: Vec<u64> = (0..n).map(|_| rng.next_u64()).collect();
    let vals: Vec<u32> = (0..n as u32).collect();
    let (gk, gv) = h.run(&keys, &vals, 40, 56);
    let (rk, rv) = common::reference_sort(&keys, &vals, 40, 56);
    assert!(gk == rk, "keys differ");
    assert!(gv == rv, "values differ");
    common::finish(&h.ctx);
}

/// The element count read from a GPU buffer (indirect dispatch, no host read-back);
/// a count above capacity is clamped and flagged, never written out of bounds.
#[test]
fn sort_count_from_device_and_overflow() {
    let ctx = common::context();
    let cap = 10_000u32;
    for pass in passes(&ctx) {
        let sort = RadixSort::with_pass(&ctx, cap, pass).unwrap();
        let buf = SortScratch::new(&ctx, cap).unwrap();
        let count = ctx.buffer("count", 4, Memory::Device).unwrap();
        let mut rng = Rng(13);
        let keys: Vec<u64> = (0..cap).map(|_| rng.next_u64()).collect();
        let vals: Vec<u32> = (0..cap).collect();
        for n in [0u32, 1, 777, 5000, cap] {
            ctx.upload(&buf.keys, 0, &keys).unwrap();
            ctx.upload(&buf.values, 0, &vals).unwrap();
            ctx.upload(&count, 0, &[n]).unwrap();
            let w = ctx
                .submit_and_wait(|cmd| {
                    sort.record(
                        cmd,
                        &buf.as_buffers(),
                        Count::Device {
                            buffer: &count,
                            offset: 0,
                        },
                        0..64,
                        None,
                    )
                })
                .unwrap();
            assert_eq!(sort.take_errors().unwrap(), 0);
            assert_eq!(sort.last_count().unwrap(), (n, n));
            let (k, v) = buf.result(w);
            let gk: Vec<u64> = ctx.download(k, 0, n as usize).unwrap();
            let gv: Vec<u32> = ctx.download(v, 0, n as usize).unwrap();
            let (rk, rv) = common::reference_sort(&keys[..n as usize], &vals[..n as usize], 0, 64);
            assert!(gk == rk && gv == rv, "{}: device count {n}", pass.name());
        }
        // Overflow: the sort clamps to `cap`, sorts those pairs, and raises ERR_OVERFLOW.
        ctx.upload(&buf.keys, 0, &keys).unwrap();
        ctx.upload(&buf.values, 0, &vals).unwrap();
        ctx.upload(&count, 0, &[cap + 12_345]).unwrap();
        let w = ctx
            .submit_and_wait(|cmd| {
                sort.record(
                    cmd,
                    &buf.as_buffers(),
                    Count::Device {
                        buffer: &count,
                        offset: 0,
                    },
                    0..64,
                    None,
                )
            })
            .unwrap();
        assert_eq!(sort.last_count().unwrap(), (cap, cap + 12_345));
        assert_eq!(sort.take_errors().unwrap(), ERR_OVERFLOW);
        assert_eq!(
            sort.take_errors().unwrap(),
            0,
            "errors are cleared once taken"
        );
        let (k, _) = buf.result(w);
        let gk: Vec<u64> = ctx.download(k, 0, cap as usize).unwrap();
        let (rk, _) = common::reference_sort(&keys, &vals, 0, 64);
        assert_eq!(gk, rk);
    }
    common::finish(&ctx);
}

/// Two sorts recorded back to back in one command buffer, with every pass kernel (the
/// look-back epochs of the second run must not see the first run's status words; the
/// reduce-then-scan passes rewrite their counts there).
#[test]
fn sort_twice_in_one_command_buffer() {
    let ctx = common::context();
    let n = 300_000u32;
    for pass in passes(&ctx) {
        let sort = RadixSort::with_pass(&ctx, n, pass).unwrap();
        let a = SortScratch::new(&ctx, n).unwrap();
        let b = SortScratch::new(&ctx, n).unwrap();
        let mut rng = Rng(14);
        let ka: Vec<u64> = (0..n).map(|_| rng.next_u64()).collect();
        let kb: Vec<u64> = (0..n).map(|_| rng.next_u64() & 0xffff_ffff).collect();
        let vals: Vec<u32> = (0..n).collect();
        for (s, k) in [(&a, &ka), (&b, &kb)] {
            ctx.upload(&s.keys, 0, k).unwrap();
            ctx.upload(&s.values, 0, &vals).unwrap();
        }
        let (wa, wb) = ctx
            .submit_and_wait(|cmd| {
                let wa = sort.record(cmd, &a.as_buffers(), Count::Host(n), 0..64, None)?;
                let wb = sort.record(cmd, &b.as_buffers(), Count::Host(n), 0..32, None)?;
                Ok((wa, wb))
            })
            .unwrap();
        for (s, w, k, bits) in [(&a, wa, &ka, 64), (&b, wb, &kb, 32)] {
            let (rk, rv) = common::reference_sort(k, &vals, 0, bits);
            let (gk, gv) = s.result(w);
            let ok = ctx.download::<u64>(gk, 0, n as usize).unwrap() == rk
                && ctx.download::<u32>(gv, 0, n as usize).unwrap() == rv;
            assert!(ok, "{}: sort of {bits} bits", pass.name());
        }
    }
    common::finish(&ctx);
}

#[test]
fn scan_matches_reference() {
    let ctx = common::context();
    let scan = PrefixScan::new(&ctx, 1 << 22).unwrap();
    let mut rng = Rng(21);
    for &n in SIZES {
        for kind in 0..4 {
            let data: Vec<u32> = (0..n)
                .map(|_| match kind {
                    0 => rng.below(1000) as u32,
                    1 => 0,
                    2 => 1,
                    _ => rng.next_u64() as u32, // wraps many times
                })
                .collect();
            let (out, total) = scan.scan(&data).unwrap();
            let (ro, rt) = common::reference_scan(&data);
            assert!(out == ro, "scan n={n} kind={kind}");
            assert_eq!(total, rt, "total n={n} kind={kind}");
        }
    }
    common::finish(&ctx);
}

/// Scan with the count from a GPU buffer, the total written to a caller's buffer, and
/// overflow clamping.
#[test]
fn scan_count_from_device_total_and_overflow() {
    let ctx = common::context();
    let cap = 50_000u32;
    let scan = PrefixScan::new(&ctx, cap).unwrap();
    let input = ctx.buffer("in", cap as u64 * 4, Memory::Device).unwrap();
    let output = ctx.buffer("out", cap as u64 * 4, Memory::Device).unwrap();
    let misc = ctx.buffer("count+total", 16, Memory::Device).unwrap();
    let mut rng = Rng(22);
    let data: Vec<u32> = (0..cap).map(|_| rng.below(50) as u32).collect();
    ctx.upload(&input, 0, &data).unwrap();
    for n in [0u32, 3, 2048, 2049, 33_333, cap, cap + 1] {
        ctx.upload(&misc, 0, &[n, 0xdead_beef, 0, 0]).unwrap();
        ctx.submit_and_wait(|cmd| {
            scan.record(
                cmd,
                &input,
                &output,
                Count::Device {
                    buffer: &misc,
                    offset: 0,
                },
                Some((&misc, 4)),
            )
        })
        .unwrap();
        let used = n.min(cap) as usize;
        let (ro, rt) = common::reference_scan(&data[..used]);
        assert_eq!(ctx.download::<u32>(&output, 0, used).unwrap(), ro, "n={n}");
        let total = ctx.download::<u32>(&misc, 4, 1).unwrap()[0];
        // With n = 0 no tile runs: the caller's total is left untouched.
        assert_eq!(
            total,
            if used == 0 { 0xdead_beef } else { rt },
            "total n={n}"
        );
        assert_eq!(scan.last_total().unwrap(), rt);
        assert_eq!(
            scan.take_errors().unwrap(),
            if n > cap { ERR_OVERFLOW } else { 0 }
        );
    }
    assert!(
        scan.record(vk_null(), &input, &input, Count::Host(1), None)
            .is_err(),
        "aliasing is refused"
    );
    common::finish(&ctx);
}

/// The validation harness itself: a deliberate misuse must be reported (so a clean
/// run means something).
#[test]
fn validation_layer_reports_misuse() {
    let ctx = common::context();
    assert!(ctx.validation_enabled());
    let b = ctx.buffer("misuse", 64, Memory::Device).unwrap();
    ctx.submit_and_wait(|cmd| {
        // size must be a multiple of 4 (VUID-vkCmdFillBuffer-size-00028)
        recorder::fill(&ctx, cmd, &b, 0, 6, 0);
        Ok(())
    })
    .unwrap();
    assert!(
        ctx.validation_messages() > 0,
        "the validation layer did not report an invalid fill"
    );
}
