use super::*;

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
    // A point that is not at a finite position, binary and text: named with its file.
    for (k, v) in [(0, f64::NAN), (1, f64::INFINITY), (2, f64::NEG_INFINITY)] {
        let mut bad = rec.clone();
        bad.points[3].xyz[k] = v;
        let id = bad.points[3].id.to_string();
        colmap::write_bin(dir.path(), &bad).unwrap();
        expect_err(dir.path(), &["points3D.bin", &id, "not a finite position"]);
        let t = tmp("badpt");
        colmap::write_txt(t.path(), &bad).unwrap();
        expect_err(t.path(), &["points3D.txt", &id, "not a finite position"]);
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
