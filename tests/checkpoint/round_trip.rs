use super::*;

// ---------------------------------------------------------------------------------------
// Round trips

#[test]
fn random_scenes_round_trip_bit_exactly() {
    let dir = TempDir::new("roundtrip");
    let mut deepest = 0;
    let mut levels_seen = [false; MAX_LEVEL as usize + 1];
    let mut degrees_seen = [false; MAX_SH_DEGREE as usize + 1];
    for seed in 0..48u64 {
        let mut scene = random_scene(seed);
        if seed % 3 == 1 {
            // A capture's world frame (f64, any magnitude) round-trips bit-exactly.
            scene.world = svraster::scene::WorldFrame {
                center: [1.0e4 + seed as f64 / 7.0, -0.1 / 3.0, 2.5e-7],
                scale: 1.0e-3 * (1.0 + seed as f64 / 9.0),
            };
        }
        deepest = deepest.max(scene.max_level());
        for &l in &scene.octlevel {
            levels_seen[l as usize] = true;
        }
        degrees_seen[scene.sh_degree as usize] = true;
        let path = dir.path(&format!("scene-{seed}.safetensors"));
        save(&scene, &path).unwrap();
        let back = load(&path).unwrap();
        assert_same(&scene, &back);
        // In-memory path and re-encoding agree with the file byte for byte.
        let bytes = to_bytes(&scene).unwrap();
        assert_eq!(bytes, std::fs::read(&path).unwrap(), "seed {seed}");
        assert_same(&scene, &from_bytes(&bytes).unwrap());
        assert_eq!(to_bytes(&back).unwrap(), bytes, "seed {seed}");
    }
    assert_eq!(deepest, MAX_LEVEL);
    assert!(
        levels_seen[1..].iter().all(|&s| s),
        "levels seen: {levels_seen:?}"
    );
    assert!(degrees_seen.iter().all(|&s| s));
    // Only the saved files are left: no temporary files.
    assert_eq!(dir.list().len(), 48);
    assert!(dir.list().iter().all(|n| n.ends_with(".safetensors")));
}

#[test]
fn deep_staircase_round_trips() {
    // One voxel at every level 1..=16 on a path to the far corner, plus its 7 siblings
    // at level 16: corners at coordinate 65536 and at every scale.
    let mut v = Vec::new();
    let mut prefix = 0u64;
    for l in 1..=MAX_LEVEL {
        let shift = 3 * (MAX_LEVEL - l);
        v.push((prefix, l as u8));
        if l == MAX_LEVEL {
            v.extend((1..8u64).map(|c| (prefix | c << shift, l as u8)));
        }
        prefix |= 7 << shift;
    }
    let mut rng = Pcg64::seed_from_u64(5);
    for degree in 0..=MAX_SH_DEGREE {
        let scene = scene_from(&mut rng, &v, degree);
        assert_eq!(scene.max_level(), MAX_LEVEL);
        assert_same(&scene, &from_bytes(&to_bytes(&scene).unwrap()).unwrap());
    }
}

#[test]
fn empty_scene_round_trips() {
    let dir = TempDir::new("empty");
    for degree in 0..=MAX_SH_DEGREE {
        let mut scene =
            Scene::from_voxels([1.0, -2.0, 0.5], 3.0, degree, vec![], vec![], 0.0).unwrap();
        scene.background = [0.25, 0.5, 1.0];
        let path = dir.path(&format!("empty-{degree}.safetensors"));
        save(&scene, &path).unwrap();
        let back = load(&path).unwrap();
        assert_same(&scene, &back);
        assert_eq!(back.num_voxels(), 0);
        assert_eq!(back.num_grid_points(), 0);
        let bytes = std::fs::read(&path).unwrap();
        let (h, data) = split(&bytes);
        assert!(data.is_empty());
        let k = sh_coeffs(degree) as u64 - 1;
        assert_eq!(h["shs"]["shape"], json!([0, k, 3]));
        assert_eq!(h["geo_grid_pts"]["shape"], json!([0]));
    }
}

#[test]
fn degree_zero_has_empty_shs_tensor() {
    let mut rng = Pcg64::seed_from_u64(1);
    let voxels = random_voxels(&mut rng, 5, 200);
    assert!(!voxels.is_empty());
    let scene = scene_from(&mut rng, &voxels, 0);
    let bytes = to_bytes(&scene).unwrap();
    let (h, _) = split(&bytes);
    let o = &h["shs"]["data_offsets"];
    assert_eq!(h["shs"]["shape"], json!([voxels.len(), 0, 3]));
    assert_eq!(o[0], o[1]);
    assert_same(&scene, &from_bytes(&bytes).unwrap());
}

// ---------------------------------------------------------------------------------------
// Byte layout

#[test]
fn byte_layout() {
    // 3 voxels: two level-1 octants and one level-2 voxel, degree 1.
    let paths = vec![0u64, 1 << 45, 7 << 45 | 2 << 42];
    let levels = vec![1u8, 1, 2];
    let mut scene = Scene::from_voxels(
        [0.5, -1.0, 2.25],
        4.0,
        1,
        paths.clone(),
        levels.clone(),
        0.0,
    )
    .unwrap();
    scene.background = [0.0, 0.5, 1.0];
    scene.supersample = 1.5;
    for (i, g) in scene.geo.iter_mut().enumerate() {
        *g = i as f32 - 3.5;
    }
    for (i, c) in scene.sh0.iter_mut().enumerate() {
        *c = [i as f32, 10.0 + i as f32, 0.1];
    }
    for (i, c) in scene.shs.iter_mut().enumerate() {
        *c = -(i as f32) / 7.0;
    }
    let bytes = to_bytes(&scene).unwrap();

    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    assert_eq!((8 + n) % 8, 0, "data must start 8-byte aligned");
    let text = std::str::from_utf8(&bytes[8..8 + n]).unwrap();
    assert!(text.starts_with('{'));
    let trimmed = text.trim_end_matches(' ');
    assert!(trimmed.ends_with('}'), "header padded with spaces only");
    assert!(text.len() - trimmed.len() < 8);
    let h: Value = serde_json::from_str(text).unwrap();
    let h = h.as_object().unwrap();

    let meta = h["__metadata__"].as_object().unwrap();
    assert_eq!(meta["format"], "svraster-vk/1");
    assert_eq!(meta["format"], checkpoint::FORMAT);
    assert_eq!(meta["scene_center"], "[0.5,-1,2.25]");
    assert_eq!(meta["scene_extent"], "4");
    assert_eq!(meta["sh_degree"], "1");
    assert_eq!(meta["background"], "[0,0.5,1]");
    assert_eq!(meta["supersample"], "1.5");
    // A constant background writes no mode; the frame mean writes `frame_mean` and
    // loads back.
    assert!(!meta.contains_key("background_mode"));
    let mut fm = scene.clone();
    fm.background_frame_mean = true;
    let fm_bytes = to_bytes(&fm).unwrap();
    let back = from_bytes(&fm_bytes).unwrap();
    assert!(back.background_frame_mean);
    assert_eq!(back, fm);
    let fm_n = u64::from_le_bytes(fm_bytes[..8].try_into().unwrap()) as usize;
    let fm_head: Value = serde_json::from_slice(&fm_bytes[8..8 + fm_n]).unwrap();
    assert_eq!(fm_head["__metadata__"]["background_mode"], "frame_mean");
    assert!(meta.values().all(Value::is_string));
    let center: Vec<f32> = serde_json::from_str(meta["scene_center"].as_str().unwrap()).unwrap();
    assert_eq!(center, vec![0.5, -1.0, 2.25]);

    let m = scene.num_grid_points();
    // Octants 0 and 1 share a face (8 + 8 - 4); the level-2 voxel touches neither.
    assert_eq!(m, 20);
    let mut keys: Vec<u64> = paths
        .iter()
        .zip(&levels)
        .flat_map(|(&p, &l)| voxel_corner_keys(p, l as u32))
        .collect();
    keys.sort_unstable();
    keys.dedup();
    assert_eq!(keys.len(), m);

    let data = &bytes[8 + n..];
    let expect: [(&str, &str, Value, Vec<u8>); 5] = [
        (
            "octpath",
            "U64",
            json!([3]),
            paths.iter().flat_map(|p| p.to_le_bytes()).collect(),
        ),
        ("octlevel", "U8", json!([3]), levels.clone()),
        ("geo_grid_pts", "F32", json!([m]), f32_bytes(&scene.geo)),
        (
            "sh0",
            "F32",
            json!([3, 3]),
            f32_bytes(bytemuck::cast_slice(&scene.sh0)),
        ),
        ("shs", "F32", json!([3, 3, 3]), f32_bytes(&scene.shs)),
    ];
    assert_eq!(h.len(), 6, "metadata plus exactly 5 tensors");
    let mut spans = Vec::new();
    for (name, dtype, shape, content) in &expect {
        let t = &h[*name];
        assert_eq!(t["dtype"], *dtype, "{name}");
        assert_eq!(t["shape"], *shape, "{name}");
        let b = t["data_offsets"][0].as_u64().unwrap() as usize;
        let e = t["data_offsets"][1].as_u64().unwrap() as usize;
        let esize = match *dtype {
            "U64" => 8,
            "F32" => 4,
            _ => 1,
        };
        assert_eq!(b % esize, 0, "{name} aligned to its element size");
        assert_eq!(&data[b..e], &content[..], "{name} content");
        spans.push((b, e));
    }
    // geo_grid_pts are ordered by ascending corner key: geo[i] belongs to keys[i].
    assert_eq!(scene.grid_keys, keys);
    // Tensors tile the data buffer exactly.
    spans.sort();
    let mut pos = 0;
    for (b, e) in spans {
        assert_eq!(b, pos);
        pos = e;
    }
    assert_eq!(pos, data.len());
}

#[test]
fn metadata_numbers_round_trip_and_are_json() {
    let mut rng = Pcg64::seed_from_u64(77);
    let mut values = vec![
        0.0,
        -0.0,
        1e-30,
        3.0e38,
        f32::MIN_POSITIVE,
        1e-45,
        0.1,
        1e16,
    ];
    values.extend((0..3000).map(|_| any_finite(&mut rng)));
    for v in values {
        let mut s =
            Scene::from_voxels([v, -v, 1.0], v.abs().max(1e-45), 0, vec![], vec![], 0.0).unwrap();
        s.background = [v, 0.5, -v];
        let bytes = to_bytes(&s).unwrap();
        let (h, _) = split(&bytes);
        let meta = &h["__metadata__"];
        for key in ["scene_center", "background"] {
            let parsed: Vec<f64> = serde_json::from_str(meta[key].as_str().unwrap())
                .unwrap_or_else(|e| panic!("{key} = {} is not JSON: {e}", meta[key]));
            assert_eq!(parsed.len(), 3);
        }
        let text = meta["scene_extent"].as_str().unwrap();
        assert!(text.len() <= 16, "not the shortest form: {text}");
        let _: f64 = serde_json::from_str(text).unwrap();
        assert_same(&s, &from_bytes(&bytes).unwrap());
    }
}

// ---------------------------------------------------------------------------------------
// Atomic saving

#[test]
fn save_into_missing_directory_fails_cleanly() {
    let dir = TempDir::new("missing");
    let target = dir.0.path().join("no-such-dir").join("scene.safetensors");
    let e = save(&base_scene(), &target).unwrap_err().to_string();
    assert!(e.contains("does not exist"), "{e}");
    assert!(e.contains("no-such-dir"), "{e}");
    assert!(dir.list().is_empty(), "left behind: {:?}", dir.list());
}

#[test]
fn failed_rename_removes_temp_file() {
    // The destination is a directory: the rename fails after the temp file was written.
    let dir = TempDir::new("rename");
    let target = dir.path("scene.safetensors");
    std::fs::create_dir(&target).unwrap();
    let e = save(&base_scene(), &target).unwrap_err().to_string();
    assert!(e.contains("scene.safetensors"), "{e}");
    assert_eq!(dir.list(), vec!["scene.safetensors".to_string()]);
    assert!(target.is_dir());
}

#[test]
fn save_replaces_existing_file() {
    let dir = TempDir::new("replace");
    let target = dir.path("scene.safetensors");
    std::fs::write(&target, b"old junk that is not a checkpoint").unwrap();
    let a = random_scene(3);
    save(&a, &target).unwrap();
    assert_same(&a, &load(&target).unwrap());
    let b = random_scene(4);
    save(&b, &target).unwrap();
    assert_same(&b, &load(&target).unwrap());
    assert_eq!(dir.list(), vec!["scene.safetensors".to_string()]);
}

#[test]
fn save_refuses_non_finite_scene() {
    let dir = TempDir::new("nan");
    let target = dir.path("scene.safetensors");
    type Break = fn(&mut Scene);
    let cases: [(Break, &str); 6] = [
        (|s| s.geo[3] = f32::NAN, "geo_grid_pts"),
        (|s| s.sh0[1][2] = f32::INFINITY, "sh0"),
        (|s| s.shs[5] = f32::NAN, "shs"),
        (|s| s.center[0] = f32::NAN, "scene_center"),
        (|s| s.background[1] = f32::NEG_INFINITY, "background"),
        (|s| s.extent = f32::INFINITY, "scene_extent"),
    ];
    for (f, what) in cases {
        let mut s = base_scene();
        f(&mut s);
        for e in [
            save(&s, &target).unwrap_err().to_string(),
            to_bytes(&s).unwrap_err().to_string(),
        ] {
            assert!(e.contains(what), "{e}");
            assert!(e.contains("finite"), "{e}");
        }
        assert!(dir.list().is_empty(), "left behind: {:?}", dir.list());
    }
}

// ---------------------------------------------------------------------------------------
// Corrupt files: one test per class

#[test]
fn corrupt_header_length() {
    let good = to_bytes(&base_scene()).unwrap();
    expect_err(&good[..5], &["too short"]);
    expect_err(&[], &["too short"]);
    let mut b = good.clone();
    let beyond = (good.len() - 8 + 1) as u64;
    b[..8].copy_from_slice(&beyond.to_le_bytes());
    expect_err(&b, &["header length", "beyond the end"]);
    let mut b = good.clone();
    b[..8].copy_from_slice(&u64::MAX.to_le_bytes());
    expect_err(&b, &["header length", "absurd"]);
    // Header intact but the file cut short inside the data.
    expect_err(&good[..good.len() - 3], &["out of bounds"]);
    // Cut inside the header.
    expect_err(&good[..20], &["beyond the end"]);
}

#[test]
fn corrupt_header_not_utf8() {
    let mut b = to_bytes(&base_scene()).unwrap();
    let n = u64::from_le_bytes(b[..8].try_into().unwrap()) as usize;
    let text = std::str::from_utf8(&b[8..8 + n]).unwrap();
    let at = 8 + text.find("svraster-vk").unwrap();
    b[at] = 0xff;
    expect_err(&b, &["UTF-8"]);
}

#[test]
fn corrupt_header_malformed_json() {
    let (h, data) = split(&to_bytes(&base_scene()).unwrap());
    let text = serde_json::to_string(&h).unwrap();
    expect_err(
        &join_text(&text[..text.len() - 1], &data),
        &["malformed JSON"],
    );
    expect_err(&join_text("{not json}", &data), &["malformed JSON"]);
    expect_err(&join_text("[1, 2, 3]", &data), &["malformed JSON"]);
    expect_err(&join_text("", &data), &["malformed JSON"]);
    // A tensor entry that is not an object.
    assert!(text.contains("\"octlevel\":{"));
    let bad = text.replacen("\"octlevel\":{", "\"octlevel\":[1,2],\"x\":{", 1);
    expect_err(&join_text(&bad, &data), &["malformed JSON"]);
    // Duplicate keys would silently shadow each other: rejected.
    let dup = text.replacen('{', "{\"__metadata__\":{},", 1);
    expect_err(
        &join_text(&dup, &data),
        &["`__metadata__`", "more than once"],
    );
}

#[test]
fn corrupt_missing_tensor() {
    for name in ["octpath", "octlevel", "geo_grid_pts", "sh0", "shs"] {
        corrupt(
            |_, ts| ts.retain(|t| t.name != name),
            &[&format!("`{name}` is missing")],
        );
    }
}

#[test]
fn corrupt_unknown_tensor() {
    corrupt(
        |_, ts| {
            ts.push(T {
                name: "opacity".into(),
                dtype: "F32".into(),
                shape: vec![2],
                data: vec![0; 8],
            })
        },
        &["unknown tensor `opacity`"],
    );
    // Even an empty one.
    corrupt(
        |_, ts| {
            ts.push(T {
                name: "x".into(),
                dtype: "U8".into(),
                shape: vec![0],
                data: vec![],
            })
        },
        &["unknown tensor `x`"],
    );
}

#[test]
fn corrupt_wrong_dtype() {
    for (name, wrong) in [
        ("octpath", "I64"),
        ("octlevel", "I8"),
        ("geo_grid_pts", "F64"),
        ("sh0", "F16"),
        ("shs", "U32"),
    ] {
        corrupt(
            |_, ts| tensor(ts, name).dtype = wrong.into(),
            &[&format!("`{name}`"), "dtype", wrong],
        );
    }
    corrupt_header(
        |h, _| h["octlevel"]["dtype"] = json!(8),
        &["`octlevel`", "dtype"],
    );
    corrupt_header(
        |h, _| {
            h["sh0"].as_object_mut().unwrap().remove("dtype");
        },
        &["`sh0`", "`dtype`"],
    );
}

#[test]
fn corrupt_wrong_shape_or_rank() {
    let s = base_scene();
    let n = s.num_voxels() as u64;
    let m = s.num_grid_points() as u64;
    corrupt(
        |_, ts| tensor(ts, "octpath").shape = vec![n, 1],
        &["`octpath`", "rank"],
    );
    corrupt(
        |_, ts| tensor(ts, "octlevel").shape = vec![],
        &["`octlevel`", "rank"],
    );
    corrupt(
        |_, ts| tensor(ts, "geo_grid_pts").shape = vec![m, 1],
        &["`geo_grid_pts`", "rank"],
    );
    corrupt(
        |_, ts| tensor(ts, "sh0").shape = vec![n * 3],
        &["`sh0`", "rank"],
    );
    corrupt(
        |_, ts| tensor(ts, "sh0").shape = vec![3, n],
        &["`sh0`", "shape"],
    );
    // Degree 2 has 8 higher coefficients; a degree-3 layout is wrong.
    corrupt(
        |_, ts| {
            let t = tensor(ts, "shs");
            t.shape = vec![n, 15, 3];
            t.data = vec![0; (n * 15 * 12) as usize];
        },
        &["`shs`", "shape", "sh_degree 2"],
    );
    corrupt(
        |_, ts| tensor(ts, "shs").shape = vec![n, 24],
        &["`shs`", "rank"],
    );
    corrupt_header(
        |h, _| h["shs"]["shape"] = json!([n, -8, 3]),
        &["`shs`", "`shape`", "non-negative integers"],
    );
}

#[test]
fn corrupt_inconsistent_voxel_count() {
    let n = base_scene().num_voxels();
    corrupt(
        |_, ts| {
            let t = tensor(ts, "octlevel");
            t.shape = vec![n as u64 - 1];
            t.data.pop();
        },
        &["`octlevel`", "N = 12"],
    );
    corrupt(
        |_, ts| {
            let t = tensor(ts, "sh0");
            t.shape = vec![n as u64 + 1, 3];
            t.data.extend_from_slice(&[0; 12]);
        },
        &["`sh0`", "N = 12"],
    );
    corrupt(
        |_, ts| {
            let t = tensor(ts, "shs");
            t.shape = vec![n as u64 - 1, 8, 3];
            t.data.truncate(t.data.len() - 8 * 12);
        },
        &["`shs`", "N = 12"],
    );
    // octpath itself shorter than the rest.
    corrupt(
        |_, ts| {
            let t = tensor(ts, "octpath");
            t.shape = vec![n as u64 - 1];
            t.data.truncate(t.data.len() - 8);
        },
        &["`octlevel`", "N = 11"],
    );
}
