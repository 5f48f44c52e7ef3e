use super::*;

#[test]
fn max_weight_and_interval_match_reference() {
    let ctx = context();
    let mut pass = StatsPass::new(&ctx).unwrap();
    let mut worst = Report::default();
    let mut totals = Report::default();
    // Voxels whose centre some view holds within its near plane (the two paths differ).
    let (mut near_voxels, mut near_differ) = (0usize, 0usize);
    // Without segments, and with lists cut into segments of 3 entries (the exact pass
    // folds the weights, on the frame's transmittance).
    for (seed, seg) in (0..6u64).map(|s| (s, 0)).chain((0..3).map(|s| (s, 3))) {
        let mut renderer = Renderer::new(&ctx).unwrap();
        renderer.set_segment_entries(seg);
        let mut rng = Rng(5150 + seed);
        let max_level = [4, 7, 10, 16, 6, 12][seed as usize];
        let scene = random_scene(&mut rng, max_level, (seed % 3) as u32);
        let gpu = SceneGpu::upload(&ctx, &scene).unwrap();
        // Non-square pixels in one view: the interval uses fx, not fy.
        let mut wide = camera_outside(&mut rng, &scene, 29, 37);
        wide.fy *= 1.3;
        let cams = [
            camera_outside(&mut rng, &scene, 48, 36),
            wide,
            camera_inside(&mut rng, &scene, 40, 30),
        ];
        for k in [1u32, 3] {
            let what = format!(
                "seed {seed} (levels ≤{max_level}, {} voxels) K {k}, segments of {seg}",
                scene.num_voxels()
            );
            pass.begin(scene.num_voxels() as u32).unwrap();
            let mut weights = vec![WeightBounds::default(); scene.num_voxels()];
            let mut intervals = vec![IntervalBounds::default(); scene.num_voxels()];
            for cam in &cams {
                pass.add_view(&mut renderer, &gpu, cam, k).unwrap();
                assert_eq!(renderer.max_weight_target(), None);
                reference_max_weights(&scene, cam, k as usize, &mut weights);
                reference_intervals(&scene, cam, &mut intervals);
            }
            let stats = pass.read().unwrap();
            // The preprocess-only path (initialisation) gives the same intervals, bit for
            // bit, and leaves the weights alone.
            let mut geo_only = StatsPass::new(&ctx).unwrap();
            geo_only.begin(scene.num_voxels() as u32).unwrap();
            for cam in &cams {
                geo_only
                    .add_view_intervals(&mut renderer, &gpu, cam)
                    .unwrap();
            }
            let g = geo_only.read().unwrap();
            assert!(g.max_weight.iter().all(|&w| w == 0.0), "{what}");
            // The preprocess-only path (the initial layout's) leaves a view out of a voxel
            // whose centre is within the view's near plane (SVRaster's mark_max_samp_rate);
            // the training path clamps the depth to it. Elsewhere they agree bit for bit.
            for (v, (a, b)) in g.min_interval.iter().zip(&stats.min_interval).enumerate() {
                let near = cams.iter().any(|c| {
                    let (p, o) = (scene.voxel_center(v), c.origin());
                    (0..3).map(|k| (p[k] - o[k]) * c.c2w[k][2]).sum::<f64>() <= c.near
                });
                if near {
                    near_voxels += 1;
                    assert!(a >= b, "{what}: voxel {v}: init interval {a} below {b}");
                    near_differ += usize::from(a > b);
                } else {
                    assert_eq!(a.to_bits(), b.to_bits(), "{what}: voxel {v}: {a} vs {b}");
                }
            }
            let r = compare(&stats, &weights, &intervals, &what);
            println!("{what}: {r:?}");
            assert!(r.weighted > 10, "{what}: too few voxels contribute: {r:?}");
            assert!(r.visible > 10, "{what}: too few visible voxels: {r:?}");
            assert!(
                r.weight_loose * 2 <= r.weighted,
                "{what}: too many ill-conditioned weights: {r:?}"
            );
            assert!(
                r.vis_ambiguous * 20 <= r.voxels,
                "{what}: too many ambiguous visibilities: {r:?}"
            );
            worst.weight_err = worst.weight_err.max(r.weight_err);
            worst.weight_width = worst.weight_width.max(r.weight_width);
            worst.interval_err = worst.interval_err.max(r.interval_err);
            totals.voxels += r.voxels;
            totals.weighted += r.weighted;
            totals.weight_loose += r.weight_loose;
            totals.near_clamped += r.near_clamped;
            totals.visible += r.visible;
            totals.invisible += r.invisible;
            totals.vis_ambiguous += r.vis_ambiguous;
        }
    }
    println!(
        "worst: weight {:.3e} outside the reference range (bound {WEIGHT_TOL:e}; widest \
         range {:.3e}; {} of {} contributing voxels have a range wider than {WEIGHT_LOOSE:e}), \
         interval {:.3e} (bound {INTERVAL_TOL:e}); totals {totals:?}",
        worst.weight_err,
        worst.weight_width,
        totals.weight_loose,
        totals.weighted,
        worst.interval_err
    );
    assert!(
        totals.invisible > 0,
        "the never-visible path is not exercised"
    );
    assert!(
        totals.near_clamped > 0,
        "the near-plane clamp is not exercised"
    );
    assert!(
        near_differ > 0,
        "the init path's near rule is not exercised ({near_voxels} voxels near a view)"
    );
    finish(&ctx);
}

/// Frames are unaffected by the statistics: an image rendered before a stats pass, one
/// after it (target unset again) and one rendered with a target set are bit-identical.
#[test]
fn frames_are_bit_identical_with_and_without_statistics() {
    let ctx = context();
    let mut renderer = Renderer::new(&ctx).unwrap();
    let mut rng = Rng(99);
    let scene = random_scene(&mut rng, 8, 2);
    let gpu = SceneGpu::upload(&ctx, &scene).unwrap();
    let cam = camera_outside(&mut rng, &scene, 48, 40);
    let opts = RenderOptions {
        samples: 2,
        supersample: 1.0,
    };
    let (before, _) = renderer.render(&gpu, &cam, &opts).unwrap();
    assert!(before.alpha.iter().any(|&a| a > 0.1), "nothing in view");

    let mut pass = StatsPass::new(&ctx).unwrap();
    pass.begin(scene.num_voxels() as u32).unwrap();
    pass.add_view(&mut renderer, &gpu, &cam, 2).unwrap();
    assert_eq!(renderer.max_weight_target(), None);
    let (after, _) = renderer.render(&gpu, &cam, &opts).unwrap();

    renderer.set_max_weight_target(Some(pass.max_weight_address()));
    let (with_target, _) = renderer.render(&gpu, &cam, &opts).unwrap();
    renderer.set_max_weight_target(None);
    let stats = pass.read().unwrap();
    assert!(stats.max_weight.iter().any(|&w| w > 0.1));

    let same = |a: &Image, b: &Image, what: &str| {
        let bits = |img: &Image| -> Vec<u32> {
            img.rgb
                .iter()
                .flatten()
                .chain(&img.alpha)
                .chain(&img.depth)
                .chain(&img.depth_median)
                .chain(img.normal.iter().flatten())
                .map(|v| v.to_bits())
                .collect()
        };
        assert!(bits(a) == bits(b), "{what}: images differ");
    };
    same(&before, &after, "after a stats pass");
    same(&before, &with_target, "with a max-weight target");
    finish(&ctx);
}

/// A voxel behind an opaque wall (all its rays stop early in the wall) gets max weight
/// exactly 0 but a finite interval (it is visible: preprocess gives it entries); with a
/// transparent wall it gets a clear weight.
#[test]
fn voxel_behind_an_opaque_wall_gets_zero_weight() {
    let ctx = context();
    let mut renderer = Renderer::new(&ctx).unwrap();
    // Level 2 (4³ cells of 0.5 in a cube of 2 around the origin): the wall is the slab
    // i = 3 (x in [0.5, 1]) across all of y and z; the voxel behind it is (0, 1, 1).
    let mut paths = Vec::new();
    for j in 0..4 {
        for k in 0..4 {
            paths.push(octpath_from_ijk([3, j, k], 2));
        }
    }
    let behind = paths.len();
    paths.push(octpath_from_ijk([0, 1, 1], 2));
    let levels = vec![2u8; paths.len()];
    let scene = Scene::from_voxels([0.0; 3], 2.0, 0, paths, levels, 0.0).unwrap();
    let wall_corners: Vec<u32> = scene.corners[..behind].iter().flatten().copied().collect();
    let cam = Camera::look_at([5.0, 0.1, -0.05], [0.0; 3], [0.0, 0.0, 1.0], 0.7, 41, 37);
    let mut pass = StatsPass::new(&ctx).unwrap();

    let mut run = |scene: &Scene, wall: f32| -> VoxelStats {
        let mut s = scene.clone();
        for (g, v) in s.geo.iter_mut().enumerate() {
            *v = if wall_corners.contains(&(g as u32)) {
                wall
            } else {
                2.0
            };
        }
        let gpu = SceneGpu::upload(&ctx, &s).unwrap();
        pass.begin(s.num_voxels() as u32).unwrap();
        pass.add_view(&mut renderer, &gpu, &cam, 1).unwrap();
        // A scene of another size is refused.
        let other = Scene::from_voxels([0.0; 3], 2.0, 0, vec![0], vec![1], 0.0).unwrap();
        let other = SceneGpu::upload(&ctx, &other).unwrap();
        assert!(pass.add_view(&mut renderer, &other, &cam, 1).is_err());
        assert_eq!(renderer.max_weight_target(), None);
        pass.read().unwrap()
    };

    // Transparent wall (explin(-60) ≈ 1e-24: α below the skip threshold).
    let open = run(&scene, -60.0);
    println!("transparent wall: behind {:?}", open.max_weight[behind]);
    assert!(open.max_weight[behind] > 0.5, "{:?}", open.max_weight);
    assert!(open.max_weight[..behind].iter().all(|&w| w == 0.0));
    // Opaque wall: α clamps to 0.99999 in the first wall voxel, T = 1e-5 < 1e-4 stops.
    let closed = run(&scene, 1e4);
    println!(
        "opaque wall: behind {}, wall max {:?}",
        closed.max_weight[behind],
        closed.max_weight[..behind]
            .iter()
            .fold(0f32, |a, &b| a.max(b))
    );
    assert_eq!(closed.max_weight[behind], 0.0);
    assert!(closed.max_weight[..behind]
        .iter()
        .any(|&w| (w - 0.99999).abs() < 1e-6));
    // Visible in both (its projection covers pixels), same interval.
    assert!(closed.min_interval[behind].is_finite());
    assert_eq!(closed.min_interval[behind], open.min_interval[behind]);
    let rate = closed.sampling_rate(&scene);
    let want = scene.voxel_size(behind) / closed.min_interval[behind] as f64;
    assert!((rate[behind] as f64 - want).abs() <= 1e-6 * want);
    finish(&ctx);
}

/// A renderer that must grow (entry overflow, too few composite chunks) and re-render
/// gives exactly the statistics of one with room to spare: an incomplete frame leaves
/// nothing stale in the accumulators.
#[test]
fn grow_and_retry_leaves_no_stale_statistics() {
    let ctx = context();
    let mut rng = Rng(2024);
    // All 4096 level-4 voxels of a cube of 2, semi-transparent (α ≈ 0.003..0.1 each):
    // rays from inside cross many voxels, and the near ones cover many tiles.
    let mut paths = Vec::new();
    for i in 0..16 {
        for j in 0..16 {
            for k in 0..16 {
                paths.push(octpath_from_ijk([i, j, k], 4));
            }
        }
    }
    let levels = vec![4u8; paths.len()];
    let mut scene = Scene::from_voxels([0.0; 3], 2.0, 0, paths, levels, 0.0).unwrap();
    for g in scene.geo.iter_mut() {
        *g = rng.range(-8.0, -3.0) as f32;
    }
    for c in scene.sh0.iter_mut() {
        *c = [rng.unit() as f32, rng.unit() as f32, rng.unit() as f32];
    }
    let gpu = SceneGpu::upload(&ctx, &scene).unwrap();
    let cams = [
        camera_outside(&mut rng, &scene, 960, 720),
        camera_inside(&mut rng, &scene, 640, 480),
    ];
    let n = scene.num_voxels() as u32;
    let mut pass = StatsPass::new(&ctx).unwrap();

    let mut big = Renderer::new(&ctx).unwrap();
    big.set_chunk_size(1 << 20);
    big.reserve_entries(4 << 20).unwrap();
    pass.begin(n).unwrap();
    for cam in &cams {
        pass.add_view(&mut big, &gpu, cam, 1).unwrap();
        let s = big.stats().unwrap();
        println!("big renderer: {s:?}");
        assert!(s.complete() && s.chunks == 1);
    }
    let want = pass.read().unwrap();

    let mut small = Renderer::new(&ctx).unwrap();
    small.set_chunk_size(40);
    small
        .prepare(&gpu, &cams[0], &RenderOptions::default())
        .unwrap();
    let cap0 = small.entry_capacity();
    pass.begin(n).unwrap();
    for cam in &cams {
        pass.add_view(&mut small, &gpu, cam, 1).unwrap();
    }
    let got = pass.read().unwrap();
    let s = small.stats().unwrap();
    println!("small renderer: initial capacity {cap0}, last frame {s:?}");
    assert!(
        small.entry_capacity() > cap0,
        "the test must overflow the initial entry capacity"
    );
    assert!(s.chunks > 1, "the test must need several chunks");
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert!(bits(&got.max_weight) == bits(&want.max_weight));
    // The views queued behind each other (what the adaptive step runs), with a renderer
    // that must grow mid-queue: the same statistics; warm, one submission per view and
    // one drain.
    let mut queued = Renderer::new(&ctx).unwrap();
    queued.set_chunk_size(40);
    for warm in [false, true] {
        pass.begin(n).unwrap();
        let c0 = ctx.queue_counters();
        pass.add_views(&mut queued, &gpu, &cams, 1).unwrap();
        let c = ctx.queue_counters() - c0;
        let q = pass.read().unwrap();
        println!("queued views (warm {warm}): {c:?}");
        assert!(bits(&q.max_weight) == bits(&want.max_weight), "warm {warm}");
        assert!(
            bits(&q.min_interval) == bits(&want.min_interval),
            "warm {warm}"
        );
        if warm {
            assert_eq!((c.submits, c.fence_waits), (cams.len() as u64, 1));
        } else {
            assert!(
                c.submits > cams.len() as u64,
                "the test must regrow mid-queue"
            );
        }
    }
    assert!(bits(&got.min_interval) == bits(&want.min_interval));
    assert!(want.max_weight.iter().filter(|&&w| w > 0.0).count() > 10);

    // SVRaster's rule (each view's weights in a buffer of their own, supersampled
    // frames): a queue that regrows mid-way gives the statistics of views added one at
    // a time to a renderer with room to spare.
    pass.set_rule(StatsRule {
        supersample: 1.25,
        visible: StatsVisible::Weight,
    })
    .unwrap();
    pass.begin(n).unwrap();
    for cam in &cams {
        pass.add_view(&mut big, &gpu, cam, 1).unwrap();
    }
    let want_w = pass.read().unwrap();
    let mut regrow = Renderer::new(&ctx).unwrap();
    regrow.set_chunk_size(40);
    pass.begin(n).unwrap();
    let c0 = ctx.queue_counters();
    pass.add_views(&mut regrow, &gpu, &cams, 1).unwrap();
    let c = ctx.queue_counters() - c0;
    let got_w = pass.read().unwrap();
    assert!(
        c.submits > cams.len() as u64,
        "the test must regrow mid-queue"
    );
    assert!(bits(&got_w.max_weight) == bits(&want_w.max_weight));
    assert!(bits(&got_w.min_interval) == bits(&want_w.min_interval));
    // The rule changes the statistics (supersampled weights; hidden voxels keep +inf).
    assert!(bits(&got_w.max_weight) != bits(&want.max_weight));
    finish(&ctx);
}

/// SVRaster's statistics rule (docs/PARITY.md item 9) against the reference: frames
/// supersampled ×1.5, so the max weights are those of the supersampled rays, while the
/// intervals stay `max(z, near) / fx` at each view's own resolution; and a view shows
/// only the voxels it gives a non-zero weight (`StatsVisible::Weight`), not every
/// voxel it lists (`Entries`, checked here supersampled too).
#[test]
fn supersampled_statistics_and_weight_visibility_match_reference() {
    let ctx = context();
    let mut pass = StatsPass::new(&ctx).unwrap();
    let ss = 1.5f32;
    // Voxels a view lists but gives no weight (hidden behind others): the two rules
    // differ only there.
    let mut hidden = 0usize;
    for visible in [StatsVisible::Weight, StatsVisible::Entries] {
        for seed in 0..3u64 {
            let mut renderer = Renderer::new(&ctx).unwrap();
            let mut rng = Rng(7070 + seed);
            let max_level = [5, 8, 12][seed as usize];
            let scene = random_scene(&mut rng, max_level, (seed % 3) as u32);
            let n = scene.num_voxels();
            let gpu = SceneGpu::upload(&ctx, &scene).unwrap();
            let cams = [
                camera_outside(&mut rng, &scene, 32, 24),
                camera_inside(&mut rng, &scene, 28, 20),
            ];
            let what = format!("{visible:?}, seed {seed} (levels ≤{max_level}, {n} voxels)");
            pass.set_rule(StatsRule {
                supersample: ss,
                visible,
            })
            .unwrap();
            pass.begin(n as u32).unwrap();
            let mut weights = vec![WeightBounds::default(); n];
            let mut intervals = vec![IntervalBounds::default(); n];
            for cam in &cams {
                pass.add_view(&mut renderer, &gpu, cam, 1).unwrap();
                let rw = (cam.width as f64 * ss as f64).round() as u32;
                let rh = (cam.height as f64 * ss as f64).round() as u32;
                let rcam = cam.resized(rw, rh);
                let mut view = vec![WeightBounds::default(); n];
                reference_max_weights(&scene, &rcam, 1, &mut view);
                for (w, v) in weights.iter_mut().zip(&view) {
                    w.lo = w.lo.max(v.lo);
                    w.hi = w.hi.max(v.hi);
                }
                let listed = |i: usize| reference_visibility(&scene, &rcam, i);
                match visible {
                    StatsVisible::Weight => {
                        hidden += (0..n)
                            .filter(|&i| listed(i) == Vis::Yes && view[i].hi == 0.0)
                            .count();
                        fold_intervals(&scene, cam, &mut intervals, |i| {
                            if view[i].lo > 0.0 {
                                Vis::Yes
                            } else if view[i].hi > 0.0 {
                                Vis::Maybe
                            } else {
                                Vis::No
                            }
                        });
                    }
                    StatsVisible::Entries => fold_intervals(&scene, cam, &mut intervals, listed),
                }
            }
            let stats = pass.read().unwrap();
            let r = compare(&stats, &weights, &intervals, &what);
            println!("{what}: {r:?}");
            assert!(r.weighted > 10, "{what}: too few voxels contribute: {r:?}");
            assert!(r.visible > 10, "{what}: too few visible voxels: {r:?}");
            assert!(
                r.vis_ambiguous * 10 <= r.voxels,
                "{what}: too many ambiguous visibilities: {r:?}"
            );
        }
    }
    println!("voxels listed but unweighted in a view: {hidden}");
    assert!(hidden > 10, "the test must tell the two view sets apart");
    assert!(pass
        .set_rule(StatsRule {
            supersample: 0.5,
            visible: StatsVisible::Weight
        })
        .is_err());
    finish(&ctx);
}
