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

#[test]
fn demo_then_render_and_bench() {
    let dir = tmp("demo");
    let d = dir.path().to_str().unwrap();
    let (ok, out, err) = svraster(&[
        "demo", "--out", d, "--size", "32", "--level", "4", "--iters", "60",
    ]);
    assert!(ok, "demo failed: {out}\n{err}");
    // Trained, evaluated and rendered (quality is asserted by tests/train.rs).
    let psnr: f64 = out
        .split("PSNR ")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .and_then(|s| s.parse().ok())
        .expect("PSNR in the demo output");
    assert!(psnr > 12.0, "demo PSNR {psnr}: {out}");
    assert!(out.contains("SSIM"), "{out}");
    for f in [
        "config.json",
        "stats.jsonl",
        "model.safetensors",
        "optimizer.safetensors",
    ] {
        assert!(dir.path().join("run").join(f).is_file(), "missing run/{f}");
    }
    // The training curves (PSNR, loss, voxels: three panels).
    let curves =
        image::open(dir.path().join("run/training.png")).expect("run/training.png decodes");
    assert!(
        curves.width() >= 3 * curves.height() / 2,
        "{:?}",
        (curves.width(), curves.height())
    );
    for i in 0..10 {
        assert!(dir.path().join(format!("renders/r_{i}.png")).is_file());
        assert!(dir
            .path()
            .join(format!("renders/r_{i}_depth.png"))
            .is_file());
        assert!(dir
            .path()
            .join(format!("renders/r_{i}_compare.png"))
            .is_file());
    }
    // Metric depth: 16-bit counts × the sidecar's scale are camera depths inside the
    // sidecar's range (0: no surface); the normal map is black where there is no surface.
    let side: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("renders/r_0_depth.json")).unwrap(),
    )
    .unwrap();
    let scale = side["scale"].as_f64().unwrap();
    let (lo, hi) = (
        side["min_depth"].as_f64().unwrap(),
        side["max_depth"].as_f64().unwrap(),
    );
    assert!(scale > 0.0 && 0.0 < lo && lo <= hi, "{side}");
    let d16 = image::open(dir.path().join("renders/r_0_depth16.png"))
        .unwrap()
        .to_luma16();
    let alpha_px: Vec<&image::Luma<u16>> = d16.pixels().filter(|p| p.0[0] > 0).collect();
    assert!(!alpha_px.is_empty() && alpha_px.len() < (d16.width() * d16.height()) as usize);
    for p in alpha_px {
        let z = f64::from(p.0[0]) * scale;
        assert!(
            z >= lo - scale && z <= hi + scale,
            "{z} outside [{lo}, {hi}]"
        );
    }
    let nrm = image::open(dir.path().join("renders/r_0_normal.png"))
        .unwrap()
        .to_rgb8();
    for (x, y, p) in d16.enumerate_pixels() {
        if p.0[0] == 0 {
            // No surface (alpha ≤ 0.5): the normal colour is at most half its value.
            assert!(nrm.get_pixel(x, y).0.iter().all(|&c| c <= 128), "({x},{y})");
        }
    }
    assert_eq!(nrm.get_pixel(0, 0).0, [0, 0, 0], "the corner is background");

    let r = dir.path().join("val_renders");
    let (ok, out, err) = svraster(&[
        "render",
        dir.path().join("run").to_str().unwrap(), // a run directory holding model.safetensors
        "--data",
        dir.path().join("data").to_str().unwrap(),
        "--split",
        "val",
        "--downscale",
        "2",
        "--out",
        r.to_str().unwrap(),
        "--normal",
        "--compare",
        "--ss",
        "1.5",
    ]);
    assert!(ok, "render failed: {out}\n{err}");
    let img = image::open(r.join("r_0.png"))
        .expect("rendered PNG")
        .to_rgb8();
    assert_eq!(img.dimensions(), (16, 16));
    assert!(r.join("r_0_normal.png").is_file());
    // --compare: the photo (as the split loads it) on the left, the render on the right.
    let both = image::open(r.join("r_0_compare.png")).unwrap().to_rgb8();
    assert_eq!(both.dimensions(), (32, 16));
    let val = svraster::data::load_split(&dir.path().join("data"), "val", 2.0, [1.0; 3]).unwrap();
    for y in 0..16u32 {
        for x in 0..16u32 {
            assert_eq!(
                both.get_pixel(x + 16, y),
                img.get_pixel(x, y),
                "render ({x},{y})"
            );
            let photo = val.frames[0].rgb[(y * 16 + x) as usize];
            let got = both.get_pixel(x, y).0;
            for c in 0..3 {
                let want = (photo[c].clamp(0.0, 1.0) * 255.0).round();
                assert!(
                    (f32::from(got[c]) - want).abs() <= 1.0,
                    "photo ({x},{y}) {c}"
                );
            }
        }
    }

    // Two frames with one file stem get distinct outputs (none overwrites the other).
    let tj = dir.path().join("data/transforms_val.json");
    let mut t: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&tj).unwrap()).unwrap();
    let first = t["frames"][0].clone();
    t["frames"].as_array_mut().unwrap().push(first);
    let n = t["frames"].as_array().unwrap().len();
    std::fs::write(&tj, t.to_string()).unwrap();
    let r2 = dir.path().join("dup_renders");
    let (ok, _, err) = svraster(&[
        "render",
        dir.path().join("run").to_str().unwrap(),
        "--data",
        dir.path().join("data").to_str().unwrap(),
        "--split",
        "val",
        "--out",
        r2.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(r2.join("r_0_0.png").is_file() && r2.join(format!("r_0_{}.png", n - 1)).is_file());
    assert!(!r2.join("r_0.png").exists());
    assert_eq!(std::fs::read_dir(&r2).unwrap().count(), n);

    let (ok, out, err) = svraster(&[
        "bench",
        "render",
        dir.path().join("run/model.safetensors").to_str().unwrap(),
        "--data",
        dir.path().join("data").to_str().unwrap(),
        "--views",
        "2",
        "--runs",
        "1",
        "--json",
    ]);
    assert!(ok, "bench failed: {out}\n{err}");
    let v: serde_json::Value = serde_json::from_str(out.trim()).expect("bench JSON");
    assert!(v["median_ms"].as_f64().unwrap() > 0.0);
    assert!(v["entries_median"].as_f64().unwrap() > 0.0);
    assert!(v["stages_median_ms"]["composite"].as_f64().is_some());
}

#[test]
fn render_rejects_bad_input_with_one_clear_error() {
    let dir = tmp("bad");
    let d = dir.path().to_str().unwrap();
    let (ok, _, err) = svraster(&["render", d, "--data", d, "--out", d]);
    assert!(!ok && err.contains("model.safetensors"), "{err}");

    let bad = dir.path().join("bad.safetensors");
    std::fs::write(&bad, b"\x10\x00\x00\x00\x00\x00\x00\x00{not json}      ").unwrap();
    let (ok, _, err) = svraster(&["render", bad.to_str().unwrap(), "--data", d, "--out", d]);
    assert!(!ok && err.contains("bad.safetensors"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "one error line: {err}");
}

/// Every line of a run's stats.jsonl.
fn stats_lines(run: &std::path::Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(run.join("stats.jsonl"))
        .unwrap_or_default()
        .lines()
        .map(|l| serde_json::from_str(l).expect("stats line is JSON"))
        .collect()
}

/// Iterations logged in a run's stats.jsonl (the adaptive steps' lines left out).
fn logged(run: &std::path::Path) -> Vec<serde_json::Value> {
    stats_lines(run)
        .into_iter()
        .filter(|l| l.get("adapt").is_none())
        .collect()
}

#[test]
fn train_interrupt_resume_eval_and_bench() {
    let dir = tmp("train");
    let data = dir.path().join("data");
    // A small dataset (the demo generator, no training).
    write_demo(&data, 24, [8, 3, 2], 1);
    let ds = data.to_str().unwrap();
    let run = dir.path().join("run");
    let rs = run.to_str().unwrap();
    let args = [
        "train",
        ds,
        "--out",
        rs,
        "--preset",
        "quick",
        "--iters",
        "400",
        "--set",
        "grid_level=3",
        "--set",
        "log_every=5",
        "--seed",
        "4",
    ];
    // Ctrl-C: SIGINT after the first logged steps saves the run and exits with 130.
    let child = Command::new(env!("CARGO_BIN_EXE_svraster"))
        .arg("--validation")
        .args(args)
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = std::time::Instant::now();
    while logged(&run).len() < 3 {
        assert!(t0.elapsed().as_secs() < 300, "training did not start");
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    let st = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(st.success());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{err}");
    assert!(err.contains("--resume"), "{err}");
    assert!(run.join("model.safetensors").is_file() && run.join("optimizer.safetensors").is_file());
    let cfg: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("config.json")).unwrap()).unwrap();
    assert_eq!(cfg["config"]["iters"], 400);
    assert_eq!(cfg["config"]["grid_level"], 3);
    assert_eq!(
        cfg["schedule"]["sh_degree_up"],
        serde_json::json!([20, 40, 60])
    );
    let stopped = logged(&run).last().unwrap()["iter"].as_u64().unwrap();

    // Starting again without --resume refuses to overwrite; with --set it refuses too.
    let (ok, _, err) = svraster(&args);
    assert!(!ok && err.contains("--resume"), "{err}");
    let (ok, _, err) = svraster(&["train", ds, "--out", rs, "--resume", "--iters", "5"]);
    assert!(!ok && err.contains("--resume"), "{err}");
    // Resume to the end.
    let (ok, out, err) = svraster(&["train", ds, "--out", rs, "--resume"]);
    assert!(ok, "resume failed: {out}\n{err}");
    let lines = logged(&run);
    let iters: Vec<u64> = lines.iter().map(|l| l["iter"].as_u64().unwrap()).collect();
    assert_eq!(*iters.last().unwrap(), 400);
    assert!(
        iters.windows(2).all(|w| w[0] < w[1] || w[1] == stopped + 1),
        "{iters:?}"
    );
    for k in [
        "loss",
        "psnr",
        "ssim",
        "it_per_s",
        "voxels",
        "grid_points",
        "device_memory",
    ] {
        assert!(lines.last().unwrap()[k].is_number(), "stats lack {k}");
    }
    // The adaptive layout (the default) logged its steps: counts, grid points, memory.
    let adapt: Vec<serde_json::Value> = stats_lines(&run)
        .into_iter()
        .filter_map(|l| l.get("adapt").cloned())
        .collect();
    assert!(!adapt.is_empty(), "no adaptive steps logged");
    for a in &adapt {
        for k in [
            "iter",
            "voxels_before",
            "pruned",
            "subdivided",
            "voxels",
            "grid_points",
            "device_memory",
        ] {
            assert!(a[k].is_number(), "adapt line lacks {k}: {a}");
        }
        assert_eq!(
            a["voxels"].as_u64().unwrap(),
            a["voxels_before"].as_u64().unwrap() - a["pruned"].as_u64().unwrap()
                + 7 * a["subdivided"].as_u64().unwrap(),
            "{a}"
        );
        assert!(a["device_memory"].as_u64().unwrap() > 0);
    }
    let (ok, _, err) = svraster(&["train", ds, "--out", rs, "--resume"]);
    assert!(!ok && err.contains("already completed"), "{err}");

    // eval --json
    let (ok, out, err) = svraster(&["eval", rs, "--data", ds, "--split", "val", "--json"]);
    assert!(ok, "eval failed: {out}\n{err}");
    let v: serde_json::Value = serde_json::from_str(out.trim()).expect("eval JSON");
    assert_eq!(v["views"], 3);
    let psnr = v["psnr"].as_f64().unwrap();
    let ssim = v["ssim"].as_f64().unwrap();
    assert!(psnr > 10.0 && (0.0..=1.0).contains(&ssim), "{v}");
    assert!(v["ms_per_frame"].as_f64().unwrap() > 0.0);
    // Renders at the model's supersampling (the quick preset trains without), unless
    // --ss says otherwise; a model trained with ss 1.5 renders at 1.5 by default.
    assert_eq!(v["supersample"], 1.0, "{v}");
    let mut scene = svraster::scene::checkpoint::load(&run.join("model.safetensors")).unwrap();
    scene.supersample = 1.5;
    let ss_model = dir.path().join("ss15.safetensors");
    svraster::scene::checkpoint::save(&scene, &ss_model).unwrap();
    let sm = ss_model.to_str().unwrap();
    for (extra, want) in [(None, 1.5), (Some("1"), 1.0), (Some("2"), 2.0)] {
        let mut a = vec!["eval", sm, "--data", ds, "--split", "val", "--json"];
        if let Some(x) = extra {
            a.extend(["--ss", x]);
        }
        let (ok, out, err) = svraster(&a);
        assert!(ok, "eval failed: {out}\n{err}");
        let v: serde_json::Value = serde_json::from_str(out.trim()).expect("eval JSON");
        assert_eq!(v["supersample"], want, "{extra:?}: {v}");
    }

    // bench train
    let (ok, out, err) = svraster(&[
        "bench",
        "train",
        ds,
        "--preset",
        "quick",
        "--set",
        "grid_level=3",
        "--iters",
        "3",
        "--warmup",
        "1",
        "--json",
    ]);
    assert!(ok, "bench train failed: {out}\n{err}");
    let v: serde_json::Value = serde_json::from_str(out.trim()).expect("bench JSON");
    assert!(v["median_ms_per_iter"].as_f64().unwrap() > 0.0);
    // The full-model regime: the timed iterations used the final SH degree.
    assert_eq!(v["sh_degree"], 3, "{v}");
    for s in [
        "preprocess",
        "sort",
        "forward",
        "losses",
        "backward",
        "optimizer",
    ] {
        assert!(
            v["stages_median_ms"][s].as_f64().is_some(),
            "stage {s} missing: {v}"
        );
    }
}

#[test]
fn train_rejects_bad_input_with_one_clear_error() {
    let dir = tmp("trainbad");
    let data = dir.path().join("data");
    let d = data.to_str().unwrap();
    let out = dir.path().join("run");
    let o = out.to_str().unwrap();
    // Missing dataset.
    let (ok, _, err) = svraster(&["train", d, "--out", o]);
    assert!(!ok && err.contains("transforms_*.json"), "{err}");
    assert_eq!(err.trim().lines().count(), 2, "{err}"); // "loading …" + the error
    write_demo(&data, 16, [3, 1, 1], 1);
    // Bad --set key and value, unknown preset.
    let (ok, _, err) = svraster(&["train", d, "--out", o, "--set", "gridlevel=3"]);
    assert!(!ok && err.contains("unknown config key"), "{err}");
    let (ok, _, err) = svraster(&["train", d, "--out", o, "--set", "grid_level=99"]);
    assert!(!ok && err.contains("grid_level"), "{err}");
    let (ok, _, err) = svraster(&["train", d, "--out", o, "--preset", "fast"]);
    assert!(!ok && err.contains("unknown preset"), "{err}");
    assert!(
        !out.join("config.json").exists(),
        "nothing may be written on bad input"
    );
    // An odd-sized training image.
    let img = image::RgbaImage::new(15, 16);
    img.save(data.join("train/r_1.png")).unwrap();
    let (ok, _, err) = svraster(&["train", d, "--out", o, "--preset", "quick"]);
    assert!(!ok && err.contains("r_1"), "{err}");
    assert!(!out.join("model.safetensors").exists());
    // Corrupt optimizer state on resume.
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("config.json"), "{\"config\": {}}").unwrap();
    std::fs::write(out.join("model.safetensors"), b"junk").unwrap();
    std::fs::write(out.join("optimizer.safetensors"), b"junk").unwrap();
    let (ok, _, err) = svraster(&["train", d, "--out", o, "--resume"]);
    assert!(
        !ok && err.contains("optimizer.safetensors") && err.contains("corrupt"),
        "{err}"
    );
    // A run directory of an older version (optimizer.bin) is refused with what to do.
    std::fs::remove_file(out.join("optimizer.safetensors")).unwrap();
    std::fs::write(out.join("optimizer.bin"), b"SVRVKOPT").unwrap();
    let (ok, _, err) = svraster(&["train", d, "--out", o, "--resume"]);
    assert!(
        !ok && err.contains("cannot resume a run from an older version"),
        "{err}"
    );
}

#[test]
fn bench_trade_writes_table_json_and_chart() {
    let dir = tmp("trade");
    let data = dir.path().join("data");
    write_demo(&data, 24, [8, 2, 1], 3);
    let out = dir.path().join("trade");
    // The same comparison both times (the second run adds --reuse).
    let trade = |extra: &[&str]| {
        let mut args = vec![
            "bench",
            "trade",
            data.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--downscale",
            "1",
            "--iters",
            "160",
            "--max-voxels",
            "3000",
            "--uniform-levels",
            "3,4",
            "--set",
            "grid_level=3",
            "--set",
            "subdivide_percent=0.3",
            // A 160-iteration run: subdivide anyway (the default waits for 500 to follow),
            // at steps 5 % of the run apart (the default: at least 100).
            "--set",
            "subdivide_min_after=0",
            "--set",
            "adapt_min_spacing=0",
            "--json",
        ];
        args.extend_from_slice(extra);
        svraster(&args)
    };
    let (ok, stdout, err) = trade(&[]);
    assert!(ok, "bench trade failed: {stdout}\n{err}");
    let doc: serde_json::Value = serde_json::from_str(stdout.trim()).expect("trade JSON");
    let rows = doc["rows"].as_array().unwrap();
    let names: Vec<&str> = rows
        .iter()
        .map(|r| r["variant"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["adaptive", "uniform-3", "uniform-4"]);
    for r in rows {
        let voxels = r["voxels"].as_u64().unwrap();
        assert!(voxels > 0 && voxels <= 3000, "{r}");
        assert!(r["psnr"].as_f64().unwrap() > 10.0, "{r}");
        assert!((0.0..=1.0).contains(&r["ssim"].as_f64().unwrap()), "{r}");
        assert!(r["train_s"].as_f64().unwrap() > 0.0 && r["ms_per_frame"].as_f64().unwrap() > 0.0);
        assert!(r["peak_device_memory"].as_u64().unwrap() > 0, "{r}");
    }
    // uniform-3 never subdivides; uniform-4 subdivides the kept voxels once (as many as
    // the budget allows).
    assert_eq!(rows[1]["max_level"], 3);
    assert_eq!(rows[2]["max_level"], 4);
    assert_eq!(rows[1]["budget_capped"], false);
    let md = std::fs::read_to_string(out.join("trade.md")).unwrap();
    assert_eq!(
        md.lines().filter(|l| l.starts_with("| uniform-")).count(),
        2,
        "{md}"
    );
    let png = image::open(out.join("trade.png")).expect("trade.png decodes");
    assert!(png.width() >= 640 && png.height() >= 480);

    // --reuse keeps the variants an identical comparison finished and retrains one whose
    // saved parameters differ (here: uniform-3's row claims another iteration count).
    let row_file = out.join("uniform-3").join("trade_row.json");
    let mut saved: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&row_file).unwrap()).unwrap();
    assert_eq!(saved["key"]["iters"], 160);
    saved["key"]["iters"] = 999.into();
    std::fs::write(&row_file, saved.to_string()).unwrap();
    let (ok, stdout2, err2) = trade(&["--reuse"]);
    assert!(ok, "bench trade --reuse failed: {stdout2}\n{err2}");
    let reused: Vec<&str> = err2
        .lines()
        .filter(|l| l.contains("reusing the finished run"))
        .collect();
    assert_eq!(reused.len(), 2, "{err2}");
    assert!(reused[0].starts_with("== adaptive ==") && reused[1].starts_with("== uniform-4 =="));
    assert!(
        err2.contains("replacing the previous run") && err2.contains("== uniform-3 (2 of 3) ==")
    );
    let doc2: serde_json::Value = serde_json::from_str(stdout2.trim()).expect("trade JSON");
    let rows2 = doc2["rows"].as_array().unwrap();
    assert_eq!(rows2.len(), 3);
    // Reused rows are the saved ones, bit for bit (timings included).
    assert_eq!(rows2[0], rows[0]);
    assert_eq!(rows2[2], rows[2]);
    // The retrained variant is a fresh, complete row.
    assert_eq!(rows2[1]["variant"], "uniform-3");
    assert_eq!(rows2[1]["max_level"], 3);
    let v = rows2[1]["voxels"].as_u64().unwrap();
    assert!(v > 0 && v <= 3000, "{}", rows2[1]);
    let saved: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&row_file).unwrap()).unwrap();
    assert_eq!(saved["key"]["iters"], 160);

    // A uniform variant the budget stops short of its level is marked as such.
    let capped_out = dir.path().join("capped");
    let (ok, stdout3, err3) = svraster(&[
        "bench",
        "trade",
        data.to_str().unwrap(),
        "--out",
        capped_out.to_str().unwrap(),
        "--iters",
        "160",
        "--max-voxels",
        "1500",
        "--uniform-levels",
        "5",
        "--set",
        "grid_level=3",
        "--set",
        "subdivide_min_after=0",
        "--set",
        "adapt_min_spacing=0",
        "--json",
    ]);
    assert!(ok, "{err3}");
    let doc3: serde_json::Value = serde_json::from_str(stdout3.trim()).expect("trade JSON");
    let u5 = &doc3["rows"][1];
    assert_eq!(u5["variant"], "uniform-5");
    assert_eq!(u5["budget_capped"], true, "{u5}");
    assert!(u5["max_level"].as_u64().unwrap() < 5, "{u5}");
    let md = std::fs::read_to_string(capped_out.join("trade.md")).unwrap();
    assert!(
        md.contains("uniform-5 (capped by the budget at level"),
        "{md}"
    );
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

/// `--resume` continues the same run (its data, downscale and preset) and refuses
/// anything else; a checkpoint that cannot be written leaves the previous one resumable.
#[test]
fn resume_is_the_same_run_and_checkpoints_are_atomic() {
    let dir = tmp("resume-same");
    let data = small_data(dir.path(), "data", 1);
    let other = small_data(dir.path(), "other", 2);
    let (ds, os) = (data.to_str().unwrap(), other.to_str().unwrap());
    let run = dir.path().join("run");
    let rs = run.to_str().unwrap();
    let (ok, _, err) = svraster(&[
        "train",
        ds,
        "--out",
        rs,
        "--preset",
        "quick",
        "--iters",
        "20",
        "--downscale",
        "2",
        "--set",
        "grid_level=3",
    ]);
    assert!(ok, "{err}");
    set_run_iters(&run, 30);
    for (args, needle) in [
        (vec!["train", os, "--out", rs, "--resume"], "trains on"),
        (
            vec![
                "train",
                ds,
                "--out",
                rs,
                "--resume",
                "--preset",
                "synthetic",
            ],
            "--preset quick",
        ),
        (
            vec!["train", ds, "--out", rs, "--resume", "--downscale", "1"],
            "--downscale 2",
        ),
    ] {
        let (ok, _, err) = svraster(&args);
        assert!(!ok && err.contains(needle), "{args:?}: {err}");
    }
    assert_eq!(checkpoint_iter(&run), 20);
    // Resumes at the run's own downscale (12×12 images).
    let (ok, _, err) = svraster(&["train", ds, "--out", rs, "--resume"]);
    assert!(ok && err.contains("12×12"), "{err}");
    assert_eq!(checkpoint_iter(&run), 30);

    // A checkpoint write that fails (here: the optimizer's temporary path is taken by a
    // directory; on a full disk it is ENOSPC) fails the run with a clear error and leaves
    // the previous pair as it was.
    set_run_iters(&run, 40);
    let blocker = run.join("optimizer.safetensors.tmp");
    std::fs::create_dir(&blocker).unwrap();
    let model_before = std::fs::read(run.join("model.safetensors")).unwrap();
    let (ok, _, err) = svraster(&["train", ds, "--out", rs, "--resume"]);
    assert!(!ok && err.contains("previous checkpoint"), "{err}");
    assert_eq!(checkpoint_iter(&run), 30);
    assert!(
        std::fs::read(run.join("model.safetensors")).unwrap() == model_before,
        "a failed checkpoint replaced model.safetensors"
    );
    assert!(!run.join("model.safetensors.tmp").exists());
    std::fs::remove_dir(&blocker).unwrap();
    let (ok, _, err) = svraster(&["train", ds, "--out", rs, "--resume"]);
    assert!(ok, "{err}");
    assert_eq!(checkpoint_iter(&run), 40);

    // A save stopped between its two renames (new optimizer, model still in .tmp) is
    // completed by --resume.
    set_run_iters(&run, 50);
    let model = run.join("model.safetensors");
    std::fs::rename(&model, run.join("model.safetensors.tmp")).unwrap();
    std::fs::write(&model, &model_before).unwrap(); // the older model
    let (ok, _, err) = svraster(&["train", ds, "--out", rs, "--resume"]);
    assert!(ok && err.contains("completed the checkpoint"), "{err}");
    assert_eq!(checkpoint_iter(&run), 50);

    // eval/render default to the run's downscale and to a split that exists.
    std::fs::remove_file(data.join("transforms_test.json")).unwrap();
    let (ok, out, err) = svraster(&["eval", rs, "--data", ds, "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    assert_eq!(
        (v["split"].as_str(), v["width"].as_u64()),
        (Some("val"), Some(12)),
        "{v}"
    );
    let r = dir.path().join("renders");
    let (ok, _, err) = svraster(&["render", rs, "--data", ds, "--out", r.to_str().unwrap()]);
    assert!(ok, "{err}");
    let img = image::open(r.join("r_0.png")).unwrap();
    assert_eq!((img.width(), img.height()), (12, 12));
}

/// SIGTERM saves and exits like Ctrl-C; a second process cannot train into a locked run
/// directory; after a crash, --resume drops the log lines past the checkpoint.
#[test]
fn sigterm_saves_runs_are_locked_and_stats_are_truncated_on_resume() {
    let dir = tmp("sigterm");
    let data = small_data(dir.path(), "data", 3);
    let ds = data.to_str().unwrap();
    let run = dir.path().join("run");
    let rs = run.to_str().unwrap();
    let child = Command::new(env!("CARGO_BIN_EXE_svraster"))
        .args([
            "train",
            ds,
            "--out",
            rs,
            "--preset",
            "quick",
            "--iters",
            "100000",
            "--set",
            "grid_level=3",
            "--set",
            "log_every=5",
            "--set",
            "checkpoint_every=0",
        ])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = std::time::Instant::now();
    while logged(&run).len() < 2 {
        assert!(t0.elapsed().as_secs() < 300, "training did not start");
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    // Locked: a second process fails at once, whatever it asks.
    let (ok, _, err) = svraster(&["train", ds, "--out", rs, "--resume"]);
    assert!(!ok && err.contains("in use"), "{err}");
    let st = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(st.success());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{err}");
    assert!(
        err.contains("stopping after this step") && err.contains("--resume"),
        "{err}"
    );
    let saved = checkpoint_iter(&run);
    assert!(saved >= 5, "saved at {saved}");

    // A crash after the checkpoint leaves lines past it; --resume drops them.
    let mut log = std::fs::read_to_string(run.join("stats.jsonl")).unwrap();
    log.push_str(&format!("{{\"iter\":{},\"psnr\":1}}\n", saved + 5));
    log.push_str(&format!("{{\"adapt\":{{\"iter\":{}}}}}\n", saved + 3));
    std::fs::write(run.join("stats.jsonl"), log).unwrap();
    set_run_iters(&run, saved as u32 + 10);
    let (ok, _, err) = svraster(&["train", ds, "--out", rs, "--resume"]);
    assert!(ok, "{err}");
    let iters: Vec<u64> = stats_lines(&run)
        .iter()
        .map(|l| {
            l["iter"]
                .as_u64()
                .or_else(|| l["adapt"]["iter"].as_u64())
                .unwrap()
        })
        .collect();
    assert!(iters.windows(2).all(|w| w[0] <= w[1]), "{iters:?}");
    let logged_iters: Vec<u64> = logged(&run)
        .iter()
        .map(|l| l["iter"].as_u64().unwrap())
        .collect();
    assert!(
        logged_iters.windows(2).all(|w| w[0] < w[1]),
        "{logged_iters:?}"
    );
}

/// `demo --out` never deletes what it did not create, and checks its arguments before
/// writing anything.
#[test]
fn demo_keeps_directories_it_did_not_make() {
    let dir = tmp("demo-foreign");
    let run = dir.path().join("run");
    std::fs::create_dir_all(&run).unwrap();
    std::fs::write(run.join("precious.txt"), b"mine").unwrap();
    let d = dir.path().to_str().unwrap();
    let (ok, _, err) = svraster(&["demo", "--out", d, "--size", "16", "--iters", "5"]);
    assert!(!ok && err.contains("not made by"), "{err}");
    assert_eq!(std::fs::read(run.join("precious.txt")).unwrap(), b"mine");
    assert!(!dir.path().join("data").exists(), "nothing written");

    // A demo directory from before the mark (its run trained on its own data/) is the
    // demo's: it is replaced.
    let legacy = dir.path().join("legacy");
    std::fs::create_dir_all(legacy.join("run")).unwrap();
    std::fs::create_dir_all(legacy.join("data")).unwrap();
    let data_abs = std::fs::canonicalize(legacy.join("data")).unwrap();
    std::fs::write(
        legacy.join("run/config.json"),
        serde_json::json!({ "data": data_abs }).to_string(),
    )
    .unwrap();
    let l = legacy.to_str().unwrap();
    let (ok, _, err) = svraster(&[
        "demo", "--out", l, "--size", "16", "--iters", "5", "--level", "3",
    ]);
    assert!(ok, "{err}");
    assert!(
        legacy.join(".svraster-demo").is_file() && legacy.join("run/model.safetensors").is_file()
    );

    let fresh = dir.path().join("fresh");
    let f = fresh.to_str().unwrap();
    let (ok, _, err) = svraster(&["demo", "--out", f, "--level", "0", "--iters", "5"]);
    assert!(!ok && err.contains("grid_level"), "{err}");
    assert!(!fresh.exists(), "a rejected demo wrote {}", fresh.display());
}

/// `bench sort` with more keys than the device (or host) can hold is one clear error.
#[test]
fn bench_sort_too_large_is_a_clear_error() {
    let (ok, _, err) = svraster(&["bench", "sort", "--n", "4000000000", "--runs", "5"]);
    assert!(
        !ok && err.contains("--n 4000000000") && err.contains("use"),
        "{err}"
    );
    assert_eq!(err.trim().lines().count(), 1, "one error line: {err}");
}

/// A voxel budget below the starting grid is refused before training (not a run that
/// silently never subdivides), and leaves no run behind.
#[test]
fn train_refuses_a_budget_below_the_starting_grid() {
    let dir = tmp("budget-small");
    let data = small_data(dir.path(), "data", 4);
    let run = dir.path().join("run");
    let (ok, _, err) = svraster(&[
        "train",
        data.to_str().unwrap(),
        "--out",
        run.to_str().unwrap(),
        "--preset",
        "quick",
        "--iters",
        "30",
        "--set",
        "grid_level=3",
        "--max-voxels",
        "10",
    ]);
    assert!(
        !ok && err.contains("voxel budget (10)") && err.contains("--max-voxels"),
        "{err}"
    );
    assert!(!run.join("model.safetensors").exists() && !run.join("config.json").exists());
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

/// A COLMAP capture (the demo scene's views as photos in images_2/, a PINHOLE camera
/// given for twice their size) through train → eval → resume with the data options:
/// `--images` and `--holdout` shape the run, are saved in config.json and reused by
/// `eval`; a resume that reads the data differently is refused; Blender data refuses
/// capture options.
#[test]
fn colmap_capture_train_eval_with_data_options() {
    use svraster::data::colmap::{self, ColmapCamera, ColmapImage, Reconstruction};
    use svraster::data::lens::CameraModel;
    let demo = tmp("cap-demo");
    write_demo(demo.path(), 24, [16, 1, 1], 5);
    let ds = svraster::data::load_split(demo.path(), "train", 1.0, [0.0; 3]).unwrap();
    let dir = tmp("cap");
    std::fs::create_dir_all(dir.path().join("images_2")).unwrap();
    std::fs::create_dir_all(dir.path().join("sparse/0")).unwrap();
    let c = &ds.frames[0].camera;
    let mut rec = Reconstruction::default();
    rec.cameras.insert(
        1,
        ColmapCamera {
            id: 1,
            model: CameraModel::Pinhole,
            width: 48,
            height: 48,
            params: vec![2.0 * c.fx, 2.0 * c.fy, 2.0 * c.cx, 2.0 * c.cy],
        },
    );
    for (k, f) in ds.frames.iter().enumerate() {
        let name = format!("shot_{k}.png");
        svraster::data::image::save_rgb_png(
            &dir.path().join("images_2").join(&name),
            24,
            24,
            &f.rgb,
        )
        .unwrap();
        // World-to-camera: R = c2w_Rᵀ, t = −R·centre.
        let r: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| f.camera.c2w[j][i]));
        let o = f.camera.origin();
        let t = std::array::from_fn(|i| -(r[i][0] * o[0] + r[i][1] * o[1] + r[i][2] * o[2]));
        rec.images.insert(
            k as u32 + 1,
            ColmapImage {
                id: k as u32 + 1,
                qvec: quat(r),
                tvec: t,
                camera_id: 1,
                name,
                points2d: Vec::new(),
            },
        );
    }
    colmap::write_bin(&dir.path().join("sparse/0"), &rec).unwrap();
    let run = tmp("cap-run");
    let (d, r) = (dir.path().to_str().unwrap(), run.path().to_str().unwrap());
    let (ok, _, err) = svraster(&[
        "train",
        d,
        "--out",
        r,
        "--iters",
        "30",
        "--images",
        "images_2",
        "--holdout",
        "4",
        "--set",
        "grid_level=3",
        "--set",
        "outside_level=1",
        "--set",
        "ss=1",
        "--set",
        "sh_degree=1",
    ]);
    assert!(ok, "{err}");
    assert!(err.contains("main region (camera_median"), "{err}");
    assert!(err.contains("on 12 views of 24×24"), "{err}");
    // The voxel split reported at the end: the main region is [-1, 1]³ in the model's
    // frame; counted here from the saved model by the voxels' corners.
    let model = svraster::scene::checkpoint::load(&run.path().join("model.safetensors")).unwrap();
    let main = (0..model.num_voxels())
        .filter(|&i| {
            let (lo, s) = (model.voxel_min(i), model.voxel_size(i));
            lo.iter().all(|&v| v >= -1.0 && v + s <= 1.0)
        })
        .count();
    let want = format!(
        "({} voxels: {main} in the main region, {} in the background shells)",
        model.num_voxels(),
        model.num_voxels() - main
    );
    assert!(main > 0 && main < model.num_voxels(), "{want}");
    assert!(err.contains(&want), "{want} not in {err}");
    let cfg: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.path().join("config.json")).unwrap())
            .unwrap();
    assert_eq!(cfg["preset"], "real");
    // The real preset's background: the mean colour of the 12 training photos (every
    // 4th of the 16 held out), saved in config.json and in the model.
    let mut sum = [0f64; 3];
    let mut n = 0;
    for k in (0..16).filter(|k| k % 4 != 0) {
        let png = image::open(dir.path().join(format!("images_2/shot_{k}.png")))
            .unwrap()
            .to_rgb8();
        for p in png.pixels() {
            for (s, v) in sum.iter_mut().zip(p.0) {
                *s += f64::from(v) / 255.0;
            }
            n += 1;
        }
    }
    for c in 0..3 {
        let want = sum[c] / n as f64;
        let got = cfg["config"]["background"][c].as_f64().unwrap();
        assert!((got - want).abs() < 1e-5, "background[{c}] {got} vs {want}");
        assert!((f64::from(model.background[c]) - want).abs() < 1e-5);
    }
    assert!(
        err.contains("background colour: the training photos' mean ["),
        "{err}"
    );
    assert_eq!(cfg["source"]["images"], "images_2");
    assert_eq!(cfg["source"]["holdout"], 4);
    // eval reuses the run's data options: 4 held-out views (0, 4, 8, 12).
    let (ok, out, err) = svraster(&["eval", r, "--data", d, "--json"]);
    assert!(ok, "{err}");
    let rep: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    assert_eq!(rep["views"], 4, "{out}");
    assert!(rep["psnr"].as_f64().unwrap() > 10.0, "{out}");
    // Resuming with other data options is refused (the run reads its data one way).
    let (ok, _, err) = svraster(&["train", d, "--out", r, "--resume", "--holdout", "8"]);
    assert!(
        !ok && err.contains("drop --format/--images/--holdout"),
        "{err}"
    );
    // Capture options on Blender data.
    let (ok, _, err) = svraster(&[
        "train",
        demo.path().to_str().unwrap(),
        "--out",
        tmp("cap-bad").path().to_str().unwrap(),
        "--holdout",
        "4",
    ]);
    assert!(!ok && err.contains("apply to captures"), "{err}");
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

/// `svraster mesh` on the analytically voxelized demo scene: the PLY reads back with an
/// independent numpy reader (tools/ply_read.py), lies on the true surface (eval-mesh
/// --demo), and bad requests fail with one clear error and no file.
#[test]
fn mesh_of_the_voxelized_demo_is_accurate_and_readable() {
    let dir = tmp("mesh");
    let d = dir.path().to_str().unwrap();
    let (ok, _, err) = svraster(&[
        "demo",
        "--out",
        d,
        "--size",
        "64",
        "--voxelize",
        "--level",
        "7",
    ]);
    assert!(ok, "{err}");
    let run = dir.path().join("run");
    let data = dir.path().join("data");
    let (run, data) = (run.to_str().unwrap(), data.to_str().unwrap());
    let ply = dir.path().join("m.ply");
    let p = ply.to_str().unwrap();
    let (ok, out, err) = svraster(&[
        "mesh",
        run,
        "--data",
        data,
        "--out",
        p,
        "--vertex-colors",
        "--preview",
        "1",
    ]);
    assert!(ok, "{err}");
    assert!(err.contains("← mesh level"), "{err}");
    assert!(dir.path().join("m_r_0.png").is_file(), "preview written");
    // "wrote …: V vertices, T triangles, …"
    let count = |what: &str| -> u64 {
        let i = out.find(what).unwrap_or_else(|| panic!("{what} in {out}"));
        out[..i].split_whitespace().last().unwrap().parse().unwrap()
    };
    let (nv, nt) = (count(" vertices"), count(" triangles"));
    let (v, props) = ply_info(&ply);
    assert_eq!(v["vertices"].as_u64(), Some(nv));
    assert_eq!(v["faces"].as_u64(), Some(nt));
    assert!(v["max_index"].as_i64().unwrap() < nv as i64);
    assert_eq!(
        props,
        ["x", "y", "z", "nx", "ny", "nz", "red", "green", "blue"]
    );
    // The demo's primitives span [-0.8, 0.8] × [-0.8, 0.8] × [-0.7, 0.4].
    for k in 0..3 {
        let (lo, hi) = (v["min"][k].as_f64().unwrap(), v["max"][k].as_f64().unwrap());
        assert!(
            lo > -0.9 && hi < 0.9 && hi - lo > 1.0,
            "axis {k}: {lo}..{hi}"
        );
    }
    let (ok, out, err) = svraster(&["eval-mesh", p, "--data", data, "--demo", "--json"]);
    assert!(ok, "{err}");
    let e: serde_json::Value = serde_json::from_str(&out).unwrap();
    let (chamfer, f) = (
        e["chamfer"].as_f64().unwrap(),
        e["fscore"].as_f64().unwrap(),
    );
    println!("voxelized demo, level 7: Chamfer {chamfer:.4}, F-score {f:.3} at 0.02");
    // Level-6 voxels are 3/64 = 0.047 wide: measured Chamfer 0.019, F 0.66.
    assert!(
        chamfer < 0.025 && f > 0.55,
        "Chamfer {chamfer}, F-score {f}"
    );

    // Bad requests: one clear error, no file.
    let bad = dir.path().join("bad.ply");
    let b = bad.to_str().unwrap();
    for (args, want) in [
        (vec!["--bbox", "5", "5", "5", "6", "6", "6"], "no voxel"),
        (vec!["--bbox", "1", "1", "1", "0", "0", "0"], "min < max"),
        (vec!["--max-voxels", "100"], "--level"),
        (vec!["--trunc", "0.5"], "at least 1"),
        (vec!["--level", "17"], "outside 1..=16"),
    ] {
        let mut a = vec!["mesh", run, "--data", data, "--out", b];
        a.extend(args.iter().copied());
        let (ok, _, err) = svraster(&a);
        assert!(!ok && err.contains(want), "{args:?}: {err}");
        assert_eq!(err.matches("error").count(), 1, "{args:?}: {err}");
        assert!(!bad.exists(), "{args:?} left a file");
    }
    std::fs::write(&bad, b"ply\nformat ascii 1.0\nend_header\n").unwrap();
    let (ok, _, err) = svraster(&["eval-mesh", b, "--data", data, "--demo"]);
    assert!(
        !ok && err.contains("bad.ply") && err.contains("binary_little_endian"),
        "{err}"
    );
}

/// `svraster export`: the voxel PLY reads back with the independent numpy reader (one
/// point per voxel, in the scene cube), and the 8-bit quantized checkpoint is smaller
/// and renders within 0.1 dB of the full model; bad requests fail with one
/// clear error and no file.
#[test]
fn export_ply_and_quantized_checkpoint() {
    let dir = tmp("export");
    let d = dir.path().to_str().unwrap();
    let (ok, out, err) = svraster(&[
        "demo",
        "--out",
        d,
        "--size",
        "32",
        "--voxelize",
        "--level",
        "6",
    ]);
    assert!(ok, "{err}");
    let voxels: u64 = out
        .split("demo: ")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("voxel count in {out}"));
    let run = dir.path().join("run");
    let data = dir.path().join("data");
    let (run_s, data_s) = (run.to_str().unwrap(), data.to_str().unwrap());
    let ply = dir.path().join("voxels.ply");
    let (ok, out, err) = svraster(&["export", run_s, "--out", ply.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert!(out.contains(&format!("{voxels} voxels")), "{out}");
    let (v, props) = ply_info(&ply);
    assert_eq!(v["vertices"].as_u64(), Some(voxels));
    assert_eq!(v["faces"].as_u64(), Some(0));
    assert_eq!(
        props,
        ["x", "y", "z", "size", "level", "density", "red", "green", "blue"]
    );
    for k in 0..3 {
        let (lo, hi) = (v["min"][k].as_f64().unwrap(), v["max"][k].as_f64().unwrap());
        assert!(lo > -1.5 && hi < 1.5 && lo < hi, "axis {k}: {lo} .. {hi}");
    }

    let q = dir.path().join("q.safetensors");
    let (ok, out, err) = svraster(&[
        "export",
        run_s,
        "--format",
        "quantized",
        "--out",
        q.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let full = std::fs::metadata(run.join("model.safetensors"))
        .unwrap()
        .len();
    let small = std::fs::metadata(&q).unwrap().len();
    println!("{out}: {full} → {small} bytes");
    // The voxelized demo has SH degree 0 (21 bytes per voxel, 12 quantized, plus the
    // codebooks); degree 3 gives ~70 % (tests/checkpoint.rs).
    assert!((small as f64) < 0.6 * full as f64, "{full} → {small}");
    let psnr = |model: &str| -> f64 {
        let (ok, out, err) = svraster(&["eval", model, "--data", data_s, "--json"]);
        assert!(ok, "{err}");
        let j: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
        j["psnr"].as_f64().unwrap()
    };
    let (p_full, p_q) = (psnr(run_s), psnr(q.to_str().unwrap()));
    println!("test PSNR: full {p_full:.3} dB, quantized {p_q:.3} dB");
    assert!((p_full - p_q).abs() < 0.1, "{p_full} vs {p_q}");

    let missing = dir.path().join("nope");
    let bad = dir.path().join("bad.ply");
    let (ok, _, err) = svraster(&[
        "export",
        missing.to_str().unwrap(),
        "--out",
        bad.to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("not found"), "{err}");
    assert!(!bad.exists());
}

/// `bench trade --vary`: one factor at a time around the preset (a `--set` key and
/// `iters`), Pareto fronts marked in the JSON and the table, the ETA reported, and a
/// knob the preset does not have refused before anything trains.
#[test]
fn bench_trade_varies_knobs_one_at_a_time_and_marks_the_front() {
    let dir = tmp("trade-vary");
    let data = dir.path().join("data");
    write_demo(&data, 20, [6, 2, 1], 4);
    let out = dir.path().join("trade");
    let common = [
        "bench",
        "trade",
        data.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--downscale",
        "1",
        "--iters",
        "60",
        "--max-voxels",
        "3000",
        "--set",
        "grid_level=3",
    ];
    let mut bad = common.to_vec();
    bad.extend_from_slice(&["--vary", "no_such_knob=1,2"]);
    let (ok, _, err) = svraster(&bad);
    assert!(!ok && err.contains("no_such_knob"), "{err}");
    assert!(
        !out.join("base").exists(),
        "nothing trained before the check"
    );

    let mut args = common.to_vec();
    args.extend_from_slice(&["--vary", "samples=1,3", "--vary", "iters=20", "--json"]);
    let (ok, stdout, err) = svraster(&args);
    assert!(ok, "bench trade --vary failed: {stdout}\n{err}");
    let doc: serde_json::Value = serde_json::from_str(stdout.trim()).expect("trade JSON");
    let rows = doc["rows"].as_array().unwrap();
    let names: Vec<&str> = rows
        .iter()
        .map(|r| r["variant"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["base", "samples=1", "samples=3", "iters=20"]);
    assert_eq!(rows[3]["iters"], 20);
    assert_eq!(rows[0]["iters"], 60);
    let cfg: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("samples=3").join("config.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(cfg["config"]["samples"], 3, "{cfg}");
    // Each front holds the fastest variant, and the most accurate one.
    for (front, cost) in [("front_train", "train_s"), ("front_render", "ms_per_frame")] {
        let fastest = rows
            .iter()
            .min_by(|a, b| {
                a[cost]
                    .as_f64()
                    .unwrap()
                    .total_cmp(&b[cost].as_f64().unwrap())
            })
            .unwrap();
        let best = rows
            .iter()
            .max_by(|a, b| {
                a["psnr"]
                    .as_f64()
                    .unwrap()
                    .total_cmp(&b["psnr"].as_f64().unwrap())
            })
            .unwrap();
        assert_eq!(fastest[front], true, "{front}: {fastest}");
        assert_eq!(best[front], true, "{front}: {best}");
    }
    assert!(err.contains("ETA"), "{err}");
    let md = std::fs::read_to_string(out.join("trade.md")).unwrap();
    assert!(
        md.contains("speed/accuracy trade") && md.contains("| Pareto front |"),
        "{md}"
    );
    assert!(md.contains("**train"), "{md}");
}

/// `--deterministic`: two runs with the same seed write byte-identical checkpoints
/// (model, optimizer state), through supersampling, TV, SSIM and adaptive steps.
#[test]
fn deterministic_runs_write_identical_checkpoints() {
    let dir = tmp("deterministic");
    let data = dir.path().join("data");
    write_demo(&data, 32, [8, 2, 1], 4);
    let ds = data.to_str().unwrap();
    let train = |name: &str, det: bool| -> (Vec<u8>, Vec<u8>, String) {
        let run = dir.path().join(name);
        let mut args = vec![
            "train",
            ds,
            "--out",
            run.to_str().unwrap(),
            "--preset",
            "synthetic",
            "--iters",
            "160",
            "--seed",
            "5",
            "--set",
            "grid_level=4",
            "--set",
            "lambda_tv=1e-9",
            "--set",
            "tv_until=1",
        ];
        if det {
            args.push("--deterministic");
        }
        let (ok, out, err) = svraster(&args);
        assert!(ok, "{out}\n{err}");
        (
            std::fs::read(run.join("model.safetensors")).unwrap(),
            std::fs::read(run.join("optimizer.safetensors")).unwrap(),
            out + &err,
        )
    };
    let (m1, o1, log) = train("det1", true);
    let (m2, o2, _) = train("det2", true);
    // The run changed its layout (so the grid point lists were rebuilt on the way).
    assert!(
        log.contains("pruned") || log.contains("subdivided"),
        "{log}"
    );
    let cfg = std::fs::read_to_string(dir.path().join("det1/config.json")).unwrap();
    assert!(cfg.contains("\"reduction\": \"ordered\""), "{cfg}");
    assert!(m1 == m2, "models differ between two deterministic runs");
    assert!(
        o1 == o2,
        "optimizer states differ between two deterministic runs"
    );
    // The default mode's float atomics add in a varying order (not asserted: a small
    // scene may happen to come out the same).
    let (a1, _, _) = train("atomic1", false);
    let (a2, _, _) = train("atomic2", false);
    let differing = a1.iter().zip(&a2).filter(|(x, y)| x != y).count();
    println!(
        "default mode: {differing} of {} model bytes differ between two runs",
        a1.len()
    );
}

/// `bench trade --budget-minutes`: a calibration run sets the iterations (here the least,
/// 100, for a budget far too small), reported in the log and the rows; the calibration
/// run is removed.
#[test]
fn bench_trade_fits_the_schedule_to_a_time_budget() {
    let dir = tmp("trade-budget");
    let data = dir.path().join("data");
    write_demo(&data, 16, [4, 1, 1], 5);
    let out = dir.path().join("trade");
    let (ok, stdout, err) = svraster(&[
        "bench",
        "trade",
        data.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--downscale",
        "1",
        "--max-voxels",
        "3000",
        "--set",
        "grid_level=3",
        "--vary",
        "sh_degree=0",
        "--combine",
        "0",
        "--budget-minutes",
        "0.01",
        "--json",
    ]);
    assert!(ok, "{stdout}\n{err}");
    assert!(err.contains("s per iteration"), "{err}");
    assert!(err.contains("more than the budget"), "{err}");
    let doc: serde_json::Value = serde_json::from_str(stdout.trim()).expect("trade JSON");
    let rows = doc["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 2);
    assert!(rows.iter().all(|r| r["iters"] == 100), "{doc}");
    assert_eq!(doc["iters"], 100);
    assert!(!out.join("calibration").exists());
    let (ok, _, err) = svraster(&[
        "bench",
        "trade",
        data.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--budget-minutes=-1",
    ]);
    assert!(!ok && err.contains("--budget-minutes"), "{err}");
}
