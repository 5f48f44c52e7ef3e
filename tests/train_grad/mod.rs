//! GPU training backward vs the f64 reference gradients (tests/common/reference_grad.rs),
//! with native float atomics, the compare-and-swap fallback and the ordered
//! (deterministic) reduction, chunked and not,
//! K = 1..3; gradients stay finite at the numerical extremes.

use crate::common;

use common::backward::{
    ambiguous, compare, compare_within, default_reduction, gpu_grads, gpu_grads_segmented,
    gpu_grads_ss, gpu_grads_walk, gpu_grads_with, random_weights, reductions, rel_err,
};
use common::reference_grad::{grads, LossSpec, PixelWeights, RefGrads};
use common::{camera_inside, camera_outside, context, finish, random_scene, scattered_scene, Rng};
use svraster::data::Camera;
use svraster::raster::FrameOutputs;
use svraster::scene::Scene;
use svraster::train::backward::Reduction;

/// A random scene with moderate densities and a 40×29 outside view on which the
/// reference decides every pixel's order unambiguously at K = 1.
fn scene_and_clear_view(rng: &mut Rng, max_level: u32, degree: u32) -> (Scene, Camera) {
    let mut scene = random_scene(rng, max_level, degree);
    for g in scene.geo.iter_mut() {
        *g = (rng.range(-6.0, 2.5)) as f32;
    }
    let cam = loop {
        let cam = camera_outside(rng, &scene, 40, 29);
        if !ambiguous(&scene, &cam, 1) {
            break cam;
        }
    };
    (scene, cam)
}

/// A dense grid of `8^level` voxels over the scene box with raw density `geo`.
fn dense_scene(level: u32, geo: f32, degree: u32) -> Scene {
    let n = 1u32 << level;
    let mut paths = Vec::new();
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                paths.push(svraster::scene::octpath_from_ijk([i, j, k], level));
            }
        }
    }
    let levels = vec![level as u8; paths.len()];
    let mut s = Scene::from_voxels([0.0; 3], 2.0, degree, paths, levels, geo).unwrap();
    s.background = [0.3, 0.6, 0.9];
    s
}

/// f64 transpose of the frame's tent downsample (raster/downsample.comp): the weights of
/// render pixel p are Σ_q w_qp / Σ_p' w_qp' · u_q; ground truth from the output pixel
/// containing p's centre.
fn transpose_downsample(
    u: &[PixelWeights],
    ow: u32,
    oh: u32,
    rw: u32,
    rh: u32,
) -> Vec<PixelWeights> {
    let (sx, sy) = (rw as f64 / ow as f64, rh as f64 / oh as f64);
    let (rx, ry) = (sx.max(1.0), sy.max(1.0));
    let tent = |i: u32, o: u32, s: f64, r: f64| {
        (1.0 - ((i as f64 + 0.5) - (o as f64 + 0.5) * s).abs() / r).max(0.0)
    };
    let mut out = vec![PixelWeights::default(); (rw * rh) as usize];
    for oy in 0..oh {
        for ox in 0..ow {
            let q = u[(oy * ow + ox) as usize];
            let sum: f64 = (0..rh).map(|y| tent(y, oy, sy, ry)).sum::<f64>()
                * (0..rw).map(|x| tent(x, ox, sx, rx)).sum::<f64>();
            for y in 0..rh {
                for x in 0..rw {
                    let w = tent(y, oy, sy, ry) * tent(x, ox, sx, rx) / sum;
                    if w == 0.0 {
                        continue;
                    }
                    let p = &mut out[(y * rw + x) as usize];
                    for c in 0..3 {
                        p.rgb[c] += w * q.rgb[c];
                        p.normal[c] += w * q.normal[c];
                    }
                    p.alpha += w * q.alpha;
                    p.depth += w * q.depth;
                }
            }
        }
    }
    for y in 0..rh {
        for x in 0..rw {
            let ox = (((x as f64 + 0.5) / sx) as u32).min(ow - 1);
            let oy = (((y as f64 + 0.5) / sy) as u32).min(oh - 1);
            out[(y * rw + x) as usize].gt = u[(oy * ow + ox) as usize].gt;
        }
    }
    out
}

/// The photo bilinearly resized to render resolution, into each render pixel's `gt`:
/// torch's `interpolate(mode="bilinear", align_corners=False)` (SVRaster's
/// `resize_rendering`; its antialiased form is the same when enlarging), in f64.
fn upsample_gt_bilinear(
    u: &[PixelWeights],
    ow: u32,
    oh: u32,
    rpix: &mut [PixelWeights],
    rw: u32,
    rh: u32,
) {
    let (sx, sy) = (rw as f64 / ow as f64, rh as f64 / oh as f64);
    // Source position along one axis: the two neighbours and the second one's weight.
    let taps = |i: u32, s: f64, n: u32| {
        let src = ((i as f64 + 0.5) / s - 0.5).max(0.0);
        let i0 = (src.floor() as u32).min(n - 1);
        let i1 = (i0 + 1).min(n - 1);
        (i0, i1, src - i0 as f64)
    };
    for y in 0..rh {
        let (y0, y1, fy) = taps(y, sy, oh);
        for x in 0..rw {
            let (x0, x1, fx) = taps(x, sx, ow);
            let at = |xx: u32, yy: u32, c: usize| u[(yy * ow + xx) as usize].gt[c];
            let p = &mut rpix[(y * rw + x) as usize];
            for c in 0..3 {
                let top = at(x0, y0, c) * (1.0 - fx) + at(x1, y0, c) * fx;
                let bot = at(x0, y1, c) * (1.0 - fx) + at(x1, y1, c) * fx;
                p.gt[c] = top * (1.0 - fy) + bot * fy;
            }
        }
    }
}

mod gradients;
mod supersampled;
