//! Defects a new user hit (issue "What users of nerfstudio, Brush and SVRaster reach
//! for"), each through the command line.

use super::*;

/// A training photo that is a truncated JPEG (an interrupted copy) stops `train` with an
/// error naming the file, before anything is written; the decoder alone would train on
/// its missing rows as flat grey.
#[test]
fn train_refuses_a_truncated_jpeg() {
    let data = tmp("trunc-jpeg");
    write_demo(data.path(), 24, [4, 1, 1], 3);
    // Frame 0 of the train split as a JPEG, cut to 60 %.
    let json_path = data.path().join("transforms_train.json");
    let mut doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json_path).unwrap()).unwrap();
    let rel = doc["frames"][0]["file_path"].as_str().unwrap().to_string();
    let png = data.path().join(format!("{rel}.png"));
    let img = image::open(&png).unwrap().to_rgb8();
    let mut jpg = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpg, 90)
        .encode(
            img.as_raw(),
            img.width(),
            img.height(),
            image::ExtendedColorType::Rgb8,
        )
        .unwrap();
    let cut = data.path().join(format!("{rel}.jpg"));
    std::fs::write(&cut, &jpg[..jpg.len() * 6 / 10]).unwrap();
    doc["frames"][0]["file_path"] = serde_json::Value::String(format!("{rel}.jpg"));
    std::fs::write(&json_path, serde_json::to_string(&doc).unwrap()).unwrap();

    let run = tmp("trunc-jpeg-run");
    let out = run.path().join("run");
    let (ok, _, err) = svraster(&[
        "train",
        data.path().to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--iters",
        "5",
    ]);
    assert!(!ok, "train accepted a truncated JPEG");
    let name = cut.file_name().unwrap().to_str().unwrap();
    assert!(
        err.contains(name) && err.contains("truncated"),
        "the error does not name the truncated file: {err}"
    );
    assert!(!out.join("model.safetensors").exists());
}

/// No output may replace an input: `render --out DATA/test` wrote its PNGs over the
/// dataset's photos (a later `eval` then scored 58.74 dB), and `export --out
/// RUN/model.safetensors` replaced the trained model. Both are refused before anything
/// is written; the photos and the model are byte for byte what they were.
#[test]
fn outputs_never_replace_inputs() {
    let dir = tmp("out-over-in");
    let d = dir.path().to_str().unwrap();
    let (ok, _, err) = svraster(&["demo", "--out", d, "--size", "16", "--iters", "5"]);
    assert!(ok, "demo failed: {err}");
    let (data, run) = (dir.path().join("data"), dir.path().join("run"));
    let model = run.join("model.safetensors");
    let photos = data.join("test");
    let snapshot = |p: &std::path::Path| -> Vec<(std::path::PathBuf, Vec<u8>)> {
        let mut v: Vec<_> = std::fs::read_dir(p)
            .unwrap()
            .map(|e| e.unwrap().path())
            .map(|f| (f.clone(), std::fs::read(&f).unwrap()))
            .collect();
        v.sort();
        v
    };
    let before_photos = snapshot(&photos);
    let before_model = std::fs::read(&model).unwrap();

    for out in [photos.clone(), data.clone(), data.join("renders")] {
        let (ok, _, err) = svraster(&[
            "render",
            run.to_str().unwrap(),
            "--data",
            data.to_str().unwrap(),
            "--split",
            "test",
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(!ok, "render into {} was accepted", out.display());
        assert!(err.contains("inside the dataset"), "{err}");
    }
    assert!(!data.join("renders").exists());
    for out in [
        model.clone(),
        run.join("optimizer.safetensors"),
        run.join("./model.safetensors"),
    ] {
        for format in ["ply", "quantized"] {
            let (ok, _, err) = svraster(&[
                "export",
                run.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                "--format",
                format,
            ]);
            assert!(!ok, "export --out {} was accepted", out.display());
            assert!(err.contains("would replace"), "{err}");
        }
    }
    assert_eq!(
        snapshot(&photos),
        before_photos,
        "the dataset's photos changed"
    );
    assert_eq!(
        std::fs::read(&model).unwrap(),
        before_model,
        "the model changed"
    );
    // Outside the inputs both still work.
    let (ok, _, err) = svraster(&[
        "export",
        run.to_str().unwrap(),
        "--out",
        dir.path().join("voxels.ply").to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
}

/// A dataset folder that does not exist is "not found" (it was reported as "not a
/// Blender dataset", or as capture options given to one), and a nerfstudio key of the
/// wrong type is a wrong type, not a missing key (`"w": "512"` was "no `w`").
#[test]
fn data_errors_say_what_is_wrong() {
    let dir = tmp("data-errors");
    let missing = dir.path().join("no-such-capture");
    let out = dir.path().join("run");
    for extra in [&[][..], &["--holdout", "4"][..]] {
        let mut args = vec![
            "train",
            missing.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        let (ok, _, err) = svraster(&args);
        assert!(!ok);
        assert!(
            err.contains("no-such-capture") && err.contains("not found"),
            "{extra:?}: {err}"
        );
    }
    let ns = dir.path().join("ns");
    std::fs::create_dir_all(&ns).unwrap();
    let pose = "[[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]";
    std::fs::write(
        ns.join("transforms.json"),
        format!(
            r#"{{"fl_x": 100, "w": "512", "h": 384, "frames": [{{"file_path": "images/a.png", "transform_matrix": {pose}}}]}}"#
        ),
    )
    .unwrap();
    let (ok, _, err) = svraster(&[
        "train",
        ns.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!ok);
    assert!(err.contains("`w` is \"512\", not a number"), "{err}");
}

/// The demo scene voxelized down to `level` in `dir` (no training): its run and data.
fn voxelized_demo(dir: &std::path::Path, level: u32) -> (PathBuf, PathBuf) {
    let level = level.to_string();
    let (ok, _, err) = svraster(&[
        "demo",
        "--out",
        dir.to_str().unwrap(),
        "--size",
        "16",
        "--voxelize",
        "--level",
        &level,
    ]);
    assert!(ok, "demo failed: {err}");
    (dir.join("run"), dir.join("data"))
}

/// `eval-mesh` refuses flags that contradict each other or the data: `--demo` with
/// `--truth` (the truth was ignored), and `--demo` on a dataset that is not the demo's
/// (lego was scored against the demo scene's surface).
#[test]
fn eval_mesh_refuses_conflicting_or_wrong_scene_flags() {
    let dir = tmp("eval-mesh-flags");
    let (run, data) = voxelized_demo(dir.path(), 5);
    let ply = dir.path().join("m.ply");
    let (ok, _, err) = svraster(&[
        "mesh",
        run.to_str().unwrap(),
        "--data",
        data.to_str().unwrap(),
        "--out",
        ply.to_str().unwrap(),
    ]);
    assert!(ok, "mesh failed: {err}");
    let (m, dt) = (ply.to_str().unwrap(), data.to_str().unwrap());
    let (ok, _, err) = svraster(&["eval-mesh", m, "--data", dt, "--demo"]);
    assert!(ok, "the demo's own data was refused: {err}");
    let (ok, _, err) = svraster(&["eval-mesh", m, "--data", dt, "--demo", "--truth", m]);
    assert!(!ok && err.contains("give one"), "{err}");
    // The same dataset with every camera 25 % farther out: not the demo's.
    let other = dir.path().join("other");
    std::fs::create_dir_all(&other).unwrap();
    for e in std::fs::read_dir(&data).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_owned();
        if p.extension().is_some_and(|x| x == "json") {
            let mut doc: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
            for f in doc["frames"].as_array_mut().unwrap() {
                for row in 0..3 {
                    let t = f["transform_matrix"][row][3].as_f64().unwrap();
                    f["transform_matrix"][row][3] = (t * 1.25).into();
                }
            }
            std::fs::write(other.join(name), doc.to_string()).unwrap();
        } else if p.is_dir() {
            std::fs::create_dir_all(other.join(&name)).unwrap();
            for img in std::fs::read_dir(&p).unwrap() {
                let img = img.unwrap().path();
                std::fs::copy(&img, other.join(&name).join(img.file_name().unwrap())).unwrap();
            }
        }
    }
    let (ok, _, err) = svraster(&["eval-mesh", m, "--data", other.to_str().unwrap(), "--demo"]);
    assert!(!ok && err.contains("not the demo's dataset"), "{err}");
}

/// Help texts are complete: `eval --data` has one, every command that reads a dataset
/// names NeuS among the layouts, and `render --depth` names every file it writes.
#[test]
fn help_texts_are_complete() {
    let help = |cmd: &str| {
        let (ok, out, err) = svraster(&[cmd, "--help"]);
        assert!(ok, "{cmd} --help: {err}");
        out
    };
    let eval = help("eval");
    let data_help = eval
        .lines()
        .find(|l| l.trim_start().starts_with("--data <DATA>"))
        .and_then(|l| l.split("<DATA>").nth(1))
        .unwrap_or("")
        .trim();
    assert!(!data_help.is_empty(), "eval --data has no help:\n{eval}");
    for cmd in ["train", "eval", "render"] {
        assert!(help(cmd).contains("NeuS"), "{cmd} --help omits NeuS");
    }
    let render = help("render");
    for f in ["NAME_depth16.png", "NAME_depth.json", "NAME_depth.png"] {
        assert!(render.contains(f), "render --help omits {f}");
    }
}

/// `mesh` checks that it can write its output before the work: an `--out` that is a
/// folder, or whose folder cannot be made, fails before fusing (it failed after).
#[test]
fn mesh_checks_its_output_first() {
    let dir = tmp("mesh-out");
    let (run, data) = voxelized_demo(dir.path(), 4);
    let file = dir.path().join("a-file");
    std::fs::write(&file, b"x").unwrap();
    for out in [dir.path().to_path_buf(), file.join("m.ply")] {
        let (ok, _, err) = svraster(&[
            "mesh",
            run.to_str().unwrap(),
            "--data",
            data.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(!ok, "{}: accepted", out.display());
        assert!(
            !err.contains("← mesh level"),
            "{}: the mesh was extracted before the output was checked: {err}",
            out.display()
        );
    }
}

/// Defect 1: a run stopped before its first checkpoint (killed, or its first checkpoint
/// could not be written) leaves config.json and stats.jsonl only. The failed write says
/// there is no checkpoint (not that "the previous checkpoint is resumable"), `--resume`
/// says exactly what to do, and the same `train` command starts it over.
#[test]
fn a_run_without_a_checkpoint_starts_over() {
    let dir = tmp("no-checkpoint");
    let data = small_data(dir.path(), "data", 1);
    let run = dir.path().join("run");
    std::fs::create_dir_all(&run).unwrap();
    // The first checkpoint cannot be written (a full disk is ENOSPC; here a directory
    // takes the optimizer's temporary path).
    let blocker = run.join("optimizer.safetensors.tmp");
    std::fs::create_dir(&blocker).unwrap();
    let args = [
        "train",
        data.to_str().unwrap(),
        "--out",
        run.to_str().unwrap(),
        "--preset",
        "quick",
        "--iters",
        "20",
        "--set",
        "grid_level=3",
    ];
    let (ok, _, err) = svraster(&args);
    assert!(!ok && err.contains("no checkpoint yet"), "{err}");
    assert!(!err.contains("resumable"), "{err}");
    assert!(run.join("config.json").is_file() && !run.join("model.safetensors").exists());
    std::fs::remove_dir(&blocker).unwrap();
    let mut resume = args[..4].to_vec();
    resume.push("--resume");
    let (ok, _, err) = svraster(&resume);
    assert!(
        !ok && err.contains("never saved a checkpoint") && err.contains("without --resume"),
        "{err}"
    );
    let (ok, _, err) = svraster(&args);
    assert!(ok && err.contains("starting over"), "{err}");
    assert!(run.join("model.safetensors").is_file());
    let lines = stats_lines(&run);
    let iters: Vec<u64> = lines.iter().filter_map(|l| l["iter"].as_u64()).collect();
    assert!(
        iters.windows(2).all(|w| w[0] < w[1]),
        "one run's log: {iters:?}"
    );
}

/// Defect 10: `bench render RUN` measures frames as the run renders them — its
/// downscale and its model's supersampling unless told otherwise — and labels the walk's
/// work per frame, not per iteration.
#[test]
fn bench_render_uses_the_runs_settings_and_says_per_frame() {
    let dir = tmp("bench-render-run");
    let data = small_data(dir.path(), "data", 2);
    let run = dir.path().join("run");
    let (ok, _, err) = svraster(&[
        "train",
        data.to_str().unwrap(),
        "--out",
        run.to_str().unwrap(),
        "--preset",
        "quick",
        "--iters",
        "10",
        "--downscale",
        "2",
        "--set",
        "grid_level=3",
        "--set",
        "ss=1.5",
    ]);
    assert!(ok, "{err}");
    let bench = |extra: &[&str]| {
        let mut args = vec![
            "bench",
            "render",
            run.to_str().unwrap(),
            "--data",
            data.to_str().unwrap(),
            "--views",
            "1",
            "--runs",
            "1",
        ];
        args.extend_from_slice(extra);
        let (ok, out, err) = svraster(&args);
        assert!(ok, "{err}");
        out
    };
    let v: serde_json::Value = serde_json::from_str(&bench(&["--json"])).unwrap();
    assert_eq!(
        (v["width"].as_u64(), v["supersample"].as_f64()),
        (Some(12), Some(1.5)),
        "{v}"
    );
    let v: serde_json::Value =
        serde_json::from_str(&bench(&["--json", "--downscale", "1", "--ss", "1"])).unwrap();
    assert_eq!(
        (v["width"].as_u64(), v["supersample"].as_f64()),
        (Some(24), Some(1.0)),
        "{v}"
    );
    let text = bench(&[]);
    assert!(
        text.contains("work per frame") && !text.contains("per iteration"),
        "{text}"
    );
}

/// Defect 11: a demo too large for this machine is refused before anything is written
/// (it aborted on memory with a half-written dataset), with a size that fits.
#[test]
fn demo_too_large_is_refused_before_writing() {
    let dir = tmp("demo-huge");
    let out = dir.path().join("out");
    let (ok, _, err) = svraster(&["demo", "--out", out.to_str().unwrap(), "--size", "16384"]);
    assert!(
        !ok && err.contains("use --size") && err.contains("GiB"),
        "{err}"
    );
    assert!(!out.exists(), "the refused demo created {}", out.display());
}

/// Defect 5: `--resume` of a run whose model.safetensors is truncated, empty or changed,
/// or whose optimizer file holds a NaN, names the damaged file and the way out (it said
/// "model and optimizer are from different iterations", and a NaN ran into an error
/// advising --set, which --resume refuses).
#[test]
fn resume_names_a_damaged_checkpoint_file() {
    let dir = tmp("resume-damaged");
    let data = small_data(dir.path(), "data", 4);
    let run = dir.path().join("run");
    let (ds, rs) = (data.to_str().unwrap(), run.to_str().unwrap());
    let (ok, _, err) = train_quick(ds, rs, "20", &[]);
    assert!(ok, "{err}");
    set_run_iters(&run, 30);
    let model = run.join("model.safetensors");
    let opt = run.join("optimizer.safetensors");
    let (good_model, good_opt) = (std::fs::read(&model).unwrap(), std::fs::read(&opt).unwrap());
    let resume = || svraster(&["train", ds, "--out", rs, "--resume"]);
    // Truncated, empty.
    for bytes in [&good_model[..good_model.len() / 2], &[][..]] {
        std::fs::write(&model, bytes).unwrap();
        let (ok, _, err) = resume();
        assert!(
            !ok && err.contains("model.safetensors is damaged") && err.contains("start a new run"),
            "{err}"
        );
    }
    // The lowest bit of the first SH coefficient changed: still a valid checkpoint, no
    // longer the saved one.
    let mut flipped = good_model.clone();
    let header = u64::from_le_bytes(flipped[..8].try_into().unwrap()) as usize;
    let meta: serde_json::Value = serde_json::from_slice(&flipped[8..8 + header]).unwrap();
    let sh0 = meta["sh0"]["data_offsets"][0].as_u64().unwrap() as usize;
    flipped[8 + header + sh0] ^= 0x01;
    std::fs::write(&model, &flipped).unwrap();
    let (ok, _, err) = resume();
    assert!(
        !ok && err.contains("does not match") && err.contains("optimizer.safetensors"),
        "{err}"
    );
    std::fs::write(&model, &good_model).unwrap();
    // A NaN in the optimizer's moments (the first value of its first tensor).
    let mut nan = good_opt.clone();
    let header = u64::from_le_bytes(nan[..8].try_into().unwrap()) as usize;
    nan[8 + header..12 + header].copy_from_slice(&f32::NAN.to_le_bytes());
    std::fs::write(&opt, &nan).unwrap();
    let (ok, _, err) = resume();
    assert!(
        !ok && err.contains("optimizer.safetensors is corrupt") && err.contains("NaN at entry 0"),
        "{err}"
    );
    assert!(!err.contains("--set"), "{err}");
    std::fs::write(&opt, &good_opt).unwrap();
    let (ok, _, err) = resume();
    assert!(ok, "the restored pair resumes: {err}");
}

/// Defect 6: the progress line shows the values of its own iteration (it showed
/// iteration 1's loss and PSNR until the first logged iteration), and a resumed run's
/// `elapsed_s` continues from the checkpoint's (it restarted at 0).
#[test]
fn progress_shows_current_values_and_elapsed_time_continues() {
    let dir = tmp("progress-values");
    let data = small_data(dir.path(), "data", 5);
    let run = dir.path().join("run");
    let (ds, rs) = (data.to_str().unwrap(), run.to_str().unwrap());
    let out = Command::new(env!("CARGO_BIN_EXE_svraster"))
        .args([
            "--validation",
            "train",
            ds,
            "--out",
            rs,
            "--preset",
            "quick",
            "--iters",
            "200",
            "--set",
            "grid_level=3",
            "--set",
            "log_every=1000",
        ])
        .env("SVRASTER_PROGRESS_EVERY", "0.02")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{err}");
    // Plain progress lines (stderr is not a terminal) between the first and the last.
    let psnr: Vec<String> = err
        .lines()
        .filter(|l| l.starts_with("train ") && !l.starts_with("train 200/") && l.contains("PSNR"))
        .filter_map(|l| {
            l.split("PSNR ")
                .nth(1)?
                .split_whitespace()
                .next()
                .map(String::from)
        })
        .collect();
    let distinct: std::collections::BTreeSet<&String> = psnr.iter().collect();
    assert!(
        psnr.len() >= 3 && distinct.len() >= 2,
        "progress lines show stale values: {psnr:?}\n{err}"
    );
    set_run_iters(&run, 260);
    let (ok, _, err) = svraster(&["train", ds, "--out", rs, "--resume"]);
    assert!(ok, "{err}");
    let at = |iter: u64| -> f64 {
        logged(&run)
            .iter()
            .find(|l| l["iter"].as_u64() == Some(iter))
            .and_then(|l| l["elapsed_s"].as_f64())
            .unwrap_or_else(|| panic!("no line for iteration {iter}"))
    };
    assert!(
        at(201) >= at(200) && at(260) >= at(201),
        "elapsed_s {} → {} → {}",
        at(200),
        at(201),
        at(260)
    );
}

/// Defect 4: a dataset moved after training started is recognised on `--resume` by its
/// training views (names and cameras) and the run continues there, its config.json
/// updated; other data is still refused.
#[test]
fn resume_follows_a_moved_dataset() {
    let dir = tmp("moved-data");
    let data = small_data(dir.path(), "data", 11);
    let other = small_data(dir.path(), "other", 12);
    let run = dir.path().join("run");
    let rs = run.to_str().unwrap();
    let (ok, _, err) = train_quick(data.to_str().unwrap(), rs, "20", &[]);
    assert!(ok, "{err}");
    set_run_iters(&run, 30);
    let moved = dir.path().join("moved");
    std::fs::rename(&data, &moved).unwrap();
    let (ok, _, err) = svraster(&["train", other.to_str().unwrap(), "--out", rs, "--resume"]);
    assert!(
        !ok && err.contains("trains on") && err.contains("differ"),
        "{err}"
    );
    let (ok, _, err) = svraster(&["train", moved.to_str().unwrap(), "--out", rs, "--resume"]);
    assert!(ok && err.contains("the run's data moved"), "{err}");
    assert_eq!(checkpoint_iter(&run), 30);
    let cfg: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("config.json")).unwrap()).unwrap();
    let recorded = std::path::PathBuf::from(cfg["data"].as_str().unwrap());
    assert_eq!(recorded, moved.canonicalize().unwrap());
    // Later commands of the run find it there.
    let (ok, _, err) = svraster(&["eval", rs]);
    assert!(ok, "{err}");
}
