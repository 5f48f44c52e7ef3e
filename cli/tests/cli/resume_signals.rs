use super::*;

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
    let child = spawn_training(ds, &run, "100000", &["--set", "checkpoint_every=0"]);
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

/// Starts a long quick-preset training of `data` into `run` in the background (level-3
/// grid, a log line every 5 iterations, stderr piped) and returns once it has logged two
/// lines.
fn spawn_training(
    data: &str,
    run: &std::path::Path,
    iters: &str,
    extra: &[&str],
) -> std::process::Child {
    let child = Command::new(env!("CARGO_BIN_EXE_svraster"))
        .args([
            "train",
            data,
            "--out",
            run.to_str().unwrap(),
            "--preset",
            "quick",
            "--iters",
            iters,
            "--set",
            "grid_level=3",
            "--set",
            "log_every=5",
        ])
        .args(extra)
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = std::time::Instant::now();
    while logged_so_far(run) < 2 {
        assert!(t0.elapsed().as_secs() < 300, "training did not start");
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    child
}

/// A run whose directory is removed, or moved and replaced by another, while it trains
/// stops at its next logged step with an error naming the directory, and writes nothing
/// at that path afterwards (no re-created directory, nothing mixed into another run's).
#[test]
fn a_run_whose_directory_is_removed_or_replaced_stops_without_writing_there() {
    let dir = tmp("run-removed");
    let data = small_data(dir.path(), "data", 4);
    let ds = data.to_str().unwrap();
    for replace in [false, true] {
        let run = dir.path().join(format!("run-{replace}"));
        let rs = run.to_str().unwrap();
        let mut child = spawn_training(ds, &run, "1000000", &[]);
        let moved = dir.path().join(format!("moved-{replace}"));
        if replace {
            // Moved away, and a new directory (with a lock file of its own, as another
            // run's) made at the old path.
            std::fs::rename(&run, &moved).unwrap();
            std::fs::create_dir(&run).unwrap();
            std::fs::write(run.join(".lock"), b"").unwrap();
            std::fs::write(run.join("mine"), b"another run").unwrap();
        } else {
            std::fs::remove_dir_all(&run).unwrap();
        }
        // It stops soon (the next logged step), not at the end of a million iterations.
        let t1 = std::time::Instant::now();
        let status = loop {
            if let Some(st) = child.try_wait().unwrap() {
                break st;
            }
            if t1.elapsed().as_secs() > 120 {
                child.kill().unwrap();
                panic!("the run went on training after its directory was removed or replaced (replace: {replace})");
            }
            std::thread::sleep(std::time::Duration::from_millis(100));
        };
        let mut err = String::new();
        std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut err).unwrap();
        assert!(!status.success(), "{err}");
        assert!(
            err.contains("was removed, moved or replaced") && err.contains(rs),
            "{err}"
        );
        if replace {
            let mut names: Vec<String> = std::fs::read_dir(&run)
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            names.sort();
            assert_eq!(
                names,
                [".lock", "mine"],
                "written into the replacing directory"
            );
            // The moved run keeps the log it wrote.
            assert!(logged(&moved).len() >= 2);
        } else {
            assert!(!run.exists(), "the removed run directory was made again");
        }
    }
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

/// `bench sort --probe`: the probe's result is checked against what it defines and named
/// in the JSON; the direct pass (no probes) and an unknown probe are one clear error.
#[test]
fn bench_sort_probes_are_checked_and_named() {
    for probe in ["copy", "tile"] {
        let (ok, out, err) = svraster(&[
            "bench",
            "sort",
            "--n",
            "5000",
            "--runs",
            "5",
            "--warmup",
            "1",
            "--pass",
            "c128",
            "--probe",
            probe,
            "--no-baseline",
            "--json",
        ]);
        assert!(ok, "{err}");
        let v: serde_json::Value = serde_json::from_str(out.trim()).expect("bench sort JSON");
        assert_eq!(v["probe"], probe, "{v}");
        assert_eq!(v["pass_kernel"], "c128", "{v}");
        assert_eq!(v["verified"], true, "{v}");
        assert!(v["copy_floor_ms"].as_f64().unwrap() >= 0.0, "{v}");
        assert!(
            v["speedup_vs_cpu"].is_null(),
            "a probe has no CPU baseline: {v}"
        );
    }
    let (ok, out, _) = svraster(&[
        "bench",
        "sort",
        "--n",
        "5000",
        "--runs",
        "5",
        "--pass",
        "c128",
        "--no-baseline",
        "--json",
    ]);
    assert!(ok);
    let v: serde_json::Value = serde_json::from_str(out.trim()).expect("bench sort JSON");
    assert!(v["probe"].is_null(), "{v}");
    for (args, says) in [
        (["--pass", "direct", "--probe", "tile"], "no probes"),
        (
            ["--pass", "c128", "--probe", "half"],
            "unknown pass probe `half`",
        ),
    ] {
        let mut a = vec![
            "bench",
            "sort",
            "--n",
            "5000",
            "--runs",
            "5",
            "--no-baseline",
        ];
        a.extend(args);
        let (ok, _, err) = svraster(&a);
        assert!(!ok && err.contains(says), "{args:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "one error line: {err}");
    }
}

/// `bench sort --heat-ms`: untimed sorts recorded before each run in its submission (off
/// by default on a CPU device), named in the JSON with every run's time; the timed sort
/// after them is still verified, and an out-of-range value is one clear error.
#[test]
fn bench_sort_heat_runs_before_each_timed_sort() {
    let run = |extra: &[&str]| {
        let mut a = vec![
            "bench",
            "sort",
            "--n",
            "5000",
            "--runs",
            "5",
            "--warmup",
            "1",
            "--no-baseline",
            "--json",
        ];
        a.extend(extra);
        let (ok, out, err) = svraster(&a);
        assert!(ok, "{extra:?}: {err}");
        serde_json::from_str::<serde_json::Value>(out.trim()).expect("bench sort JSON")
    };
    // The default: none on a CPU device, 200 ms on a GPU (`info --json` says which).
    let (ok, info, err) = svraster(&["info", "--json"]);
    assert!(ok, "info: {err}");
    let info: serde_json::Value = serde_json::from_str(info.trim()).expect("info JSON");
    let cpu = info["is_cpu"].as_bool().expect("info --json names is_cpu");
    let v = run(&[]);
    let want = if cpu { 0.0 } else { 200.0 };
    assert_eq!(v["heat_ms"], want, "default heat (CPU device {cpu}): {v}");
    if cpu {
        assert_eq!(v["heat_sorts"], 0, "{v}");
    }
    assert_eq!(v["runs_ms"].as_array().unwrap().len(), 5, "{v}");
    // A heat longer than any sort of 5 000 keys here: at least one sort before each run.
    let v = run(&["--heat-ms", "1000"]);
    assert_eq!(v["heat_ms"], 1000.0, "{v}");
    let sorts = v["heat_sorts"].as_u64().unwrap();
    assert!((1..=256).contains(&sorts), "{v}");
    assert_eq!(v["verified"], true, "{v}");
    let runs: Vec<f64> = v["runs_ms"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t.as_f64().unwrap())
        .collect();
    assert_eq!(runs.len(), 5, "{v}");
    assert!(runs.iter().all(|&t| t > 0.0), "{v}");
    // The wall time of a run leaves its heat out (timed apart): against the same runs
    // without heat it grows by far less than the heat's GPU time. (A run's wall carries
    // a fixed cost of its own, submission and read-back under the validation layer: on
    // the H200 32 ms for a 0.16 ms sort, so the heat is not compared with it alone.)
    let cold = run(&["--heat-ms", "0"]);
    assert_eq!(cold["heat_sorts"], 0, "{cold}");
    let wall = v["wall_median_ms"].as_f64().unwrap();
    let wall_cold = cold["wall_median_ms"].as_f64().unwrap();
    let heat_total = v["heat_gpu_ms"].as_f64().unwrap();
    assert!(heat_total > 0.0, "{v}");
    if sorts >= 8 {
        assert!(
            wall < wall_cold + heat_total / 2.0,
            "{wall} ms wall with {heat_total} ms of heat, {wall_cold} ms without: {v}"
        );
    }
    let (ok, _, err) = svraster(&[
        "bench",
        "sort",
        "--n",
        "5000",
        "--runs",
        "5",
        "--heat-ms",
        "20000",
    ]);
    assert!(!ok && err.contains("--heat-ms"), "{err}");
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
    // Big-endian meshes are refused naming the forms read; an (ASCII) mesh without
    // faces is named too.
    std::fs::write(&bad, b"ply\nformat binary_big_endian 1.0\nend_header\n").unwrap();
    let (ok, _, err) = svraster(&["eval-mesh", b, "--data", data, "--demo"]);
    assert!(
        !ok && err.contains("bad.ply") && err.contains("binary_little_endian and ascii"),
        "{err}"
    );
    std::fs::write(&bad, b"ply\nformat ascii 1.0\nend_header\n").unwrap();
    let (ok, _, err) = svraster(&["eval-mesh", b, "--data", data, "--demo"]);
    assert!(!ok && err.contains("bad.ply has no triangles"), "{err}");
}
