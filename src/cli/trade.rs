//! `svraster bench trade`: the speed/accuracy trade of the voxel layout (paper Tab. 6 on
//! our data). Trains the adaptive layout and uniform layouts of given final levels under
//! one voxel budget, evaluates each on a held-out split, and reports val PSNR, SSIM,
//! training time, frame time and voxel count as a table, JSON and a PNG chart.

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
    pub run: PathBuf,
}

/// Runs every variant and writes `OUT/trade.json`, `OUT/trade.md` and `OUT/trade.png`.
pub fn run(ctx: &Context, a: &TradeArgs) -> anyhow::Result<Vec<TradeRow>> {
    if a.max_voxels == 0 {
        bail!("--max-voxels must be ≥ 1: every variant trains under the same budget");
    }
    let mut variants: Vec<(String, Vec<String>)> = vec![(
        "adaptive".into(),
        vec!["layout=adaptive".into(), "max_level=16".into()],
    )];
    for &l in &a.uniform_levels {
        if !(1..=16).contains(&l) {
            bail!("--uniform-levels: level {l} outside 1..=16");
        }
        variants.push((
            format!("uniform-{l}"),
            vec!["layout=uniform".into(), format!("max_level={l}")],
        ));
    }
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let mut rows = Vec::new();
    // The outputs as of the last finished variant (there is always one: `adaptive`).
    let mut doc = serde_json::Value::Null;
    for (name, extra) in variants {
        let run = a.out.join(&name);
        let mut set = a.set.clone();
        set.extend(extra);
        set.push(format!("max_voxels={}", a.max_voxels));
        // What makes a finished variant reusable: everything its row depends on.
        let key = serde_json::json!({
            "data": a.data, "split": a.split, "downscale": a.downscale, "preset": a.preset,
            "iters": a.iters, "seed": a.seed, "set": set,
        });
        let row_file = run.join("trade_row.json");
        if a.reuse {
            if let Some(row) = finished_row(&row_file, &key) {
                eprintln!("== {name} == reusing the finished run in {}", run.display());
                rows.push(row);
                doc = write_outputs(ctx, a, &rows)?;
                continue;
            }
        }
        if run.join("config.json").exists() {
            eprintln!("replacing the previous run in {}", run.display());
            std::fs::remove_dir_all(&run)
                .with_context(|| format!("cannot clear {}", run.display()))?;
        }
        eprintln!("== {name} ==");
        let summary = run_train(
            ctx,
            &TrainArgs {
                data: a.data.clone(),
                out: run.clone(),
                iters: Some(a.iters),
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
            run,
        };
        let saved = serde_json::json!({ "key": key, "row": row });
        write(&row_file, serde_json::to_string_pretty(&saved)?.as_bytes())?;
        rows.push(row);
        // Every finished variant is on disk at once: a long comparison stopped part-way
        // keeps the rows it measured.
        doc = write_outputs(ctx, a, &rows)?;
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
    rows: &[TradeRow],
) -> anyhow::Result<serde_json::Value> {
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
        "voxel layout trade on {} ({}, downscale {}, {} iterations, preset {}, budget {} \
         voxels, {} split)\n\n",
        ctx.info().name,
        a.data.display(),
        a.downscale,
        a.iters,
        a.preset,
        a.max_voxels,
        a.split
    );
    s += "| variant | voxels | grid points | max level | peak device memory | PSNR | SSIM | \
          train | ms/frame |\n";
    s += "|---|---|---|---|---|---|---|---|---|\n";
    for r in rows {
        let name = if r.budget_capped {
            format!(
                "{} (capped by the budget at level {})",
                r.variant, r.max_level
            )
        } else {
            r.variant.clone()
        };
        s += &format!(
            "| {} | {} | {} | {} | {:.0} MiB | {:.2} | {:.4} | {:.0} s | {:.1} |\n",
            name,
            r.voxels,
            r.grid_points,
            r.max_level,
            r.peak_device_memory as f64 / (1u64 << 20) as f64,
            r.psnr,
            r.ssim,
            r.train_s,
            r.ms_per_frame
        );
    }
    s
}

/// PSNR against training time, frame time and voxel count; one series per layout.
fn charts(rows: &[TradeRow], split: &str) -> Vec<Chart> {
    let series = |x: &dyn Fn(&TradeRow) -> f64| -> Vec<Series> {
        let mut out: Vec<Series> = Vec::new();
        for layout in ["adaptive", "uniform"] {
            let points: Vec<Point> = rows
                .iter()
                .filter(|r| r.layout == layout)
                .map(|r| Point::labeled(x(r), r.psnr, r.variant.clone()))
                .collect();
            if !points.is_empty() {
                out.push(Series::new(layout, points));
            }
        }
        out
    };
    let y = format!("{split} PSNR (dB)");
    vec![
        Chart {
            title: "quality vs training time".into(),
            x_label: "training time (s)".into(),
            y_label: y.clone(),
            series: series(&|r| r.train_s),
            markers: true,
            ..Default::default()
        },
        Chart {
            title: "quality vs frame time".into(),
            x_label: "ms per frame".into(),
            y_label: y.clone(),
            series: series(&|r| r.ms_per_frame),
            markers: true,
            ..Default::default()
        },
        Chart {
            title: "quality vs model size".into(),
            x_label: "voxels".into(),
            y_label: y,
            series: series(&|r| r.voxels as f64),
            x_log: true,
            markers: true,
            ..Default::default()
        },
    ]
}
