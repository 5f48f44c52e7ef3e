//! The pixel-loss kernel (MSE + transmittance concentration + inside term) vs an f64
//! reference, whose
//! gradient is checked by central differences; and the distortion sum against the
//! f64 reference forward.

use crate::common;

use common::reference_grad::{evaluate, pixel_rays, LossSpec, Params, PixelWeights, TERM_DIST};
use common::{camera_outside, context, finish, random_scene, Rng};
use svraster::raster::{FrameOutputs, RenderOptions, Renderer, CHANNELS};
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
/// T = 1 − alpha; with `clamp`, rgb clamped to [0, 1] first.
fn loss(rgb: &[[f64; 3]], alpha: &[f64], gt: &[[f64; 3]], w: W, clamp: bool) -> f64 {
    let n = rgb.len() as f64;
    let mut se = 0.0;
    let mut tc = 0.0;
    let mut tin = 0.0;
    for p in 0..rgb.len() {
        for c in 0..3 {
            let x = if clamp {
                rgb[p][c].clamp(0.0, 1.0)
            } else {
                rgb[p][c]
            };
            se += (x - gt[p][c]).powi(2);
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
    // With the rgb clamp, a brighter copy of the scene: part of its output is above 1.
    let mut bright = scene.clone();
    for v in bright.sh0.iter_mut().flatten() {
        *v = *v * 3.0 + 0.8;
    }
    for (ss, clamp) in [(1.0f32, false), (1.5, false), (1.0, true), (1.5, true)] {
        let scene = if clamp { &bright } else { &scene };
        let cam = camera_outside(&mut rng, scene, 37, 29);
        let gpu = SceneGpu::upload(&ctx, scene).unwrap();
        let mut r = Renderer::new(&ctx).unwrap();
        // The distortion sum is checked below.
        r.set_outputs(FrameOutputs {
            normals: true,
            distortion: true,
            distortion_contracted: false,
        });
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
                clamp,
            )
        })
        .unwrap();
        let d: Vec<f32> = ctx
            .download(b.dout().unwrap(), 0, dout::CHANNELS * np)
            .unwrap();
        let sums = pl.read().unwrap();

        let rgb: Vec<[f64; 3]> = img.rgb.iter().map(|c| c.map(|v| v as f64)).collect();
        let alpha: Vec<f64> = img.alpha.iter().map(|&a| a as f64).collect();
        let outside = rgb
            .iter()
            .flatten()
            .filter(|v| !(0.0..=1.0).contains(*v))
            .count();
        match pl.clamped_rgb() {
            Some(buf) => {
                assert!(clamp);
                // Enough of the output outside [0, 1] for the clamp to be seen.
                assert!(outside * 10 >= 3 * np, "{outside} of {} outside", 3 * np);
                let got: Vec<f32> = ctx.download(buf, 0, 3 * np).unwrap();
                for p in 0..np {
                    for c in 0..3 {
                        assert_eq!(got[c * np + p], img.rgb[p][c].clamp(0.0, 1.0));
                    }
                }
            }
            None => assert!(!clamp),
        }
        // Value.
        let l_ref = loss(&rgb, &alpha, &gt, w, clamp);
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
                    (loss(&r1, &a1, &gt, w, clamp) - loss(&r2, &a2, &gt, w, clamp)) / (2.0 * h)
                };
                // At the clamp's kinks a central difference is the mean of the two
                // sides; the rule there is the clamp's derivative (1 on [0, 1]
                // inclusive).
                let fd = if clamp && c < 3 && (rgb[p][c].abs() <= h || (rgb[p][c] - 1.0).abs() <= h)
                {
                    let pass = if (0.0..=1.0).contains(&rgb[p][c]) {
                        1.0
                    } else {
                        0.0
                    };
                    pass * 2.0 * w.m * (rgb[p][c].clamp(0.0, 1.0) - gt[p][c]) / (3.0 * np as f64)
                } else {
                    fd
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
            "ss {ss} clamp {clamp} ({outside} outside [0, 1]): loss {l_gpu:.6} (ref {l_ref:.6}); \
             gradient error {worst:.2e} of {scale:.2e}"
        );
        assert!(worst <= 1e-4 * scale, "gradient error {worst} of {scale}");

        // Distortion sum (render resolution) vs the f64 reference forward, without
        // supersampling (the reference renders at the camera's size).
        if ss == 1.0 {
            let rays = pixel_rays(scene, &cam);
            let ev = evaluate(
                scene,
                &Params::of(scene),
                &rays,
                1,
                &vec![PixelWeights::default(); np],
                &LossSpec {
                    lambda_dist: 1.0,
                    ..Default::default()
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

// ---------------------------------------------------------------------------------
// Depth–normal consistency (glsl/train/normal_loss.comp) vs the f64 loss and its
// central differences.

use svraster::train::loss::NormalLoss;
use svraster::Camera;

/// Camera-space normal from a depth map at interior pixel (x, y) (the reference's
/// 3-pixel stencil), None where a depth is ≤ 0 or the cross product vanishes.
fn depth_normal(d: &[f64], cam: &Camera, x: usize, y: usize) -> Option<[f64; 3]> {
    let (w, h) = (cam.width as usize, cam.height as usize);
    if x < 1 || y < 1 || x + 2 > w || y + 2 > h {
        return None;
    }
    let p = |x: usize, y: usize| -> Option<[f64; 3]> {
        let z = d[y * w + x];
        (z > 0.0).then(|| {
            cam.camera_dir(x as f64 + 0.5, y as f64 + 0.5)
                .map(|c| c * z)
        })
    };
    let (r, l, dn, up) = (p(x + 1, y)?, p(x - 1, y)?, p(x, y + 1)?, p(x, y - 1)?);
    let dx = [r[0] - l[0], r[1] - l[1], r[2] - l[2]];
    let dy = [dn[0] - up[0], dn[1] - up[1], dn[2] - up[2]];
    let u = [
        dx[1] * dy[2] - dx[2] * dy[1],
        dx[2] * dy[0] - dx[0] * dy[2],
        dx[0] * dy[1] - dx[1] * dy[0],
    ];
    let len = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
    (len > 0.0).then(|| u.map(|c| c / len))
}

/// λ_med·mean(1 − N·n_med) + λ_mean·mean(α² − α N·n_mean) over the pixels where the
/// depth normal is defined (N rotated into camera space), and the two unweighted sums.
#[allow(clippy::too_many_arguments)]
fn normal_loss(
    mean_d: &[f64],
    med_d: &[f64],
    alpha: &[f64],
    nrm: &[[f64; 3]],
    cam: &Camera,
    lm: f64,
    le: f64,
) -> (f64, f64, f64) {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let rot = cam.w2c();
    let (mut sm, mut se) = (0.0, 0.0);
    for y in 0..h {
        for x in 0..w {
            let k = y * w + x;
            let n = nrm[k];
            let nc: [f64; 3] = std::array::from_fn(|r| (0..3).map(|c| rot[r][c] * n[c]).sum());
            let dot = |a: [f64; 3]| a[0] * nc[0] + a[1] * nc[1] + a[2] * nc[2];
            if let Some(m) = depth_normal(med_d, cam, x, y) {
                sm += 1.0 - dot(m);
            }
            if let Some(m) = depth_normal(mean_d, cam, x, y) {
                se += alpha[k] * alpha[k] - alpha[k] * dot(m);
            }
        }
    }
    let np = (w * h) as f64;
    (lm * sm / np + le * se / np, sm, se)
}

#[test]
fn depth_normal_losses_match_the_f64_reference() {
    let ctx = context();
    let mut rng = Rng(0xd0e5);
    let (w, h) = (23u32, 17u32);
    let cam = Camera::look_at(
        [2.0, -1.5, 1.2],
        [0.1, 0.0, -0.1],
        [0.0, 0.0, 1.0],
        0.9,
        w,
        h,
    );
    let np = (w * h) as usize;
    // A tilted plane's depth plus noise (normals vary but stay defined), with holes.
    let plane = |hole: f64, rng: &mut Rng| -> Vec<f64> {
        (0..np)
            .map(|k| {
                if rng.unit() < hole {
                    0.0
                } else {
                    let (x, y) = ((k % w as usize) as f64, (k / w as usize) as f64);
                    2.0 + 0.03 * x - 0.02 * y + rng.range(-0.05, 0.05)
                }
            })
            .collect()
    };
    let mean_d = plane(0.08, &mut rng);
    let med_d = plane(0.08, &mut rng);
    let alpha: Vec<f64> = (0..np).map(|_| rng.range(0.0, 1.0)).collect();
    let nrm: Vec<[f64; 3]> = (0..np)
        .map(|_| {
            let d = rng.dir();
            let s = rng.range(0.2, 1.0);
            d.map(|c| c * s)
        })
        .collect();
    let (lm, le) = (0.7, 1.3);
    let mut img = vec![0f32; CHANNELS * np];
    for k in 0..np {
        img[3 * np + k] = alpha[k] as f32;
        img[4 * np + k] = mean_d[k] as f32;
        img[5 * np + k] = med_d[k] as f32;
        for c in 0..3 {
            img[(6 + c) * np + k] = nrm[k][c] as f32;
        }
    }
    // f64 values as the GPU sees them (f32-rounded inputs).
    let r32 = |v: &[f64]| v.iter().map(|&x| x as f32 as f64).collect::<Vec<f64>>();
    let (mean_d, med_d, alpha) = (r32(&mean_d), r32(&med_d), r32(&alpha));
    let nrm: Vec<[f64; 3]> = nrm.iter().map(|n| n.map(|c| c as f32 as f64)).collect();
    let img_buf = ctx.buffer_from("img", &img).unwrap();
    let before: Vec<f32> = (0..dout::CHANNELS * np)
        .map(|_| rng.range(-1.0, 1.0) as f32)
        .collect();
    let dout_buf = ctx.buffer_from("dout", &before).unwrap();
    let mut nl = NormalLoss::new(&ctx).unwrap();
    ctx.submit_and_wait(|cmd| {
        nl.record(
            cmd,
            &cam,
            img_buf.address(),
            dout_buf.address(),
            lm as f32,
            le as f32,
        )
    })
    .unwrap();
    let after: Vec<f32> = ctx.download_all(&dout_buf).unwrap();
    let sums = nl.read().unwrap();
    let (_, sm, se) = normal_loss(&mean_d, &med_d, &alpha, &nrm, &cam, lm, le);
    assert!(
        (sums.median - sm).abs() < 1e-4 * sm.abs().max(1.0),
        "Σ median {} vs {sm}",
        sums.median
    );
    assert!(
        (sums.mean - se).abs() < 1e-4 * se.abs().max(1.0),
        "Σ mean {} vs {se}",
        sums.mean
    );
    let l = |md: &[f64], n: &[[f64; 3]]| normal_loss(md, &med_d, &alpha, n, &cam, lm, le).0;
    let hstep = 1e-6;
    let (mut worst, mut scale, mut nonzero_depth_grads) = (0.0f64, 0.0f64, 0);
    for k in 0..np {
        // Normal channels.
        for c in 0..3 {
            let (mut a, mut b) = (nrm.clone(), nrm.clone());
            a[k][c] += hstep;
            b[k][c] -= hstep;
            let fd = (l(&mean_d, &a) - l(&mean_d, &b)) / (2.0 * hstep);
            let ch = dout::NX + c;
            let g = f64::from(after[ch * np + k] - before[ch * np + k]);
            worst = worst.max((g - fd).abs());
            scale = scale.max(fd.abs());
        }
        // Mean depth (where it is a surface: a hole stays a hole).
        let ch = dout::DEPTH;
        let g = f64::from(after[ch * np + k] - before[ch * np + k]);
        if mean_d[k] > 0.0 {
            let (mut a, mut b) = (mean_d.clone(), mean_d.clone());
            a[k] += hstep;
            b[k] -= hstep;
            let fd = (l(&a, &nrm) - l(&b, &nrm)) / (2.0 * hstep);
            worst = worst.max((g - fd).abs());
            scale = scale.max(fd.abs());
            nonzero_depth_grads += usize::from(fd.abs() > 1e-6);
        } else {
            assert_eq!(g, 0.0, "pixel {k}: a hole gets no depth gradient");
        }
        // The other channels are left as they were.
        for ch in [dout::R, dout::G, dout::B, dout::ALPHA] {
            assert_eq!(after[ch * np + k], before[ch * np + k]);
        }
    }
    println!(
        "max |gpu − fd| {worst:.3e} of max |fd| {scale:.3e}; {nonzero_depth_grads} depth gradients"
    );
    assert!(
        nonzero_depth_grads > np / 2,
        "the depth gradients must be exercised"
    );
    assert!(
        worst <= 2e-3 * scale,
        "max |gpu − fd| {worst:.3e} of {scale:.3e}"
    );
    finish(&ctx);
}
