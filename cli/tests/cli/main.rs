//! The `demo`, `train`, `eval`, `render` and `bench` commands end to end (with
//! validation on).

use std::path::PathBuf;
use std::process::Command;

use tempfile::TempDir;

fn svraster(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_svraster"))
        .arg("--validation")
        .args(args)
        .output()
        .expect("run svraster");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A fresh, empty directory named `svraster-cli-<name>-…`, removed when dropped.
fn tmp(name: &str) -> TempDir {
    tempfile::Builder::new()
        .prefix(&format!("svraster-cli-{name}-"))
        .tempdir()
        .unwrap()
}

/// The demo dataset (square `size`², `[train, val, test]` views) written to `dir`.
fn write_demo(dir: &std::path::Path, size: u32, views: [usize; 3], seed: u64) {
    svraster::data::demo::write_dataset(
        dir,
        &svraster::data::demo::DemoOptions {
            width: size,
            height: size,
            train: views[0],
            val: views[1],
            test: views[2],
            seed,
        },
    )
    .unwrap();
}

/// Every line of a run's stats.jsonl.
fn stats_lines(run: &std::path::Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(run.join("stats.jsonl"))
        .unwrap_or_default()
        .lines()
        .map(|l| serde_json::from_str(l).expect("stats line is JSON"))
        .collect()
}

/// The complete lines of a run's stats.jsonl while it trains (a line being appended is
/// left out), parsed.
fn stats_lines_so_far(run: &std::path::Path) -> Vec<serde_json::Value> {
    let text = std::fs::read_to_string(run.join("stats.jsonl")).unwrap_or_default();
    let complete = text.rfind('\n').map_or("", |i| &text[..i]);
    complete
        .lines()
        .map(|l| serde_json::from_str(l).expect("stats line is JSON"))
        .collect()
}

/// Iterations logged so far in the stats.jsonl of a run that is training.
fn logged_so_far(run: &std::path::Path) -> usize {
    stats_lines_so_far(run)
        .iter()
        .filter(|l| l.get("adapt").is_none())
        .count()
}

/// Iterations logged in a run's stats.jsonl (the adaptive steps' lines left out).
fn logged(run: &std::path::Path) -> Vec<serde_json::Value> {
    stats_lines(run)
        .into_iter()
        .filter(|l| l.get("adapt").is_none())
        .collect()
}

/// `svraster train DATA --out RUN --preset quick --iters N --set grid_level=3` and
/// `extra`: the small runs most command tests start from.
fn train_quick(data: &str, run: &str, iters: &str, extra: &[&str]) -> (bool, String, String) {
    let mut args = vec![
        "train",
        data,
        "--out",
        run,
        "--preset",
        "quick",
        "--iters",
        iters,
        "--set",
        "grid_level=3",
    ];
    args.extend_from_slice(extra);
    svraster(&args)
}

/// A small demo dataset in `dir/name` (no training).
fn small_data(dir: &std::path::Path, name: &str, seed: u64) -> PathBuf {
    let data = dir.join(name);
    write_demo(&data, 24, [6, 2, 1], seed);
    data
}

/// Sets `config.iters` in a run's config.json (turns a finished run into one that
/// `--resume` continues).
fn set_run_iters(run: &std::path::Path, iters: u32) {
    let p = run.join("config.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    v["config"]["iters"] = serde_json::json!(iters);
    std::fs::write(&p, serde_json::to_string_pretty(&v).unwrap()).unwrap();
}

/// The iteration a run's optimizer.safetensors holds (its `iteration` metadata).
fn checkpoint_iter(run: &std::path::Path) -> u64 {
    let b = std::fs::read(run.join("optimizer.safetensors")).unwrap();
    let n = u64::from_le_bytes(b[..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&b[8..8 + n]).unwrap();
    header["__metadata__"]["iteration"]
        .as_str()
        .unwrap()
        .parse()
        .unwrap()
}

/// A unit quaternion `[w, x, y, z]` of a rotation matrix (rows).
fn quat(r: [[f64; 3]; 3]) -> [f64; 4] {
    let t = r[0][0] + r[1][1] + r[2][2];
    let q = if t > 0.0 {
        let s = 0.5 / (t + 1.0).sqrt();
        [
            0.25 / s,
            (r[2][1] - r[1][2]) * s,
            (r[0][2] - r[2][0]) * s,
            (r[1][0] - r[0][1]) * s,
        ]
    } else if r[0][0] > r[1][1] && r[0][0] > r[2][2] {
        let s = 2.0 * (1.0 + r[0][0] - r[1][1] - r[2][2]).sqrt();
        [
            (r[2][1] - r[1][2]) / s,
            0.25 * s,
            (r[0][1] + r[1][0]) / s,
            (r[0][2] + r[2][0]) / s,
        ]
    } else if r[1][1] > r[2][2] {
        let s = 2.0 * (1.0 + r[1][1] - r[0][0] - r[2][2]).sqrt();
        [
            (r[0][2] - r[2][0]) / s,
            (r[0][1] + r[1][0]) / s,
            0.25 * s,
            (r[1][2] + r[2][1]) / s,
        ]
    } else {
        let s = 2.0 * (1.0 + r[2][2] - r[0][0] - r[1][1]).sqrt();
        [
            (r[1][0] - r[0][1]) / s,
            (r[0][2] + r[2][0]) / s,
            (r[1][2] + r[2][1]) / s,
            0.25 * s,
        ]
    };
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    q.map(|v| v / n)
}

/// A `python3` with numpy: Debian's own first (a pyenv or venv earlier on PATH may lack
/// it), else the one on PATH (a GPU image's /usr/bin/python3 may lack numpy while its
/// own Python has it). Falls back to Debian's, whose failure names the fix.
fn python() -> &'static str {
    let has_numpy = |py: &str| {
        Command::new(py)
            .args(["-c", "import numpy"])
            .output()
            .is_ok_and(|o| o.status.success())
    };
    ["/usr/bin/python3", "python3"]
        .into_iter()
        .find(|py| has_numpy(py))
        .unwrap_or("/usr/bin/python3")
}

/// tools/ply_read.py's JSON summary of a PLY file (an independent numpy reader) and the
/// vertex property names.
fn ply_info(path: &std::path::Path) -> (serde_json::Value, Vec<String>) {
    let py = Command::new(python())
        .arg(concat!(env!("CARGO_MANIFEST_DIR"), "/../tools/ply_read.py"))
        .arg(path)
        .output()
        .expect("run python3 (tools/setup.sh installs python3-numpy)");
    assert!(
        py.status.success(),
        "tools/ply_read.py failed (needs python3-numpy: tools/setup.sh): {}",
        String::from_utf8_lossy(&py.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&py.stdout).unwrap();
    let props = v["properties"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_str().unwrap().to_string())
        .collect();
    (v, props)
}

mod defects;
mod demo_render_train;
mod export_bench;
mod features;
mod field;
mod import;
mod inputs;
mod outputs;
mod resume_signals;
mod view;
