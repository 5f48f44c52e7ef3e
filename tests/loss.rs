//! The pixel-loss kernel (MSE + transmittance concentration + inside term) vs an f64
//! reference, whose
//! gradient is checked by central differences; and the distortion sum against the
//! f64 reference forward.

mod common;

use common::reference_grad::{evaluate, pixel_rays, LossSpec, Params, PixelWeights, TERM_DIST};
use common::{camera_outside, context, finish, random_scene, Rng};
use svraster::raster::{RenderOptions, Renderer, CHANNELS};
use svraster::scene::SceneGpu;
use svraster::train::backward::{dout, Backward};
use svraster::train::loss::{LossWeights, PixelLoss};

/// f64 loss weights: λ_mse, λ_T (concentration), λ_T_inside.
#[derive(Clone, Copy)]
struct W {
    m: f64,
    t: f64,
    i: f64,
}

/// f64 loss: λ_mse·mean((rgb − gt)²) + λ_T·mean(T²(1−T)²) + λ_in·mean(T²),
/// T = 1 − alpha.
fn loss(rgb: &[[f64; 3]], alpha: &[f64], gt: &[[f64; 3]], w: W) -> f64 {
    let n = rgb.len() as f64;
    let mut se = 0.0;
    let mut tc = 0.0;
    let mut tin = 0.0;
    for p in 0..rgb.len() {
        for c in 0..3 {
            se += (rgb[p][c] - gt[p][c]).powi(2);
        }
        let t = 1.0 - alpha[p];
        tc += t * t * (1.0 - t) * (1.0 - t);
        tin += t * t;
    }
    w.m * se / (3.0 * n) + w.t * tc / n + w.i * tin / n
}

#[test]
fn pixel_losses_match_the_f64_reference() {
    let ctx = context();
    let mut rng = Rng(0x1055);
    let mut scene = random_scene(&mut rng, 5, 1);
    for g in scene.geo.iter_mut() {
        *g = rng.range(-5.0, 3.0) as f32;
    }
    let w = W {
        m: 1.3,
        t: 0.7,
        i: 0.45,
    };
    for ss in [1.0f32, 1.5] {
        let cam = camera_outside(&mut rng, &scene, 37, 29);
        let gpu = SceneGpu::upload(&ctx, &scene).unwrap();
        let mut r = Renderer::new(&ctx).unwrap();
        let opts = RenderOptions {
            samples: 1,
            supersample: ss,
        };
        let (img, _) = r.render(&gpu, &cam, &opts).unwrap();
        let frame = r.last_frame().unwrap();
        let np = img.rgb.len();
        let gt: Vec<[f64; 3]> = (0..np)
            .map(|_| [rng.unit(), rng.unit(), rng.unit()])
            .collect();
        let mut gt_planar = vec![0f32; 3 * np];
        for (p, g) in gt.iter().enumerate() {
            for c in 0..3 {
                gt_planar[c * np + p] = g[c] as f32;
            }
        }
        let gt_buf = ctx.buffer_from("gt", &gt_planar).unwrap();
        let mut b = Backward::new(&ctx, true).unwrap();
        b.prepare(&frame, gpu.voxels).unwrap();
        // Stale contents must be overwritten everywhere.
        ctx.upload(b.dout().unwrap(), 0, &vec![f32::NAN; dout::CHANNELS * np])
            .unwrap();
        let mut pl = PixelLoss::new(&ctx).unwrap();
        let out = r.output_address().unwrap();
        let dout_addr = b.dout().unwrap().address();
        ctx.submit_and_wait(|cmd| {
            pl.record(
                cmd,
                &frame,
                out,
                gt_buf.address(),
                dout_addr,
                LossWeights {
                    mse: w.m as f32,
                    t_concentration: w.t as f32,
                    t_inside: w.i as f32,
                },
            )
        })
        .unwrap();
        let d: Vec<f32> = ctx
            .download(b.dout().unwrap(), 0, dout::CHANNELS * np)
            .unwrap();
        let sums = pl.read().unwrap();

        let rgb: Vec<[f64; 3]> = img.rgb.iter().map(|c| c.map(|v| v as f64)).collect();
        let alpha: Vec<f64> = img.alpha.iter().map(|&a| a as f64).collect();
        // Value.
        let l_ref = loss(&rgb, &alpha, &gt, w);
        let l_gpu = w.m * sums.squared_error / (3.0 * np as f64)
            + w.t * sums.t_concentration / np as f64
            + w.i * sums.t_inside / np as f64;
        assert!(
            (l_gpu - l_ref).abs() <= 1e-5 * l_ref,
            "loss {l_gpu} vs {l_ref}"
        );
        // Each term's sum on its own (the logged values).
        let t_inside_ref: f64 = alpha.iter().map(|a| (1.0 - a).powi(2)).sum();
        assert!(
            (sums.t_inside - t_inside_ref).abs() <= 1e-5 * t_inside_ref,
            "Σ T² {} vs {t_inside_ref}",
            sums.t_inside
        );
        // Gradients vs central differences of the f64 loss (it is a polynomial: h = 1e-4
        // leaves only rounding), for every pixel's rgb and alpha.
        let h = 1e-4;
        let mut worst = 0.0f64;
        let mut scale = 0.0f64;
        for p in 0..np {
            for c in 0..4 {
                let fd = {
                    let (mut r1, mut a1) = (rgb.clone(), alpha.clone());
                    let (mut r2, mut a2) = (rgb.clone(), alpha.clone());
                    if c < 3 {
                        r1[p][c] += h;
                        r2[p][c] -= h;
                    } else {
                        a1[p] += h;
                        a2[p] -= h;
                    }
                    (loss(&r1, &a1, &gt, w) - loss(&r2, &a2, &gt, w)) / (2.0 * h)
                };
                let ch = if c < 3 { dout::R + c } else { dout::ALPHA };
                let g = d[ch * np + p] as f64;
                worst = worst.max((g - fd).abs());
                scale = scale.max(fd.abs());
            }
            for c in 0..3 {
                assert_eq!(d[(dout::GT_R + c) * np + p], gt_planar[c * np + p]);
            }
            for ch in [dout::DEPTH, dout::NX, dout::NY, dout::NZ] {
                assert_eq!(d[ch * np + p], 0.0);
            }
        }
        println!(
            "ss {ss}: loss {l_gpu:.6} (ref {l_ref:.6}); gradient error {worst:.2e} of {scale:.2e}"
        );
        assert!(worst <= 1e-4 * scale, "gradient error {worst} of {scale}");

        // Distortion sum (render resolution) vs the f64 reference forward, without
        // supersampling (the reference renders at the camera's size).
        if ss == 1.0 {
            let rays = pixel_rays(&scene, &cam);
            let ev = evaluate(
                &scene,
                &Params::of(&scene),
                &rays,
                1,
                &vec![PixelWeights::default(); np],
                &LossSpec {
                    lambda_dist: 1.0,
                    lambda_r: 0.0,
                },
                None,
            );
            let want = ev.terms[TERM_DIST];
            assert!(
                (sums.distortion - want).abs() <= 1e-4 * want.abs().max(1e-3),
                "distortion {} vs {want}",
                sums.distortion
            );
            println!("distortion sum {:.6} (ref {want:.6})", sums.distortion);
        }
        assert_eq!(CHANNELS, 9);
    }
    finish(&ctx);
}
