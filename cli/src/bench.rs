//! `svraster bench …`: GPU timings by timestamps, medians after warm-up, and a CPU
//! baseline measured in the same process.

use std::collections::BTreeMap;
use std::time::Instant;

use anyhow::bail;
use clap::Subcommand;
use svraster::gpu::{Context, Timestamps};
use svraster::sort::SortPass;

use svraster::eval::median;

use super::bench_report::{
    mean_counters, print_work, tile_balance, walk_json, walk_workgroups, work_json, QueueCost,
};

#[derive(Subcommand)]
pub enum BenchCmd {
    /// Onesweep radix sort of u64 keys + u32 values; every run is verified.
    Sort(super::bench_sort::SortArgs),
    /// Forward rendering of a model over the views of a dataset split.
    Render {
        /// A .safetensors checkpoint, or a run directory holding model.safetensors.
        model: std::path::PathBuf,
        /// Dataset whose cameras are rendered (any format `svraster train` reads;
        /// default: the run's own when MODEL is a run directory).
        #[arg(long)]
        data: Option<std::path::PathBuf>,
        #[arg(long, default_value = "test", value_parser = ["train", "val", "test"])]
        split: String,
        /// Downscale factor of the cameras' images (default: the run's own when MODEL is
        /// a run directory, else 1).
        #[arg(long)]
        downscale: Option<f64>,
        /// Views used (the first N of the split).
        #[arg(long, default_value_t = 5)]
        views: usize,
        /// Timed passes over the views (medians are over all timed frames).
        #[arg(long, default_value_t = 3)]
        runs: u32,
        /// Samples per ray-voxel segment.
        #[arg(long, default_value_t = 1)]
        samples: u32,
        /// Supersampling factor (default: the model's, i.e. the `ss` it was trained with,
        /// as `render` and `eval` use).
        #[arg(long)]
        ss: Option<f32>,
        /// Entries per segment of a tile's list in the composite (0: segments off;
        /// default: the device's: 0 on CPU devices; on GPUs chosen per frame from its tile
        /// count, 256 to 2048, raster::auto_segment_entries).
        #[arg(long)]
        segments: Option<u32>,
        /// Warm-up lasts at least this long: after one frame per view, the views again
        /// until it has (a GPU left idle lowers its clocks; default 300 on GPUs, 0 on
        /// CPU devices; at most 100 000 frames).
        #[arg(long, value_name = "MS")]
        warmup_ms: Option<f64>,
        #[arg(long)]
        json: bool,
    },
    /// Training iterations on a dataset: median ms per iteration and per stage.
    Train {
        /// Dataset (its train split; any format `svraster train` reads).
        data: std::path::PathBuf,
        #[arg(long, default_value_t = 1.0)]
        downscale: f64,
        /// Configuration preset (see `svraster train`; default: the data format's, as
        /// for `svraster train`).
        #[arg(long)]
        preset: Option<String>,
        /// Config overrides, as for `svraster train`.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Timed iterations (after the warm-up).
        #[arg(long, default_value_t = 20)]
        iters: u32,
        /// Untimed warm-up iterations.
        #[arg(long, default_value_t = 3)]
        warmup: u32,
        /// Warm-up lasts at least this long: iterations past --warmup until it has (a GPU
        /// left idle lowers its clocks; default 300 on GPUs, 0 on CPU devices; at most
        /// 100 000 iterations). Warm-up iterations train the model as the timed ones do.
        #[arg(long, value_name = "MS")]
        warmup_ms: Option<f64>,
        /// Entries per segment of a tile's list in the composite (0: segments off;
        /// default: the device's: 0 on CPU devices; on GPUs chosen per frame from its tile
        /// count, 256 to 2048, raster::auto_segment_entries).
        #[arg(long)]
        segments: Option<u32>,
        #[arg(long)]
        json: bool,
    },
    /// Speed/accuracy trade: without --vary, of the voxel layout (paper Tab. 6: adaptive
    /// vs uniform layouts under one voxel budget); with --vary, of any knobs, one factor at
    /// a time around the preset. Every variant is trained and evaluated on a held-out
    /// split; writes OUT/trade.md, OUT/trade.json and OUT/trade.png (Pareto fronts marked).
    Trade {
        /// Dataset (any format `svraster train` reads; captures: use --split test, every
        /// --holdout-th view).
        data: std::path::PathBuf,
        /// Output directory (one run directory per variant).
        #[arg(long, default_value = "trade")]
        out: std::path::PathBuf,
        #[arg(long, default_value_t = 4.0)]
        downscale: f64,
        #[arg(long, default_value = "quick")]
        preset: String,
        /// Training iterations of every variant.
        #[arg(long, default_value_t = 300)]
        iters: u32,
        /// The voxel budget every variant trains under.
        #[arg(long, default_value_t = 300_000)]
        max_voxels: u64,
        /// Final levels of the uniform variants (comma-separated).
        #[arg(long, value_delimiter = ',', default_value = "6,7")]
        uniform_levels: Vec<u32>,
        #[arg(long, default_value = "val", value_parser = ["train", "val", "test"])]
        split: String,
        /// Config overrides applied to every variant.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// A knob to sweep, one factor at a time around the preset (repeatable): any
        /// --set key or `iters`, e.g. --vary ss=1,1.5 --vary samples=1,3 --vary
        /// sh_degree=0,1 --vary layout=uniform,fixed. With --vary, --uniform-levels is
        /// not used (vary `layout` and `max_level` instead).
        #[arg(long, value_name = "KEY=V1,V2")]
        vary: Vec<String>,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Keep a variant that an earlier run of the same comparison (same data, split,
        /// downscale, preset, iterations, seed, overrides and budget) finished, instead of
        /// training it again: a long comparison stopped part-way continues.
        #[arg(long)]
        reuse: bool,
        #[arg(long)]
        json: bool,
        /// With --vary: after the one-factor variants, train up to this many pairwise
        /// combinations of those on a Pareto front (different knobs; 0: none).
        #[arg(long, default_value_t = 4)]
        combine: usize,
        /// Fit the whole comparison in this many minutes: a 100-iteration calibration run
        /// of the base configuration sets --iters (a multiple of 100, at least 100).
        #[arg(long, value_name = "MINUTES")]
        budget_minutes: Option<f64>,
    },
}

pub fn run(ctx: &Context, cmd: BenchCmd) -> anyhow::Result<()> {
    match cmd {
        BenchCmd::Render {
            model,
            data,
            split,
            downscale,
            views,
            runs,
            samples,
            ss,
            segments,
            warmup_ms,
            json,
        } => bench_render(
            ctx,
            &RenderBench {
                data: super::data_or_run(data, &model)?,
                downscale: downscale.unwrap_or_else(|| super::run_downscale(&model)),
                source: super::run_source(&model, &super::DataArgs::default()),
                model,
                split,
                views,
                runs,
                samples,
                ss,
                segments,
                warmup_ms: warmup_ms_for(ctx, warmup_ms)?,
            },
            json,
        ),
        BenchCmd::Train {
            data,
            downscale,
            preset,
            set,
            iters,
            warmup,
            warmup_ms,
            segments,
            json,
        } => {
            let format = super::train::format_preset(svraster::data::detect_format(&data));
            let preset = match preset {
                Some(p) => svraster::train::config::TrainConfig::resolve_preset(&p, format),
                None => format.into(),
            };
            let warmup = Warmup {
                at_least: warmup,
                ms: warmup_ms_for(ctx, warmup_ms)?,
            };
            bench_train(
                ctx, &data, downscale, &preset, &set, iters, warmup, segments, json,
            )
        }
        BenchCmd::Trade {
            data,
            out,
            downscale,
            preset,
            iters,
            max_voxels,
            uniform_levels,
            split,
            set,
            vary,
            seed,
            reuse,
            json,
            combine,
            budget_minutes,
        } => super::trade::run(
            ctx,
            &super::trade::TradeArgs {
                combine,
                budget_minutes,
                data,
                out,
                downscale,
                preset,
                iters,
                max_voxels,
                uniform_levels,
                split,
                set,
                vary,
                seed,
                reuse,
                json,
            },
        )
        .map(|_| ()),
        BenchCmd::Sort(args) => super::bench_sort::bench_sort(ctx, &args),
    }
}

/// Most warm-up frames or iterations `--warmup-ms` adds (a bound on a mistyped value).
const MAX_WARMUP: u32 = 100_000;

/// `--warmup-ms` checked, or the device's default: 300 ms on GPUs (on the H200 a process
/// whose card had idled ran the same kernels up to 5× slower until its clocks rose:
/// docs/NVIDIA.md), none on CPU devices.
fn warmup_ms_for(ctx: &Context, ms: Option<f64>) -> anyhow::Result<f64> {
    let ms = ms.unwrap_or(if ctx.info().is_cpu { 0.0 } else { 300.0 });
    if !(0.0..=60_000.0).contains(&ms) {
        bail!("--warmup-ms {ms}: must be between 0 and 60000");
    }
    Ok(ms)
}

/// `bench train`'s warm-up: at least this many iterations, and on until `ms` have passed.
#[derive(Clone, Copy)]
struct Warmup {
    at_least: u32,
    ms: f64,
}

#[allow(clippy::too_many_arguments)]
/// What `bench render` measures.
struct RenderBench {
    model: std::path::PathBuf,
    data: std::path::PathBuf,
    split: String,
    downscale: f64,
    source: svraster::data::SourceOptions,
    views: usize,
    runs: u32,
    samples: u32,
    /// Supersampling (None: the model's).
    ss: Option<f32>,
    segments: Option<u32>,
    /// Warm-up lasts at least this long (ms).
    warmup_ms: f64,
}

fn bench_render(ctx: &Context, b: &RenderBench, json: bool) -> anyhow::Result<()> {
    use svraster::raster::Renderer;
    use svraster::scene::SceneGpu;
    let (model, data, split, runs, segments) =
        (&b.model, &b.data, b.split.as_str(), b.runs, b.segments);
    if runs == 0 || b.views == 0 {
        bail!("--runs and --views must be at least 1");
    }
    let scene = super::inputs::load_model(model)?;
    let opts = svraster::raster::RenderOptions {
        samples: b.samples,
        supersample: b.ss.unwrap_or(scene.supersample),
    };
    let mut cams = super::render::split_cameras(data, split, b.downscale, &b.source, &scene)?;
    cams.truncate(b.views);
    if cams.is_empty() {
        bail!("split `{split}` of {} has no frames", data.display());
    }
    let gpu = SceneGpu::upload(ctx, &scene)?;
    let mut r = Renderer::new(ctx)?;
    if let Some(s) = segments {
        r.set_segment_entries(s);
    }
    let mut pools = [Timestamps::new(ctx, 32)?, Timestamps::new(ctx, 32)?];
    // Warm-up: pipelines compiled, buffers grown to what every view needs; then the
    // views queued again until --warmup-ms have passed (the device's clocks up).
    let warm = Instant::now();
    for cam in &cams {
        r.render_to_device(&gpu, cam, &opts, None)?;
    }
    let mut warmup_frames = cams.len() as u32;
    while warm.elapsed().as_secs_f64() * 1e3 < b.warmup_ms && warmup_frames < MAX_WARMUP {
        r.render_each(&gpu, &cams, &opts, |_, _, _| -> anyhow::Result<()> {
            Ok(())
        })?;
        warmup_frames += cams.len() as u32;
    }
    let warmup_wall_ms = warm.elapsed().as_secs_f64() * 1e3;
    let mut frame_ms = Vec::new();
    let mut wall_ms = Vec::new();
    let mut stages: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut order: Vec<String> = Vec::new();
    let (mut dup, mut per_tile, mut max_tile, mut entries) =
        (Vec::new(), Vec::new(), 0u32, Vec::new());
    let mut visible = Vec::new();
    let mut queue = QueueCost::default();
    let mut balance = Vec::new();
    let mut walk_groups = Vec::new();
    // Timed frames queued as `render` and `eval` queue them (Renderer::render_each):
    // each frame's timestamps land in one of two pools, read while the next frame
    // runs, so the GPU is never idle between timed frames and their timeline is the
    // queued one. The wall time between frames handed over is the throughput with
    // the timestamps.
    for _ in 0..runs {
        let mut t = Instant::now();
        r.render_each_timed(
            &gpu,
            &cams,
            &opts,
            &mut pools,
            |_, _, st, times| -> anyhow::Result<()> {
                wall_ms.push(t.elapsed().as_secs_f64() * 1e3);
                balance.push(tile_balance(&st));
                walk_groups.push(walk_workgroups(&st));
                frame_ms.push(times.iter().map(|(_, ms)| ms).sum());
                for (name, ms) in times {
                    if !order.contains(&name) {
                        order.push(name.clone());
                    }
                    stages.entry(name).or_default().push(ms);
                }
                dup.push(st.entries as f64 / st.visible_voxels.max(1) as f64);
                per_tile.push(st.entries as f64 / st.tiles as f64);
                max_tile = max_tile.max(st.max_tile_entries);
                entries.push(st.entries as f64);
                visible.push(st.visible_voxels as f64);
                t = Instant::now();
                Ok(())
            },
        )?;
    }
    // The same frames without timestamps, as `render` and `eval` render them, images
    // read back from mapped memory: the wall time per frame, and the queue traffic what
    // a steady frame costs the host.
    let mut queued_ms = Vec::new();
    for _ in 0..runs {
        let mut c0 = ctx.queue_counters();
        let mut t = Instant::now();
        r.render_each(&gpu, &cams, &opts, |_, _, _| -> anyhow::Result<()> {
            let wall = t.elapsed().as_secs_f64() * 1e3;
            queue.push(ctx.queue_counters() - c0, wall);
            queued_ms.push(wall);
            c0 = ctx.queue_counters();
            t = Instant::now();
            Ok(())
        })?;
    }
    // Work counters from separate frames (the counting kernel is slower).
    r.set_counters(true)?;
    let mut counted = Vec::new();
    for cam in &cams {
        r.render_to_device(&gpu, cam, &opts, None)?;
        counted.extend(r.counters()?);
    }
    r.set_counters(false)?;
    let work = mean_counters(&counted);
    let (w, h) = (cams[0].width, cams[0].height);
    let stage_medians: Vec<(String, f64)> = order
        .iter()
        .map(|n| (n.clone(), median(&stages[n])))
        .collect();
    if json {
        let obj = serde_json::json!({
            "model": model.display().to_string(),
            "voxels": scene.num_voxels(),
            "width": w,
            "height": h,
            "views": cams.len(),
            "frames_timed": frame_ms.len(),
            "warmup_ms": b.warmup_ms,
            "warmup_frames": warmup_frames,
            "warmup_wall_ms": warmup_wall_ms,
            "samples": opts.samples,
            "supersample": opts.supersample,
            "median_ms": median(&frame_ms),
            "wall_median_ms": median(&queued_ms),
            "wall_timed_median_ms": median(&wall_ms),
            "stages_median_ms": stage_medians.iter().cloned().collect::<BTreeMap<_, _>>(),
            "visible_voxels_median": median(&visible),
            "entries_median": median(&entries),
            "duplicates_per_visible_voxel_median": median(&dup),
            "entries_per_tile_median": median(&per_tile),
            "max_entries_per_tile": max_tile,
            "tile_balance_median": median(&balance),
            "walk_workgroups_per_dispatch": median(&walk_groups),
            "segment_entries": r.segment_entries(),
            "sort_pass": SortPass::for_run(ctx.info()).map_err(anyhow::Error::msg)?.name(),
            "queue_per_frame": queue.json(),
            "device": ctx.info().name,
            "subgroup_size": ctx.info().subgroup_size,
            "work_per_frame": walk_json(&work.forward),
        });
        println!("{obj}");
    } else {
        println!(
            "bench render: {} voxels, {w}×{h}, {} views × {runs} runs, K={}, ss={} on {}",
            scene.num_voxels(),
            cams.len(),
            opts.samples,
            opts.supersample,
            ctx.info().name
        );
        println!(
            "  median {:.2} ms per frame (GPU timestamps, frames queued), {:.2} ms wall \
             queued with the image read back ({:.2} ms with the timestamps); after \
             {warmup_frames} warm-up frames in {warmup_wall_ms:.0} ms",
            median(&frame_ms),
            median(&queued_ms),
            median(&wall_ms)
        );
        for (n, ms) in &stage_medians {
            println!("    {n:<12} {ms:9.2} ms");
        }
        println!(
            "  visible voxels {:.0}, entries {:.0}: {:.2} per visible voxel, {:.1} per tile (max {max_tile}; longest/mean {:.1}, {} walk workgroups per dispatch)",
            median(&visible),
            median(&entries),
            median(&dup),
            median(&per_tile),
            median(&balance),
            median(&walk_groups)
        );
        println!("  per frame: {}", queue.text());
        print_work(&work, ctx.info().subgroup_size, "frame");
    }
    Ok(())
}

/// Stage groups of a training iteration: the frame's stages mapped to what the issue
/// asks for (preprocess, sort, forward), then losses, backward, optimizer.
fn stage_group(name: &str) -> &'static str {
    // Sub-stages (`backward.walk`, `optimizer.shs`, …) count towards their group.
    match name.split('.').next().unwrap_or(name) {
        "preprocess" => "preprocess",
        "scan" | "emit_keys" | "sort" | "tile_ranges" => "sort",
        "composite" | "finalize" => "forward",
        "losses" => "losses",
        "backward" => "backward",
        "optimizer" => "optimizer",
        _ => "other",
    }
}

#[allow(clippy::too_many_arguments)]
fn bench_train(
    ctx: &Context,
    data: &std::path::Path,
    downscale: f64,
    preset: &str,
    set: &[String],
    iters: u32,
    warmup: Warmup,
    segments: Option<u32>,
    json: bool,
) -> anyhow::Result<()> {
    use svraster::train::config::TrainConfig;
    use svraster::train::trainer::Trainer;
    if iters < 3 {
        bail!("--iters must be at least 3");
    }
    let mut cfg = TrainConfig::preset(preset)?;
    for kv in set {
        cfg.set(kv)?;
    }
    let mut train = svraster::data::load_split(data, "train", downscale, cfg.background)?;
    cfg.background = train.background;
    // As a new run of `svraster train`: a capture's background and world frame.
    svraster::train::bounds::resolve_run(&mut cfg, &mut train)?;
    // Time the full-model regime: SH at its final degree, supersampling on, all losses
    // (the distortion loss, off by default, at the paper's weight unless --set).
    if !set
        .iter()
        .any(|kv| kv.trim_start().starts_with("lambda_dist"))
    {
        cfg.lambda_dist = 0.1;
    }
    // A long schedule with no adaptive steps: every milestone's switch holds for every
    // iteration run here (TV until the end of a 10^6-iteration schedule; a 1-iteration
    // schedule, as before 2026-11-29, turned TV off after iteration 0), and the layout
    // stays what it is.
    cfg.iters = 1_000_000;
    cfg.adapt_every = 0.0;
    cfg.sh_every = 0.0;
    cfg.ss_from = 0.0;
    cfg.dist_from = 0.0;
    cfg.tv_until = 1.0;
    cfg.validate()?;
    let mut t = Trainer::new(ctx, cfg.clone(), &train, None)?;
    if let Some(s) = segments {
        t.set_segment_entries(s)?;
    }
    t.enable_timing()?;
    let mut groups: BTreeMap<&'static str, Vec<f64>> = BTreeMap::new();
    // Every timestamped part (kernel or kernel group); the text output lists them in
    // recording order, the JSON map by name.
    let mut parts: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut part_order: Vec<String> = Vec::new();
    let mut total = Vec::new();
    let mut wall = Vec::new();
    // The SH degree the timed iterations actually used (reported, not assumed).
    let mut sh_used = 0;
    let mut queue = QueueCost::default();
    let mut balance = Vec::new();
    let mut walk_groups = Vec::new();
    // Timestamped iterations, queued as training runs them: each one's stage times are
    // read when the host settles it, one step later (the last after a flush).
    let mut collect = |times: Vec<(String, f64)>| {
        let mut sums: BTreeMap<&'static str, f64> = BTreeMap::new();
        for (name, ms) in &times {
            *sums.entry(stage_group(name)).or_default() += ms;
            if !parts.contains_key(name) {
                part_order.push(name.clone());
            }
            parts.entry(name.clone()).or_default().push(*ms);
        }
        total.push(sums.values().sum::<f64>());
        for (k, v) in sums {
            groups.entry(k).or_default().push(v);
        }
    };
    let warm = Instant::now();
    let mut warmup_iters = 0u32;
    while warmup_iters < warmup.at_least
        || (warm.elapsed().as_secs_f64() * 1e3 < warmup.ms && warmup_iters < MAX_WARMUP)
    {
        t.step(false)?;
        warmup_iters += 1;
    }
    // The warm-up's last iteration settled and its times dropped: from here on every
    // settled iteration is a timed one.
    t.flush()?;
    let warmup_wall_ms = warm.elapsed().as_secs_f64() * 1e3;
    t.take_stage_times();
    for _ in 0..iters {
        let w = Instant::now();
        sh_used = t.step(false)?.sh_degree;
        wall.push(w.elapsed().as_secs_f64() * 1e3);
        if let Some(st) = t.frame_stats() {
            balance.push(tile_balance(&st));
            walk_groups.push(walk_workgroups(&st));
        }
        t.take_stage_times().into_iter().for_each(&mut collect);
    }
    t.flush()?;
    t.take_stage_times().into_iter().for_each(&mut collect);
    // Whether TV (a windowed term) was on through the timed iterations.
    let tv_on = cfg.lambda_tv > 0.0 && t.iter() <= cfg.schedule().tv_until;
    // The same iterations without timestamps: the wall time per iteration is the
    // throughput, and the queue traffic what a steady iteration costs the host.
    t.set_timing(false)?;
    let mut queued_wall = Vec::new();
    let (warmup, warmup_ms) = (warmup.at_least, warmup.ms);
    for i in 0..warmup + iters {
        let c0 = ctx.queue_counters();
        let w = Instant::now();
        t.step(false)?;
        let wall_ms = w.elapsed().as_secs_f64() * 1e3;
        if i < warmup {
            continue;
        }
        queue.push(ctx.queue_counters() - c0, wall_ms);
        queued_wall.push(wall_ms);
    }
    t.flush()?;
    // Work counters from separate iterations (the counting kernels are slower).
    t.set_counters(true)?;
    let mut counted = Vec::new();
    for _ in 0..iters.min(3) {
        t.step(false)?;
        counted.extend(t.counters()?);
    }
    t.set_counters(false)?;
    let work = mean_counters(&counted);
    t.check_finite()?;
    let med: Vec<(&str, f64)> = [
        "preprocess",
        "sort",
        "forward",
        "losses",
        "backward",
        "optimizer",
        "other",
    ]
    .iter()
    .filter_map(|&k| groups.get(k).map(|v| (k, median(v))))
    .collect();
    if json {
        let obj = serde_json::json!({
            "device": ctx.info().name,
            "data": data,
            "downscale": downscale,
            "image": [train.width, train.height],
            "voxels": t.voxels(),
            "grid_level": cfg.grid_level,
            "ss": cfg.ss,
            "sh_degree": sh_used,
            "float_atomics": t.float_atomics(),
            "reduction": t.reduction().name(),
            "iters": iters,
            "median_ms_per_iter": median(&total),
            "wall_median_ms_per_iter": median(&queued_wall),
            "wall_timed_median_ms_per_iter": median(&wall),
            "timed_iterations": total.len(),
            "warmup_ms": warmup_ms,
            "warmup_iters": warmup_iters,
            "tv_on": tv_on,
            "warmup_wall_ms": warmup_wall_ms,
            "stages_median_ms": med.iter().map(|(k, v)| (k.to_string(), *v)).collect::<BTreeMap<_, _>>(),
            "parts_median_ms": part_order.iter().map(|k| (k.clone(), median(&parts[k]))).collect::<BTreeMap<_, _>>(),
            "subgroup_size": ctx.info().subgroup_size,
            "queue_per_iter": queue.json(),
            "tile_balance_median": median(&balance),
            "walk_workgroups_per_dispatch_median": median(&walk_groups),
            "segment_entries": t.segment_entries(),
            "sort_pass": SortPass::for_run(ctx.info()).map_err(anyhow::Error::msg)?.name(),
            "work_per_iter": work_json(&work),
        });
        println!("{obj}");
    } else {
        println!(
            "train bench on {}: {} voxels (level {}), {}×{} images, ss up to {}, SH {}, {} timed iterations",
            ctx.info().name,
            t.voxels(),
            cfg.grid_level,
            train.width,
            train.height,
            cfg.ss,
            sh_used,
            iters
        );
        println!(
            "median {:.1} ms per iteration on the GPU timeline; wall {:.1} ms queued \
             ({:.1} ms with the timestamps); after {warmup_iters} warm-up iterations in \
             {warmup_wall_ms:.0} ms",
            median(&total),
            median(&queued_wall),
            median(&wall)
        );
        println!(
            "per iteration: {}; tile lists longest/mean {:.1}, {:.0} walk workgroups per dispatch",
            queue.text(),
            median(&balance),
            median(&walk_groups)
        );
        for (k, v) in med {
            println!("  {k:<11} {v:>9.2} ms");
            let mine: Vec<&String> = part_order.iter().filter(|p| stage_group(p) == k).collect();
            for p in mine.iter().filter(|_| mine.len() > 1) {
                println!("    {p:<18} {:>9.2} ms", median(&parts[p.as_str()]));
            }
        }
        print_work(&work, ctx.info().subgroup_size, "iteration");
    }
    Ok(())
}
