//! The f64 gradient reference (tests/common/reference_grad.rs) against finite
//! differences of its own forward, which is itself checked against the reference
//! renderer (tests/common/reference.rs). CPU only.
//!
//! Finite differences: parameter x, step h = FD_STEP·max(1, |x|) in f64, central
//! differences D(h) = (L(x+h) − L(x−h)) / 2h Richardson-extrapolated,
//! (4·D(h) − D(2h)) / 3 (truncation O(h⁴), so h can be large enough to keep rounding
//! noise ~1e-12·|L|/h small). A parameter is skipped (and counted) when the forward's
//! branch signature (alpha skip, early stop, alpha / local-alpha clamps, explin
//! branch, colour clamp, normal clamp) at x ± h or x ± 2h differs from the one at x:
//! there the loss is not differentiable on the stencil. Skips must stay below
//! MAX_SKIP_FRACTION of the parameters.
//!
//! Bound, per loss term t and parameter kind (geo, sh0, shs): with G = the largest
//! |fd| of that term over all checked parameters of that kind in that case,
//! |analytic − fd| ≤ GRAD_TOL·(|fd| + 1e-3·G + 1e-9), GRAD_TOL = 1e-6.
//! Measured (seed 7, 24 cases, 28 298 parameters, 11 skipped): worst
//! |analytic − fd| / (|fd| + 1e-3·G) is 8.3e-8 (shs, rgb term), ≤ 7.1e-8 for geo.
//!
//! Priority: ∂L_p/∂α_k by central differences on the alpha value itself
//! ([`AlphaNudge`]; L_p is quadratic in one alpha, so the difference is exact up to
//! rounding), |prio − fd| ≤ 1e-8·(fd + 1e-3·max fd); measured 4.7e-11.

use crate::common;

use common::reference::{self, render_pixel, voxel_rgb};
use common::reference_grad::{
    evaluate, grads, grads_with, loss, pixel_rays, AlphaNudge, LossSpec, Params, PixelRay,
    PixelWeights, RefGrads, NUM_TERMS, TERM_ALPHA, TERM_DEPTH, TERM_DIST, TERM_NAMES, TERM_NORMAL,
    TERM_POINT_RGB, TERM_RGB, TERM_T,
};
use common::{camera_inside, Rng};
use svraster::data::Camera;
use svraster::scene::{octpath_from_ijk, Scene};

const FD_STEP: f64 = 3e-4;
const GRAD_TOL: f64 = 1e-6;
const MAX_SKIP_FRACTION: f64 = 0.02;
const W: u32 = 12;
const H: u32 = 10;

/// A few dozen voxels that mostly tile the root cube: the 8 level-1 cells, each split
/// into level 2 with probability 0.35, each of those into level 3 with probability 0.1
/// (one level-3 chain forced), 15% of the leaves dropped.
fn dense_voxels(rng: &mut Rng) -> (Vec<u64>, Vec<u8>) {
    let (mut paths, mut levels) = (Vec::new(), Vec::new());
    let forced = (rng.below(8) as u32, rng.below(8) as u32);
    let child = |ijk: [u32; 3], c: u32| {
        [
            ijk[0] * 2 + (c >> 2 & 1),
            ijk[1] * 2 + (c >> 1 & 1),
            ijk[2] * 2 + (c & 1),
        ]
    };
    let mut leaf = |rng: &mut Rng, ijk: [u32; 3], l: u32| {
        if rng.unit() < 0.85 {
            paths.push(octpath_from_ijk(ijk, l));
            levels.push(l as u8);
        }
    };
    for c1 in 0..8 {
        let ijk1 = child([0, 0, 0], c1);
        if c1 != forced.0 && rng.unit() >= 0.35 {
            leaf(rng, ijk1, 1);
            continue;
        }
        for c2 in 0..8 {
            let ijk2 = child(ijk1, c2);
            if (c1, c2) != forced && rng.unit() >= 0.1 {
                leaf(rng, ijk2, 2);
                continue;
            }
            for c3 in 0..8 {
                leaf(rng, child(ijk2, c3), 3);
            }
        }
    }
    (paths, levels)
}

/// A small random multi-level scene (levels 1..=3, small extent) whose densities give a
/// mix of translucent and opaque voxels, both explin branches, some alpha clamps and
/// early stops; SH of `degree` with some colours clamped at 0.
fn grad_scene(rng: &mut Rng, degree: u32) -> Scene {
    let (paths, levels) = dense_voxels(rng);
    let center = [
        rng.range(-0.2, 0.2) as f32,
        rng.range(-0.2, 0.2) as f32,
        rng.range(-0.2, 0.2) as f32,
    ];
    let extent = rng.range(0.08, 0.2) as f32;
    let mut s = Scene::from_voxels(center, extent, degree, paths, levels, 0.0)
        .expect("random voxels are valid");
    for g in s.geo.iter_mut() {
        let u = rng.unit();
        *g = if u < 0.6 {
            rng.range(-8.0, 0.0)
        } else if u < 0.85 {
            rng.range(0.0, 4.0)
        } else {
            rng.range(4.0, 12.0)
        } as f32;
    }
    for c in s.sh0.iter_mut() {
        *c = [
            rng.range(-1.5, 1.5) as f32,
            rng.range(-1.5, 1.5) as f32,
            rng.range(-1.5, 1.5) as f32,
        ];
    }
    for v in s.shs.iter_mut() {
        *v = rng.range(-0.6, 0.6) as f32;
    }
    s.background = [rng.unit() as f32, rng.unit() as f32, rng.unit() as f32];
    s
}

/// As `camera_outside`, but the target offset scales with the scene (which is small
/// here, so that moderate densities give a mix of translucent and opaque voxels).
fn camera_outside_near(rng: &mut Rng, scene: &Scene, w: u32, h: u32) -> Camera {
    let c = scene.center.map(|v| v as f64);
    let e = scene.extent as f64;
    let d = rng.dir();
    let r = e * rng.range(1.2, 2.0);
    let eye = [c[0] + r * d[0], c[1] + r * d[1], c[2] + r * d[2]];
    let target = [
        c[0] + e * rng.range(-0.1, 0.1),
        c[1] + e * rng.range(-0.1, 0.1),
        c[2] + e * rng.range(-0.1, 0.1),
    ];
    Camera::look_at(eye, target, rng.dir(), rng.range(0.6, 1.2), w, h)
}

/// As `camera_outside_near` (the same random draws), moved back along the same direction
/// to distance 1 from the scene's centre, with the field of view narrowed to frame the
/// scene alike: its hits straddle ray distance 1, where SVRaster's contracted distortion
/// axis bends.
fn camera_at_distance_one(rng: &mut Rng, scene: &Scene, w: u32, h: u32) -> Camera {
    let c = scene.center.map(|v| v as f64);
    let e = scene.extent as f64;
    let d = rng.dir();
    let r = e * rng.range(1.2, 2.0);
    let eye = [c[0] + d[0], c[1] + d[1], c[2] + d[2]];
    let target = [
        c[0] + e * rng.range(-0.1, 0.1),
        c[1] + e * rng.range(-0.1, 0.1),
        c[2] + e * rng.range(-0.1, 0.1),
    ];
    let up = rng.dir();
    let fov = 2.0 * ((0.5 * rng.range(0.6, 1.2)).tan() * r).atan();
    Camera::look_at(eye, target, up, fov, w, h)
}

fn random_weights(rng: &mut Rng, n: usize) -> Vec<PixelWeights> {
    (0..n)
        .map(|_| PixelWeights {
            rgb: [
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
            ],
            alpha: rng.range(-1.0, 1.0),
            depth: rng.range(-1.0, 1.0),
            normal: [
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
            ],
            gt: [rng.unit(), rng.unit(), rng.unit()],
        })
        .collect()
}

fn random_spec(rng: &mut Rng) -> LossSpec {
    LossSpec {
        lambda_dist: rng.range(0.2, 2.0),
        lambda_r: rng.range(0.2, 2.0),
        lambda_t: rng.range(0.2, 2.0),
        lambda_t_inside: rng.range(0.2, 2.0),
        ..Default::default()
    }
}

/// The weights and spec with only term `t` kept (gt is kept: it only matters to the
/// per-point RGB term).
fn only_term(pix: &[PixelWeights], spec: &LossSpec, t: usize) -> (Vec<PixelWeights>, LossSpec) {
    let pix = pix
        .iter()
        .map(|p| PixelWeights {
            rgb: if t == TERM_RGB { p.rgb } else { [0.0; 3] },
            alpha: if t == TERM_ALPHA { p.alpha } else { 0.0 },
            depth: if t == TERM_DEPTH { p.depth } else { 0.0 },
            normal: if t == TERM_NORMAL { p.normal } else { [0.0; 3] },
            gt: p.gt,
        })
        .collect();
    let spec = LossSpec {
        lambda_dist: if t == TERM_DIST {
            spec.lambda_dist
        } else {
            0.0
        },
        lambda_r: if t == TERM_POINT_RGB {
            spec.lambda_r
        } else {
            0.0
        },
        lambda_r_colour: 0.0,
        dist_contracted: spec.dist_contracted,
        colour_straight: spec.colour_straight,
        alpha_straight: spec.alpha_straight,
        lambda_t: if t == TERM_T { spec.lambda_t } else { 0.0 },
        lambda_t_inside: if t == TERM_T {
            spec.lambda_t_inside
        } else {
            0.0
        },
        r_target_bilinear: false,
    };
    (pix, spec)
}

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / (1.0 + a.abs().max(b.abs()))
}

struct Case {
    name: String,
    scene: Scene,
    cam: Camera,
    k: usize,
    pix: Vec<PixelWeights>,
    spec: LossSpec,
}

/// SH degrees 0..=3 × K = 1, 2, 3 × a camera outside and one inside; the odd degrees
/// with the frame-mean background (`Scene::background_frame_mean`), which couples
/// every pixel's rgb term to every other's colour.
fn cases(seed: u64) -> Vec<Case> {
    let mut rng = Rng(seed);
    let mut out = Vec::new();
    for degree in 0..=3u32 {
        for k in 1..=3usize {
            for inside in [false, true] {
                let mut scene = grad_scene(&mut rng, degree);
                scene.background_frame_mean = degree % 2 == 1;
                let cam = if inside {
                    camera_inside(&mut rng, &scene, W, H)
                } else if k == 2 {
                    camera_at_distance_one(&mut rng, &scene, W, H)
                } else {
                    camera_outside_near(&mut rng, &scene, W, H)
                };
                let pix = random_weights(&mut rng, (W * H) as usize);
                let mut spec = random_spec(&mut rng);
                // SVRaster's contracted distortion axis in the K = 2 cases.
                spec.dist_contracted = k == 2;
                out.push(Case {
                    name: format!(
                        "degree {degree} K={k} {}{}{} ({} voxels)",
                        if inside { "inside" } else { "outside" },
                        if k == 2 {
                            ", contracted distortion"
                        } else {
                            ""
                        },
                        if scene.background_frame_mean {
                            ", frame-mean background"
                        } else {
                            ""
                        },
                        scene.num_voxels()
                    ),
                    scene,
                    cam,
                    k,
                    pix,
                    spec,
                });
            }
        }
    }
    out
}

/// The gradient forward reproduces the reference renderer's outputs (random linear
/// combinations of rgb, alpha, depth, normal per pixel), the distortion equals the
/// pairwise mip-NeRF 360 form Σ_ij w_i w_j |m_i − m_j| + 1/3 Σ w² δ, and the per-point
/// RGB loss equals its definition with the reference colour `voxel_rgb`.
#[test]
fn forward_matches_reference_renderer() {
    let mut worst = [0.0f64; 3];
    for c in cases(11) {
        let rays = pixel_rays(&c.scene, &c.cam);
        let ev = evaluate(
            &c.scene,
            &Params::of(&c.scene),
            &rays,
            c.k,
            &c.pix,
            &c.spec,
            None,
        );
        let refs = reference::render(&c.scene, &c.cam, c.k);
        let mut want = 0.0;
        let mut want_dist = 0.0;
        let mut want_r = 0.0;
        for (p, (r, w)) in refs.iter().zip(&c.pix).enumerate() {
            want += reference::dot(w.rgb, r.rgb)
                + w.alpha * r.alpha
                + w.depth * r.depth
                + reference::dot(w.normal, r.normal);
            let cs = &ev.contributors[p];
            let o = c.cam.origin();
            for (i, ci) in cs.iter().enumerate() {
                let wi = ci.t * ci.alpha;
                // The pairwise form on the distortion's axis: the ray distance, or
                // SVRaster's contraction x < 1 ? x : 2 − 1/x written out here.
                let axis = |x: f64| {
                    if c.spec.dist_contracted && x >= 1.0 {
                        2.0 - 1.0 / x
                    } else {
                        x
                    }
                };
                let mi = 0.5 * (axis(ci.a) + axis(ci.b));
                for cj in cs {
                    let mj = 0.5 * (axis(cj.a) + axis(cj.b));
                    want_dist += wi * cj.t * cj.alpha * (mi - mj).abs();
                }
                want_dist += wi * wi * (axis(ci.b) - axis(ci.a)) / 3.0;
                let rgb = voxel_rgb(&c.scene, ci.voxel, o);
                want_r += wi * (0..3).map(|ch| (rgb[ch] - w.gt[ch]).powi(2)).sum::<f64>() / 3.0;
                // Entries are in order of entry distance with disjoint segments.
                if i > 0 {
                    assert!(
                        cs[i - 1].b <= ci.a + 1e-12,
                        "{}: overlapping segments",
                        c.name
                    );
                }
            }
        }
        let got = ev.terms[TERM_RGB]
            + ev.terms[TERM_ALPHA]
            + ev.terms[TERM_DEPTH]
            + ev.terms[TERM_NORMAL];
        let e = [
            rel(got, want),
            rel(ev.terms[TERM_DIST], c.spec.lambda_dist * want_dist),
            rel(ev.terms[TERM_POINT_RGB], c.spec.lambda_r * want_r),
        ];
        for j in 0..3 {
            worst[j] = worst[j].max(e[j]);
        }
        assert!(
            e.iter().all(|&v| v < 1e-12),
            "{}: forward mismatch {e:?}",
            c.name
        );
        // Same outputs pixel by pixel for unit weights on one pixel.
        let p = (W * H / 2 + W / 2) as usize;
        let r = render_pixel(
            &c.scene,
            &c.cam,
            (p as u32 % W) as f64 + 0.5,
            (p as u32 / W) as f64 + 0.5,
            c.k,
        );
        let mut one = vec![PixelWeights::default(); (W * H) as usize];
        one[p].depth = 1.0;
        let d = loss(&c.scene, &c.cam, c.k, &one, &LossSpec::default());
        assert!(
            rel(d, r.depth) < 1e-13,
            "{}: depth {d} vs {}",
            c.name,
            r.depth
        );
    }
    println!("forward vs reference: max rel err (outputs, dist, point rgb) = {worst:?}");
}

/// `loss` with a single-term spec equals that term of the full evaluation, and `loss`
/// equals the sum of all terms and `grads(..).loss`.
#[test]
fn loss_is_the_sum_of_its_terms() {
    for c in cases(12).into_iter().step_by(5) {
        let rays = pixel_rays(&c.scene, &c.cam);
        let ev = evaluate(
            &c.scene,
            &Params::of(&c.scene),
            &rays,
            c.k,
            &c.pix,
            &c.spec,
            None,
        );
        for t in 0..NUM_TERMS {
            let (pix_t, spec_t) = only_term(&c.pix, &c.spec, t);
            let l = loss(&c.scene, &c.cam, c.k, &pix_t, &spec_t);
            assert!(
                rel(l, ev.terms[t]) < 1e-13,
                "{}: term {}",
                c.name,
                TERM_NAMES[t]
            );
            assert!(
                ev.terms[t] != 0.0,
                "{}: term {} is zero",
                c.name,
                TERM_NAMES[t]
            );
        }
        let l = loss(&c.scene, &c.cam, c.k, &c.pix, &c.spec);
        let g = grads(&c.scene, &c.cam, c.k, &c.pix, &c.spec);
        assert!(
            rel(l, ev.loss()) < 1e-13 && rel(g.loss, l) < 1e-13,
            "{}",
            c.name
        );
    }
}

/// Which parameter of [`Params`].
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Kind {
    Geo,
    Sh0,
    Shs,
}
const KINDS: [Kind; 3] = [Kind::Geo, Kind::Sh0, Kind::Shs];

fn param_count(p: &Params, kind: Kind) -> usize {
    match kind {
        Kind::Geo => p.geo.len(),
        Kind::Sh0 => p.sh0.len() * 3,
        Kind::Shs => p.shs.len(),
    }
}

fn param_mut(p: &mut Params, kind: Kind, j: usize) -> &mut f64 {
    match kind {
        Kind::Geo => &mut p.geo[j],
        Kind::Sh0 => &mut p.sh0[j / 3][j % 3],
        Kind::Shs => &mut p.shs[j],
    }
}

fn grad_of(g: &RefGrads, kind: Kind, j: usize) -> f64 {
    match kind {
        Kind::Geo => g.geo[j],
        Kind::Sh0 => g.sh0[j / 3][j % 3],
        Kind::Shs => g.shs[j],
    }
}

/// Central differences of every term at once (the terms are independent of each
/// other's weights) plus the total, Richardson-extrapolated from steps h and 2h:
/// (4·D(h) − D(2h))/3, error O(h⁴). None when a branch decision at x ± h or x ± 2h
/// differs from the one at x.
fn fd_terms(
    params: &Params,
    rays: &[PixelRay],
    c: &Case,
    base_sig: &[u8],
    kind: Kind,
    j: usize,
) -> Option<[f64; NUM_TERMS + 1]> {
    let mut p = params.clone();
    let x = *param_mut(&mut p, kind, j);
    let h = FD_STEP * x.abs().max(1.0);
    let mut eval_at = |v: f64| {
        *param_mut(&mut p, kind, j) = v;
        let e = evaluate(&c.scene, &p, rays, c.k, &c.pix, &c.spec, None);
        (e.signature == base_sig).then(|| {
            let mut t = [0.0; NUM_TERMS + 1];
            t[..NUM_TERMS].copy_from_slice(&e.terms);
            t[NUM_TERMS] = e.loss();
            t
        })
    };
    let (p1, m1) = (eval_at(x + h)?, eval_at(x - h)?);
    let (p2, m2) = (eval_at(x + 2.0 * h)?, eval_at(x - 2.0 * h)?);
    Some(std::array::from_fn(|t| {
        let d1 = (p1[t] - m1[t]) / (2.0 * h);
        let d2 = (p2[t] - m2[t]) / (4.0 * h);
        (4.0 * d1 - d2) / 3.0
    }))
}

/// Every parameter of every kind, every term separately and combined, K = 1, 2, 3, SH
/// degrees 0..=3, cameras outside and inside.
#[test]
fn gradients_match_finite_differences() {
    let names: Vec<&str> = TERM_NAMES.iter().copied().chain(["combined"]).collect();
    // Worst error (relative to the bound's scale) per term and kind over all cases.
    let mut worst = [[0.0f64; 3]; NUM_TERMS + 1];
    let (mut checked, mut skipped) = (0usize, 0usize);
    // Parameters with a clearly non-zero gradient, per term and kind (non-vacuity).
    let mut nonzero = [[0usize; 3]; NUM_TERMS + 1];
    for c in cases(7) {
        let params = Params::of(&c.scene);
        let rays = pixel_rays(&c.scene, &c.cam);
        let base = evaluate(&c.scene, &params, &rays, c.k, &c.pix, &c.spec, None);
        let an: Vec<RefGrads> = (0..=NUM_TERMS)
            .map(|t| {
                if t == NUM_TERMS {
                    grads_with(&c.scene, &params, &rays, c.k, &c.pix, &c.spec)
                } else {
                    let (pix_t, spec_t) = only_term(&c.pix, &c.spec, t);
                    grads_with(&c.scene, &params, &rays, c.k, &pix_t, &spec_t)
                }
            })
            .collect();
        let (mut case_checked, mut case_skipped) = (0, 0);
        for (ki, &kind) in KINDS.iter().enumerate() {
            let n = param_count(&params, kind);
            let mut fds = Vec::with_capacity(n);
            for j in 0..n {
                let fd = fd_terms(&params, &rays, &c, &base.signature, kind, j);
                match fd {
                    Some(fd) => {
                        case_checked += 1;
                        fds.push((j, fd));
                    }
                    None => case_skipped += 1,
                }
            }
            for t in 0..=NUM_TERMS {
                let gmax = fds.iter().map(|(_, fd)| fd[t].abs()).fold(0.0, f64::max);
                for &(j, ref fd) in &fds {
                    let a = grad_of(&an[t], kind, j);
                    let scale = fd[t].abs() + 1e-3 * gmax + 1e-9;
                    let e = (a - fd[t]).abs() / scale;
                    worst[t][ki] = worst[t][ki].max(e);
                    if fd[t].abs() > 1e-3 * gmax && fd[t].abs() > 1e-6 {
                        nonzero[t][ki] += 1;
                    }
                    assert!(
                        e <= GRAD_TOL,
                        "{}: {kind:?}[{j}] term {}: analytic {a:e} vs fd {:e} (rel err {e:e})",
                        c.name,
                        names[t],
                        fd[t]
                    );
                }
            }
        }
        println!(
            "{}: {case_checked} parameters checked, {case_skipped} skipped",
            c.name
        );
        checked += case_checked;
        skipped += case_skipped;
    }
    for t in 0..=NUM_TERMS {
        println!(
            "{:>10}: max |an − fd| / (|fd| + 1e-3·max|fd|)  geo {:.2e}  sh0 {:.2e}  shs {:.2e}   non-zero gradients geo {} sh0 {} shs {}",
            names[t], worst[t][0], worst[t][1], worst[t][2], nonzero[t][0], nonzero[t][1], nonzero[t][2]
        );
    }
    println!("{checked} checked, {skipped} skipped");
    assert!(
        (skipped as f64) < MAX_SKIP_FRACTION * (checked + skipped) as f64,
        "{skipped} of {} parameters skipped",
        checked + skipped
    );
    // Every term reaches geo; only rgb and per-point RGB reach the SH.
    for t in 0..=NUM_TERMS {
        assert!(
            nonzero[t][0] > 100,
            "{}: too few geo gradients checked",
            names[t]
        );
        let sh = matches!(t, TERM_RGB | TERM_POINT_RGB) || t == NUM_TERMS;
        for ki in 1..3 {
            if sh {
                assert!(
                    nonzero[t][ki] > 100,
                    "{}: too few SH gradients checked",
                    names[t]
                );
            } else {
                assert_eq!(
                    nonzero[t][ki], 0,
                    "{}: SH gradient from a geometry term",
                    names[t]
                );
            }
        }
    }
}

/// SVRaster's colour-only per-point RGB term (λ_c·Σ w |c − gt|², w held constant): its
/// reference gradient on the colours is the central difference, on the SH, of the
/// per-point RGB term's value with λ_R = 3λ_c (same sum, /3 in ours; w does not depend
/// on the SH), and it reaches neither the densities nor the priority.
#[test]
fn colour_only_point_rgb_matches_finite_differences_on_the_colours() {
    let lc = 0.7;
    let (mut worst, mut nonzero) = (0.0f64, 0usize);
    for c in cases(17).into_iter().step_by(3) {
        let params = Params::of(&c.scene);
        let rays = pixel_rays(&c.scene, &c.cam);
        let (pix, _) = only_term(&c.pix, &c.spec, TERM_POINT_RGB);
        let colour_only = LossSpec {
            lambda_r_colour: lc,
            ..Default::default()
        };
        let an = grads_with(&c.scene, &params, &rays, c.k, &pix, &colour_only);
        assert!(
            an.geo.iter().chain(&an.priority).all(|&g| g == 0.0),
            "{}: the colour-only term reached a density or the priority",
            c.name
        );
        let full = Case {
            name: c.name.clone(),
            scene: c.scene.clone(),
            cam: c.cam.clone(),
            k: c.k,
            pix,
            spec: LossSpec {
                lambda_r: 3.0 * lc,
                ..Default::default()
            },
        };
        let base = evaluate(
            &full.scene,
            &params,
            &rays,
            full.k,
            &full.pix,
            &full.spec,
            None,
        );
        for kind in [Kind::Sh0, Kind::Shs] {
            let fds: Vec<(usize, f64)> = (0..param_count(&params, kind))
                .filter_map(|j| {
                    fd_terms(&params, &rays, &full, &base.signature, kind, j)
                        .map(|fd| (j, fd[TERM_POINT_RGB]))
                })
                .collect();
            let gmax = fds.iter().map(|f| f.1.abs()).fold(0.0, f64::max);
            for (j, fd) in fds {
                let a = grad_of(&an, kind, j);
                let e = (a - fd).abs() / (fd.abs() + 1e-3 * gmax + 1e-9);
                assert!(
                    e <= GRAD_TOL,
                    "{}: {kind:?}[{j}]: analytic {a:e} vs fd {fd:e} (rel err {e:e})",
                    c.name
                );
                worst = worst.max(e);
                nonzero += usize::from(fd.abs() > 1e-3 * gmax && fd.abs() > 1e-6);
            }
        }
    }
    println!("colour-only point RGB: max rel error {worst:.2e}, {nonzero} non-zero SH gradients");
    assert!(nonzero > 100, "too few SH gradients checked ({nonzero})");
}

/// priority[v] = Σ |α·∂L/∂α| over v's contributing entries, with ∂L/∂α by central
/// differences on the alpha value itself (AlphaNudge), for K = 1, 2, 3.
#[test]
fn priority_matches_alpha_finite_differences() {
    let mut rng = Rng(99);
    let mut worst = 0.0f64;
    let mut skipped = 0;
    let mut entries = 0;
    for k in 1..=3 {
        let scene = grad_scene(&mut rng, 2);
        let cam = camera_outside_near(&mut rng, &scene, W, H);
        let pix = random_weights(&mut rng, (W * H) as usize);
        let spec = random_spec(&mut rng);
        let params = Params::of(&scene);
        let rays = pixel_rays(&scene, &cam);
        let base = evaluate(&scene, &params, &rays, k, &pix, &spec, None);
        let g = grads_with(&scene, &params, &rays, k, &pix, &spec);
        let mut prio = vec![0.0; scene.num_voxels()];
        let mut unchecked = vec![false; scene.num_voxels()];
        for (p, cs) in base.contributors.iter().enumerate() {
            for (e, ctb) in cs.iter().enumerate() {
                entries += 1;
                // L_p is a polynomial of degree ≤ 4 in one alpha value while no branch
                // changes (quadratic, and T²(1−T)² of the transmittance terms), so
                // Richardson's extrapolation of two central differences (steps δ and
                // δ/2) is exact up to rounding: start with a large step, shrink it while
                // it changes a branch (an early stop).
                let mut delta = 1e-4;
                let mut dl_dalpha = None;
                for _ in 0..6 {
                    let ev = |d: f64| {
                        let nudge = AlphaNudge {
                            pixel: p,
                            entry: e,
                            delta: d,
                        };
                        evaluate(&scene, &params, &rays, k, &pix, &spec, Some(nudge))
                    };
                    let evals = [ev(delta), ev(-delta), ev(0.5 * delta), ev(-0.5 * delta)];
                    if evals.iter().all(|e| e.signature == base.signature) {
                        let d1 = (evals[0].pixel_loss[p] - evals[1].pixel_loss[p]) / (2.0 * delta);
                        let d2 = (evals[2].pixel_loss[p] - evals[3].pixel_loss[p]) / delta;
                        dl_dalpha = Some((4.0 * d2 - d1) / 3.0);
                        break;
                    }
                    delta *= 0.1;
                }
                match dl_dalpha {
                    Some(v) => prio[ctb.voxel] += (ctb.alpha * v).abs(),
                    None => {
                        skipped += 1;
                        unchecked[ctb.voxel] = true;
                    }
                }
            }
        }
        let pmax = prio.iter().copied().fold(0.0, f64::max);
        assert!(pmax > 0.0);
        for v in (0..scene.num_voxels()).filter(|&v| !unchecked[v]) {
            let e = (g.priority[v] - prio[v]).abs() / (prio[v] + 1e-3 * pmax + 1e-12);
            worst = worst.max(e);
            assert!(
                e < 1e-8,
                "K={k} voxel {v}: priority {} vs fd {}",
                g.priority[v],
                prio[v]
            );
        }
    }
    println!("priority: {entries} entries, {skipped} skipped, max rel err {worst:.2e}");
    assert!(
        (skipped as f64) < MAX_SKIP_FRACTION * entries as f64,
        "{skipped} of {entries} alpha nudges changed a branch"
    );
}

/// What the random cases of the finite-difference test exercise: every branch of the
/// forward occurs (alpha below MIN_ALPHA, alpha and local-alpha clamps, early stops,
/// colour clamps, both explin branches, near-plane clipping). Prints per case.
#[test]
fn cases_exercise_every_branch() {
    // [skipped hits, alpha-clamped, early stops, clamped colour channels,
    //  explin-linear samples, local-alpha-clamped samples (K > 1), near-clipped hits,
    //  contracted-distortion hits ending before distance 1, and ending beyond it]
    let mut total = [0usize; 9];
    for c in cases(7) {
        let rays = pixel_rays(&c.scene, &c.cam);
        let params = Params::of(&c.scene);
        let ev = evaluate(&c.scene, &params, &rays, c.k, &c.pix, &c.spec, None);
        let hits: usize = rays.iter().map(|r| r.hits.len()).sum();
        let contrib: usize = ev.contributors.iter().map(|v| v.len()).sum();
        let mut n = [0usize; 9];
        if c.spec.dist_contracted {
            for h in rays.iter().flat_map(|r| &r.hits) {
                n[if h.1 < 1.0 { 7 } else { 8 }] += 1;
            }
        }
        n[6] = rays
            .iter()
            .flat_map(|r| r.hits.iter().map(move |h| h.0 == c.cam.near * r.norm))
            .filter(|&b| b)
            .count();
        let s = &ev.signature;
        let mut i = 0;
        while i < s.len() {
            let b = s[i];
            i += 1;
            match b {
                0 => n[0] += 1,
                255 => n[2] += 1,
                _ => {
                    n[1] += (b & 2 != 0) as usize;
                    n[3] += ((b >> 3) & 7).count_ones() as usize;
                    for _ in 0..c.k {
                        n[4] += (s[i] & 2 != 0) as usize;
                        n[5] += (c.k > 1 && s[i] & 1 != 0) as usize;
                        i += 1;
                    }
                }
            }
        }
        println!(
            "{}: levels {:?}, {hits} hits, {contrib} contributors; skipped {}, alpha-clamped {}, early stops {}, clamped colour channels {}, explin-linear samples {}, clamped local alphas {}, near-clipped {}, contracted before / beyond 1: {} / {}",
            c.name,
            (1..=3)
                .map(|l| c.scene.octlevel.iter().filter(|&&v| v == l).count())
                .collect::<Vec<_>>(),
            n[0], n[1], n[2], n[3], n[4], n[5], n[6], n[7], n[8]
        );
        for j in 0..9 {
            total[j] += n[j];
        }
    }
    println!("totals {total:?}");
    assert!(
        total.iter().all(|&v| v > 0),
        "a branch never occurs: {total:?}"
    );
}
