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

fn load_round_trip(s: &Scene) -> Scene {
    from_bytes(&to_bytes(s).unwrap()).unwrap()
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

mod corrupt;
mod round_trip;
