//! SSIM: the f64 CPU reference against finite differences, closed forms and an
//! independent (numpy/scipy) value; the GPU value and gradient against the reference.

use crate::common;

use common::Rng;
use svraster::eval::ssim::{
    gaussian_window, ssim as ssim_cpu, ssim_grad as ssim_grad_cpu, ssim_grad_margin, ssim_margin,
    C1, C2,
};
use svraster::gpu::{Buffer, Context, Memory};
use svraster::train::ssim::Ssim;

fn random_image(rng: &mut Rng, n: usize) -> Vec<[f32; 3]> {
    (0..n)
        .map(|_| [rng.unit() as f32, rng.unit() as f32, rng.unit() as f32])
        .collect()
}

/// `y` = `x` plus noise, clamped to [0, 1]: a pair with a mid-range SSIM.
fn noisy_copy(rng: &mut Rng, x: &[[f32; 3]], amp: f64) -> Vec<[f32; 3]> {
    x.iter()
        .map(|p| p.map(|v| (v as f64 + amp * rng.range(-1.0, 1.0)).clamp(0.0, 1.0) as f32))
        .collect()
}

fn planar(img: &[[f32; 3]]) -> Vec<f32> {
    (0..3).flat_map(|c| img.iter().map(move |p| p[c])).collect()
}

fn max_abs(v: &[[f64; 3]]) -> f64 {
    v.iter().flatten().fold(0.0f64, |m, &g| m.max(g.abs()))
}

// ---------------------------------------------------------------------------------
// CPU reference

/// Central differences of `ssim_cpu` in f64 against `ssim_grad_cpu`, every coordinate.
/// Step 2^-14 on inputs quantised so that the f32 step is exact.
#[test]
fn cpu_gradient_matches_finite_differences() {
    let mut rng = Rng(0x5513_0001);
    let mut worst = 0.0f64;
    // Margin 5 is "valid" SSIM (12×12 and 13×17 have window centres inside; the smaller
    // ones fall back to every pixel).
    for (&(w, h), margin) in [(1, 1), (3, 2), (2, 3), (5, 4), (1, 9), (13, 17), (12, 12)]
        .iter()
        .flat_map(|s| [(s, 0), (s, 5)])
    {
        let n = w * h;
        for trial in 0..2 {
            // Multiples of 2^-20, so x ± 2^-14 is exact in f32 (a symmetric step).
            let quantise = |img: Vec<[f32; 3]>| -> Vec<[f32; 3]> {
                img.into_iter()
                    .map(|p| p.map(|v| (v * 1048576.0).round() / 1048576.0))
                    .collect()
            };
            let x = quantise(random_image(&mut rng, n));
            let y = if trial == 0 {
                random_image(&mut rng, n)
            } else {
                noisy_copy(&mut rng, &x, 0.1)
            };
            let grad = ssim_grad_margin(&x, &y, w, h, margin);
            let scale = max_abs(&grad);
            assert!(scale > 0.0);
            let mut err = 0.0f64;
            for p in 0..n {
                for c in 0..3 {
                    let step = 1.0 / 16384.0;
                    let mut xp = x.clone();
                    let mut xm = x.clone();
                    xp[p][c] += step;
                    xm[p][c] -= step;
                    let denom = xp[p][c] as f64 - xm[p][c] as f64;
                    assert_eq!(denom, 2.0 * step as f64);
                    let fd = (ssim_margin(&xp, &y, w, h, margin)
                        - ssim_margin(&xm, &y, w, h, margin))
                        / denom;
                    err = err.max((fd - grad[p][c]).abs());
                }
            }
            let rel = err / scale;
            worst = worst.max(rel);
            assert!(
                rel <= 5e-6,
                "{w}×{h} margin {margin} trial {trial}: |fd − grad| = {err:e} vs max |grad| {scale:e}"
            );
        }
    }
    eprintln!("finite differences: worst max-abs error / max |grad| = {worst:.3e}");
}

/// Constant images `x ≡ a`, `y ≡ b`: with zero padding the statistics are closed forms
/// of the in-bounds window mass `s(p) = sh(col)·sv(row)`: μx = a s, σx² = a² s(1 − s),
/// σxy = ab s(1 − s).
#[test]
fn cpu_constant_images_match_closed_form() {
    let g = gaussian_window();
    let mass = |i: usize, len: usize| -> f64 {
        (0..11)
            .filter(|&t| {
                let j = i as isize + t as isize - 5;
                j >= 0 && j < len as isize
            })
            .map(|t| g[t])
            .sum()
    };
    for &(w, h) in &[(1, 1), (4, 3), (11, 11), (30, 20), (7, 40)] {
        for &(a, b) in &[
            (0.5f32, 0.5f32),
            (0.25, 0.75),
            (0.0, 0.6),
            (1.0, 0.1),
            (0.0, 0.0),
        ] {
            let mut expect = 0.0;
            for r in 0..h {
                for c in 0..w {
                    let s = mass(c, w) * mass(r, h);
                    let (a, b) = (a as f64, b as f64);
                    let v = s * (1.0 - s);
                    expect += (2.0 * a * b * s * s + C1) * (2.0 * a * b * v + C2)
                        / (((a * a + b * b) * s * s + C1) * ((a * a + b * b) * v + C2));
                }
            }
            expect /= (w * h) as f64;
            let got = ssim_cpu(&vec![[a; 3]; w * h], &vec![[b; 3]; w * h], w, h);
            assert!(
                (got - expect).abs() <= 1e-12,
                "{w}×{h} a={a} b={b}: {got} vs closed form {expect}"
            );
        }
    }
}

/// Identical images: S ≡ 1 and the gradient vanishes (SSIM is maximal).
#[test]
fn cpu_identical_images() {
    let mut rng = Rng(0x5513_0002);
    for &(w, h) in &[(1, 1), (6, 5), (40, 31)] {
        let x = random_image(&mut rng, w * h);
        let v = ssim_cpu(&x, &x, w, h);
        assert!((v - 1.0).abs() <= 1e-14, "{w}×{h}: {v}");
        let g = ssim_grad_cpu(&x, &x, w, h);
        let m = max_abs(&g);
        assert!(m <= 1e-12, "{w}×{h}: max |grad| {m:e} at identical images");
    }
}

/// A deterministic pair (exact multiples of 1/256) whose SSIM was computed independently
/// with numpy 2.4.6 / scipy 1.17.1:
/// ```python
/// import numpy as np
/// from scipy.signal import correlate2d
/// W, H = 23, 17
/// r = np.arange(H)[:, None]; q = np.arange(W)[None, :]
/// def img(c, kind):
///     if kind == 0:
///         v = (r * 5 + q * 3 + c * 40) % 256
///     else:
///         v = np.clip((r * 5 + q * 3 + c * 40) % 256 + ((r * q + 7 * c) % 23) - 11, 0, 255)
///     return (v / 256.0).astype(np.float64)
/// g = np.exp(-((np.arange(11) - 5.0) ** 2) / (2 * 1.5 ** 2)); g /= g.sum()
/// w2 = np.outer(g, g)
/// blur = lambda a: correlate2d(a, w2, mode="same", boundary="fill", fillvalue=0.0)
/// C1, C2 = 0.01 ** 2, 0.03 ** 2
/// tot = 0.0
/// for c in range(3):
///     x, y = img(c, 0), img(c, 1)
///     mx, my = blur(x), blur(y)
///     sxx = blur(x * x) - mx * mx; syy = blur(y * y) - my * my; sxy = blur(x * y) - mx * my
///     S = ((2 * mx * my + C1) * (2 * sxy + C2)) / ((mx ** 2 + my ** 2 + C1) * (sxx + syy + C2))
///     tot += S.sum()
/// print(repr(tot / (3 * W * H)))   # 0.9177043552331456
/// ```
fn scipy_pair() -> (Vec<[f32; 3]>, Vec<[f32; 3]>, usize, usize) {
    let (w, h) = (23usize, 17usize);
    let mut x = vec![[0.0f32; 3]; w * h];
    let mut y = vec![[0.0f32; 3]; w * h];
    for r in 0..h {
        for q in 0..w {
            for c in 0..3 {
                let base = ((r * 5 + q * 3 + c * 40) % 256) as i64;
                let other = (base + ((r * q + 7 * c) % 23) as i64 - 11).clamp(0, 255);
                x[r * w + q][c] = base as f32 / 256.0;
                y[r * w + q][c] = other as f32 / 256.0;
            }
        }
    }
    (x, y, w, h)
}
const SCIPY_SSIM: f64 = 0.917_704_355_233_145_6;

/// The pair's "valid" SSIM (window centres 5 pixels from every border), from the torch
/// `fused_ssim` of ../shared/gpu/svr/stubs (F.conv2d, zero padding, then the 5-pixel
/// crop SVRaster's `padding="valid"` asks for), in float64:
/// `fused_ssim(x[None], y[None], padding="valid", train=False)` = 0.8321439993519721
/// (its "same" value, 0.9177043552331444, is scipy's above).
const TORCH_VALID_SSIM: f64 = 0.832_143_999_351_972_1;

#[test]
fn cpu_matches_independent_scipy_value() {
    let (x, y, w, h) = scipy_pair();
    let v = ssim_cpu(&x, &y, w, h);
    assert!((v - SCIPY_SSIM).abs() <= 1e-13, "{v} vs scipy {SCIPY_SSIM}");
    let v = ssim_margin(&x, &y, w, h, 5);
    assert!(
        (v - TORCH_VALID_SSIM).abs() <= 1e-13,
        "{v} vs torch {TORCH_VALID_SSIM}"
    );
}

// ---------------------------------------------------------------------------------
// GPU

struct Run {
    value: f64,
    /// grad after − grad before, interleaved.
    delta: Vec<[f64; 3]>,
}

/// Uploads x, y and an initial gradient `g0`, records `weights.len()` SSIM calls into
/// one command buffer, and returns the value of the last and the change of `grad`.
#[allow(clippy::too_many_arguments)]
fn gpu_run(
    ctx: &Context,
    ssim: &mut Ssim,
    x: &[[f32; 3]],
    y: &[[f32; 3]],
    g0: &[f32],
    weights: &[f32],
    w: usize,
    h: usize,
) -> Run {
    let (w32, h32) = (w as u32, h as u32);
    ssim.prepare(w32, h32).unwrap();
    let xb = ctx.buffer_from("x", &planar(x)).unwrap();
    let yb = ctx.buffer_from("y", &planar(y)).unwrap();
    let gb: Buffer = ctx.buffer_from("grad", g0).unwrap();
    ctx.submit_and_wait(|cmd| {
        for &wt in weights {
            ssim.record(cmd, xb.address(), yb.address(), gb.address(), wt, w32, h32)?;
        }
        Ok(())
    })
    .unwrap();
    let value = ssim.read_value().unwrap();
    let g1: Vec<f32> = ctx.download(&gb, 0, 3 * w * h).unwrap();
    let n = w * h;
    let delta = (0..n)
        .map(|p| std::array::from_fn(|c| g1[c * n + p] as f64 - g0[c * n + p] as f64))
        .collect();
    Run { value, delta }
}

/// Max over coordinates of |got − want|, divided by max |want|.
fn rel_err(got: &[[f64; 3]], want: &[[f64; 3]]) -> f64 {
    let scale = max_abs(want);
    let err = got
        .iter()
        .flatten()
        .zip(want.iter().flatten())
        .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    err / scale
}

/// Value |Δ| ≤ 5e-7 and gradient max-abs error ≤ 2e-5 · max |grad| against the f64
/// reference (measured worst on lavapipe: 9.5e-8 and 1.7e-6), for random and correlated pairs, with
/// a non-unit weight and non-zero initial gradient (the result must be added).
#[test]
fn gpu_matches_cpu_reference() {
    let ctx = common::context();
    let mut ssim = Ssim::new(&ctx).unwrap();
    let mut rng = Rng(0x5513_0003);
    let (mut worst_v, mut worst_g) = (0.0f64, 0.0f64);
    // 200×150 first, so the smaller sizes run in larger scratch.
    let sizes = [
        (200, 150),
        (1, 1),
        (5, 7),
        (16, 16),
        (37, 23),
        (11, 1),
        (1, 300),
        (3, 2),
        (257, 3),
    ];
    for (i, (&(w, h), valid)) in sizes
        .iter()
        .flat_map(|s| [(s, false), (s, true)])
        .enumerate()
    {
        // "valid" SSIM: the window centres 5 pixels from every border only.
        ssim.set_valid(valid);
        let margin = if valid { 5 } else { 0 };
        for trial in 0..2 {
            let n = w * h;
            let x = random_image(&mut rng, n);
            let y = if trial == 0 {
                random_image(&mut rng, n)
            } else {
                noisy_copy(&mut rng, &x, 0.15)
            };
            let want_v = ssim_margin(&x, &y, w, h, margin);
            let want_g = ssim_grad_margin(&x, &y, w, h, margin);
            let weight = if i % 2 == 0 { -0.8f32 } else { 2.5f32 };
            let gscale = max_abs(&want_g) * weight.abs() as f64;
            let g0: Vec<f32> = (0..3 * n)
                .map(|_| (gscale * rng.range(-1.0, 1.0)) as f32)
                .collect();
            let run = gpu_run(&ctx, &mut ssim, &x, &y, &g0, &[weight], w, h);
            let scaled: Vec<[f64; 3]> = want_g
                .iter()
                .map(|g| g.map(|v| v * weight as f64))
                .collect();
            let dv = (run.value - want_v).abs();
            let dg = rel_err(&run.delta, &scaled);
            eprintln!(
                "{w}×{h} valid {valid} trial {trial}: ssim {want_v:.6} |Δvalue| {dv:.2e} \
                 grad rel {dg:.2e}"
            );
            worst_v = worst_v.max(dv);
            worst_g = worst_g.max(dg);
            assert!(dv <= 5e-7, "{w}×{h}: value {} vs {want_v}", run.value);
            assert!(dg <= 2e-5, "{w}×{h}: gradient relative error {dg:e}");
        }
    }
    eprintln!("GPU vs CPU: worst |Δvalue| = {worst_v:.3e}, worst grad rel = {worst_g:.3e}");
    drop(ssim);
    common::finish(&ctx);
}

/// Two calls in one command buffer accumulate (weights 1 and 2 → 3 × grad); the value is
/// the last call's. Also the scipy pair's value on the GPU.
#[test]
fn gpu_accumulates_and_matches_scipy_pair() {
    let ctx = common::context();
    let mut ssim = Ssim::new(&ctx).unwrap();
    let (x, y, w, h) = scipy_pair();
    let g0 = vec![0.0f32; 3 * w * h];
    let run = gpu_run(&ctx, &mut ssim, &x, &y, &g0, &[1.0, 2.0], w, h);
    assert!(
        (run.value - SCIPY_SSIM).abs() <= 5e-7,
        "{} vs {SCIPY_SSIM}",
        run.value
    );
    let want: Vec<[f64; 3]> = ssim_grad_cpu(&x, &y, w, h)
        .iter()
        .map(|g| g.map(|v| 3.0 * v))
        .collect();
    let e = rel_err(&run.delta, &want);
    assert!(e <= 2e-5, "accumulated gradient relative error {e:e}");
    drop(ssim);
    common::finish(&ctx);
}

/// Identical images: value 1 and a vanishing gradient on the GPU too (relative to the
/// gradient scale of a nearby pair; measured ≤ 5e-9 and 1.5e-6).
#[test]
fn gpu_identical_images() {
    let ctx = common::context();
    let mut ssim = Ssim::new(&ctx).unwrap();
    let mut rng = Rng(0x5513_0004);
    for &(w, h) in &[(1, 1), (19, 14), (64, 48)] {
        let x = random_image(&mut rng, w * h);
        let y = noisy_copy(&mut rng, &x, 0.1);
        let scale = max_abs(&ssim_grad_cpu(&x, &y, w, h));
        let g0 = vec![0.0f32; 3 * w * h];
        let run = gpu_run(&ctx, &mut ssim, &x, &x, &g0, &[1.0], w, h);
        let m = max_abs(&run.delta);
        eprintln!(
            "identical {w}×{h}: |1 − value| {:.2e}, max |grad| / nearby scale {:.2e}",
            (run.value - 1.0).abs(),
            m / scale
        );
        assert!((run.value - 1.0).abs() <= 5e-7, "{w}×{h}: {}", run.value);
        assert!(
            m <= 2e-5 * scale,
            "{w}×{h}: max |grad| {m:e} (nearby scale {scale:e})"
        );
    }
    drop(ssim);
    common::finish(&ctx);
}

/// Constant images (μ → 0 at a = 0, where C1 dominates; σ → 0 inside, where C2 does) on
/// the GPU against the reference.
#[test]
fn gpu_constant_images() {
    let ctx = common::context();
    let mut ssim = Ssim::new(&ctx).unwrap();
    for &(w, h) in &[(1, 1), (9, 4), (33, 20), (64, 64)] {
        for &(a, b) in &[
            (0.0f32, 0.3f32),
            (0.7, 0.7),
            (1.0, 0.0),
            (0.2, 0.25),
            (0.9, 1.0),
        ] {
            let x = vec![[a; 3]; w * h];
            let y = vec![[b; 3]; w * h];
            let want_v = ssim_cpu(&x, &y, w, h);
            let want_g = ssim_grad_cpu(&x, &y, w, h);
            let g0 = vec![0.0f32; 3 * w * h];
            let run = gpu_run(&ctx, &mut ssim, &x, &y, &g0, &[1.0], w, h);
            let dv = (run.value - want_v).abs();
            // Inside a constant image σ² = E[x²] − μ² and σxy cancel to 0, and their f32
            // rounding (~ε·μ²) is divided by C2 = 9e-4: the value is off by up to 5.0e-5
            // at 33×20 and 9.7e-5 at 64×64 (a = 0.9, b = 1; the interior pixels' error).
            // Not a kernel defect: the same formula in float32 numpy (the reference's
            // PyTorch arithmetic) gives 0.991078379 at 33×20 against the f64 0.991128657,
            // and ours 0.991078248. Textured images stay below 1e-7.
            assert!(dv <= 2e-4, "{w}×{h} a={a} b={b}: {} vs {want_v}", run.value);
            let scale = max_abs(&want_g);
            let err = run
                .delta
                .iter()
                .flatten()
                .zip(want_g.iter().flatten())
                .fold(0.0f64, |m, (p, q)| m.max((p - q).abs()));
            // The gradients of constant pairs are tiny or zero, so bound the error of
            // M·grad (per-pixel dS/dx, O(1–10) for textured images) in absolute terms; the
            // same cancellation makes it up to 8.8e-4 (a = 0.9, b = 1).
            let m = (3 * w * h) as f64;
            eprintln!(
                "constant {w}×{h} a={a} b={b}: |Δvalue| {dv:.2e}, M·|Δgrad| {:.2e} (M·max |grad| {:.2e})",
                err * m,
                scale * m
            );
            assert!(
                err * m <= 3e-3,
                "{w}×{h} a={a} b={b}: gradient error {err:e}"
            );
        }
    }
    drop(ssim);
    common::finish(&ctx);
}

/// Misuse is reported, not recorded.
#[test]
fn gpu_errors() {
    let ctx = common::context();
    let mut ssim = Ssim::new(&ctx).unwrap();
    assert!(ssim.read_value().is_err());
    assert!(ssim.prepare(0, 5).is_err());
    let buf = ctx.buffer("dummy", 16, Memory::Device).unwrap();
    let a = buf.address();
    ctx.submit_and_wait(|cmd| {
        assert!(ssim.record(cmd, a, a, a, 1.0, 4, 4).is_err(), "no scratch");
        Ok(())
    })
    .unwrap();
    ssim.prepare(4, 4).unwrap();
    ctx.submit_and_wait(|cmd| {
        assert!(
            ssim.record(cmd, a, a, a, 1.0, 5, 4).is_err(),
            "scratch too small"
        );
        assert!(ssim.record(cmd, a, a, a, 1.0, 0, 4).is_err(), "empty");
        Ok(())
    })
    .unwrap();
    drop(buf);
    drop(ssim);
    common::finish(&ctx);
}

/// A frame large enough for a 2-D dispatch grid (3·W·H / 256 > 65 535 workgroups, so
/// the grid has padding groups that must do nothing). ~10 s on lavapipe.
#[test]
fn gpu_large_frame_2d_grid() {
    let ctx = common::context();
    let mut ssim = Ssim::new(&ctx).unwrap();
    let mut rng = Rng(0x5513_0005);
    let (w, h) = (2400usize, 2340usize);
    assert!((3 * w * h).div_ceil(256) > 65535);
    let x = random_image(&mut rng, w * h);
    let y = noisy_copy(&mut rng, &x, 0.2);
    let want_v = ssim_cpu(&x, &y, w, h);
    let want_g = ssim_grad_cpu(&x, &y, w, h);
    let g0 = vec![0.0f32; 3 * w * h];
    let run = gpu_run(&ctx, &mut ssim, &x, &y, &g0, &[1.0], w, h);
    let dv = (run.value - want_v).abs();
    let dg = rel_err(&run.delta, &want_g);
    eprintln!("{w}×{h}: ssim {want_v:.6} |Δvalue| {dv:.2e} grad rel {dg:.2e}");
    assert!(dv <= 5e-7);
    assert!(dg <= 2e-5);
    drop(ssim);
    common::finish(&ctx);
}

/// SSIM of a clamped image (`Ssim::record_clamped`, the loss on clamp(raw, 0, 1)): the
/// value is the reference's SSIM of the clamped image, and the gradient added is the
/// reference's gradient at the clamped image where the raw value is in [0, 1]
/// (inclusive: exact 0 and 1 pass, as the clamp's derivative in torch) and exactly
/// nothing elsewhere. About a third of the raw values lie outside [0, 1].
#[test]
fn gpu_clamped_input_passes_the_gradient_only_inside() {
    let ctx = common::context();
    let mut ssim = Ssim::new(&ctx).unwrap();
    let mut rng = Rng(0x5513_0006);
    let (w, h) = (37usize, 23usize);
    let n = w * h;
    let raw: Vec<[f32; 3]> = (0..n)
        .map(|p| {
            std::array::from_fn(|c| match (p * 3 + c) % 11 {
                0 => 0.0,
                1 => 1.0,
                _ => rng.range(-0.35, 1.35) as f32,
            })
        })
        .collect();
    let x: Vec<[f32; 3]> = raw.iter().map(|p| p.map(|v| v.clamp(0.0, 1.0))).collect();
    let y = noisy_copy(&mut rng, &x, 0.2);
    let want_v = ssim_cpu(&x, &y, w, h);
    let full = ssim_grad_cpu(&x, &y, w, h);
    let weight = -0.7f32;
    let want: Vec<[f64; 3]> = raw
        .iter()
        .zip(&full)
        .map(|(r, g)| {
            std::array::from_fn(|c| {
                if (0.0..=1.0).contains(&r[c]) {
                    g[c] * weight as f64
                } else {
                    0.0
                }
            })
        })
        .collect();
    let outside = raw
        .iter()
        .flatten()
        .filter(|v| !(0.0..=1.0).contains(*v))
        .count();
    assert!(
        outside * 4 > 3 * n,
        "{outside} of {} raw values outside [0, 1]",
        3 * n
    );
    ssim.prepare(w as u32, h as u32).unwrap();
    let xb = ctx.buffer_from("x", &planar(&x)).unwrap();
    let rb = ctx.buffer_from("raw", &planar(&raw)).unwrap();
    let yb = ctx.buffer_from("y", &planar(&y)).unwrap();
    let g0: Vec<f32> = (0..3 * n).map(|_| rng.range(-1e-4, 1e-4) as f32).collect();
    let gb = ctx.buffer_from("grad", &g0).unwrap();
    ctx.submit_and_wait(|cmd| {
        assert!(ssim
            .record_clamped(
                cmd,
                xb.address(),
                0,
                yb.address(),
                gb.address(),
                weight,
                37,
                23
            )
            .is_err());
        ssim.record_clamped(
            cmd,
            xb.address(),
            rb.address(),
            yb.address(),
            gb.address(),
            weight,
            w as u32,
            h as u32,
        )
    })
    .unwrap();
    let value = ssim.read_value().unwrap();
    let g1: Vec<f32> = ctx.download(&gb, 0, 3 * n).unwrap();
    let delta: Vec<[f64; 3]> = (0..n)
        .map(|p| std::array::from_fn(|c| g1[c * n + p] as f64 - g0[c * n + p] as f64))
        .collect();
    for p in 0..n {
        for c in 0..3 {
            if !(0.0..=1.0).contains(&raw[p][c]) {
                assert_eq!(
                    g1[c * n + p],
                    g0[c * n + p],
                    "pixel {p} channel {c} outside"
                );
            }
        }
    }
    let dv = (value - want_v).abs();
    let dg = rel_err(&delta, &want);
    eprintln!("clamped: ssim {want_v:.6} |Δvalue| {dv:.2e} grad rel {dg:.2e}, {outside} outside");
    assert!(dv <= 5e-7, "value {value} vs {want_v}");
    assert!(dg <= 2e-5, "gradient relative error {dg:e}");
    drop((xb, rb, yb, gb));
    drop(ssim);
    common::finish(&ctx);
}
