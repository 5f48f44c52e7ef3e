//! The forward rasterizer against the f64 reference (tests/common/reference.rs).
//!
//! Stated bounds (max abs error per pixel, f32 GPU vs f64 reference): rgb and alpha
//! ≤ RGB_TOL, depth ≤ DEPTH_TOL·(1 + depth), normal ≤ NORMAL_TOL, median depth ≤
//! DEPTH_TOL·(1 + depth) except where the reference decides it within 1e-3 of T = 0.5.

mod common;

use common::reference::{self, RefPixel};
use common::{camera_inside, camera_outside, context, finish, random_scene, Rng};
use svraster::data::Camera;
use svraster::raster::{Image, RenderOptions, Renderer, SceneGpu};
use svraster::scene::{octpath_from_ijk, Scene};

const RGB_TOL: f64 = 1e-3;
const DEPTH_TOL: f64 = 1e-3;
const NORMAL_TOL: f64 = 1e-3;

#[derive(Default, Debug, Clone, Copy)]
struct Errors {
    rgb: f64,
    alpha: f64,
    depth: f64,
    median: f64,
    normal: f64,
    median_skipped: usize,
}

impl Errors {
    fn max(self, o: Errors) -> Errors {
        Errors {
            rgb: self.rgb.max(o.rgb),
            alpha: self.alpha.max(o.alpha),
            depth: self.depth.max(o.depth),
            median: self.median.max(o.median),
            normal: self.normal.max(o.normal),
            median_skipped: self.median_skipped + o.median_skipped,
        }
    }
}

fn compare(img: &Image, refs: &[RefPixel], what: &str) -> Errors {
    assert_eq!(img.rgb.len(), refs.len(), "{what}: pixel count");
    let mut e = Errors::default();
    for (i, r) in refs.iter().enumerate() {
        for c in 0..3 {
            e.rgb = e.rgb.max((img.rgb[i][c] as f64 - r.rgb[c]).abs());
            e.normal = e.normal.max((img.normal[i][c] as f64 - r.normal[c]).abs());
        }
        e.alpha = e.alpha.max((img.alpha[i] as f64 - r.alpha).abs());
        e.depth = e
            .depth
            .max((img.depth[i] as f64 - r.depth).abs() / (1.0 + r.depth.abs()));
        if r.median_ambiguous {
            e.median_skipped += 1;
        } else {
            e.median = e.median.max(
                (img.depth_median[i] as f64 - r.depth_median).abs() / (1.0 + r.depth_median.abs()),
            );
        }
        assert!(
            img.rgb[i].iter().all(|v| v.is_finite())
                && img.alpha[i].is_finite()
                && img.depth[i].is_finite()
                && img.depth_median[i].is_finite(),
            "{what}: non-finite output at pixel {i}"
        );
    }
    e
}

fn assert_within(e: &Errors, what: &str) {
    println!("{what}: {e:?}");
    assert!(e.rgb <= RGB_TOL, "{what}: rgb error {} > {RGB_TOL}", e.rgb);
    assert!(
        e.alpha <= RGB_TOL,
        "{what}: alpha error {} > {RGB_TOL}",
        e.alpha
    );
    assert!(
        e.depth <= DEPTH_TOL,
        "{what}: depth error {} > {DEPTH_TOL}",
        e.depth
    );
    assert!(
        e.median <= DEPTH_TOL,
        "{what}: median depth error {}",
        e.median
    );
    assert!(e.normal <= NORMAL_TOL, "{what}: normal error {}", e.normal);
}

fn render(
    r: &mut Renderer,
    ctx: &svraster::gpu::Context,
    scene: &Scene,
    cam: &Camera,
    k: u32,
) -> Image {
    let gpu = SceneGpu::upload(ctx, scene).expect("upload");
    let (img, stats) = r
        .render(
            &gpu,
            cam,
            &RenderOptions {
                samples: k,
                supersample: 1.0,
            },
        )
        .expect("render");
    assert!(stats.complete());
    img
}

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
