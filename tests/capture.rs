//! Real-capture input: COLMAP models (binary and text), COLMAP's camera models, lens
//! removal at load, splits, and the real captures in ../shared/data when present.

use crate::common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde_json::json;
use svraster::data::capture::{self, load_colmap, load_shots, natural_cmp, CaptureOptions, Shot};
use svraster::data::colmap::{self, ColmapCamera, ColmapImage, ColmapPoint, Reconstruction};
use svraster::data::image::save_rgb_png;
use svraster::data::lens::{CameraModel, Lens};
use tempfile::TempDir;

/// A fresh directory named `svraster-capture-<name>-…`, removed when dropped.
fn tmp(name: &str) -> TempDir {
    tempfile::Builder::new()
        .prefix(&format!("svraster-capture-{name}-"))
        .tempdir()
        .unwrap()
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
    colmap::write_bin(b.path(), &rec).unwrap();
    colmap::write_txt(t.path(), &rec).unwrap();
    let from_bin = colmap::read_model(b.path()).unwrap();
    let from_txt = colmap::read_model(t.path()).unwrap();
    assert_eq!(from_bin, rec);
    assert_eq!(from_txt, rec);
    // No points3D file at all is fine.
    std::fs::remove_file(b.path().join("points3D.bin")).unwrap();
    assert!(colmap::read_model(b.path()).unwrap().points.is_empty());
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
        colmap::write_bin(dir.path(), &rec).unwrap();
        let full = std::fs::read(dir.path().join(file)).unwrap();
        for cut in [0, 7, 8, 13, full.len() / 2, full.len() - 1] {
            std::fs::write(dir.path().join(file), &full[..cut]).unwrap();
            expect_err(dir.path(), &[file]);
        }
        let mut long = full.clone();
        long.push(0);
        std::fs::write(dir.path().join(file), &long).unwrap();
        expect_err(dir.path(), &[file, "trailing"]);
    }
    // An absurd count.
    colmap::write_bin(dir.path(), &rec).unwrap();
    let mut b = std::fs::read(dir.path().join("images.bin")).unwrap();
    b[..8].copy_from_slice(&u64::MAX.to_le_bytes());
    std::fs::write(dir.path().join("images.bin"), &b).unwrap();
    expect_err(dir.path(), &["images.bin", "truncated or corrupt"]);
    // Unknown model id / name.
    colmap::write_bin(dir.path(), &rec).unwrap();
    let mut b = std::fs::read(dir.path().join("cameras.bin")).unwrap();
    b[12..16].copy_from_slice(&99i32.to_le_bytes());
    std::fs::write(dir.path().join("cameras.bin"), &b).unwrap();
    expect_err(
        dir.path(),
        &["cameras.bin", "camera 10", "unknown camera model id 99"],
    );
    let t = tmp("badtxt");
    colmap::write_txt(t.path(), &rec).unwrap();
    let s = std::fs::read_to_string(t.path().join("cameras.txt")).unwrap();
    std::fs::write(
        t.path().join("cameras.txt"),
        s.replace("SIMPLE_PINHOLE", "PINHOLLE"),
    )
    .unwrap();
    expect_err(
        t.path(),
        &["cameras.txt", "line 3", "unknown camera model `PINHOLLE`"],
    );
    // Wrong parameter count in text.
    colmap::write_txt(t.path(), &rec).unwrap();
    let s = std::fs::read_to_string(t.path().join("cameras.txt")).unwrap();
    let line = s.lines().nth(2).unwrap();
    std::fs::write(
        t.path().join("cameras.txt"),
        s.replace(line, &format!("{line} 0.5")),
    )
    .unwrap();
    expect_err(t.path(), &["line 3", "4 parameters", "needs 3"]);
    // An image whose camera is missing.
    let mut r = rec.clone();
    r.images.get_mut(&103).unwrap().camera_id = 77;
    colmap::write_bin(dir.path(), &r).unwrap();
    expect_err(dir.path(), &["images.bin", "image 103", "camera 77"]);
    // NaN / zero rotations.
    for q in [[f64::NAN, 0.0, 0.0, 1.0], [0.0; 4]] {
        let mut r = rec.clone();
        r.images.get_mut(&104).unwrap().qvec = q;
        colmap::write_txt(t.path(), &r).unwrap();
        expect_err(
            t.path(),
            &["images.txt", "image 104", "not a rigid transform"],
        );
    }
    // Zero-size camera.
    let mut r = rec.clone();
    r.cameras.get_mut(&11).unwrap().width = 0;
    colmap::write_bin(dir.path(), &r).unwrap();
    expect_err(dir.path(), &["cameras.bin", "camera 11", "empty"]);
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
    let (u, v): (f64, f64) = (0.31, -0.22);
    let (r2, r) = (u * u + v * v, (u * u + v * v).sqrt());
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
        std::fs::create_dir_all(dir.path().join("images")).unwrap();
        let photo: Vec<[f32; 3]> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64 + 0.5, (i / w) as f64 + 0.5);
                let (u, v) = lens.undistort(x, y).unwrap();
                pattern(u, v)
            })
            .collect();
        let shots: Vec<Shot> = (0..2)
            .map(|k| {
                save_rgb_png(&dir.path().join(format!("images/p{k}.png")), w, h, &photo).unwrap();
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
        let ds = load_shots(dir.path(), shots, "all", &opts).unwrap();
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
    std::fs::create_dir_all(dir.path().join("images_2")).unwrap();
    let lens = Lens::new(CameraModel::SimplePinhole, vec![20.0, 8.0, 6.0]).unwrap();
    let shots: Vec<Shot> = names
        .iter()
        .enumerate()
        .map(|(k, n)| {
            let rgb = vec![[k as f32 / 20.0; 3]; (w * h) as usize];
            save_rgb_png(&dir.path().join("images_2").join(n), w, h, &rgb).unwrap();
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
    let test = load_shots(dir.path(), shots.clone(), "test", &opts).unwrap();
    let train = load_shots(dir.path(), shots.clone(), "train", &opts).unwrap();
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
    let e = load_shots(dir.path(), shots.clone(), "val", &opts)
        .unwrap_err()
        .to_string();
    assert!(e.contains("`val`"), "{e}");
    let e = load_shots(dir.path(), shots[..1].to_vec(), "all", &opts)
        .unwrap_err()
        .to_string();
    assert!(e.contains("at least 2"), "{e}");
    let mut gone = shots.clone();
    gone[3].name = "nope.png".into();
    let e = load_shots(dir.path(), gone, "all", &opts)
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

// ---------------------------------------------------------------------------------------
// Unbounded scenes: main region and background shells

use svraster::adapt::shells::{initial_shells, inside_grid, quantile, shell_layout};
use svraster::data::Camera;
use svraster::train::bounds::main_region;

/// The main grid fills exactly the central cube; the shells tile the rest of the root
/// cube without overlap (volumes add up to root³ − main³, no two cells overlap).
#[test]
fn shells_tile_the_root_outside_the_main_region() {
    assert_eq!(inside_grid(0, 3).len(), 512);
    for (o, g) in [(1u32, 2u32), (3, 2), (5, 1)] {
        let inside = inside_grid(o, g);
        let shells = initial_shells(o);
        assert_eq!(shells.len(), 56 * o as usize);
        // In units of the root edge, the main cube is [0.5 − 2^−(o+1), 0.5 + 2^−(o+1)]³.
        let half = 0.5f64.powi(o as i32 + 1);
        let boxes: Vec<([f64; 3], f64)> = inside
            .iter()
            .chain(&shells)
            .map(|&(ijk, l)| {
                let s = 0.5f64.powi(l as i32);
                (ijk.map(|v| v as f64 * s), s)
            })
            .collect();
        for (k, (lo, s)) in boxes.iter().enumerate() {
            let is_inside = k < inside.len();
            let within = lo
                .iter()
                .all(|&v| v >= 0.5 - half - 1e-12 && v + s <= 0.5 + half + 1e-12);
            assert_eq!(within, is_inside, "o {o}: cell {k} at {lo:?} size {s}");
        }
        let volume: f64 = boxes[inside.len()..].iter().map(|b| b.1.powi(3)).sum();
        assert!(
            (volume - (1.0 - (2.0 * half).powi(3))).abs() < 1e-12,
            "o {o}: {volume}"
        );
        let main: f64 = boxes[..inside.len()].iter().map(|b| b.1.powi(3)).sum();
        assert!((main - (2.0 * half).powi(3)).abs() < 1e-12);
        // Pairwise disjoint (cells of one level are distinct; cells of different levels
        // lie in different shells).
        let mut keys: Vec<_> = inside.iter().chain(&shells).collect();
        keys.sort();
        keys.dedup();
        assert_eq!(keys.len(), boxes.len());
    }
    assert_eq!(quantile(&[0.0, 1.0, 2.0, 3.0, 4.0], 0.9), 3.6);
}

fn ring_cameras(n: usize, radius: f64, center: [f64; 3], w: u32) -> Vec<Camera> {
    (0..n)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / n as f64;
            let eye = [
                center[0] + radius * a.cos(),
                center[1] + radius * a.sin(),
                center[2] + 0.3 * radius,
            ];
            Camera::look_at(eye, center, [0.0, 0.0, 1.0], 1.2, w, w)
        })
        .collect()
}

#[test]
fn main_region_from_cameras() {
    // 360°: centre = mean position (raised by the ring's height), radius = median distance.
    let cams = ring_cameras(12, 4.0, [10.0, -5.0, 2.0], 32);
    let r = main_region(&cams, &[], "auto").unwrap();
    assert_eq!(r.mode, "camera_median");
    let want = [10.0, -5.0, 2.0 + 1.2];
    for (got, want) in r.center.iter().zip(want) {
        assert!((got - want).abs() < 1e-9, "{:?}", r.center);
    }
    assert!((r.radius - 4.0).abs() < 1e-9, "{}", r.radius);
    assert!((main_region(&cams, &[], "camera_max").unwrap().radius - r.radius).abs() < 1e-9);
    // Forward-facing: cameras on a small grid, all looking down +y.
    let cams: Vec<Camera> = (0..4)
        .map(|k| {
            let eye = [(k % 2) as f64, 0.0, (k / 2) as f64];
            let target = [eye[0], 10.0, eye[2]];
            Camera::look_at(eye, target, [0.0, 0.0, 1.0], 1.0, 32, 24)
        })
        .collect();
    let r = main_region(&cams, &[], "auto").unwrap();
    assert_eq!(r.mode, "forward");
    // Mean position (0.5, 0, 0.5); largest distance √0.5; e = 2√0.5.
    let e = 2.0 * 0.5f64.sqrt();
    let want = [0.5, e, 0.5];
    for (got, want) in r.center.iter().zip(want) {
        assert!((got - want).abs() < 1e-9, "{:?}", r.center);
    }
    assert!((r.radius - 0.8 * e).abs() < 1e-9);
    // With sparse points, forward-facing captures are bounded by them: a dense cube of
    // half-size 2 around (3, 20, 1) and a few far points.
    let mut pts = Vec::new();
    for i in 0..20 {
        for j in 0..20 {
            for k in 0..20 {
                let u = |v: i32| -2.0 + 4.0 * (v as f64 + 0.5) / 20.0;
                pts.push([3.0 + u(i), 20.0 + u(j), 1.0 + u(k)]);
            }
        }
    }
    // A thin halo out to 40 (real captures' points thin out; they do not stop).
    let mut rng = common::Rng(3);
    for _ in 0..400 {
        let d = rng.dir();
        let r = rng.range(2.0, 40.0) / d.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        pts.push([3.0 + r * d[0], 20.0 + r * d[1], 1.0 + r * d[2]]);
    }
    let r = main_region(&cams, &pts, "auto").unwrap();
    assert_eq!(r.mode, "points");
    assert!(
        (r.center[0] - 3.0).abs() < 0.2 && (r.center[1] - 20.0).abs() < 0.2,
        "{r:?}"
    );
    // Density 8000/(2r)³ in the core; it falls to a tenth of its peak by r ≈ 2·10^⅓.
    assert!((2.0..6.0).contains(&r.radius), "{r:?}");
    assert!(main_region(&cams, &[], "points").is_err());
    assert!(main_region(&cams[..1], &[], "auto").is_err());
    assert!(main_region(&cams, &[], "sphere").is_err());
}

/// Background shells around a ring of cameras: every kept voxel is seen, the count
/// reaches the target ratio, and what the cameras see closely is finer.
#[test]
fn shell_layout_reaches_the_ratio_with_seen_voxels() {
    let ctx = common::context();
    let cams = ring_cameras(16, 1.0, [0.0; 3], 48);
    let mut renderer = svraster::raster::Renderer::new(&ctx).unwrap();
    let mut stats = svraster::adapt::stats::StatsPass::new(&ctx).unwrap();
    // Main region edge 2 (radius 1), 3 shell levels: root edge 16.
    let (cells, rep) = shell_layout(
        [0.0; 3],
        16.0,
        3,
        3 + 4,
        3000,
        &cams,
        &mut renderer,
        &mut stats,
    )
    .unwrap();
    println!("{rep:?}");
    assert_eq!(rep.voxels, cells.len());
    assert!(cells.len() >= 3000, "{}", cells.len());
    assert!(
        cells.len() < 3000 + 8 * 3000 / 7,
        "overshoot: {}",
        cells.len()
    );
    assert!(rep.rounds >= 2 && rep.max_level > 4, "{rep:?}");
    assert!(rep.max_level <= 7);
    // Every kept voxel is seen by some camera: a second measurement finds no zero rate.
    let scene = svraster::adapt::shells::scene_of([0.0; 3], 16.0, &cells, -10.0).unwrap();
    let gpu = svraster::scene::SceneGpu::upload(&ctx, &scene).unwrap();
    stats.begin(gpu.voxels).unwrap();
    for c in &cams {
        stats.add_view_intervals(&mut renderer, &gpu, c).unwrap();
    }
    let rate = stats.read().unwrap().sampling_rate(&scene);
    assert!(rate.iter().all(|&r| r > 0.0));
    let per_level: Vec<usize> = (2..=7)
        .map(|l| cells.iter().filter(|c| c.1 == l).count())
        .collect();
    println!("background voxels per level 2..=7: {per_level:?}");
    // The shells nearest the cameras are subdivided: voxels finer than the initial
    // level-4 cells of the innermost shell exist.
    assert!(per_level[3] + per_level[4] > 0, "{per_level:?}");
    drop(gpu);
    common::finish(&ctx);
}

/// nerfstudio's transforms.json of the garden against the COLMAP model it was derived
/// from: same lens, and poses equal after nerfstudio's `applied_transform` of the world;
/// the loaded test views are pixel-identical.
#[test]
fn real_mip360_garden_nerfstudio_matches_colmap() {
    let Some(dir) = shared("mip360_garden_512") else {
        return;
    };
    let (folder, shots) = svraster::data::nerfstudio::shots(&dir).unwrap();
    assert_eq!(folder, dir.join("images"));
    assert_eq!(shots.len(), 185);
    let rec = colmap::read_model(&dir.join("sparse/0")).unwrap();
    let col = capture::colmap_shots(&rec, &dir.join("sparse/0")).unwrap();
    let t: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("transforms.json")).unwrap())
            .unwrap();
    let a: Vec<Vec<f64>> = serde_json::from_value(t["applied_transform"].clone()).unwrap();
    let mut worst = 0.0f64;
    for (n, c) in shots.iter().zip(&col) {
        assert_eq!(n.name, c.name);
        assert_eq!(n.lens, c.lens);
        for (row, ar) in n.c2w.iter().zip(&a) {
            for (k, got) in row.iter().enumerate() {
                let mut want: f64 = (0..3).map(|j| ar[j] * c.c2w[j][k]).sum();
                if k == 3 {
                    want += ar[3];
                }
                worst = worst.max((got - want).abs());
            }
        }
    }
    assert!(worst < 1e-9, "pose mismatch {worst:e}");
    let opts = CaptureOptions {
        downscale: 8.0,
        ..Default::default()
    };
    let ns = capture::load_nerfstudio(&dir, "test", &opts).unwrap();
    let cm = load_colmap(&dir, "test", &opts).unwrap();
    assert_eq!(ns.frames.len(), 24);
    for (x, y) in ns.frames.iter().zip(&cm.frames) {
        assert_eq!(x.rgb, y.rgb);
        assert_eq!((x.camera.fx, x.camera.cx), (y.camera.fx, y.camera.cx));
    }
}

/// A small transforms.json written here: per-frame intrinsics override the global ones,
/// a non-rigid pose and an unknown camera model are named.
#[test]
fn nerfstudio_fixture() {
    let dir = tmp("ns");
    std::fs::create_dir_all(dir.path().join("imgs")).unwrap();
    for k in 0..3 {
        save_rgb_png(
            &dir.path().join(format!("imgs/f{k}.png")),
            8,
            6,
            &vec![[0.5; 3]; 48],
        )
        .unwrap();
    }
    let pose = |x: f64| json!([[1, 0, 0, x], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]);
    let mut doc = json!({
        "camera_model": "OPENCV", "fl_x": 10.0, "fl_y": 11.0, "cx": 4.0, "cy": 3.0,
        "w": 8, "h": 6, "k1": 0.0,
        "frames": [
            {"file_path": "./imgs/f2.png", "transform_matrix": pose(2.0)},
            {"file_path": "imgs/f0.png", "transform_matrix": pose(0.0), "fl_x": 12.0},
            {"file_path": "imgs/f1.png", "transform_matrix": pose(1.0)},
        ]
    });
    let write = |d: &serde_json::Value| {
        std::fs::write(dir.path().join("transforms.json"), d.to_string()).unwrap();
    };
    write(&doc);
    assert_eq!(
        svraster::data::detect_format(dir.path()),
        svraster::data::Format::Nerfstudio
    );
    let ds = capture::load_nerfstudio(dir.path(), "all", &CaptureOptions::default()).unwrap();
    let names: Vec<&str> = ds.frames.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(names, ["f0", "f1", "f2"]);
    assert_eq!(ds.frames[0].camera.fx, 12.0);
    assert_eq!(
        (ds.frames[1].camera.fx, ds.frames[1].camera.fy),
        (10.0, 11.0)
    );
    // OpenGL → OpenCV axes: the camera looks down world −z.
    assert_eq!(
        ds.frames[1].camera.rotate([0.0, 0.0, 1.0]),
        [0.0, 0.0, -1.0]
    );
    assert_eq!(ds.frames[2].camera.origin(), [2.0, 0.0, 0.0]);
    doc["frames"][1]["transform_matrix"] =
        json!([[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]);
    write(&doc);
    let e = capture::load_nerfstudio(dir.path(), "all", &CaptureOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("frame 1") && e.contains("rigid"), "{e}");
    doc["frames"][1]["transform_matrix"] = pose(0.0);
    doc["camera_model"] = json!("EQUIRECTANGULAR");
    write(&doc);
    let e = capture::load_nerfstudio(dir.path(), "all", &CaptureOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("EQUIRECTANGULAR"), "{e}");
}

/// LLFF's poses_bounds.npy of the flower against its COLMAP model (the README of the
/// data: images.bin was rebuilt from these poses): same camera centres and axes after
/// LLFF's [down, right, back] → OpenCV conversion, same focal length; the COLMAP model
/// wins the format detection; the LLFF depth bounds become points that bound the scene.
#[test]
fn real_llff_flower_poses_bounds_match_colmap() {
    let Some(dir) = shared("llff_flower") else {
        return;
    };
    assert_eq!(
        svraster::data::detect_format(&dir),
        svraster::data::Format::Colmap
    );
    let (folder, rows) = svraster::data::llff::shots(&dir, None).unwrap();
    assert_eq!(folder, dir.join("images_8"));
    assert_eq!(rows.len(), 34);
    let rec = colmap::read_model(&dir.join("sparse/0")).unwrap();
    let col = capture::colmap_shots(&rec, &dir.join("sparse/0")).unwrap();
    let mut worst = 0.0f64;
    for ((l, bounds), c) in rows.iter().zip(&col) {
        assert_eq!(l.name, c.name);
        assert_eq!(l.lens.fx, c.lens.fx);
        assert_eq!((l.lens.cx, l.lens.cy), (c.lens.cx, c.lens.cy));
        assert!(bounds[0] > 0.0 && bounds[1] > bounds[0]);
        for (a, b) in l.c2w.iter().flatten().zip(c.c2w.iter().flatten()) {
            worst = worst.max((a - b).abs());
        }
    }
    assert!(worst < 1e-9, "LLFF vs COLMAP pose difference {worst:e}");
    let ds = capture::load_llff(&dir, "test", &CaptureOptions::default()).unwrap();
    assert_eq!(ds.frames.len(), 5);
    assert_eq!(ds.points.len(), 34 * 10);
    let r = main_region(&ds.cameras(), &ds.points, "auto").unwrap();
    println!("flower from LLFF bounds: {r:?}");
    assert_eq!(r.mode, "points");
}

/// PLY point clouds: the garden's ASCII `sparse_pc.ply` is its COLMAP points3D in
/// nerfstudio's frame; binary files of either endianness and property type read the same.
#[test]
fn ply_points() {
    let dir = tmp("ply");
    let pts = [[1.5f64, -2.25, 3.0], [0.0, 1e-3, -7.5]];
    let head = |fmt: &str, t: &str| {
        format!(
            "ply\nformat {fmt} 1.0\ncomment x\nelement vertex 2\nproperty uchar red\n\
             property {t} x\nproperty {t} y\nproperty {t} z\nelement face 0\n\
             property list uchar int vertex_indices\nend_header\n"
        )
    };
    for (fmt, t) in [
        ("binary_little_endian", "float"),
        ("binary_big_endian", "double"),
        ("ascii", "float"),
    ] {
        let mut b = head(fmt, t).into_bytes();
        for p in &pts {
            if fmt == "ascii" {
                b.extend(format!("7 {} {} {}\n", p[0], p[1], p[2]).bytes());
                continue;
            }
            b.push(7);
            for v in p {
                match (fmt, t) {
                    ("binary_little_endian", _) => b.extend((*v as f32).to_le_bytes()),
                    _ => b.extend(v.to_be_bytes()),
                }
            }
        }
        let path = dir.path().join(format!("{fmt}.ply"));
        std::fs::write(&path, &b).unwrap();
        let got = svraster::data::ply::read_points(&path).unwrap();
        for (g, w) in got.iter().zip(&pts) {
            for a in 0..3 {
                assert!((g[a] - w[a]).abs() < 1e-6, "{fmt}: {got:?}");
            }
        }
        // Cut inside the last vertex (for ASCII: before its z).
        let cut = if fmt == "ascii" { 9 } else { 3 };
        std::fs::write(&path, &b[..b.len() - cut]).unwrap();
        assert!(
            svraster::data::ply::read_points(&path).is_err(),
            "{fmt} truncated"
        );
    }
    let Some(garden) = shared("mip360_garden_512") else {
        return;
    };
    let ply = svraster::data::nerfstudio::points(&garden).unwrap();
    let rec = colmap::read_model(&garden.join("sparse/0")).unwrap();
    assert_eq!(ply.len(), rec.points.len());
    let t: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(garden.join("transforms.json")).unwrap())
            .unwrap();
    let a: Vec<Vec<f64>> = serde_json::from_value(t["applied_transform"].clone()).unwrap();
    let mut worst = 0.0f64;
    for (p, c) in ply.iter().zip(&rec.points) {
        for r in 0..3 {
            let want = (0..3).map(|j| a[r][j] * c.xyz[j]).sum::<f64>() + a[r][3];
            worst = worst.max((p[r] - want).abs());
        }
    }
    assert!(worst < 1e-5, "ply vs COLMAP points: {worst:e}");
}

/// Writes a float64 C-order `.npy` file (format 1.0) of `rows × cols`.
fn write_npy(path: &Path, rows: usize, cols: usize, v: &[f64]) {
    let mut header =
        format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({rows}, {cols}), }}");
    while !(10 + header.len() + 1).is_multiple_of(64) {
        header.push(' ');
    }
    header.push('\n');
    let mut b = b"\x93NUMPY\x01\x00".to_vec();
    b.extend((header.len() as u16).to_le_bytes());
    b.extend(header.as_bytes());
    v.iter().for_each(|x| b.extend(x.to_le_bytes()));
    std::fs::write(path, b).unwrap();
}

/// An LLFF fixture written here: rows in [down, right, back | t | hwf] + near/far come
/// back as OpenCV cameras (x = right, y = down, z = −back) with the focal scaled to the
/// images_4 files; a non-rigid row and a pose/image count mismatch are named.
#[test]
fn llff_fixture() {
    let dir = tmp("llff");
    std::fs::create_dir_all(dir.path().join("images_4")).unwrap();
    // Camera k at (k, 0, 0) looking down world −z with world y up: down = (0,−1,0),
    // right = (1,0,0), back = (0,0,1); full resolution 40×32 (h, w = 32, 40), f = 50.
    let row = |k: usize| -> Vec<f64> {
        let r = [
            [0.0, 1.0, 0.0, k as f64, 32.0],
            [-1.0, 0.0, 0.0, 0.0, 40.0],
            [0.0, 0.0, 1.0, 0.0, 50.0],
        ];
        let mut v: Vec<f64> = r.iter().flatten().copied().collect();
        v.extend([2.0, 9.0]);
        v
    };
    let rows: Vec<f64> = (0..3).flat_map(row).collect();
    write_npy(&dir.path().join("poses_bounds.npy"), 3, 17, &rows);
    for k in 0..3 {
        save_rgb_png(
            &dir.path().join(format!("images_4/img{k}.png")),
            10,
            8,
            &vec![[0.2; 3]; 80],
        )
        .unwrap();
    }
    assert_eq!(
        svraster::data::detect_format(dir.path()),
        svraster::data::Format::Llff
    );
    let ds = capture::load_llff(dir.path(), "all", &CaptureOptions::default()).unwrap();
    assert_eq!(ds.frames.len(), 3);
    let c = &ds.frames[2].camera;
    assert_eq!(
        (c.width, c.height, c.fx, c.fy, c.cx, c.cy),
        (10, 8, 12.5, 12.5, 5.0, 4.0)
    );
    assert_eq!(c.origin(), [2.0, 0.0, 0.0]);
    assert_eq!(c.rotate([1.0, 0.0, 0.0]), [1.0, 0.0, 0.0], "x = right");
    assert_eq!(c.rotate([0.0, 1.0, 0.0]), [0.0, -1.0, 0.0], "y = down");
    assert_eq!(
        c.rotate([0.0, 0.0, 1.0]),
        [0.0, 0.0, -1.0],
        "z = forward = −back"
    );
    // 3 cameras × 5 rays × {near, far} bounding points; the far centre point of camera 0.
    assert_eq!(ds.points.len(), 30);
    assert_eq!(ds.points[1], [0.0, 0.0, -9.0]);
    // A scaled rotation, and a count mismatch.
    let mut bad = rows.clone();
    bad[17 + 1] = 2.0;
    write_npy(&dir.path().join("poses_bounds.npy"), 3, 17, &bad);
    let e = capture::load_llff(dir.path(), "all", &CaptureOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("row 1") && e.contains("rigid"), "{e}");
    write_npy(&dir.path().join("poses_bounds.npy"), 2, 17, &rows[..34]);
    let e = capture::load_llff(dir.path(), "all", &CaptureOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("2 poses") && e.contains("3 images"), "{e}");
}

// ---------------------------------------------------------------------------------
// NeuS / DTU layout: cameras_sphere.npz + image/ + mask/.

/// A `.npy` (v1.0, little-endian f64, C order) of a 4×4 matrix.
fn npy4(m: &[[f64; 4]; 4]) -> Vec<u8> {
    let mut header = "{'descr': '<f8', 'fortran_order': False, 'shape': (4, 4), }".to_string();
    while !(10 + header.len() + 1).is_multiple_of(64) {
        header.push(' ');
    }
    header.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for row in m {
        for x in row {
            out.extend_from_slice(&x.to_le_bytes());
        }
    }
    out
}

/// Writes a NeuS capture of the demo scene seen by `cams` (photos and masks from the
/// analytic renderer); the sphere is `centre`, `radius`. Returns the 8-bit photos and
/// masks as written.
#[allow(clippy::type_complexity)]
fn write_neus(
    dir: &Path,
    cams: &[svraster::Camera],
    centre: [f64; 3],
    radius: f64,
) -> Vec<(Vec<[f32; 3]>, Vec<f32>)> {
    use std::io::Write;
    std::fs::create_dir_all(dir.join("image")).unwrap();
    std::fs::create_dir_all(dir.join("mask")).unwrap();
    let f = std::fs::File::create(dir.join("cameras_sphere.npz")).unwrap();
    let mut zip = zip::ZipWriter::new(f);
    let opts: zip::write::SimpleFileOptions =
        zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    let scale = [
        [radius, 0.0, 0.0, centre[0]],
        [0.0, radius, 0.0, centre[1]],
        [0.0, 0.0, radius, centre[2]],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let mut written = Vec::new();
    for (i, c) in cams.iter().enumerate() {
        // K with NeuS's integer pixel centres, [R | t] world to camera; P up to a scale
        // (negative for one view: the decomposition must fix the sign).
        let k = [
            [c.fx, 0.0, c.cx - 0.5],
            [0.0, c.fy, c.cy - 0.5],
            [0.0, 0.0, 1.0],
        ];
        let w2c = c.w2c();
        let s = if i == 1 { -2.5 } else { 3.7 };
        let mut p = [[0.0; 4]; 4];
        for r in 0..3 {
            for col in 0..4 {
                p[r][col] = s * (0..3).map(|j| k[r][j] * w2c[j][col]).sum::<f64>();
            }
        }
        p[3] = [0.0, 0.0, 0.0, 1.0];
        for (name, m) in [
            (format!("world_mat_{i}"), p),
            (format!("scale_mat_{i}"), scale),
        ] {
            zip.start_file(format!("{name}.npy"), opts).unwrap();
            zip.write_all(&npy4(&m)).unwrap();
        }
        let rgba = svraster::data::demo::render_rgba(c);
        let q = |x: f32| (x.clamp(0.0, 1.0) * 255.0).round() / 255.0;
        let rgb: Vec<[f32; 3]> = rgba.iter().map(|p| [q(p[0]), q(p[1]), q(p[2])]).collect();
        let mask: Vec<f32> = rgba.iter().map(|p| q(p[3])).collect();
        save_rgb_png(
            &dir.join(format!("image/{i:06}.png")),
            c.width,
            c.height,
            &rgb,
        )
        .unwrap();
        svraster::data::image::save_gray_png(
            &dir.join(format!("mask/{i:03}.png")),
            c.width,
            c.height,
            &mask,
        )
        .unwrap();
        written.push((rgb, mask));
    }
    zip.finish().unwrap();
    written
}

#[test]
fn neus_capture_cameras_masks_and_sphere() {
    let dir = tmp("neus");
    let cams: Vec<svraster::Camera> = (0..10)
        .map(|i| {
            let a = i as f64 * 0.63;
            svraster::Camera::look_at(
                [3.5 * a.cos(), 3.5 * a.sin(), 1.2 + 0.1 * i as f64],
                [0.05, -0.1, 0.0],
                [0.0, 0.0, 1.0],
                0.8,
                40 + (i % 2),
                30,
            )
        })
        .collect();
    let written = write_neus(dir.path(), &cams, [0.1, -0.2, 0.3], 1.5);
    let bg = [0.2f32, 0.4, 0.6];
    assert_eq!(
        svraster::data::detect_format(dir.path()),
        svraster::data::Format::Neus
    );
    let all = svraster::data::load_split(dir.path(), "all", 1.0, bg).unwrap();
    assert!(all.alpha);
    assert_eq!(all.sphere, Some(([0.1, -0.2, 0.3], 1.5)));
    assert_eq!(all.frames.len(), 10);
    for (i, (f, c)) in all.frames.iter().zip(&cams).enumerate() {
        assert_eq!((f.camera.width, f.camera.height), (c.width, c.height));
        for (a, b) in [
            (f.camera.fx, c.fx),
            (f.camera.fy, c.fy),
            (f.camera.cx, c.cx),
            (f.camera.cy, c.cy),
        ] {
            assert!(
                (a - b).abs() < 1e-9 * b.abs().max(1.0),
                "view {i}: {a} vs {b}"
            );
        }
        for r in 0..3 {
            for k in 0..4 {
                assert!(
                    (f.camera.c2w[r][k] - c.c2w[r][k]).abs() < 1e-9,
                    "view {i} c2w[{r}][{k}]"
                );
            }
        }
        let (rgb, mask) = &written[i];
        for ((p, q), a) in f.rgb.iter().zip(rgb).zip(mask) {
            for ch in 0..3 {
                let want = q[ch] * a + bg[ch] * (1.0 - a);
                assert!((p[ch] - want).abs() < 1e-6, "view {i}: composite");
            }
        }
    }
    // Every 8th view is test; masks come back per split, downscaled like the photos.
    let train = svraster::data::load_split(dir.path(), "train", 2.0, bg).unwrap();
    assert_eq!(
        train
            .frames
            .iter()
            .map(|f| f.name.as_str())
            .collect::<Vec<_>>(),
        ["000001", "000002", "000003", "000004", "000005", "000006", "000007", "000009"]
    );
    let masks = svraster::data::neus::load_masks(dir.path(), "train", 2.0, 8).unwrap();
    assert_eq!(masks.len(), 8);
    assert_eq!(
        masks[0].len(),
        (train.frames[0].camera.width * train.frames[0].camera.height) as usize
    );
    let m1 = &written[1].1;
    let want00 = (m1[0] + m1[1] + m1[40 + 1] + m1[40 + 1 + 1]) / 4.0;
    assert!(
        (masks[0][0] - want00).abs() < 1e-6,
        "2×2 box average of the first view's mask (41 wide)"
    );
    // The run's main region is the sphere.
    let mut cfg = svraster::TrainConfig::preset("object").unwrap();
    let mut t = svraster::data::load_split(dir.path(), "train", 1.0, bg).unwrap();
    let r = svraster::train::bounds::resolve_run(&mut cfg, &mut t)
        .unwrap()
        .unwrap();
    assert_eq!(
        (r.mode, r.center, r.radius),
        ("sphere", [0.1, -0.2, 0.3], 1.5)
    );
    assert_eq!(cfg.world_scale, 1.5);

    // Bad input: one error naming the file.
    std::fs::remove_file(dir.path().join("mask/003.png")).unwrap();
    let e = svraster::data::load_split(dir.path(), "all", 1.0, bg)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("mask") && e.contains("9 masks for 10 images"),
        "{e}"
    );
    std::fs::remove_dir_all(dir.path().join("mask")).unwrap();
    let opaque = svraster::data::load_split(dir.path(), "all", 1.0, bg).unwrap();
    assert!(!opaque.alpha, "no mask/ folder: opaque photos");
    std::fs::remove_file(dir.path().join("image/000004.png")).unwrap();
    let e = svraster::data::load_split(dir.path(), "all", 1.0, bg)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("cameras_sphere.npz") && e.contains("9 images"),
        "{e}"
    );
    std::fs::write(dir.path().join("cameras_sphere.npz"), b"not a zip").unwrap();
    let e = svraster::data::load_split(dir.path(), "all", 1.0, bg)
        .unwrap_err()
        .to_string();
    assert!(e.contains("cameras_sphere.npz") && e.contains("zip"), "{e}");
}

/// The DTU scan in ../shared/data: 49 views, and the sphere's centre projects inside
/// every mask.
#[test]
fn dtu_scan37_loads_with_the_sphere_inside_every_mask() {
    let dir = Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../shared/data/dtu_scan37"
    ));
    if !dir.join("cameras_sphere.npz").is_file() {
        println!("skipped: {} is absent", dir.display());
        return;
    }
    let ds = svraster::data::load(dir, "all", 4.0, [0.0; 3], &Default::default()).unwrap();
    let masks = svraster::data::neus::load_masks(dir, "all", 4.0, 8).unwrap();
    assert_eq!(ds.frames.len(), 49);
    let (c, r) = ds.sphere.unwrap();
    assert!(r > 100.0 && r < 1000.0, "DTU millimetres: radius {r}");
    for (f, m) in ds.frames.iter().zip(&masks) {
        let q = f.camera.world_to_camera(c);
        let (u, v) = (
            f.camera.fx * q[0] / q[2] + f.camera.cx,
            f.camera.fy * q[1] / q[2] + f.camera.cy,
        );
        let (x, y) = (u.floor() as usize, v.floor() as usize);
        assert!(q[2] > 0.0 && x < f.camera.width as usize && y < f.camera.height as usize);
        assert!(
            m[y * f.camera.width as usize + x] > 0.5,
            "{}: centre outside the mask",
            f.name
        );
    }
}
