//! `svraster import` and SVRaster checkpoints read directly: a model written as SVRaster
//! writes it (tools/svraster_checkpoint.py, without PyTorch) renders exactly as the model
//! it came from, directly and once imported with the background and supersampling given;
//! bad arguments are refused. Needs `python3`; skipped without it.

use super::*;

/// Writes our model `orig` as SVRaster's save lays it out, to `pt`
/// (tools/svraster_checkpoint.py, without PyTorch).
fn write_svraster_checkpoint(orig: &std::path::Path, pt: &std::path::Path) {
    let o = Command::new("python3")
        .arg(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../tools/svraster_checkpoint.py"
        ))
        .arg(orig)
        .arg(pt)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

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
    write_svraster_checkpoint(&orig, &pt);
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
        err.contains("without its config.yaml, read with a black background"),
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
        (vec!["import", p, "--out", p], "would replace an input"),
        (
            vec!["import", p, "--out", "m.bin"],
            "name the file NAME.safetensors",
        ),
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

/// The `config.yaml` SVRaster writes beside `checkpoints/` decides how its model is read
/// (renderer.py: white, black, else the frame's own mean; `model.ss`), for `import` and
/// for the `.pt` read directly; the options override it; a broken one is refused naming
/// the file.
#[test]
fn svraster_config_yaml_sets_background_and_ss() {
    if Command::new("python3").arg("--version").output().is_err() {
        println!("SKIPPED: python3 not found (the test writes an SVRaster checkpoint with it)");
        return;
    }
    let dir = tmp("import-config");
    let scene = svraster::data::demo::voxelize(4, 1).unwrap();
    let orig = dir.path().join("orig.safetensors");
    svraster::scene::checkpoint::save(&scene, &orig).unwrap();
    let ckpts = dir.path().join("model/checkpoints");
    std::fs::create_dir_all(&ckpts).unwrap();
    let pt = ckpts.join("iter000300_model.pt");
    write_svraster_checkpoint(&orig, &pt);
    let config = dir.path().join("model/config.yaml");
    let m = dir.path().join("m.safetensors");
    let import = |extra: &[&str]| -> (bool, Option<svraster::scene::Scene>, String) {
        let mut args = vec!["import", pt.to_str().unwrap(), "--out", m.to_str().unwrap()];
        args.extend_from_slice(extra);
        let (ok, _, err) = svraster(&args);
        (
            ok,
            ok.then(|| svraster::scene::checkpoint::load(&m).unwrap()),
            err,
        )
    };
    // SVRaster's dump: sections, other keys around the three read.
    let yaml = |white: &str, black: &str, ss: &str| {
        format!(
            "data:\n  res_downscale: 4.0\n  eval: false\nmodel:\n  black_background: {black}\n  \
             n_samp_per_vox: 1\n  ss: {ss}\n  white_background: {white}\noptimizer:\n  \
             geo_lr: 0.025\n"
        )
    };
    for (white, black, ss, bg, mean) in [
        ("true", "false", "1.5", [1.0; 3], false),
        ("false", "true", "1.0", [0.0; 3], false),
        ("false", "false", "2", [0.0; 3], true),
    ] {
        std::fs::write(&config, yaml(white, black, ss)).unwrap();
        let (ok, got, err) = import(&[]);
        assert!(ok, "{err}");
        let got = got.unwrap();
        assert!(err.contains("config.yaml: SVRaster's settings"), "{err}");
        let want_ss: f32 = ss.parse().unwrap();
        assert_eq!(
            (got.background, got.background_frame_mean, got.supersample),
            (bg, mean, want_ss),
            "white {white} black {black} ss {ss}"
        );
    }
    // The options win over the file.
    std::fs::write(&config, yaml("true", "false", "1.5")).unwrap();
    let (ok, got, err) = import(&["--background", "black", "--ss", "1"]);
    assert!(ok, "{err}");
    let got = got.unwrap();
    assert_eq!((got.background, got.supersample), ([0.0; 3], 1.0));
    // Read directly: the file's white background.
    let data = small_data(dir.path(), "data", 4);
    let (ok, _, err) = svraster(&[
        "eval",
        pt.to_str().unwrap(),
        "--data",
        data.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(err.contains("read with the background and ss of"), "{err}");
    // Broken files are refused naming the file.
    for (text, want) in [
        ("model: [unclosed\n", "not YAML"),
        ("data:\n  eval: false\n", "no `model:` section"),
        (
            "model:\n  white_background: maybe\n",
            "model.white_background is not true or false",
        ),
        ("model:\n  ss: 9\n", "model.ss is not a number from 1 to 4"),
    ] {
        std::fs::write(&config, text).unwrap();
        let (ok, _, err) = import(&[]);
        assert!(
            !ok && err.contains(want) && err.contains("config.yaml"),
            "{text}: {err}"
        );
    }
}

/// A model trained by SVRaster's own code renders here as SVRaster rendered it (issue
/// 34: this proves the forward pass is the paper's). The fixture is what the GPU kit's
/// `run.sh` step 6 keeps (`res.tgz`: `svr_tiny/`): SVRaster's checkpoint
/// (`checkpoints/iterNNNNNN_model.pt`), its `config.yaml` and its own renders of test
/// views (`test/ours_*/renders/r_N.png.png`) of `../shared/data/lego_400`'s val split.
/// It is not in the repository (SVRaster's output from fetched data): the test reads it
/// from `SVRASTER_SVR_FIXTURE=DIR`, else `../shared/data/svraster_lego_tiny`, and is
/// skipped, saying so, when neither exists. Every view must reach 50 dB PSNR against
/// SVRaster's render (8-bit PNGs on both sides: ±1 level everywhere is 48.1 dB).
#[test]
fn svraster_s_own_renders_match_ours() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let fixture = std::env::var_os("SVRASTER_SVR_FIXTURE")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join("shared/data/svraster_lego_tiny"));
    let lego = root.join("shared/data/lego_400");
    if !fixture.is_dir() || !lego.is_dir() {
        println!(
            "SKIPPED: needs an SVRaster fixture ({}: set SVRASTER_SVR_FIXTURE to the GPU \
             kit's svr_tiny/) and {}",
            fixture.display(),
            lego.display()
        );
        return;
    }
    let ckpt = std::fs::read_dir(fixture.join("checkpoints"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "pt"))
        .expect("checkpoints/iterNNNNNN_model.pt in the fixture");
    let config = std::fs::read_to_string(fixture.join("config.yaml")).unwrap();
    let value = |key: &str| -> String {
        config
            .lines()
            .find_map(|l| l.trim().strip_prefix(&format!("{key}:")))
            .unwrap_or_else(|| panic!("config.yaml has no {key}"))
            .trim()
            .to_string()
    };
    let background = if value("white_background") == "true" {
        "white"
    } else {
        "black"
    };
    let (ss, downscale) = (value("ss"), value("res_downscale"));
    let dir = tmp("svr-fixture");
    let model = dir.path().join("model.safetensors");
    let (ok, _, err) = svraster(&[
        "import",
        ckpt.to_str().unwrap(),
        "--out",
        model.to_str().unwrap(),
        "--background",
        background,
        "--ss",
        &ss,
    ]);
    assert!(ok, "{err}");
    let ours = dir.path().join("ours");
    let (ok, _, err) = svraster(&[
        "render",
        model.to_str().unwrap(),
        "--data",
        lego.to_str().unwrap(),
        "--split",
        "val",
        "--downscale",
        &downscale,
        "--out",
        ours.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let mut theirs: Vec<PathBuf> = std::fs::read_dir(fixture.join("test"))
        .unwrap()
        .flat_map(|e| std::fs::read_dir(e.unwrap().path().join("renders")).unwrap())
        .map(|e| e.unwrap().path())
        .collect();
    theirs.sort();
    assert!(!theirs.is_empty(), "no renders in the fixture");
    let mut worst = f64::INFINITY;
    for t in &theirs {
        let name = t.file_name().unwrap().to_str().unwrap();
        let stem = name.trim_end_matches(".png");
        let a = image::open(t).unwrap().to_rgb8();
        let b = image::open(ours.join(format!("{stem}.png")))
            .unwrap()
            .to_rgb8();
        assert_eq!(a.dimensions(), b.dimensions(), "{name}");
        let se: f64 = a
            .as_raw()
            .iter()
            .zip(b.as_raw())
            .map(|(&x, &y)| (f64::from(x) - f64::from(y)).powi(2))
            .sum();
        let mse = se / a.as_raw().len() as f64 / 255f64.powi(2);
        let psnr = -10.0 * mse.max(1e-12).log10();
        println!("{stem}: {psnr:.2} dB against SVRaster's render");
        worst = worst.min(psnr);
        assert!(
            psnr >= 50.0,
            "{stem}: {psnr:.2} dB against SVRaster's render"
        );
    }
    println!(
        "{} views of {}: worst {worst:.2} dB",
        theirs.len(),
        ckpt.display()
    );
}
