use super::*;

/// A frame without normals and distortion sums (`Renderer::set_outputs`) gives the
/// backward the same gradients, bit for bit under the ordered reduction, when no loss
/// reads them (zero normal weights, λ_dist = 0); with λ_dist ≠ 0 the backward refuses
/// such a frame instead of dropping the distortion gradient, and with the sums but no
/// normals matches the f64 reference.
#[test]
fn optional_outputs_off_give_the_same_gradients() {
    let ctx = context();
    let mut rng = Rng(0x0071_00e5);
    let (scene, cam) = scene_and_clear_view(&mut rng, 6, 2);
    let np = (cam.width * cam.height) as usize;
    let pix = random_weights(&mut rng, np, [true, true, true, false, true]);
    let on = FrameOutputs {
        normals: true,
        distortion: true,
        distortion_contracted: false,
    };
    let off = FrameOutputs {
        normals: false,
        distortion: false,
        distortion_contracted: false,
    };
    let red = Reduction::Ordered;
    let spec = LossSpec {
        lambda_r: 0.5,
        ..Default::default()
    };
    let a = gpu_grads_with(
        &ctx, &scene, &cam, 1, &pix, &spec, red, None, 1.0, false, on,
    )
    .unwrap();
    let b = gpu_grads_with(
        &ctx, &scene, &cam, 1, &pix, &spec, red, None, 1.0, false, off,
    )
    .unwrap();
    assert!(
        a.geo.iter().any(|&x| x != 0.0) && a.shs.iter().any(|&x| x != 0.0),
        "the test view gives no gradient"
    );
    assert!(
        a.same_bits(&b),
        "gradients differ without the optional outputs"
    );
    // The no-normal kernels of the device's default reduction, against the f64 reference.
    let red = default_reduction(&ctx);
    let c = gpu_grads_with(
        &ctx, &scene, &cam, 1, &pix, &spec, red, None, 1.0, false, off,
    )
    .unwrap();
    let mut worst = [0.0f64; 4];
    compare(
        "outputs off",
        &c,
        &grads(&scene, &cam, 1, &pix, &spec),
        &mut worst,
    );
    let spec = LossSpec {
        lambda_dist: 0.5,
        lambda_r: 0.5,
        ..Default::default()
    };
    // Distortion without normals (the no-normal kernels with the distortion terms).
    let dist_only = FrameOutputs {
        normals: false,
        distortion: true,
        distortion_contracted: false,
    };
    let d = gpu_grads_with(
        &ctx, &scene, &cam, 1, &pix, &spec, red, None, 1.0, false, dist_only,
    )
    .unwrap();
    let reference = grads(&scene, &cam, 1, &pix, &spec);
    compare("distortion without normals", &d, &reference, &mut worst);
    let red = Reduction::Ordered;
    let e = gpu_grads_with(
        &ctx, &scene, &cam, 1, &pix, &spec, red, None, 1.0, false, off,
    );
    let msg = e
        .err()
        .expect("λ_dist ≠ 0 without the distortion sums")
        .to_string();
    assert!(msg.contains("distortion"), "unclear error: {msg}");
    finish(&ctx);
}

/// The tile walk's path for any subgroup size (what 32- and 64-lane GPUs run) gives
/// the same gradients as the 8-lane register transpose, bit for bit under the ordered
/// reduction (same visit sets, same order), on random scenes with the last-contributor
/// cut in play; each also within the f64 reference's bound.
#[test]
fn generic_walk_gradients_equal_the_8_lane_walk() {
    let ctx = context();
    let mut rng = Rng(0x6a4d_0077);
    let mut worst = [0.0f64; 4];
    for (i, &(max_level, degree)) in [(3u32, 0u32), (6, 1), (8, 3)].iter().enumerate() {
        let (scene, cam) = scene_and_clear_view(&mut rng, max_level, degree);
        let np = (cam.width * cam.height) as usize;
        let pix = random_weights(&mut rng, np, [true; 5]);
        let spec = LossSpec {
            lambda_dist: 0.5,
            lambda_r: 0.5,
            ..Default::default()
        };
        let red = Reduction::Ordered;
        let fast = gpu_grads_walk(&ctx, &scene, &cam, 1, &pix, &spec, red, None, 1.0, false);
        let generic = gpu_grads_walk(&ctx, &scene, &cam, 1, &pix, &spec, red, None, 1.0, true);
        assert!(
            fast.same_bits(&generic),
            "scene {i}: the generic walk's gradients differ from the 8-lane walk's"
        );
        let reference = grads(&scene, &cam, 1, &pix, &spec);
        compare(
            &format!("generic walk, scene {i}"),
            &generic,
            &reference,
            &mut worst,
        );
    }
    println!("generic walk, worst relative errors {worst:?}");
    finish(&ctx);
}

#[test]
fn backward_matches_reference_on_random_scenes() {
    let ctx = context();
    let mut rng = Rng(0x6a4d_0001);
    let mut worst = [0.0f64; 4];
    let mut cases = 0;
    let mut redrawn = 0;
    for (i, &(max_level, degree)) in [(3u32, 0u32), (5, 1), (6, 2), (8, 3)].iter().enumerate() {
        let mut scene = random_scene(&mut rng, max_level, degree);
        // Moderate densities keep several voxels per ray in play.
        for g in scene.geo.iter_mut() {
            *g = (rng.range(-6.0, 2.5)) as f32;
        }
        for inside in [false, true] {
            let k = 1 + (i as u32 + inside as u32) % 3;
            let cam = loop {
                let cam = if inside {
                    camera_inside(&mut rng, &scene, 21, 17)
                } else {
                    camera_outside(&mut rng, &scene, 24, 19)
                };
                if !ambiguous(&scene, &cam, k) {
                    break cam;
                }
                redrawn += 1;
                assert!(redrawn < 10, "too many cameras at the early-stop threshold");
            };
            let np = (cam.width * cam.height) as usize;
            let pix = random_weights(&mut rng, np, [true; 5]);
            let spec = LossSpec {
                lambda_dist: rng.range(0.1, 2.0),
                lambda_r: rng.range(0.1, 2.0),
                ..Default::default()
            };
            let reference = grads(&scene, &cam, k as usize, &pix, &spec);
            for red in reductions(&ctx) {
                let g = gpu_grads(&ctx, &scene, &cam, k, &pix, &spec, red, None);
                compare(
                    &format!("scene {i} inside {inside} K {k} reduction {red:?}"),
                    &g,
                    &reference,
                    &mut worst,
                );
                cases += 1;
            }
        }
    }
    println!(
        "{cases} cases ({redrawn} cameras redrawn at a threshold); worst relative errors: geo {:.2e} sh0 {:.2e} shs {:.2e} priority {:.2e}",
        worst[0], worst[1], worst[2], worst[3]
    );
    finish(&ctx);
}

#[test]
fn each_loss_term_alone_and_small_chunks() {
    let ctx = context();
    let mut rng = Rng(0x6a4d_0002);
    let mut scene = random_scene(&mut rng, 6, 2);
    for g in scene.geo.iter_mut() {
        *g = (rng.range(-5.0, 2.0)) as f32;
    }
    let mut cam = camera_outside(&mut rng, &scene, 33, 20);
    while (1..=3).any(|k| ambiguous(&scene, &cam, k)) {
        cam = camera_outside(&mut rng, &scene, 33, 20);
    }
    let np = (cam.width * cam.height) as usize;
    let mut worst = [0.0f64; 4];
    // Terms 0–3: pixel weights; 4: distortion; 5: per-point RGB; 6: both; 7: SVRaster's
    // colour-only per-point RGB; 8: distortion on SVRaster's contracted axis (this
    // outside view's hits all lie beyond distance 1, its 2 − 1/x branch).
    for term in 0..9 {
        let mut on = [false; 5];
        if term < 4 {
            on[term] = true;
        }
        let pix = random_weights(&mut rng, np, on);
        let spec = LossSpec {
            lambda_dist: if matches!(term, 4 | 6 | 8) { 1.0 } else { 0.0 },
            lambda_r: if term == 5 || term == 6 { 1.0 } else { 0.0 },
            lambda_r_colour: if term == 7 { 0.8 } else { 0.0 },
            dist_contracted: term == 8,
            colour_straight: false,
            alpha_straight: false,
            lambda_t: 0.0,
            lambda_t_inside: 0.0,
            r_target_bilinear: false,
        };
        for k in 1..=3u32 {
            let reference = grads(&scene, &cam, k as usize, &pix, &spec);
            // Chunks of 7 entries: many dispatches, state carried between them; the
            // ordered reduction with chunks of 3 and 3 records per gather pass (a voxel
            // with more entries sums them over several passes).
            for (red, chunk) in [(default_reduction(&ctx), 7), (Reduction::Ordered, 3)] {
                let g = gpu_grads(&ctx, &scene, &cam, k, &pix, &spec, red, Some(chunk));
                compare(
                    &format!("term {term} K {k} {red:?} chunk {chunk}"),
                    &g,
                    &reference,
                    &mut worst,
                );
            }
        }
    }
    println!(
        "worst relative errors: geo {:.2e} sh0 {:.2e} shs {:.2e} priority {:.2e}",
        worst[0], worst[1], worst[2], worst[3]
    );
    finish(&ctx);
}

/// A frame composited in segments (a tile's list cut into segments of 1, 3 or 16
/// entries, each walked by its own workgroup and merged in depth order) and its
/// backward walked per segment from the state behind each (train/seg_bmerge.comp):
/// gradients of every loss term at once match the f64 reference, with every reduction.
#[test]
fn segmented_frame_gradients_match_reference() {
    let ctx = context();
    let mut rng = Rng(0x6a4d_0005);
    let mut scene = random_scene(&mut rng, 6, 2);
    for g in scene.geo.iter_mut() {
        *g = (rng.range(-5.0, 2.0)) as f32;
    }
    let mut cam = camera_outside(&mut rng, &scene, 33, 20);
    while (1..=3).any(|k| ambiguous(&scene, &cam, k)) {
        cam = camera_outside(&mut rng, &scene, 33, 20);
    }
    let np = (cam.width * cam.height) as usize;
    let all = FrameOutputs {
        normals: true,
        distortion: true,
        distortion_contracted: false,
    };
    let mut worst = [0.0f64; 4];
    for (i, seg) in [1u32, 3, 16].into_iter().enumerate() {
        let k = 1 + i as u32;
        let pix = random_weights(&mut rng, np, [true; 5]);
        let spec = LossSpec {
            lambda_dist: 1.0,
            lambda_r: 0.5,
            lambda_r_colour: 0.3,
            dist_contracted: seg == 3,
            ..Default::default()
        };
        let reference = grads(&scene, &cam, k as usize, &pix, &spec);
        for red in reductions(&ctx) {
            let g = gpu_grads_segmented(
                &ctx,
                &scene,
                &cam,
                k,
                &pix,
                &spec,
                red,
                None,
                1.0,
                false,
                all,
                Some(seg),
            )
            .unwrap();
            assert!(
                g.max_tile > 2 * seg,
                "segments of {seg}: the longest list ({}) must span several",
                g.max_tile
            );
            compare(
                &format!("segments of {seg}, K {k}, {red:?}"),
                &g,
                &reference,
                &mut worst,
            );
        }
    }
    println!(
        "worst relative errors: geo {:.2e} sh0 {:.2e} shs {:.2e} priority {:.2e}",
        worst[0], worst[1], worst[2], worst[3]
    );
    finish(&ctx);
}

/// A tile whose list fits one segment trains exactly as without segments: with
/// segments longer than any list, the ordered reduction's gradients are the same bits.
#[test]
fn one_segment_per_tile_gives_the_unsegmented_gradients() {
    let ctx = context();
    let mut rng = Rng(0x6a4d_0006);
    let (scene, cam) = scene_and_clear_view(&mut rng, 6, 2);
    let np = (cam.width * cam.height) as usize;
    let pix = random_weights(&mut rng, np, [true; 5]);
    let spec = LossSpec {
        lambda_dist: 0.7,
        lambda_r: 0.4,
        ..Default::default()
    };
    let all = FrameOutputs {
        normals: true,
        distortion: true,
        distortion_contracted: false,
    };
    for k in 1..=3u32 {
        let run = |segments: u32| {
            gpu_grads_segmented(
                &ctx,
                &scene,
                &cam,
                k,
                &pix,
                &spec,
                Reduction::Ordered,
                None,
                1.0,
                false,
                all,
                Some(segments),
            )
            .unwrap()
        };
        let off = run(0);
        let one = run(1 << 20);
        assert!(off.max_tile > 8, "K {k}: lists too short to matter");
        assert!(one.same_bits(&off), "K {k}: one segment per tile differs");
        // And the ordered reduction stays reproducible with many segments.
        assert!(run(3).same_bits(&run(3)), "K {k}: segmented runs differ");
    }
    finish(&ctx);
}

#[test]
fn long_tile_lists_at_the_default_chunk_size() {
    // A column of 8192 level-13 voxels seen end-on through a telephoto lens: every ray of
    // the single 16x16 tile crosses all of them, and the tile holds 4 sign octants x 8192
    // = 32 768 entries, so every backward chunk (2048 entries on lavapipe) is walked in
    // full by every pixel. An invocation hitting the loop limit would truncate gradients.
    let ctx = context();
    let mut rng = Rng(0x6a4d_0003);
    let level = 13u32;
    let n = 1u32 << level;
    let c = n / 2;
    let paths: Vec<u64> = (0..n)
        .map(|k| svraster::scene::octpath_from_ijk([c, c, k], level))
        .collect();
    let mut scene =
        Scene::from_voxels([0.0; 3], 2.0, 1, paths, vec![level as u8; n as usize], 0.0).unwrap();
    for g in scene.geo.iter_mut() {
        *g = rng.range(-4.5, -3.5) as f32;
    }
    for s in scene.sh0.iter_mut() {
        *s = [rng.range(-1.0, 1.0) as f32, 0.3, -0.2];
    }
    scene.background = [0.2, 0.5, 0.7];
    let size = 2.0 / n as f64;
    let mid = 0.5 * size;
    let cam = Camera::look_at(
        [mid, mid, 10.0],
        [mid, mid, 0.0],
        [0.0, 1.0, 0.0],
        0.8 * size / 10.0,
        16,
        16,
    );
    let pix = random_weights(&mut rng, 256, [true; 5]);
    let spec = LossSpec {
        lambda_dist: 1.0,
        lambda_r: 1.0,
        ..Default::default()
    };
    let reference = grads(&scene, &cam, 1, &pix, &spec);
    let hit = reference.priority.iter().filter(|&&p| p > 0.0).count();
    assert_eq!(hit, n as usize, "every voxel should be composited");
    let mut worst = [0.0; 4];
    let mut max_tile = 0;
    for red in reductions(&ctx) {
        let g = gpu_grads(&ctx, &scene, &cam, 1, &pix, &spec, red, None);
        // 8192 composited voxels per ray in f32: bound 1e-3 (measured 1.9e-4).
        compare_within(
            &format!("long tile, reduction {red:?}"),
            &g,
            &reference,
            &mut worst,
            1e-3,
        );
        max_tile = g.max_tile;
    }
    assert_eq!(
        max_tile,
        4 * n,
        "the tile list should hold 4 octants of every voxel"
    );
    println!(
        "{max_tile} entries on one tile; worst relative errors: geo {:.2e} sh0 {:.2e} priority {:.2e}",
        worst[0], worst[1], worst[3]
    );
    finish(&ctx);
}

/// The backward's walk on tiles whose entries mostly miss most pixels (each subgroup
/// visits only what its pixels need, back to front) against the reference, K = 1..3,
/// both atomic variants.
#[test]
fn sparse_tiles_backward_matches_reference() {
    let ctx = context();
    let mut rng = Rng(0x6a4d_0007);
    let mut worst = [0.0; 4];
    for k in 1..=3u32 {
        let scene = scattered_scene(&mut rng, 300, 4, k - 1);
        let cam = Camera::look_at(
            [0.3, 0.1 * k as f64, 3.2],
            [0.1, -0.2, 0.05],
            [0.0, 1.0, 0.0],
            0.9,
            48,
            40,
        );
        assert!(!ambiguous(&scene, &cam, k));
        let pix = random_weights(&mut rng, 48 * 40, [true; 5]);
        let spec = LossSpec {
            lambda_dist: 1.0,
            lambda_r: 0.5,
            ..Default::default()
        };
        let reference = grads(&scene, &cam, k as usize, &pix, &spec);
        for red in reductions(&ctx) {
            let g = gpu_grads(&ctx, &scene, &cam, k, &pix, &spec, red, None);
            compare(
                &format!("sparse K {k} reduction {red:?}"),
                &g,
                &reference,
                &mut worst,
            );
        }
    }
    println!(
        "worst relative errors: geo {:.2e} sh0 {:.2e} shs {:.2e} priority {:.2e}",
        worst[0], worst[1], worst[2], worst[3]
    );
    finish(&ctx);
}

/// Near-opaque voxels (α from 0.99 up to the 0.99999 clamp): the backward walks back
/// from the last contributor, where rebuilding T_k = T / (1 − α) would amplify any
/// rounding difference of α between the forward and the backward by up to 1e5. The
/// gradients must match the reference to the usual bound.
#[test]
fn near_opaque_voxels_backward_matches_reference() {
    let ctx = context();
    let mut rng = Rng(0x6a4d_0008);
    let mut worst = [0.0; 4];
    let mut cases = 0;
    for k in 1..=3u32 {
        // Level-3 grid of side 0.25: vol = 100·len·explin(ρ) ≈ 25·explin(ρ) for a full
        // crossing; ρ in [-0.9, 0.6] gives α between ~0.99 and the clamp, and the thin
        // corner crossings everything below.
        let mut scene = dense_scene(3, 0.0, 1);
        for g in scene.geo.iter_mut() {
            *g = rng.range(-0.9, 0.6) as f32;
        }
        for c in scene.sh0.iter_mut() {
            *c = [
                rng.range(-1.0, 1.0) as f32,
                0.2,
                rng.range(-1.0, 1.0) as f32,
            ];
        }
        let mut tries = 0;
        let cam = loop {
            let cam = camera_outside(&mut rng, &scene, 24, 20);
            if !ambiguous(&scene, &cam, k) {
                break cam;
            }
            tries += 1;
            assert!(tries < 20, "no camera away from the thresholds");
        };
        let pix = random_weights(&mut rng, 24 * 20, [true; 5]);
        let spec = LossSpec {
            lambda_dist: 1.0,
            lambda_r: 1.0,
            ..Default::default()
        };
        let reference = grads(&scene, &cam, k as usize, &pix, &spec);
        for red in reductions(&ctx) {
            let g = gpu_grads(&ctx, &scene, &cam, k, &pix, &spec, red, None);
            compare(
                &format!("near-opaque K {k} reduction {red:?}"),
                &g,
                &reference,
                &mut worst,
            );
            cases += 1;
        }
    }
    println!(
        "{cases} cases; worst relative errors: geo {:.2e} sh0 {:.2e} shs {:.2e} priority {:.2e}",
        worst[0], worst[1], worst[2], worst[3]
    );
    finish(&ctx);
}

/// The distortion on SVRaster's contracted axis from a camera inside the scene, whose
/// rays cross distance 1 (where the axis turns from x to 2 − 1/x): distortion alone and
/// with every other term, K = 1..3, every reduction, against the f64 reference.
#[test]
fn contracted_distortion_matches_reference_across_distance_one() {
    let ctx = context();
    let mut rng = Rng(0x6a4d_00c1);
    let mut scene = random_scene(&mut rng, 6, 1);
    for g in scene.geo.iter_mut() {
        *g = (rng.range(-6.0, 1.0)) as f32;
    }
    let cam = loop {
        let cam = camera_inside(&mut rng, &scene, 31, 23);
        if !(1..=3).any(|k| ambiguous(&scene, &cam, k)) {
            break cam;
        }
    };
    // The view's hits lie on both sides of distance 1.
    let rays = common::reference_grad::pixel_rays(&scene, &cam);
    let hits = || rays.iter().flat_map(|r| &r.hits);
    let (before, beyond) = (
        hits().filter(|h| h.1 < 1.0).count(),
        hits().filter(|h| h.0 > 1.0).count(),
    );
    println!("hits ending before distance 1: {before}, starting beyond it: {beyond}");
    assert!(before > 50 && beyond > 50, "{before} / {beyond}");
    let np = (cam.width * cam.height) as usize;
    let mut worst = [0.0f64; 4];
    for (all, k) in [(false, 1u32), (true, 2), (false, 3)] {
        let pix = random_weights(&mut rng, np, [all; 5]);
        let spec = LossSpec {
            lambda_dist: 1.0,
            lambda_r: if all { 0.5 } else { 0.0 },
            dist_contracted: true,
            ..Default::default()
        };
        let reference = grads(&scene, &cam, k as usize, &pix, &spec);
        // The contraction changes the gradients (the test sees it).
        let raw = grads(
            &scene,
            &cam,
            k as usize,
            &pix,
            &LossSpec {
                dist_contracted: false,
                ..spec
            },
        );
        let moved = reference
            .geo
            .iter()
            .zip(&raw.geo)
            .filter(|(a, b)| (*a - *b).abs() > 1e-3 * b.abs().max(1e-6))
            .count();
        assert!(moved > 10, "contraction moved only {moved} gradients");
        for red in reductions(&ctx) {
            let g = gpu_grads(&ctx, &scene, &cam, k, &pix, &spec, red, Some(5));
            compare(
                &format!("contracted K {k} all terms {all} {red:?}"),
                &g,
                &reference,
                &mut worst,
            );
        }
    }
    println!(
        "worst relative errors: geo {:.2e} sh0 {:.2e} shs {:.2e} priority {:.2e}",
        worst[0], worst[1], worst[2], worst[3]
    );
    finish(&ctx);
}

/// The frame-mean background (`Scene::background_frame_mean`): out_p = C_p + T_p·m with
/// m the frame's mean C, so every pixel's rgb gradient reaches every other pixel's
/// colour, (1/N) Σ_q T_q ∂L/∂out_q (raster/frame_mean.comp in the backward). Against the
/// reference (itself checked against central differences, tests/reference_grad.rs) with
/// every reduction, chunked and segmented, K = 1..3, a frame of two partial sums, and
/// supersampled (the mean at render resolution).
#[test]
fn frame_mean_background_gradients_match_reference() {
    let ctx = context();
    let mut rng = Rng(0x6a4d_00f3);
    let mut scene = random_scene(&mut rng, 6, 1);
    for g in scene.geo.iter_mut() {
        *g = (rng.range(-5.0, 2.0)) as f32;
    }
    scene.background = [0.8, 0.2, 0.6];
    scene.background_frame_mean = true;
    // 4 640 pixels: two of frame_mean.comp's partial sums (4 096 pixels each).
    let mut cam = camera_outside(&mut rng, &scene, 80, 58);
    while (1..=3).any(|k| ambiguous(&scene, &cam, k)) {
        cam = camera_outside(&mut rng, &scene, 80, 58);
    }
    let np = (cam.width * cam.height) as usize;
    let all = FrameOutputs {
        normals: true,
        distortion: true,
        distortion_contracted: false,
    };
    let mut worst = [0.0f64; 4];
    for k in 1..=3u32 {
        let pix = random_weights(&mut rng, np, [true; 5]);
        let spec = LossSpec {
            lambda_dist: 0.5,
            lambda_r: 0.5,
            ..Default::default()
        };
        let reference = grads(&scene, &cam, k as usize, &pix, &spec);
        // The frame mean changes the gradients (the test sees it).
        let mut plain = scene.clone();
        plain.background_frame_mean = false;
        let constant = grads(&plain, &cam, k as usize, &pix, &spec);
        let moved = |a: &[f64], b: &[f64]| {
            a.iter()
                .zip(b)
                .filter(|(x, y)| (*x - *y).abs() > 1e-3 * y.abs().max(1e-6))
                .count()
        };
        let sh0 = |g: &common::reference_grad::RefGrads| -> Vec<f64> {
            g.sh0.iter().flatten().copied().collect()
        };
        let (mg, ms) = (
            moved(&reference.geo, &constant.geo),
            moved(&sh0(&reference), &sh0(&constant)),
        );
        assert!(
            mg > 10 && ms > 10,
            "the frame mean moved {mg} density and {ms} colour gradients"
        );
        for red in reductions(&ctx) {
            let g = gpu_grads(&ctx, &scene, &cam, k, &pix, &spec, red, Some(5));
            compare(
                &format!("frame mean K {k} {red:?} chunks of 5"),
                &g,
                &reference,
                &mut worst,
            );
            let g = gpu_grads_segmented(
                &ctx,
                &scene,
                &cam,
                k,
                &pix,
                &spec,
                red,
                None,
                1.0,
                false,
                all,
                Some(3),
            )
            .unwrap();
            compare(
                &format!("frame mean K {k} {red:?} segments of 3"),
                &g,
                &reference,
                &mut worst,
            );
        }
    }
    // Supersampled: the reference at render resolution with the output weights
    // transposed through the downsample (the frame mean is a render-resolution mean).
    let ss = 1.5f32;
    let (rw, rh) = ((19.0 * ss).round() as u32, (14.0 * ss).round() as u32);
    let mut cam = camera_outside(&mut rng, &scene, 19, 14);
    while ambiguous(&scene, &cam.resized(rw, rh), 1) {
        cam = camera_outside(&mut rng, &scene, 19, 14);
    }
    let pix = random_weights(&mut rng, (cam.width * cam.height) as usize, [true; 5]);
    let spec = LossSpec::default();
    let rpix = super::transpose_downsample(&pix, cam.width, cam.height, rw, rh);
    let reference = grads(&scene, &cam.resized(rw, rh), 1, &rpix, &spec);
    let red = default_reduction(&ctx);
    let g = gpu_grads_ss(&ctx, &scene, &cam, 1, &pix, &spec, red, None, ss);
    compare("frame mean ss 1.5", &g, &reference, &mut worst);
    println!(
        "worst relative errors: geo {:.2e} sh0 {:.2e} shs {:.2e} priority {:.2e}",
        worst[0], worst[1], worst[2], worst[3]
    );
    finish(&ctx);
}

/// The colour clamp's two gradient rules (`colour_clamp_grad`): with many colours
/// clamped (SH DC drawn so that about half of 0.5 + SH fall below 0), the masked and
/// the straight-through backward each match the f64 reference of their rule, on every
/// reduction, for the pixel rgb and both per-point RGB terms; the two rules differ on
/// the clamped voxels' SH and agree on the densities and priorities.
#[test]
fn colour_clamp_straight_through_matches_reference() {
    let ctx = context();
    let mut rng = Rng(0x6a4d_0c1a);
    let mut scene = random_scene(&mut rng, 6, 2);
    for g in scene.geo.iter_mut() {
        *g = (rng.range(-5.0, 2.0)) as f32;
    }
    for c in scene.sh0.iter_mut() {
        for x in c.iter_mut() {
            *x = rng.range(-4.0, 1.0) as f32;
        }
    }
    let mut cam = camera_outside(&mut rng, &scene, 33, 20);
    while ambiguous(&scene, &cam, 2) {
        cam = camera_outside(&mut rng, &scene, 33, 20);
    }
    let np = (cam.width * cam.height) as usize;
    let pix = random_weights(&mut rng, np, [true, false, false, false, false]);
    let mut worst = [0.0f64; 4];
    let mut refs = Vec::new();
    for straight in [false, true] {
        let spec = LossSpec {
            lambda_r: 0.5,
            lambda_r_colour: 0.3,
            colour_straight: straight,
            ..Default::default()
        };
        let reference = grads(&scene, &cam, 2, &pix, &spec);
        for red in reductions(&ctx) {
            let g = gpu_grads(&ctx, &scene, &cam, 2, &pix, &spec, red, None);
            compare(
                &format!("straight {straight} {red:?}"),
                &g,
                &reference,
                &mut worst,
            );
        }
        refs.push(reference);
    }
    let (m, s) = (&refs[0], &refs[1]);
    let differ = |a: &[f64], b: &[f64]| {
        a.iter()
            .zip(b)
            .filter(|(x, y)| (*x - *y).abs() > 1e-6 * (1.0 + x.abs()))
            .count()
    };
    let sh0 = |r: &RefGrads| r.sh0.iter().flatten().copied().collect::<Vec<f64>>();
    let d_sh = differ(&sh0(m), &sh0(s)) + differ(&m.shs, &s.shs);
    println!(
        "{d_sh} SH gradients differ between the rules; worst relative errors: geo {:.2e} \
         sh0 {:.2e} shs {:.2e} priority {:.2e}",
        worst[0], worst[1], worst[2], worst[3]
    );
    assert!(
        d_sh > 50,
        "too few clamped colours seen ({d_sh} SH gradients differ)"
    );
    assert_eq!(
        differ(&m.geo, &s.geo),
        0,
        "the clamp rule changed a density gradient"
    );
    assert_eq!(
        differ(&m.priority, &s.priority),
        0,
        "the clamp rule changed a priority"
    );
    finish(&ctx);
}

/// `alpha_clamp_grad = straight` (SVRaster's backward: dα/dvol = exp(−vol) also where
/// α = min(MAX_ALPHA, ·) clamps) against the f64 reference with the same rule, K = 1
/// and K = 2 (the depth's local alphas clamp on their own), every reduction; both rules
/// checked, and the scene dense enough that many entries clamp. The rule changes
/// density gradients only: the SH gradients and priorities of both rules are equal.
#[test]
fn alpha_clamp_straight_through_matches_reference() {
    let ctx = context();
    let mut rng = Rng(0x6a4d_0c1b);
    let mut scene = random_scene(&mut rng, 6, 1);
    for g in scene.geo.iter_mut() {
        *g = (rng.range(-4.0, 4.0)) as f32;
    }
    let mut cam = camera_outside(&mut rng, &scene, 31, 22);
    while ambiguous(&scene, &cam, 2) || ambiguous(&scene, &cam, 1) {
        cam = camera_outside(&mut rng, &scene, 31, 22);
    }
    let np = (cam.width * cam.height) as usize;
    let pix = random_weights(&mut rng, np, [true, true, true, false, false]);
    let mut worst = [0.0f64; 4];
    for k in [1u32, 2] {
        let mut refs = Vec::new();
        let mut ordered = Vec::new();
        for straight in [false, true] {
            let spec = LossSpec {
                lambda_r: 0.5,
                alpha_straight: straight,
                ..Default::default()
            };
            let reference = grads(&scene, &cam, k as usize, &pix, &spec);
            for red in reductions(&ctx) {
                let g = gpu_grads(&ctx, &scene, &cam, k, &pix, &spec, red, None);
                compare(
                    &format!("K {k} straight {straight} {red:?}"),
                    &g,
                    &reference,
                    &mut worst,
                );
                if red == Reduction::Ordered {
                    ordered.push(g.geo);
                }
            }
            refs.push(reference);
        }
        let (m, s) = (&refs[0], &refs[1]);
        let differ = |a: &[f64], b: &[f64]| {
            a.iter()
                .zip(b)
                .filter(|(x, y)| (*x - *y).abs() > 1e-9 * (1.0 + x.abs()))
                .count()
        };
        // What passes the clamp is at most 1e-5 of ∂L/∂α, below the comparisons' f32
        // tolerance: so the rule's own part is compared on its own. The ordered
        // reduction sums every other term in the same order under both rules, so the
        // difference of its two results is the clamped entries' gradient (to the
        // rounding of the sums).
        let d_gpu: Vec<f32> = ordered[1]
            .iter()
            .zip(&ordered[0])
            .map(|(a, b)| a - b)
            .collect();
        let d_ref: Vec<f64> = s.geo.iter().zip(&m.geo).map(|(a, b)| a - b).collect();
        let e_diff = rel_err(&d_gpu, &d_ref);
        println!("K {k}: the straight-through part, relative error {e_diff:.2e}");
        assert!(
            e_diff <= 0.02,
            "K {k}: straight-through part relative error {e_diff:e}"
        );
        let sh0 = |r: &RefGrads| r.sh0.iter().flatten().copied().collect::<Vec<f64>>();
        let d_geo = differ(&m.geo, &s.geo);
        println!(
            "K {k}: {d_geo} of {} density gradients differ between the rules; worst \
             relative errors: geo {:.2e} sh0 {:.2e} shs {:.2e} priority {:.2e}",
            m.geo.len(),
            worst[0],
            worst[1],
            worst[2],
            worst[3]
        );
        assert!(d_geo >= 10, "too few clamped alphas seen ({d_geo} differ)");
        assert_eq!(
            differ(&sh0(m), &sh0(s)),
            0,
            "the rule changed a colour gradient"
        );
        assert_eq!(
            differ(&m.priority, &s.priority),
            0,
            "the rule changed a priority"
        );
    }
    finish(&ctx);
}
