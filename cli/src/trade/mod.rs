//! `svraster bench trade`: the speed/accuracy trade on a user's own scene. Without
//! `--vary`, the trade of the voxel layout (paper Tab. 6 on our data): the adaptive layout
//! and uniform layouts of given final levels under one voxel budget. With `--vary
//! KEY=V1,V2,…` (repeatable), one factor at a time around the preset: a `base` variant,
//! then one variant per listed value of each knob (any `--set` key, or `iters`). Every
//! variant is trained, evaluated on a held-out split, and reported (PSNR, SSIM, training
//! time, median frame time, voxels, peak device memory) as a table, JSON and a PNG chart,
//! with the Pareto fronts (quality vs training time, quality vs frame time) marked.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context as _};
use svraster::gpu::Context;
use svraster::raster::RenderOptions;
use svraster::scene::checkpoint;

use super::train::{evaluate, run_train, TrainArgs};

mod report;
use report::{budget_capped, peak_device_memory, read_config, table, write, write_outputs};

/// Arguments of `bench trade`.
#[derive(Clone)]
pub struct TradeArgs {
    pub data: PathBuf,
    pub out: PathBuf,
    pub downscale: f64,
    pub preset: String,
    pub iters: u32,
    pub max_voxels: u64,
    pub uniform_levels: Vec<u32>,
    pub split: String,
    pub set: Vec<String>,
    /// One-factor-at-a-time knobs, `KEY=V1,V2,…` (empty: the layout comparison).
    pub vary: Vec<String>,
    pub seed: u64,
    /// Keep variants an identical earlier comparison finished (`VARIANT/trade_row.json`).
    pub reuse: bool,
    pub json: bool,
    /// With --vary: at most this many pairwise combinations of the one-factor variants on
    /// a Pareto front, trained after them (0: none).
    pub combine: usize,
    /// Wall-clock minutes the whole comparison may take: sets `iters` from a timed
    /// calibration run of the base configuration (None: `iters` as given).
    pub budget_minutes: Option<f64>,
}

impl TradeArgs {
    /// `--set` plus a variant's `extra` overrides, with the comparison's voxel budget
    /// unless they set one.
    fn overrides(&self, extra: &[String]) -> Vec<String> {
        let mut set = self.set.clone();
        set.extend_from_slice(extra);
        if !set
            .iter()
            .any(|kv| kv.trim_start().starts_with("max_voxels"))
        {
            set.push(format!("max_voxels={}", self.max_voxels));
        }
        set
    }

    /// Trains a new run in `out` on the comparison's data, downscale, preset and seed.
    fn train(
        &self,
        ctx: &Context,
        out: &Path,
        iters: u32,
        set: Vec<String>,
    ) -> anyhow::Result<super::train::RunSummary> {
        run_train(
            ctx,
            &TrainArgs {
                data: self.data.clone(),
                out: out.to_path_buf(),
                iters: Some(iters),
                downscale: Some(self.downscale),
                preset: Some(self.preset.clone()),
                seed: Some(self.seed),
                set,
                resume: false,
                source: Default::default(),
                eval_every: None,
                config: None,
            },
        )
    }
}

/// One trained variant.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TradeRow {
    pub variant: String,
    pub layout: String,
    pub max_level: u32,
    pub voxels: usize,
    pub grid_points: usize,
    /// Peak device memory the training allocated (bytes, from its stats.jsonl).
    pub peak_device_memory: u64,
    pub psnr: f64,
    pub ssim: f64,
    pub train_s: f64,
    pub ms_per_frame: f64,
    /// Whether the voxel budget stopped a subdivision of this variant (a capped
    /// `uniform-L` does not reach level L: it is not the layout its name says).
    #[serde(default)]
    pub budget_capped: bool,
    /// On the Pareto front of PSNR against training time (no other variant trains as
    /// fast or faster to an equal or higher PSNR, one of them strictly).
    #[serde(default)]
    pub front_train: bool,
    /// On the Pareto front of PSNR against frame time.
    #[serde(default)]
    pub front_render: bool,
    /// Training iterations of this variant.
    #[serde(default)]
    pub iters: u32,
    pub run: PathBuf,
}

/// A variant to train: its name, its overrides on top of `--set`, its iterations.
#[derive(Clone)]
struct Variant {
    name: String,
    extra: Vec<String>,
    iters: u32,
}

/// The variants of a comparison (see the module docs); knobs are checked against the
/// preset before anything trains.
fn variants(a: &TradeArgs) -> anyhow::Result<Vec<Variant>> {
    if a.vary.is_empty() {
        let mut v = vec![Variant {
            name: "adaptive".into(),
            extra: vec!["layout=adaptive".into(), "max_level=16".into()],
            iters: a.iters,
        }];
        for &l in &a.uniform_levels {
            if !(1..=16).contains(&l) {
                bail!("--uniform-levels: level {l} outside 1..=16");
            }
            v.push(Variant {
                name: format!("uniform-{l}"),
                extra: vec!["layout=uniform".into(), format!("max_level={l}")],
                iters: a.iters,
            });
        }
        return Ok(v);
    }
    let mut base = svraster::train::config::TrainConfig::preset(&a.preset)?;
    for kv in &a.set {
        base.set(kv)?;
    }
    let mut v = vec![Variant {
        name: "base".into(),
        extra: Vec::new(),
        iters: a.iters,
    }];
    for spec in &a.vary {
        let (key, values) = spec
            .split_once('=')
            .filter(|(k, v)| !k.trim().is_empty() && !v.trim().is_empty())
            .ok_or_else(|| anyhow::anyhow!("--vary `{spec}`: expected KEY=V1,V2,…"))?;
        let key = key.trim();
        for value in values.split(',').map(str::trim) {
            if key == "iters" {
                let n: u32 = value
                    .parse()
                    .ok()
                    .filter(|&n| n >= 1)
                    .ok_or_else(|| anyhow::anyhow!("--vary iters: `{value}` is not ≥ 1"))?;
                v.push(Variant {
                    name: format!("iters={n}"),
                    extra: Vec::new(),
                    iters: n,
                });
                continue;
            }
            let kv = format!("{key}={value}");
            let mut probe = base.clone();
            probe
                .set(&kv)
                .and_then(|_| probe.validate())
                .map_err(|e| anyhow::anyhow!("--vary {kv}: {e}"))?;
            v.push(Variant {
                name: kv.clone(),
                extra: vec![kv],
                iters: a.iters,
            });
        }
    }
    // One directory per variant: names must be distinct and usable as a path component.
    let mut seen = std::collections::HashSet::new();
    for x in &v {
        if x.name.contains(['/', '\\']) || x.name.starts_with('.') {
            bail!("--vary: `{}` cannot name a run directory", x.name);
        }
        if !seen.insert(x.name.clone()) {
            bail!("--vary: `{}` is listed twice", x.name);
        }
        if x.extra
            .iter()
            .any(|kv| kv.replace(' ', "") == "max_voxels=0")
        {
            bail!("--vary max_voxels=0: every variant trains under an explicit budget");
        }
    }
    Ok(v)
}

/// Pairwise combinations of the one-factor variants on either Pareto front of `rows`
/// (variants of different knobs, at the same iterations), front variants with the higher
/// PSNR first, at most `limit`; none that an existing variant already names.
fn combinations(done: &[Variant], rows: &[TradeRow], limit: usize) -> Vec<Variant> {
    let mut front: Vec<(&Variant, f64)> = done
        .iter()
        .filter(|v| v.extra.len() == 1)
        .filter_map(|v| {
            rows.iter()
                .find(|r| r.variant == v.name && (r.front_train || r.front_render))
                .map(|r| (v, r.psnr))
        })
        .collect();
    front.sort_by(|a, b| b.1.total_cmp(&a.1));
    let key = |v: &Variant| {
        v.extra[0]
            .split('=')
            .next()
            .unwrap_or("")
            .trim()
            .to_string()
    };
    let mut out: Vec<Variant> = Vec::new();
    for i in 0..front.len() {
        for j in i + 1..front.len() {
            let (a, b) = (front[i].0, front[j].0);
            if key(a) == key(b) || a.iters != b.iters {
                continue;
            }
            let name = format!("{}+{}", a.name, b.name);
            if out.len() < limit && !done.iter().any(|d| d.name == name) {
                out.push(Variant {
                    name,
                    extra: vec![a.extra[0].clone(), b.extra[0].clone()],
                    iters: a.iters,
                });
            }
        }
    }
    out
}

/// Runs every variant and writes `OUT/trade.json`, `OUT/trade.md` and `OUT/trade.png`.
pub fn run(ctx: &Context, a: &TradeArgs) -> anyhow::Result<Vec<TradeRow>> {
    if a.max_voxels == 0 {
        bail!("--max-voxels must be ≥ 1: every variant trains under the same budget");
    }
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    // A bare speed modifier (`--preset fast-train`) applies to the data's preset.
    let format = super::train::format_preset(svraster::data::detect_format(&a.data));
    let resolved = TradeArgs {
        preset: svraster::train::config::TrainConfig::resolve_preset(&a.preset, format),
        ..a.clone()
    };
    let a = &resolved;
    let budgeted;
    let a = match a.budget_minutes {
        Some(m) => {
            budgeted = TradeArgs {
                iters: fit_iters(ctx, a, m)?,
                budget_minutes: None,
                ..a.clone()
            };
            &budgeted
        }
        None => a,
    };
    let mut variants = variants(a)?;
    let mut total = variants.len() + if a.vary.is_empty() { 0 } else { a.combine };
    let mut clock = Clock {
        started: std::time::Instant::now(),
        trained_s: Vec::new(),
    };
    let mut rows = Vec::new();
    // The outputs as of the last finished variant (there is always one).
    let mut doc = serde_json::Value::Null;
    for (index, v) in variants.clone().into_iter().enumerate() {
        doc = run_variant(ctx, a, &v, index, &mut total, &mut clock, &mut rows)?;
    }
    if !a.vary.is_empty() && a.combine > 0 {
        // A pair of knobs that were valid alone may not be together: skip it.
        let combos: Vec<Variant> = combinations(&variants, &rows, a.combine)
            .into_iter()
            .filter(|c| {
                let ok =
                    svraster::train::config::TrainConfig::preset(&a.preset).is_ok_and(|mut cfg| {
                        a.set.iter().chain(&c.extra).all(|kv| cfg.set(kv).is_ok())
                            && cfg.validate().is_ok()
                    });
                if !ok {
                    eprintln!(
                        "skipping the combination {}: not a valid configuration",
                        c.name
                    );
                }
                ok
            })
            .collect();
        total = variants.len() + combos.len();
        if combos.is_empty() {
            eprintln!("no combinations: fewer than two knobs have a variant on a Pareto front");
        } else {
            eprintln!(
                "combining the front's one-factor variants: {}",
                combos
                    .iter()
                    .map(|c| c.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        for c in combos {
            let index = variants.len();
            variants.push(c.clone());
            doc = run_variant(ctx, a, &c, index, &mut total, &mut clock, &mut rows)?;
        }
    }
    if a.json {
        println!("{doc}");
    } else {
        print!("{}", table(ctx, a, &rows));
        println!("chart: {}", a.out.join("trade.png").display());
    }
    Ok(rows)
}

/// Wall time of the comparison so far, for the ETA.
struct Clock {
    started: std::time::Instant,
    trained_s: Vec<f64>,
}

/// The iterations at which the whole comparison fits in `minutes`: a calibration run of
/// the base configuration (`OUT/calibration`, 100 iterations, deleted afterwards) gives
/// the seconds per iteration including the run's fixed costs (initialisation, the first
/// adaptive steps; not the evaluation of each variant, which comes on top), which every
/// variant is assumed to take; rounded down to a multiple of 100, at least 100.
/// `--vary iters=N` variants keep their N.
fn fit_iters(ctx: &Context, a: &TradeArgs, minutes: f64) -> anyhow::Result<u32> {
    if !(minutes.is_finite() && minutes > 0.0) {
        bail!("--budget-minutes must be a positive number of minutes, got {minutes}");
    }
    let count = variants(a)?.len() + if a.vary.is_empty() { 0 } else { a.combine };
    let calib = a.out.join("calibration");
    if calib.exists() {
        std::fs::remove_dir_all(&calib)
            .with_context(|| format!("cannot clear {}", calib.display()))?;
    }
    const CALIB_ITERS: u32 = 100;
    eprintln!(
        "--budget-minutes {minutes}: timing {CALIB_ITERS} iterations of the base configuration \
         to fit {count} variants …"
    );
    let t = std::time::Instant::now();
    let summary = a.train(ctx, &calib, CALIB_ITERS, a.overrides(&[]))?;
    if summary.interrupted {
        bail!("interrupted during the calibration run");
    }
    let per_iter = t.elapsed().as_secs_f64() / f64::from(CALIB_ITERS);
    let _ = std::fs::remove_dir_all(&calib);
    let left = minutes * 60.0 - t.elapsed().as_secs_f64();
    let fit = left / count as f64 / per_iter;
    let iters = ((fit / 100.0).floor() as u32 * 100).max(100);
    eprintln!(
        "{:.2} s per iteration (with the fixed costs): {count} variants × {iters} iterations \
         ≈ {:.0} min{}",
        per_iter,
        count as f64 * f64::from(iters) * per_iter / 60.0,
        if fit < 100.0 {
            " — more than the budget: 100 iterations is the least this comparison trains"
        } else {
            ""
        }
    );
    eprintln!(
        "(to continue this comparison later, pass --iters {iters} --reuse instead of \
         --budget-minutes: a new calibration may choose other iterations)"
    );
    Ok(iters)
}

/// Trains (or reuses) one variant, appends its row and rewrites the outputs; returns the
/// JSON document.
fn run_variant(
    ctx: &Context,
    a: &TradeArgs,
    v: &Variant,
    index: usize,
    total: &mut usize,
    clock: &mut Clock,
    rows: &mut Vec<TradeRow>,
) -> anyhow::Result<serde_json::Value> {
    let Variant { name, extra, iters } = v.clone();
    let run = a.out.join(&name);
    let set = a.overrides(&extra);
    // What makes a finished variant reusable: everything its row depends on.
    let key = serde_json::json!({
        "data": a.data, "split": a.split, "downscale": a.downscale, "preset": a.preset,
        "iters": iters, "seed": a.seed, "set": set,
    });
    let row_file = run.join("trade_row.json");
    if a.reuse {
        if let Some(mut row) = finished_row(&row_file, &key) {
            eprintln!("== {name} == reusing the finished run in {}", run.display());
            row.iters = iters; // rows saved before the field existed read 0
            rows.push(row);
            return write_outputs(ctx, a, rows);
        }
    }
    if run.join("config.json").exists() {
        eprintln!("replacing the previous run in {}", run.display());
        std::fs::remove_dir_all(&run).with_context(|| format!("cannot clear {}", run.display()))?;
    }
    eprintln!("== {name} ({} of {}) ==", index + 1, *total);
    let t_variant = std::time::Instant::now();
    let summary = a.train(ctx, &run, iters, set)?;
    if summary.interrupted {
        bail!("interrupted while training {name}");
    }
    let scene = checkpoint::load(&run.join("model.safetensors"))?;
    let rep = evaluate(
        ctx,
        &scene,
        &super::train::Views {
            data: &a.data,
            split: &a.split,
            downscale: a.downscale,
            source: &Default::default(),
        },
        &RenderOptions::for_scene(&scene),
        false,
    )?;
    let cfg = read_config(&run)?;
    let row = TradeRow {
        variant: name,
        layout: cfg["config"]["layout"].as_str().unwrap_or("?").to_string(),
        max_level: scene.max_level(),
        voxels: scene.num_voxels(),
        grid_points: scene.num_grid_points(),
        peak_device_memory: peak_device_memory(&run)?,
        psnr: rep.psnr,
        ssim: rep.ssim,
        train_s: summary.seconds,
        ms_per_frame: rep.ms_per_frame.unwrap_or(f64::NAN),
        budget_capped: budget_capped(&run)?,
        front_train: false,
        front_render: false,
        iters,
        run,
    };
    let saved = serde_json::json!({ "key": key, "row": row });
    write(&row_file, serde_json::to_string_pretty(&saved)?.as_bytes())?;
    rows.push(row);
    // Every finished variant is on disk at once: a long comparison stopped part-way
    // keeps the rows it measured.
    let doc = write_outputs(ctx, a, rows)?;
    clock.trained_s.push(t_variant.elapsed().as_secs_f64());
    let left = total.saturating_sub(index + 1);
    if left > 0 {
        let mean = clock.trained_s.iter().sum::<f64>() / clock.trained_s.len() as f64;
        eprintln!(
            "{} of {} variants done in {:.0} min; ETA ~{:.0} min for the {left} left \
             (mean of the variants trained so far{})",
            index + 1,
            *total,
            clock.started.elapsed().as_secs_f64() / 60.0,
            mean * left as f64 / 60.0,
            if a.combine > 0 && !a.vary.is_empty() {
                "; combinations counted at their most"
            } else {
                ""
            }
        );
    }
    Ok(doc)
}

/// The row an earlier identical comparison saved for this variant, if its model is
/// still there; anything else (no file, another key, unreadable) means train again.
fn finished_row(row_file: &Path, key: &serde_json::Value) -> Option<TradeRow> {
    let saved: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(row_file).ok()?).ok()?;
    if &saved["key"] != key {
        return None;
    }
    let row: TradeRow = serde_json::from_value(saved["row"].clone()).ok()?;
    row.run.join("model.safetensors").exists().then_some(row)
}

#[cfg(test)]
mod tests {
    use super::report::mark_fronts;
    use super::*;

    fn row(name: &str, train_s: f64, ms: f64, psnr: f64) -> TradeRow {
        TradeRow {
            variant: name.into(),
            layout: "adaptive".into(),
            max_level: 1,
            voxels: 1,
            grid_points: 1,
            peak_device_memory: 0,
            psnr,
            ssim: 0.0,
            train_s,
            ms_per_frame: ms,
            budget_capped: false,
            front_train: false,
            front_render: false,
            iters: 1,
            run: PathBuf::new(),
        }
    }

    fn variant(name: &str) -> Variant {
        Variant {
            name: name.into(),
            extra: if name == "base" {
                Vec::new()
            } else {
                vec![name.into()]
            },
            iters: 1,
        }
    }

    /// Pairs of front variants of different knobs, best PSNR first, within the limit;
    /// off-front variants, `base` and two values of one knob are never combined.
    #[test]
    fn combinations_pair_front_variants_of_different_knobs() {
        let done: Vec<Variant> = [
            "base",
            "ss=1",
            "ss=1.1",
            "samples=3",
            "sh_degree=0",
            "grid_level=5",
        ]
        .iter()
        .map(|n| variant(n))
        .collect();
        let mut rows = vec![
            row("base", 100.0, 10.0, 30.0),
            row("ss=1", 60.0, 9.0, 30.5),   // front (dominates base)
            row("ss=1.1", 25.0, 9.5, 29.0), // front (train)
            row("samples=3", 200.0, 20.0, 29.0), // dominated
            row("sh_degree=0", 20.0, 3.0, 28.0), // front
            row("grid_level=5", 30.0, 4.0, 29.5), // front
        ];
        mark_fronts(&mut rows);
        assert!(!rows[3].front_train && !rows[3].front_render);
        let names = |c: Vec<Variant>| c.into_iter().map(|v| v.name).collect::<Vec<_>>();
        let all = names(combinations(&done, &rows, 10));
        assert_eq!(
            all,
            [
                "ss=1+grid_level=5",
                "ss=1+sh_degree=0",
                "grid_level=5+ss=1.1",
                "grid_level=5+sh_degree=0",
                "ss=1.1+sh_degree=0",
            ]
        );
        assert_eq!(names(combinations(&done, &rows, 2)).len(), 2);
        assert!(combinations(&done, &rows, 0).is_empty());
        let c = &combinations(&done, &rows, 1)[0];
        assert_eq!(c.extra, ["ss=1", "grid_level=5"]);
    }

    #[test]
    fn pareto_fronts_hold_exactly_the_undominated_variants() {
        let mut rows = vec![
            row("fast", 10.0, 5.0, 25.0),
            row("slow-best", 100.0, 9.0, 32.0),
            row("dominated", 50.0, 9.5, 24.0), // slower and worse than "fast"
            row("middle", 40.0, 4.0, 30.0),
            row("tie", 40.0, 4.0, 30.0), // equal to "middle": neither dominates
        ];
        mark_fronts(&mut rows);
        let train: Vec<&str> = rows
            .iter()
            .filter(|r| r.front_train)
            .map(|r| r.variant.as_str())
            .collect();
        assert_eq!(train, ["fast", "slow-best", "middle", "tie"]);
        let render: Vec<&str> = rows
            .iter()
            .filter(|r| r.front_render)
            .map(|r| r.variant.as_str())
            .collect();
        // "middle" renders faster than "fast" and is more accurate: "fast" is dominated.
        assert_eq!(render, ["slow-best", "middle", "tie"]);
    }
}
