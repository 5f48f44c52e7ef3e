use super::*;

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
        // A header count the body cannot hold is an error naming the file, never an
        // allocation of that size (2^31 aborted, u64::MAX panicked "capacity overflow").
        for n in ["2147483648", "18446744073709551615"] {
            let mut bytes = head(fmt, t)
                .replace("vertex 2", &format!("vertex {n}"))
                .into_bytes();
            bytes.extend_from_slice(&b[head(fmt, t).len()..]);
            std::fs::write(&path, &bytes).unwrap();
            let e = svraster::data::ply::read_points(&path)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains(&format!("{fmt}.ply")) && e.contains("truncated"),
                "{fmt}, {n} vertices: {e}"
            );
        }
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
