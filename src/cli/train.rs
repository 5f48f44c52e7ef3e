//! `svraster train`, `svraster eval` and the training part of `svraster demo`.

use std::io::{IsTerminal, Write as _};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Instant;

use anyhow::{bail, Context as _};
use svraster::data;
use svraster::eval::EvalReport;
use svraster::gpu::Context;
use svraster::raster::RenderOptions;
use svraster::scene::{checkpoint, Scene};
use svraster::train::config::TrainConfig;
use svraster::train::trainer::Trainer;

use super::render::load_model;

/// Stop requests (Ctrl-C, SIGTERM, SIGHUP) since the training loop started.
static INTERRUPTS: AtomicU32 = AtomicU32::new(0);

/// Routes Ctrl-C and SIGTERM/SIGHUP (what `timeout`, `kill`, Slurm, systemd and
/// `docker stop` send) to a counter the training loop polls: the first request is
/// acknowledged at once and the run saves and stops after the current step (an adaptive
/// step included); a second one exits at once without saving (status 130).
fn catch_signals() -> anyhow::Result<()> {
    static INSTALLED: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    INSTALLED
        .get_or_init(|| {
            ctrlc::set_handler(|| {
                if INTERRUPTS.fetch_add(1, Ordering::SeqCst) == 0 {
                    eprintln!(
                        "\nstopping after this step and saving … (again to exit without saving)"
                    );
                } else {
                    eprintln!("\nexiting without saving");
                    std::process::exit(130);
                }
            })
            .map_err(|e| e.to_string())
        })
        .clone()
        .map_err(|e| anyhow::anyhow!("cannot install the Ctrl-C/SIGTERM handler: {e}"))
}

/// Locks `run` (an existing directory) for this process: an advisory lock on
/// `run/.lock`, released when the returned file is dropped or the process dies. A second
/// `train`/`demo` into the same directory fails at once instead of mixing two runs.
pub fn lock_run(run: &Path) -> anyhow::Result<std::fs::File> {
    let path = run.join(".lock");
    let f = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .with_context(|| format!("cannot open the run lock {}", path.display()))?;
    match f.try_lock() {
        Ok(()) => Ok(f),
        Err(std::fs::TryLockError::WouldBlock) => bail!(
            "{} is in use: another svraster process is training in it; wait for it to \
             finish (or stop it), or choose another --out",
            run.display()
        ),
        Err(std::fs::TryLockError::Error(e)) => {
            bail!("cannot lock {}: {e}", path.display())
        }
    }
}

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
}

use svraster::fsio::{sync_dir, tmp_path, write_synced};

/// Writes `bytes` to `path` atomically ([`svraster::fsio::write_atomic`]).
fn atomic_write(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    Ok(svraster::fsio::write_atomic(path, bytes)?)
}

fn fnv64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

const OPT_MAGIC: &[u8; 8] = b"SVRVKOPT";

/// Writes the checkpoint pair model.safetensors + optimizer.bin (iteration, hash of the
/// model file, Adam moments) so that a failure at any point leaves a resumable pair: both
/// are written and flushed as `.tmp` files first (a full disk fails here, and the
/// previous pair stays as it was), then renamed, optimizer first. A crash between the two
/// renames leaves the new optimizer state beside `model.safetensors.tmp`, which
/// `--resume` recognises by its hash and completes.
fn save_run(run: &Path, trainer: &mut Trainer) -> anyhow::Result<()> {
    let scene = trainer.scene()?;
    let model = checkpoint::to_bytes(&scene)?;
    let state = trainer.optimizer_state()?;
    let mut opt = Vec::new();
    opt.extend_from_slice(OPT_MAGIC);
    opt.extend_from_slice(&(trainer.iter() as u64).to_le_bytes());
    opt.extend_from_slice(&fnv64(&model).to_le_bytes());
    opt.extend_from_slice(&(state.len() as u64).to_le_bytes());
    for s in &state {
        opt.extend_from_slice(&(s.len() as u64).to_le_bytes());
        opt.extend_from_slice(bytemuck::cast_slice(s));
    }
    let model_path = run.join("model.safetensors");
    let opt_path = run.join("optimizer.bin");
    let (model_tmp, opt_tmp) = (tmp_path(&model_path), tmp_path(&opt_path));
    let written = write_synced(&model_tmp, &model).and_then(|()| write_synced(&opt_tmp, &opt));
    if let Err(e) = written {
        let _ = std::fs::remove_file(&model_tmp);
        let _ = std::fs::remove_file(&opt_tmp);
        bail!(
            "cannot write the checkpoint ({e}); the previous checkpoint in {} is \
             unchanged and resumable (free space, then --resume)",
            run.display()
        );
    }
    std::fs::rename(&opt_tmp, &opt_path)
        .and_then(|()| std::fs::rename(&model_tmp, &model_path))
        .with_context(|| format!("cannot install the checkpoint in {}", run.display()))?;
    sync_dir(run);
    Ok(())
}

/// Reads the checkpoint pair for `--resume`: (model bytes, iteration, moments),
/// completing a save that stopped between its two renames (see [`save_run`]).
fn load_pair(run: &Path) -> anyhow::Result<(Vec<u8>, u32, Vec<Vec<f32>>)> {
    let model_path = run.join("model.safetensors");
    let (iter, hash, state) = load_optimizer(&run.join("optimizer.bin"))?;
    let model = std::fs::read(&model_path)
        .with_context(|| format!("cannot resume: cannot read {}", model_path.display()))?;
    if fnv64(&model) == hash {
        return Ok((model, iter, state));
    }
    let tmp = tmp_path(&model_path);
    if let Ok(pending) = std::fs::read(&tmp) {
        if fnv64(&pending) == hash {
            std::fs::rename(&tmp, &model_path)
                .with_context(|| format!("cannot complete the checkpoint {}", tmp.display()))?;
            eprintln!("completed the checkpoint of iteration {iter} that a stop interrupted");
            return Ok((pending, iter, state));
        }
    }
    bail!(
        "{} and optimizer.bin are from different iterations; cannot resume safely",
        model_path.display()
    )
}

/// Drops the lines of `run/stats.jsonl` past iteration `iter` (a run that crashed after
/// its last checkpoint logged iterations the resumed run will log again).
fn truncate_stats(run: &Path, iter: u32) -> anyhow::Result<()> {
    let path = run.join("stats.jsonl");
    let Ok(text) = std::fs::read_to_string(&path) else {
        return Ok(());
    };
    let keep: Vec<&str> = text
        .lines()
        .filter(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap_or_default();
            let at = v["iter"].as_u64().or_else(|| v["adapt"]["iter"].as_u64());
            at.is_some_and(|i| i <= u64::from(iter))
        })
        .collect();
    if keep.len() != text.lines().count() {
        let mut out = keep.join("\n");
        if !out.is_empty() {
            out.push('\n');
        }
        atomic_write(&path, out.as_bytes())?;
    }
    Ok(())
}

/// Reads optimizer.bin: (iteration, model hash, moments).
fn load_optimizer(path: &Path) -> anyhow::Result<(u32, u64, Vec<Vec<f32>>)> {
    let b = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let corrupt = || anyhow::anyhow!("{} is corrupt or truncated", path.display());
    let u64_at = |o: usize| -> anyhow::Result<u64> {
        Ok(u64::from_le_bytes(
            b.get(o..o + 8)
                .ok_or_else(corrupt)?
                .try_into()
                .expect("8 bytes"),
        ))
    };
    if b.get(..8) != Some(OPT_MAGIC.as_slice()) {
        bail!("{} is not an svraster optimizer state", path.display());
    }
    let iter = u64_at(8)?;
    let hash = u64_at(16)?;
    let n = u64_at(24)?;
    if n != 6 || iter > u32::MAX as u64 {
        return Err(corrupt());
    }
    let mut o = 32;
    let mut out = Vec::new();
    for _ in 0..n {
        let len = u64_at(o)? as usize;
        o += 8;
        let bytes = b
            .get(o..o + len.checked_mul(4).ok_or_else(corrupt)?)
            .ok_or_else(corrupt)?;
        out.push(
            bytes
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
                .collect(),
        );
        o += len * 4;
    }
    if o != b.len() {
        return Err(corrupt());
    }
    Ok((iter as u32, hash, out))
}

/// Iteration rate over a moving window (the last ~30 s, at least 2 samples), so the ETA
/// follows the run's current speed (the first iterations carry warm-up and a larger
/// model, adaptive steps come and go) instead of its mean since the start.
struct RateWindow {
    samples: std::collections::VecDeque<(u32, f64)>,
    window_s: f64,
}

impl RateWindow {
    fn new(window_s: f64) -> Self {
        RateWindow {
            samples: std::collections::VecDeque::new(),
            window_s,
        }
    }

    /// Records that iteration `iter` finished at time `t` (seconds).
    fn push(&mut self, iter: u32, t: f64) {
        self.samples.push_back((iter, t));
        while self.samples.len() > 2 && t - self.samples[1].1 >= self.window_s {
            self.samples.pop_front();
        }
    }

    /// Iterations per second over the window (NaN before two samples).
    fn rate(&self) -> f64 {
        match (self.samples.front(), self.samples.back()) {
            (Some(a), Some(b)) if b.1 > a.1 => f64::from(b.0 - a.0) / (b.1 - a.1),
            _ => f64::NAN,
        }
    }
}

fn fmt_duration(s: f64) -> String {
    if !s.is_finite() {
        return "?".into();
    }
    let s = s.round() as u64;
    if s >= 3600 {
        format!("{}h{:02}m", s / 3600, (s % 3600) / 60)
    } else if s >= 60 {
        format!("{}m{:02}s", s / 60, s % 60)
    } else {
        format!("{s}s")
    }
}

/// Resolves the configuration of a new run.
pub fn resolve_config(a: &TrainArgs) -> anyhow::Result<TrainConfig> {
    let mut cfg = TrainConfig::preset(a.preset.as_deref().unwrap_or("synthetic"))?;
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
    let (cfg, init, opt_state, start_iter, preset, downscale) = if a.resume {
        if a.iters.is_some() || a.seed.is_some() || !a.set.is_empty() {
            bail!("--resume continues a run with its own config.json: drop --iters/--seed/--set (or start a new --out)");
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
        let cfg: TrainConfig = serde_json::from_value(v["config"].clone())
            .with_context(|| format!("{}: bad \"config\"", cfg_path.display()))?;
        cfg.validate()?;
        // The same run: the data, downscale and preset that shaped it.
        let run_data = v["data"].as_str().map(PathBuf::from);
        if let Some(d) = &run_data {
            if canonical(d) != canonical(&a.data) {
                bail!(
                    "--resume: the run in {} trains on {}, not {}; pass that DATA (or start a new --out)",
                    run.display(),
                    d.display(),
                    a.data.display()
                );
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
        let run_preset = v["preset"].as_str().unwrap_or("synthetic").to_string();
        if let Some(p) = &a.preset {
            if *p != run_preset {
                bail!(
                    "--resume: the run in {} was started with --preset {run_preset}, not {p}; drop --preset (or start a new --out)",
                    run.display()
                );
            }
        }
        let (model_bytes, iter, state) = load_pair(run)?;
        let model_path = run.join("model.safetensors");
        let scene = checkpoint::from_bytes(&model_bytes)
            .with_context(|| format!("cannot load {}", model_path.display()))?;
        if iter >= cfg.iters {
            bail!(
                "the run in {} already completed its {} iterations",
                run.display(),
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
        )
    } else {
        if run.join("model.safetensors").exists() || cfg_path.exists() {
            bail!(
                "{} already holds a run: pass --resume to continue it, or choose another --out",
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
            a.preset.clone().unwrap_or_else(|| "synthetic".into()),
            downscale,
        )
    };
    eprintln!("loading the train split of {} …", a.data.display());
    let train = data::load_split(&a.data, "train", downscale, cfg.background)?;
    if _lock.is_none() {
        // A new run: everything is validated; now the directory, locked before anything
        // is written into it (and checked again under the lock).
        std::fs::create_dir_all(run)
            .with_context(|| format!("cannot create run directory {}", run.display()))?;
        _lock = Some(lock_run(run)?);
        if run.join("model.safetensors").exists() || cfg_path.exists() {
            bail!(
                "{} already holds a run: pass --resume to continue it, or choose another --out",
                run.display()
            );
        }
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
            "image_size": [train.width, train.height],
            "train_views": train.frames.len(),
            "voxels": trainer.voxels(),
            "voxel_budget": trainer.budget(),
            "device": ctx.info().name,
            "float_atomics": trainer.float_atomics(),
        });
        atomic_write(&cfg_path, serde_json::to_string_pretty(&doc)?.as_bytes())?;
        let _ = std::fs::remove_file(run.join("stats.jsonl"));
    }
    if ctx.info().is_cpu && !a.resume && preset == "synthetic" && cfg.iters > 5_000 {
        eprintln!(
            "note: {} is a CPU device: {} iterations take hours here (0.2–1 s each at \
             100²–200²); a few thousand (--iters 3000) reach most of the quality",
            ctx.info().name,
            cfg.iters
        );
    }
    eprintln!(
        "training {} voxels (level-{} grid, voxels no camera sees removed; layout {}, \
         budget {} voxels) on {} views of {}×{} for {} iterations (density learning rate \
         {}) → {}",
        trainer.voxels(),
        cfg.grid_level,
        format!("{:?}", cfg.layout).to_lowercase(),
        trainer.budget(),
        train.frames.len(),
        train.width,
        train.height,
        cfg.iters,
        trainer.schedule().lr_geo,
        run.display()
    );
    let summary = train_loop(&mut trainer, run)?;
    Ok(summary)
}

/// Runs the remaining iterations with progress, stats.jsonl, checkpoints and Ctrl-C.
fn train_loop(trainer: &mut Trainer, run: &Path) -> anyhow::Result<RunSummary> {
    catch_signals()?;
    INTERRUPTS.store(0, Ordering::SeqCst);
    let cfg = trainer.config().clone();
    let sched = trainer.schedule().clone();
    let tty = std::io::stderr().is_terminal();
    let stats_path = run.join("stats.jsonl");
    let mut stats = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&stats_path)
        .with_context(|| format!("cannot open {}", stats_path.display()))?;
    let t0 = Instant::now();
    let first = trainer.iter();
    let mut last_print = Instant::now();
    let mut shown = None;
    let mut window = RateWindow::new(30.0);
    window.push(first, 0.0);
    while trainer.iter() < cfg.iters {
        if INTERRUPTS.load(Ordering::SeqCst) > 0 {
            eprintln!();
            save_run(run, trainer)?;
            eprintln!(
                "interrupted: saved iteration {} to {}; continue with --resume",
                trainer.iter(),
                run.display()
            );
            return Ok(RunSummary {
                iters: trainer.iter(),
                seconds: t0.elapsed().as_secs_f64(),
                interrupted: true,
            });
        }
        let it = trainer.iter() + 1;
        let measure = it.is_multiple_of(cfg.log_every) || it == cfg.iters || it == first + 1;
        let info = trainer.step(measure)?;
        if let Some(l) = info.losses {
            trainer.check_finite()?;
            let el = t0.elapsed().as_secs_f64();
            let line = serde_json::json!({
                "iter": info.iter,
                "loss": l.loss, "mse": l.mse, "psnr": l.psnr, "ssim": l.ssim,
                "t_concentration": l.t_concentration, "distortion": l.distortion, "tv": l.tv,
                "sh_degree": info.sh_degree, "ss": info.supersample, "entries": info.entries,
                "voxels": trainer.voxels(), "grid_points": trainer.grid_points(),
                "device_memory": trainer.device_memory(), "elapsed_s": el,
                "it_per_s": (info.iter - first) as f64 / el.max(1e-9),
            });
            writeln!(stats, "{line}")
                .with_context(|| format!("cannot write {}", stats_path.display()))?;
            shown = Some(l);
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
            if tty {
                eprint!("\r{msg}\n");
            } else {
                eprintln!("{msg}");
            }
        }
        if sched.checkpoints.contains(&info.iter) {
            trainer.check_finite()?;
            save_run(run, trainer)?;
        }
        let done = info.iter == cfg.iters;
        window.push(info.iter, t0.elapsed().as_secs_f64());
        if (tty && last_print.elapsed().as_secs_f64() > 0.5) || info.losses.is_some() || done {
            let rate = window.rate();
            let eta = (cfg.iters - info.iter) as f64 / rate;
            let (loss, p) = shown.map_or((f64::NAN, f64::NAN), |l| (l.loss, l.psnr));
            let msg = format!(
                "it {}/{} [{:>3.0}%] {rate:.2} it/s  loss {loss:.4}  PSNR {p:.2}  voxels {}  SH {}  ETA {}",
                info.iter,
                cfg.iters,
                100.0 * info.iter as f64 / cfg.iters as f64,
                trainer.voxels(),
                info.sh_degree,
                fmt_duration(eta)
            );
            if tty {
                eprint!("\r{msg}   ");
            } else if info.losses.is_some() || done {
                eprintln!("{msg}");
            }
            last_print = Instant::now();
        }
    }
    if tty {
        eprintln!();
    }
    trainer.check_finite()?;
    save_run(run, trainer)?;
    let secs = t0.elapsed().as_secs_f64();
    eprintln!(
        "trained {} iterations in {} → {}",
        cfg.iters - first,
        fmt_duration(secs),
        run.join("model.safetensors").display()
    );
    Ok(RunSummary {
        iters: trainer.iter(),
        seconds: secs,
        interrupted: false,
    })
}

/// Evaluates `scene` on a split of the dataset at `data` ([`svraster::eval::evaluate`]),
/// with a progress line on stderr unless `quiet`.
pub fn evaluate(
    ctx: &Context,
    scene: &Scene,
    data: &Path,
    split: &str,
    downscale: f64,
    opts: &RenderOptions,
    quiet: bool,
) -> anyhow::Result<EvalReport> {
    let ds = data::load_split(data, split, downscale, scene.background)?;
    if ds.frames.is_empty() {
        bail!("split `{split}` of {} has no frames", data.display());
    }
    let rep = svraster::eval::evaluate(ctx, scene, &ds, opts, |i, n, name, p, s| {
        if !quiet {
            eprint!("\r[{i}/{n}] {name}: PSNR {p:.2} SSIM {s:.4}     ");
        }
    })?;
    if !quiet {
        eprintln!();
    }
    Ok(rep)
}

/// `svraster eval`.
pub fn run_eval(
    ctx: &Context,
    model: &Path,
    data: &Path,
    split: &str,
    downscale: f64,
    ss: Option<f32>,
    json: bool,
) -> anyhow::Result<()> {
    let scene = load_model(model)?;
    let opts = RenderOptions {
        supersample: ss.unwrap_or(scene.supersample),
        ..RenderOptions::for_scene(&scene)
    };
    let rep = evaluate(ctx, &scene, data, split, downscale, &opts, json)?;
    if json {
        println!("{}", serde_json::to_string(&rep)?);
    } else {
        println!(
            "{} views of `{split}` at {}×{} (supersampling {}): PSNR {:.2} dB, SSIM {:.4}, {:.1} ms per frame (median, render only)",
            rep.views, rep.width, rep.height, opts.supersample, rep.psnr, rep.ssim, rep.ms_per_frame
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
    };
    if !a.voxelize {
        resolve_config(&train_args)?;
    } else if !(1..=svraster::scene::MAX_LEVEL).contains(&a.level) {
        bail!(
            "--level must be in 1..={} for --voxelize",
            svraster::scene::MAX_LEVEL
        );
    }
    // The demo replaces what it made before, in a directory it made (marked), and never
    // touches one it did not.
    let marker = a.out.join(".svraster-demo");
    let non_empty = a
        .out
        .read_dir()
        .map(|mut d| d.next().is_some())
        .unwrap_or(false);
    if non_empty && !marker.is_file() {
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
    demo::write_dataset(&data_dir, &opts)?;
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
        &data_dir,
        "test",
        1.0,
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
            out: renders.clone(),
            depth: true,
            normal: true,
            samples: 1,
            ss: None,
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

#[cfg(test)]
mod tests {
    use super::RateWindow;

    #[test]
    fn eta_follows_the_current_rate() {
        // 10 slow iterations (1 s each), then 200 fast ones (0.1 s each).
        let mut w = RateWindow::new(5.0);
        let mut t = 0.0;
        w.push(0, t);
        assert!(w.rate().is_nan());
        for i in 1..=210u32 {
            t += if i <= 10 { 1.0 } else { 0.1 };
            w.push(i, t);
        }
        // The mean since the start would say 210 / 30 s = 7 it/s.
        assert!((w.rate() - 10.0).abs() < 1e-6, "{}", w.rate());
        // A run that slows down is seen within the window.
        for i in 211..=260u32 {
            t += 1.0;
            w.push(i, t);
        }
        assert!((w.rate() - 1.0).abs() < 1e-6, "{}", w.rate());
    }
}
