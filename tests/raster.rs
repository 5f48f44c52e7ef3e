//! The forward rasterizer against the f64 reference (tests/common/reference.rs).
//!
//! Stated bounds (max abs error per pixel, f32 GPU vs f64 reference): rgb and alpha
//! ≤ RGB_TOL, depth ≤ DEPTH_TOL·(1 + depth), normal ≤ NORMAL_TOL, median depth ≤
//! DEPTH_TOL·(1 + depth) except where the reference decides it within 1e-3 of T = 0.5.

use crate::common;

use common::forward::{
    assert_within, compare, pixel, render, Errors, DEPTH_TOL, NORMAL_TOL, RGB_TOL,
};
use common::reference::{self, RefPixel};
use common::{camera_inside, camera_outside, context, finish, random_scene, scattered_scene, Rng};
use svraster::data::Camera;
use svraster::raster::{FrameOutputs, Image, RenderOptions, Renderer};
use svraster::scene::SceneGpu;
use svraster::scene::{octpath_from_ijk, Scene};

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
    });
    let mut none = Renderer::new(&ctx).unwrap();
    none.set_outputs(FrameOutputs {
        normals: false,
        distortion: false,
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

/// A dense scene of a few levels with solid densities, for the extreme-camera tests.
fn block_scene(center: [f32; 3], extent: f32, level: u32, geo: f32) -> Scene {
    let n = 1u32 << level;
    let mut paths = Vec::new();
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                if (i + j + k) % 3 != 0 {
                    paths.push(octpath_from_ijk([i, j, k], level));
                }
            }
        }
    }
    let levels = vec![level as u8; paths.len()];
    let mut s = Scene::from_voxels(center, extent, 1, paths, levels, geo).unwrap();
    let mut rng = Rng(5);
    for (gi, g) in s.geo.iter_mut().enumerate() {
        *g = geo + (gi % 7) as f32 * 0.3 - 1.0 + rng.range(-0.1, 0.1) as f32;
    }
    for c in s.sh0.iter_mut() {
        *c = [
            rng.unit() as f32,
            rng.unit() as f32 - 0.5,
            -(rng.unit() as f32),
        ];
    }
    for v in s.shs.iter_mut() {
        *v = rng.range(-0.3, 0.3) as f32;
    }
    s.background = [0.2, 0.4, 0.9];
    s
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

#[test]
fn image_sizes_from_1x1_to_4096x4096() {
    let ctx = context();
    let mut r = Renderer::new(&ctx).unwrap();
    let mut rng = Rng(4242);
    let scene = random_scene(&mut rng, 16, 1);
    assert_eq!(scene.max_level(), 16);
    let base = camera_outside(&mut rng, &scene, 64, 64);
    let gpu = SceneGpu::upload(&ctx, &scene).unwrap();
    for (w, h) in [(1, 1), (17, 9), (1, 33), (4096, 4096)] {
        let cam = base.resized(w, h);
        let (img, stats) = r.render(&gpu, &cam, &RenderOptions::default()).unwrap();
        assert_eq!((img.width, img.height), (w, h));
        // Up to 400 pixels (all of a small image) against the reference.
        let mut prng = Rng(w as u64 * 7 + h as u64);
        let n = (w * h).min(400);
        let mut e = Errors::default();
        for s in 0..n {
            let (px, py) = if w * h <= 400 {
                (s % w, s / w)
            } else {
                (prng.below(w as u64) as u32, prng.below(h as u64) as u32)
            };
            let rp = reference::render_pixel(&scene, &cam, px as f64 + 0.5, py as f64 + 0.5, 1);
            let i = (py * w + px) as usize;
            e = e.max(compare(&pixel(&img, i), &[rp], "size"));
        }
        assert_within(
            &e,
            &format!(
                "{w}×{h} ({} tiles, sort bits {})",
                stats.tiles, stats.sort_bits
            ),
        );
    }
    // One pixel column more than 4096 needs more tiles than 64-bit keys leave room for
    // next to level-16 Morton codes.
    let err = r
        .render(&gpu, &base.resized(4097, 4096), &RenderOptions::default())
        .unwrap_err()
        .to_string();
    assert!(err.contains("tiles") && err.contains("level 16"), "{err}");
    finish(&ctx);
}

#[test]
fn empty_scene_renders_background() {
    let ctx = context();
    let mut r = Renderer::new(&ctx).unwrap();
    let mut scene = Scene::from_voxels([0.0; 3], 2.0, 2, vec![], vec![], 0.0).unwrap();
    scene.background = [0.25, 0.5, 1.0];
    let cam = Camera::look_at([0.0, 0.0, 4.0], [0.0; 3], [0.0, 1.0, 0.0], 0.8, 23, 19);
    let gpu = SceneGpu::upload(&ctx, &scene).unwrap();
    let (img, stats) = r.render(&gpu, &cam, &RenderOptions::default()).unwrap();
    assert_eq!(stats.entries, 0);
    for i in 0..img.rgb.len() {
        assert_eq!(img.rgb[i], [0.25, 0.5, 1.0]);
        assert_eq!(img.alpha[i], 0.0);
        assert_eq!(img.depth[i], 0.0);
    }
    finish(&ctx);
}

/// The reference's anti-aliasing downsample (tent filter of radius = scale).
fn reference_downsample(src: &[RefPixel], sw: u32, sh: u32, w: u32, h: u32) -> Vec<RefPixel> {
    let (sx, sy) = (sw as f64 / w as f64, sh as f64 / h as f64);
    let (rx, ry) = (sx.max(1.0), sy.max(1.0));
    let mut out = Vec::new();
    for oy in 0..h {
        for ox in 0..w {
            let (cx, cy) = ((ox as f64 + 0.5) * sx, (oy as f64 + 0.5) * sy);
            let mut acc = RefPixel::default();
            let mut wsum = 0.0;
            for y in 0..sh {
                let wy = (1.0 - (y as f64 + 0.5 - cy).abs() / ry).max(0.0);
                for x in 0..sw {
                    let wx = (1.0 - (x as f64 + 0.5 - cx).abs() / rx).max(0.0);
                    let wgt = wx * wy;
                    if wgt == 0.0 {
                        continue;
                    }
                    let p = &src[(y * sw + x) as usize];
                    for c in 0..3 {
                        acc.rgb[c] += wgt * p.rgb[c];
                        acc.normal[c] += wgt * p.normal[c];
                    }
                    acc.alpha += wgt * p.alpha;
                    acc.depth += wgt * p.depth;
                    acc.depth_median += wgt * p.depth_median;
                    acc.median_ambiguous |= p.median_ambiguous;
                    wsum += wgt;
                }
            }
            for c in 0..3 {
                acc.rgb[c] /= wsum;
                acc.normal[c] /= wsum;
            }
            acc.alpha /= wsum;
            acc.depth /= wsum;
            acc.depth_median /= wsum;
            out.push(acc);
        }
    }
    out
}

#[test]
fn supersampling_matches_reference_downsample() {
    let ctx = context();
    let mut r = Renderer::new(&ctx).unwrap();
    let mut rng = Rng(606);
    let scene = random_scene(&mut rng, 8, 2);
    let cam = camera_outside(&mut rng, &scene, 30, 22);
    let gpu = SceneGpu::upload(&ctx, &scene).unwrap();
    for ss in [1.5f32, 2.0, 3.0] {
        let (img, stats) = r
            .render(
                &gpu,
                &cam,
                &RenderOptions {
                    samples: 1,
                    supersample: ss,
                },
            )
            .unwrap();
        assert_eq!((img.width, img.height), (30, 22));
        let (rw, rh) = (stats.render_width, stats.render_height);
        assert_eq!(rw, (30.0 * ss).round() as u32);
        let hi = reference::render(&scene, &cam.resized(rw, rh), 1);
        let refs = reference_downsample(&hi, rw, rh, 30, 22);
        let e = compare(&img, &refs, "ss");
        assert_within(&e, &format!("supersample {ss}"));
    }
    finish(&ctx);
}

/// Small composite chunks and a too-small entry capacity: the renderer must flag the
/// shortfalls, grow, and produce exactly the image of a renderer with enough room.
#[test]
fn chunking_and_capacity_growth_give_identical_frames() {
    let ctx = context();
    let mut rng = Rng(808);
    let scene = block_scene([0.1, -0.2, 0.3], 2.5, 5, -1.5);
    let cam = Camera::look_at(
        [2.1, 0.8, 1.8],
        [0.1, -0.2, 0.3],
        [0.0, 0.0, 1.0],
        1.3,
        800,
        600,
    );
    let gpu = SceneGpu::upload(&ctx, &scene).unwrap();

    let mut big = Renderer::new(&ctx).unwrap();
    big.set_chunk_size(1 << 20);
    big.reserve_entries(4 << 20).unwrap();
    let (want, s_big) = big.render(&gpu, &cam, &RenderOptions::default()).unwrap();
    assert_eq!(s_big.chunks, 1);

    let mut small = Renderer::new(&ctx).unwrap();
    small.set_chunk_size(50);
    let cap0 = {
        small
            .prepare(&gpu, &cam, &RenderOptions::default())
            .unwrap();
        small.entry_capacity()
    };
    let (got, s) = small.render(&gpu, &cam, &RenderOptions::default()).unwrap();
    println!(
        "entries {} (initial capacity {cap0}), chunks {}, longest tile {}",
        s.entries, s.chunks, s.max_tile_entries
    );
    assert!(
        s.entries > cap0 as u64,
        "the test must overflow the initial capacity"
    );
    assert!(small.entry_capacity() as u64 >= s.entries);
    assert!(s.chunks > 1, "the test must need several chunks");
    assert_eq!(got.rgb, want.rgb);
    assert_eq!(got.alpha, want.alpha);
    assert_eq!(got.depth, want.depth);
    assert_eq!(got.depth_median, want.depth_median);
    assert_eq!(got.normal, want.normal);
    // And a sample of pixels against the reference.
    let mut e = Errors::default();
    for _ in 0..150 {
        let (px, py) = (rng.below(800) as u32, rng.below(600) as u32);
        let rp = reference::render_pixel(&scene, &cam, px as f64 + 0.5, py as f64 + 0.5, 1);
        let i = (py * 800 + px) as usize;
        e = e.max(compare(&pixel(&got, i), &[rp], "grown"));
    }
    assert_within(&e, "grown renderer");
    finish(&ctx);
}

/// The two hard limits of the entry encoding are refused up front with one clear error
/// (README: Numerical limits): pixel rectangles pack each coordinate in 16 bits (at most
/// 65 535 pixels per render edge) and entry values keep the voxel id in 29 bits.
/// Frames queued behind each other (`render_each`, what `render` and `eval` use) give
/// exactly the frames rendered one by one, including frames that come out incomplete
/// (small chunks, small entry capacity) while the next one is queued; a warm pass is
/// one submission per frame and one drain in all.
#[test]
fn queued_frames_match_frames_rendered_one_by_one() {
    let ctx = context();
    let scene = block_scene([0.1, -0.2, 0.3], 2.5, 5, -1.5);
    // Far and near views in turn: tile lists grow and shrink from frame to frame.
    let cams: Vec<Camera> = [3.2, 1.5, 4.5, 1.2, 2.0, 5.5, 1.8, 2.6]
        .iter()
        .enumerate()
        .map(|(i, &d)| {
            let a = i as f64 * 0.7;
            Camera::look_at(
                [0.1 + d * a.cos(), -0.2 + d * a.sin(), 0.3 + 0.4 * d],
                [0.1, -0.2, 0.3],
                [0.0, 0.0, 1.0],
                1.1,
                96 + 8 * i as u32,
                72,
            )
        })
        .collect();
    let gpu = SceneGpu::upload(&ctx, &scene).unwrap();
    let opts = RenderOptions {
        samples: 1,
        supersample: 1.5,
    };
    let mut one = Renderer::new(&ctx).unwrap();
    let want: Vec<Image> = cams
        .iter()
        .map(|c| one.render(&gpu, c, &opts).unwrap().0)
        .collect();
    let mut r = Renderer::new(&ctx).unwrap();
    r.set_chunk_size(40);
    for pass in 0..2 {
        let c0 = ctx.queue_counters();
        let grown0 = r.frames_grown();
        let mut order = Vec::new();
        r.render_each(&gpu, &cams, &opts, |i, img, st| -> svraster::Result<()> {
            assert!(st.complete(), "frame {i}: {st:?}");
            let w = &want[i];
            assert_eq!((img.width, img.height), (w.width, w.height), "frame {i}");
            assert!(img.rgb == w.rgb, "frame {i}: colours differ (pass {pass})");
            assert!(img.alpha == w.alpha, "frame {i}: alpha differs");
            assert!(img.depth == w.depth, "frame {i}: depth differs");
            assert!(
                img.depth_median == w.depth_median,
                "frame {i}: median differs"
            );
            order.push(i);
            Ok(())
        })
        .unwrap();
        let c = ctx.queue_counters() - c0;
        let grown = r.frames_grown() - grown0;
        println!("pass {pass}: {c:?}, {grown} frames rendered again");
        assert_eq!(order, (0..cams.len()).collect::<Vec<_>>());
        if pass == 0 {
            assert!(grown >= 2, "the small chunks must make frames incomplete");
        } else {
            assert_eq!(grown, 0);
            assert_eq!(c.submits, cams.len() as u64);
            assert_eq!(c.fence_waits, 1, "only the last frame drains the queue");
            assert_eq!(c.throttle_waits, cams.len() as u64 - 1);
        }
    }
    finish(&ctx);
}

#[test]
fn edge_and_voxel_id_limits_are_clear_errors() {
    let ctx = context();
    let mut r = Renderer::new(&ctx).unwrap();
    let mut rng = Rng(77);
    let scene = random_scene(&mut rng, 3, 0);
    let base = camera_outside(&mut rng, &scene, 16, 16);
    let mut gpu = SceneGpu::upload(&ctx, &scene).unwrap();
    let err = r
        .render(&gpu, &base.resized(65536, 1), &RenderOptions::default())
        .unwrap_err()
        .to_string();
    assert!(err.contains("65535"), "{err}");
    // 65 535 is accepted by the edge check (here: 65 535 × 1 renders).
    let (img, _) = r
        .render(&gpu, &base.resized(65535, 1), &RenderOptions::default())
        .unwrap();
    assert_eq!(img.width, 65535);
    gpu.voxels = svraster::scene::MAX_VOXELS as u32 + 1;
    let err = r
        .render(&gpu, &base, &RenderOptions::default())
        .unwrap_err()
        .to_string();
    assert!(err.contains("29-bit"), "{err}");
    finish(&ctx);
}
