//! What an output may be (issue "Robust"): a symlink is followed, a FIFO or character
//! device is written in place, a folder is refused before any work; no output replaces a
//! run's own files or a file being read; a failed start leaves nothing behind; a resume
//! keeps the run's history. Special files are made in a temporary folder, never `/dev`.

use super::*;

/// The files of a run directory with their bytes.
fn snapshot(run: &std::path::Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<_> = std::fs::read_dir(run)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file())
        .map(|p| {
            let bytes = std::fs::read(&p).unwrap();
            (p.file_name().unwrap().to_string_lossy().into_owned(), bytes)
        })
        .collect();
    v.sort();
    v
}

/// A trained quick run on a small demo dataset: (temp dir, data, run).
fn quick_run(name: &str) -> (TempDir, PathBuf, PathBuf) {
    let dir = tmp(name);
    let data = small_data(dir.path(), "data", 21);
    let run = dir.path().join("run");
    let (ok, _, err) = train_quick(data.to_str().unwrap(), run.to_str().unwrap(), "10", &[]);
    assert!(ok, "{err}");
    (dir, data, run)
}

/// The `error:` line of a command's stderr (other lines are its notes); asserts there
/// is exactly one.
fn error_line(err: &str) -> &str {
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(lines.len(), 1, "one error line: {err}");
    lines[0]
}

fn mkfifo(p: &std::path::Path) {
    let ok = Command::new("mkfifo").arg(p).status().unwrap().success();
    assert!(ok, "mkfifo {}", p.display());
}

/// `export` through a FIFO, a symlink and a dangling symlink writes the same bytes as to
/// a plain file, leaving the FIFO a FIFO and the links links; a folder or a symlink to
/// one is refused with one line before the model is read. Before, every one of these was replaced by a regular file (`/dev/full` "wrote"
/// and exited 0; as root `--out /dev/null` replaced the machine's /dev/null).
#[test]
fn special_outputs_are_written_in_place_and_links_followed() {
    let (dir, _data, run) = quick_run("out-special");
    let d = dir.path();
    let r = run.to_str().unwrap();
    let plain = d.join("plain.ply");
    let (ok, _, err) = svraster(&["export", r, "--out", plain.to_str().unwrap()]);
    assert!(ok, "{err}");
    let want = std::fs::read(&plain).unwrap();

    // A FIFO: written in place, read by a reader on the other end.
    let fifo = d.join("pipe");
    mkfifo(&fifo);
    let reader = {
        let fifo = fifo.clone();
        std::thread::spawn(move || std::fs::read(fifo).unwrap())
    };
    let (ok, _, err) = svraster(&["export", r, "--out", fifo.to_str().unwrap()]);
    assert!(ok, "{err}");
    // Checked before the reader is joined: a replaced FIFO leaves it waiting forever.
    use std::os::unix::fs::FileTypeExt;
    assert!(
        std::fs::symlink_metadata(&fifo)
            .unwrap()
            .file_type()
            .is_fifo(),
        "the FIFO was replaced"
    );
    assert_eq!(
        reader.join().unwrap(),
        want,
        "the FIFO's reader got other bytes"
    );

    // Symlinks: the target is written, the link stays; a dangling link makes its target.
    let target = d.join("target.ply");
    std::fs::write(&target, b"old").unwrap();
    for (link, to) in [
        (d.join("link.ply"), target.clone()),
        (d.join("dangling.ply"), d.join("new.ply")),
    ] {
        std::os::unix::fs::symlink(&to, &link).unwrap();
        let (ok, _, err) = svraster(&["export", r, "--out", link.to_str().unwrap()]);
        assert!(ok, "{}: {err}", link.display());
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        assert_eq!(std::fs::read(&to).unwrap(), want, "{}", to.display());
    }

    // Refused before any work: a folder, a link to one, a mesh's folder.
    let folder = d.join("folder.ply");
    std::fs::create_dir(&folder).unwrap();
    std::os::unix::fs::symlink(&folder, d.join("to_folder.ply")).unwrap();
    for (cmd, out) in [
        ("export", folder.clone()),
        ("export", d.join("to_folder.ply")),
        ("mesh", folder.clone()),
    ] {
        let (ok, _, err) = svraster(&[cmd, r, "--out", out.to_str().unwrap()]);
        assert!(!ok, "{cmd} --out {} accepted", out.display());
        assert!(error_line(&err).contains("is a directory"), "{cmd}: {err}");
    }
    assert!(folder.read_dir().unwrap().next().is_none());
}

/// No command's output replaces a run's own files (`fuse`/`mesh`/`import` replaced the
/// trained model, `export --format splat` config.json), a file it reads, or takes a name
/// of a type it does not write; each is one line, and the run is byte for byte what it
/// was.
#[test]
fn no_output_replaces_a_runs_files_or_an_input() {
    let (dir, data, run) = quick_run("out-run-files");
    let d = dir.path();
    let (r, dd) = (run.to_str().unwrap(), data.to_str().unwrap());
    let before = snapshot(&run);
    let labels = d.join("labels");
    std::fs::create_dir(&labels).unwrap();
    let pt = d.join("x.pt");
    std::fs::write(&pt, b"not read: the output is refused first").unwrap();
    let run_files = [
        "model.safetensors",
        "optimizer.safetensors",
        "config.json",
        "stats.jsonl",
        "training.png",
    ];
    for name in run_files {
        let out = run.join(name);
        let o = out.to_str().unwrap();
        let l = labels.to_str().unwrap();
        let cases: [Vec<&str>; 5] = [
            vec!["fuse", r, "--from", l, "--out", o],
            vec!["mesh", r, "--out", o],
            vec!["export", r, "--format", "splat", "--out", o],
            vec!["export", r, "--format", "quantized", "--out", o],
            vec!["import", pt.to_str().unwrap(), "--out", o],
        ];
        for args in cases {
            let (ok, _, err) = svraster(&args);
            assert!(!ok, "{args:?} accepted");
            assert!(
                error_line(&err).contains("would replace the run's own"),
                "{args:?}: {err}"
            );
        }
    }
    // The dataset and the model being read.
    let model = run.join("model.safetensors");
    let elsewhere = d.join("elsewhere");
    std::fs::create_dir(&elsewhere).unwrap();
    let link = elsewhere.join("m.safetensors");
    std::os::unix::fs::symlink(&model, &link).unwrap();
    let in_data = data.join("mesh.ply");
    for args in [
        vec![
            "export",
            r,
            "--format",
            "quantized",
            "--out",
            link.to_str().unwrap(),
        ],
        vec!["mesh", r, "--data", dd, "--out", in_data.to_str().unwrap()],
    ] {
        let (ok, _, err) = svraster(&args);
        assert!(!ok, "{args:?} accepted");
        assert!(
            error_line(&err).contains("would replace"),
            "{args:?}: {err}"
        );
    }
    assert!(!in_data.exists());
    // Types a command does not write.
    for args in [
        vec!["mesh", r, "--out", "m.txt"],
        vec!["export", r, "--out", "v.glb"],
        vec![
            "fuse",
            r,
            "--from",
            labels.to_str().unwrap(),
            "--out",
            "f.ply",
        ],
    ] {
        let (ok, _, err) = svraster(&args);
        assert!(!ok, "{args:?} accepted");
        assert!(err.contains("is written as"), "{args:?}: {err}");
    }
    assert_eq!(snapshot(&run), before, "the run's files changed");
}

/// A start that fails leaves nothing behind: a new run whose held-out split is empty
/// (it failed after making RUN/ and left RUN/.lock), a path render that fails after
/// making its folder. A folder that existed stays.
#[test]
fn a_failed_start_leaves_nothing_behind() {
    let dir = tmp("out-failed-start");
    let d = dir.path();
    let data = d.join("data");
    write_demo(&data, 24, [4, 1, 1], 8);
    // A held-out split without frames.
    let test = data.join("transforms_test.json");
    let mut doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&test).unwrap()).unwrap();
    doc["frames"] = serde_json::json!([]);
    std::fs::write(&test, doc.to_string()).unwrap();
    let run = d.join("runs/new");
    let (ok, _, err) = train_quick(
        data.to_str().unwrap(),
        run.to_str().unwrap(),
        "5",
        &["--eval-every", "2"],
    );
    assert!(!ok, "trained with an empty held-out split");
    assert!(error_line(&err).contains("transforms_test.json"), "{err}");
    assert!(!d.join("runs").exists(), "the failed run left its folder");
    // An existing, empty folder is kept.
    std::fs::create_dir(d.join("kept")).unwrap();
    let (ok, _, _) = train_quick(
        data.to_str().unwrap(),
        d.join("kept").to_str().unwrap(),
        "5",
        &["--eval-every", "2"],
    );
    assert!(!ok);
    assert!(d.join("kept").is_dir());

    // A path render that fails in its first frame (a supersampled size past the
    // renderer's edge).
    let good = d.join("good");
    let (ok, _, err) = train_quick(data.to_str().unwrap(), good.to_str().unwrap(), "5", &[]);
    assert!(ok, "{err}");
    let frames = d.join("frames");
    let (ok, _, err) = svraster(&[
        "render",
        good.to_str().unwrap(),
        "--path",
        "orbit",
        "--frames",
        "2",
        "--size",
        "60000x60000",
        "--ss",
        "1.5",
        "--out",
        frames.to_str().unwrap(),
    ]);
    assert!(!ok, "rendered past the edge");
    assert!(
        !frames.exists(),
        "the failed render left {}: {err}",
        frames.display()
    );
}

/// A resume that fails before its first checkpoint leaves config.json as it was (an
/// extension rewrote it at the start, so the run recorded iterations it never trained),
/// and a resume keeps the held-out scores of `--eval-every` up to its checkpoint (they
/// were dropped).
#[test]
fn resume_keeps_the_runs_record() {
    let dir = tmp("out-resume");
    let data = small_data(dir.path(), "data", 5);
    let run = dir.path().join("run");
    let (r, dd) = (run.to_str().unwrap(), data.to_str().unwrap());
    let (ok, _, err) = train_quick(dd, r, "10", &["--eval-every", "5"]);
    assert!(ok, "{err}");
    let evals = |run: &std::path::Path| {
        stats_lines(run)
            .iter()
            .filter_map(|l| l["eval"]["iter"].as_u64())
            .collect::<Vec<_>>()
    };
    assert_eq!(evals(&run), [5, 10]);
    // Extended by 10 iterations: the scores at 5 and 10 stay, 15 and 20 are added.
    let (ok, _, err) = svraster(&[
        "train",
        dd,
        "--out",
        r,
        "--resume",
        "--iters",
        "20",
        "--eval-every",
        "5",
    ]);
    assert!(ok, "{err}");
    assert_eq!(evals(&run), [5, 10, 15, 20]);

    // The optimizer's moments poisoned: the extension stops on an infinite value.
    let opt = run.join("optimizer.safetensors");
    let bytes = std::fs::read(&opt).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
    let tensors: Vec<(String, Vec<u8>, Vec<usize>)> = st
        .tensors()
        .into_iter()
        .map(|(name, t)| {
            let mut data = t.data().to_vec();
            // Finite (the loader refuses NaN), but the first step overflows.
            let poison = match name.as_str() {
                "geo.m" => Some(3e38f32),
                "geo.v" => Some(0.0),
                _ => None,
            };
            if let Some(x) = poison {
                for c in data.chunks_exact_mut(4) {
                    c.copy_from_slice(&x.to_le_bytes());
                }
            }
            (name, data, t.shape().to_vec())
        })
        .collect();
    let views: Vec<(String, safetensors::tensor::TensorView)> = tensors
        .iter()
        .map(|(n, d, s)| {
            let v = safetensors::tensor::TensorView::new(safetensors::Dtype::F32, s.clone(), d)
                .unwrap();
            (n.clone(), v)
        })
        .collect();
    let poisoned = safetensors::serialize(views, header.metadata().clone()).unwrap();
    std::fs::write(&opt, poisoned).unwrap();
    let config = std::fs::read(run.join("config.json")).unwrap();
    let (ok, _, err) = svraster(&["train", dd, "--out", r, "--resume", "--iters", "30"]);
    assert!(!ok, "trained on overflowing moments");
    assert!(err.to_lowercase().contains("finite"), "{err}");
    assert_eq!(
        std::fs::read(run.join("config.json")).unwrap(),
        config,
        "a failed resume rewrote config.json"
    );
}
