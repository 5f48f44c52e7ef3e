//! Adam and the density-grid TV regulariser against f64 CPU references.
//!
//! Stated bounds (f32 GPU vs f64 reference):
//! - Adam, 5 steps: |m − m_ref| ≤ ADAM_TOL · max(m_abs, f32::MIN_POSITIVE) + F, where
//!   m_abs is the same moving average of |g| (m can cancel); |v − v_ref| ≤ ADAM_TOL ·
//!   max(v_ref, f32::MIN_POSITIVE) + F. F = 2t · f32::MIN_POSITIVE after step t: a
//!   device may flush denormal results to 0 (the H200 does: v = 4e-40 read back as 0),
//!   each step losing less than the smallest normal in each moment; |p − p_ref| ≤ ADAM_TOL ·
//!   (|p_ref| + t·lr). Elements with a saturated v (|g| = 1e20 every step) are compared
//!   with the f64 reference, which saturates v at `f32::MAX` too.
//! - TV: |L − L_ref| ≤ TV_VALUE_TOL · L_ref; per grid point |grad − grad_ref| ≤
//!   (n + 4)·2⁻²⁴ · (|grad₀| + |w| · Σ over its n corner slots of 2·Σ_k |Δg|) (n f32
//!   atomic adds in any order); the reference gradient matches central differences
//!   within 1e-9·max(|grad|, 1) + 16·ε₆₄·L/h. The same with SVRaster's L1 form
//!   ([`TvForm::L1`]), whose per-slot scale is Σ_k |±1| = 3.

use crate::common;

use common::{context, finish, Rng};
use svraster::gpu::{recorder, Buffer, Context, Memory};
use svraster::train::backward::Reduction;
use svraster::train::optim::{Adam, AdamConfig, Tv, TvForm};

const ADAM_TOL: f64 = 1e-6;
const TV_VALUE_TOL: f64 = 2e-6;

/// The TV gradient bound of a point receiving `adds` f32 atomic adds: (adds + 4) units
/// of f32 rounding (2⁻²⁴) — recursive summation in any order, plus the rounding of each
/// term — times the point's scale.
fn grad_units(adds: u32) -> f64 {
    f64::from(adds + 4) * f64::from(f32::EPSILON) * 0.5
}

// ---------------------------------------------------------------------------------
// Adam
// ---------------------------------------------------------------------------------

/// f64 Adam state of one element, plus the moving average of |g| as an error scale.
/// The kernel's one deliberate departure is modelled: v saturates at `f32::MAX` (the
/// true v of |g| ≳ 1.8e19 sustained over steps is not representable in f32).
#[derive(Clone, Copy, Default)]
struct RefAdam {
    p: f64,
    m: f64,
    v: f64,
    m_abs: f64,
    saturated: bool,
}

fn ref_adam_step(s: &mut RefAdam, g: f64, t: u32, cfg: &AdamConfig) {
    let (b1, b2) = (f64::from(cfg.beta1), f64::from(cfg.beta2));
    let (lr, eps) = (f64::from(cfg.lr), f64::from(cfg.eps));
    s.m = b1 * s.m + (1.0 - b1) * g;
    s.m_abs = b1 * s.m_abs + (1.0 - b1) * g.abs();
    s.v = b2 * s.v + (1.0 - b2) * g * g;
    if s.v > f64::from(f32::MAX) {
        s.v = f64::from(f32::MAX);
        s.saturated = true;
    }
    let bc1 = 1.0 - b1.powi(t as i32);
    let bc2 = 1.0 - b2.powi(t as i32);
    s.p -= lr * (s.m / bc1) / ((s.v / bc2).sqrt() + eps);
}

/// A gradient: zeros, tiny (±1e-30), huge (±1e20), and magnitudes 10^[-20, 4].
fn random_grad(rng: &mut Rng) -> f32 {
    let sign = if rng.below(2) == 0 { 1.0 } else { -1.0 };
    let u = rng.unit();
    let mag = if u < 0.1 {
        0.0
    } else if u < 0.15 {
        1e-30
    } else if u < 0.16 {
        1e20
    } else {
        10f64.powf(rng.range(-20.0, 4.0))
    };
    (sign * mag) as f32
}

struct AdamBufs {
    p: Buffer,
    g: Buffer,
    m: Buffer,
    v: Buffer,
}

impl AdamBufs {
    fn new(ctx: &Context, p: &[f32], m: &[f32], v: &[f32]) -> AdamBufs {
        AdamBufs {
            p: ctx.buffer_from("test.p", p).unwrap(),
            g: ctx
                .buffer("test.g", p.len() as u64 * 4, Memory::Device)
                .unwrap(),
            m: ctx.buffer_from("test.m", m).unwrap(),
            v: ctx.buffer_from("test.v", v).unwrap(),
        }
    }
    fn step(&self, ctx: &Context, adam: &Adam, grads: &[f32], t: u32, cfg: &AdamConfig) {
        ctx.upload(&self.g, 0, grads).unwrap();
        let n = grads.len() as u32;
        ctx.submit_and_wait(|cmd| {
            adam.record(
                cmd,
                self.p.address(),
                self.g.address(),
                self.m.address(),
                self.v.address(),
                n,
                t,
                cfg,
            );
            Ok(())
        })
        .unwrap();
    }
    fn read(&self, ctx: &Context) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
        (
            ctx.download_all(&self.p).unwrap(),
            ctx.download_all(&self.m).unwrap(),
            ctx.download_all(&self.v).unwrap(),
        )
    }
}

/// Instructions of `spirv` decorated NoContraction (GLSL `precise`): the compiler must
/// evaluate them as written, neither fused nor reassociated.
fn no_contraction_count(spirv: &[u8]) -> usize {
    const OP_DECORATE: u32 = 71;
    const NO_CONTRACTION: u32 = 42;
    let words: Vec<u32> = spirv
        .chunks_exact(4)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    assert_eq!(words[0], 0x0723_0203, "SPIR-V magic");
    let mut i = 5; // header
    let mut n = 0;
    while i < words.len() {
        let (count, op) = ((words[i] >> 16) as usize, words[i] & 0xffff);
        assert!(count > 0, "malformed SPIR-V at word {i}");
        if op == OP_DECORATE && count >= 3 && words[i + 2] == NO_CONTRACTION {
            n += 1;
        }
        i += count;
    }
    n
}

/// Adam's overflow safety at |g| = 1e20 rests on the order ((1−β₂)·g)·g. llvmpipe keeps
/// the order written whatever the SPIR-V says, so the f64 comparison above cannot catch
/// a compiler that reassociates (NVIDIA's did: g·g overflowed, v saturated, the step of
/// a g = ±1e20 element shrank to 0.54·lr, and both Adam tests failed on an H200). What
/// lavapipe can check is that the kernel forbids it: its moment, denominator and
/// parameter updates are `precise` (NoContraction) in both code paths (four elements
/// per invocation, and the scalar tail).
#[test]
fn adam_update_order_is_fixed_in_the_spirv() {
    use svraster::gpu::kernels;
    let n = no_contraction_count(kernels::TRAIN_ADAM.spirv);
    // Per inlined copy of step1: sg (mul), v2 (2 mul, add), m2 (2 mul, add), denom
    // (mul, add; sqrt is an extended instruction), p2 (div, mul, sub): 12; two copies.
    // Without `precise` the count is 0.
    assert!(
        n >= 24,
        "train/adam has {n} NoContraction instructions; its updates must be `precise`"
    );
}

// ---------------------------------------------------------------------------------
// TV
// ---------------------------------------------------------------------------------

/// Voxels × 8 corner indices into a grid of `points` densities.
struct Layout {
    corners: Vec<u32>,
    points: usize,
}

/// A dense n³ grid of voxels over (n+1)³ points plus `extra` unreferenced points, with
/// voxel order and point indices randomly permuted.
fn dense_layout(rng: &mut Rng, n: usize, extra: usize) -> Layout {
    let np = n + 1;
    let points = np * np * np + extra;
    let mut perm: Vec<u32> = (0..points as u32).collect();
    shuffle(rng, &mut perm);
    let mut voxels: Vec<[u32; 8]> = Vec::with_capacity(n * n * n);
    for x in 0..n {
        for y in 0..n {
            for z in 0..n {
                let mut c8 = [0u32; 8];
                for (c, slot) in c8.iter_mut().enumerate() {
                    let (dx, dy, dz) = (c >> 2 & 1, c >> 1 & 1, c & 1);
                    let lin = ((x + dx) * np + (y + dy)) * np + (z + dz);
                    *slot = perm[lin];
                }
                voxels.push(c8);
            }
        }
    }
    shuffle(rng, &mut voxels);
    Layout {
        corners: voxels.into_iter().flatten().collect(),
        points,
    }
}

/// Voxels whose corners are drawn at random from a small pool: heavy sharing and
/// contention on the gradient words (corners may even repeat within a voxel).
fn pool_layout(rng: &mut Rng, voxels: usize, pool: usize) -> Layout {
    Layout {
        corners: (0..voxels * 8)
            .map(|_| rng.below(pool as u64) as u32)
            .collect(),
        points: pool,
    }
}

fn shuffle<T>(rng: &mut Rng, v: &mut [T]) {
    for i in (1..v.len()).rev() {
        let j = rng.below(i as u64 + 1) as usize;
        v.swap(i, j);
    }
}

fn random_geo(rng: &mut Rng, points: usize) -> Vec<f32> {
    (0..points)
        .map(|_| {
            if rng.unit() < 0.05 {
                rng.range(-300.0, 300.0) as f32
            } else {
                rng.range(-5.0, 5.0) as f32
            }
        })
        .collect()
}

/// One edge's penalty in f64.
fn ref_edge(form: TvForm, d: f64) -> f64 {
    match form {
        TvForm::L2 => d * d,
        TvForm::L1 => d.abs(),
    }
}

/// A corner's gradient from its three edges (value `ga`, neighbours `nb`), unweighted,
/// and its scale (the sum of the terms' magnitudes): L2 `2·Σ (ga − nb)`; L1 SVRaster's
/// rule `Σ (ga > nb ? 1 : −1)`, written out as a comparison (equal ends give −1).
fn ref_corner(form: TvForm, ga: f64, nb: [f64; 3]) -> (f64, f64) {
    let (mut d, mut s) = (0.0, 0.0);
    for gb in nb {
        match form {
            TvForm::L2 => {
                d += 2.0 * (ga - gb);
                s += 2.0 * (ga - gb).abs();
            }
            TvForm::L1 => {
                d += if ga > gb { 1.0 } else { -1.0 };
                s += 1.0;
            }
        }
    }
    (d, s)
}

fn corner_neighbours(c8: &[u32], a: usize, geo: &[f64]) -> [f64; 3] {
    [4, 2, 1].map(|k| geo[c8[a ^ k] as usize])
}

/// L_tv in f64.
fn ref_tv_value(form: TvForm, corners: &[u32], geo: &[f64]) -> f64 {
    let mut l = 0.0;
    for c8 in corners.chunks_exact(8) {
        for a in 0..8 {
            for k in [4, 2, 1] {
                if a & k == 0 {
                    l += ref_edge(form, geo[c8[a] as usize] - geo[c8[a | k] as usize]);
                }
            }
        }
    }
    l
}

/// ∂L_tv/∂geo in f64 (for L1 SVRaster's gradient rule), per point the scale of its
/// contributions, and the number of contributions (corner slots naming the point).
fn ref_tv_grad(form: TvForm, corners: &[u32], geo: &[f64]) -> (Vec<f64>, Vec<f64>, Vec<u32>) {
    let mut grad = vec![0.0; geo.len()];
    let mut scale = vec![0.0; geo.len()];
    let mut adds = vec![0u32; geo.len()];
    for c8 in corners.chunks_exact(8) {
        for a in 0..8 {
            let p = c8[a] as usize;
            let (d, s) = ref_corner(form, geo[p], corner_neighbours(c8, a, geo));
            grad[p] += d;
            scale[p] += s;
            adds[p] += 1;
        }
    }
    (grad, scale, adds)
}

struct TvErrors {
    value: f64,
    grad: f64,
}

/// Records the GPU TV of `layout` over the gradient buffer `grad0` (per grid point, or per
/// voxel corner for the ordered variant); returns its value and the buffer after.
fn run_tv(
    ctx: &Context,
    tv: &mut Tv,
    layout: &Layout,
    geo: &[f32],
    grad0: &[f32],
    weight: f32,
) -> (f64, Vec<f32>) {
    let voxels = (layout.corners.len() / 8) as u32;
    let corners_b = ctx.buffer_from("test.corners", &layout.corners).unwrap();
    let geo_b = ctx.buffer_from("test.geo", geo).unwrap();
    let grad_b = ctx.buffer_from("test.grad", grad0).unwrap();
    ctx.submit_and_wait(|cmd| {
        tv.record(
            cmd,
            corners_b.address(),
            geo_b.address(),
            grad_b.address(),
            voxels,
            weight,
        )
    })
    .unwrap();
    (tv.read_value().unwrap(), ctx.download_all(&grad_b).unwrap())
}

/// Runs the GPU TV (weight, initial gradient contents) and compares with the reference.
fn check_tv(
    ctx: &Context,
    tv: &mut Tv,
    layout: &Layout,
    geo: &[f32],
    weight: f32,
    rng: &mut Rng,
) -> TvErrors {
    if tv.reduction() == Reduction::Ordered {
        return check_tv_ordered(ctx, tv, layout, geo, weight, rng);
    }
    let grad0: Vec<f32> = (0..layout.points)
        .map(|i| {
            if i % 3 == 0 {
                0.0
            } else {
                rng.range(-10.0, 10.0) as f32
            }
        })
        .collect();
    let (value, grad) = run_tv(ctx, tv, layout, geo, &grad0, weight);
    // Give-ups first: a lost add shows as a wrong gradient below, this names the cause.
    assert_eq!(
        tv.read_lost().unwrap(),
        0,
        "{:?}: compare-and-swap adds gave up",
        tv.reduction()
    );
    let geo64: Vec<f64> = geo.iter().map(|&g| f64::from(g)).collect();
    let l_ref = ref_tv_value(tv.form(), &layout.corners, &geo64);
    let (g_ref, scale, adds) = ref_tv_grad(tv.form(), &layout.corners, &geo64);
    let e_value = (value - l_ref).abs() / l_ref.max(f64::MIN_POSITIVE);
    assert!(
        e_value <= TV_VALUE_TOL,
        "TV value {value} vs reference {l_ref} (rel {e_value:e})"
    );
    let w = f64::from(weight);
    let mut e_grad = 0.0f64;
    for i in 0..layout.points {
        let expect = f64::from(grad0[i]) + w * g_ref[i];
        if scale[i] == 0.0 || weight == 0.0 {
            assert_eq!(grad[i].to_bits(), grad0[i].to_bits(), "point {i} untouched");
            continue;
        }
        let s = f64::from(grad0[i]).abs() + w.abs() * scale[i];
        let e = (f64::from(grad[i]) - expect).abs() / (grad_units(adds[i]) * s);
        assert!(
            e <= 1.0,
            "{:?} {:?}: point {i} ({} adds): grad {} expected {expect} (start {}, rel {e:e})",
            tv.reduction(),
            tv.form(),
            adds[i],
            grad[i],
            grad0[i]
        );
        e_grad = e_grad.max(e);
    }
    TvErrors {
        value: e_value,
        grad: e_grad,
    }
}

/// The ordered variant: `grad` holds 8 floats per voxel (its corners), each the start
/// value plus weight · ∂L_v/∂geo[corner] of that voxel alone, with plain adds.
fn check_tv_ordered(
    ctx: &Context,
    tv: &mut Tv,
    layout: &Layout,
    geo: &[f32],
    weight: f32,
    rng: &mut Rng,
) -> TvErrors {
    let grad0: Vec<f32> = (0..layout.corners.len())
        .map(|i| {
            if i % 3 == 0 {
                0.0
            } else {
                rng.range(-10.0, 10.0) as f32
            }
        })
        .collect();
    let (value, grad) = run_tv(ctx, tv, layout, geo, &grad0, weight);
    let geo64: Vec<f64> = geo.iter().map(|&g| f64::from(g)).collect();
    let l_ref = ref_tv_value(tv.form(), &layout.corners, &geo64);
    let e_value = (value - l_ref).abs() / l_ref.max(f64::MIN_POSITIVE);
    assert!(
        e_value <= TV_VALUE_TOL,
        "TV value {value} vs reference {l_ref} (rel {e_value:e})"
    );
    let w = f64::from(weight);
    let mut e_grad = 0.0f64;
    for (v, c8) in layout.corners.chunks_exact(8).enumerate() {
        for a in 0..8 {
            let i = 8 * v + a;
            let ga = geo64[c8[a] as usize];
            let (d, s) = ref_corner(tv.form(), ga, corner_neighbours(c8, a, &geo64));
            let expect = f64::from(grad0[i]) + w * d;
            if weight == 0.0 {
                assert_eq!(
                    grad[i].to_bits(),
                    grad0[i].to_bits(),
                    "corner {i} untouched"
                );
                continue;
            }
            let bound = f64::from(grad0[i]).abs() + w.abs() * s;
            let e = (f64::from(grad[i]) - expect).abs() / (grad_units(2) * bound.max(1e-30));
            assert!(
                e <= 1.0,
                "voxel {v} corner {a}: grad {} expected {expect} (rel {e:e})",
                grad[i]
            );
            e_grad = e_grad.max(e);
        }
    }
    TvErrors {
        value: e_value,
        grad: e_grad,
    }
}

fn tv_variants(ctx: &Context) -> Vec<Tv> {
    let mut v = vec![
        Tv::new(ctx, false).unwrap(),
        Tv::with_reduction(ctx, Reduction::Ordered).unwrap(),
    ];
    assert!(!v[0].uses_float_atomics());
    let native = Tv::new(ctx, true).unwrap();
    assert_eq!(native.uses_float_atomics(), ctx.info().float_atomic_add);
    if native.uses_float_atomics() {
        v.push(native);
    } else {
        eprintln!("device lacks float atomic add: only the CAS variant is tested");
    }
    v
}

mod adam_tv;
