//! The f64 CPU reference for the training losses and their analytic gradients w.r.t.
//! every model parameter (grid-point densities, SH), written for clarity: per pixel a
//! forward pass with the exact semantics of [`super::reference::render_pixel`] that keeps
//! every contributor's intermediate values, then a hand-written reverse-mode pass back
//! to front.
//!
//! # The loss
//! Per pixel `p` (pixel centres `px + 0.5, py + 0.5`, index `py·W + px`) with weights
//! [`PixelWeights`] and global [`LossSpec`]:
//!
//! `L = Σ_p rgb·out.rgb + alpha·out.alpha + depth·out.depth + normal·out.normal
//!        + λ_dist·dist_p + λ_R·R_p`
//!
//! where `out` are the reference outputs (rgb includes `T_final·bg`, where bg is the
//! scene's colour or, with `background_frame_mean`, the frame's mean composited colour,
//! which couples the pixels: see `frame_background`; alpha = `1 − T_final`,
//! depth = camera z = `Σ T_k dval_k / |camera dir|`, normal = `Σ w_k n_k`). Over the
//! contributors `k` of the pixel (hits in entry order, skipped when alpha < MIN_ALPHA,
//! stopping after early termination), `w_k = T_k α_k`, `[a_k, b_k]` the near-clamped ray
//! segment (unit direction), `m_k = (a_k + b_k)/2`, `δ_k = b_k − a_k`,
//! `W_k = Σ_{j<k} w_j`, `M_k = Σ_{j<k} w_j m_j`:
//!
//! * `dist_p = Σ_k 2 w_k (m_k W_k − M_k) + 1/3 Σ_k w_k² δ_k` (mip-NeRF 360 distortion; the
//!   segments are constants),
//! * `R_p = Σ_k w_k · 1/3 Σ_ch (c_k,ch − gt_ch)²` (per-point RGB loss).
//!
//! # Derivative conventions (at the branch points of the forward)
//! * `α = min(MAX_ALPHA, 1 − exp(−vol))` has zero derivative w.r.t. `vol` when clamped
//!   (`1 − exp(−vol) > MAX_ALPHA`); otherwise `dα/dvol = exp(−vol)`. The same holds for
//!   the per-sample local alphas of the K > 1 depth. With `LossSpec::alpha_straight`
//!   the derivative is `exp(−vol)` either way (SVRaster's rule).
//! * Skipped hits (α < MIN_ALPHA) and hits after early termination do not enter the
//!   loss at all: no gradient, no priority. The skip/stop decisions are not
//!   differentiated (they are discontinuities).
//! * `colour = max(0, 0.5 + SH)` passes gradient only where `0.5 + SH > 0`.
//! * `n = n_raw / sqrt(max(|n_raw|², 1e-30))` has zero gradient when `|n_raw|² ≤ 1e-30`.
//! * `explin'(x) = 1` for `x > 1.1`, else `explin(x)/1.1`.
//! * Trilinear weights as in [`super::reference::trilinear`]; all 8 corners of a voxel
//!   accumulate into the grid points they reference.
//! * Gradients of `geo` flow through α (all K samples), through the K > 1 depth's local
//!   alphas, and through the normal. SH gradients flow through the colour (rgb term and
//!   per-point RGB loss). Nothing flows through the segment ends `a, b`.
//! * K = 1 depth is `dval = α·m` (as the reference): it depends on α as a variable, so
//!   the depth term is part of `∂L/∂α` (and of the priority) for K = 1. For K > 1
//!   `dval = Σ_s tr_s la_s t_s` depends on the local alphas only, not on α.
//!
//! * Consequences worth knowing: a voxel whose α is clamped still passes gradient to
//!   `geo` through its normal and (K > 1) through its depth's local alphas, which are
//!   clamped separately; and since `T·(1 − MAX_ALPHA) < EARLY_STOP_T` for any T ≤ 1, a
//!   clamped α always ends the ray (the stopping entry itself contributes fully; the
//!   background and alpha terms see the small `T_final`).
//!
//! # Priority
//! `priority[v] = Σ_p Σ_{contributors k of v on p} |α_k · ∂L/∂α_k|`, where `∂L/∂α_k` is the
//! derivative w.r.t. that entry's (clamped) alpha value taken as a variable (everything
//! downstream of α: w_k, T_{j>k}, T_final, and for K = 1 the entry's depth), before the
//! clamp's own derivative.
#![allow(clippy::needless_range_loop, clippy::too_many_arguments)]

use super::reference::{
    dot, explin, normalize, pixel_ray, ray_hits, sh_basis, sub, trilinear, EARLY_STOP_T, MAX_ALPHA,
    MIN_ALPHA, STEP_SZ_SCALE,
};
use svraster::data::Camera;
use svraster::scene::Scene;

/// Per-pixel loss weights (and the per-point RGB loss target `gt`).
#[derive(Clone, Copy, Debug, Default)]
pub struct PixelWeights {
    pub rgb: [f64; 3],
    pub alpha: f64,
    pub depth: f64,
    pub normal: [f64; 3],
    pub gt: [f64; 3],
}

/// Global loss weights of the distortion and per-point RGB losses.
#[derive(Clone, Copy, Debug, Default)]
pub struct LossSpec {
    pub lambda_dist: f64,
    pub lambda_r: f64,
    /// SVRaster's per-point RGB form: λ·Σ_k w_k |c_k − gt|² with the w_k held constant.
    /// No value (it is not the gradient of the loss here); gradient 2λ·w_k·(c_k − gt)
    /// on the colours only.
    pub lambda_r_colour: f64,
    /// The distortion on SVRaster's contracted axis (`depth_contracted` of the ray
    /// distance: x < 1 ? x : 2 − 1/x) instead of the ray distance.
    pub dist_contracted: bool,
    /// The colour gradient passes max(0, 0.5 + SH) straight through (SVRaster's
    /// backward) instead of the clamp's derivative. Not the gradient of the loss where a
    /// colour is clamped: no finite-difference check applies there.
    pub colour_straight: bool,
    /// The density gradient passes the α clamp min(MAX_ALPHA, ·) straight through
    /// (dα/dvol = exp(−vol) also where clamped, and likewise the K > 1 depth's local
    /// alphas: SVRaster's backward). Not the gradient of the loss there.
    pub alpha_straight: bool,
    /// Transmittance concentration λ·T²(1−T)² on each pixel's final transmittance (the
    /// evaluated resolution's: SVRaster's `raw_T`).
    pub lambda_t: f64,
    /// The inside term λ·T² on each pixel's final transmittance.
    pub lambda_t_inside: f64,
    /// For the GPU backward only: the per-point RGB target at render resolution is the
    /// photo's bilinear resize (`EntryLosses::r_target_bilinear`). The reference takes
    /// each pixel's target from its `PixelWeights::gt`, which a test fills to match.
    pub r_target_bilinear: bool,
}

impl LossSpec {
    /// A ray distance on the distortion's axis.
    pub fn dist_axis(&self, t: f64) -> f64 {
        if self.dist_contracted && t >= 1.0 {
            2.0 - 1.0 / t
        } else {
            t
        }
    }
}

/// The loss and its gradients w.r.t. every parameter, plus the per-voxel priority.
#[derive(Clone, Debug)]
pub struct RefGrads {
    pub loss: f64,
    /// Per grid point (layout of `scene.geo`).
    pub geo: Vec<f64>,
    /// Per voxel (layout of `scene.sh0`).
    pub sh0: Vec<[f64; 3]>,
    /// Layout of `scene.shs`: `[(i·nc + k−1)·3 + ch]`.
    pub shs: Vec<f64>,
    /// Per voxel: `Σ |α_k ∂L/∂α_k|` over its contributing entries (see module docs).
    pub priority: Vec<f64>,
}

/// The trainable parameters in f64 (the scene's f32 values widened), so finite
/// differences can take f64 steps. Geometry, SH degree and background come from the
/// scene.
#[derive(Clone, Debug)]
pub struct Params {
    pub geo: Vec<f64>,
    pub sh0: Vec<[f64; 3]>,
    pub shs: Vec<f64>,
}

impl Params {
    pub fn of(scene: &Scene) -> Params {
        Params {
            geo: scene.geo.iter().map(|&v| v as f64).collect(),
            sh0: scene.sh0.iter().map(|c| c.map(|v| v as f64)).collect(),
            shs: scene.shs.iter().map(|&v| v as f64).collect(),
        }
    }
}

/// Indices of the loss terms in [`Eval::terms`].
pub const TERM_RGB: usize = 0;
pub const TERM_ALPHA: usize = 1;
pub const TERM_DEPTH: usize = 2;
pub const TERM_NORMAL: usize = 3;
pub const TERM_DIST: usize = 4;
pub const TERM_POINT_RGB: usize = 5;
pub const TERM_T: usize = 6;
pub const NUM_TERMS: usize = 7;
pub const TERM_NAMES: [&str; NUM_TERMS] = [
    "rgb",
    "alpha",
    "depth",
    "normal",
    "dist",
    "point_rgb",
    "transmittance",
];

/// One contributor of a pixel (after skipping and early termination), in compositing
/// order.
#[derive(Clone, Copy, Debug)]
pub struct Contributor {
    pub voxel: usize,
    /// Near-clamped segment in ray-distance units.
    pub a: f64,
    pub b: f64,
    /// Transmittance before this entry.
    pub t: f64,
    /// The (clamped) alpha.
    pub alpha: f64,
}

/// A detailed forward evaluation.
#[derive(Clone, Debug)]
pub struct Eval {
    /// The weighted loss terms, each summed over pixels (`TERM_*`); their sum is `L`.
    pub terms: [f64; NUM_TERMS],
    /// Every discrete branch the forward took (skip, clamps, explin branch, colour and
    /// normal clamps, early stop), per hit per pixel: equal signatures at two parameter
    /// vectors mean no discontinuity (nor derivative kink) was crossed between the
    /// forward passes' branch decisions.
    pub signature: Vec<u8>,
    /// Per pixel: its contributors.
    pub contributors: Vec<Vec<Contributor>>,
    /// Per pixel: its loss `L_p` (all terms).
    pub pixel_loss: Vec<f64>,
}

impl Eval {
    pub fn loss(&self) -> f64 {
        self.terms.iter().sum()
    }
}

/// Perturbs the alpha *value* of one contributor (`entry` counts contributors of
/// `pixel`, in compositing order) by `delta`, after the skip test and before anything
/// uses it (w, T, K = 1 depth, early-stop test). Used to check the priority's `∂L/∂α`.
#[derive(Clone, Copy, Debug)]
pub struct AlphaNudge {
    pub pixel: usize,
    pub entry: usize,
    pub delta: f64,
}

/// One pixel's ray and the voxels it hits, ordered exactly as `render_pixel` does.
#[derive(Clone, Debug)]
pub struct PixelRay {
    pub o: [f64; 3],
    pub d: [f64; 3],
    /// |camera-space direction| (z = 1): depth = ray distance / norm.
    pub norm: f64,
    /// (a, b, voxel), sorted by (a, b).
    pub hits: Vec<(f64, f64, usize)>,
}

/// The rays of every pixel of `cam` (they depend on geometry only, not on parameters).
pub fn pixel_rays(scene: &Scene, cam: &Camera) -> Vec<PixelRay> {
    let mut rays = Vec::with_capacity((cam.width * cam.height) as usize);
    for py in 0..cam.height {
        for px in 0..cam.width {
            let (o, d, norm) = pixel_ray(cam, px as f64 + 0.5, py as f64 + 0.5);
            let t_near = cam.near * norm;
            let hits = ray_hits(scene, o, d, t_near);
            rays.push(PixelRay { o, d, norm, hits });
        }
    }
    rays
}

/// f64 forward value of L (the forward semantics of `render_pixel` exactly).
pub fn loss(scene: &Scene, cam: &Camera, k: usize, pix: &[PixelWeights], spec: &LossSpec) -> f64 {
    let rays = pixel_rays(scene, cam);
    evaluate(scene, &Params::of(scene), &rays, k, pix, spec, None).loss()
}

/// Analytic gradients of L by reverse-mode differentiation written out by hand, per
/// pixel back to front.
pub fn grads(
    scene: &Scene,
    cam: &Camera,
    k: usize,
    pix: &[PixelWeights],
    spec: &LossSpec,
) -> RefGrads {
    let rays = pixel_rays(scene, cam);
    grads_with(scene, &Params::of(scene), &rays, k, pix, spec)
}

/// The forward with explicit f64 parameters and precomputed rays; see [`Eval`].
pub fn evaluate(
    scene: &Scene,
    params: &Params,
    rays: &[PixelRay],
    k: usize,
    pix: &[PixelWeights],
    spec: &LossSpec,
    nudge: Option<AlphaNudge>,
) -> Eval {
    assert_eq!(rays.len(), pix.len(), "one PixelWeights per pixel");
    let mut ev = Eval {
        terms: [0.0; NUM_TERMS],
        signature: Vec::new(),
        contributors: Vec::with_capacity(rays.len()),
        pixel_loss: Vec::with_capacity(rays.len()),
    };
    let fwd: Vec<PixelForward> = rays
        .iter()
        .zip(pix)
        .enumerate()
        .map(|(p, (ray, pw))| {
            let n = nudge.filter(|n| n.pixel == p).map(|n| (n.entry, n.delta));
            forward_pixel(scene, params, ray, k, pw, spec, n, &mut ev.signature)
        })
        .collect();
    let (bg, _) = frame_background(scene, &fwd, pix);
    for (mut f, pw) in fwd.into_iter().zip(pix) {
        f.terms[TERM_RGB] += f.t_final * dot(pw.rgb, bg);
        for t in 0..NUM_TERMS {
            ev.terms[t] += f.terms[t];
        }
        ev.pixel_loss.push(f.terms.iter().sum());
        ev.contributors.push(
            f.contribs
                .iter()
                .map(|c| Contributor {
                    voxel: c.voxel,
                    a: c.a,
                    b: c.b,
                    t: c.t,
                    alpha: c.alpha,
                })
                .collect(),
        );
    }
    ev
}

/// [`grads`] with explicit f64 parameters and precomputed rays.
pub fn grads_with(
    scene: &Scene,
    params: &Params,
    rays: &[PixelRay],
    k: usize,
    pix: &[PixelWeights],
    spec: &LossSpec,
) -> RefGrads {
    assert_eq!(rays.len(), pix.len(), "one PixelWeights per pixel");
    let mut out = RefGrads {
        loss: 0.0,
        geo: vec![0.0; params.geo.len()],
        sh0: vec![[0.0; 3]; params.sh0.len()],
        shs: vec![0.0; params.shs.len()],
        priority: vec![0.0; scene.num_voxels()],
    };
    let mut sig = Vec::new();
    let fwd: Vec<PixelForward> = rays
        .iter()
        .zip(pix)
        .map(|(ray, pw)| forward_pixel(scene, params, ray, k, pw, spec, None, &mut sig))
        .collect();
    let (bg, extra) = frame_background(scene, &fwd, pix);
    for ((ray, pw), f) in rays.iter().zip(pix).zip(&fwd) {
        out.loss += f.terms.iter().sum::<f64>() + f.t_final * dot(pw.rgb, bg);
        backward_pixel(scene, ray, k, pw, spec, bg, extra, f, &mut out);
    }
    out
}

/// `explin'(x)`.
pub fn explin_grad(x: f64) -> f64 {
    if x > 1.1 {
        1.0
    } else {
        explin(x) / 1.1
    }
}

/// The 8 trilinear weights of `trilinear` (corner index x<<2 | y<<1 | z).
pub fn trilinear_weights(q: [f64; 3]) -> [f64; 8] {
    std::array::from_fn(|c| {
        let wx = if c & 4 != 0 { q[0] } else { 1.0 - q[0] };
        let wy = if c & 2 != 0 { q[1] } else { 1.0 - q[1] };
        let wz = if c & 1 != 0 { q[2] } else { 1.0 - q[2] };
        wx * wy * wz
    })
}

/// One of the K samples of a contributor.
#[derive(Clone, Debug)]
struct Sample {
    /// Ray distance of the sample.
    t: f64,
    /// Position in the voxel's unit cube.
    q: [f64; 3],
    /// Interpolated raw density.
    x: f64,
    /// Local volume `STEP_SZ_SCALE·step·explin(x)`.
    lv: f64,
    /// Local alpha `min(MAX_ALPHA, 1 − exp(−lv))` and whether it is clamped.
    la: f64,
    la_clamped: bool,
}

/// Everything the backward pass needs of one contributor.
#[derive(Clone, Debug)]
struct Contrib {
    voxel: usize,
    a: f64,
    b: f64,
    step: f64,
    samples: Vec<Sample>,
    vol: f64,
    /// Clamped alpha (plus the nudge, if any) and whether the clamp is active.
    alpha: f64,
    alpha_clamped: bool,
    /// Transmittance before the entry.
    t: f64,
    basis: Vec<f64>,
    /// 0.5 + SH per channel, and the clamped colour.
    pre: [f64; 3],
    rgb: [f64; 3],
    /// The unnormalised normal's squared length, and the normal.
    nn: f64,
    n: [f64; 3],
    /// Un-transmitted depth contribution (ray-distance units).
    dval: f64,
}

struct PixelForward {
    contribs: Vec<Contrib>,
    terms: [f64; NUM_TERMS],
    /// The composited colour C = Σ w c (no background) and the final transmittance.
    colour: [f64; 3],
    t_final: f64,
}

/// The background behind every pixel of a frame: the scene's colour, or with
/// `background_frame_mean` the frame's mean composited colour m = (1/N) Σ_p C_p, whose
/// gradient reaches every pixel: out_p = C_p + T_p m gives, for the linear loss,
/// ∂L/∂C_p = rgb_p + (1/N) Σ_q rgb_q T_q (returned as the extra C weight) and
/// ∂L/∂T_p = rgb_p·m − alpha_p.
fn frame_background(
    scene: &Scene,
    fwd: &[PixelForward],
    pix: &[PixelWeights],
) -> ([f64; 3], [f64; 3]) {
    if !scene.background_frame_mean {
        return (scene.background.map(|v| v as f64), [0.0; 3]);
    }
    let n = fwd.len() as f64;
    let mut m = [0.0; 3];
    let mut extra = [0.0; 3];
    for (f, pw) in fwd.iter().zip(pix) {
        for ch in 0..3 {
            m[ch] += f.colour[ch] / n;
            extra[ch] += pw.rgb[ch] * f.t_final / n;
        }
    }
    (m, extra)
}

fn corner_values(scene: &Scene, params: &Params, i: usize) -> [f64; 8] {
    std::array::from_fn(|c| params.geo[scene.corners[i][c] as usize])
}

fn forward_pixel(
    scene: &Scene,
    params: &Params,
    ray: &PixelRay,
    k: usize,
    pw: &PixelWeights,
    spec: &LossSpec,
    nudge: Option<(usize, f64)>,
    sig: &mut Vec<u8>,
) -> PixelForward {
    let (o, d) = (ray.o, ray.d);
    let nc = scene.shs_per_voxel();
    let mut contribs: Vec<Contrib> = Vec::new();
    let mut t = 1.0;
    for &(a, b, i) in &ray.hits {
        let g = corner_values(scene, params, i);
        let vmin = scene.voxel_min(i);
        let size = scene.voxel_size(i);
        // Alpha from K samples (as `alpha_of` of the reference).
        let step = (b - a) / k as f64;
        let mut vol = 0.0;
        let mut samples = Vec::with_capacity(k);
        for s in 0..k {
            let ts = a + (s as f64 + 0.5) * step;
            let q: [f64; 3] = std::array::from_fn(|ax| (o[ax] + ts * d[ax] - vmin[ax]) / size);
            let x = trilinear(&g, q);
            let lv = STEP_SZ_SCALE * step * explin(x);
            vol += lv;
            let la_raw = 1.0 - (-lv).exp();
            samples.push(Sample {
                t: ts,
                q,
                x,
                lv,
                la: la_raw.min(MAX_ALPHA),
                la_clamped: la_raw > MAX_ALPHA,
            });
        }
        let alpha_raw = 1.0 - (-vol).exp();
        let mut alpha = alpha_raw.min(MAX_ALPHA);
        if alpha < MIN_ALPHA {
            sig.push(0);
            continue;
        }
        if let Some((entry, delta)) = nudge {
            if entry == contribs.len() {
                alpha += delta;
            }
        }
        // Colour towards the voxel centre (as `voxel_rgb`).
        let dir = normalize(sub(scene.voxel_center(i), o));
        let basis = sh_basis(dir, scene.sh_degree);
        let mut pre = [0.0; 3];
        let mut rgb = [0.0; 3];
        for ch in 0..3 {
            let mut v = basis[0] * params.sh0[i][ch];
            for kk in 1..=nc {
                v += basis[kk] * params.shs[(i * nc + kk - 1) * 3 + ch];
            }
            pre[ch] = v + 0.5;
            rgb[ch] = pre[ch].max(0.0);
        }
        // Normal (as `voxel_normal`).
        let nraw = [
            (g[4] + g[5] + g[6] + g[7]) - (g[0] + g[1] + g[2] + g[3]),
            (g[2] + g[3] + g[6] + g[7]) - (g[0] + g[1] + g[4] + g[5]),
            (g[1] + g[3] + g[5] + g[7]) - (g[0] + g[2] + g[4] + g[6]),
        ];
        let nn = dot(nraw, nraw);
        let r = 1.0 / nn.max(1e-30).sqrt();
        let n = [nraw[0] * r, nraw[1] * r, nraw[2] * r];
        // Depth contribution.
        let dval = if k == 1 {
            alpha * 0.5 * (a + b)
        } else {
            let mut tr = 1.0;
            let mut dv = 0.0;
            for smp in &samples {
                dv += tr * smp.la * smp.t;
                tr *= 1.0 - smp.la;
            }
            dv
        };
        // Branch signature of this contributor.
        let mut bits = 1u8;
        if alpha_raw > MAX_ALPHA {
            bits |= 2;
        }
        if nn <= 1e-30 {
            bits |= 4;
        }
        for ch in 0..3 {
            if pre[ch] <= 0.0 {
                bits |= 8 << ch;
            }
        }
        sig.push(bits);
        for smp in &samples {
            sig.push(smp.la_clamped as u8 | ((smp.x > 1.1) as u8) << 1);
        }
        contribs.push(Contrib {
            voxel: i,
            a,
            b,
            step,
            samples,
            vol,
            alpha,
            alpha_clamped: alpha_raw > MAX_ALPHA,
            t,
            basis,
            pre,
            rgb,
            nn,
            n,
            dval,
        });
        t *= 1.0 - alpha;
        if t < EARLY_STOP_T {
            sig.push(255);
            break;
        }
    }

    // The loss terms.
    let mut terms = [0.0; NUM_TERMS];
    let mut out_rgb = [0.0; 3];
    let mut out_normal = [0.0; 3];
    let mut out_depth = 0.0;
    let mut point_rgb = 0.0;
    let (mut w_before, mut wm_before, mut dist) = (0.0, 0.0, 0.0);
    for c in &contribs {
        let w = c.t * c.alpha;
        for ch in 0..3 {
            out_rgb[ch] += w * c.rgb[ch];
            out_normal[ch] += w * c.n[ch];
        }
        out_depth += c.t * c.dval;
        point_rgb += w
            * (0..3)
                .map(|ch| (c.rgb[ch] - pw.gt[ch]).powi(2))
                .sum::<f64>()
            / 3.0;
        let (da, db) = (spec.dist_axis(c.a), spec.dist_axis(c.b));
        let m = 0.5 * (da + db);
        let delta = db - da;
        dist += 2.0 * w * (m * w_before - wm_before) + w * w * delta / 3.0;
        w_before += w;
        wm_before += w * m;
    }
    // The rgb term without its background part, which the frame adds
    // (`frame_background`).
    terms[TERM_RGB] = dot(pw.rgb, out_rgb);
    terms[TERM_ALPHA] = pw.alpha * (1.0 - t);
    terms[TERM_DEPTH] = pw.depth * (out_depth / ray.norm);
    terms[TERM_NORMAL] = dot(pw.normal, out_normal);
    terms[TERM_DIST] = spec.lambda_dist * dist;
    terms[TERM_POINT_RGB] = spec.lambda_r * point_rgb;
    terms[TERM_T] = spec.lambda_t * (t * (1.0 - t)).powi(2) + spec.lambda_t_inside * t * t;
    PixelForward {
        contribs,
        terms,
        colour: out_rgb,
        t_final: t,
    }
}

/// Reverse mode for one pixel; accumulates into `out`. `bg` is the frame's background
/// and `extra` the weight its gradient adds to the composited colour C
/// (`frame_background`): the rgb weight on C is `rgb + extra`, on `T_final` `rgb·bg`.
///
/// With `g_k = ∂L/∂w_k` (w_k held as a variable: colour, normal, per-point RGB and the
/// distortion's `u_k = ∂dist/∂w_k`), `D_k = depth_weight·dval_k/norm` (the term
/// multiplied by T_k) and `B = rgb·bg − alpha_weight` (the term multiplied by T_final),
/// the pixel loss is `Σ_k T_k (α_k g_k + D_k) + T_final·B` to first order. Back to
/// front: `A_{N+1} = B`, `A_k = α_k g_k + D_k + (1 − α_k) A_{k+1}` (= ∂L/∂T_k) and
/// `∂L/∂α_k = T_k (g_k + ∂D_k/∂α_k − A_{k+1})`.
fn backward_pixel(
    scene: &Scene,
    ray: &PixelRay,
    k: usize,
    pw: &PixelWeights,
    spec: &LossSpec,
    bg: [f64; 3],
    extra: [f64; 3],
    f: &PixelForward,
    out: &mut RefGrads,
) {
    let crgb: [f64; 3] = std::array::from_fn(|ch| pw.rgb[ch] + extra[ch]);
    let cs = &f.contribs;
    let n = cs.len();
    let nc = scene.shs_per_voxel();
    let w: Vec<f64> = cs.iter().map(|c| c.t * c.alpha).collect();
    // Midpoints on the distortion's axis (the depth term uses the ray distances).
    let m: Vec<f64> = cs
        .iter()
        .map(|c| 0.5 * (spec.dist_axis(c.a) + spec.dist_axis(c.b)))
        .collect();

    // g_k = ∂L/∂w_k. Distortion: u_k = 2 (m_k W_k − M_k) + 2 Σ_{j>k} w_j (m_j − m_k)
    //   + 2/3 w_k δ_k, with prefix sums W, M and suffix sums S0 = Σ_{j>k} w_j,
    //   S1 = Σ_{j>k} w_j m_j.
    let mut g = vec![0.0; n];
    let (mut pw_sum, mut pwm_sum) = (0.0, 0.0);
    let mut s0 = vec![0.0; n];
    let mut s1 = vec![0.0; n];
    for j in (0..n.saturating_sub(1)).rev() {
        s0[j] = s0[j + 1] + w[j + 1];
        s1[j] = s1[j + 1] + w[j + 1] * m[j + 1];
    }
    for j in 0..n {
        let c = &cs[j];
        let delta = spec.dist_axis(c.b) - spec.dist_axis(c.a);
        let u = 2.0 * (m[j] * pw_sum - pwm_sum)
            + 2.0 * (s1[j] - m[j] * s0[j])
            + 2.0 / 3.0 * w[j] * delta;
        let r = (0..3)
            .map(|ch| (c.rgb[ch] - pw.gt[ch]).powi(2))
            .sum::<f64>()
            / 3.0;
        g[j] = dot(crgb, c.rgb) + dot(pw.normal, c.n) + spec.lambda_r * r + spec.lambda_dist * u;
        pw_sum += w[j];
        pwm_sum += w[j] * m[j];
    }

    let dd = pw.depth / ray.norm; // ∂L/∂(T_k dval_k)
                                  // A_{N+1} = ∂L/∂T_final, with the transmittance terms' derivative.
    let tf = f.t_final;
    let mut acc = dot(pw.rgb, bg) - pw.alpha
        + spec.lambda_t * 2.0 * tf * (1.0 - tf) * (1.0 - 2.0 * tf)
        + spec.lambda_t_inside * 2.0 * tf; // A_{k+1}
    for j in (0..n).rev() {
        let c = &cs[j];
        let i = c.voxel;
        // ∂L/∂α_j and the priority.
        let d_dval_dalpha = if k == 1 { 0.5 * (c.a + c.b) } else { 0.0 };
        let dl_dalpha = c.t * (g[j] + dd * d_dval_dalpha - acc);
        out.priority[i] += (c.alpha * dl_dalpha).abs();
        acc = c.alpha * g[j] + dd * c.dval + (1.0 - c.alpha) * acc;

        // α → vol → every local volume.
        let dl_dvol = if c.alpha_clamped && !spec.alpha_straight {
            0.0
        } else {
            dl_dalpha * (-c.vol).exp()
        };
        let mut dl_dlv = vec![dl_dvol; k];
        // K > 1 depth: dval = Σ_s tr_s la_s t_s, tr_s = Π_{r<s} (1 − la_r); back to front
        // with E_{K+1} = 0, E_s = la_s t_s + (1 − la_s) E_{s+1}:
        // ∂dval/∂la_s = tr_s (t_s − E_{s+1}).
        if k > 1 {
            let dl_ddval = c.t * dd;
            let mut tr = vec![1.0; k];
            for s in 1..k {
                tr[s] = tr[s - 1] * (1.0 - c.samples[s - 1].la);
            }
            let mut e = 0.0;
            for s in (0..k).rev() {
                let smp = &c.samples[s];
                let dla = dl_ddval * tr[s] * (smp.t - e);
                e = smp.la * smp.t + (1.0 - smp.la) * e;
                if !smp.la_clamped || spec.alpha_straight {
                    dl_dlv[s] += dla * (-smp.lv).exp();
                }
            }
        }
        // Local volumes → interpolated densities → corners.
        let mut dg = [0.0; 8];
        for (s, smp) in c.samples.iter().enumerate() {
            let dx = dl_dlv[s] * STEP_SZ_SCALE * c.step * explin_grad(smp.x);
            let tw = trilinear_weights(smp.q);
            for cc in 0..8 {
                dg[cc] += dx * tw[cc];
            }
        }
        // Normal: ∂L/∂n = w·normal_weight; n = n_raw/|n_raw| →
        // ∂L/∂n_raw = (∂L/∂n − n (n·∂L/∂n)) / |n_raw|.
        if c.nn > 1e-30 {
            let dn = pw.normal.map(|v| v * w[j]);
            let r = 1.0 / c.nn.sqrt();
            let ndn = dot(c.n, dn);
            let dnraw: [f64; 3] = std::array::from_fn(|ax| r * (dn[ax] - c.n[ax] * ndn));
            for cc in 0..8 {
                for (ax, bit) in [4, 2, 1].into_iter().enumerate() {
                    let sign = if cc & bit != 0 { 1.0 } else { -1.0 };
                    dg[cc] += sign * dnraw[ax];
                }
            }
        }
        for cc in 0..8 {
            out.geo[scene.corners[i][cc] as usize] += dg[cc];
        }
        // Colour: ∂L/∂c = w (rgb_weight + λ_R·2/3 (c − gt) + λ_Rc·2 (c − gt)), through
        // max(0, ·) to SH (or past it, straight through).
        for ch in 0..3 {
            if c.pre[ch] <= 0.0 && !spec.colour_straight {
                continue;
            }
            let diff = c.rgb[ch] - pw.gt[ch];
            let dc = w[j]
                * (crgb[ch] + spec.lambda_r * 2.0 / 3.0 * diff + spec.lambda_r_colour * 2.0 * diff);
            out.sh0[i][ch] += c.basis[0] * dc;
            for kk in 1..=nc {
                out.shs[(i * nc + kk - 1) * 3 + ch] += c.basis[kk] * dc;
            }
        }
    }
}
