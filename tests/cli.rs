//! The `demo`, `render` and `bench render` commands end to end (with validation on).

use std::path::PathBuf;
use std::process::Command;

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

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("svraster-cli-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

#[test]
fn demo_then_render_and_bench() {
    let dir = tmp("demo");
    let d = dir.to_str().unwrap();
    let (ok, out, err) = svraster(&["demo", "--out", d, "--size", "40", "--level", "5"]);
    assert!(ok, "demo failed: {out}\n{err}");
    assert!(out.contains("mean PSNR"), "{out}");
    // The voxelized primitives must resemble the ray-traced photos.
    let psnr: f64 = out
        .split("mean PSNR ")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .and_then(|s| s.parse().ok())
        .expect("PSNR in the demo output");
    assert!(psnr > 15.0, "demo PSNR {psnr}");
    for i in 0..10 {
        assert!(dir.join(format!("renders/r_{i}.png")).is_file());
        assert!(dir.join(format!("renders/r_{i}_depth.png")).is_file());
    }

    let r = dir.join("val_renders");
    let (ok, out, err) = svraster(&[
        "render",
        d, // a run directory holding model.safetensors
        "--data",
        dir.join("data").to_str().unwrap(),
        "--split",
        "val",
        "--downscale",
        "2",
        "--out",
        r.to_str().unwrap(),
        "--normal",
        "--ss",
        "1.5",
    ]);
    assert!(ok, "render failed: {out}\n{err}");
    let img = image::open(r.join("r_0.png"))
        .expect("rendered PNG")
        .to_rgb8();
    assert_eq!(img.dimensions(), (20, 20));
    assert!(r.join("r_0_normal.png").is_file());

    let (ok, out, err) = svraster(&[
        "bench",
        "render",
        dir.join("model.safetensors").to_str().unwrap(),
        "--data",
        dir.join("data").to_str().unwrap(),
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
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn render_rejects_bad_input_with_one_clear_error() {
    let dir = tmp("bad");
    std::fs::create_dir_all(&dir).unwrap();
    let d = dir.to_str().unwrap();
    let (ok, _, err) = svraster(&["render", d, "--data", d, "--out", d]);
    assert!(!ok && err.contains("model.safetensors"), "{err}");

    let bad = dir.join("bad.safetensors");
    std::fs::write(&bad, b"\x10\x00\x00\x00\x00\x00\x00\x00{not json}      ").unwrap();
    let (ok, _, err) = svraster(&["render", bad.to_str().unwrap(), "--data", d, "--out", d]);
    assert!(!ok && err.contains("bad.safetensors"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "one error line: {err}");
    let _ = std::fs::remove_dir_all(&dir);
}
