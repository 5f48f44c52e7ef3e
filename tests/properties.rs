//! Property-based tests (proptest): small random scenes and cameras drawn with their
//! extremes — cameras inside the scene, on the optical axis of an axis-aligned view
//! (exact ±0 ray components), on voxel boundary planes; densities that leave every voxel
//! empty, that clamp every alpha at its maximum, or a mix of both with moderate ones;
//! image sizes from 1×1; SH degrees 0–3 and 1–3 samples per segment — and the forward
//! frame and the training gradients checked against the f64 references within the bounds
//! tests/raster/ and tests/train_grad/ state. The runs are deterministic (a fixed
//! generator seed), so CI draws the same cases every time; a failure prints the case,
//! shrunk towards the simplest one that still fails.

use crate::common;

use common::backward::{
    compare_within, forward_eval, gpu_grads, random_weights, reductions, BOUND,
};
use common::forward::{assert_within, compare, pixel, render, Errors};
use common::reference;
use common::reference_grad::{grads, LossSpec};
use common::{camera_inside, camera_outside, context, finish, random_scene, Rng};
use proptest::prelude::*;
use proptest::test_runner::{Config, RngAlgorithm, TestCaseError, TestRng, TestRunner};
use std::cell::{Cell, RefCell};
use svraster::data::Camera;
use svraster::raster::Renderer;
use svraster::scene::Scene;

/// Where the camera is.
#[derive(Clone, Copy, Debug)]
enum View {
    Outside,
    Inside,
    /// On a scene axis (0, 1, 2) on the given side, looking at the centre with an axis
    /// as up: the centre column/row rays have exact ±0 components.
    AxisAligned(usize, bool),
    /// Outside, with its x and y on planes of the finest voxel grid.
    OnBoundaryPlanes,
}

fn view_index(v: View) -> usize {
    match v {
        View::Outside => 0,
        View::Inside => 1,
        View::AxisAligned(..) => 2,
        View::OnBoundaryPlanes => 3,
    }
}

/// How dense the voxels are.
#[derive(Clone, Copy, Debug)]
enum Densities {
    /// common::random_density: moderate, tiny, large and huge (up to 1e5) mixed.
    Mixed,
    /// Every density in [-60, -8]: alphas at or below the skip threshold.
    Empty,
    /// Every density in [1e3, 1e4]: every crossing clamps alpha at its maximum and the
    /// transmittance underflows the early-stop threshold after the first voxels.
    Opaque,
}

#[derive(Clone, Copy, Debug)]
struct Case {
    seed: u64,
    max_level: u32,
    degree: u32,
    samples: u32,
    view: View,
    densities: Densities,
    width: u32,
    height: u32,
}

fn cases(max_w: u32, max_h: u32) -> impl Strategy<Value = Case> {
    let view = prop_oneof![
        Just(View::Outside),
        Just(View::Inside),
        (0usize..3, any::<bool>()).prop_map(|(a, s)| View::AxisAligned(a, s)),
        Just(View::OnBoundaryPlanes),
    ];
    let densities = prop_oneof![
        2 => Just(Densities::Mixed),
        1 => Just(Densities::Empty),
        1 => Just(Densities::Opaque),
    ];
    (
        any::<u64>(),
        1u32..=8,
        0u32..=3,
        1u32..=3,
        view,
        densities,
        1u32..=max_w,
        1u32..=max_h,
    )
        .prop_map(
            |(seed, max_level, degree, samples, view, densities, width, height)| Case {
                seed,
                max_level,
                degree,
                samples,
                view,
                densities,
                width,
                height,
            },
        )
}

/// The scene and camera of a case.
fn build(c: &Case) -> (Scene, Camera) {
    let mut rng = Rng(c.seed);
    let mut scene = random_scene(&mut rng, c.max_level, c.degree);
    match c.densities {
        Densities::Mixed => {}
        Densities::Empty => {
            for g in scene.geo.iter_mut() {
                *g = rng.range(-60.0, -8.0) as f32;
            }
        }
        Densities::Opaque => {
            for g in scene.geo.iter_mut() {
                *g = rng.range(1e3, 1e4) as f32;
            }
        }
    }
    let (w, h) = (c.width, c.height);
    let centre = scene.center.map(f64::from);
    let e = f64::from(scene.extent);
    let cam = match c.view {
        View::Outside => camera_outside(&mut rng, &scene, w, h),
        View::Inside => camera_inside(&mut rng, &scene, w, h),
        View::AxisAligned(axis, positive) => {
            let mut eye = centre;
            eye[axis] += if positive { 1.6 * e } else { -1.6 * e };
            let mut up = [0.0; 3];
            up[(axis + 1) % 3] = 1.0;
            Camera::look_at(eye, centre, up, rng.range(0.6, 1.2), w, h)
        }
        View::OnBoundaryPlanes => {
            // Planes of the finest level: centre − e/2 + i·e/2^L.
            let cells = 1u64 << c.max_level;
            let plane = |rng: &mut Rng, axis: usize| {
                let i = rng.below(cells + 1) as f64;
                centre[axis] - 0.5 * e + i * e / cells as f64
            };
            let eye = [plane(&mut rng, 0), plane(&mut rng, 1), centre[2] + 1.7 * e];
            let target = [centre[0], centre[1], centre[2]];
            Camera::look_at(eye, target, [0.0, 1.0, 0.0], rng.range(0.6, 1.2), w, h)
        }
    };
    (scene, cam)
}

/// Whether the ray of pixel (px, py) crosses a dense voxel (max corner density > 10)
/// over less than 1e-5·(1 + t): a ray through an edge or corner where voxels meet.
/// The f64 reference crosses such a voxel over exactly 0 (α = 0) where f32 rounding of
/// the entry and exit distances (~1e-7·t) leaves a sliver whose α, at density 1e4, can
/// be anything up to the clamp — an ill-conditioned case, not an error (README:
/// Numerical limits).
fn grazes_a_dense_voxel(scene: &Scene, cam: &Camera, px: u32, py: u32) -> bool {
    let (o, d, norm) = reference::pixel_ray(cam, f64::from(px) + 0.5, f64::from(py) + 0.5);
    let t_near = cam.near * norm;
    reference::ray_hits(scene, o, d, t_near)
        .iter()
        .any(|&(a, b, i)| {
            let dense = scene.corners[i]
                .iter()
                .any(|&g| scene.geo[g as usize] > 10.0);
            dense && b - a < 1e-5 * (1.0 + b.abs())
        })
}

/// Pixels where f32 and f64 may legitimately composite different entries, so their loss
/// weights are set to zero in the gradient comparison (the other pixels' gradients do
/// not depend on them): a crossing whose α is within 1e-3 (relative) of the skip
/// threshold 1e-5 — f32 forms α with ~1e-6 relative error (alpha_of_depth) — or within
/// 5 % of the clamp at 0.99999 in optical depth (there f32 resolves 1 − α only to ~1 %,
/// and the clamp switches the gradient through α off), or a
/// transmittance after a contributor within 1e-3 of the early-stop threshold 1e-4 (the
/// stop is a discontinuity: ∂L/∂α of the entries before it jumps).
fn undecidable_pixels(scene: &Scene, cam: &Camera, k: u32) -> Vec<bool> {
    let ev = forward_eval(scene, cam, k);
    let np = ev.contributors.len();
    let near = |x: f64, threshold: f64| (x / threshold - 1.0).abs() < 1e-3;
    (0..np)
        .map(|p| {
            let (px, py) = (p as u32 % cam.width, p as u32 / cam.width);
            let stop = ev.contributors[p]
                .iter()
                .any(|c| near(c.t * (1.0 - c.alpha), reference::EARLY_STOP_T));
            let (o, d, norm) = reference::pixel_ray(cam, f64::from(px) + 0.5, f64::from(py) + 0.5);
            let skip = reference::ray_hits(scene, o, d, cam.near * norm)
                .iter()
                .any(|&(a, b, i)| {
                    let g: [f64; 8] =
                        std::array::from_fn(|c| f64::from(scene.geo[scene.corners[i][c] as usize]));
                    let (vmin, size) = (scene.voxel_min(i), scene.voxel_size(i));
                    let (alpha, _, _) = reference::alpha_of(&g, vmin, size, o, d, a, b, k as usize);
                    // The optical depth of the segment and of each sample: the clamp at
                    // α = 0.99999 (σ = ln 1e5) zeroes the gradient through α, and f32
                    // resolves 1 − α there to ~1 %.
                    let step = (b - a) / f64::from(k);
                    let lv: Vec<f64> = (0..k)
                        .map(|s| {
                            let t = a + (f64::from(s) + 0.5) * step;
                            let q: [f64; 3] =
                                std::array::from_fn(|ax| (o[ax] + t * d[ax] - vmin[ax]) / size);
                            reference::STEP_SZ_SCALE
                                * step
                                * reference::explin(reference::trilinear(&g, q))
                        })
                        .collect();
                    let vol: f64 = lv.iter().sum();
                    let clamp = (1.0 - reference::MAX_ALPHA).ln().abs();
                    near(alpha, reference::MIN_ALPHA)
                        || (vol - clamp).abs() < 0.05
                        || lv.iter().any(|x| (x - clamp).abs() < 0.05)
                });
            stop || skip
        })
        .collect()
}

fn runner(cases: u32) -> TestRunner {
    TestRunner::new_with_rng(
        Config {
            cases,
            failure_persistence: None,
            // Bounded shrinking: each step renders and differentiates a scene.
            max_shrink_iters: 64,
            ..Config::default()
        },
        TestRng::deterministic_rng(RngAlgorithm::ChaCha),
    )
}

/// Turns a panic of the shared assertion helpers into a proptest failure (so the case is
/// shrunk and printed).
fn checked(f: impl FnOnce()) -> Result<(), TestCaseError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).map_err(|p| {
        let msg = p
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_else(|| "panic".into());
        TestCaseError::fail(msg)
    })
}

#[test]
fn forward_matches_the_reference_on_drawn_scenes() {
    let ctx = context();
    // The runner takes a `Fn`: the renderer and the tally live in cells.
    let r = RefCell::new(Renderer::new(&ctx).unwrap());
    let views = RefCell::new([0usize; 4]);
    let (pixels, grazing) = (Cell::new(0usize), Cell::new(0usize));
    let result = runner(48).run(&cases(40, 32), |c| {
        let (scene, cam) = build(&c);
        views.borrow_mut()[view_index(c.view)] += 1;
        checked(|| {
            let what = format!("{c:?} ({} voxels)", scene.num_voxels());
            let img = render(&mut r.borrow_mut(), &ctx, &scene, &cam, c.samples);
            let refs = reference::render(&scene, &cam, c.samples as usize);
            let mut e = Errors::default();
            let mut compared = 0;
            for (i, rp) in refs.iter().enumerate() {
                let (px, py) = (i as u32 % cam.width, i as u32 / cam.width);
                if grazes_a_dense_voxel(&scene, &cam, px, py) {
                    grazing.set(grazing.get() + 1);
                    continue;
                }
                e = e.max(compare(&pixel(&img, i), std::slice::from_ref(rp), &what));
                compared += 1;
            }
            pixels.set(pixels.get() + compared);
            assert_within(&e, &what);
        })
    });
    if let Err(e) = result {
        panic!("{e}");
    }
    let views = views.into_inner();
    assert!(
        views.iter().all(|&n| n > 0),
        "every kind of view drawn: {views:?}"
    );
    let (pixels, grazing) = (pixels.get(), grazing.get());
    println!("views {views:?}: {pixels} pixels compared, {grazing} grazing a dense voxel");
    assert!(
        grazing * 20 < pixels,
        "{grazing} grazing pixels of {pixels}"
    );
    finish(&ctx);
}

#[test]
fn gradients_match_the_reference_on_drawn_scenes() {
    let ctx = context();
    // Cases compared per density kind [mixed, empty, opaque] and per view kind.
    let kinds = RefCell::new(([0usize; 3], [0usize; 4]));
    let (pixels, excluded) = (Cell::new(0usize), Cell::new(0usize));
    let limited = Cell::new(0usize);
    let result = runner(32).run(&cases(24, 20), |c| {
        let (scene, cam) = build(&c);
        let mut rng = Rng(c.seed ^ 0x9e37_79b9_7f4a_7c15);
        let np = (cam.width * cam.height) as usize;
        let mut pix = random_weights(&mut rng, np, [true; 5]);
        // Pixels whose f32 and f64 frames may legitimately differ (undecidable
        // thresholds, rays grazing a dense voxel) get zero loss weights. The per-point
        // losses (distortion, per-point RGB) act on every pixel whatever its weights, so
        // a case with such a pixel is compared with them off.
        let mut excluded_px = undecidable_pixels(&scene, &cam, c.samples);
        for (p, x) in excluded_px.iter_mut().enumerate() {
            let (px, py) = (p as u32 % cam.width, p as u32 / cam.width);
            *x = *x || grazes_a_dense_voxel(&scene, &cam, px, py);
        }
        for (w, &u) in pix.iter_mut().zip(&excluded_px) {
            if u {
                *w = Default::default();
            }
        }
        pixels.set(pixels.get() + np);
        let n_excluded = excluded_px.iter().filter(|&&u| u).count();
        excluded.set(excluded.get() + n_excluded);
        let spec = if n_excluded > 0 {
            limited.set(limited.get() + 1);
            LossSpec::default()
        } else {
            LossSpec {
                lambda_dist: rng.range(0.1, 2.0),
                lambda_r: rng.range(0.1, 2.0),
                ..Default::default()
            }
        };
        {
            let mut k = kinds.borrow_mut();
            k.0[c.densities as usize] += 1;
            k.1[view_index(c.view)] += 1;
        }
        checked(|| {
            let reference = grads(&scene, &cam, c.samples as usize, &pix, &spec);
            for red in reductions(&ctx) {
                let g = gpu_grads(&ctx, &scene, &cam, c.samples, &pix, &spec, red, None);
                let mut worst = [0.0; 4];
                compare_within(
                    &format!("{c:?} reduction {red:?}"),
                    &g,
                    &reference,
                    &mut worst,
                    BOUND,
                );
            }
        })
    });
    if let Err(e) = result {
        panic!("{e}");
    }
    let (densities, views) = kinds.into_inner();
    let (pixels, excluded) = (pixels.get(), excluded.get());
    let limited = limited.get();
    println!(
        "compared: densities {densities:?}, views {views:?}; {excluded} of {pixels} pixels \
         undecidable or grazing a dense voxel (weights zeroed); {limited} of 32 cases \
         compared without the per-point losses"
    );
    // Most cases keep the per-point losses (a case without them still compares the
    // colour, alpha, depth and normal terms).
    assert!(
        limited * 2 < 32,
        "{limited} of 32 cases without the per-point losses"
    );
    assert!(
        densities.iter().chain(&views).all(|&n| n > 0),
        "every kind compared: {densities:?} {views:?}"
    );
    assert!(
        excluded * 10 < pixels,
        "{excluded} of {pixels} pixels undecidable"
    );
    finish(&ctx);
}
