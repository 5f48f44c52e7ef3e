//! Topology change (prune + subdivide, GPU grid-point dedup) against a plain host
//! implementation, and its effect on rendered images.
//!
//! Measured on lavapipe (2 threads), printed by the tests (`--nocapture`):
//! - random multi-level scenes (levels ≤ 3, 6, 10, 16; two rounds each): octpaths,
//!   levels, grid keys, corners, SH and SH moments exact; densities and geo moments
//!   within `DENSITY_TOL` = 1e-6 relative of the f64 reference, measured ≤ 9.7e-8.
//! - subdividing a linear density field (SH 0): max |Δrgb|, |Δalpha| 3.1e-6 (bound 1e-4).
//! - subdividing a smooth random field (SH 3): see `SMOOTH_OUTSIDE`, `SMOOTH_INSIDE`,
//!   `SMOOTH_QUADRATURE`.
//! - pruning voxels that never reach MIN_ALPHA: images bit-identical (Δ = 0).
//! - ~350 k voxels / 2.76 M candidates: invariants and host comparison hold (≤ 9.1e-8),
//!   with 24 and with 51 sort key bits.

use crate::common;

use common::forward::render;

use std::collections::BTreeMap;

use common::reference::trilinear;
use common::{camera_inside, camera_outside, context, finish, random_scene, Rng};
use svraster::adapt::topology::{Moments, Topology};
use svraster::data::Camera;
use svraster::raster::{Image, Renderer};
use svraster::scene::{key_coords, octpath_from_ijk, voxel_corner_keys, Scene, MAX_LEVEL};

/// Density (and geo moment) tolerance relative to the largest |value| a grid point's
/// result is formed from (its candidates and the parent corners they interpolate):
/// f32 interpolation and averaging of ≤ 8 values.
const DENSITY_TOL: f64 = 1e-6;

/// The plain host implementation of a topology change, for clarity: the new voxels in
/// the documented order, every (voxel, corner) candidate with its parent-interpolated
/// values in f64, grouped by grid key in a BTreeMap (ascending keys) and averaged.
struct Expected {
    octpath: Vec<u64>,
    octlevel: Vec<u8>,
    sh0: Vec<[f32; 3]>,
    shs: Vec<f32>,
    /// sh0 m, sh0 v, shs m, shs v.
    sh_moments: Option<[Vec<f32>; 4]>,
    grid_keys: Vec<u64>,
    /// Per grid point: mean of its (geo, geo m, geo v) candidates, and the largest
    /// |value| they are formed from (the candidates and the parent corners their
    /// interpolation weighs), the scale of the f32 rounding.
    values: Vec<[f64; 3]>,
    scale: Vec<[f64; 3]>,
}

fn expected(scene: &Scene, moments: Option<&Moments>, keep: &[bool], split: &[bool]) -> Expected {
    let nc = scene.shs_per_voxel() * 3;
    let mut e = Expected {
        octpath: vec![],
        octlevel: vec![],
        sh0: vec![],
        shs: vec![],
        sh_moments: moments.map(|_| Default::default()),
        grid_keys: vec![],
        values: vec![],
        scale: vec![],
    };
    let mut candidates: BTreeMap<u64, Vec<[(f64, f64); 3]>> = BTreeMap::new();
    for i in 0..scene.num_voxels() {
        if !keep[i] {
            continue;
        }
        // The parent's corner values per plane: geo, geo m, geo v.
        let corner_vals = |plane: usize| -> [f64; 8] {
            std::array::from_fn(|c| {
                let gp = scene.corners[i][c] as usize;
                match (plane, moments) {
                    (0, _) => scene.geo[gp] as f64,
                    (p, Some(m)) => m[p - 1][gp] as f64,
                    (_, None) => 0.0,
                }
            })
        };
        let parent_vals = [corner_vals(0), corner_vals(1), corner_vals(2)];
        let level = scene.octlevel[i] as u32;
        let children: Vec<(u64, u32, Option<u32>)> = if split[i] {
            (0..8u32)
                .map(|c| {
                    let shift = 3 * (MAX_LEVEL - level - 1);
                    (scene.octpath[i] | (c as u64) << shift, level + 1, Some(c))
                })
                .collect()
        } else {
            vec![(scene.octpath[i], level, None)]
        };
        for (path, lvl, child) in children {
            e.octpath.push(path);
            e.octlevel.push(lvl as u8);
            e.sh0.push(scene.sh0[i]);
            e.shs.extend_from_slice(&scene.shs[i * nc..(i + 1) * nc]);
            if let (Some(m), Some(dst)) = (moments, e.sh_moments.as_mut()) {
                for (k, d) in dst.iter_mut().enumerate() {
                    let w = if k < 2 { 3 } else { nc };
                    d.extend_from_slice(&m[2 + k][i * w..(i + 1) * w]);
                }
            }
            let keys = voxel_corner_keys(path, lvl);
            for (k, &key) in keys.iter().enumerate() {
                // (value, |largest value it is formed from|) per plane.
                let v: [(f64, f64); 3] = std::array::from_fn(|p| match child {
                    None => (parent_vals[p][k], parent_vals[p][k].abs()),
                    Some(c) => {
                        // Corner k of child c in the parent's local coordinates.
                        let q = [
                            ((c >> 2 & 1) + (k as u32 >> 2 & 1)) as f64 * 0.5,
                            ((c >> 1 & 1) + (k as u32 >> 1 & 1)) as f64 * 0.5,
                            ((c & 1) + (k as u32 & 1)) as f64 * 0.5,
                        ];
                        let mut scale: f64 = 0.0;
                        for (j, g) in parent_vals[p].iter().enumerate() {
                            let w: f64 = (0..3)
                                .map(|a| {
                                    if j >> (2 - a) & 1 == 1 {
                                        q[a]
                                    } else {
                                        1.0 - q[a]
                                    }
                                })
                                .product();
                            if w != 0.0 {
                                scale = scale.max(g.abs());
                            }
                        }
                        (trilinear(&parent_vals[p], q), scale)
                    }
                });
                candidates.entry(key).or_default().push(v);
            }
        }
    }
    for (key, vals) in candidates {
        assert!(
            vals.len() <= 8,
            "reference: {} candidates at one point",
            vals.len()
        );
        e.grid_keys.push(key);
        e.values.push(std::array::from_fn(|p| {
            vals.iter().map(|v| v[p].0).sum::<f64>() / vals.len() as f64
        }));
        e.scale.push(std::array::from_fn(|p| {
            vals.iter().map(|v| v[p].1).fold(1e-30, f64::max)
        }));
    }
    e
}

/// Checks a GPU result against the host implementation; returns the largest relative
/// density / geo-moment error.
fn check_against_host(
    scene: &Scene,
    moments: Option<&Moments>,
    keep: &[bool],
    split: &[bool],
    out: &Scene,
    out_m: Option<&Moments>,
    what: &str,
) -> f64 {
    out.validate()
        .unwrap_or_else(|e| panic!("{what}: result does not validate: {e}"));
    let e = expected(scene, moments, keep, split);
    assert_eq!(out.octpath, e.octpath, "{what}: octpaths / voxel order");
    assert_eq!(out.octlevel, e.octlevel, "{what}: levels");
    assert_eq!(out.sh0, e.sh0, "{what}: sh0 copied");
    assert_eq!(out.shs, e.shs, "{what}: shs copied");
    assert_eq!(out.grid_keys, e.grid_keys, "{what}: grid keys");
    // Keys unique and ascending, every corner resolves, no unused point (validate
    // checks these too; stated here for the reader).
    assert!(
        out.grid_keys.windows(2).all(|w| w[0] < w[1]),
        "{what}: keys"
    );
    let mut used = vec![false; out.grid_keys.len()];
    for (v, corners) in out.corners.iter().enumerate() {
        let keys = voxel_corner_keys(out.octpath[v], out.octlevel[v] as u32);
        for c in 0..8 {
            let g = corners[c] as usize;
            assert_eq!(out.grid_keys[g], keys[c], "{what}: voxel {v} corner {c}");
            used[g] = true;
        }
    }
    assert!(used.iter().all(|&u| u), "{what}: unused grid point");
    let mut worst: f64 = 0.0;
    let planes = if moments.is_some() { 3 } else { 1 };
    for p in 0..planes {
        let got: &[f32] = match (p, out_m) {
            (0, _) => &out.geo,
            (p, Some(m)) => &m[p - 1],
            _ => panic!("{what}: moments missing from the result"),
        };
        assert_eq!(got.len(), e.values.len(), "{what}: plane {p} length");
        for (g, (&v, (want, scale))) in got.iter().zip(e.values.iter().zip(&e.scale)).enumerate() {
            let rel = (v as f64 - want[p]).abs() / scale[p];
            worst = worst.max(rel);
            assert!(
                rel <= DENSITY_TOL,
                "{what}: plane {p} grid point {g} (key {:#x}, coords {:?}): {v} vs {} (rel {rel:e})",
                e.grid_keys[g],
                key_coords(e.grid_keys[g]),
                want[p]
            );
        }
    }
    match (out_m, &e.sh_moments) {
        (Some(m), Some(sm)) => {
            assert_eq!(m.len(), 6, "{what}: six moment arrays");
            for k in 0..4 {
                assert_eq!(m[2 + k], sm[k], "{what}: SH moment {k} carried");
            }
        }
        (None, None) => {}
        _ => panic!("{what}: moments given / returned mismatch"),
    }
    worst
}

fn random_moments(rng: &mut Rng, scene: &Scene) -> Moments {
    let g = scene.num_grid_points();
    let n = scene.num_voxels();
    let nc = scene.shs_per_voxel() * 3;
    let mut signed =
        |len: usize, s: f64| -> Vec<f32> { (0..len).map(|_| rng.range(-s, s) as f32).collect() };
    let geo_m = signed(g, 0.5);
    let geo_v: Vec<f32> = signed(g, 1.0).iter().map(|v| v * v * 1e-3).collect();
    let sh0_m = signed(3 * n, 0.1);
    let sh0_v: Vec<f32> = signed(3 * n, 1.0).iter().map(|v| v * v).collect();
    let shs_m = signed(n * nc, 0.1);
    let shs_v: Vec<f32> = signed(n * nc, 1.0).iter().map(|v| v * v).collect();
    vec![geo_m, geo_v, sh0_m, sh0_v, shs_m, shs_v]
}

fn random_masks(
    rng: &mut Rng,
    scene: &Scene,
    p_prune: f64,
    p_split: f64,
) -> (Vec<bool>, Vec<bool>) {
    let n = scene.num_voxels();
    let keep: Vec<bool> = (0..n).map(|_| rng.unit() >= p_prune).collect();
    let split: Vec<bool> = (0..n)
        .map(|i| (scene.octlevel[i] as u32) < MAX_LEVEL && rng.unit() < p_split)
        .collect();
    (keep, split)
}

// ---- rendering ----------------------------------------------------------------------

/// (max, mean) abs difference of rgb and alpha.
fn image_diff(a: &Image, b: &Image) -> (f64, f64) {
    let mut max: f64 = 0.0;
    let mut sum = 0.0;
    let mut cnt = 0usize;
    for i in 0..a.rgb.len() {
        for c in 0..4 {
            let (x, y) = if c < 3 {
                (a.rgb[i][c], b.rgb[i][c])
            } else {
                (a.alpha[i], b.alpha[i])
            };
            let d = (x as f64 - y as f64).abs();
            max = max.max(d);
            sum += d;
            cnt += 1;
        }
    }
    (max, sum / cnt as f64)
}

/// A single-level scene: every voxel of `level` within a tiny cube (edge `extent`, so
/// that a voxel is semi-transparent at densities ≥ 1.1: alpha ≈ 1 − exp(−100·len·ρ)),
/// with a fraction dropped at random.
fn single_level_scene(rng: &mut Rng, level: u32, extent: f32, drop: f64, degree: u32) -> Scene {
    let side = 1u32 << level;
    let mut paths = vec![];
    for i in 0..side {
        for j in 0..side {
            for k in 0..side {
                if rng.unit() >= drop {
                    paths.push(octpath_from_ijk([i, j, k], level));
                }
            }
        }
    }
    let n = paths.len();
    let mut s = Scene::from_voxels(
        [0.1, -0.2, 0.05],
        extent,
        degree,
        paths,
        vec![level as u8; n],
        0.0,
    )
    .unwrap();
    for c in s.sh0.iter_mut() {
        *c = std::array::from_fn(|_| rng.range(-1.5, 1.5) as f32);
    }
    for v in s.shs.iter_mut() {
        *v = rng.range(-0.6, 0.6) as f32;
    }
    s.background = [0.2, 0.5, 0.9];
    s
}

/// Grid-point position relative to the scene cube, each axis in [−0.5, 0.5].
fn unit_pos(key: u64) -> [f64; 3] {
    let c = key_coords(key);
    std::array::from_fn(|a| c[a] as f64 / (1u64 << 16) as f64 - 0.5)
}

/// A camera outside a (tiny) scene cube looking at its centre: `camera_outside` aims
/// within ±0.2 world units, which misses a cube this small.
fn camera_facing(rng: &mut Rng, scene: &Scene, w: u32, h: u32) -> Camera {
    let c = scene.center.map(|v| v as f64);
    let e = scene.extent as f64;
    let d = rng.dir();
    let r = e * rng.range(1.3, 2.0);
    let eye = std::array::from_fn(|a| c[a] + r * d[a]);
    let target = std::array::from_fn(|a| c[a] + e * rng.range(-0.05, 0.05));
    Camera::look_at(eye, target, rng.dir(), rng.range(0.8, 1.2), w, h)
}

/// Three cameras outside the cube and one inside.
fn cameras(rng: &mut Rng, scene: &Scene) -> Vec<Camera> {
    let mut cams = vec![
        camera_facing(rng, scene, 64, 48),
        camera_facing(rng, scene, 48, 64),
        camera_facing(rng, scene, 57, 41),
        camera_inside(rng, scene, 50, 40),
    ];
    for c in cams.iter_mut() {
        // The default near plane (0.02) is larger than these tiny scenes.
        c.near = 1e-5;
    }
    cams
}

fn split_all(topo: &mut Topology, s: &Scene) -> Scene {
    let n = s.num_voxels();
    let (out, _) = topo.apply(s, None, &vec![true; n], &vec![true; n]).unwrap();
    out.validate().unwrap();
    assert_eq!(out.num_voxels(), 8 * n);
    out
}

/// Subdividing every voxel of a single-level scene whose raw density is a linear
/// function of position with values > 1.1 everywhere (explin is the identity there)
/// and SH degree 0 leaves the image unchanged.
///
/// Why exact in theory: trilinear interpolation reproduces a linear field, so parent
/// and children hold the same density ρ(x), linear along every ray. A voxel's optical
/// depth with K = 1 is 100·len·ρ(midpoint) = 100·∫ρ over its segment (the midpoint rule
/// is exact for linear integrands), so the children's depths along a ray sum to the
/// parent's and T·(1 − e^(−ΣVᵢ)) = Σ T·e^(−V₁…)·(1 − e^(−Vᵢ)): with the same colour
/// (SH 0 does not depend on the direction, and children copy it) the composited colour
/// and alpha are the same. Only the clamps break this (MAX_ALPHA, early stop, skipping
/// below MIN_ALPHA); the densities here keep alpha far from them except for segments
/// shorter than ~5e-8 (MIN_ALPHA), whose effect is ≤ 1e-5.
#[test]
fn subdividing_a_linear_field_leaves_the_image_unchanged() {
    let ctx = context();
    let mut topo = Topology::new(&ctx).unwrap();
    let mut r = Renderer::new(&ctx).unwrap();
    let mut worst: f64 = 0.0;
    for seed in 0..3u64 {
        let mut rng = Rng(31 + seed);
        let mut s = single_level_scene(&mut rng, 3, 0.016, 0.3, 0);
        let dir = rng.dir();
        for (g, &key) in s.geo.iter_mut().zip(&s.grid_keys) {
            let p = unit_pos(key);
            *g = (2.0 + 0.6 * (p[0] * dir[0] + p[1] * dir[1] + p[2] * dir[2])) as f32;
        }
        assert!(s.geo.iter().all(|&g| g > 1.2));
        let fine = split_all(&mut topo, &s);
        for (ci, cam) in cameras(&mut rng, &s).iter().enumerate() {
            let a = render(&mut r, &ctx, &s, cam, 1);
            let b = render(&mut r, &ctx, &fine, cam, 1);
            let seen = a.alpha.iter().filter(|&&x| x > 0.05).count();
            assert!(
                seen > 100,
                "seed {seed} camera {ci}: the view shows too little ({seen})"
            );
            let (max, mean) = image_diff(&a, &b);
            println!("linear field seed {seed} camera {ci}: max |Δ| {max:.3e}, mean {mean:.3e}");
            worst = worst.max(max);
        }
    }
    println!("linear field, SH 0: largest |Δrgb|, |Δalpha| = {worst:.3e}");
    assert!(worst <= 1e-4, "subdivision changed the image by {worst}");
    finish(&ctx);
}

/// Stated bounds for subdividing a smooth random field with SH degree 3, as
/// (mean |Δ|, max |Δ|) over rgb and alpha: cameras outside the cube, and a camera
/// inside it (voxels close to the eye: the direction to a child's centre differs most
/// from the direction to its parent's). Measured (3 seeds): outside ≤ (3.6e-3, 4.6e-2),
/// inside ≤ (2.9e-2, 0.13). The quadrature part alone (higher SH zeroed, colour
/// direction-independent) measured ≤ (9.1e-4, 6.2e-3) for all cameras.
const SMOOTH_OUTSIDE: (f64, f64) = (6e-3, 0.08);
const SMOOTH_INSIDE: (f64, f64) = (0.05, 0.2);
const SMOOTH_QUADRATURE: (f64, f64) = (2e-3, 0.012);

/// ~350k voxels after the change (level-6 uniform grid, 262 144 voxels, 5 % split,
/// 2 % pruned, moments carried): many workgroups in every kernel, sort and scan tiles.
/// `deep`: voxel (0,0,0) of the grid is replaced by a chain of subdivisions down to
/// level 16, so the finest level is 16 and the sort takes all 51 key bits (7 passes)
/// instead of 24 (3 passes).
fn large_case(deep: bool) {
    let what = if deep { "large deep" } else { "large" };
    let ctx = context();
    let mut topo = Topology::new(&ctx).unwrap();
    let mut rng = Rng(2024);
    let level = 6;
    let side = 1u32 << level;
    let mut paths: Vec<u64> = (0..side * side * side)
        .map(|k| octpath_from_ijk([k / (side * side), (k / side) % side, k % side], level))
        .collect();
    let mut levels = vec![level as u8; paths.len()];
    if deep {
        // Cube (0,0,0) of level 6 → at each finer level, the 7 children off the chain
        // (child 0 continues), and all 8 children at level 16.
        paths.remove(0);
        levels.remove(0);
        for l in level + 1..=MAX_LEVEL {
            for c in 0..8u32 {
                if c != 0 || l == MAX_LEVEL {
                    paths.push(octpath_from_ijk([c >> 2 & 1, c >> 1 & 1, c & 1], l));
                    levels.push(l as u8);
                }
            }
        }
    }
    let n = paths.len();
    let mut s = Scene::from_voxels([0.0; 3], 3.0, 1, paths, levels, 0.0).unwrap();
    for g in s.geo.iter_mut() {
        *g = rng.range(-10.0, 10.0) as f32;
    }
    for c in s.sh0.iter_mut() {
        *c = std::array::from_fn(|_| rng.range(-1.0, 1.0) as f32);
    }
    for v in s.shs.iter_mut() {
        *v = rng.range(-0.5, 0.5) as f32;
    }
    let moments = random_moments(&mut rng, &s);
    let (keep, split) = random_masks(&mut rng, &s, 0.02, 0.05);
    let mut times = vec![];
    let mut result = None;
    for _ in 0..3 {
        let t = std::time::Instant::now();
        let r = topo.apply(&s, Some(&moments), &keep, &split).unwrap();
        times.push(t.elapsed().as_secs_f64() * 1e3);
        println!("{what}: {:?}", topo.last_stats());
        result = Some(r);
    }
    let (out, out_m) = result.unwrap();
    assert_eq!(topo.last_stats().sort_bits, if deep { 51 } else { 24 });
    println!(
        "{what}: {n} → {} voxels, {} → {} grid points, {} key bits; apply {:.1} ms cold, \
         {:.1} / {:.1} ms warm",
        out.num_voxels(),
        s.num_grid_points(),
        out.num_grid_points(),
        topo.last_stats().sort_bits,
        times[0],
        times[1],
        times[2]
    );
    assert!(out.num_voxels() > 300_000);
    let t = std::time::Instant::now();
    out.validate().unwrap();
    println!(
        "{what}: Scene::validate on the result takes {:.1} ms",
        t.elapsed().as_secs_f64() * 1e3
    );
    let rel = check_against_host(
        &s,
        Some(&moments),
        &keep,
        &split,
        &out,
        out_m.as_ref(),
        what,
    );
    println!("{what}: max rel density error {rel:.3e}");
    finish(&ctx);
}

mod changes;
