use super::*;

#[test]
fn demo_then_render_and_bench() {
    let dir = tmp("demo");
    let d = dir.path().to_str().unwrap();
    let (ok, out, err) = svraster(&[
        "demo", "--out", d, "--size", "32", "--level", "4", "--iters", "60",
    ]);
    assert!(ok, "demo failed: {out}\n{err}");
    // Trained, evaluated and rendered (quality is asserted by tests/train/).
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
    // 2 views × 1 run, timed while queued; and the same frames untimed.
    assert_eq!(v["frames_timed"], 2, "{v}");
    assert!(v["wall_timed_median_ms"].as_f64().unwrap() > 0.0, "{v}");
    assert!(v["wall_median_ms"].as_f64().unwrap() > 0.0, "{v}");
    // Warm-up: one frame per view, then (--warmup-ms; by default on GPUs only) the
    // views again until it has lasted that long.
    let model = dir.path().join("run/model.safetensors");
    let data = dir.path().join("data");
    let warm = |ms: &str| {
        let a = [
            "bench",
            "render",
            model.to_str().unwrap(),
            "--data",
            data.to_str().unwrap(),
            "--views",
            "2",
            "--runs",
            "1",
            "--warmup-ms",
            ms,
            "--json",
        ];
        let (ok, out, err) = svraster(&a);
        assert!(ok, "{ms}: {err}");
        serde_json::from_str::<serde_json::Value>(out.trim()).expect("bench JSON")
    };
    if v["warmup_ms"] == 0.0 {
        assert_eq!(v["warmup_frames"], 2, "{v}");
    }
    let w = warm("400");
    assert_eq!(w["warmup_ms"], 400.0, "{w}");
    assert!(w["warmup_wall_ms"].as_f64().unwrap() >= 400.0, "{w}");
    assert_eq!(
        w["warmup_frames"].as_u64().unwrap() % 2,
        0,
        "whole rounds: {w}"
    );
    let (ok, _, err) = svraster(&[
        "bench",
        "render",
        model.to_str().unwrap(),
        "--data",
        data.to_str().unwrap(),
        "--warmup-ms",
        "nan",
    ]);
    assert!(!ok && err.contains("--warmup-ms"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "one error line: {err}");
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
    while logged_so_far(&run) < 3 {
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
    let bench_train = |extra: &[&str]| {
        let mut a = vec![
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
        ];
        a.extend(extra);
        let (ok, out, err) = svraster(&a);
        assert!(ok, "bench train {extra:?} failed: {out}\n{err}");
        serde_json::from_str::<serde_json::Value>(out.trim()).expect("bench JSON")
    };
    let v = bench_train(&[]);
    assert!(v["median_ms_per_iter"].as_f64().unwrap() > 0.0);
    // Every timed (queued) iteration's stage times were read, once.
    assert_eq!(v["timed_iterations"], 3, "{v}");
    // The warm-up: --warmup iterations, more only where --warmup-ms asks (GPUs).
    if v["warmup_ms"] == 0.0 {
        assert_eq!(v["warmup_iters"], 1, "{v}");
    } else {
        assert!(v["warmup_wall_ms"].as_f64().unwrap() >= v["warmup_ms"].as_f64().unwrap());
    }
    let w = bench_train(&["--warmup-ms", "400"]);
    assert_eq!(w["warmup_ms"], 400.0, "{w}");
    assert!(w["warmup_wall_ms"].as_f64().unwrap() >= 400.0, "{w}");
    let (ok, _, err) = svraster(&["bench", "train", ds, "--warmup-ms", "70000"]);
    assert!(!ok && err.contains("--warmup-ms"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "one error line: {err}");
    assert!(v["wall_timed_median_ms_per_iter"].as_f64().unwrap() > 0.0);
    // The full-model regime: the timed iterations used the final SH degree.
    assert_eq!(v["sh_degree"], 3, "{v}");
    // ... and every loss term: TV's window covers them.
    assert_eq!(v["tv_on"], true, "{v}");
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
