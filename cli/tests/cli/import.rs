//! `svraster import` and SVRaster checkpoints read directly: a model written as SVRaster
//! writes it (tools/svraster_checkpoint.py, without PyTorch) renders exactly as the model
//! it came from, directly and once imported with the background and supersampling given;
//! bad arguments are refused. Needs `python3`; skipped without it.

use super::*;

#[test]
fn svraster_checkpoints_render_as_the_model_they_hold() {
    if Command::new("python3").arg("--version").output().is_err() {
        println!("SKIPPED: python3 not found (the test writes an SVRaster checkpoint with it)");
        return;
    }
    let dir = tmp("import");
    let data = small_data(dir.path(), "data", 4);
    let mut scene = svraster::data::demo::voxelize(4, 1).unwrap();
    // What a .pt read directly gets: black, ss 1.5.
    scene.background = [0.0; 3];
    scene.supersample = 1.5;
    let orig = dir.path().join("orig.safetensors");
    svraster::scene::checkpoint::save(&scene, &orig).unwrap();
    let pt = dir.path().join("iter000300_model.pt");
    let o = Command::new("python3")
        .arg(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../tools/svraster_checkpoint.py"
        ))
        .arg(&orig)
        .arg(&pt)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let d = data.to_str().unwrap();
    let render = |model: &std::path::Path, out: &str| {
        let out = dir.path().join(out);
        let (ok, _, err) = svraster(&[
            "render",
            model.to_str().unwrap(),
            "--data",
            d,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(ok, "render {}: {err}", model.display());
        (out, err)
    };
    let (r_orig, _) = render(&orig, "r_orig");
    let (r_pt, err) = render(&pt, "r_pt");
    assert!(
        err.contains("an SVRaster checkpoint, read with a black background"),
        "{err}"
    );
    let mut frames = 0;
    for e in std::fs::read_dir(&r_orig).unwrap() {
        let name = e.unwrap().file_name();
        let a = std::fs::read(r_orig.join(&name)).unwrap();
        let b = std::fs::read(r_pt.join(&name)).unwrap();
        assert!(a == b, "{name:?} differs");
        frames += 1;
    }
    assert!(frames > 0);
    // Imported with a background and supersampling of its own.
    let m = dir.path().join("m.safetensors");
    let (ok, out, err) = svraster(&[
        "import",
        pt.to_str().unwrap(),
        "--out",
        m.to_str().unwrap(),
        "--background",
        "0.2,0.3,0.4",
        "--ss",
        "1",
        "--json",
    ]);
    assert!(ok, "import: {err}");
    let j: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    assert_eq!(j["voxels"], scene.num_voxels());
    assert_eq!(j["grid_points"], scene.num_grid_points());
    let got = svraster::scene::checkpoint::load(&m).unwrap();
    assert_eq!((got.background, got.supersample), ([0.2, 0.3, 0.4], 1.0));
    assert_eq!(
        (&got.geo, &got.sh0, &got.shs),
        (&scene.geo, &scene.sh0, &scene.shs)
    );
    println!("{frames} frames identical; imported: {out}");
    // SVRaster's Mip-NeRF 360 background: each frame's own mean colour.
    let fm = dir.path().join("fm.safetensors");
    let (ok, out, err) = svraster(&[
        "import",
        pt.to_str().unwrap(),
        "--out",
        fm.to_str().unwrap(),
        "--background",
        "frame-mean",
        "--json",
    ]);
    assert!(ok, "import: {err}");
    let j: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    assert_eq!(j["background"], "frame-mean");
    assert!(
        svraster::scene::checkpoint::load(&fm)
            .unwrap()
            .background_frame_mean
    );
    // Refused.
    let p = pt.to_str().unwrap();
    let ms = m.to_str().unwrap();
    let missing = dir.path().join("none.pt");
    for (args, want) in [
        (
            vec!["import", missing.to_str().unwrap(), "--out", ms],
            "not found",
        ),
        (vec!["import", p, "--out", p], "name it *.safetensors"),
        (
            vec!["import", p, "--out", ms, "--background", "red"],
            "expected white, black, frame-mean or R,G,B",
        ),
        (vec!["import", p, "--out", ms, "--ss", "9"], "--ss 9"),
        (
            vec!["import", orig.to_str().unwrap(), "--out", ms],
            "not a readable PyTorch checkpoint",
        ),
    ] {
        let (ok, _, err) = svraster(&args);
        assert!(!ok && err.contains(want), "{args:?}: {err}");
    }
}
