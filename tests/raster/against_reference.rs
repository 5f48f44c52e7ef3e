use super::*;

#[test]
fn matches_reference_on_random_multilevel_scenes() {
    let ctx = context();
    let mut r = Renderer::new(&ctx).unwrap();
    let mut total = Errors::default();
    for seed in 0..8u64 {
        let mut rng = Rng(1000 + seed);
        let degree = (seed % 4) as u32;
        let k = 1 + (seed % 3) as usize;
        let max_level = [3, 6, 10, 16][(seed % 4) as usize];
        let scene = random_scene(&mut rng, max_level, degree);
        for (ci, cam) in [
            camera_outside(&mut rng, &scene, 45, 31),
            camera_inside(&mut rng, &scene, 38, 29),
        ]
        .iter()
        .enumerate()
        {
            let what = format!(
                "seed {seed} (levels ≤{max_level}, {} voxels, SH {degree}, K {k}) camera {ci}",
                scene.num_voxels()
            );
            let img = render(&mut r, &ctx, &scene, cam, k as u32);
            let refs = reference::render(&scene, cam, k);
            let hit = refs.iter().filter(|p| p.hits > 0).count();
            assert!(hit > 0, "{what}: the test view shows nothing");
            let e = compare(&img, &refs, &what);
            assert_within(&e, &what);
            total = total.max(e);
        }
    }
    println!("all random scenes: {total:?}");
    finish(&ctx);
}

/// GPUs choose each frame's segment length from its tile count
/// (`raster::auto_segment_entries`): fewer tiles, shorter segments, at most the longest
/// allowed; a frame renders exactly as with that length fixed.
#[test]
fn segment_length_follows_the_frame_tile_count() {
    use svraster::raster::auto_segment_entries as auto;
    // 100², 200², 300², 400², 600² and a 64-tile frame at the H200's 640-tile scale.
    assert_eq!(auto(49, 2048), 256);
    assert_eq!(auto(169, 2048), 512);
    assert_eq!(auto(361, 2048), 1024);
    assert_eq!(auto(625, 2048), 2048);
    assert_eq!(auto(1444, 2048), 2048);
    assert_eq!(auto(64, 4096), 512);
    assert_eq!(auto(1, 128), 128);
    assert_eq!(auto(5000, 0), 0);
    let ctx = context();
    let mut rng = Rng(4242);
    let scene = random_scene(&mut rng, 6, 1);
    let gpu = SceneGpu::upload(&ctx, &scene).unwrap();
    let mut r = Renderer::new(&ctx).unwrap();
    r.set_segment_entries_auto(2048);
    // 2048, unless the device's chunks bound segments to less.
    let longest = r.segment_entries();
    assert!(longest > 0);
    let opts = RenderOptions::default();
    for (w, h) in [(45u32, 31u32), (300, 200)] {
        let cam = camera_outside(&mut rng, &scene, w, h);
        let (img, st) = r.render(&gpu, &cam, &opts).unwrap();
        assert!(st.complete(), "{w}×{h}: {st:?}");
        let want = auto(st.tiles, longest);
        assert_eq!(r.segment_entries(), want, "{w}×{h}: {} tiles", st.tiles);
        let mut fixed = Renderer::new(&ctx).unwrap();
        fixed.set_segment_entries(want);
        let (same, _) = fixed.render(&gpu, &cam, &opts).unwrap();
        assert!(img.rgb == same.rgb && img.alpha == same.alpha && img.depth == same.depth);
        println!("{w}×{h}: {} tiles, segments of {want}", st.tiles);
    }
    finish(&ctx);
}

/// Segmented compositing (a tile's list cut into segments walked by separate
/// workgroups, merged in depth order; "Segments" in raster_params.glsl) renders what
/// the sequential walk renders up to rounding, and what the f64 reference renders as
/// closely, from one-entry segments (every contributor alone) up, with K = 1..3.
#[test]
#[allow(clippy::needless_range_loop)]
fn segmented_frames_match_the_reference() {
    let ctx = context();
    let mut off = Renderer::new(&ctx).unwrap();
    off.set_segment_entries(0);
    let mut worst_diff = 0.0f64;
    let mut total = Errors::default();
    for (i, seg) in [1u32, 2, 5, 16].into_iter().enumerate() {
        let mut r = Renderer::new(&ctx).unwrap();
        r.set_segment_entries(seg);
        assert_eq!(r.segment_entries(), seg);
        // Frames whose longest list spans more than two segments.
        let mut spanning = 0;
        for seed in 0..3u64 {
            let mut rng = Rng(3000 + 10 * i as u64 + seed);
            let max_level = [3, 6, 10][seed as usize];
            let scene = random_scene(&mut rng, max_level, (seed % 4) as u32);
            let k = 1 + ((seed + i as u64) % 3) as u32;
            for (ci, cam) in [
                camera_outside(&mut rng, &scene, 45, 31),
                camera_inside(&mut rng, &scene, 38, 29),
            ]
            .iter()
            .enumerate()
            {
                let what = format!("segments of {seg}, seed {seed}, K {k}, camera {ci}");
                let gpu = SceneGpu::upload(&ctx, &scene).unwrap();
                let opts = RenderOptions {
                    samples: k,
                    supersample: 1.0,
                };
                let (img, st) = r.render(&gpu, cam, &opts).unwrap();
                assert!(st.complete(), "{what}: {st:?}");
                spanning += usize::from(st.max_tile_entries > 2 * seg);
                let (seq, _) = off.render(&gpu, cam, &opts).unwrap();
                let refs = reference::render(&scene, cam, k as usize);
                // Against the sequential walk: rounding only (sums regrouped by
                // segment), except where the reference decides the median within
                // 1e-3 of T = 0.5.
                for p in 0..refs.len() {
                    let mut d = (img.alpha[p] - seq.alpha[p]).abs();
                    for c in 0..3 {
                        d = d.max((img.rgb[p][c] - seq.rgb[p][c]).abs());
                        d = d.max((img.normal[p][c] - seq.normal[p][c]).abs());
                    }
                    d = d.max((img.depth[p] - seq.depth[p]).abs() / (1.0 + seq.depth[p].abs()));
                    if !refs[p].median_ambiguous {
                        let m = seq.depth_median[p];
                        d = d.max((img.depth_median[p] - m).abs() / (1.0 + m.abs()));
                    }
                    assert!(
                        d <= 1e-5,
                        "{what}: pixel {p} differs from the sequential walk by {d}"
                    );
                    worst_diff = worst_diff.max(d as f64);
                }
                // Against the reference: within the stated bounds, or no further
                // from it than the sequential walk is.
                let e = compare(&img, &refs, &what);
                let e_seq = compare(&seq, &refs, &what);
                let slack = |on: f64, seq: f64, tol: f64| on <= tol.max(seq + 1e-5);
                assert!(
                    slack(e.rgb, e_seq.rgb, RGB_TOL),
                    "{what}: {e:?} vs {e_seq:?}"
                );
                assert!(
                    slack(e.alpha, e_seq.alpha, RGB_TOL),
                    "{what}: {e:?} vs {e_seq:?}"
                );
                assert!(
                    slack(e.depth, e_seq.depth, DEPTH_TOL),
                    "{what}: {e:?} vs {e_seq:?}"
                );
                assert!(
                    slack(e.median, e_seq.median, DEPTH_TOL),
                    "{what}: {e:?} vs {e_seq:?}"
                );
                assert!(
                    slack(e.normal, e_seq.normal, NORMAL_TOL),
                    "{what}: {e:?} vs {e_seq:?}"
                );
                total = total.max(e);
            }
        }
        assert!(
            spanning >= 3,
            "segments of {seg}: only {spanning} frames span several"
        );
    }
    println!("segmented frames: largest difference from the sequential walk {worst_diff:.2e}; against the reference {total:?}");
    finish(&ctx);
}

/// A tile whose list fits one segment composites exactly as without segments: with
/// segments longer than any list, every channel of the image is the same bits.
#[test]
fn one_segment_per_tile_is_the_unsegmented_frame() {
    let ctx = context();
    let mut off = Renderer::new(&ctx).unwrap();
    off.set_segment_entries(0);
    let mut on = Renderer::new(&ctx).unwrap();
    on.set_segment_entries(1 << 20);
    for r in [&mut off, &mut on] {
        r.set_outputs(FrameOutputs {
            normals: true,
            distortion: true,
            distortion_contracted: false,
        });
    }
    let bits = |im: &Image| -> Vec<u32> {
        let f = im.rgb.iter().chain(im.normal.iter()).flatten();
        let g = im.alpha.iter().chain(&im.depth).chain(&im.depth_median);
        f.chain(g).map(|x| x.to_bits()).collect()
    };
    for seed in 0..3u64 {
        let mut rng = Rng(3100 + seed);
        let scene = random_scene(&mut rng, [3, 6, 10][seed as usize], 2);
        let cam = camera_outside(&mut rng, &scene, 45, 31);
        let k = 1 + seed as u32;
        let a = render(&mut off, &ctx, &scene, &cam, k);
        let b = render(&mut on, &ctx, &scene, &cam, k);
        assert!(
            a.alpha.iter().any(|&x| x > 0.0),
            "seed {seed}: nothing rendered"
        );
        assert!(
            bits(&a) == bits(&b),
            "seed {seed}: one segment per tile differs"
        );
    }
    finish(&ctx);
}

/// The tile walk's path for any subgroup size (what 32- and 64-lane GPUs run) renders
/// the same images as the 8-lane register transpose, bit for bit: same visit sets, same
/// order per pixel.
#[test]
fn generic_walk_renders_what_the_8_lane_walk_renders() {
    let ctx = context();
    let mut fast = Renderer::new(&ctx).unwrap();
    let mut generic = Renderer::new(&ctx).unwrap();
    generic.set_generic_walk(true);
    for seed in 0..4u64 {
        let mut rng = Rng(2000 + seed);
        let max_level = [3, 6, 10, 16][seed as usize];
        let scene = random_scene(&mut rng, max_level, (seed % 4) as u32);
        for cam in [
            camera_outside(&mut rng, &scene, 45, 31),
            camera_inside(&mut rng, &scene, 38, 29),
        ] {
            let k = 1 + (seed % 3) as u32;
            let a = render(&mut fast, &ctx, &scene, &cam, k);
            let b = render(&mut generic, &ctx, &scene, &cam, k);
            assert!(
                a.alpha.iter().any(|&x| x > 0.0),
                "seed {seed}: nothing rendered"
            );
            let bits = |im: &svraster::raster::Image| -> Vec<u32> {
                let f = im.rgb.iter().chain(im.normal.iter()).flatten();
                let g = im.alpha.iter().chain(&im.depth).chain(&im.depth_median);
                f.chain(g).map(|x| x.to_bits()).collect()
            };
            assert!(
                bits(&a) == bits(&b),
                "seed {seed}: the generic walk's image differs"
            );
        }
    }
    finish(&ctx);
}

/// Frames recorded without normals or distortion sums (`Renderer::set_outputs`) keep
/// every other channel bit for bit; their normal image reads zero.
#[test]
fn optional_outputs_off_change_no_other_channel() {
    let ctx = context();
    let mut all = Renderer::new(&ctx).unwrap();
    all.set_outputs(FrameOutputs {
        normals: true,
        distortion: true,
        distortion_contracted: false,
    });
    let mut none = Renderer::new(&ctx).unwrap();
    none.set_outputs(FrameOutputs {
        normals: false,
        distortion: false,
        distortion_contracted: false,
    });
    for seed in 0..3u64 {
        let mut rng = Rng(3000 + seed);
        let scene = random_scene(&mut rng, [3, 8, 16][seed as usize], (seed % 4) as u32);
        let cam = camera_outside(&mut rng, &scene, 45, 31);
        let k = 1 + seed as u32;
        let a = render(&mut all, &ctx, &scene, &cam, k);
        let b = render(&mut none, &ctx, &scene, &cam, k);
        let bits = |im: &svraster::raster::Image| -> Vec<u32> {
            let f = im.rgb.iter().flatten();
            let g = im.alpha.iter().chain(&im.depth).chain(&im.depth_median);
            f.chain(g).map(|x| x.to_bits()).collect()
        };
        assert!(
            a.alpha.iter().any(|&x| x > 0.0),
            "seed {seed}: nothing rendered"
        );
        assert!(
            bits(&a) == bits(&b),
            "seed {seed}: a frame without the optional outputs differs"
        );
        assert!(
            a.normal.iter().flatten().any(|&x| x != 0.0),
            "seed {seed}: no normal with normals on"
        );
        assert!(
            b.normal.iter().flatten().all(|&x| x == 0.0),
            "seed {seed}: a normal with normals off"
        );
    }
    finish(&ctx);
}

/// Per-tile order for a ray's sign equals the order of entry distances.
#[test]
fn tile_order_is_entry_distance_order() {
    let ctx = context();
    let mut r = Renderer::new(&ctx).unwrap();
    let mut checked = 0usize;
    for seed in 0..6u64 {
        let mut rng = Rng(77 + seed);
        let scene = random_scene(&mut rng, 8, 0);
        let cam = if seed % 2 == 0 {
            camera_outside(&mut rng, &scene, 64, 48)
        } else {
            camera_inside(&mut rng, &scene, 64, 48)
        };
        let _ = render(&mut r, &ctx, &scene, &cam, 1);
        let lists = r.tile_lists().unwrap();
        let tiles_x = cam.width.div_ceil(16);
        for py in (0..cam.height).step_by(3) {
            for px in (0..cam.width).step_by(3) {
                let (o, d, norm) = reference::pixel_ray(&cam, px as f64 + 0.5, py as f64 + 0.5);
                let sign = (d[0] < 0.0) as u32 * 4 + (d[1] < 0.0) as u32 * 2 + (d[2] < 0.0) as u32;
                let tile = (py / 16) * tiles_x + px / 16;
                let mut last = f64::NEG_INFINITY;
                let mut seen = std::collections::HashSet::new();
                for &v in &lists[tile as usize] {
                    if v >> 29 != sign {
                        continue;
                    }
                    let i = (v & 0x1fff_ffff) as usize;
                    assert!(seen.insert(i), "voxel {i} twice in one tile/sign list");
                    let lo = scene.voxel_min(i);
                    let s = scene.voxel_size(i);
                    let (a, b) = reference::ray_aabb(lo, [lo[0] + s, lo[1] + s, lo[2] + s], o, d);
                    let a = a.max(cam.near * norm);
                    if a < b {
                        assert!(
                            a >= last - 1e-9,
                            "seed {seed} pixel ({px},{py}): voxel {i} entered at {a} after one at {last}"
                        );
                        last = a;
                        checked += 1;
                    }
                }
                // Every voxel the ray hits is in the list.
                for i in 0..scene.num_voxels() {
                    let lo = scene.voxel_min(i);
                    let s = scene.voxel_size(i);
                    let (a, b) = reference::ray_aabb(lo, [lo[0] + s, lo[1] + s, lo[2] + s], o, d);
                    if a.max(cam.near * norm) < b - 1e-9 * (1.0 + b.abs()) {
                        assert!(
                            seen.contains(&i),
                            "seed {seed} pixel ({px},{py}): hit voxel {i} missing from its tile list"
                        );
                    }
                }
            }
        }
    }
    assert!(checked > 1000, "only {checked} ordered hits checked");
    finish(&ctx);
}

#[test]
fn axis_parallel_rays_with_signed_zeros() {
    let ctx = context();
    let mut r = Renderer::new(&ctx).unwrap();
    let scene = block_scene([0.0, 0.0, 0.0], 3.0, 3, -2.0);
    // Odd image sizes put the centre pixel's ray exactly on the optical axis; axis-aligned
    // cameras give exact ±0 components; eyes on voxel boundary planes (x = 0, y = 0.375
    // are level-3 boundaries) test the half-open slab rule.
    let mut worst = Errors::default();
    let mut zero_rays = 0;
    for (eye, target, up) in [
        ([0.0, 0.0, 5.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
        ([0.3, 0.375, -4.0], [0.3, 0.375, 0.0], [0.0, -1.0, 0.0]),
        ([6.0, 0.2, 0.1], [0.0, 0.2, 0.1], [0.0, 0.0, 1.0]),
        ([0.1, -5.0, 0.0], [0.1, 0.0, 0.0], [1.0, 0.0, 0.0]),
        ([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]),
    ] {
        let cam = Camera::look_at(eye, target, up, 0.9, 17, 9);
        for py in 0..cam.height {
            for px in 0..cam.width {
                let (_, d, _) = reference::pixel_ray(&cam, px as f64 + 0.5, py as f64 + 0.5);
                zero_rays += d.iter().filter(|v| **v == 0.0).count();
            }
        }
        let img = render(&mut r, &ctx, &scene, &cam, 2);
        let refs = reference::render(&scene, &cam, 2);
        let e = compare(&img, &refs, &format!("eye {eye:?}"));
        assert_within(&e, &format!("axis-parallel eye {eye:?}"));
        worst = worst.max(e);
    }
    assert!(
        zero_rays > 20,
        "only {zero_rays} zero direction components exercised"
    );
    println!("axis-parallel: {worst:?}, {zero_rays} zero components");
    finish(&ctx);
}

#[test]
fn camera_inside_a_voxel_and_near_plane() {
    let ctx = context();
    let mut r = Renderer::new(&ctx).unwrap();
    // Level-2 voxels (0.75 wide): the camera sits inside one, looking through it.
    let scene = block_scene([0.0, 0.0, 0.0], 3.0, 2, -1.0);
    let mut rng = Rng(9);
    for _ in 0..4 {
        let eye = [
            rng.range(-1.2, 1.2),
            rng.range(-1.2, 1.2),
            rng.range(-1.2, 1.2),
        ];
        let d = rng.dir();
        let cam = Camera::look_at(
            eye,
            [eye[0] + d[0], eye[1] + d[1], eye[2] + d[2]],
            rng.dir(),
            1.4,
            33,
            25,
        );
        let img = render(&mut r, &ctx, &scene, &cam, 3);
        let refs = reference::render(&scene, &cam, 3);
        let e = compare(&img, &refs, "inside");
        assert_within(&e, &format!("camera inside at {eye:?}"));
    }
    finish(&ctx);
}

#[test]
fn level16_voxels_far_from_the_origin() {
    let ctx = context();
    let mut r = Renderer::new(&ctx).unwrap();
    let mut rng = Rng(31);
    let mut scene = random_scene(&mut rng, 16, 2);
    scene.center = [1000.25, -2000.5, 500.125];
    // Look at the deepest voxel from close by, so level-16 voxels cover pixels.
    let deepest = (0..scene.num_voxels())
        .max_by_key(|&i| scene.octlevel[i])
        .unwrap();
    assert_eq!(scene.octlevel[deepest], 16);
    let c = scene.voxel_center(deepest);
    let s = scene.voxel_size(deepest);
    for dir in [[1.0, 0.3, 0.2], [-0.2, -1.0, 0.5]] {
        let n: f64 = dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2];
        let n = n.sqrt();
        let eye = [
            c[0] - 60.0 * s * dir[0] / n,
            c[1] - 60.0 * s * dir[1] / n,
            c[2] - 60.0 * s * dir[2] / n,
        ];
        let mut cam = Camera::look_at(eye, c, [0.0, 0.0, 1.0], 0.3, 32, 24);
        cam.near = 1e-4;
        let img = render(&mut r, &ctx, &scene, &cam, 1);
        let refs = reference::render(&scene, &cam, 1);
        let deep_hits = refs.iter().filter(|p| p.hits > 0).count();
        assert!(deep_hits > 10, "the level-16 voxels are not in view");
        let e = compare(&img, &refs, "far level 16");
        assert_within(&e, "level-16 voxels at |x| ~ 2000");
    }
    finish(&ctx);
}

/// Tiles whose entries mostly miss most of their pixels: a few hundred voxels of a few
/// pixels each, scattered over 3×3 tiles. Each subgroup must visit only the entries whose
/// rectangle meets its pixel block (the work counters show it), and the image must still
/// match the f64 reference (a skipped entry a pixel needs would show there).
#[test]
fn sparse_tiles_walk_only_what_their_pixels_need() {
    let ctx = context();
    let mut r = Renderer::new(&ctx).unwrap();
    r.set_counters(true).unwrap();
    let mut rng = Rng(0x5a_0001);
    for (i, k) in [1u32, 2, 3].into_iter().enumerate() {
        let scene = scattered_scene(&mut rng, 300, 4, i as u32);
        let cam = Camera::look_at(
            [0.3, 0.2 + 0.1 * i as f64, 3.2],
            [0.1, -0.2, 0.05],
            [0.0, 1.0, 0.0],
            0.9,
            48,
            40,
        );
        let img = render(&mut r, &ctx, &scene, &cam, k);
        let refs = reference::render(&scene, &cam, k as usize);
        assert_within(&compare(&img, &refs, "sparse tiles"), "sparse tiles");
        let c = r.counters().unwrap().expect("counters on").forward;
        let hits: usize = refs.iter().map(|p| p.hits).sum();
        println!(
            "K={k}: {c:?}; reference ray-voxel hits {hits}; full walk / trips {:.1}",
            c.full_walk_trips as f64 / c.trips as f64
        );
        assert!(c.trips > 0 && c.useful_trips > 0, "{c:?}");
        assert!(
            c.trips_per_useful() <= 2.0,
            "trips per useful trip {:.2} > 2",
            c.trips_per_useful()
        );
        assert!(
            c.full_walk_trips >= 4 * c.trips,
            "the walk should skip most (subgroup, entry) pairs: {c:?}"
        );
        assert!(c.pairs >= c.crossings && c.crossings >= c.contributions);
        // The compositing body runs for the subgroup when any lane's pixel crosses the
        // voxel (at most twice a useful trip: two pixels per lane); a walk over each
        // lane's own crossings would run it at most that often, and at least the
        // crossings spread over the lanes.
        let lanes = u64::from(ctx.info().subgroup_size);
        assert!(
            c.body_runs <= 2 * c.useful_trips && c.body_runs > 0,
            "body runs: {c:?}"
        );
        assert!(
            c.lane_max_crossings <= c.body_runs && c.crossings <= lanes * c.lane_max_crossings,
            "lane maxima: {c:?}"
        );
        // Every ray-voxel crossing of the reference is composited or tested (rays that
        // stopped early walk fewer): crossings within 1 % of the reference's hits.
        let rel = (c.crossings as f64 - hits as f64).abs() / hits as f64;
        assert!(
            rel <= 0.01,
            "crossings {} vs reference hits {hits}",
            c.crossings
        );
    }
    finish(&ctx);
}

/// A tile whose list holds ~393 000 entries: a column of 2 × 65 536 level-16 voxels seen
/// end-on (the centre pixel's ray runs along one column). Lavapipe stops any
/// invocation's loops after 65 535 iterations, so this only passes if compositing is
/// split into chunks correctly (state carried between dispatches).
#[test]
fn tile_list_longer_than_the_loop_limit() {
    let ctx = context();
    let mut r = Renderer::new(&ctx).unwrap();
    let mut paths = Vec::new();
    for i in [32768u32, 32769] {
        for k in 0..65536u32 {
            paths.push(octpath_from_ijk([i, 32768, k], 16));
        }
    }
    let levels = vec![16u8; paths.len()];
    // explin(-4.55) ≈ 6.5e-3: α ≈ 3e-5 per voxel, above the 1e-5 skip threshold, and
    // T ≈ 0.14 after one column, so no early stop.
    let mut scene = Scene::from_voxels([0.0; 3], 3.0, 0, paths, levels, -4.55).unwrap();
    for (i, c) in scene.sh0.iter_mut().enumerate() {
        let k = (i % 65536) as f32 / 65536.0;
        *c = [k * 3.0 - 1.5, 1.0 - k * 2.0, 0.3];
    }
    scene.background = [0.1, 0.2, 0.3];
    let e = 2.0e-5;
    let cam = Camera::look_at([e, e, -3.0], [e, e, 0.0], [0.0, 1.0, 0.0], 0.05, 17, 17);
    let gpu = SceneGpu::upload(&ctx, &scene).unwrap();
    let (img, stats) = r.render(&gpu, &cam, &RenderOptions::default()).unwrap();
    println!("{stats:?}");
    assert!(stats.max_tile_entries > 100_000, "{stats:?}");
    assert!(stats.chunks > 1 || !ctx.info().loop_limit());
    let refs = reference::render(&scene, &cam, 1);
    // The centre pixel's subgroup visits every entry on its ray (65 536 of them, more
    // than one invocation's loop limit): the walk is chunked like the list.
    r.set_counters(true).unwrap();
    let (img2, _) = r.render(&gpu, &cam, &RenderOptions::default()).unwrap();
    assert_eq!(img2.rgb, img.rgb, "counting changes nothing");
    let c = r.counters().unwrap().expect("counters on").forward;
    assert!(c.trips >= 65536 && c.contributions >= 65536, "{c:?}");
    let centre = (8 * 17 + 8) as usize;
    assert_eq!(
        refs[centre].hits, 65536,
        "the centre ray runs along one column"
    );
    assert!(refs[centre].alpha > 0.5 && refs[centre].alpha < 0.99);
    let err = compare(&img, &refs, "long tile");
    assert_within(&err, "tile list of ~393k entries");
    finish(&ctx);
}
