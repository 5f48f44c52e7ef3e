//! `svraster train`, `svraster eval` and the training part of `svraster demo`.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::Instant;

use anyhow::{bail, Context as _};
use svraster::data;
use svraster::eval::EvalReport;
use svraster::gpu::Context;
use svraster::raster::RenderOptions;
use svraster::scene::{checkpoint, Scene};
use svraster::train::config::TrainConfig;
use svraster::train::trainer::Trainer;

use super::progress::{fmt_duration, Progress, RateWindow};
use super::render::load_model;
use super::run_dir::{
    atomic_write, catch_signals, load_pair, lock_run, save_run, truncate_stats, INTERRUPTS,
};

pub struct TrainArgs {
    pub data: PathBuf,
    pub out: PathBuf,
    pub iters: Option<u32>,
    /// None: 1 for a new run, the run's own when resuming.
    pub downscale: Option<f64>,
    /// None: `synthetic` for a new run, the run's own when resuming.
    pub preset: Option<String>,
    pub seed: Option<u64>,
    pub set: Vec<String>,
    pub resume: bool,
    /// How to read DATA (new run: as given; resume: the run's own).
    pub source: data::SourceOptions,
    /// Evaluate the held-out split every N iterations (and at the end) into stats.jsonl.
    pub eval_every: Option<u32>,
    /// A config.json (or configuration object) as the base of a new run.
    pub config: Option<PathBuf>,
}

/// The preset of a new run: `--preset`, else the one the data's format calls for
/// (Blender → synthetic, COLMAP → real).
pub fn default_preset(a: &TrainArgs) -> String {
    let format = || {
        format_preset(
            a.source
                .format
                .unwrap_or_else(|| data::detect_format(&a.data)),
        )
    };
    match &a.preset {
        Some(p) => TrainConfig::resolve_preset(p, format()),
        None => format().into(),
    }
}

/// The preset a data format calls for.
pub fn format_preset(format: data::Format) -> &'static str {
    match format {
        data::Format::Blender => "synthetic",
        data::Format::Colmap | data::Format::Nerfstudio => "real",
        data::Format::Llff => "forward",
        data::Format::Neus => "object",
    }
}

/// The base configuration `--config FILE` names: a run's config.json (its `config`
/// and `preset`) or a bare configuration object; the schedule length of an extended run
/// is not carried over.
fn config_file(path: &Path) -> anyhow::Result<(TrainConfig, Option<String>)> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read --config {}", path.display()))?;
    let v: serde_json::Value = serde_json::from_str(&text)
        .with_context(|| format!("--config {} is not valid JSON", path.display()))?;
    let (obj, preset) = match v.get("config") {
        Some(c) => (c.clone(), v["preset"].as_str().map(String::from)),
        None => (v, None),
    };
    let mut cfg: TrainConfig = serde_json::from_value(obj).with_context(|| {
        format!(
            "--config {}: not a training configuration (a run's config.json, or its \
             \"config\" object)",
            path.display()
        )
    })?;
    cfg.schedule_iters = None;
    cfg.validate()
        .with_context(|| format!("--config {}", path.display()))?;
    Ok((cfg, preset))
}

/// The preset a new run records: the base config's, else [`default_preset`].
fn run_preset(a: &TrainArgs) -> anyhow::Result<String> {
    Ok(match &a.config {
        Some(p) => config_file(p)?.1.unwrap_or_else(|| "config".into()),
        None => default_preset(a),
    })
}

/// Resolves the configuration of a new run.
pub fn resolve_config(a: &TrainArgs) -> anyhow::Result<TrainConfig> {
    if a.config.is_some() && a.preset.is_some() {
        bail!("--config is the base of the run instead of a preset: drop --preset (or --config)");
    }
    let mut cfg = match &a.config {
        Some(p) => config_file(p)?.0,
        None => TrainConfig::preset(&default_preset(a))?,
    };
    if let Some(n) = a.iters {
        cfg.iters = n;
    }
    if let Some(s) = a.seed {
        cfg.seed = s;
    }
    for kv in &a.set {
        cfg.set(kv)?;
    }
    cfg.validate()?;
    Ok(cfg)
}

/// Outcome of a training run.
pub struct RunSummary {
    pub iters: u32,
    pub seconds: f64,
    pub interrupted: bool,
    /// Voxels of the saved model.
    pub voxels: u32,
}

impl RunSummary {
    /// `train --json`: the run's summary on stdout.
    pub fn json(&self, run: &Path) -> serde_json::Value {
        serde_json::json!({
            "run": run,
            "model": run.join("model.safetensors"),
            "iters": self.iters,
            "seconds": self.seconds,
            "voxels": self.voxels,
            "interrupted": self.interrupted,
        })
    }
}

/// Whether `run` holds a checkpoint (either file of the pair; temporary files alone are
/// a first checkpoint that was never completed): a directory with only config.json and
/// stats.jsonl is a run stopped before its first checkpoint, which starts over.
fn has_checkpoint(run: &Path) -> bool {
    ["model.safetensors", super::run_dir::OPT_FILE]
        .iter()
        .any(|f| run.join(f).exists())
}

/// Identity of a training split, to recognise a moved dataset on `--resume`: FNV-1a of
/// every frame's name and camera (size, intrinsics and pose as f32), in order.
fn split_fingerprint(ds: &data::Dataset) -> String {
    let mut bytes = Vec::new();
    for f in &ds.frames {
        bytes.extend_from_slice(f.name.as_bytes());
        bytes.push(0);
        let c = &f.camera;
        bytes.extend_from_slice(&c.width.to_le_bytes());
        bytes.extend_from_slice(&c.height.to_le_bytes());
        let vals = [c.fx, c.fy, c.cx, c.cy]
            .into_iter()
            .chain(c.c2w.iter().flatten().copied());
        for x in vals {
            bytes.extend_from_slice(&(x as f32).to_le_bytes());
        }
    }
    format!("{:016x}", super::run_dir::fnv64(&bytes))
}

/// The path as written in config.json (absolute where it resolves).
fn canonical(p: &Path) -> PathBuf {
    std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf())
}

/// `svraster train`.
pub fn run_train(ctx: &Context, a: &TrainArgs) -> anyhow::Result<RunSummary> {
    let run = &a.out;
    let cfg_path = run.join("config.json");
    let mut _lock = None;
    let mut extended = false;
    let mut moved: Option<(PathBuf, Option<String>)> = None;
    let (mut cfg, init, opt_state, start_iter, preset, downscale, source) = if a.resume {
        if a.seed.is_some() || !a.set.is_empty() || a.config.is_some() {
            bail!("--resume continues a run with its own config.json: drop --seed/--set/--config (or start a new --out)");
        }
        if !cfg_path.is_file() {
            bail!(
                "cannot resume: {} not found (start the run without --resume)",
                cfg_path.display()
            );
        }
        _lock = Some(lock_run(run)?);
        let text = std::fs::read_to_string(&cfg_path)
            .with_context(|| format!("cannot read {}", cfg_path.display()))?;
        let v: serde_json::Value = serde_json::from_str(&text)
            .with_context(|| format!("{} is not valid JSON", cfg_path.display()))?;
        let mut cfg: TrainConfig = serde_json::from_value(v["config"].clone())
            .with_context(|| format!("{}: bad \"config\"", cfg_path.display()))?;
        cfg.validate()?;
        if let Some(n) = a.iters.filter(|&n| n != cfg.iters) {
            // An extension: the milestones stay where the run's schedule put them.
            if n < cfg.iters {
                bail!(
                    "--resume --iters {n}: the run in {} is {} iterations long; --iters can \
                     only extend it (to end it early, stop it: its last checkpoint stands)",
                    run.display(),
                    cfg.iters
                );
            }
            cfg.schedule_iters = Some(cfg.schedule_iters.unwrap_or(cfg.iters));
            cfg.iters = n;
            cfg.validate()?;
            extended = true;
        }
        // The same run: the data, downscale and preset that shaped it.
        // Another path is the same data when its training views are the run's (a moved
        // dataset): decided once they are loaded.
        let run_data = v["data"].as_str().map(PathBuf::from);
        if let Some(d) = &run_data {
            if canonical(d) != canonical(&a.data) {
                moved = Some((d.clone(), v["train_fingerprint"].as_str().map(String::from)));
            }
        }
        let run_downscale = v["downscale"].as_f64().unwrap_or(1.0);
        if let Some(d) = a.downscale {
            if d != run_downscale {
                bail!(
                    "--resume: the run in {} uses --downscale {run_downscale}, not {d}; drop --downscale (or start a new --out)",
                    run.display()
                );
            }
        }
        let run_source: data::SourceOptions =
            serde_json::from_value(v["source"].clone()).unwrap_or_default();
        if a.source != data::SourceOptions::default() && a.source != run_source {
            bail!(
                "--resume: the run in {} reads its data with {:?}, not {:?}; drop --format/--images/--holdout (or start a new --out)",
                run.display(),
                run_source,
                a.source
            );
        }
        let run_preset = v["preset"].as_str().unwrap_or("synthetic").to_string();
        if let Some(p) = &a.preset {
            let format = run_source
                .format
                .unwrap_or_else(|| data::detect_format(&a.data));
            let p = TrainConfig::resolve_preset(p, format_preset(format));
            if p != run_preset {
                bail!(
                    "--resume: the run in {} was started with --preset {run_preset}, not {p}; drop --preset (or start a new --out)",
                    run.display()
                );
            }
        }
        if !has_checkpoint(run) {
            bail!(
                "cannot resume: {} never saved a checkpoint (the run stopped before its \
                 first); nothing is lost — run the same command without --resume to start it \
                 again",
                run.display()
            );
        }
        let (model_bytes, iter, state) = load_pair(run)?;
        let model_path = run.join("model.safetensors");
        let scene = checkpoint::from_bytes(&model_bytes)
            .with_context(|| format!("cannot load {}", model_path.display()))?;
        if iter >= cfg.iters {
            bail!(
                "the run in {} already completed its {} iterations; to train it further, \
                 pass --resume --iters N with N > {} (the extra iterations go on at the \
                 schedule's final state)",
                run.display(),
                cfg.iters,
                cfg.iters
            );
        }
        truncate_stats(run, iter)?;
        (
            cfg,
            Some(scene),
            Some(state),
            iter,
            run_preset,
            run_downscale,
            run_source,
        )
    } else {
        if has_checkpoint(run) {
            bail!(
                "{} already holds a run: pass --resume to continue it, or choose another --out",
                run.display()
            );
        }
        if cfg_path.exists() {
            eprintln!(
                "{} holds a run that never saved a checkpoint (only its config.json and \
                 log): starting over",
                run.display()
            );
        }
        let downscale = a.downscale.unwrap_or(1.0);
        if !(downscale.is_finite() && downscale >= 1.0) {
            bail!("--downscale must be a number >= 1, got {downscale}");
        }
        (
            resolve_config(a)?,
            None,
            None,
            0,
            run_preset(a)?,
            downscale,
            a.source.clone(),
        )
    };
    eprintln!("loading the train split of {} …", a.data.display());
    let train = data::load(&a.data, "train", downscale, cfg.background, &source)?;
    let fingerprint = split_fingerprint(&train);
    if let Some((old, recorded)) = moved {
        match recorded {
            Some(fp) if fp == fingerprint => {
                eprintln!(
                    "the run's data moved: {} → {} holds the same {} training views; the run \
                     continues there",
                    old.display(),
                    a.data.display(),
                    train.frames.len()
                );
                let text = std::fs::read_to_string(&cfg_path)
                    .with_context(|| format!("cannot read {}", cfg_path.display()))?;
                let mut v: serde_json::Value = serde_json::from_str(&text)
                    .with_context(|| format!("{} is not valid JSON", cfg_path.display()))?;
                v["data"] = serde_json::json!(canonical(&a.data));
                atomic_write(&cfg_path, serde_json::to_string_pretty(&v)?.as_bytes())?;
            }
            Some(_) => bail!(
                "--resume: the run in {} trains on {}, not {}: its training views (names, \
                 cameras) differ from the run's; pass the run's DATA (or start a new --out)",
                run.display(),
                old.display(),
                a.data.display()
            ),
            None => bail!(
                "--resume: the run in {} trains on {}, not {}; pass that DATA (or start a new \
                 --out). This run predates the record that recognises a moved dataset: move it \
                 back, or link the old path to it",
                run.display(),
                old.display(),
                a.data.display()
            ),
        }
    }
    if _lock.is_none() {
        // A new run: everything is validated; now the directory, locked before anything
        // is written into it (and checked again under the lock).
        std::fs::create_dir_all(run)
            .with_context(|| format!("cannot create run directory {}", run.display()))?;
        _lock = Some(lock_run(run)?);
        if has_checkpoint(run) {
            bail!(
                "{} already holds a run: pass --resume to continue it, or choose another --out",
                run.display()
            );
        }
    }
    let mut train = train;
    if init.is_none() {
        let region = svraster::train::bounds::resolve_run(&mut cfg, &mut train)?;
        if cfg.background_from_photos {
            eprintln!(
                "background colour: the training photos' mean [{:.3}, {:.3}, {:.3}]",
                cfg.background[0], cfg.background[1], cfg.background[2]
            );
        }
        if let Some(r) = region {
            eprintln!(
                "main region ({} from the {} training cameras): centre [{:.4}, {:.4}, {:.4}], \
                 edge {:.4} (world units); trained in its frame (edge 2), with {} background \
                 shell levels (root edge {})",
                r.mode,
                train.frames.len(),
                r.center[0],
                r.center[1],
                r.center[2],
                2.0 * r.radius,
                cfg.outside_level,
                svraster::train::trainer::root_extent(&cfg)
            );
            if a.preset.is_none() && preset == "real" && cfg.bound == "auto" && r.forward {
                eprintln!(
                    "note: every training camera looks the same way (a forward-facing \
                     capture): --preset forward trains it with 2 background shell levels \
                     instead of 5, black behind them and no inside loss"
                );
            }
        }
    } else {
        train.to_model(&cfg.world());
    }
    if init.is_none() {
        eprintln!(
            "initialising: a level-{} grid ({} voxels), keeping those the {} training views \
             see …",
            cfg.grid_level,
            1u64 << (3 * cfg.grid_level),
            train.frames.len()
        );
    }
    let mut trainer = Trainer::new(ctx, cfg.clone(), &train, init)?;
    if let Some(state) = opt_state {
        trainer.set_optimizer_state(&state)?;
        trainer.skip_to(start_iter);
    }
    if !a.resume {
        let doc = serde_json::json!({
            "config": cfg,
            "schedule": trainer.schedule(),
            "preset": preset,
            "data": canonical(&a.data),
            "downscale": downscale,
            "source": source,
            "image_size": [train.width, train.height],
            "train_views": train.frames.len(),
            "train_fingerprint": fingerprint,
            "voxels": trainer.voxels(),
            "voxel_budget": trainer.budget(),
            "device": ctx.info().name,
            "float_atomics": trainer.float_atomics(),
            "reduction": trainer.reduction().name(),
        });
        atomic_write(&cfg_path, serde_json::to_string_pretty(&doc)?.as_bytes())?;
        let _ = std::fs::remove_file(run.join("stats.jsonl"));
        let _ = std::fs::remove_file(run.join("training.png"));
    } else if extended {
        // An extension: config.json records the new end and the schedule's length.
        let text = std::fs::read_to_string(&cfg_path)
            .with_context(|| format!("cannot read {}", cfg_path.display()))?;
        let mut v: serde_json::Value = serde_json::from_str(&text)
            .with_context(|| format!("{} is not valid JSON", cfg_path.display()))?;
        v["config"] = serde_json::to_value(&cfg)?;
        v["schedule"] = serde_json::to_value(trainer.schedule())?;
        atomic_write(&cfg_path, serde_json::to_string_pretty(&v)?.as_bytes())?;
        eprintln!(
            "extending the run to {} iterations: its milestones stay where its {}-iteration \
             schedule put them; the rest trains at the schedule's final state",
            cfg.iters,
            cfg.schedule_iters.unwrap_or(cfg.iters)
        );
    }
    let budget_source = trainer.budget_source().to_string();
    eprintln!(
        "training {} voxels (level-{} grid, voxels no camera sees removed; layout {}, \
         budget {} voxels: {budget_source}) on {} views of {}{}×{} for {} iterations \
         (density learning rate {}) → {}",
        trainer.voxels(),
        cfg.grid_level,
        format!("{:?}", cfg.layout).to_lowercase(),
        trainer.budget(),
        train.frames.len(),
        if train.uniform_size() { "" } else { "up to " },
        train.width,
        train.height,
        cfg.iters,
        trainer.schedule().lr_geo,
        run.display()
    );
    let long_run = ctx.info().is_cpu.then(|| LongRun {
        device: ctx.info().name.clone(),
        downscale,
        warned: false,
    });
    let held = match a.eval_every {
        Some(0) => bail!("--eval-every must be at least 1"),
        Some(every) => {
            let split = super::default_split(&a.data);
            let mut ds = data::load(&a.data, &split, downscale, cfg.background, &source)?;
            if ds.frames.is_empty() {
                bail!(
                    "--eval-every: split `{split}` of {} has no frames",
                    a.data.display()
                );
            }
            ds.to_model(&cfg.world());
            eprintln!(
                "evaluating the {} views of split `{split}` every {every} iterations",
                ds.frames.len()
            );
            Some(HeldOut {
                ctx: ctx.clone(),
                ds,
                every,
            })
        }
        None => None,
    };
    let summary = train_loop(&mut trainer, run, long_run, held.as_ref())?;
    Ok(summary)
}

/// The queue traffic since `last` (counters, iteration), per iteration, for stats.jsonl:
/// submissions, fence waits that drained the queue, throttle waits, milliseconds blocked.
fn queue_json(
    trainer: &Trainer,
    last: &mut (svraster::gpu::QueueCounters, u32),
    iter: u32,
) -> serde_json::Value {
    let now = trainer.queue_counters();
    let d = now - last.0;
    let n = f64::from(iter.saturating_sub(last.1).max(1));
    *last = (now, iter);
    serde_json::json!({
        "iters": n as u32,
        "submits_per_iter": d.submits as f64 / n,
        "fence_waits_per_iter": d.fence_waits as f64 / n,
        "throttle_waits_per_iter": d.throttle_waits as f64 / n,
        "wait_ms_per_iter": d.wait_ms / n,
        "throttle_ms_per_iter": d.throttle_ms / n,
    })
}

/// Redraws `RUN/training.png` from `RUN/stats.jsonl`. A chart that cannot be drawn is
/// reported and training goes on (the statistics themselves are intact).
fn curves(run: &Path) {
    let png = run.join("training.png");
    if let Err(e) = super::plot::training_chart(&run.join("stats.jsonl"), &png) {
        eprintln!("warning: cannot draw {}: {e:#}", png.display());
    }
}

/// `elapsed_s` of the last iteration line of a run's stats.jsonl (0 without one).
fn last_elapsed(stats: &Path) -> f64 {
    std::fs::read_to_string(stats)
        .unwrap_or_default()
        .lines()
        .rev()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .find_map(|v| v["elapsed_s"].as_f64())
        .unwrap_or(0.0)
}

/// Runs the remaining iterations with progress, stats.jsonl, checkpoints and Ctrl-C.
/// The one-time warning of a run that will take long on a CPU device.
struct LongRun {
    device: String,
    downscale: f64,
    warned: bool,
}

/// The held-out views `--eval-every` scores during training.
struct HeldOut {
    ctx: Context,
    ds: data::Dataset,
    every: u32,
}

impl HeldOut {
    /// Scores the current model; the stats line and the progress line.
    fn score(
        &self,
        trainer: &mut Trainer,
        iter: u32,
    ) -> anyhow::Result<(serde_json::Value, String)> {
        let t = Instant::now();
        let scene = trainer.scene()?;
        let rep = svraster::eval::evaluate(
            &self.ctx,
            &scene,
            &self.ds,
            &RenderOptions::for_scene(&scene),
            |_, _, _, _, _| {},
        )?;
        let secs = t.elapsed().as_secs_f64();
        let line = serde_json::json!({ "eval": {
            "iter": iter, "split": self.ds.split, "views": rep.views,
            "psnr": rep.psnr, "ssim": rep.ssim, "seconds": secs,
        }});
        let msg = format!(
            "eval @{iter}: {} views of `{}`: PSNR {:.2} dB, SSIM {:.4} ({secs:.1} s)",
            rep.views, self.ds.split, rep.psnr, rep.ssim
        );
        Ok((line, msg))
    }
}

/// Minutes beyond which a run on a CPU device is said to be long.
const LONG_RUN_MIN: f64 = 30.0;

impl LongRun {
    /// Once the rate is known (≥ 10 s or ≥ 50 iterations in), says how long the run will
    /// take when that exceeds [`LONG_RUN_MIN`], and what shortens it.
    fn check(&mut self, done: u32, left: u32, seconds: f64, rate: f64, p: &Progress) {
        if self.warned || !(seconds >= 10.0 || done >= 50) || rate.is_nan() || rate <= 0.0 {
            return;
        }
        self.warned = true;
        let eta = f64::from(left) / rate;
        if eta < LONG_RUN_MIN * 60.0 {
            return;
        }
        p.line(&format!(
            "note: at {rate:.1} it/s this run takes about {} more on {} (a CPU device). \
             To shorten it: --downscale {} (a quarter of the pixels), fewer --iters (every \
             milestone scales), or --preset quick; Ctrl-C saves and `--resume` continues",
            fmt_duration(eta),
            self.device,
            self.downscale * 2.0
        ));
    }
}

fn train_loop(
    trainer: &mut Trainer,
    run: &Path,
    mut long_run: Option<LongRun>,
    held: Option<&HeldOut>,
) -> anyhow::Result<RunSummary> {
    catch_signals()?;
    INTERRUPTS.store(0, Ordering::SeqCst);
    let cfg = trainer.config().clone();
    let sched = trainer.schedule().clone();
    let stats_path = run.join("stats.jsonl");
    let mut stats = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&stats_path)
        .with_context(|| format!("cannot open {}", stats_path.display()))?;
    let t0 = Instant::now();
    let first = trainer.iter();
    // A resumed run's elapsed time continues from its log's last line (the log was
    // truncated to the checkpoint).
    let elapsed_before = last_elapsed(&stats_path);
    let mut last_measure = t0;
    let mut shown = None;
    let mut window = RateWindow::new(30.0);
    window.push(first, 0.0);
    let mut progress = Progress::new("train", u64::from(cfg.iters));
    progress.update(u64::from(first), || "starting".into());
    // Queue traffic between logged steps (all of it: iterations, their logging, the
    // adaptive steps and checkpoints in between).
    let mut queue_last = (trainer.queue_counters(), first);
    while trainer.iter() < cfg.iters {
        if INTERRUPTS.load(Ordering::SeqCst) > 0 {
            progress.finish();
            save_run(run, trainer)?;
            curves(run);
            eprintln!(
                "interrupted: saved iteration {} to {}; continue with --resume",
                trainer.iter(),
                run.display()
            );
            return Ok(RunSummary {
                iters: trainer.iter(),
                seconds: t0.elapsed().as_secs_f64(),
                interrupted: true,
                voxels: trainer.voxels(),
            });
        }
        let it = trainer.iter() + 1;
        let logged = it.is_multiple_of(cfg.log_every) || it == cfg.iters || it == first + 1;
        // The progress shows current values: measured for each plain line, and about
        // once a second under a bar (a measurement waits for the queue to drain).
        let fresh = if progress.is_bar() {
            last_measure.elapsed().as_secs_f64() >= 1.0
        } else {
            progress.line_due(u64::from(it))
        };
        let info = trainer.step(logged || fresh)?;
        if let Some(l) = info.losses {
            trainer.check_finite()?;
            last_measure = Instant::now();
            shown = Some(l);
        }
        if let Some(l) = info.losses.filter(|_| logged) {
            let el = elapsed_before + t0.elapsed().as_secs_f64();
            let line = serde_json::json!({
                "iter": info.iter,
                "loss": l.loss, "mse": l.mse, "psnr": l.psnr, "ssim": l.ssim,
                "t_concentration": l.t_concentration, "t_inside": l.t_inside, "distortion": l.distortion, "tv": l.tv,
                "normal_dmed": l.normal_dmed, "normal_dmean": l.normal_dmean,
                "sh_degree": info.sh_degree, "ss": info.supersample, "entries": info.entries,
                "voxels": trainer.voxels(), "grid_points": trainer.grid_points(),
                "device_memory": trainer.device_memory(), "elapsed_s": el,
                "it_per_s": (info.iter - first) as f64 / t0.elapsed().as_secs_f64().max(1e-9),
                "queue": queue_json(trainer, &mut queue_last, info.iter),
            });
            writeln!(stats, "{line}")
                .with_context(|| format!("cannot write {}", stats_path.display()))?;
        }
        if let Some(r) = &info.adapt {
            let line = serde_json::json!({ "adapt": r });
            writeln!(stats, "{line}")
                .with_context(|| format!("cannot write {}", stats_path.display()))?;
            let msg = format!(
                "adapt @{}: pruned {} (max weight < {}), subdivided {} → {} voxels, {} grid \
                 points, max level {}, {:.0} MiB device memory, {:.1} s",
                r.iter,
                r.pruned,
                r.prune_below.map_or("-".into(), |t| format!("{t:.4}")),
                r.subdivided,
                r.voxels,
                r.grid_points,
                r.max_level,
                r.device_memory as f64 / (1u64 << 20) as f64,
                r.seconds
            );
            progress.line(&msg);
        }
        if let Some(h) =
            held.filter(|h| info.iter.is_multiple_of(h.every) || info.iter == cfg.iters)
        {
            let (line, msg) = h.score(trainer, info.iter)?;
            writeln!(stats, "{line}")
                .with_context(|| format!("cannot write {}", stats_path.display()))?;
            progress.line(&msg);
        }
        if sched.checkpoints.contains(&info.iter) {
            trainer.check_finite()?;
            save_run(run, trainer)?;
            curves(run);
        }
        let done = info.iter == cfg.iters;
        window.push(info.iter, t0.elapsed().as_secs_f64());
        if let Some(l) = long_run.as_mut() {
            l.check(
                info.iter - first,
                cfg.iters - info.iter,
                t0.elapsed().as_secs_f64(),
                window.rate(),
                &progress,
            );
        }
        progress.update(u64::from(info.iter), || {
            let rate = window.rate();
            let eta = (cfg.iters - info.iter) as f64 / rate;
            let (loss, p) = shown.map_or((f64::NAN, f64::NAN), |l| (l.loss, l.psnr));
            format!(
                "{rate:.2} it/s  loss {loss:.4}  PSNR {p:.2}  voxels {}  SH {}  ETA {}",
                trainer.voxels(),
                info.sh_degree,
                fmt_duration(if done { 0.0 } else { eta })
            )
        });
    }
    progress.finish();
    trainer.check_finite()?;
    save_run(run, trainer)?;
    curves(run);
    let secs = t0.elapsed().as_secs_f64();
    let layout = if cfg.outside_level > 0 {
        let main = trainer.scene()?.voxels_inside(cfg.center, cfg.extent);
        format!(
            "{} voxels: {main} in the main region, {} in the background shells",
            trainer.voxels(),
            trainer.voxels() as usize - main
        )
    } else {
        format!("{} voxels", trainer.voxels())
    };
    eprintln!(
        "trained {} iterations in {} ({layout}) → {}",
        cfg.iters - first,
        fmt_duration(secs),
        run.join("model.safetensors").display()
    );
    Ok(RunSummary {
        iters: trainer.iter(),
        seconds: secs,
        interrupted: false,
        voxels: trainer.voxels(),
    })
}

/// Which views of which dataset, read how.
pub struct Views<'a> {
    pub data: &'a Path,
    pub split: &'a str,
    pub downscale: f64,
    pub source: &'a data::SourceOptions,
}

/// Evaluates `scene` on a split of a dataset ([`svraster::eval::evaluate`]), with a
/// progress line on stderr unless `quiet`.
pub fn evaluate(
    ctx: &Context,
    scene: &Scene,
    views: &Views,
    opts: &RenderOptions,
    quiet: bool,
) -> anyhow::Result<EvalReport> {
    let Views {
        data,
        split,
        downscale,
        source,
    } = *views;
    let mut ds = data::load(data, split, downscale, scene.background, source)?;
    ds.to_model(&scene.world);
    if ds.frames.is_empty() {
        bail!("split `{split}` of {} has no frames", data.display());
    }
    let mut progress = if quiet {
        Progress::hidden()
    } else {
        Progress::new(&format!("eval {split}"), ds.frames.len() as u64)
    };
    let rep = svraster::eval::evaluate(ctx, scene, &ds, opts, |i, _, name, p, s| {
        progress.update(i as u64, || format!("{name}: PSNR {p:.2} SSIM {s:.4}"));
    })?;
    progress.finish();
    Ok(rep)
}

/// `svraster eval`.
pub fn run_eval(
    ctx: &Context,
    model: &Path,
    views: &Views,
    ss: Option<f32>,
    json: bool,
) -> anyhow::Result<()> {
    let split = views.split;
    let scene = load_model(model)?;
    let opts = RenderOptions {
        supersample: ss.unwrap_or(scene.supersample),
        ..RenderOptions::for_scene(&scene)
    };
    let rep = evaluate(ctx, &scene, views, &opts, json)?;
    if json {
        println!("{}", serde_json::to_string(&rep)?);
    } else {
        println!(
            "{} views of `{split}` at {}{}×{} (supersampling {}): PSNR {:.2} dB, SSIM {:.4}, {:.1} ms per frame (median, frames queued, read-back included, scoring excluded)",
            rep.views,
            if rep.sizes_differ { "up to " } else { "" },
            rep.width,
            rep.height,
            opts.supersample,
            rep.psnr,
            rep.ssim,
            rep.ms_per_frame
        );
    }
    Ok(())
}

pub struct DemoArgs {
    pub out: PathBuf,
    pub size: u32,
    pub iters: u32,
    pub level: u32,
    pub seed: u64,
    pub voxelize: bool,
    /// Also write per-primitive label images (OUT/labels/SPLIT/r_i.png).
    pub labels: bool,
}

/// Runs `write(tmp)` into `dir` + `.partial` (made afresh), then replaces `dir` with it;
/// on failure removes the partial folder and says nothing was kept.
fn staged(dir: &Path, write: impl FnOnce(&Path) -> anyhow::Result<()>) -> anyhow::Result<()> {
    let mut name = dir.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    let tmp = dir.with_file_name(name);
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp)
            .with_context(|| format!("cannot clear {} of an earlier demo", tmp.display()))?;
    }
    std::fs::create_dir_all(&tmp).with_context(|| format!("cannot create {}", tmp.display()))?;
    if let Err(e) = write(&tmp) {
        let _ = std::fs::remove_dir_all(&tmp);
        bail!("{e:#}; nothing of {} was kept", dir.display());
    }
    if dir.exists() {
        std::fs::remove_dir_all(dir)
            .with_context(|| format!("cannot replace {} of an earlier demo", dir.display()))?;
    }
    std::fs::rename(&tmp, dir)
        .with_context(|| format!("cannot move {} to {}", tmp.display(), dir.display()))
}

/// Refuses a demo this machine cannot hold, before anything is written: the training
/// views stay in memory as f32 RGB, 12 bytes per pixel on the host and as many on the
/// device (host memory too on a CPU device), and the dataset's PNGs take up to 4 bytes
/// per pixel on disk.
fn check_demo_resources(
    ctx: &Context,
    opts: &svraster::data::demo::DemoOptions,
    out: &Path,
) -> anyhow::Result<()> {
    let px = u64::from(opts.width) * u64::from(opts.height);
    let views = (opts.train + opts.val + opts.test) as u64;
    let train = opts.train as u64 * px * 12;
    let cpu = ctx.info().is_cpu;
    // The frame, loss and backward buffers at the image's size: ~64 floats per pixel.
    let frame = px * 256;
    let host = if cpu { 2 * train + frame } else { train };
    let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
    let smaller = |need: u64, have: u64| {
        // The edge at which the need fits (it scales with the pixel count).
        let f = (have as f64 / need as f64).sqrt();
        ((opts.width.max(opts.height) as f64 * f) as u32 / 16 * 16).max(16)
    };
    // A fifth of what is available left for everything else (measured: --size 4096 on
    // 23 GiB available, estimated at 22.5 GiB without the frame buffers, was killed).
    if let Some(avail) = mem_available().map(|a| a / 5 * 4) {
        if host > avail {
            bail!(
                "demo --size {}: its {} training views at {}×{} need about {:.1} GiB of \
                 memory{}, more than the {:.1} GiB this machine can spare (four fifths of what \
                 is available): use --size {} or less",
                opts.width,
                opts.train,
                opts.width,
                opts.height,
                gib(host),
                if cpu {
                    " (photos on the host and on the CPU device)"
                } else {
                    ""
                },
                gib(avail),
                smaller(host, avail)
            );
        }
    }
    if let Some(avail) = ctx.memory_budget().map(|b| b.available_bytes() / 5 * 4) {
        if !cpu && train + frame > avail {
            bail!(
                "demo --size {}: its training views need about {:.1} GiB of device memory, \
                 more than the {:.1} GiB the device can spare: use --size {} or less",
                opts.width,
                gib(train + frame),
                gib(avail),
                smaller(train + frame, avail)
            );
        }
    }
    let disk = views * px * 4;
    if let Some(free) = disk_free(out) {
        if disk > free {
            bail!(
                "demo --size {}: its {views} images may take up to {:.1} GiB, {} has {:.1} GiB \
                 free: use a smaller --size or free space",
                opts.width,
                gib(disk),
                out.display(),
                gib(free)
            );
        }
    }
    Ok(())
}

/// MemAvailable of /proc/meminfo (None where there is none).
fn mem_available() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Bytes free to this user on the file system that holds `path` (or its nearest
/// existing ancestor).
fn disk_free(path: &Path) -> Option<u64> {
    let mut p = super::render::resolved(path);
    while !p.exists() {
        p = p.parent()?.to_path_buf();
    }
    let s = rustix::fs::statvfs(&p).ok()?;
    Some(s.f_bavail.saturating_mul(s.f_frsize))
}

/// `svraster demo`: generate the procedural dataset, train on it, evaluate and render
/// the test views.
pub fn run_demo(ctx: &Context, a: DemoArgs) -> anyhow::Result<()> {
    use svraster::data::demo;
    let data_dir = a.out.join("data");
    let opts = demo::DemoOptions {
        width: a.size,
        height: a.size,
        seed: a.seed,
        ..Default::default()
    };
    // Every argument is checked before anything is written.
    demo::demo_splits(&opts)?;
    let train_args = TrainArgs {
        data: data_dir.clone(),
        out: a.out.join("run"),
        iters: Some(a.iters),
        downscale: Some(1.0),
        preset: Some("quick".into()),
        seed: Some(a.seed),
        set: vec![format!("grid_level={}", a.level)],
        resume: false,
        source: Default::default(),
        eval_every: None,
        config: None,
    };
    if !a.voxelize {
        resolve_config(&train_args)?;
    } else if !(1..=svraster::scene::MAX_LEVEL).contains(&a.level) {
        bail!(
            "--level must be in 1..={} for --voxelize",
            svraster::scene::MAX_LEVEL
        );
    }
    check_demo_resources(ctx, &opts, &a.out)?;
    // The demo replaces what it made before, in a directory it made (marked), and never
    // touches one it did not.
    let marker = a.out.join(".svraster-demo");
    let non_empty = a
        .out
        .read_dir()
        .map(|mut d| d.next().is_some())
        .unwrap_or(false);
    // A demo directory from before the mark: its run trained on its own data.
    let legacy_demo = || {
        std::fs::read_to_string(a.out.join("run/config.json"))
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .and_then(|v| v["data"].as_str().map(PathBuf::from))
            .is_some_and(|d| canonical(&d) == canonical(&data_dir))
    };
    if non_empty && !marker.is_file() && !legacy_demo() {
        bail!(
            "{} exists and was not made by `svraster demo`: choose another --out (the demo \
             only replaces files in a directory it created)",
            a.out.display()
        );
    }
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let _lock = lock_run(&a.out)?;
    std::fs::write(&marker, b"made by svraster demo\n")
        .with_context(|| format!("cannot write {}", marker.display()))?;
    let t = Instant::now();
    eprintln!(
        "generating the demo dataset ({}×{}, {} train / {} val / {} test views) in {} …",
        opts.width,
        opts.height,
        opts.train,
        opts.val,
        opts.test,
        data_dir.display()
    );
    // Written beside and renamed into place when complete: a failure (a full disk, a
    // kill) never leaves a half-written dataset where a run would read it.
    staged(&data_dir, |dir| Ok(demo::write_dataset(dir, &opts)?))?;
    if a.labels {
        staged(&a.out.join("labels"), |dir| {
            demo::write_labels(dir, &opts)?;
            // write_labels makes DIR/labels/SPLIT: move them up into the staged folder.
            for split in ["train", "val", "test"] {
                std::fs::rename(dir.join("labels").join(split), dir.join(split))?;
            }
            std::fs::remove_dir(dir.join("labels"))?;
            Ok(())
        })?;
    }
    eprintln!("  done in {:.1} s", t.elapsed().as_secs_f64());
    let run = a.out.join("run");
    if run.exists() {
        std::fs::remove_dir_all(&run)
            .with_context(|| format!("cannot clear the previous demo run {}", run.display()))?;
    }
    let summary = if a.voxelize {
        let t = Instant::now();
        let scene = demo::voxelize(a.level, 0)?;
        std::fs::create_dir_all(&run)
            .with_context(|| format!("cannot create {}", run.display()))?;
        checkpoint::save(&scene, &run.join("model.safetensors"))?;
        RunSummary {
            iters: 0,
            seconds: t.elapsed().as_secs_f64(),
            interrupted: false,
            voxels: scene.num_voxels() as u32,
        }
    } else {
        run_train(ctx, &train_args)?
    };
    if summary.interrupted {
        std::process::exit(130);
    }
    let scene = checkpoint::load(&run.join("model.safetensors"))?;
    let rep = evaluate(
        ctx,
        &scene,
        &Views {
            data: &data_dir,
            split: "test",
            downscale: 1.0,
            source: &data::SourceOptions::default(),
        },
        &RenderOptions::for_scene(&scene),
        false,
    )?;
    let renders = a.out.join("renders");
    super::render::render_split(
        ctx,
        &super::render::RenderArgs {
            model: run.clone(),
            data: data_dir,
            split: "test".into(),
            downscale: 1.0,
            source: data::SourceOptions::default(),
            out: renders.clone(),
            depth: true,
            normal: true,
            compare: true,
            samples: 1,
            ss: None,
            field: None,
            truth: None,
            mask: false,
            by_order: false,
            json: false,
            path: None,
            frames: 0,
            size: None,
            fov: None,
        },
    )?;
    let how = if a.voxelize {
        format!("voxelized the primitives down to level {}", a.level)
    } else {
        format!("trained for {} iterations", summary.iters)
    };
    println!(
        "demo: {} voxels, {how} in {}; test views: PSNR {:.2} dB, SSIM {:.4} \
         ({} views); renders (rgb, depth, normal PNGs) in {}",
        scene.num_voxels(),
        fmt_duration(summary.seconds),
        rep.psnr,
        rep.ssim,
        rep.views,
        renders.display()
    );
    Ok(())
}
