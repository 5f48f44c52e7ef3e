//! `bench trade`'s outputs: the Pareto fronts, trade.md, trade.json and trade.png, and
//! what a finished run's files say (peak device memory, budget reached).

use std::path::Path;

use anyhow::Context as _;
use svraster::gpu::Context;

use super::super::plot::{save_row, Chart, Point, Series};
use super::{TradeArgs, TradeRow};

/// Marks the two Pareto fronts: a row is on a front when no other row has a cost at most
/// its own and a PSNR at least its own, one of the two strictly better.
pub(super) fn mark_fronts(rows: &mut [TradeRow]) {
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

/// Writes `trade.md`, `trade.json` and `trade.png` for the rows so far; returns the JSON.
pub(super) fn write_outputs(
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

pub(super) fn read_config(run: &Path) -> anyhow::Result<serde_json::Value> {
    let p = run.join("config.json");
    let text =
        std::fs::read_to_string(&p).with_context(|| format!("cannot read {}", p.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{} is not JSON", p.display()))
}

/// The largest `device_memory` any line of a run's stats.jsonl records.
pub(super) fn peak_device_memory(run: &Path) -> anyhow::Result<u64> {
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
pub(super) fn budget_capped(run: &Path) -> anyhow::Result<bool> {
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

pub(super) fn write(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    Ok(svraster::fsio::write_atomic(path, bytes)?)
}

/// The markdown table of the rows.
pub(super) fn table(ctx: &Context, a: &TradeArgs, rows: &[TradeRow]) -> String {
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
