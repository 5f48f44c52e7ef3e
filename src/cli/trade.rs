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

use super::plot::{save_row, Chart, Point, Series};
use super::train::{evaluate, run_train, TrainArgs};

/// Arguments of `bench trade`.
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

/// Marks the two Pareto fronts: a row is on a front when no other row has a cost at most
/// its own and a PSNR at least its own, one of the two strictly better.
fn mark_fronts(rows: &mut [TradeRow]) {
    let on_front = |rows: &[TradeRow], i: usize, cost: &dyn Fn(&TradeRow) -> f64| {
        let r = &rows[i];
        !rows.iter().enumerate().any(|(j, o)| {
            j != i
                && cost(o) <= cost(r)
                && o.psnr >= r.psnr
                && (cost(o) < cost(r) || o.psnr > r.psnr)
        })
    };
    let train: Vec<bool> = (0..rows.len())
        .map(|i| on_front(rows, i, &|r| r.train_s))
        .collect();
    let render: Vec<bool> = (0..rows.len())
        .map(|i| on_front(rows, i, &|r| r.ms_per_frame))
        .collect();
    for (i, r) in rows.iter_mut().enumerate() {
        r.front_train = train[i];
        r.front_render = render[i];
    }
}

/// Runs every variant and writes `OUT/trade.json`, `OUT/trade.md` and `OUT/trade.png`.
pub fn run(ctx: &Context, a: &TradeArgs) -> anyhow::Result<Vec<TradeRow>> {
    if a.max_voxels == 0 {
        bail!("--max-voxels must be ≥ 1: every variant trains under the same budget");
    }
    let variants = variants(a)?;
    let total = variants.len();
    let started = std::time::Instant::now();
    let mut trained_s = Vec::new();
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let mut rows = Vec::new();
    // The outputs as of the last finished variant (there is always one: `adaptive`).
    let mut doc = serde_json::Value::Null;
    for (index, Variant { name, extra, iters }) in variants.into_iter().enumerate() {
        let run = a.out.join(&name);
        let mut set = a.set.clone();
        set.extend(extra);
        if !set
            .iter()
            .any(|kv| kv.trim_start().starts_with("max_voxels"))
        {
            set.push(format!("max_voxels={}", a.max_voxels));
        }
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
                doc = write_outputs(ctx, a, &mut rows)?;
                continue;
            }
        }
        if run.join("config.json").exists() {
            eprintln!("replacing the previous run in {}", run.display());
            std::fs::remove_dir_all(&run)
                .with_context(|| format!("cannot clear {}", run.display()))?;
        }
        eprintln!("== {name} ({} of {total}) ==", index + 1);
        let t_variant = std::time::Instant::now();
        let summary = run_train(
            ctx,
            &TrainArgs {
                data: a.data.clone(),
                out: run.clone(),
                iters: Some(iters),
                downscale: Some(a.downscale),
                preset: Some(a.preset.clone()),
                seed: Some(a.seed),
                set,
                resume: false,
                source: Default::default(),
            },
        )?;
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
            ms_per_frame: rep.ms_per_frame,
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
        doc = write_outputs(ctx, a, &mut rows)?;
        trained_s.push(t_variant.elapsed().as_secs_f64());
        let left = total - index - 1;
        if left > 0 {
            let mean = trained_s.iter().sum::<f64>() / trained_s.len() as f64;
            eprintln!(
                "{} of {total} variants done in {:.0} min; ETA ~{:.0} min for the {left} left \
                 (mean of the variants trained so far)",
                index + 1,
                started.elapsed().as_secs_f64() / 60.0,
                mean * left as f64 / 60.0
            );
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

/// Writes `trade.md`, `trade.json` and `trade.png` for the rows so far; returns the JSON.
fn write_outputs(
    ctx: &Context,
    a: &TradeArgs,
    rows: &mut [TradeRow],
) -> anyhow::Result<serde_json::Value> {
    mark_fronts(rows);
    let rows = &*rows;
    let table = table(ctx, a, rows);
    write(&a.out.join("trade.md"), table.as_bytes())?;
    let doc = serde_json::json!({
        "device": ctx.info().name,
        "data": a.data,
        "downscale": a.downscale,
        "preset": a.preset,
        "iters": a.iters,
        "max_voxels": a.max_voxels,
        "split": a.split,
        "set": a.set,
        "vary": a.vary,
        "rows": rows,
    });
    write(
        &a.out.join("trade.json"),
        serde_json::to_string_pretty(&doc)?.as_bytes(),
    )?;
    save_row(&charts(rows, &a.split), &a.out.join("trade.png"), 640, 480)?;
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

fn read_config(run: &Path) -> anyhow::Result<serde_json::Value> {
    let p = run.join("config.json");
    let text =
        std::fs::read_to_string(&p).with_context(|| format!("cannot read {}", p.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{} is not JSON", p.display()))
}

/// The largest `device_memory` any line of a run's stats.jsonl records.
fn peak_device_memory(run: &Path) -> anyhow::Result<u64> {
    let p = run.join("stats.jsonl");
    let text =
        std::fs::read_to_string(&p).with_context(|| format!("cannot read {}", p.display()))?;
    let mut peak = 0;
    for line in text.lines() {
        let v: serde_json::Value =
            serde_json::from_str(line).with_context(|| format!("{} is not JSON", p.display()))?;
        let m = v
            .get("adapt")
            .unwrap_or(&v)
            .get("device_memory")
            .and_then(|m| m.as_u64());
        peak = peak.max(m.unwrap_or(0));
    }
    Ok(peak)
}

/// Whether any adaptive step of a run's stats.jsonl reports the voxel budget reached.
fn budget_capped(run: &Path) -> anyhow::Result<bool> {
    let p = run.join("stats.jsonl");
    let text =
        std::fs::read_to_string(&p).with_context(|| format!("cannot read {}", p.display()))?;
    Ok(text.lines().any(|l| {
        serde_json::from_str::<serde_json::Value>(l)
            .ok()
            .and_then(|v| v["adapt"]["budget_reached"].as_bool())
            .unwrap_or(false)
    }))
}

fn write(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    Ok(svraster::fsio::write_atomic(path, bytes)?)
}

/// The markdown table of the rows.
fn table(ctx: &Context, a: &TradeArgs, rows: &[TradeRow]) -> String {
    let mut s = format!(
        "{} trade on {} ({}, downscale {}, {} iterations, preset {}, budget {} voxels, {} \
         split{})\n\n",
        if a.vary.is_empty() {
            "voxel layout"
        } else {
            "speed/accuracy"
        },
        ctx.info().name,
        a.data.display(),
        a.downscale,
        a.iters,
        a.preset,
        a.max_voxels,
        a.split,
        if a.set.is_empty() {
            String::new()
        } else {
            format!(", --set {}", a.set.join(" "))
        }
    );
    s += "| variant | voxels | grid points | max level | peak device memory | PSNR | SSIM | \
          train | ms/frame | Pareto front |\n";
    s += "|---|---|---|---|---|---|---|---|---|---|\n";
    for r in rows {
        let name = if r.budget_capped {
            format!(
                "{} (capped by the budget at level {})",
                r.variant, r.max_level
            )
        } else {
            r.variant.clone()
        };
        let front = match (r.front_train, r.front_render) {
            (true, true) => "**train, render**",
            (true, false) => "**train**",
            (false, true) => "**render**",
            (false, false) => "",
        };
        s += &format!(
            "| {} | {} | {} | {} | {:.0} MiB | {:.2} | {:.4} | {:.0} s | {:.1} | {} |\n",
            name,
            r.voxels,
            r.grid_points,
            r.max_level,
            r.peak_device_memory as f64 / (1u64 << 20) as f64,
            r.psnr,
            r.ssim,
            r.train_s,
            r.ms_per_frame,
            front
        );
    }
    s += "\nPareto front: no other variant is as fast (training, or per frame) and at least as \
          accurate, one of the two strictly.\n";
    s
}

/// PSNR against training time, frame time and voxel count; one series per layout.
fn charts(rows: &[TradeRow], split: &str) -> Vec<Chart> {
    let series = |x: &dyn Fn(&TradeRow) -> f64, front: &dyn Fn(&TradeRow) -> bool| -> Vec<Series> {
        let mut out: Vec<Series> = Vec::new();
        for layout in ["adaptive", "uniform", "fixed"] {
            let points: Vec<Point> = rows
                .iter()
                .filter(|r| r.layout == layout)
                .map(|r| Point::labeled(x(r), r.psnr, r.variant.clone()))
                .collect();
            if !points.is_empty() {
                out.push(Series::scatter(layout, points));
            }
        }
        // Last, so the layouts keep their colours from chart to chart.
        let f: Vec<Point> = rows
            .iter()
            .filter(|r| front(r))
            .map(|r| Point::new(x(r), r.psnr))
            .collect();
        if f.len() > 1 {
            out.push(Series::new("Pareto front", f));
        }
        out
    };
    let y = format!("{split} PSNR (dB)");
    vec![
        Chart {
            title: "quality vs training time".into(),
            x_label: "training time (s)".into(),
            y_label: y.clone(),
            series: series(&|r| r.train_s, &|r| r.front_train),
            markers: true,
            ..Default::default()
        },
        Chart {
            title: "quality vs frame time".into(),
            x_label: "ms per frame".into(),
            y_label: y.clone(),
            series: series(&|r| r.ms_per_frame, &|r| r.front_render),
            markers: true,
            ..Default::default()
        },
        Chart {
            title: "quality vs model size".into(),
            x_label: "voxels".into(),
            y_label: y,
            series: series(&|r| r.voxels as f64, &|_| false),
            x_log: true,
            markers: true,
            ..Default::default()
        },
    ]
}

#[cfg(test)]
mod tests {
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
