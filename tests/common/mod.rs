//! Shared test helpers: a validated context, deterministic random data, and the f64/
//! plain-Rust references the GPU results are checked against.

use svraster::gpu::{Context, ContextOptions};

/// A context on the default device (lavapipe in CI) with the Khronos validation layer.
/// Tests call [`finish`] at the end: any validation message fails the test.
pub fn context() -> Context {
    Context::new(&ContextOptions {
        device: None,
        validation: true,
    })
    .expect("cannot create a Vulkan context with validation (see README: Requirements)")
}

/// Asserts that validation reported nothing.
pub fn finish(ctx: &Context) {
    let n = ctx.validation_messages();
    assert_eq!(
        n,
        0,
        "validation messages:\n{}",
        ctx.validation_log().join("\n")
    );
}

/// SplitMix64: small, seedable, good enough for test data.
pub struct Rng(pub u64);
impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n
    }
}

/// The reference for a stable sort by bits `lo..hi`: Rust's stable `sort_by_key` on
/// the extracted bits, carrying the values.
pub fn reference_sort(keys: &[u64], values: &[u32], lo: u32, hi: u32) -> (Vec<u64>, Vec<u32>) {
    let mask = if hi - lo == 64 {
        u64::MAX
    } else {
        (1u64 << (hi - lo)) - 1
    };
    let mut pairs: Vec<(u64, u32)> = keys.iter().copied().zip(values.iter().copied()).collect();
    pairs.sort_by_key(|&(k, _)| (k >> lo) & mask);
    pairs.into_iter().unzip()
}

/// The reference exclusive scan (wrapping u32) and its total.
pub fn reference_scan(data: &[u32]) -> (Vec<u32>, u32) {
    let mut run = 0u32;
    let out = data
        .iter()
        .map(|&x| {
            let r = run;
            run = run.wrapping_add(x);
            r
        })
        .collect();
    (out, run)
}

pub mod backward;
pub mod forward;
pub mod host;
pub mod reference;
pub mod reference_grad;

use svraster::data::Camera;
use svraster::scene::{octpath_from_ijk, Scene, MAX_LEVEL};

impl Rng {
    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
    /// A random unit vector.
    pub fn dir(&mut self) -> [f64; 3] {
        loop {
            let v = [
                self.range(-1.0, 1.0),
                self.range(-1.0, 1.0),
                self.range(-1.0, 1.0),
            ];
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if n > 0.1 && n <= 1.0 {
                return [v[0] / n, v[1] / n, v[2] / n];
            }
        }
    }
}

/// A random non-overlapping multi-level voxel set: random subdivision from the root
/// (more likely near the top), some leaves dropped, and one chain of subdivisions
/// down to `max_level` so every level is present.
pub fn random_voxels(rng: &mut Rng, max_level: u32) -> (Vec<u64>, Vec<u8>) {
    let mut paths = Vec::new();
    let mut levels = Vec::new();
    let mut stack: Vec<([u32; 3], u32, bool)> = vec![([0, 0, 0], 0, true)];
    while let Some((ijk, level, chain)) = stack.pop() {
        let chain_child = rng.below(8) as u32;
        for c in 0..8u32 {
            let child = [
                ijk[0] * 2 + (c >> 2 & 1),
                ijk[1] * 2 + (c >> 1 & 1),
                ijk[2] * 2 + (c & 1),
            ];
            let l = level + 1;
            let on_chain = chain && c == chain_child && l < max_level;
            let p_split = if l <= 2 { 0.3 } else { 0.04 };
            if on_chain || (l < max_level && rng.unit() < p_split) {
                stack.push((child, l, on_chain));
            } else if rng.unit() < 0.8 {
                paths.push(octpath_from_ijk(child, l));
                levels.push(l as u8);
            }
        }
    }
    (paths, levels)
}

/// Random raw densities: mostly moderate, some very small, some large and huge.
pub fn random_density(rng: &mut Rng) -> f32 {
    let u = rng.unit();
    (if u < 0.55 {
        rng.range(-4.0, 3.0)
    } else if u < 0.75 {
        rng.range(-60.0, -8.0)
    } else if u < 0.95 {
        rng.range(3.0, 60.0)
    } else {
        rng.range(1e3, 1e5)
    }) as f32
}

/// A random scene of `random_voxels` with random densities and SH of `degree`.
pub fn random_scene(rng: &mut Rng, max_level: u32, degree: u32) -> Scene {
    let (paths, levels) = random_voxels(rng, max_level.min(MAX_LEVEL));
    let center = [
        rng.range(-1.0, 1.0) as f32,
        rng.range(-1.0, 1.0) as f32,
        rng.range(-1.0, 1.0) as f32,
    ];
    let extent = rng.range(2.0, 4.0) as f32;
    let mut s = Scene::from_voxels(center, extent, degree, paths, levels, 0.0)
        .expect("random voxels are valid");
    for g in s.geo.iter_mut() {
        *g = random_density(rng);
    }
    random_colours(rng, &mut s);
    s.background = [rng.unit() as f32, rng.unit() as f32, rng.unit() as f32];
    s
}

/// Random SH: DC in [-1.5, 1.5], higher degrees in [-0.6, 0.6].
fn random_colours(rng: &mut Rng, s: &mut Scene) {
    for c in s.sh0.iter_mut() {
        *c = [
            rng.range(-1.5, 1.5) as f32,
            rng.range(-1.5, 1.5) as f32,
            rng.range(-1.5, 1.5) as f32,
        ];
    }
    for v in s.shs.iter_mut() {
        *v = rng.range(-0.6, 0.6) as f32;
    }
}

/// A camera outside the scene cube looking at its centre.
pub fn camera_outside(rng: &mut Rng, scene: &Scene, w: u32, h: u32) -> Camera {
    let c = scene.center.map(|v| v as f64);
    let d = rng.dir();
    let r = scene.extent as f64 * rng.range(1.2, 2.0);
    let eye = [c[0] + r * d[0], c[1] + r * d[1], c[2] + r * d[2]];
    let target = [
        c[0] + rng.range(-0.2, 0.2),
        c[1] + rng.range(-0.2, 0.2),
        c[2] + rng.range(-0.2, 0.2),
    ];
    Camera::look_at(eye, target, rng.dir(), rng.range(0.6, 1.2), w, h)
}

/// A camera inside the scene cube looking in a random direction.
pub fn camera_inside(rng: &mut Rng, scene: &Scene, w: u32, h: u32) -> Camera {
    let c = scene.center.map(|v| v as f64);
    let e = scene.extent as f64;
    let eye = [
        c[0] + rng.range(-0.4, 0.4) * e,
        c[1] + rng.range(-0.4, 0.4) * e,
        c[2] + rng.range(-0.4, 0.4) * e,
    ];
    let d = rng.dir();
    let target = [eye[0] + d[0], eye[1] + d[1], eye[2] + d[2]];
    Camera::look_at(eye, target, rng.dir(), rng.range(0.8, 1.6), w, h)
}

/// Scattered small voxels: `n` distinct random voxels of `level` (≥ 6) in the unit-extent
/// box, moderate densities (no ray reaches the early stop). Seen from outside at a few dozen pixels, each covers a few
/// pixels, so most entries of a tile's list miss most of its pixels.
pub fn scattered_scene(rng: &mut Rng, n: usize, level: u32, degree: u32) -> Scene {
    let side = 1u64 << level;
    let mut seen = std::collections::HashSet::new();
    let mut paths = Vec::new();
    while paths.len() < n {
        let ijk = [
            rng.below(side) as u32,
            rng.below(side) as u32,
            rng.below(side) as u32,
        ];
        if seen.insert(ijk) {
            paths.push(octpath_from_ijk(ijk, level));
        }
    }
    let levels = vec![level as u8; n];
    let mut s = Scene::from_voxels([0.1, -0.2, 0.05], 2.0, degree, paths, levels, 0.0)
        .expect("distinct voxels are valid");
    for g in s.geo.iter_mut() {
        *g = rng.range(-6.0, -1.5) as f32;
    }
    random_colours(rng, &mut s);
    s.background = [0.4, 0.5, 0.6];
    s
}

/// Mean PSNR of `scene` over a split at the model's default render options (the metric
/// every report uses, `svraster::eval::evaluate`).
#[allow(dead_code)]
pub fn mean_psnr(ctx: &Context, scene: &Scene, ds: &svraster::data::Dataset) -> f64 {
    svraster::eval::evaluate(
        ctx,
        scene,
        ds,
        &svraster::raster::RenderOptions::default(),
        svraster::eval::Timing::Skipped,
        |_, _, _, _, _| {},
    )
    .unwrap()
    .psnr
}
