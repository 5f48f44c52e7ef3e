//! The adaptive pass's per-voxel statistics (paper §3.2, Eq. 7; §3.2.2 pruning) against
//! an f64 CPU reference written for clarity.
//!
//! * Max weight: every pixel's ray is walked exactly as `reference::render_pixel` does
//!   (entry-distance order, α < 1e-5 skipped, α clamped, K samples, early stop at
//!   T < 1e-4) and each voxel keeps its largest T·α. The reference gives each weight as
//!   a range [lo, hi]: α is evaluated on the nominal ray and on rays perturbed by the
//!   f32 rounding of the renderer's ray (direction tilted by a few ε, segment ends moved
//!   by a few ε of the distance), the transmittance is carried as a range, and
//!   threshold decisions within 0.1 % of the early-stop or skip threshold are taken both
//!   ways. The GPU value must lie within WEIGHT_TOL (1e-6) of the range; a voxel no ray
//!   composites must read exactly 0. Most ranges are narrower than 1e-5; rays clipping the
//!   edge of a very dense voxel give wide ones (f32 cannot resolve those α): the test
//!   reports how many are wider than 1e-5 and fails if that is half of them or more.
//! * Min interval: per view, the reference reproduces the preprocess's visibility test
//!   in f64 (near-clipped box projected to a pixel rectangle, widened by 0.01 px, must
//!   cover a pixel centre) and calls it ambiguous when moving the rectangle's edges by
//!   a rounding margin changes the answer; the GPU's min over views must lie between the
//!   min over surely-visible views and the min over possibly-visible ones, within
//!   INTERVAL_TOL relative to `max(|centre − origin|, near) / fx` (f32 rounding of the
//!   camera-relative centre scales with its distance, not with its depth z).

use crate::common;

use common::reference::{self, alpha_of, pixel_ray, EARLY_STOP_T, MIN_ALPHA};
use common::{camera_inside, camera_outside, context, finish, random_scene, Rng};
use svraster::adapt::stats::{StatsPass, StatsRule, StatsVisible, VoxelStats};
use svraster::data::Camera;
use svraster::raster::{Image, RenderOptions, Renderer};
use svraster::scene::SceneGpu;
use svraster::scene::{octpath_from_ijk, Scene};

/// Max abs distance of a max weight from the reference range (the f32 rounding of α's
/// exp and of the products, which the range does not model).
const WEIGHT_TOL: f64 = 1e-6;
/// Ranges wider than this are counted as ill-conditioned (reported, and limited to half
/// of the contributing voxels so the comparison keeps its teeth).
const WEIGHT_LOOSE: f64 = 1e-5;
/// Max error of a min interval relative to max(|centre − origin|, near) / fx.
const INTERVAL_TOL: f64 = 1e-5;
/// Relative band around the early-stop and α-skip thresholds where f32 may decide
/// otherwise.
const THRESHOLD_BAND: f64 = 1e-3;

/// Reference max weight per voxel as an interval [lo, hi] (see `reference_max_weights`).
#[derive(Clone, Copy, Debug, Default)]
struct WeightBounds {
    lo: f64,
    hi: f64,
}

/// f32 rounding of the renderer's ray, in units of ε = 2^-23: the direction (the
/// normalised pixel direction, rotated) is off by a few ε radians, and the segment ends
/// of the camera-relative ray–box test by a few ε of the distance.
const RAY_DIR_EPS: f64 = 4.0;
const SEGMENT_EPS: f64 = 4.0;

/// One voxel on one pixel's ray with the range of α the f32 renderer may compute.
struct Hit {
    voxel: usize,
    entry: f64,
    exit: f64,
    alpha_lo: f64,
    alpha_hi: f64,
}

/// Voxels on pixel (px, py)'s ray in compositing order, each with α evaluated exactly
/// as `reference::render_pixel` does (K samples, clamp), as a range over the nominal
/// f64 ray and rays perturbed by the f32 rounding: the direction tilted by
/// ±RAY_DIR_EPS·ε along the camera's x and y axes, and each segment's ends moved by
/// ±SEGMENT_EPS·ε·exit. A voxel only some of those rays hit may or may not be hit in f32
/// (its α range starts at 0). A ray clipping a dense voxel's edge has an α that f32
/// cannot resolve, and its range says so.
fn pixel_hits(scene: &Scene, cam: &Camera, px: u32, py: u32, k: usize) -> Vec<Hit> {
    let eps = f32::EPSILON as f64;
    let (o, d, norm) = pixel_ray(cam, px as f64 + 0.5, py as f64 + 0.5);
    let t_near = cam.near * norm;
    let (ex, ey) = (cam.rotate([1.0, 0.0, 0.0]), cam.rotate([0.0, 1.0, 0.0]));
    let tilt = |e: [f64; 3], s: f64| {
        let h = RAY_DIR_EPS * eps * s;
        reference::normalize(std::array::from_fn(|a| d[a] + h * e[a]))
    };
    let dirs = [
        d,
        tilt(ex, 1.0),
        tilt(ex, -1.0),
        tilt(ey, 1.0),
        tilt(ey, -1.0),
    ];
    let mut hits = Vec::new();
    for i in 0..scene.num_voxels() {
        let lo = scene.voxel_min(i);
        let size = scene.voxel_size(i);
        let hi = [lo[0] + size, lo[1] + size, lo[2] + size];
        let g: [f64; 8] = std::array::from_fn(|c| scene.geo[scene.corners[i][c] as usize] as f64);
        let mut hit: Option<Hit> = None;
        let mut missed = false;
        for (j, &dj) in dirs.iter().enumerate() {
            let (a, b) = reference::ray_aabb(lo, hi, o, dj);
            let a = a.max(t_near);
            if a > b {
                missed = true;
                continue;
            }
            let delta = SEGMENT_EPS * eps * b.abs();
            let alpha = |a: f64, b: f64| {
                if a < b {
                    alpha_of(&g, lo, size, o, dj, a, b, k).0
                } else {
                    0.0
                }
            };
            let h = hit.get_or_insert(Hit {
                voxel: i,
                entry: a,
                exit: b,
                alpha_lo: f64::INFINITY,
                alpha_hi: 0.0,
            });
            if j == 0 {
                (h.entry, h.exit) = (a, b);
            }
            for al in [
                alpha(a, b),
                alpha(a + delta, b - delta),
                alpha(a - delta, b + delta),
            ] {
                h.alpha_lo = h.alpha_lo.min(al);
                h.alpha_hi = h.alpha_hi.max(al);
            }
        }
        if let Some(mut h) = hit {
            if missed {
                h.alpha_lo = 0.0;
            }
            hits.push(h);
        }
    }
    hits.sort_by(|x, y| x.entry.total_cmp(&y.entry).then(x.exit.total_cmp(&y.exit)));
    hits
}

/// Folds the max weights of every pixel of `cam` into `out`: each pixel's voxels are
/// walked as `reference::render_pixel` does (α < 1e-5 skipped, early stop at T < 1e-4)
/// with the α ranges of `pixel_hits` carried as a transmittance range, and threshold
/// decisions within THRESHOLD_BAND of either threshold taken both ways.
fn reference_max_weights(scene: &Scene, cam: &Camera, k: usize, out: &mut [WeightBounds]) {
    for py in 0..cam.height {
        for px in 0..cam.width {
            // Transmittance before the current voxel: [t_lo, t_hi].
            let (mut t_lo, mut t_hi) = (1.0f64, 1.0f64);
            for h in pixel_hits(scene, cam, px, py, k) {
                let skip_sure = h.alpha_hi < MIN_ALPHA * (1.0 - THRESHOLD_BAND);
                let skip_maybe = h.alpha_lo < MIN_ALPHA * (1.0 + THRESHOLD_BAND);
                if skip_sure {
                    continue;
                }
                // The renderer may already have stopped when t_lo is near the early-stop
                // threshold: then only the upper bound grows.
                let stop_maybe = t_lo < EARLY_STOP_T * (1.0 + THRESHOLD_BAND);
                let w = &mut out[h.voxel];
                if !skip_maybe && !stop_maybe {
                    w.lo = w.lo.max(t_lo * h.alpha_lo);
                }
                w.hi = w.hi.max(t_hi * h.alpha_hi);
                t_lo *= 1.0 - h.alpha_hi;
                t_hi *= 1.0 - if skip_maybe { 0.0 } else { h.alpha_lo };
                // Surely stopped after this voxel.
                if t_hi < EARLY_STOP_T * (1.0 - THRESHOLD_BAND) {
                    break;
                }
            }
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Vis {
    No,
    Yes,
    Maybe,
}

/// The preprocess's visibility of voxel `i` (a non-empty pixel rectangle), in f64.
fn reference_visibility(scene: &Scene, cam: &Camera, i: usize) -> Vis {
    let lo = scene.voxel_min(i);
    let s = scene.voxel_size(i);
    let cc: Vec<[f64; 3]> = (0..8)
        .map(|c| {
            cam.world_to_camera([
                lo[0] + if c & 4 != 0 { s } else { 0.0 },
                lo[1] + if c & 2 != 0 { s } else { 0.0 },
                lo[2] + if c & 1 != 0 { s } else { 0.0 },
            ])
        })
        .collect();
    let near = cam.near;
    let max_z = cc.iter().map(|p| p[2]).fold(f64::NEG_INFINITY, f64::max);
    let z_band = 1e-5 * (1.0 + s + cc.iter().map(|p| p[2].abs()).fold(0.0, f64::max));
    if max_z < near - z_band {
        return Vis::No;
    }
    let near_ambiguous = max_z < near + z_band;
    // Screen bounds of the part in front of the near plane.
    let mut blo = [f64::INFINITY; 2];
    let mut bhi = [f64::NEG_INFINITY; 2];
    let mut project = |p: [f64; 3]| {
        let uv = [cam.fx * p[0] / p[2] + cam.cx, cam.fy * p[1] / p[2] + cam.cy];
        for a in 0..2 {
            blo[a] = blo[a].min(uv[a]);
            bhi[a] = bhi[a].max(uv[a]);
        }
    };
    for p in &cc {
        if p[2] >= near {
            project(*p);
        }
    }
    for c in 0..8usize {
        for b in [1usize, 2, 4] {
            if c & b != 0 {
                continue;
            }
            let (p0, p1) = (cc[c], cc[c | b]);
            if (p0[2] >= near) != (p1[2] >= near) {
                let t = (near - p0[2]) / (p1[2] - p0[2]);
                let mut p: [f64; 3] = std::array::from_fn(|a| p0[a] + t * (p1[a] - p0[a]));
                p[2] = near;
                project(p);
            }
        }
    }
    if blo[0] > bhi[0] {
        // Every corner behind the plane within the band.
        return Vis::Maybe;
    }
    let (w, h) = (cam.width as f64, cam.height as f64);
    let covers = |lo: [f64; 2], hi: [f64; 2]| {
        let flo = [
            (lo[0] - 0.5 - 0.01).ceil().clamp(0.0, w),
            (lo[1] - 0.5 - 0.01).ceil().clamp(0.0, h),
        ];
        let fhi = [
            (hi[0] - 0.5 + 0.01).floor().clamp(-1.0, w - 1.0),
            (hi[1] - 0.5 + 0.01).floor().clamp(-1.0, h - 1.0),
        ];
        flo[0] <= fhi[0] && flo[1] <= fhi[1]
    };
    let mag = blo.iter().chain(&bhi).map(|v| v.abs()).fold(0.0, f64::max);
    let m = 2e-3 + 3e-5 * mag;
    let shrunk = covers([blo[0] + m, blo[1] + m], [bhi[0] - m, bhi[1] - m]);
    let grown = covers([blo[0] - m, blo[1] - m], [bhi[0] + m, bhi[1] + m]);
    match (shrunk, grown, near_ambiguous) {
        (true, true, false) => Vis::Yes,
        (false, false, _) => Vis::No,
        _ => Vis::Maybe,
    }
}

/// Reference min interval per voxel: (min over possibly-visible views, min over
/// surely-visible views, scale = max(|centre − origin|, near) / fx of the best view).
#[derive(Clone, Copy, Debug)]
struct IntervalBounds {
    lo: f64,
    hi: f64,
    scale: f64,
    maybe: bool,
    /// `hi` comes from a view where the centre is closer than the near plane.
    clamped: bool,
}

impl Default for IntervalBounds {
    fn default() -> Self {
        IntervalBounds {
            lo: f64::INFINITY,
            hi: f64::INFINITY,
            scale: 0.0,
            maybe: false,
            clamped: false,
        }
    }
}

fn reference_intervals(scene: &Scene, cam: &Camera, out: &mut [IntervalBounds]) {
    fold_intervals(scene, cam, out, |i| reference_visibility(scene, cam, i));
}

/// Folds `cam`'s intervals (`max(z, near) / fx` at its own resolution) into `out` for
/// the voxels `vis` says it shows.
fn fold_intervals(
    scene: &Scene,
    cam: &Camera,
    out: &mut [IntervalBounds],
    vis: impl Fn(usize) -> Vis,
) {
    let o = cam.origin();
    let fwd = [cam.c2w[0][2], cam.c2w[1][2], cam.c2w[2][2]];
    for (i, b) in out.iter_mut().enumerate() {
        let vis = vis(i);
        if vis == Vis::No {
            continue;
        }
        let rel = reference::sub(scene.voxel_center(i), o);
        let z = reference::dot(rel, fwd);
        let interval = z.max(cam.near) / cam.fx;
        let scale = reference::dot(rel, rel).sqrt().max(cam.near) / cam.fx;
        b.scale = b.scale.max(scale);
        b.lo = b.lo.min(interval);
        if vis == Vis::Yes {
            if interval < b.hi {
                b.hi = interval;
                b.clamped = z < cam.near;
            }
        } else {
            b.maybe = true;
        }
    }
}

#[derive(Debug, Default, Clone, Copy)]
struct Report {
    weight_err: f64,
    interval_err: f64,
    voxels: usize,
    weighted: usize,
    /// Widest reference interval, and voxels whose interval is wider than WEIGHT_TOL
    /// (ill-conditioned in f32: checked only loosely).
    weight_width: f64,
    weight_loose: usize,
    /// Voxels whose min interval is the near plane's (z < near).
    near_clamped: usize,
    visible: usize,
    invisible: usize,
    vis_ambiguous: usize,
}

/// Compares GPU statistics with the reference bounds, returning the errors.
fn compare(
    stats: &VoxelStats,
    weights: &[WeightBounds],
    intervals: &[IntervalBounds],
    what: &str,
) -> Report {
    let n = weights.len();
    assert_eq!(stats.max_weight.len(), n, "{what}: max weight count");
    assert_eq!(stats.min_interval.len(), n, "{what}: interval count");
    let mut r = Report {
        voxels: n,
        ..Default::default()
    };
    for i in 0..n {
        let g = stats.max_weight[i] as f64;
        assert!(g.is_finite() && g >= 0.0, "{what}: voxel {i} weight {g}");
        let wb = weights[i];
        let e = if g < wb.lo {
            wb.lo - g
        } else if g > wb.hi {
            g - wb.hi
        } else {
            0.0
        };
        r.weight_err = r.weight_err.max(e);
        assert!(
            e <= WEIGHT_TOL,
            "{what}: voxel {i} max weight {g} vs reference [{}, {}]",
            wb.lo,
            wb.hi
        );
        if wb.hi > 0.0 {
            r.weighted += 1;
        }
        if wb.hi == 0.0 {
            // No ray (nominal or perturbed) composites it: exactly 0.
            assert!(g == 0.0, "{what}: voxel {i} max weight {g}, reference 0");
        }
        if wb.hi - wb.lo > WEIGHT_LOOSE {
            r.weight_loose += 1;
        }
        r.weight_width = r.weight_width.max(wb.hi - wb.lo);

        let gi = stats.min_interval[i] as f64;
        let ib = intervals[i];
        if ib.maybe {
            r.vis_ambiguous += 1;
        }
        if ib.lo.is_infinite() {
            // Never (possibly) visible: must stay +inf, and never have contributed.
            assert!(
                gi.is_infinite() && gi > 0.0,
                "{what}: voxel {i} invisible in every view but interval {gi}"
            );
            r.invisible += 1;
            continue;
        }
        if ib.hi.is_finite() {
            r.visible += 1;
        }
        if ib.clamped {
            r.near_clamped += 1;
        }
        // A voxel that contributed a weight was visible.
        if g > 0.0 {
            assert!(
                gi.is_finite(),
                "{what}: voxel {i} has weight {g} but no interval"
            );
        }
        let e = if gi < ib.lo {
            (ib.lo - gi) / ib.scale
        } else if gi > ib.hi {
            if ib.hi.is_infinite() {
                // Only ambiguous views: +inf is allowed only if none showed it.
                0.0
            } else {
                (gi - ib.hi) / ib.scale
            }
        } else {
            0.0
        };
        r.interval_err = r.interval_err.max(e);
        assert!(
            e <= INTERVAL_TOL,
            "{what}: voxel {i} min interval {gi} vs reference [{}, {}] (scale {})",
            ib.lo,
            ib.hi,
            ib.scale
        );
    }
    r
}

mod max_weights;
