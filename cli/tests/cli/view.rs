//! `svraster view` under a virtual X server (xvfb-run; skipped with a printed reason
//! without it): from a training camera its screenshot is `render`'s image of that view;
//! the overlay, the frusta and the depth and normal modes draw where they should; a
//! quantized checkpoint opens; bad arguments are refused before a window opens.

use super::*;

fn have_xvfb() -> bool {
    if Command::new("xvfb-run").arg("--help").output().is_ok() {
        return true;
    }
    println!("SKIPPED: xvfb-run not found (tools/setup.sh installs xvfb)");
    false
}

/// `xvfb-run -a svraster --validation view ARGS…`.
fn view(args: &[&str]) -> (bool, String, String) {
    let out = Command::new("xvfb-run")
        .args(["-a", "-s", "-screen 0 640x480x24"])
        .arg(env!("CARGO_BIN_EXE_svraster"))
        .arg("--validation")
        .arg("view")
        .args(args)
        .output()
        .expect("run xvfb-run");
    let r = (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    );
    assert!(
        !r.2.contains("[validation]"),
        "validation messages: {}",
        r.2
    );
    r
}

fn rgb(path: &std::path::Path) -> image::RgbImage {
    image::open(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .to_rgb8()
}

/// PSNR (dB) of two 8-bit images of one size.
fn psnr(a: &image::RgbImage, b: &image::RgbImage) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions());
    let n = a.as_raw().len() as f64;
    let mse = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(&x, &y)| (x as f64 - y as f64).powi(2))
        .sum::<f64>()
        / n;
    10.0 * (255.0f64 * 255.0 / mse.max(1e-12)).log10()
}

/// A trained run on the small demo data and its first training view's file stem.
fn trained(dir: &std::path::Path) -> (PathBuf, PathBuf, String) {
    let data = small_data(dir, "data", 11);
    let run = dir.join("run");
    let (ok, _, err) = train_quick(data.to_str().unwrap(), run.to_str().unwrap(), "150", &[]);
    assert!(ok, "train: {err}");
    let t: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data.join("transforms_train.json")).unwrap())
            .unwrap();
    let stem = std::path::Path::new(t["frames"][0]["file_path"].as_str().unwrap())
        .file_stem()
        .unwrap()
        .to_string_lossy()
        .into_owned();
    (data, run, stem)
}

#[test]
fn view_from_a_training_camera_is_the_render_of_it() {
    if !have_xvfb() {
        return;
    }
    let dir = tmp("view");
    let (_data, run, stem) = trained(dir.path());
    let run_s = run.to_str().unwrap();
    let renders = dir.path().join("renders");
    let (ok, _, err) = svraster(&[
        "render",
        run_s,
        "--split",
        "train",
        "--normal",
        "--out",
        renders.to_str().unwrap(),
    ]);
    assert!(ok, "render: {err}");
    let shot = |name: &str, extra: &[&str]| {
        let p = dir.path().join(name);
        let mut args = vec![run_s, "--camera", "0", "--frames", "3", "--screenshot"];
        args.push(p.to_str().unwrap());
        args.extend_from_slice(extra);
        let (ok, out, err) = view(&args);
        assert!(ok, "view {extra:?}: {err}");
        println!("view {extra:?}: {out}");
        rgb(&p)
    };
    // Colour: the window takes the camera's size and composites over the model's
    // background in display values, as render does (measured: 54 dB, every value within
    // 2; blending in linear light instead gave 27.5 dB).
    let plain = shot("colour.png", &["--no-hud", "--hide-cameras"]);
    let truth = rgb(&renders.join(format!("{stem}.png")));
    let p = psnr(&plain, &truth);
    let same = plain
        .as_raw()
        .iter()
        .zip(truth.as_raw())
        .filter(|(a, b)| (**a as i32 - **b as i32).abs() <= 2)
        .count() as f64
        / plain.as_raw().len() as f64;
    println!(
        "view vs render of {stem}: PSNR {p:.1} dB, {:.1} % within 2",
        100.0 * same
    );
    assert!(
        p > 45.0 && same > 0.99,
        "PSNR {p:.1} dB, {same:.3} within 2"
    );
    // Normal: as render's NAME_normal.png, over black.
    let normal = shot(
        "normal.png",
        &["--no-hud", "--hide-cameras", "--mode", "normal"],
    );
    let nt = rgb(&renders.join(format!("{stem}_normal.png")));
    let pn = psnr(&normal, &nt);
    println!("normal view vs render: PSNR {pn:.1} dB");
    assert!(pn > 45.0, "normal PSNR {pn:.1} dB");
    // Depth: grey, black where nothing is hit, bright and dark parts.
    let depth = shot(
        "depth.png",
        &["--no-hud", "--hide-cameras", "--mode", "depth"],
    );
    assert!(depth.pixels().all(|p| p[0] == p[1] && p[1] == p[2]));
    let lit: Vec<u8> = depth.pixels().map(|p| p[0]).filter(|&v| v > 0).collect();
    let (lo, hi) = (lit.iter().min().unwrap(), lit.iter().max().unwrap());
    println!(
        "depth view: {} of {} pixels lit, grey {lo}..{hi}",
        lit.len(),
        depth.pixels().len()
    );
    assert!(
        lit.len() > depth.pixels().len() / 5 && hi - lo > 20,
        "{} {lo} {hi}",
        lit.len()
    );
}

#[test]
fn view_draws_overlay_and_frusta_and_opens_quantized_checkpoints() {
    if !have_xvfb() {
        return;
    }
    let dir = tmp("view-hud");
    let (data, run, _) = trained(dir.path());
    let run_s = run.to_str().unwrap();
    let shot = |name: &str, model: &str, extra: &[&str]| {
        let p = dir.path().join(name);
        let mut args = vec![model, "--size", "320x200", "--frames", "3", "--screenshot"];
        args.push(p.to_str().unwrap());
        args.extend_from_slice(extra);
        let (ok, out, err) = view(&args);
        assert!(ok, "view {extra:?}: {err}");
        println!("view {extra:?}: {out}");
        rgb(&p)
    };
    let bare = shot("bare.png", run_s, &["--no-hud", "--hide-cameras"]);
    let hud = shot("hud.png", run_s, &["--hide-cameras"]);
    let frusta = shot("frusta.png", run_s, &["--no-hud"]);
    // The overlay darkens a box in the top-left corner and leaves the bottom alone.
    let diff = |a: &image::RgbImage, b: &image::RgbImage, x0: u32, x1: u32, y0: u32, y1: u32| {
        let mut n = 0;
        for y in y0..y1 {
            for x in x0..x1 {
                if a.get_pixel(x, y) != b.get_pixel(x, y) {
                    n += 1;
                }
            }
        }
        n
    };
    let top = diff(&bare, &hud, 0, 60, 0, 40);
    let bottom = diff(&bare, &hud, 0, 320, 100, 200);
    println!("overlay: {top} of 2400 top-left pixels changed, {bottom} below it");
    assert!(top > 2000 && bottom == 0, "{top} {bottom}");
    // The other training cameras' frusta: orange lines (red over blue) where the bare
    // view has none.
    let lines = frusta
        .enumerate_pixels()
        .filter(|(x, y, p)| *p != bare.get_pixel(*x, *y) && p[0] as i32 > p[2] as i32 + 60)
        .count();
    println!("frusta: {lines} orange pixels");
    assert!(lines > 30, "{lines} frusta pixels");
    // A quantized checkpoint, with the run's cameras named by --data.
    let q = dir.path().join("model_q.safetensors");
    let (ok, _, err) = svraster(&[
        "export",
        run_s,
        "--format",
        "quantized",
        "--out",
        q.to_str().unwrap(),
    ]);
    assert!(ok, "export: {err}");
    let quant = shot(
        "quant.png",
        q.to_str().unwrap(),
        &[
            "--no-hud",
            "--hide-cameras",
            "--data",
            data.to_str().unwrap(),
        ],
    );
    let p = psnr(&quant, &bare);
    println!("quantized vs full model, same view: PSNR {p:.1} dB");
    assert!(p > 25.0, "{p}");
}

#[test]
fn view_refuses_bad_arguments_before_opening_a_window() {
    let dir = tmp("view-bad");
    let data = small_data(dir.path(), "data", 3);
    let model = dir.path().join("m.safetensors");
    let scene = svraster::data::demo::voxelize(3, 1).unwrap();
    svraster::scene::checkpoint::save(&scene, &model).unwrap();
    let m = model.to_str().unwrap();
    let d = data.to_str().unwrap();
    let cases: [(&[&str], &str); 5] = [
        (
            &[m, "--data", d, "--camera", "99"],
            "--camera 99: the train split has 6 cameras",
        ),
        (&[m, "--camera", "0"], "no dataset: pass --data"),
        (&[m, "--screenshot", "out.jpg"], "is written as .png"),
        (&[m, "--json"], "--json summarises a --screenshot run"),
        (&[m, "--samples", "4"], "--samples must be 1, 2 or 3"),
    ];
    for (args, want) in cases {
        let mut a = vec!["view"];
        a.extend_from_slice(args);
        let (ok, _, err) = svraster(&a);
        assert!(!ok && err.contains(want), "{args:?}: {err}");
    }
    let (ok, _, err) = svraster(&["view", dir.path().join("none").to_str().unwrap()]);
    assert!(!ok && err.contains("not found"), "{err}");
}
