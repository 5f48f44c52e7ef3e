//! `svraster bench sort`: the onesweep radix sort against the CPU's sort_unstable, with
//! every result checked.

use std::collections::BTreeMap;
use std::ops::Range;
use std::time::Instant;

use anyhow::{bail, Context as _};
use rand::{RngCore, SeedableRng};
use svraster::eval::median;
use svraster::gpu::{recorder, Context, Timestamps};
use svraster::sort::{passes_for, Count, PassProbe, RadixSort, SortPass, SortScratch};

/// `svraster bench sort` options.
#[derive(clap::Args)]
pub struct SortArgs {
    /// Number of key/value pairs.
    #[arg(long, default_value_t = 1 << 20)]
    n: u32,
    /// Key bits to sort, LO..HI.
    #[arg(long, default_value = "0..64", value_parser = parse_bits)]
    bits: Range<u32>,
    /// Bits of the random keys that vary, LO..HI; the others are the same in every key,
    /// so the passes whose digit lies outside are skipped (see --all-passes).
    #[arg(long, default_value = "0..64", value_parser = parse_bits)]
    vary: Range<u32>,
    /// Run every pass, also those whose digit is the same in every key.
    #[arg(long)]
    all_passes: bool,
    /// Pass kernel: auto (the device's), direct (lavapipe's), c128 or c256 (coalesced
    /// writes through shared memory, for GPUs).
    #[arg(long, default_value = "auto")]
    pass: String,
    /// Timed runs (the median is reported; at least 5).
    #[arg(long, default_value_t = 7)]
    runs: u32,
    /// Untimed warm-up runs.
    #[arg(long, default_value_t = 2)]
    warmup: u32,
    /// Milliseconds of untimed sorts recorded before each run, in its submission, so
    /// that the device is busy when the timed sort starts (default: 200 on GPUs, 0 on
    /// CPU devices). Every run is verified on the host, and a GPU idles meanwhile: on
    /// the H200 its clocks fell, and the same kernels timed 5× slower in some
    /// processes than in others, histogram and passes alike. As many sorts as the
    /// fastest run so far fills it with, at most 256 (a small sort gets less).
    #[arg(long)]
    heat_ms: Option<f64>,
    /// Polls of an unpublished look-back word before the pass recounts that tile itself
    /// (default: the device's, 256 on CPU devices, 4096 on GPUs).
    #[arg(long)]
    spin: Option<u32>,
    /// Workgroups of the histogram kernel at most (0: one per 4 096 keys; default the
    /// sort's, 1 024).
    #[arg(long)]
    hist_groups: Option<u32>,
    /// Look-back status words each digit of a coalesced pass (c128, c256) reads at
    /// once, 1 to 8 (default the device's: 1 on CPUs, 8 on GPUs).
    #[arg(long)]
    window: Option<u32>,
    /// ALU rounds a coalesced pass spends between two polls of an unpublished
    /// look-back word (default 0: back to back; CUB sleeps between polls).
    #[arg(long, default_value_t = 0)]
    backoff: u32,
    /// Run a part of the pass in its place, to time that part (coalesced and
    /// reduce-then-scan passes): `copy` (each tile loaded and written back through
    /// shared memory: the pass's traffic, no ranking, no look-back) or `tile` (ranked
    /// and staged as the pass does, written back into its own tile: no look-back, no
    /// scattered writes). The result is checked against what the probe defines (the
    /// input; every tile sorted), not against a sort, and there is no CPU baseline.
    #[arg(long)]
    probe: Option<String>,
    /// Skip the CPU baseline (`sort_unstable` timed W + R times; sweeps of large sorts
    /// on a GPU machine). Every run is still verified.
    #[arg(long)]
    no_baseline: bool,
    /// Seed of the random keys.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
}

/// Most untimed sorts recorded before one run (`--heat-ms` over a fast sort).
const MAX_HEAT_SORTS: f64 = 256.0;

/// Untimed sorts that fill `heat_ms` when one takes `sort_ms` (0 without heat).
fn heat_sorts_for(heat_ms: f64, sort_ms: f64) -> u32 {
    if heat_ms > 0.0 {
        (heat_ms / sort_ms.max(1e-3)).ceil().min(MAX_HEAT_SORTS) as u32
    } else {
        0
    }
}

fn parse_bits(s: &str) -> Result<Range<u32>, String> {
    let (a, b) = s.split_once("..").ok_or("expected LO..HI, e.g. 0..64")?;
    let lo: u32 = a.trim().parse().map_err(|_| format!("bad LO `{a}`"))?;
    let hi: u32 = b.trim().parse().map_err(|_| format!("bad HI `{b}`"))?;
    if lo >= hi || hi > 64 {
        return Err(format!("need 0 <= LO < HI <= 64, got {lo}..{hi}"));
    }
    Ok(lo..hi)
}

fn stage_order(name: &str) -> (u32, u32, u32, String) {
    let index = |p: &str| p.parse().unwrap_or(u32::MAX);
    match name {
        "sort.setup" => (0, 0, 0, String::new()),
        "sort.histogram" => (1, 0, 0, String::new()),
        "sort.copy" => (3, 0, 0, String::new()),
        _ => {
            // A reduce-then-scan pass's count and scan, then the pass itself.
            if let Some(p) = name.strip_prefix("sort.count") {
                (2, index(p), 0, String::new())
            } else if let Some(p) = name.strip_prefix("sort.pass") {
                (2, index(p), 1, String::new())
            } else {
                (2, u32::MAX, 0, name.to_string())
            }
        }
    }
}

#[derive(serde::Serialize)]
struct SortReport {
    device: String,
    n: u32,
    bits: String,
    vary: String,
    /// The pass kernel (`SortPass::name`).
    pass_kernel: &'static str,
    /// Look-back polls before the fallback recount.
    spin_limit: u32,
    /// Histogram workgroups at most (0: one per 4 096 keys).
    hist_groups: u32,
    /// Look-back words a digit reads at once (coalesced passes).
    lookback_window: u32,
    /// ALU rounds between two polls of an unpublished look-back word (coalesced passes).
    lookback_backoff: u32,
    /// The probe run in place of the passes (`copy`, `tile`; null: the pass itself).
    probe: Option<&'static str>,
    passes: u32,
    /// Bit p set: pass p was skipped (its digit is the same in every key).
    skipped_passes: u32,
    runs: u32,
    /// Milliseconds of untimed sorts run back to back before each run (`--heat-ms`).
    heat_ms: f64,
    /// Untimed sorts recorded before each timed run (median): heat_ms over the fastest
    /// run's GPU time so far, at most MAX_HEAT_SORTS.
    heat_sorts: u32,
    /// GPU time of those untimed sorts before each timed run (median; 0 without heat).
    heat_gpu_ms: f64,
    /// GPU time of every timed run, in order: a device still changing its clocks shows
    /// as a trend here.
    runs_ms: Vec<f64>,
    median_ms: f64,
    mkeys_per_s: f64,
    wall_median_ms: f64,
    stages_median_ms: BTreeMap<String, f64>,
    /// Bytes a pass reads and writes: n × (8-byte key + 4-byte value) × 2.
    bytes_per_pass: u64,
    /// bytes_per_pass / median time, per pass that ran (GB/s = 1e9 bytes/s); the
    /// histogram and a reduce-then-scan pass's count (`sort.countP`: the tile counts
    /// and their scan, timed apart from `sort.passP`) read n keys once.
    stages_gb_per_s: BTreeMap<String, f64>,
    /// The device's own copy of the same pairs (vkCmdCopyBuffer of the keys and the
    /// values, median of the runs), and bytes_per_pass over its time: the floor of a
    /// pass, which moves the same bytes.
    copy_floor_ms: f64,
    /// Null where the copy took no measurable time (a timer too coarse for the size).
    copy_floor_gb_per_s: Option<f64>,
    /// The decoupled look-back of the timed runs (medians): status words read per digit
    /// and tile (1 is the least: the predecessor had its inclusive prefix), extra polls
    /// of unpublished words per tile, fallback rounds per run.
    lookback: LookbackReport,
    verified: bool,
    failed_runs: u32,
    /// The CPU baseline (null with --no-baseline).
    cpu_median_ms: Option<f64>,
    cpu_mkeys_per_s: Option<f64>,
    speedup_vs_cpu: Option<f64>,
}

#[derive(serde::Serialize)]
struct LookbackReport {
    steps_per_digit_tile: f64,
    waits_per_tile: f64,
    fallbacks_per_run: f64,
}

pub(super) fn bench_sort(ctx: &Context, args: &SortArgs) -> anyhow::Result<()> {
    let SortArgs {
        n,
        ref bits,
        ref vary,
        all_passes,
        ref pass,
        runs,
        warmup,
        heat_ms,
        spin,
        hist_groups,
        window,
        backoff,
        ref probe,
        no_baseline,
        seed,
        json,
    } = *args;
    let bits = bits.clone();
    let pass = match pass.as_str() {
        "auto" => SortPass::for_device(ctx.info()),
        p => p.parse::<SortPass>().map_err(anyhow::Error::msg)?,
    };
    let pass_probe = probe
        .as_deref()
        .map(|p| p.parse::<PassProbe>().map_err(anyhow::Error::msg))
        .transpose()?;
    let heat_ms = heat_ms.unwrap_or(if ctx.info().is_cpu { 0.0 } else { 200.0 });
    if !(0.0..=10_000.0).contains(&heat_ms) {
        bail!("--heat-ms {heat_ms}: must be between 0 and 10000");
    }
    if runs < 5 {
        bail!("--runs must be at least 5 (medians of fewer runs are noise on a shared machine)");
    }
    if n == 0 {
        bail!("--n must be at least 1");
    }
    // Sizes checked before anything is allocated: the device's largest buffer holds the
    // keys (8 bytes each), and the host holds keys, values and two reference copies.
    let max_alloc = ctx.info().max_memory_allocation_size;
    if u64::from(n) * 8 > max_alloc {
        bail!(
            "--n {n}: the keys need {} MiB in one device buffer, above {}'s largest \
             allocation ({} MiB); use --n {} or less",
            (u64::from(n) * 8) >> 20,
            ctx.info().name,
            max_alloc >> 20,
            max_alloc / 8
        );
    }
    let host_bytes = u64::from(n) * (8 + 4 + 2 * 16);
    let mut keys: Vec<u64> = Vec::new();
    let mut values: Vec<u32> = Vec::new();
    let mut host_probe: Vec<u8> = Vec::new();
    if keys.try_reserve_exact(n as usize).is_err()
        || values.try_reserve_exact(n as usize).is_err()
        || host_probe.try_reserve_exact(host_bytes as usize).is_err()
    {
        bail!(
            "--n {n}: the benchmark needs ~{} MiB of host memory for the keys and their \
             CPU reference sorts, more than this machine can allocate; use a smaller --n",
            host_bytes >> 20
        );
    }
    drop(host_probe);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let vary_mask = if vary.end - vary.start == 64 {
        u64::MAX
    } else {
        ((1u64 << (vary.end - vary.start)) - 1) << vary.start
    };
    let fixed = rng.next_u64() & !vary_mask;
    keys.extend((0..n).map(|_| fixed | (rng.next_u64() & vary_mask)));
    values.extend(0..n);
    let mask = if bits.end - bits.start == 64 {
        u64::MAX
    } else {
        (1u64 << (bits.end - bits.start)) - 1
    };
    let lo = bits.start;

    // The sort first: a pass or probe the device cannot run fails before the CPU work.
    let mut sorter = RadixSort::with_pass(ctx, n, pass).context("creating the radix sort")?;
    sorter.set_skip_constant(!all_passes);
    sorter.set_spin_limit(spin);
    if let Some(g) = hist_groups {
        sorter.set_hist_groups(g);
    }
    sorter.set_lookback_window(window)?;
    sorter.set_lookback_backoff(backoff);
    sorter.set_probe(pass_probe)?;
    // CPU baseline in this process: sort_unstable on the same pairs, same key bits.
    let mut cpu_ms = Vec::new();
    let pairs: Vec<(u64, u32)> = keys.iter().copied().zip(values.iter().copied()).collect();
    // A probe is not a sort: no baseline to set it against.
    let cpu_runs = if no_baseline || pass_probe.is_some() {
        0
    } else {
        warmup + runs
    };
    for i in 0..cpu_runs {
        let mut p = pairs.clone();
        let t = Instant::now();
        p.sort_unstable_by_key(|&(k, _)| (k >> lo) & mask);
        let dt = t.elapsed().as_secs_f64() * 1e3;
        std::hint::black_box(&p);
        if i >= warmup {
            cpu_ms.push(dt);
        }
    }
    // Reference for verification: the stable order; with a probe, what it leaves (the
    // input, or every tile of the pass sorted stably).
    let mut expect = pairs;
    match pass_probe {
        None => expect.sort_by_key(|&(k, _)| (k >> lo) & mask),
        Some(PassProbe::Copy) => {}
        Some(PassProbe::Tile) => expect
            .chunks_mut(pass.tile() as usize)
            .for_each(|t| t.sort_by_key(|&(k, _)| (k >> lo) & mask)),
    }
    let (ek, ev): (Vec<u64>, Vec<u32>) = expect.into_iter().unzip();

    let scratch = SortScratch::new(ctx, n)?;
    let src_k = ctx.buffer_from("bench.keys.src", &keys)?;
    let src_v = ctx.buffer_from("bench.values.src", &values)?;
    let passes = passes_for(&bits);
    // start, setup, histogram, per pass a count (reduce-then-scan) and the pass, copy.
    let mut ts = Timestamps::new(ctx, 4 + 2 * passes)?;
    let mut gpu_ms = Vec::new();
    let mut wall_ms = Vec::new();
    let mut stages: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut failed = 0u32;
    let mut lookback: Vec<svraster::sort::LookbackCounters> = Vec::new();
    // Untimed sorts before each run (`--heat-ms`): as many as the fastest run so far
    // says fill heat_ms (a run timed at cold clocks would under-count them); none before
    // the first, whose time is not known yet. Timed as
    // one stage, so that the wall time of the run can leave them out.
    let mut heat_ts = Timestamps::new(ctx, 2)?;
    let record_heat = |cmd, heat: u32, heat_ts: &mut Timestamps| -> svraster::Result<()> {
        if heat == 0 {
            return Ok(());
        }
        heat_ts.begin(cmd);
        for _ in 0..heat {
            recorder::copy(ctx, cmd, &src_k, &scratch.keys, 0, 0, n as u64 * 8);
            recorder::copy(ctx, cmd, &src_v, &scratch.values, 0, 0, n as u64 * 4);
            recorder::barrier(ctx, cmd);
            sorter.record(
                cmd,
                &scratch.as_buffers(),
                Count::Host(n),
                bits.clone(),
                None,
            )?;
            recorder::barrier(ctx, cmd);
        }
        heat_ts.mark(cmd, "heat");
        Ok(())
    };
    let mut heat_sorts = Vec::new();
    let mut heat_gpu_ms = Vec::new();
    let mut fastest_ms: Option<f64> = None;
    for i in 0..warmup + runs {
        let heat = fastest_ms.map_or(0, |ms| heat_sorts_for(heat_ms, ms));
        let t0 = Instant::now();
        let mut heat_record_ms = 0.0;
        let which = ctx.submit_and_wait(|cmd| {
            let r0 = Instant::now();
            record_heat(cmd, heat, &mut heat_ts)?;
            heat_record_ms = r0.elapsed().as_secs_f64() * 1e3;
            recorder::copy(ctx, cmd, &src_k, &scratch.keys, 0, 0, n as u64 * 8);
            recorder::copy(ctx, cmd, &src_v, &scratch.values, 0, 0, n as u64 * 4);
            recorder::barrier(ctx, cmd);
            ts.begin(cmd);
            let w = sorter.record(
                cmd,
                &scratch.as_buffers(),
                Count::Host(n),
                bits.clone(),
                Some(&mut ts),
            )?;
            Ok(w)
        })?;
        let st = ts.stages()?;
        let gpu: f64 = st.iter().map(|s| s.1).sum();
        // Wall time of the timed sort alone: the heat's recording and GPU time taken out.
        let heat_gpu: f64 = if heat > 0 {
            heat_ts.stages()?.iter().map(|s| s.1).sum()
        } else {
            0.0
        };
        let wall = t0.elapsed().as_secs_f64() * 1e3 - heat_record_ms - heat_gpu;
        fastest_ms = Some(fastest_ms.map_or(gpu, |f: f64| f.min(gpu)));
        let (rk, rv) = scratch.result(which);
        let gk: Vec<u64> = ctx.download(rk, 0, n as usize)?;
        let gv: Vec<u32> = ctx.download(rv, 0, n as usize)?;
        let errors = sorter.take_errors()?;
        if gk != ek || gv != ev || errors != 0 {
            failed += 1;
            let bad = gk
                .iter()
                .zip(&ek)
                .position(|(a, b)| a != b)
                .or_else(|| gv.iter().zip(&ev).position(|(a, b)| a != b));
            eprintln!("run {i}: WRONG RESULT (first mismatch at {bad:?}, error bits {errors:#x})");
        }
        if i >= warmup {
            heat_sorts.push(f64::from(heat));
            heat_gpu_ms.push(heat_gpu);
            lookback.push(sorter.last_lookback()?);
            gpu_ms.push(gpu);
            wall_ms.push(wall);
            for (name, ms) in st {
                stages.entry(name).or_default().push(ms);
            }
        }
    }
    // The floor: the device copies the same pairs (what a pass reads and writes).
    let mut floor_ts = Timestamps::new(ctx, 2)?;
    let mut floor_ms = Vec::new();
    let heat = heat_sorts_for(
        heat_ms,
        gpu_ms.iter().copied().fold(f64::INFINITY, f64::min),
    );
    for i in 0..warmup + runs {
        ctx.submit_and_wait(|cmd| {
            record_heat(cmd, heat, &mut heat_ts)?;
            floor_ts.begin(cmd);
            recorder::copy(ctx, cmd, &src_k, &scratch.keys_alt, 0, 0, n as u64 * 8);
            recorder::copy(ctx, cmd, &src_v, &scratch.values_alt, 0, 0, n as u64 * 4);
            floor_ts.mark(cmd, "copy");
            Ok(())
        })?;
        let ms: f64 = floor_ts.stages()?.iter().map(|s| s.1).sum();
        if i >= warmup {
            floor_ms.push(ms);
        }
    }
    let copy_floor_ms = median(&floor_ms);
    let med = median(&gpu_ms);
    let cpu = (!cpu_ms.is_empty()).then(|| median(&cpu_ms));
    let skipped = sorter.last_skipped()?;
    let stages_median_ms: BTreeMap<String, f64> =
        stages.iter().map(|(k, v)| (k.clone(), median(v))).collect();
    let bytes_per_pass = u64::from(n) * 12 * 2;
    let ran = f64::from(passes - (skipped & ((1 << passes) - 1)).count_ones());
    let tiles = f64::from(n.div_ceil(pass.tile()));
    let per = |f: &dyn Fn(&svraster::sort::LookbackCounters) -> f64, d: f64| {
        let v: Vec<f64> = lookback.iter().map(|c| f(c) / d.max(1.0)).collect();
        median(&v)
    };
    let lookback = LookbackReport {
        steps_per_digit_tile: per(&|c| f64::from(c.steps), (tiles - 1.0) * 256.0 * ran),
        waits_per_tile: per(&|c| f64::from(c.waits), tiles * ran),
        fallbacks_per_run: per(&|c| f64::from(c.fallbacks), 1.0),
    };
    let stages_gb_per_s = stages_median_ms
        .iter()
        .filter_map(|(k, &ms)| {
            let bytes = if k == "sort.histogram" {
                u64::from(n) * 8
            } else if let Some(p) = k.strip_prefix("sort.count") {
                // Reduce-then-scan: the tile counts read the keys once (the scan's
                // 1 KiB per tile is not counted).
                let p: u32 = p.parse().ok()?;
                if skipped & (1 << p) != 0 {
                    return None;
                }
                u64::from(n) * 8
            } else if let Some(p) = k.strip_prefix("sort.pass") {
                let p: u32 = p.parse().ok()?;
                if skipped & (1 << p) != 0 {
                    return None;
                }
                bytes_per_pass
            } else {
                return None;
            };
            Some((k.clone(), bytes as f64 / (ms * 1e6)))
        })
        .collect();
    let report = SortReport {
        device: ctx.info().name.clone(),
        n,
        bits: format!("{}..{}", bits.start, bits.end),
        vary: format!("{}..{}", vary.start, vary.end),
        pass_kernel: pass.name(),
        spin_limit: sorter.spin_limit(),
        hist_groups: sorter.hist_groups(),
        lookback_window: sorter.lookback_window(),
        lookback_backoff: sorter.lookback_backoff(),
        probe: pass_probe.map(PassProbe::name),
        passes,
        skipped_passes: skipped,
        runs,
        heat_ms,
        heat_sorts: median(&heat_sorts) as u32,
        heat_gpu_ms: median(&heat_gpu_ms),
        runs_ms: gpu_ms.clone(),
        median_ms: med,
        mkeys_per_s: n as f64 / med / 1e3,
        wall_median_ms: median(&wall_ms),
        stages_median_ms,
        bytes_per_pass,
        stages_gb_per_s,
        copy_floor_ms,
        copy_floor_gb_per_s: (copy_floor_ms > 0.0)
            .then(|| bytes_per_pass as f64 / (copy_floor_ms * 1e6)),
        lookback,
        verified: failed == 0,
        failed_runs: failed,
        cpu_median_ms: cpu,
        cpu_mkeys_per_s: cpu.map(|c| n as f64 / c / 1e3),
        speedup_vs_cpu: cpu.map(|c| c / med),
    };
    if json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        println!(
            "sort of {} u64 keys + u32 values, bits {} ({} passes, {} skipped; keys vary in \
             bits {}), pass kernel {}{} on {}",
            n,
            report.bits,
            passes,
            skipped.count_ones(),
            report.vary,
            pass.name(),
            pass_probe.map_or(String::new(), |p| format!(
                " replaced by its `{}` probe (a timing instrument: the result is not a sort)",
                p.name()
            )),
            report.device
        );
        println!("  GPU   median {:9.2} ms  {:8.2} Mkeys/s  (timestamps; wall {:.2} ms; {} runs after {} warm-up)", med, report.mkeys_per_s, report.wall_median_ms, runs, warmup);
        if heat_ms > 0.0 {
            println!(
                "    each run after {} untimed sorts in its submission (--heat-ms {heat_ms}: the device busy before it)",
                report.heat_sorts
            );
        }
        let each: Vec<String> = report.runs_ms.iter().map(|t| format!("{t:.2}")).collect();
        println!("    runs in order: {} ms", each.join(", "));
        let mut names: Vec<_> = report.stages_median_ms.iter().collect();
        names.sort_by_key(|(k, _)| stage_order(k));
        for (k, v) in names {
            match report.stages_gb_per_s.get(k) {
                Some(g) => println!("    {k:<16} {v:9.2} ms  {g:7.2} GB/s"),
                None => println!("    {k:<16} {v:9.2} ms"),
            }
        }
        println!(
            "    (device copy of the pairs {:9.2} ms  {} GB/s: the floor of a pass)",
            report.copy_floor_ms,
            report
                .copy_floor_gb_per_s
                .map_or("-".to_string(), |g| format!("{g:7.2}"))
        );
        let lb = &report.lookback;
        println!(
            "  look-back: {:.2} status words read per digit and tile, {:.1} extra polls per \
             tile, {:.0} fallback rounds per run",
            lb.steps_per_digit_tile, lb.waits_per_tile, lb.fallbacks_per_run
        );
        if let (Some(cpu), Some(rate), Some(ratio)) =
            (cpu, report.cpu_mkeys_per_s, report.speedup_vs_cpu)
        {
            println!(
                "  CPU   median {cpu:9.2} ms  {rate:8.2} Mkeys/s  (Rust sort_unstable, 1 thread)"
            );
            println!("  GPU/CPU speed ratio {ratio:.3}");
        }
        println!(
            "  verified: {} ({} of {} runs wrong)",
            if failed == 0 { "yes" } else { "NO" },
            failed,
            warmup + runs
        );
    }
    if failed > 0 {
        bail!("{failed} run(s) produced a wrong result");
    }
    Ok(())
}
