//! Checkpoint format: bit-exact round trips of random multi-level scenes, the byte
//! layout, atomic saving, and one rejection test per class of corrupt file.

use std::path::PathBuf;

use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use serde_json::{json, Value};
use svraster::scene::checkpoint::{self, from_bytes, load, save, to_bytes};
use svraster::scene::{
    octpath_from_ijk, sh_coeffs, voxel_corner_keys, Scene, MAX_LEVEL, MAX_SH_DEGREE,
};

// ---------------------------------------------------------------------------------------
// Helpers

/// A fresh, uniquely named directory `svraster-ckpt-test-<tag>-…` under the system temp
/// dir, removed on drop.
struct TempDir(tempfile::TempDir);

impl TempDir {
    fn new(tag: &str) -> TempDir {
        TempDir(
            tempfile::Builder::new()
                .prefix(&format!("svraster-ckpt-test-{tag}-"))
                .tempdir()
                .unwrap(),
        )
    }
    fn path(&self, name: &str) -> PathBuf {
        self.0.path().join(name)
    }
    /// Names of everything in the directory, sorted.
    fn list(&self) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(self.0.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }
}

/// Any finite f32, bit patterns drawn uniformly (covers -0, subnormals, huge values),
/// or an ordinary value.
fn any_finite(rng: &mut Pcg64) -> f32 {
    if rng.gen_bool(0.5) {
        return rng.gen_range(-10.0f32..10.0);
    }
    loop {
        let v = f32::from_bits(rng.gen());
        if v.is_finite() {
            return v;
        }
    }
}

/// Non-overlapping voxels by random recursive subdivision of the root cube: each node
/// (below the root) either becomes a leaf, kept with probability 0.85, or is split with
/// a random subset of its 8 children explored further.
fn random_voxels(rng: &mut Pcg64, max_level: u32, budget: usize) -> Vec<(u64, u8)> {
    fn go(
        rng: &mut Pcg64,
        path: u64,
        level: u32,
        max_level: u32,
        budget: usize,
        out: &mut Vec<(u64, u8)>,
    ) {
        if out.len() >= budget {
            return;
        }
        if level >= 1 && (level == max_level || rng.gen_bool(0.3)) {
            if rng.gen_bool(0.85) {
                out.push((path, level as u8));
            }
            return;
        }
        let child = level + 1;
        for c in 0..8u64 {
            if rng.gen_bool(0.4) {
                let p = path | c << (3 * (MAX_LEVEL - child));
                go(rng, p, child, max_level, budget, out);
            }
        }
    }
    let mut out = Vec::new();
    go(rng, 0, 0, max_level, budget, &mut out);
    out.shuffle(rng);
    out
}

/// A scene over `voxels` with random metadata, densities and SH.
fn scene_from(rng: &mut Pcg64, voxels: &[(u64, u8)], sh_degree: u32) -> Scene {
    let center = [any_finite(rng), any_finite(rng), any_finite(rng)];
    let mut extent = any_finite(rng).abs();
    if extent == 0.0 {
        extent = 1.0;
    }
    let mut s = Scene::from_voxels(
        center,
        extent,
        sh_degree,
        voxels.iter().map(|v| v.0).collect(),
        voxels.iter().map(|v| v.1).collect(),
        0.0,
    )
    .unwrap();
    s.background = [any_finite(rng), any_finite(rng), any_finite(rng)];
    s.supersample = 1.0 + 7.0 * rng.gen::<f32>();
    for g in &mut s.geo {
        *g = any_finite(rng);
    }
    for c in &mut s.sh0 {
        *c = [any_finite(rng), any_finite(rng), any_finite(rng)];
    }
    for c in &mut s.shs {
        *c = any_finite(rng);
    }
    s.validate().unwrap();
    s
}

fn random_scene(seed: u64) -> Scene {
    let mut rng = Pcg64::seed_from_u64(seed);
    let max_level = if seed.is_multiple_of(3) {
        MAX_LEVEL
    } else {
        rng.gen_range(1..=MAX_LEVEL)
    };
    let budget = rng.gen_range(1..3000);
    let voxels = random_voxels(&mut rng, max_level, budget);
    scene_from(&mut rng, &voxels, (seed % 4) as u32)
}

/// A fixed small scene with voxels at levels 1, 2, 3 and 16, SH degree 2.
fn base_scene() -> Scene {
    let mut v: Vec<(u64, u8)> = (0..6u64).map(|c| (c << 45, 1)).collect();
    v.extend((0..4u64).map(|c| (7 << 45 | c << 42, 2)));
    v.push((7 << 45 | 5 << 42 | 3 << 39, 3));
    v.push((octpath_from_ijk([40000, 50000, 123], 16), 16));
    let mut rng = Pcg64::seed_from_u64(99);
    scene_from(&mut rng, &v, 2)
}

/// Bit-exact equality (f32 compared by bit pattern), plus `PartialEq`.
fn assert_same(a: &Scene, b: &Scene) {
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
    assert_eq!(bits(&a.center), bits(&b.center), "center");
    assert_eq!(a.extent.to_bits(), b.extent.to_bits(), "extent");
    assert_eq!(a.sh_degree, b.sh_degree, "sh_degree");
    assert_eq!(bits(&a.background), bits(&b.background), "background");
    assert_eq!(
        a.supersample.to_bits(),
        b.supersample.to_bits(),
        "supersample"
    );
    assert_eq!(
        a.world.center.map(f64::to_bits),
        b.world.center.map(f64::to_bits),
        "world center"
    );
    assert_eq!(
        a.world.scale.to_bits(),
        b.world.scale.to_bits(),
        "world scale"
    );
    assert_eq!(a.octpath, b.octpath, "octpath");
    assert_eq!(a.octlevel, b.octlevel, "octlevel");
    assert_eq!(a.grid_keys, b.grid_keys, "grid_keys");
    assert_eq!(a.corners, b.corners, "corners");
    assert_eq!(bits(&a.geo), bits(&b.geo), "geo");
    assert_eq!(
        bits(bytemuck::cast_slice(&a.sh0)),
        bits(bytemuck::cast_slice(&b.sh0)),
        "sh0"
    );
    assert_eq!(bits(&a.shs), bits(&b.shs), "shs");
    assert_eq!(a, b);
}

/// A checkpoint taken apart: header JSON and data buffer.
fn split(bytes: &[u8]) -> (serde_json::Map<String, Value>, Vec<u8>) {
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    (header.as_object().unwrap().clone(), bytes[8 + n..].to_vec())
}

/// Header text (padded to 8-byte data alignment) plus data, as a file.
fn join_text(header: &str, data: &[u8]) -> Vec<u8> {
    let mut h = header.as_bytes().to_vec();
    while !(8 + h.len()).is_multiple_of(8) {
        h.push(b' ');
    }
    let mut out = (h.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(&h);
    out.extend_from_slice(data);
    out
}

fn join(header: &serde_json::Map<String, Value>, data: &[u8]) -> Vec<u8> {
    join_text(&serde_json::to_string(header).unwrap(), data)
}

/// One tensor: name, dtype, shape, raw bytes.
#[derive(Clone)]
struct T {
    name: String,
    dtype: String,
    shape: Vec<u64>,
    data: Vec<u8>,
}

/// Metadata and tensors of a checkpoint.
fn tensors(bytes: &[u8]) -> (Value, Vec<T>) {
    let (mut h, data) = split(bytes);
    let meta = h.remove("__metadata__").unwrap();
    let mut ts: Vec<(u64, T)> = h
        .into_iter()
        .map(|(name, v)| {
            let o: Vec<u64> = serde_json::from_value(v["data_offsets"].clone()).unwrap();
            let t = T {
                name,
                dtype: v["dtype"].as_str().unwrap().to_string(),
                shape: serde_json::from_value(v["shape"].clone()).unwrap(),
                data: data[o[0] as usize..o[1] as usize].to_vec(),
            };
            (o[0], t)
        })
        .collect();
    ts.sort_by_key(|t| t.0);
    (meta, ts.into_iter().map(|t| t.1).collect())
}

/// A file from metadata and tensors laid out back to back.
fn assemble(meta: &Value, ts: &[T]) -> Vec<u8> {
    let mut h = serde_json::Map::new();
    h.insert("__metadata__".into(), meta.clone());
    let mut data = Vec::new();
    for t in ts {
        h.insert(
            t.name.clone(),
            json!({"dtype": t.dtype, "shape": t.shape,
                   "data_offsets": [data.len(), data.len() + t.data.len()]}),
        );
        data.extend_from_slice(&t.data);
    }
    join(&h, &data)
}

fn tensor<'a>(ts: &'a mut [T], name: &str) -> &'a mut T {
    ts.iter_mut().find(|t| t.name == name).unwrap()
}

/// Asserts that loading `bytes` fails with a message containing every needle.
#[track_caller]
fn expect_err(bytes: &[u8], needles: &[&str]) {
    let e = match from_bytes(bytes) {
        Ok(_) => panic!("corrupt checkpoint was accepted (expected {needles:?})"),
        Err(e) => e.to_string(),
    };
    for n in needles {
        assert!(e.contains(n), "error `{e}` does not mention `{n}`");
    }
}

/// Applies `f` to the base scene's metadata and tensors and expects rejection.
#[track_caller]
fn corrupt(f: impl FnOnce(&mut Value, &mut Vec<T>), needles: &[&str]) {
    let (mut meta, mut ts) = tensors(&to_bytes(&base_scene()).unwrap());
    f(&mut meta, &mut ts);
    expect_err(&assemble(&meta, &ts), needles);
}

/// Applies `f` to the base scene's raw header map and expects rejection.
#[track_caller]
fn corrupt_header(
    f: impl FnOnce(&mut serde_json::Map<String, Value>, &mut Vec<u8>),
    needles: &[&str],
) {
    let (mut h, mut data) = split(&to_bytes(&base_scene()).unwrap());
    f(&mut h, &mut data);
    expect_err(&join(&h, &data), needles);
}

fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

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

/// Appends one voxel (path, level) with zero SH to the tensors.
fn push_voxel(ts: &mut [T], path: u64, level: u8) {
    for t in ts.iter_mut() {
        let per = match t.name.as_str() {
            "octpath" => path.to_le_bytes().to_vec(),
            "octlevel" => vec![level],
            "sh0" => vec![0; 12],
            "shs" => vec![0; 8 * 12],
            _ => continue,
        };
        t.shape[0] += 1;
        t.data.extend_from_slice(&per);
    }
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

fn load_round_trip(s: &Scene) -> Scene {
    from_bytes(&to_bytes(s).unwrap()).unwrap()
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

// ---------------------------------------------------------------------------------------
// 8-bit quantized checkpoints (scene::quantize, checkpoint::save_quantized)

/// A scene with ordinary values: densities ~ N(-2, 3), SH DC ~ N(0, 1), higher SH
/// ~ N(0, 0.2) (sums of uniforms), SH degree 3; random voxels, or (`grid`) every voxel
/// of level 5 (32 768, as a model's starting grid).
fn ordinary_scene(seed: u64, grid: bool) -> Scene {
    let mut rng = Pcg64::seed_from_u64(seed);
    let voxels: Vec<(u64, u8)> = if grid {
        (0..32u32 * 32 * 32)
            .map(|i| (octpath_from_ijk([i % 32, i / 32 % 32, i / 1024], 5), 5u8))
            .collect()
    } else {
        random_voxels(&mut rng, 8, 500)
    };
    let mut s = scene_from(&mut rng, &voxels, 3);
    let mut normal = |mean: f32, sd: f32| -> f32 {
        let u: f32 = (0..6).map(|_| rng.gen::<f32>()).sum::<f32>() - 3.0;
        mean + sd * u * std::f32::consts::SQRT_2
    };
    for g in &mut s.geo {
        *g = normal(-2.0, 3.0);
    }
    for c in &mut s.sh0 {
        *c = [normal(0.0, 1.0), normal(0.0, 1.0), normal(0.0, 1.0)];
    }
    for c in &mut s.shs {
        *c = normal(0.0, 0.2);
    }
    s
}

/// (codebooks of every channel, in order geo, sh0 r/g/b, shs) of a quantized file.
fn codebooks(bytes: &[u8]) -> Vec<Vec<f32>> {
    let (meta, ts) = tensors(bytes);
    assert_eq!(meta["quantized"], "kmeans8");
    let mut out = vec![];
    for name in ["geo_grid_pts_codebook", "sh0_codebook", "shs_codebook"] {
        let t = ts.iter().find(|t| t.name == name).unwrap();
        let v: Vec<f32> = t
            .data
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        out.extend(v.chunks(256).map(|c| c.to_vec()));
    }
    out
}

/// Every value of `orig` channel `c` of `channels` became the codebook entry nearest
/// to it (ties either way).
#[track_caller]
fn assert_nearest(orig: &[f32], got: &[f32], books: &[Vec<f32>], channels: usize, what: &str) {
    for (i, (&o, &g)) in orig.iter().zip(got).enumerate() {
        let book = &books[i % channels];
        assert!(book.contains(&g), "{what}[{i}]: {g} is not in its codebook");
        let best = book
            .iter()
            .map(|&c| (o as f64 - c as f64).abs())
            .fold(f64::INFINITY, f64::min);
        assert!(
            (o as f64 - g as f64).abs() <= best,
            "{what}[{i}]: {o} became {g}, but a codebook entry is {best} away"
        );
    }
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
