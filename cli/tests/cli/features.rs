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
    let (ok, _, err) = svraster(&[
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
    ]);
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
