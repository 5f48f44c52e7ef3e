//! What users of the field's tools reach for (issue "What users of nerfstudio, Brush and
//! SVRaster reach for"), each through the command line.

use super::*;

/// `eval`, `render`, `bench render` (and `mesh`, `fuse`) of a run directory take the
/// dataset from its config.json when `--data` is left out; a bare checkpoint needs it.
#[test]
fn run_directories_know_their_data() {
    let dir = tmp("run-data");
    let data = small_data(dir.path(), "data", 6);
    let run = dir.path().join("run");
    let rs = run.to_str().unwrap();
    let (ok, _, err) = train_quick(data.to_str().unwrap(), rs, "10", &[]);
    assert!(ok, "{err}");
    let (ok, out, err) = svraster(&["eval", rs, "--json"]);
    assert!(ok && err.contains("(the run's; --data to choose)"), "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["views"].as_u64(), Some(1), "{v}");
    let renders = dir.path().join("renders");
    let (ok, _, err) = svraster(&["render", rs, "--out", renders.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert!(renders.join("r_0.png").is_file());
    let (ok, _, err) = svraster(&["bench", "render", rs, "--views", "1", "--runs", "1"]);
    assert!(ok, "{err}");
    // A checkpoint outside its run directory does not know its data.
    let bare = dir.path().join("bare.safetensors");
    std::fs::copy(run.join("model.safetensors"), &bare).unwrap();
    let (ok, _, err) = svraster(&["eval", bare.to_str().unwrap()]);
    assert!(!ok && err.contains("--data is needed"), "{err}");
}

/// A run that will take more than ~30 min on a CPU device says so once the rate is
/// known, with what shortens it (a default lego run on lavapipe showed an ETA of
/// 6 h 40 min without a word); on a GPU it says nothing.
#[test]
fn long_runs_on_cpu_devices_say_how_to_shorten_them() {
    use std::io::BufRead as _;
    let (ok, info, err) = svraster(&["info", "--json"]);
    assert!(ok, "{err}");
    let cpu = serde_json::from_str::<serde_json::Value>(&info).unwrap()["is_cpu"] == true;
    let dir = tmp("long-run");
    let data = small_data(dir.path(), "data", 7);
    let run = dir.path().join("run");
    // 2 million iterations: hours at the few hundred per second lavapipe makes here.
    let mut child = Command::new(env!("CARGO_BIN_EXE_svraster"))
        .args([
            "train",
            data.to_str().unwrap(),
            "--out",
            run.to_str().unwrap(),
            "--preset",
            "quick",
            "--iters",
            "2000000",
            "--set",
            "grid_level=3",
            "--set",
            "log_every=50",
        ])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = std::io::BufReader::new(child.stderr.take().unwrap()).lines();
    let (mut note, mut seen) = (None, Vec::new());
    for line in lines.by_ref() {
        let line = line.unwrap();
        if line.starts_with("note: at") {
            note = Some(line.clone());
        }
        seen.push(line);
        // Past the point where the note is due (≥ 50 iterations) by a margin.
        let far = logged(&run).iter().any(|l| l["iter"].as_u64() >= Some(500));
        if note.is_some() || far {
            break;
        }
    }
    let st = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(st.success());
    let rest: Vec<String> = lines.map_while(Result::ok).collect();
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130), "{seen:?} {rest:?}");
    if cpu {
        let note = note.unwrap_or_else(|| panic!("no long-run note: {seen:?}"));
        assert!(
            note.contains("more on")
                && note.contains("--downscale 2")
                && note.contains("--preset quick"),
            "{note}"
        );
    } else {
        assert!(note.is_none(), "a GPU run was called long: {note:?}");
    }
}

/// `train`, `render`, `mesh` and `export` print a JSON summary with `--json` (stdout is
/// the JSON alone: parsed whole here).
#[test]
fn json_summaries() {
    let dir = tmp("json-summaries");
    let data = small_data(dir.path(), "data", 8);
    let run = dir.path().join("run");
    let rs = run.to_str().unwrap();
    let json = |args: &[&str]| -> serde_json::Value {
        let (ok, out, err) = svraster(args);
        assert!(ok, "{args:?}: {err}");
        serde_json::from_str(&out).unwrap_or_else(|e| panic!("{args:?}: {e}: {out}"))
    };
    let t = json(&[
        "train",
        data.to_str().unwrap(),
        "--out",
        rs,
        "--preset",
        "quick",
        "--iters",
        "10",
        "--set",
        "grid_level=3",
        "--json",
    ]);
    assert_eq!(
        (t["iters"].as_u64(), t["interrupted"].as_bool()),
        (Some(10), Some(false)),
        "{t}"
    );
    assert!(
        t["voxels"].as_u64().unwrap() > 0 && t["seconds"].as_f64().is_some(),
        "{t}"
    );
    let renders = dir.path().join("renders");
    let r = json(&["render", rs, "--out", renders.to_str().unwrap(), "--json"]);
    assert_eq!(r["frames"].as_u64(), Some(1), "{r}");
    assert!(
        r["psnr"].as_f64().unwrap() > 5.0 && r["ms_per_frame"].as_f64().is_some(),
        "{r}"
    );
    // A model with a surface to mesh: the voxelized demo.
    let demo = dir.path().join("demo");
    let (ok, _, err) = svraster(&[
        "demo",
        "--out",
        demo.to_str().unwrap(),
        "--size",
        "32",
        "--voxelize",
        "--level",
        "5",
    ]);
    assert!(ok, "{err}");
    let ply = dir.path().join("m.ply");
    let m = json(&[
        "mesh",
        demo.join("run").to_str().unwrap(),
        "--data",
        demo.join("data").to_str().unwrap(),
        "--out",
        ply.to_str().unwrap(),
        "--json",
    ]);
    assert!(
        m["triangles"].as_u64().unwrap() > 100 && m["level"].as_u64().is_some(),
        "{m}"
    );
    for (format, ext) in [("ply", "ply"), ("quantized", "safetensors")] {
        let out = dir.path().join(format!("e.{ext}"));
        let e = json(&[
            "export",
            rs,
            "--format",
            format,
            "--out",
            out.to_str().unwrap(),
            "--json",
        ]);
        assert_eq!(e["format"], format);
        assert_eq!(
            e["bytes"].as_u64(),
            Some(std::fs::metadata(&out).unwrap().len()),
            "{e}"
        );
    }
}

/// `train --resume --iters N` extends a finished run: the milestones stay where its
/// schedule put them (config.json records `schedule_iters`), the extra iterations train
/// at the schedule's final state with checkpoints at the same spacing; a shorter N is
/// refused, and a finished run says how to extend it.
#[test]
fn resume_with_more_iterations_extends_a_finished_run() {
    let dir = tmp("extend");
    let data = small_data(dir.path(), "data", 9);
    let run = dir.path().join("run");
    let (ds, rs) = (data.to_str().unwrap(), run.to_str().unwrap());
    let (ok, _, err) = train_quick(ds, rs, "200", &[]);
    assert!(ok, "{err}");
    let config = || -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(run.join("config.json")).unwrap()).unwrap()
    };
    let before = config();
    let (ok, _, err) = svraster(&["train", ds, "--out", rs, "--resume"]);
    assert!(
        !ok && err.contains("already completed its 200") && err.contains("--iters N"),
        "{err}"
    );
    let (ok, _, err) = svraster(&["train", ds, "--out", rs, "--resume", "--iters", "150"]);
    assert!(!ok && err.contains("can only extend"), "{err}");
    let (ok, _, err) = svraster(&["train", ds, "--out", rs, "--resume", "--iters", "300"]);
    assert!(ok && err.contains("extending the run to 300"), "{err}");
    assert_eq!(checkpoint_iter(&run), 300);
    let after = config();
    assert_eq!(after["config"]["iters"], 300);
    assert_eq!(after["config"]["schedule_iters"], 200);
    for k in [
        "sh_degree_up",
        "lr_decay_at",
        "ss_from",
        "tv_until",
        "adapt",
        "lr_geo",
    ] {
        assert_eq!(after["schedule"][k], before["schedule"][k], "{k} moved");
    }
    let cps: Vec<u64> = after["schedule"]["checkpoints"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_u64().unwrap())
        .collect();
    assert_eq!(
        cps,
        [50, 100, 150, 200, 250],
        "checkpoints at the same spacing"
    );
    let last = logged(&run).last().unwrap().clone();
    assert_eq!(last["iter"], 300);
}

/// `train --eval-every N` scores the held-out split during training: `{"eval": …}`
/// lines in stats.jsonl every N iterations and at the end, a line on the progress, and a
/// held-out series in training.png.
#[test]
fn eval_every_logs_held_out_quality() {
    let dir = tmp("eval-every");
    let data = small_data(dir.path(), "data", 10);
    let run = dir.path().join("run");
    let (ok, _, err) = train_quick(
        data.to_str().unwrap(),
        run.to_str().unwrap(),
        "50",
        &["--eval-every", "20"],
    );
    assert!(ok, "{err}");
    let evals: Vec<serde_json::Value> = stats_lines(&run)
        .into_iter()
        .filter_map(|l| l.get("eval").cloned())
        .collect();
    let iters: Vec<u64> = evals.iter().map(|e| e["iter"].as_u64().unwrap()).collect();
    assert_eq!(iters, [20, 40, 50], "{evals:?}");
    for e in &evals {
        assert_eq!(e["split"], "test");
        assert!(
            e["psnr"].as_f64().unwrap() > 5.0 && e["ssim"].as_f64().is_some(),
            "{e}"
        );
    }
    assert!(err.contains("eval @40: 1 views of `test`: PSNR"), "{err}");
    assert!(run.join("training.png").is_file());
    // The last evaluation is the model's own held-out score.
    let (ok, out, err) = svraster(&["eval", run.to_str().unwrap(), "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let last = evals.last().unwrap()["psnr"].as_f64().unwrap();
    assert!(
        (v["psnr"].as_f64().unwrap() - last).abs() < 1e-6,
        "{v} vs {last}"
    );
}

/// `train --config FILE` starts a run from another run's config.json (or a bare
/// configuration object): its settings are the base, --iters/--seed/--set apply on top;
/// with --preset or --resume, or a file that is not a configuration, it is refused.
#[test]
fn config_file_is_the_base_of_a_new_run() {
    let dir = tmp("config-file");
    let data = small_data(dir.path(), "data", 13);
    let ds = data.to_str().unwrap();
    let a = dir.path().join("a");
    let (ok, _, err) = train_quick(ds, a.to_str().unwrap(), "20", &["--set", "lambda_ssim=0.1"]);
    assert!(ok, "{err}");
    let base = a.join("config.json");
    let b = dir.path().join("b");
    let (ok, _, err) = svraster(&[
        "train",
        ds,
        "--out",
        b.to_str().unwrap(),
        "--config",
        base.to_str().unwrap(),
        "--iters",
        "10",
        "--set",
        "sh_degree=1",
    ]);
    assert!(ok, "{err}");
    let cfg = |run: &std::path::Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(run.join("config.json")).unwrap()).unwrap()
    };
    let (ca, cb) = (cfg(&a), cfg(&b));
    assert_eq!(cb["preset"], ca["preset"]);
    assert_eq!(cb["config"]["grid_level"], 3);
    assert_eq!(cb["config"]["lambda_ssim"], ca["config"]["lambda_ssim"]);
    assert_eq!(
        (
            cb["config"]["iters"].as_u64(),
            cb["config"]["sh_degree"].as_u64()
        ),
        (Some(10), Some(1))
    );
    // A bare configuration object works too.
    let bare = dir.path().join("bare.json");
    std::fs::write(&bare, serde_json::to_string(&ca["config"]).unwrap()).unwrap();
    let c = dir.path().join("c");
    let (ok, _, err) = svraster(&[
        "train",
        ds,
        "--out",
        c.to_str().unwrap(),
        "--config",
        bare.to_str().unwrap(),
        "--iters",
        "5",
    ]);
    assert!(ok, "{err}");
    assert_eq!(
        cfg(&c)["config"]["lambda_ssim"],
        ca["config"]["lambda_ssim"]
    );
    let d = dir.path().join("d");
    for (extra, needle) in [
        (vec!["--preset", "quick"], "drop --preset"),
        (vec!["--resume"], "drop --seed/--set/--config"),
    ] {
        let mut args = vec![
            "train",
            ds,
            "--out",
            d.to_str().unwrap(),
            "--config",
            base.to_str().unwrap(),
        ];
        args.extend(extra);
        let (ok, _, err) = svraster(&args);
        assert!(!ok && err.contains(needle), "{err}");
    }
    let junk = dir.path().join("junk.json");
    std::fs::write(&junk, "{\"nope\": 1}").unwrap();
    let (ok, _, err) = svraster(&[
        "train",
        ds,
        "--out",
        d.to_str().unwrap(),
        "--config",
        junk.to_str().unwrap(),
    ]);
    assert!(
        !ok && err.contains("junk.json") && err.contains("not a training configuration"),
        "{err}"
    );
    assert!(!d.exists(), "a refused run made its directory");
}

/// `export --format splat` writes the 3D Gaussian Splatting PLY layout splat viewers read:
/// its property names in order, one Gaussian per voxel, the SH copied (channel-major
/// f_rest), the identity rotation, ln(edge/√12) scales and a finite opacity logit; read
/// back here by a reader of its own.
#[test]
fn splat_export_has_the_3dgs_layout() {
    let dir = tmp("splat");
    let data = small_data(dir.path(), "data", 14);
    let run = dir.path().join("run");
    let (ok, _, err) = train_quick(data.to_str().unwrap(), run.to_str().unwrap(), "30", &[]);
    assert!(ok, "{err}");
    let out = dir.path().join("g.ply");
    let (ok, _, err) = svraster(&[
        "export",
        run.to_str().unwrap(),
        "--format",
        "splat",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let bytes = std::fs::read(&out).unwrap();
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let header = std::str::from_utf8(&bytes[..end]).unwrap();
    let mut names = Vec::new();
    let mut count = 0usize;
    for line in header.lines() {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["element", "vertex", n] => count = n.parse().unwrap(),
            ["property", "float", name] => names.push(name.to_string()),
            _ => {}
        }
    }
    let mut want: Vec<String> = ["x", "y", "z", "nx", "ny", "nz"].map(String::from).to_vec();
    want.extend((0..3).map(|c| format!("f_dc_{c}")));
    want.extend((0..45).map(|k| format!("f_rest_{k}")));
    want.push("opacity".into());
    want.extend((0..3).map(|a| format!("scale_{a}")));
    want.extend((0..4).map(|a| format!("rot_{a}")));
    assert_eq!(names, want);
    let scene = svraster::scene::checkpoint::load(&run.join("model.safetensors")).unwrap();
    assert_eq!(count, scene.num_voxels());
    assert_eq!(bytes.len() - end, count * names.len() * 4);
    let m = scene.shs_per_voxel();
    assert!(m > 0, "the quick preset trains SH");
    for i in [0, count / 2, count - 1] {
        let rec = &bytes[end + i * names.len() * 4..end + (i + 1) * names.len() * 4];
        let f = |k: usize| f32::from_le_bytes(rec[4 * k..4 * k + 4].try_into().unwrap());
        let at = |name: &str| f(names.iter().position(|n| n == name).unwrap());
        for c in 0..3 {
            assert_eq!(at(&format!("f_dc_{c}")), scene.sh0[i][c]);
            for k in 0..15 {
                let want = if k < m {
                    scene.shs[(i * m + k) * 3 + c]
                } else {
                    0.0
                };
                assert_eq!(
                    at(&format!("f_rest_{}", c * 15 + k)),
                    want,
                    "voxel {i} c {c} k {k}"
                );
            }
        }
        let edge = scene.world.length_to_world(scene.voxel_size(i));
        assert!((f64::from(at("scale_0")) - (edge / 12f64.sqrt()).ln()).abs() < 1e-5);
        assert_eq!(
            [at("rot_0"), at("rot_1"), at("rot_2"), at("rot_3")],
            [1.0, 0.0, 0.0, 0.0]
        );
        assert!(at("opacity").is_finite());
        let lo = scene.voxel_min(i);
        let s = scene.voxel_size(i);
        let c = scene
            .world
            .point_to_world(std::array::from_fn(|a| lo[a] + 0.5 * s));
        assert!(
            (f64::from(at("x")) - c[0]).abs() < 1e-5 && (f64::from(at("z")) - c[2]).abs() < 1e-5
        );
    }
}

/// `mesh --out X.glb` writes glTF 2.0 binary that the `gltf` crate reads back: one
/// triangle primitive with the PLY's positions, normals, vertex colours and triangles.
#[test]
fn mesh_as_gltf_binary_reads_back() {
    let dir = tmp("glb");
    let demo = dir.path().join("demo");
    let (ok, _, err) = svraster(&[
        "demo",
        "--out",
        demo.to_str().unwrap(),
        "--size",
        "32",
        "--voxelize",
        "--level",
        "5",
    ]);
    assert!(ok, "{err}");
    let (run, data) = (demo.join("run"), demo.join("data"));
    let mesh = |out: &std::path::Path| {
        let (ok, _, err) = svraster(&[
            "mesh",
            run.to_str().unwrap(),
            "--data",
            data.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--vertex-colors",
        ]);
        assert!(ok, "{err}");
    };
    let (ply, glb) = (dir.path().join("m.ply"), dir.path().join("m.glb"));
    mesh(&ply);
    mesh(&glb);
    let (positions, triangles) = svraster::mesh::ply::read(&ply).unwrap();
    let bytes = std::fs::read(&glb).unwrap();
    let doc = gltf::Gltf::from_slice(&bytes).unwrap();
    let blob = doc.blob.clone().expect("a BIN chunk");
    let meshes: Vec<_> = doc.meshes().collect();
    assert_eq!(meshes.len(), 1);
    let prims: Vec<_> = meshes[0].primitives().collect();
    assert_eq!(prims.len(), 1);
    assert_eq!(prims[0].mode(), gltf::mesh::Mode::Triangles);
    let r = prims[0].reader(|_| Some(&blob[..]));
    let pos: Vec<[f32; 3]> = r.read_positions().unwrap().collect();
    assert_eq!(pos.len(), positions.len());
    for (a, b) in pos.iter().zip(&positions) {
        for k in 0..3 {
            assert!((f64::from(a[k]) - b[k]).abs() <= 1e-6 * b[k].abs().max(1.0));
        }
    }
    let idx: Vec<u32> = r.read_indices().unwrap().into_u32().collect();
    let tris: Vec<[u32; 3]> = idx.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
    assert_eq!(tris, triangles);
    assert_eq!(r.read_normals().unwrap().count(), pos.len());
    let colors: Vec<[u8; 4]> = r.read_colors(0).unwrap().into_rgba_u8().collect();
    assert_eq!(colors.len(), pos.len());
    assert!(
        colors.iter().any(|c| c[..3] != [0, 0, 0]),
        "vertex colours carried"
    );
    // Y-up (glTF's axes): the scene's root node turns the demo's up, world +Z, into +Y;
    // the positions under it stay the world's. It stood on its side in three.js.
    let scene = doc.default_scene().expect("a default scene");
    let roots: Vec<_> = scene.nodes().collect();
    assert_eq!(roots.len(), 1);
    let m = roots[0].transform().matrix();
    let up = [m[2][0], m[2][1], m[2][2]]; // the image of +Z (column-major)
    assert!(
        (up[0].abs() + (up[1] - 1.0).abs() + up[2].abs()) < 1e-6,
        "+Z maps to {up:?}"
    );
}

/// `render --path`: an orbit and a fly-through of the training cameras as numbered PNGs
/// (a spiral of these all-around cameras is refused, pointing to the orbit)
/// of the asked size, a nerfstudio camera_path.json (its size, its frame count), and an
/// MP4 whose frame count and size ffprobe reads back (ffmpeg is in tools/setup.sh);
/// without ffmpeg the frames are kept and the message says how to get the video.
#[test]
fn camera_paths_render_frames_and_video() {
    let dir = tmp("paths");
    let data = small_data(dir.path(), "data", 15);
    let run = dir.path().join("run");
    let rs = run.to_str().unwrap();
    let (ok, _, err) = train_quick(data.to_str().unwrap(), rs, "20", &[]);
    assert!(ok, "{err}");
    let frames = |d: &std::path::Path| -> Vec<(u32, u32)> {
        let mut names: Vec<_> = std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        names.sort();
        names
            .iter()
            .map(|p| image::image_dimensions(p).unwrap())
            .collect()
    };
    for (kind, n, size) in [("orbit", "7", "40x30"), ("train", "5", "24x24")] {
        let out = dir.path().join(kind);
        let (ok, _, err) = svraster(&[
            "render",
            rs,
            "--path",
            kind,
            "--frames",
            n,
            "--size",
            size,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(ok, "{kind}: {err}");
        let (w, h) = size.split_once('x').unwrap();
        let want = (w.parse().unwrap(), h.parse().unwrap());
        assert_eq!(frames(&out), vec![want; n.parse().unwrap()], "{kind}");
        assert!(out.join("frame_00000.png").is_file());
    }
    let (ok, _, err) = svraster(&[
        "render",
        rs,
        "--path",
        "spiral",
        "--out",
        dir.path().join("sp").to_str().unwrap(),
    ]);
    assert!(
        !ok && err.contains("forward-facing") && err.contains("--path orbit"),
        "{err}"
    );
    // nerfstudio's camera_path.json: 3 cameras of the demo's ring, 32×20.
    let json = dir.path().join("camera_path.json");
    let ring: Vec<serde_json::Value> = (0..3)
        .map(|k| {
            let m = svraster::data::demo::orbit_pose(k as f64, 0.3);
            serde_json::json!({ "camera_to_world": m.concat(), "fov": 40.0, "aspect": 1.6 })
        })
        .collect();
    let doc = serde_json::json!({ "render_width": 32, "render_height": 20, "camera_path": ring });
    std::fs::write(&json, doc.to_string()).unwrap();
    let out = dir.path().join("ns");
    let (ok, _, err) = svraster(&[
        "render",
        rs,
        "--path",
        json.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert_eq!(frames(&out), vec![(32, 20); 3]);
    // The video.
    let mp4 = dir.path().join("orbit.mp4");
    let (ok, _, err) = svraster(&[
        "render",
        rs,
        "--path",
        "orbit",
        "--frames",
        "9",
        "--size",
        "35x27",
        "--out",
        mp4.to_str().unwrap(),
    ]);
    let have_ffmpeg = Command::new("ffprobe").arg("-version").output().is_ok();
    if !have_ffmpeg {
        assert!(
            !ok && err.contains("ffmpeg not found") && err.contains("orbit.mp4.frames"),
            "{err}"
        );
        assert_eq!(frames(&dir.path().join("orbit.mp4.frames")).len(), 9);
        println!("ffmpeg is not installed: checked the message and the kept frames only");
        return;
    }
    assert!(ok, "{err}");
    let probe = Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-count_frames",
            "-select_streams",
            "v:0",
            "-show_entries",
            "stream=codec_name,width,height,nb_read_frames",
            "-of",
            "json",
        ])
        .arg(&mp4)
        .output()
        .unwrap();
    let v: serde_json::Value = serde_json::from_slice(&probe.stdout).unwrap();
    let s = &v["streams"][0];
    assert_eq!(s["codec_name"], "h264", "{v}");
    assert_eq!(s["nb_read_frames"], "9", "{v}");
    // Odd sizes are padded to even for H.264's 4:2:0.
    assert_eq!(
        (s["width"].as_u64(), s["height"].as_u64()),
        (Some(36), Some(28)),
        "{v}"
    );
}
