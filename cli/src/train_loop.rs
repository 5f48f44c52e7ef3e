//! The training loop of `svraster train`: progress with current values, stats.jsonl,
//! held-out evaluations (`--eval-every`), the long-run note on CPU devices,
//! checkpoints and Ctrl-C.

use std::io::Write as _;
use std::path::Path;
use std::sync::atomic::Ordering;
use std::time::Instant;

use anyhow::Context as _;
use svraster::data;
use svraster::gpu::Context;
use svraster::raster::RenderOptions;
use svraster::train::trainer::Trainer;

use super::progress::{fmt_duration, Progress, RateWindow};
use super::run_dir::{catch_signals, save_run, RunLock, INTERRUPTS};

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
pub(super) struct LongRun {
    pub(super) device: String,
    pub(super) downscale: f64,
    pub(super) warned: bool,
}

/// The held-out views `--eval-every` scores during training.
pub(super) struct HeldOut {
    pub(super) ctx: Context,
    pub(super) ds: data::Dataset,
    pub(super) every: u32,
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
            svraster::eval::Timing::Skipped,
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

/// A resumed run's new config.json (an extension's iterations, a moved dataset's path),
/// written with the first checkpoint the resumed run saves: a resume that fails before
/// one leaves the run's files as they were.
pub(super) struct ConfigUpdate {
    pub path: std::path::PathBuf,
    pub bytes: Vec<u8>,
}

/// Saves the checkpoint pair, then a pending config.json.
fn save(
    run: &Path,
    lock: &RunLock,
    trainer: &mut Trainer,
    config_update: &mut Option<ConfigUpdate>,
) -> anyhow::Result<()> {
    save_run(run, lock, trainer)?;
    if let Some(u) = config_update.take() {
        super::run_dir::atomic_write(&u.path, &u.bytes)?;
    }
    Ok(())
}

pub(super) fn train_loop(
    trainer: &mut Trainer,
    run: &Path,
    lock: &RunLock,
    mut long_run: Option<LongRun>,
    held: Option<&HeldOut>,
    mut config_update: Option<ConfigUpdate>,
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
            save(run, lock, trainer, &mut config_update)?;
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
            // The log goes to the file opened at the start: a run whose directory is
            // gone (or is another run's now) stops here instead of training into nowhere.
            lock.check(info.iter)?;
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
            stats
                .write_all(format!("{line}\n").as_bytes())
                .with_context(|| format!("cannot write {}", stats_path.display()))?;
        }
        if let Some(r) = &info.adapt {
            let line = serde_json::json!({ "adapt": r });
            stats
                .write_all(format!("{line}\n").as_bytes())
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
            stats
                .write_all(format!("{line}\n").as_bytes())
                .with_context(|| format!("cannot write {}", stats_path.display()))?;
            progress.line(&msg);
        }
        if sched.checkpoints.contains(&info.iter) {
            trainer.check_finite()?;
            save(run, lock, trainer, &mut config_update)?;
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
    save(run, lock, trainer, &mut config_update)?;
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
