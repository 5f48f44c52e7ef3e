use super::*;

#[test]
fn corrupt_data_offsets() {
    // end < begin
    corrupt_header(
        |h, _| h["sh0"]["data_offsets"] = json!([40, 20]),
        &["`sh0`", "end 20 < begin 40"],
    );
    // out of bounds
    corrupt_header(
        |h, data| {
            let len = data.len() as u64;
            h["octlevel"]["data_offsets"] = json!([len - 12, len + 1]);
        },
        &["`octlevel`", "out of bounds"],
    );
    corrupt_header(
        |h, _| h["octpath"]["data_offsets"] = json!([u64::MAX - 1, u64::MAX]),
        &["`octpath`", "out of bounds"],
    );
    // size != shape × dtype size
    corrupt_header(
        |h, _| {
            let e = h["octpath"]["data_offsets"][1].as_u64().unwrap();
            h["octpath"]["data_offsets"][1] = json!(e - 8);
        },
        &["`octpath`", "needs 96"],
    );
    // overlap: geo_grid_pts moved onto octpath.
    corrupt_header(
        |h, _| {
            let b = h["geo_grid_pts"]["data_offsets"][0].as_u64().unwrap();
            let e = h["geo_grid_pts"]["data_offsets"][1].as_u64().unwrap();
            h["geo_grid_pts"]["data_offsets"] = json!([b - 8, e - 8]);
        },
        &["overlap", "`octpath`", "`geo_grid_pts`"],
    );
    // a gap between tensors, and trailing bytes
    corrupt_header(
        |h, data| {
            let b = h["octpath"]["data_offsets"][1].as_u64().unwrap() as usize;
            for (k, v) in h.iter_mut() {
                if k != "__metadata__" && k != "octpath" {
                    for i in 0..2 {
                        let o = v["data_offsets"][i].as_u64().unwrap();
                        v["data_offsets"][i] = json!(o + 4);
                    }
                }
            }
            data.splice(b..b, [0u8; 4]);
        },
        &["gap", "bytes 96..100"],
    );
    corrupt_header(
        |_, data| data.extend_from_slice(&[0; 8]),
        &["gap", "8 trailing bytes"],
    );
    // malformed offsets
    corrupt_header(
        |h, _| h["sh0"]["data_offsets"] = json!([0.5, 3]),
        &["`sh0`", "`data_offsets`", "non-negative integers"],
    );
    corrupt_header(
        |h, _| h["sh0"]["data_offsets"] = json!([0, 3, 5]),
        &["`sh0`", "[begin, end]"],
    );
    corrupt_header(
        |h, _| {
            h["sh0"]["extra"] = json!(1);
        },
        &["`sh0`", "unknown field `extra`"],
    );
}

#[test]
fn corrupt_metadata() {
    corrupt_header(
        |h, _| {
            h.remove("__metadata__");
        },
        &["`__metadata__`"],
    );
    corrupt_header(
        |h, _| h["__metadata__"] = json!("svraster"),
        &["malformed JSON"],
    );
    for key in [
        "format",
        "scene_center",
        "scene_extent",
        "sh_degree",
        "background",
    ] {
        corrupt(
            |m, _| {
                m.as_object_mut().unwrap().remove(key);
            },
            &[&format!("`{key}` is missing")],
        );
    }
    let cases: &[(&str, Value, &[&str])] = &[
        ("sh_degree", json!(2), &["`sh_degree` must be a string"]),
        (
            "sh_degree",
            json!("two"),
            &["`sh_degree`", "not an integer"],
        ),
        ("sh_degree", json!("-1"), &["`sh_degree`", "not an integer"]),
        (
            "scene_center",
            json!("[1,2]"),
            &["`scene_center`", "3 numbers"],
        ),
        (
            "scene_center",
            json!("[1,2,3,4]"),
            &["`scene_center`", "3 numbers"],
        ),
        (
            "scene_center",
            json!("1,2,3"),
            &["`scene_center`", "JSON array"],
        ),
        (
            "scene_center",
            json!("[1,x,3]"),
            &["`scene_center`", "not a number"],
        ),
        ("background", json!("[]"), &["`background`", "3 numbers"]),
        (
            "scene_extent",
            json!("big"),
            &["`scene_extent`", "not a number"],
        ),
        ("scene_extent", json!("0"), &["`scene_extent`", "> 0"]),
        ("scene_extent", json!("-2"), &["`scene_extent`", "> 0"]),
        (
            "scene_extent",
            json!([4]),
            &["`scene_extent` must be a string"],
        ),
        ("comment", json!(5), &["`comment` must be a string"]),
    ];
    for (key, v, needles) in cases {
        corrupt(|m, _| m[*key] = v.clone(), needles);
    }
    for v in ["0.5", "0", "9", "-1", "inf", "NaN", "x"] {
        corrupt(|m, _| m["supersample"] = json!(v), &["`supersample`"]);
    }
    for v in ["mean", "FRAME_MEAN", ""] {
        corrupt(
            |m, _| m["background_mode"] = json!(v),
            &["`background_mode`", "`colour` or `frame_mean`"],
        );
    }
    corrupt(
        |m, _| m["background_mode"] = json!(true),
        &["`background_mode` must be a string"],
    );
    // `colour` is the default, written out.
    let (mut meta, ts) = tensors(&to_bytes(&base_scene()).unwrap());
    meta["background_mode"] = json!("colour");
    assert!(
        !from_bytes(&assemble(&meta, &ts))
            .unwrap()
            .background_frame_mean
    );
    // Files written before `supersample` existed load with none (1).
    let mut old_scene = base_scene();
    old_scene.supersample = 1.5;
    let (mut meta, ts) = tensors(&to_bytes(&old_scene).unwrap());
    meta.as_object_mut().unwrap().remove("supersample");
    let back = from_bytes(&assemble(&meta, &ts)).unwrap();
    assert_eq!(back.supersample, 1.0);
    // Unknown metadata keys are fine (free-form metadata).
    let (mut meta, ts) = tensors(&to_bytes(&base_scene()).unwrap());
    meta["comment"] = json!("trained for 20k iterations");
    assert_same(&base_scene(), &from_bytes(&assemble(&meta, &ts)).unwrap());
}

#[test]
fn corrupt_wrong_format() {
    for f in ["svraster-vk/2", "svraster", "", "SVRASTER-VK/1"] {
        corrupt(
            |m, _| m["format"] = json!(f),
            &["`format`", "svraster-vk/1"],
        );
    }
}

#[test]
fn corrupt_sh_degree_out_of_range() {
    for d in ["4", "17", "4294967295"] {
        corrupt(|m, _| m["sh_degree"] = json!(d), &["`sh_degree`", "0..=3"]);
    }
}

#[test]
fn corrupt_non_finite_values() {
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        corrupt(
            |_, ts| tensor(ts, "geo_grid_pts").data[20..24].copy_from_slice(&bad.to_le_bytes()),
            &["geo_grid_pts[5]", "not finite"],
        );
        corrupt(
            |_, ts| tensor(ts, "sh0").data[28..32].copy_from_slice(&bad.to_le_bytes()),
            &["sh0[2]", "not finite"],
        );
        corrupt(
            |_, ts| tensor(ts, "shs").data[4 * 30..4 * 31].copy_from_slice(&bad.to_le_bytes()),
            &["shs value 30 (voxel 1)", "not finite"],
        );
    }
    // A NaN with a payload, too.
    corrupt(
        |_, ts| tensor(ts, "geo_grid_pts").data[..4].copy_from_slice(&0x7fc0_1234u32.to_le_bytes()),
        &["geo_grid_pts[0]", "not finite"],
    );
    for (key, v) in [
        ("scene_center", "[NaN,0,0]"),
        ("scene_center", "[0,inf,0]"),
        ("background", "[0,0,-inf]"),
        ("scene_extent", "inf"),
        ("scene_extent", "1e39"),
    ] {
        corrupt(
            |m, _| m[key] = json!(v),
            &[&format!("`{key}`"), "not finite"],
        );
    }
}

#[test]
fn corrupt_levels() {
    for (bad, at) in [(0u8, 0usize), (17, 3), (255, 11)] {
        corrupt(
            |_, ts| tensor(ts, "octlevel").data[at] = bad,
            &[&format!("octlevel[{at}] is {bad}"), "outside 1..=16"],
        );
    }
}

#[test]
fn corrupt_octpath_bits() {
    // Voxel 0 is at level 1: any bit below bit 45 is outside its path.
    for bit in [0u32, 20, 44, 48, 63] {
        corrupt(
            |_, ts| {
                let d = &mut tensor(ts, "octpath").data[..8];
                let p = u64::from_le_bytes(d.try_into().unwrap()) | 1 << bit;
                d.copy_from_slice(&p.to_le_bytes());
            },
            &["octpath[0]", "bits outside the path of its level 1"],
        );
    }
    // The level-16 voxel may use every bit below 48, but not above.
    corrupt(
        |_, ts| {
            let d = &mut tensor(ts, "octpath").data[8 * 11..8 * 12];
            let p = u64::from_le_bytes(d.try_into().unwrap()) | 1 << 50;
            d.copy_from_slice(&p.to_le_bytes());
        },
        &["octpath[11]", "level 16"],
    );
}

#[test]
fn corrupt_duplicate_or_overlapping_voxels() {
    // An exact duplicate of voxel 0 (level-1 octant 0).
    corrupt(|_, ts| push_voxel(ts, 0, 1), &["overlap or are duplicates"]);
    // A level-3 voxel inside level-1 octant 2.
    corrupt(
        |_, ts| push_voxel(ts, 2 << 45 | 5 << 42 | 1 << 39, 3),
        &["overlap"],
    );
    // A level-1 voxel covering the four level-2 voxels in octant 7.
    corrupt(|_, ts| push_voxel(ts, 7 << 45, 1), &["overlap"]);
    // The level-16 voxel duplicated.
    let p = octpath_from_ijk([40000, 50000, 123], 16);
    corrupt(
        |_, ts| push_voxel(ts, p, 16),
        &["overlap or are duplicates"],
    );
}

#[test]
fn corrupt_grid_point_count() {
    let m = base_scene().num_grid_points();
    corrupt(
        |_, ts| {
            let t = tensor(ts, "geo_grid_pts");
            t.shape = vec![m as u64 - 1];
            t.data.truncate(t.data.len() - 4);
        },
        &[
            &format!("geo_grid_pts has {} values", m - 1),
            &format!("{m} unique corners"),
        ],
    );
    corrupt(
        |_, ts| {
            let t = tensor(ts, "geo_grid_pts");
            t.shape = vec![m as u64 + 1];
            t.data.extend_from_slice(&[0; 4]);
        },
        &[&format!("{m} unique corners")],
    );
    // A valid extra voxel (child 6 of octant 7 is free) without its grid points.
    corrupt(
        |_, ts| push_voxel(ts, 7 << 45 | 6 << 42, 2),
        &["geo_grid_pts has", "unique corners"],
    );
}

#[test]
fn load_errors_name_the_file() {
    let dir = TempDir::new("names");
    let path = dir.path("broken.safetensors");
    let mut b = to_bytes(&base_scene()).unwrap();
    b.truncate(b.len() - 1);
    std::fs::write(&path, &b).unwrap();
    let e = load(&path).unwrap_err().to_string();
    assert!(e.contains(&path.display().to_string()), "{e}");
    assert!(e.contains("out of bounds"), "{e}");

    let missing = dir.path("missing.safetensors");
    let e = load(&missing).unwrap_err();
    assert!(matches!(e, svraster::Error::Io { .. }), "{e}");
    assert!(e.to_string().contains("missing.safetensors"), "{e}");
}

#[test]
fn loaded_scene_is_usable() {
    // Derived data is rebuilt: corners resolve to the grid points of each voxel.
    let s = load_round_trip(&random_scene(12));
    assert!(s.num_voxels() > 1000);
    for i in 0..s.num_voxels() {
        let keys = voxel_corner_keys(s.octpath[i], s.octlevel[i] as u32);
        for (&g, &k) in s.corners[i].iter().zip(&keys) {
            assert_eq!(s.grid_keys[g as usize], k);
        }
    }
}

/// Interoperability with the reference implementation of the format (the `safetensors`
/// crate, as used by Python's `safetensors`): it reads our files and finds our tensors
/// byte for byte, and a file it writes from the same tensors and metadata loads back as
/// the same scene. (Our reader stays our own: the crate keeps the last of duplicate
/// keys, and its errors name neither the tensor nor the bytes for most corruptions.)
#[test]
fn safetensors_reference_implementation_interoperates() {
    use safetensors::{tensor::TensorView, Dtype, SafeTensors};
    let scene = base_scene();
    let ours = to_bytes(&scene).unwrap();
    let st = SafeTensors::deserialize(&ours).unwrap();
    let (_, header) = SafeTensors::read_metadata(&ours).unwrap();
    let meta = header.metadata().clone().unwrap();
    assert_eq!(meta["format"], checkpoint::FORMAT);
    let n = scene.num_voxels();
    let sh0: Vec<f32> = scene.sh0.iter().flatten().copied().collect();
    let want: [(&str, Dtype, Vec<usize>, &[u8]); 5] = [
        (
            "octpath",
            Dtype::U64,
            vec![n],
            bytemuck::cast_slice(&scene.octpath),
        ),
        ("octlevel", Dtype::U8, vec![n], &scene.octlevel),
        (
            "geo_grid_pts",
            Dtype::F32,
            vec![scene.num_grid_points()],
            bytemuck::cast_slice(&scene.geo),
        ),
        ("sh0", Dtype::F32, vec![n, 3], bytemuck::cast_slice(&sh0)),
        (
            "shs",
            Dtype::F32,
            vec![n, scene.shs_per_voxel(), 3],
            bytemuck::cast_slice(&scene.shs),
        ),
    ];
    assert_eq!(st.len(), want.len());
    for (name, dtype, shape, data) in &want {
        let t = st.tensor(name).unwrap();
        assert_eq!((t.dtype(), t.shape()), (*dtype, &shape[..]), "{name}");
        assert_eq!(t.data(), *data, "{name}");
    }
    let views: Vec<(&str, TensorView)> = want
        .iter()
        .map(|(name, dtype, shape, data)| {
            (*name, TensorView::new(*dtype, shape.clone(), data).unwrap())
        })
        .collect();
    let theirs = safetensors::serialize(views, Some(meta)).unwrap();
    let back = from_bytes(&theirs).unwrap();
    assert_eq!(back.octpath, scene.octpath);
    assert_eq!(back.octlevel, scene.octlevel);
    assert_eq!(back.geo, scene.geo);
    assert_eq!(back.sh0, scene.sh0);
    assert_eq!(back.shs, scene.shs);
    assert_eq!(
        (
            back.center,
            back.extent,
            back.sh_degree,
            back.background,
            back.supersample
        ),
        (
            scene.center,
            scene.extent,
            scene.sh_degree,
            scene.background,
            scene.supersample
        )
    );
}

#[test]
fn quantized_checkpoints_load_as_the_nearest_codebook_entries() {
    let dir = TempDir::new("quantized");
    for seed in 0..16u64 {
        // Extreme values (any finite f32) half of the time, ordinary ones otherwise.
        let s = if seed % 2 == 0 {
            random_scene(seed)
        } else {
            ordinary_scene(seed, false)
        };
        let path = dir.path("q.safetensors");
        checkpoint::save_quantized(&s, &path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let q = load(&path).unwrap();
        assert_eq!(q.octpath, s.octpath);
        assert_eq!(q.octlevel, s.octlevel);
        assert_eq!(q.sh_degree, s.sh_degree);
        assert_eq!(q.center, s.center);
        assert_eq!(q.extent, s.extent);
        assert_eq!(q.background, s.background);
        assert_eq!(q.supersample, s.supersample);
        let books = codebooks(&bytes);
        let k = s.shs_per_voxel();
        assert_eq!(books.len(), 1 + 3 + 3 * k);
        assert_nearest(&s.geo, &q.geo, &books[..1], 1, "geo");
        let (s0, q0): (&[f32], &[f32]) =
            (bytemuck::cast_slice(&s.sh0), bytemuck::cast_slice(&q.sh0));
        assert_nearest(s0, q0, &books[1..4], 3, "sh0");
        assert_nearest(&s.shs, &q.shs, &books[4..], 3 * k, "shs");
    }
}

#[test]
fn quantized_codebooks_are_refined_and_the_file_is_small() {
    use svraster::scene::quantize::kmeans8;
    let s = ordinary_scene(3, true);
    let full = to_bytes(&s).unwrap().len();
    let quant = checkpoint::to_bytes_quantized(&s).unwrap().len();
    let ratio = quant as f64 / full as f64;
    println!(
        "{} voxels, {} grid points: {full} → {quant} bytes ({:.0} % smaller)",
        s.num_voxels(),
        s.num_grid_points(),
        100.0 * (1.0 - ratio)
    );
    assert!(ratio < 0.35, "quantized file is {ratio:.2} of the full one");
    // k-means against its own start (256 equal-count slices) and against uniform levels.
    let mse = |v: &[f32], book: &[f32]| -> f64 {
        v.iter()
            .map(|&x| {
                book.iter()
                    .map(|&c| (x as f64 - c as f64).powi(2))
                    .fold(f64::INFINITY, f64::min)
            })
            .sum::<f64>()
            / v.len() as f64
    };
    for (what, v) in [
        ("densities", s.geo.clone()),
        ("shs", s.shs.iter().step_by(45).copied().collect()),
    ] {
        let q = kmeans8(&v);
        let mut sorted = v.clone();
        sorted.sort_by(f32::total_cmp);
        let n = sorted.len();
        let start: Vec<f32> = (0..256)
            .map(|k| {
                let (a, b) = (k * n / 256, (k + 1) * n / 256);
                (sorted[a..b].iter().map(|&x| x as f64).sum::<f64>() / (b - a) as f64) as f32
            })
            .collect();
        let (lo, hi) = (sorted[0], sorted[n - 1]);
        let uniform: Vec<f32> = (0..256)
            .map(|k| lo + (hi - lo) * (k as f32 + 0.5) / 256.0)
            .collect();
        let (e, e0, eu) = (mse(&v, &q.codebook), mse(&v, &start), mse(&v, &uniform));
        println!("{what}: mse k-means {e:.3e}, start {e0:.3e}, uniform {eu:.3e}");
        assert!(e < 0.9 * e0, "{what}: k-means did not improve on its start");
        assert!(e < eu, "{what}: k-means is worse than uniform levels");
        assert!(
            q.codebook.windows(2).all(|w| w[0] <= w[1]),
            "codebook not ascending"
        );
    }
}

#[test]
fn corrupt_quantized_checkpoints_are_rejected() {
    let q = checkpoint::to_bytes_quantized(&base_scene()).unwrap();
    let (meta, ts) = tensors(&q);
    let with = |f: &dyn Fn(&mut Value, &mut Vec<T>)| {
        let (mut m, mut t) = (meta.clone(), ts.clone());
        f(&mut m, &mut t);
        assemble(&m, &t)
    };
    expect_err(
        &with(&|_, t| {
            let cb = tensor(t, "sh0_codebook");
            cb.data[4..8].copy_from_slice(&f32::NAN.to_le_bytes());
        }),
        &["sh0_codebook", "not finite"],
    );
    expect_err(
        &with(&|m, _| m["quantized"] = json!("int4")),
        &["quantized", "int4", "unsupported"],
    );
    expect_err(
        &with(&|_, t| tensor(t, "geo_grid_pts_codebook").shape = vec![2, 128]),
        &["geo_grid_pts_codebook", "[1, 256]"],
    );
    // Without the metadata key the quantized tensors are unknown.
    expect_err(
        &with(&|m, _| {
            m.as_object_mut().unwrap().remove("quantized");
        }),
        &["unknown tensor", "geo_grid_pts_codebook"],
    );
    // A full-precision file claiming to be quantized lacks the quantized tensors.
    let (mut m, t) = tensors(&to_bytes(&base_scene()).unwrap());
    m["quantized"] = json!("kmeans8");
    expect_err(&assemble(&m, &t), &["unknown tensor"]);
}
