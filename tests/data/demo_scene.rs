use super::*;

#[test]
fn demo_scene_is_inside_the_cube_and_view_dependent() {
    for p in PRIMITIVES {
        let (c, r) = match p.shape {
            demo::Shape::Sphere { center, radius } => (center.to_array(), [radius; 3]),
            demo::Shape::Box { center, half } => (center.to_array(), half.to_array()),
        };
        for a in 0..3 {
            assert!(
                c[a] - r[a] >= -1.5 && c[a] + r[a] <= 1.5,
                "{} leaves the cube",
                p.name
            );
        }
    }
    // The glossy red sphere's point facing the light: looking along the mirror
    // direction shows a highlight, a grazing view does not.
    let (center, radius) = match PRIMITIVES[1].shape {
        demo::Shape::Sphere { center, radius } => (center.to_array(), radius),
        _ => unreachable!(),
    };
    let n = demo::light_dir().to_array();
    let point: [f64; 3] = std::array::from_fn(|a| center[a] + radius * n[a]);
    let hit = demo::Hit {
        t: 1.0,
        point: point.into(),
        normal: n.into(),
        primitive: 1,
    };
    let head_on = demo::shade(&hit, n.map(|v| -v).into());
    let side = [n[1], -n[0], 0.0];
    let l = (side[0] * side[0] + side[1] * side[1]).sqrt();
    let grazing: [f64; 3] = std::array::from_fn(|a| -0.3 * n[a] - side[a] / l);
    let gl = (grazing.iter().map(|v| v * v).sum::<f64>()).sqrt();
    let oblique = demo::shade(&hit, grazing.map(|v| v / gl).into());
    assert!(head_on[1] - oblique[1] > 0.5, "{head_on:?} vs {oblique:?}");
}

#[test]
fn voxelize_demo_scene() {
    for level in [5, 6, 7] {
        let t = std::time::Instant::now();
        let s = demo::voxelize(level, 0).unwrap();
        println!(
            "voxelize({level}, 0): {} voxels, {} grid points in {:?}",
            s.num_voxels(),
            s.num_grid_points(),
            t.elapsed()
        );
    }
    let scene = demo::voxelize(6, 0).unwrap();
    scene.validate().unwrap();
    assert!(scene.num_voxels() > 1000);
    assert!(
        scene.num_voxels() < 64 * 64 * 64 / 8,
        "{}",
        scene.num_voxels()
    );
    assert_eq!(scene.max_level(), 6);
    assert_eq!(scene.background, [1.0; 3]);
    assert_eq!((scene.center, scene.extent), ([0.0; 3], 3.0));
    assert!(scene.shs.is_empty());
    for i in 0..scene.num_voxels() {
        let (m, s) = (scene.voxel_min(i), scene.voxel_size(i));
        assert!(
            m.iter().all(|&v| v >= -1.5 && v + s <= 1.5),
            "voxel {i} leaves the box"
        );
        // Kept voxels meet or lie inside the geometry.
        let c = scene.voxel_center(i);
        assert!(demo::signed_distance(c.into()) <= 0.5 * s * 3f64.sqrt() + 1e-12);
    }
    let scene3 = demo::voxelize(4, 3).unwrap();
    assert_eq!(scene3.shs.len(), scene3.num_voxels() * 15 * 3);
    assert!(demo::voxelize(0, 0).is_err());
    assert!(demo::voxelize(12, 0).is_err());
    assert!(demo::voxelize(5, 4).is_err());
}

#[test]
fn voxelized_surfaces_are_opaque_and_coloured() {
    let scene = demo::voxelize(7, 0).unwrap();
    let field = Field::new(&scene);
    let w = 3.0 / 128.0;
    // Rays towards each primitive's centre from outside; optical depth with the
    // renderer's alpha = 1 − exp(−100 · length · density).
    for (k, prim) in PRIMITIVES.iter().enumerate() {
        let center = match prim.shape {
            demo::Shape::Sphere { center, .. } => center.to_array(),
            demo::Shape::Box { center, .. } => center.to_array(),
        };
        // Target inside the primitive and direction towards the viewer, chosen so the
        // primitive is the first thing hit.
        let (center, dir) = match prim.name {
            "pedestal" => ([0.0, 0.65, -0.6], [0.0, 0.0, 1.0]),
            "green box" => (center, [1.0, 0.0, 0.0]),
            "yellow box" => (center, [0.0, 0.0, 1.0]),
            _ => (center, demo::light_dir().to_array()),
        };
        let start: [f64; 3] = std::array::from_fn(|a| center[a] + 1.2 * dir[a]);
        let ray = dir.map(|v| -v);
        let hit = demo::ray_hit(start.into(), ray.into()).unwrap();
        let step = w / 50.0;
        let mut tau = 0.0;
        let mut t = 0.0;
        let (mut before, mut after) = (None, None);
        while t < hit.t + 3.0 * w {
            let p: [f64; 3] = std::array::from_fn(|a| start[a] + t * ray[a]);
            tau += 100.0 * step * field.density(p);
            t += step;
            if before.is_none() && t >= hit.t - 2.0 * w {
                before = Some((-tau).exp());
            }
            if after.is_none() && t >= hit.t + 2.0 * w {
                after = Some((-tau).exp());
            }
        }
        let (before, after) = (before.unwrap(), after.unwrap());
        println!(
            "{}: transmittance 2w before the surface {before:.4}, 2w after {after:.2e}",
            prim.name
        );
        assert!(before > 0.9, "{}: {before}", prim.name);
        assert!(after < 1e-3, "{}: {after}", prim.name);
        // The voxel just inside the hit point has the primitive's hue.
        let p: [f64; 3] = std::array::from_fn(|a| hit.point[a] + 0.3 * w * ray[a]);
        let i = (0..scene.num_voxels())
            .find(|&i| {
                let (m, s) = (scene.voxel_min(i), scene.voxel_size(i));
                (0..3).all(|a| p[a] >= m[a] && p[a] < m[a] + s)
            })
            .unwrap();
        let rgb = scene.sh0[i].map(|v| 0.5 + demo::SH_C0 * v as f64);
        let want = demo::diffuse_color(hit.primitive, hit.point, hit.normal);
        assert_eq!(hit.primitive, k);
        for c in 0..3 {
            assert_close(rgb[c], want[c], 0.08, prim.name);
        }
    }
}

/// Poses that are not rigid transforms are rejected with the frame named.
#[test]
fn error_non_rigid_pose() {
    let with = |m: &str| {
        format!(
            r#"{{"camera_angle_x": 0.5, "frames": [{{"file_path": "train/r_0", "transform_matrix": {POSE}}},
            {{"file_path": "train/r_1.png", "transform_matrix": {m}}}]}}"#
        )
    };
    for (tag, m, why) in [
        (
            "zero",
            "[[0,0,0,0],[0,0,0,0],[0,0,0,0],[0,0,0,1]]",
            "length 0",
        ),
        (
            "rank",
            "[[1,0,0,0],[0,1,0,0],[0,1,0,4],[0,0,0,1]]",
            "column 1 has length",
        ),
        (
            "skew",
            "[[1,0.6,0,0],[0,0.8,0,0],[0,0,1,4],[0,0,0,1]]",
            "not orthogonal",
        ),
        (
            "scaled",
            "[[2,0,0,0],[0,2,0,0],[0,0,2,4],[0,0,0,1]]",
            "length 2",
        ),
        (
            "mirror",
            "[[-1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]",
            "reflection",
        ),
        (
            "far",
            "[[1,0,0,0],[0,1,0,0],[0,0,1,1e9],[0,0,0,1]]",
            "from the origin",
        ),
        (
            "bottom",
            "[[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,1,1]]",
            "bottom row",
        ),
    ] {
        let e = error_for(tag, &with(m), 1.0);
        assert_contains(&e, &["frames[1] (train/r_1.png)", "not a rigid", why]);
    }
    // Rounded orthonormal rotations (6 decimals, as in NeRF-synthetic files) are fine.
    let dir = tiny_dataset("rounded");
    // A 30° turn about z, cos and sin rounded to 6 decimals.
    std::fs::write(
        dir.path().join("transforms_train.json"),
        with("[[0.866025,-0.5,0,0],[0.5,0.866025,0,0],[0,0,1,4],[0,0,0,1]]"),
    )
    .unwrap();
    load_split(dir.path(), "train", 1.0, [0.0; 3]).unwrap();
}
