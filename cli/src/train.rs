//! `svraster train` (its set-up: new runs, resumes, extensions, moved data) and
//! `svraster eval`; the loop is train_loop.rs, the demo demo.rs.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context as _};
use svraster::data;
use svraster::eval::{EvalReport, Timing};
use svraster::gpu::Context;
use svraster::raster::RenderOptions;
use svraster::scene::{checkpoint, Scene};
use svraster::train::config::TrainConfig;
use svraster::train::trainer::Trainer;

use super::inputs::load_model;
use super::progress::Progress;
use super::run_dir::{atomic_write, load_pair, lock_run, truncate_stats};

pub use super::train_loop::RunSummary;
use super::train_loop::{train_loop, ConfigUpdate, HeldOut, LongRun};

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
    if !obj.is_object() {
        // serde would map an array onto the fields by position (`[3]` set the seed).
        bail!(
            "--config {}: not a training configuration: expected a JSON object (a run's \
             config.json, or its \"config\" object)",
            path.display()
        );
    }
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
pub(super) fn canonical(p: &Path) -> PathBuf {
    std::fs::canonicalize(p).unwrap_or_else(|_| p.to_path_buf())
}

/// `svraster train`.
pub fn run_train(ctx: &Context, a: &TrainArgs) -> anyhow::Result<RunSummary> {
    if a.eval_every == Some(0) {
        bail!("--eval-every must be at least 1");
    }
    let run = &a.out;
    let cfg_path = run.join("config.json");
    let mut lock = None;
    let mut extended = false;
    let mut moved: Option<(PathBuf, Option<String>)> = None;
    // A resumed run's changed config.json, written with its first checkpoint.
    let mut config_update: Option<serde_json::Value> = None;
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
        lock = Some(lock_run(run)?);
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
                config_update = Some(v);
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
    let made = if lock.is_none() {
        // A new run: everything is validated; now the directory, locked before anything
        // is written into it (and checked again under the lock).
        if run.exists() && !run.is_dir() {
            bail!(
                "--out {}: it is a file; the run goes into a directory (config.json, \
                 stats.jsonl, model.safetensors …): choose another --out",
                run.display()
            );
        }
        let made = super::outputs::missing_root(run);
        std::fs::create_dir_all(run)
            .with_context(|| format!("cannot create run directory {}", run.display()))?;
        lock = Some(lock_run(run)?);
        if has_checkpoint(run) {
            bail!(
                "{} already holds a run: pass --resume to continue it, or choose another --out",
                run.display()
            );
        }
        made
    } else {
        None
    };
    let mut fresh = FreshRun(made.map(|root| FreshDirs {
        ids: [
            super::outputs::identity(&root),
            super::outputs::identity(run),
        ],
        run: run.clone(),
        root,
    }));
    let mut train = train;
    if init.is_none() {
        let region = svraster::train::bounds::resolve_run(&mut cfg, &mut train)?;
        if cfg.background_frame_mean {
            eprintln!("background: each frame's own mean colour (background_frame_mean)");
        } else if cfg.background_from_photos {
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
        // An extension: config.json records the new end and the schedule's length (with
        // the first checkpoint of the extension, [`ConfigUpdate`]).
        let mut v = match config_update.take() {
            Some(v) => v,
            None => {
                let text = std::fs::read_to_string(&cfg_path)
                    .with_context(|| format!("cannot read {}", cfg_path.display()))?;
                serde_json::from_str(&text)
                    .with_context(|| format!("{} is not valid JSON", cfg_path.display()))?
            }
        };
        v["config"] = serde_json::to_value(&cfg)?;
        v["schedule"] = serde_json::to_value(trainer.schedule())?;
        config_update = Some(v);
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
         (learning rates: density {}, SH {} / {}) → {}",
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
        trainer.schedule().lr_sh0,
        trainer.schedule().lr_shs,
        run.display()
    );
    let long_run = ctx.info().is_cpu.then(|| LongRun {
        device: ctx.info().name.clone(),
        downscale,
        warned: false,
    });
    let held = match a.eval_every {
        Some(0) => unreachable!("refused at the start"),
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
    let lock = lock.expect("the run directory is locked above");
    let config_update = match config_update {
        Some(v) => Some(ConfigUpdate {
            path: cfg_path.clone(),
            bytes: serde_json::to_string_pretty(&v)?.into_bytes(),
        }),
        None => None,
    };
    let summary = train_loop(
        &mut trainer,
        run,
        &lock,
        long_run,
        held.as_ref(),
        config_update,
    )?;
    fresh.0 = None;
    Ok(summary)
}

/// The directory of a new run that this process made and locked (with the first folder
/// of its path it made): removed again if the run fails before its first checkpoint, so
/// a failed start leaves nothing behind (it left a folder holding only `.lock`). Once a
/// checkpoint exists it always stays: a run is never lost; nor is a folder put in its
/// place while it ran removed (its identity is kept).
struct FreshRun(Option<FreshDirs>);

/// The run directory, the first folder of its path this process made, and the
/// identities of both when made.
struct FreshDirs {
    run: PathBuf,
    root: PathBuf,
    ids: [Option<(u64, u64)>; 2],
}

impl Drop for FreshRun {
    fn drop(&mut self) {
        if let Some(f) = self.0.take() {
            let same = super::outputs::identity(&f.run) == f.ids[1];
            if same && !has_checkpoint(&f.run) {
                super::outputs::remove_if_same(&f.root, f.ids[0]);
            }
        }
    }
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
    let rep = svraster::eval::evaluate(
        ctx,
        scene,
        &ds,
        opts,
        Timing::Measured,
        |i, _, name, p, s| {
            progress.update(i as u64, || format!("{name}: PSNR {p:.2} SSIM {s:.4}"));
        },
    )?;
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
            rep.ms_per_frame.unwrap_or(f64::NAN)
        );
    }
    Ok(())
}
