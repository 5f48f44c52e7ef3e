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
use svraster::gpu::Timestamps;
use svraster::raster::{FrameOutputs, Image, RenderOptions, Renderer};
use svraster::scene::SceneGpu;
use svraster::scene::{octpath_from_ijk, Scene};

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
    // Chunks split the unsegmented walk (CPU devices, `--segments 0`); a GPU's default
    // segments never run short of them, so both renderers walk unsegmented here (the
    // comparison is bit for bit) and the small chunks make frames incomplete on every
    // device.
    let mut one = Renderer::new(&ctx).unwrap();
    one.set_segment_entries(0);
    let want: Vec<Image> = cams
        .iter()
        .map(|c| one.render(&gpu, c, &opts).unwrap().0)
        .collect();
    let mut r = Renderer::new(&ctx).unwrap();
    r.set_chunk_size(40);
    r.set_segment_entries(0);
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
            // Each frame waits at most for the one before it; on a fast device that
            // one may be done already (the H200 waited 5 times of 7 in the full suite).
            assert!(c.throttle_waits < cams.len() as u64, "{c:?}");
        }
    }
    // Timed and still queued (`bench render`): the same images, each frame's own stage
    // times (the stages a waited, timestamped frame has), and no extra waits.
    let mut waited = Timestamps::new(&ctx, 32).unwrap();
    r.render_to_device(&gpu, &cams[0], &opts, Some(&mut waited))
        .unwrap();
    let labels: Vec<String> = waited.stages().unwrap().into_iter().map(|s| s.0).collect();
    assert!(labels.len() >= 3, "{labels:?}");
    let mut pools = [
        Timestamps::new(&ctx, 32).unwrap(),
        Timestamps::new(&ctx, 32).unwrap(),
    ];
    let c0 = ctx.queue_counters();
    let mut timed = 0;
    r.render_each_timed(
        &gpu,
        &cams,
        &opts,
        &mut pools,
        |i, img, st, times| -> svraster::Result<()> {
            assert!(st.complete(), "frame {i}: {st:?}");
            assert!(img.rgb == want[i].rgb, "frame {i}: colours differ (timed)");
            let names: Vec<&String> = times.iter().map(|s| &s.0).collect();
            assert_eq!(names, labels.iter().collect::<Vec<_>>(), "frame {i}");
            assert!(
                times.iter().all(|s| s.1.is_finite() && s.1 >= 0.0),
                "{times:?}"
            );
            assert!(
                times.iter().map(|s| s.1).sum::<f64>() > 0.0,
                "frame {i}: {times:?}"
            );
            timed += 1;
            Ok(())
        },
    )
    .unwrap();
    let c = ctx.queue_counters() - c0;
    assert_eq!(timed, cams.len());
    assert_eq!(c.submits, cams.len() as u64, "timed: {c:?}");
    assert_eq!(c.fence_waits, 1, "timed frames drain the queue once: {c:?}");
    finish(&ctx);
}

mod against_reference;
mod frame_mean;
mod image_edges;

/// Pipelines are made once per context: a second renderer, backward or sort on the
/// same context makes none (on lavapipe each one is a shader compile; the suite's
/// gradient tests make hundreds of renderers), and renders the same image.
#[test]
fn renderers_made_again_reuse_the_context_s_pipelines() {
    use svraster::sort::RadixSort;
    use svraster::train::backward::{Backward, Reduction};
    let ctx = context();
    assert_eq!(
        ctx.pipelines_made(),
        0,
        "a fresh context has made no pipeline"
    );
    let mut rng = Rng(4242);
    let scene = random_scene(&mut rng, 6, 1);
    let gpu = SceneGpu::upload(&ctx, &scene).unwrap();
    let cam = camera_outside(&mut rng, &scene, 24, 16);
    let opts = RenderOptions::default();
    let (first, _) = Renderer::new(&ctx)
        .unwrap()
        .render(&gpu, &cam, &opts)
        .unwrap();
    let made = ctx.pipelines_made();
    assert!(made > 5, "the renderer's kernels: {made}");
    let (again, _) = Renderer::new(&ctx)
        .unwrap()
        .render(&gpu, &cam, &opts)
        .unwrap();
    assert_eq!(
        ctx.pipelines_made(),
        made,
        "a second renderer made pipelines"
    );
    let bits = |img: &Image| -> Vec<u32> {
        img.rgb
            .iter()
            .flatten()
            .chain(&img.alpha)
            .map(|v| v.to_bits())
            .collect()
    };
    assert!(bits(&first) == bits(&again));
    drop(Backward::with_reduction(&ctx, Reduction::Ordered).unwrap());
    let with_backward = ctx.pipelines_made();
    assert!(with_backward > made);
    drop(Backward::with_reduction(&ctx, Reduction::Ordered).unwrap());
    drop(RadixSort::new(&ctx, 1024).unwrap());
    let with_sort = ctx.pipelines_made();
    drop(RadixSort::new(&ctx, 1024).unwrap());
    drop(Backward::with_reduction(&ctx, Reduction::Ordered).unwrap());
    assert_eq!(ctx.pipelines_made(), with_sort);
    finish(&ctx);
}
