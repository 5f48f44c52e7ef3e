//! Real-capture input: COLMAP models (binary and text), COLMAP's camera models, lens
//! removal at load, splits, and the real captures in ../shared/data when present.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use svraster::data::capture::{self, load_colmap, load_shots, natural_cmp, CaptureOptions, Shot};
use svraster::data::colmap::{self, ColmapCamera, ColmapImage, ColmapPoint, Reconstruction};
use svraster::data::image::save_rgb_png;
use svraster::data::lens::{CameraModel, Lens};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("svraster-capture-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Realistic parameters for each model at `w × h` (moderate distortion).
fn params(model: CameraModel, w: f64, h: f64) -> Vec<f64> {
    let (f, cx, cy) = (0.9 * w, 0.5 * w + 1.3, 0.5 * h - 0.7);
    let extra: &[f64] = match model {
        CameraModel::SimpleRadial | CameraModel::SimpleRadialFisheye => &[0.03],
        CameraModel::Radial | CameraModel::RadialFisheye => &[-0.05, 0.01],
        CameraModel::OpenCv => &[-0.06, 0.012, 0.001, -0.0015],
        CameraModel::OpenCvFisheye => &[0.02, -0.01, 0.003, -0.001],
        CameraModel::FullOpenCv => &[-0.05, 0.01, 0.001, -0.001, 0.002, 0.01, -0.003, 0.001],
        CameraModel::Fov => &[0.3],
        CameraModel::ThinPrismFisheye => {
            &[0.02, -0.01, 0.001, -0.001, 0.003, -0.001, 0.0005, -0.0004]
        }
        CameraModel::RadTanThinPrismFisheye => &[
            0.02, -0.01, 0.003, -0.001, 0.0002, -0.0001, 0.001, -0.001, 0.0005, -0.0002, 0.0004,
            0.0001,
        ],
        CameraModel::SimpleDivision | CameraModel::Division => &[-0.04],
        CameraModel::Eucm => &[0.4, 1.1],
        _ => &[],
    };
    let mut p = if model.param_names()[0] == "f" {
        vec![f, cx, cy]
    } else if model == CameraModel::Equirectangular {
        return vec![w, h];
    } else {
        vec![f, 1.02 * f, cx, cy]
    };
    p.extend_from_slice(extra);
    p
}

/// A reconstruction using every camera model, with points and tracks.
fn every_model_reconstruction() -> Reconstruction {
    let mut rng = common::Rng(5);
    let mut rec = Reconstruction::default();
    for (k, model) in CameraModel::all().enumerate() {
        let id = 10 + k as u32;
        rec.cameras.insert(
            id,
            ColmapCamera {
                id,
                model,
                width: 640 + k as u64,
                height: 480,
                params: params(model, 640.0 + k as f64, 480.0),
            },
        );
        let q: [f64; 4] = std::array::from_fn(|_| rng.range(-1.0, 1.0));
        let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        rec.images.insert(
            100 + k as u32,
            ColmapImage {
                id: 100 + k as u32,
                qvec: q.map(|v| v / n),
                tvec: std::array::from_fn(|_| rng.range(-3.0, 3.0)),
                camera_id: id,
                name: format!("dir/img {k}.jpg"),
                points2d: (0..k)
                    .map(|j| ([rng.range(0.0, 640.0), rng.range(0.0, 480.0)], j as i64 - 1))
                    .collect(),
            },
        );
    }
    rec.points = (0..7)
        .map(|i| ColmapPoint {
            id: 1000 + i,
            xyz: std::array::from_fn(|_| rng.range(-5.0, 5.0)),
            rgb: [i as u8, 200, 17],
            error: rng.unit(),
            track: (0..i as u32).map(|j| (100 + j, 2 * j)).collect(),
        })
        .collect();
    rec
}

#[test]
fn colmap_binary_and_text_models_read_back_identical() {
    let rec = every_model_reconstruction();
    let (b, t) = (tmp("bin"), tmp("txt"));
    colmap::write_bin(&b, &rec).unwrap();
    colmap::write_txt(&t, &rec).unwrap();
    let from_bin = colmap::read_model(&b).unwrap();
    let from_txt = colmap::read_model(&t).unwrap();
    assert_eq!(from_bin, rec);
    assert_eq!(from_txt, rec);
    // No points3D file at all is fine.
    std::fs::remove_file(b.join("points3D.bin")).unwrap();
    assert!(colmap::read_model(&b).unwrap().points.is_empty());
    // Every model name and id round-trips.
    for m in CameraModel::all() {
        assert_eq!(CameraModel::from_id(m.id()), Some(m));
        assert_eq!(CameraModel::from_name(m.name()), Some(m));
    }
    assert_eq!(CameraModel::all().count(), 18);
}

#[track_caller]
fn expect_err(dir: &Path, needles: &[&str]) {
    let e = match colmap::read_model(dir) {
        Ok(_) => panic!("a corrupt model was accepted (expected {needles:?})"),
        Err(e) => e.to_string(),
    };
    for n in needles {
        assert!(e.contains(n), "error `{e}` does not mention `{n}`");
    }
}

#[test]
fn colmap_bad_models_are_named() {
    let rec = every_model_reconstruction();
    let dir = tmp("bad");
    // Truncated binary files, cut anywhere: an error naming the file, never a panic.
    for file in ["cameras.bin", "images.bin", "points3D.bin"] {
        colmap::write_bin(&dir, &rec).unwrap();
        let full = std::fs::read(dir.join(file)).unwrap();
        for cut in [0, 7, 8, 13, full.len() / 2, full.len() - 1] {
            std::fs::write(dir.join(file), &full[..cut]).unwrap();
            expect_err(&dir, &[file]);
        }
        let mut long = full.clone();
        long.push(0);
        std::fs::write(dir.join(file), &long).unwrap();
        expect_err(&dir, &[file, "trailing"]);
    }
    // An absurd count.
    colmap::write_bin(&dir, &rec).unwrap();
    let mut b = std::fs::read(dir.join("images.bin")).unwrap();
    b[..8].copy_from_slice(&u64::MAX.to_le_bytes());
    std::fs::write(dir.join("images.bin"), &b).unwrap();
    expect_err(&dir, &["images.bin", "truncated or corrupt"]);
    // Unknown model id / name.
    colmap::write_bin(&dir, &rec).unwrap();
    let mut b = std::fs::read(dir.join("cameras.bin")).unwrap();
    b[12..16].copy_from_slice(&99i32.to_le_bytes());
    std::fs::write(dir.join("cameras.bin"), &b).unwrap();
    expect_err(
        &dir,
        &["cameras.bin", "camera 10", "unknown camera model id 99"],
    );
    let t = tmp("badtxt");
    colmap::write_txt(&t, &rec).unwrap();
    let s = std::fs::read_to_string(t.join("cameras.txt")).unwrap();
    std::fs::write(
        t.join("cameras.txt"),
        s.replace("SIMPLE_PINHOLE", "PINHOLLE"),
    )
    .unwrap();
    expect_err(
        &t,
        &["cameras.txt", "line 3", "unknown camera model `PINHOLLE`"],
    );
    // Wrong parameter count in text.
    colmap::write_txt(&t, &rec).unwrap();
    let s = std::fs::read_to_string(t.join("cameras.txt")).unwrap();
    let line = s.lines().nth(2).unwrap();
    std::fs::write(
        t.join("cameras.txt"),
        s.replace(line, &format!("{line} 0.5")),
    )
    .unwrap();
    expect_err(&t, &["line 3", "4 parameters", "needs 3"]);
    // An image whose camera is missing.
    let mut r = rec.clone();
    r.images.get_mut(&103).unwrap().camera_id = 77;
    colmap::write_bin(&dir, &r).unwrap();
    expect_err(&dir, &["images.bin", "image 103", "camera 77"]);
    // NaN / zero rotations.
    for q in [[f64::NAN, 0.0, 0.0, 1.0], [0.0; 4]] {
        let mut r = rec.clone();
        r.images.get_mut(&104).unwrap().qvec = q;
        colmap::write_txt(&t, &r).unwrap();
        expect_err(&t, &["images.txt", "image 104", "not a rigid transform"]);
    }
    // Zero-size camera.
    let mut r = rec.clone();
    r.cameras.get_mut(&11).unwrap().width = 0;
    colmap::write_bin(&dir, &r).unwrap();
    expect_err(&dir, &["cameras.bin", "camera 11", "empty"]);
}

/// `undistort` inverts `distort` for every perspective model, across the image.
#[test]
fn lens_models_invert() {
    for model in CameraModel::all().filter(|&m| m != CameraModel::Equirectangular) {
        let lens = Lens::new(model, params(model, 640.0, 480.0)).unwrap();
        let mut worst = 0.0f64;
        for j in 0..=12 {
            for i in 0..=16 {
                let (u, v) = (-0.5 + i as f64 / 16.0, -0.38 + 0.76 * j as f64 / 12.0);
                let (x, y) = lens.distort(u, v).unwrap();
                let (u2, v2) = lens.undistort(x, y).unwrap();
                worst = worst.max((u2 - u).abs().max((v2 - v).abs()));
            }
        }
        assert!(worst < 1e-9, "{model}: round trip error {worst:e}");
    }
    assert!(Lens::new(CameraModel::Equirectangular, vec![640.0, 320.0]).is_err());
    assert!(Lens::new(CameraModel::Pinhole, vec![0.0, 1.0, 2.0, 3.0]).is_err());
}

/// The forward models against independent formulas: the textbook OpenCV radial-tangential
/// model, the equidistant fisheye with its θ polynomial (θ_d = θ(1 + k1θ² + …)), and
/// the FOV model's atan form.
#[test]
fn lens_models_match_textbook_formulas() {
    let (u, v) = (0.31, -0.22);
    let (r2, r) = (u * u + v * v, (u * u + v * v as f64).sqrt());
    let close = |a: (f64, f64), b: (f64, f64), what: &str| {
        assert!(
            (a.0 - b.0).abs() < 1e-9 && (a.1 - b.1).abs() < 1e-9,
            "{what}: {a:?} vs {b:?}"
        )
    };
    let l = Lens::new(
        CameraModel::OpenCv,
        vec![500.0, 510.0, 320.0, 240.0, -0.1, 0.02, 0.003, -0.002],
    )
    .unwrap();
    let radial = 1.0 - 0.1 * r2 + 0.02 * r2 * r2;
    let xd = u * radial + 2.0 * 0.003 * u * v - 0.002 * (r2 + 2.0 * u * u);
    let yd = v * radial + 0.003 * (r2 + 2.0 * v * v) + 2.0 * -0.002 * u * v;
    close(
        l.distort(u, v).unwrap(),
        (500.0 * xd + 320.0, 510.0 * yd + 240.0),
        "OPENCV",
    );
    let k = [0.02, -0.01, 0.003, -0.001];
    let l = Lens::new(
        CameraModel::OpenCvFisheye,
        [vec![500.0, 510.0, 320.0, 240.0], k.to_vec()].concat(),
    )
    .unwrap();
    let t = r.atan();
    let td = t * (1.0 + k[0] * t.powi(2) + k[1] * t.powi(4) + k[2] * t.powi(6) + k[3] * t.powi(8));
    close(
        l.distort(u, v).unwrap(),
        (500.0 * u * td / r + 320.0, 510.0 * v * td / r + 240.0),
        "OPENCV_FISHEYE",
    );
    let w = 0.8f64;
    let l = Lens::new(CameraModel::Fov, vec![500.0, 510.0, 320.0, 240.0, w]).unwrap();
    let rd = (2.0 * r * (w / 2.0).tan()).atan() / w;
    close(
        l.distort(u, v).unwrap(),
        (500.0 * u * rd / r + 320.0, 510.0 * v * rd / r + 240.0),
        "FOV",
    );
}

/// A smooth test pattern on the plane z = 1 of the camera: the colour a ray through the
/// normalised point `(u, v)` sees.
fn pattern(u: f64, v: f64) -> [f32; 3] {
    [
        (0.5 + 0.4 * (3.0 * u + 1.0).sin() * (2.0 * v).cos()) as f32,
        (0.5 + 0.4 * (2.5 * v - 0.5).sin()) as f32,
        (0.5 + 0.3 * (4.0 * (u + v)).cos()) as f32,
    ]
}

/// Photos taken through distorting lenses (each pixel sees `pattern` along the ray the
/// lens model gives it) are resampled at load into pinhole images whose every pixel
/// matches the pattern along the pinhole ray: the lens removal is exact up to bilinear
/// interpolation and 8-bit quantisation, for radial, tangential and fisheye models.
#[test]
fn lens_removal_at_load_matches_the_pinhole_pattern() {
    let (w, h) = (160u32, 120u32);
    for model in [
        CameraModel::SimpleRadial,
        CameraModel::OpenCv,
        CameraModel::FullOpenCv,
        CameraModel::OpenCvFisheye,
        CameraModel::Fov,
        CameraModel::Pinhole,
    ] {
        let lens = Lens::new(model, params(model, w as f64, h as f64)).unwrap();
        let dir = tmp(&format!("lens-{}", model.name()));
        std::fs::create_dir_all(dir.join("images")).unwrap();
        let photo: Vec<[f32; 3]> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64 + 0.5, (i / w) as f64 + 0.5);
                let (u, v) = lens.undistort(x, y).unwrap();
                pattern(u, v)
            })
            .collect();
        let shots: Vec<Shot> = (0..2)
            .map(|k| {
                save_rgb_png(&dir.join(format!("images/p{k}.png")), w, h, &photo).unwrap();
                Shot {
                    name: format!("p{k}.png"),
                    lens: lens.clone(),
                    lens_size: (w as u64, h as u64),
                    c2w: [
                        [1.0, 0.0, 0.0, 0.0],
                        [0.0, 1.0, 0.0, 0.0],
                        [0.0, 0.0, 1.0, k as f64],
                    ],
                }
            })
            .collect();
        let opts = CaptureOptions {
            holdout: 0,
            ..Default::default()
        };
        let ds = load_shots(&dir, shots, "all", &opts).unwrap();
        assert_eq!(ds.frames.len(), 2);
        let cam = &ds.frames[0].camera;
        assert_eq!((cam.width, cam.height), (w, h));
        if model == CameraModel::Pinhole {
            assert_eq!((cam.fx, cam.fy, cam.cx, cam.cy), lens.pinhole());
        } else {
            assert!(cam.fx >= lens.fx, "{model}: the crop zooms in");
        }
        let (mut sum, mut worst) = (0.0f64, 0.0f64);
        for (i, got) in ds.frames[0].rgb.iter().enumerate() {
            let (x, y) = ((i as u32 % w) as f64 + 0.5, (i as u32 / w) as f64 + 0.5);
            let want = pattern((x - cam.cx) / cam.fx, (y - cam.cy) / cam.fy);
            for c in 0..3 {
                let e = (got[c] - want[c]).abs() as f64;
                sum += e;
                worst = worst.max(e);
            }
        }
        let mean = sum / (3 * w * h) as f64;
        println!(
            "{model}: zoom {:.4}, mean |error| {mean:.5}, worst {worst:.4}",
            cam.fx / lens.fx
        );
        assert!(
            // 8-bit quantisation alone gives a mean of 1/1020 and a worst of 1/510.
            mean < 0.0013 && worst < 0.004,
            "{model}: mean {mean}, worst {worst}"
        );
    }
}

#[test]
fn splits_hold_out_every_eighth_view_by_natural_name_order() {
    let mut names: Vec<String> = (0..20).map(|i| format!("IMG_{i}.png")).collect();
    names.reverse();
    names.sort_by(|a, b| natural_cmp(a, b));
    assert_eq!(names[2], "IMG_2.png");
    assert_eq!(names[10], "IMG_10.png");
    let (w, h) = (8u32, 6u32);
    let dir = tmp("split");
    std::fs::create_dir_all(dir.join("images_2")).unwrap();
    let lens = Lens::new(CameraModel::SimplePinhole, vec![20.0, 8.0, 6.0]).unwrap();
    let shots: Vec<Shot> = names
        .iter()
        .enumerate()
        .map(|(k, n)| {
            let rgb = vec![[k as f32 / 20.0; 3]; (w * h) as usize];
            save_rgb_png(&dir.join("images_2").join(n), w, h, &rgb).unwrap();
            Shot {
                name: n.clone(),
                lens: lens.clone(),
                lens_size: (16, 12),
                c2w: [
                    [1.0, 0.0, 0.0, k as f64],
                    [0.0, 1.0, 0.0, 0.0],
                    [0.0, 0.0, 1.0, 0.0],
                ],
            }
        })
        .collect();
    let opts = CaptureOptions::default();
    let test = load_shots(&dir, shots.clone(), "test", &opts).unwrap();
    let train = load_shots(&dir, shots.clone(), "train", &opts).unwrap();
    let names =
        |d: &svraster::data::Dataset| d.frames.iter().map(|f| f.name.clone()).collect::<Vec<_>>();
    assert_eq!(names(&test), ["IMG_0", "IMG_8", "IMG_16"]);
    assert_eq!(train.frames.len(), 17);
    assert!(!names(&train).contains(&"IMG_8".to_string()));
    // The lone images_2 folder was used, intrinsics scaled from 16×12 to its 8×6.
    let c = &test.frames[0].camera;
    assert_eq!(
        (c.width, c.height, c.fx, c.cx, c.cy),
        (8, 6, 10.0, 4.0, 3.0)
    );
    // A split that does not exist, too few views, a missing image.
    let e = load_shots(&dir, shots.clone(), "val", &opts)
        .unwrap_err()
        .to_string();
    assert!(e.contains("`val`"), "{e}");
    let e = load_shots(&dir, shots[..1].to_vec(), "all", &opts)
        .unwrap_err()
        .to_string();
    assert!(e.contains("at least 2"), "{e}");
    let mut gone = shots.clone();
    gone[3].name = "nope.png".into();
    let e = load_shots(&dir, gone, "all", &opts)
        .unwrap_err()
        .to_string();
    assert!(e.contains("nope.png") && e.contains("images_2"), "{e}");
}

fn shared(name: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data")
        .join(name);
    if p.is_dir() {
        Some(p)
    } else {
        println!("skipped: {} is absent", p.display());
        None
    }
}

#[test]
fn real_llff_flower_colmap_model() {
    let Some(dir) = shared("llff_flower") else {
        return;
    };
    let rec = colmap::read_model(&dir.join("sparse/0")).unwrap();
    assert_eq!(
        (rec.cameras.len(), rec.images.len(), rec.points.len()),
        (1, 34, 23_477)
    );
    let cam = rec.cameras.values().next().unwrap();
    assert_eq!(
        (cam.model, cam.width, cam.height),
        (CameraModel::SimpleRadial, 4032, 3024)
    );
    assert_eq!(
        cam.params,
        vec![3575.0586059510074, 2016.0, 1512.0, 0.025134574603909228]
    );
    // Every camera centre is in front of the scene's points (forward-facing: the points'
    // median is ahead along each optical axis).
    let observations: usize = rec.images.values().map(|i| i.points2d.len()).sum();
    assert_eq!(observations, 148_517);
    let test = load_colmap(&dir, "test", &CaptureOptions::default()).unwrap();
    let train = load_colmap(&dir, "train", &CaptureOptions::default()).unwrap();
    assert_eq!((test.frames.len(), train.frames.len()), (5, 29));
    assert_eq!((train.width, train.height), (504, 378));
    assert_eq!(test.frames[1].name, "image008");
    let c = &train.frames[0].camera;
    let zoom = c.fx / (3575.0586059510074 / 8.0);
    println!("flower: pinhole crop zoom {zoom:.5}, fx {:.3}", c.fx);
    assert!((1.0..1.05).contains(&zoom), "{zoom}");
    assert_eq!((c.cx, c.cy), (252.0, 189.0));
}

#[test]
fn real_mip360_garden_colmap_model() {
    let Some(dir) = shared("mip360_garden_512") else {
        return;
    };
    let rec = colmap::read_model(&dir.join("sparse/0")).unwrap();
    assert_eq!(
        (rec.cameras.len(), rec.images.len(), rec.points.len()),
        (1, 185, 27_046)
    );
    assert!(rec.points.iter().all(|p| p.track.is_empty()));
    let cam = rec.cameras.values().next().unwrap();
    assert_eq!(cam.model, CameraModel::OpenCv);
    let test = load_colmap(
        &dir,
        "test",
        &CaptureOptions {
            downscale: 4.0,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(test.frames.len(), 24);
    assert_eq!((test.width, test.height), (128, 128));
    assert_eq!(test.frames[0].name, "frame_00001");
    let _ = capture::image_folder(&dir, None).unwrap();
    let _: BTreeMap<u32, ColmapImage> = rec.images;
}
