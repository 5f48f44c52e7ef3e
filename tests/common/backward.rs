//! The training backward run on the GPU and compared with the f64 reference gradients
//! (tests/common/reference_grad.rs), shared by tests/train_grad/ and
//! tests/properties.rs.

use super::reference_grad::{evaluate, pixel_rays, Eval, LossSpec, Params, PixelWeights, RefGrads};
use super::Rng;
use svraster::data::Camera;
use svraster::gpu::Context;
use svraster::raster::{FrameOutputs, RenderOptions, Renderer};
use svraster::scene::{Scene, SceneGpu};
use svraster::train::backward::{dout, Backward, ClampGrad, EntryLosses, Gradients, Reduction};

pub struct GpuGrads {
    pub geo: Vec<f32>,
    pub sh0: Vec<f32>,
    pub shs: Vec<f32>,
    pub priority: Vec<f32>,
    /// Longest tile list of the frame.
    pub max_tile: u32,
}

impl GpuGrads {
    /// Whether every gradient (grid points, SH, priorities) equals `other`'s bit for bit.
    pub fn same_bits(&self, other: &GpuGrads) -> bool {
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        bits(&self.geo) == bits(&other.geo)
            && bits(&self.sh0) == bits(&other.sh0)
            && bits(&self.shs) == bits(&other.shs)
            && bits(&self.priority) == bits(&other.priority)
    }
}

#[allow(clippy::too_many_arguments)]
pub fn gpu_grads(
    ctx: &Context,
    scene: &Scene,
    cam: &Camera,
    k: u32,
    pix: &[PixelWeights],
    spec: &LossSpec,
    reduction: Reduction,
    chunk: Option<u32>,
) -> GpuGrads {
    gpu_grads_ss(ctx, scene, cam, k, pix, spec, reduction, chunk, 1.0)
}

/// The reductions this device runs: native float atomics (where it has them),
/// compare-and-swap and the ordered (deterministic) one.
pub fn reductions(ctx: &Context) -> Vec<Reduction> {
    let mut r = vec![Reduction::CompareSwap, Reduction::Ordered];
    if ctx.info().float_atomic_add {
        r.insert(0, Reduction::Atomic);
    }
    r
}

/// The default reduction (float atomics where the device has them).
pub fn default_reduction(ctx: &Context) -> Reduction {
    Reduction::choose(ctx, true, false)
}

/// As [`gpu_grads`], rendering at `ss` times the camera's size (`pix` are the output
/// pixels' weights; the backward transposes the downsample). `chunk` sets the entries per
/// backward dispatch and, for the ordered reduction, the records per gather pass.
#[allow(clippy::too_many_arguments)]
pub fn gpu_grads_ss(
    ctx: &Context,
    scene: &Scene,
    cam: &Camera,
    k: u32,
    pix: &[PixelWeights],
    spec: &LossSpec,
    reduction: Reduction,
    chunk: Option<u32>,
    ss: f32,
) -> GpuGrads {
    gpu_grads_walk(ctx, scene, cam, k, pix, spec, reduction, chunk, ss, false)
}

/// As [`gpu_grads_ss`]; `generic_walk` forces the tile walk's path for any subgroup size
/// ([`Renderer::set_generic_walk`]) in the forward and the backward.
#[allow(clippy::too_many_arguments)]
pub fn gpu_grads_walk(
    ctx: &Context,
    scene: &Scene,
    cam: &Camera,
    k: u32,
    pix: &[PixelWeights],
    spec: &LossSpec,
    reduction: Reduction,
    chunk: Option<u32>,
    ss: f32,
    generic_walk: bool,
) -> GpuGrads {
    let all = FrameOutputs {
        normals: true,
        distortion: true,
        distortion_contracted: false,
    };
    gpu_grads_with(
        ctx,
        scene,
        cam,
        k,
        pix,
        spec,
        reduction,
        chunk,
        ss,
        generic_walk,
        all,
    )
    .unwrap()
}

/// As [`gpu_grads_walk`], with the frame's optional outputs chosen by `outputs`
/// ([`Renderer::set_outputs`]); the backward's error when they do not suffice.
#[allow(clippy::too_many_arguments)]
pub fn gpu_grads_with(
    ctx: &Context,
    scene: &Scene,
    cam: &Camera,
    k: u32,
    pix: &[PixelWeights],
    spec: &LossSpec,
    reduction: Reduction,
    chunk: Option<u32>,
    ss: f32,
    generic_walk: bool,
    outputs: FrameOutputs,
) -> svraster::Result<GpuGrads> {
    gpu_grads_segmented(
        ctx,
        scene,
        cam,
        k,
        pix,
        spec,
        reduction,
        chunk,
        ss,
        generic_walk,
        outputs,
        None,
    )
}

/// As [`gpu_grads_with`]; `segments`: entries per segment of the forward composite
/// ([`Renderer::set_segment_entries`]; `None`: the device's default).
#[allow(clippy::too_many_arguments)]
pub fn gpu_grads_segmented(
    ctx: &Context,
    scene: &Scene,
    cam: &Camera,
    k: u32,
    pix: &[PixelWeights],
    spec: &LossSpec,
    reduction: Reduction,
    chunk: Option<u32>,
    ss: f32,
    generic_walk: bool,
    outputs: FrameOutputs,
    segments: Option<u32>,
) -> svraster::Result<GpuGrads> {
    let gpu = SceneGpu::upload(ctx, scene).unwrap();
    let mut r = Renderer::new(ctx).unwrap();
    r.set_generic_walk(generic_walk);
    if let Some(s) = segments {
        r.set_segment_entries(s);
    }
    // The distortion's axis is the loss's (the frame accumulates its sums on it).
    r.set_outputs(FrameOutputs {
        distortion_contracted: outputs.distortion && spec.dist_contracted,
        ..outputs
    });
    let opts = RenderOptions {
        samples: k,
        supersample: ss,
    };
    let stats = r.render_to_device(&gpu, cam, &opts, None).unwrap();
    let frame = r.last_frame().unwrap();
    let mut b = Backward::with_reduction(ctx, reduction).unwrap();
    if spec.colour_straight {
        b.set_colour_clamp_grad(ClampGrad::Straight);
    }
    if spec.alpha_straight {
        b.set_alpha_clamp_grad(ClampGrad::Straight);
    }
    if let Some(c) = chunk {
        b.set_chunk_size(c);
        b.set_gather_span(c);
    }
    b.prepare(&frame, gpu.voxels).unwrap();
    let np = pix.len();
    let mut d = vec![0f32; dout::CHANNELS * np];
    for (p, w) in pix.iter().enumerate() {
        for c in 0..3 {
            d[(dout::R + c) * np + p] = w.rgb[c] as f32;
            d[(dout::NX + c) * np + p] = w.normal[c] as f32;
            d[(dout::GT_R + c) * np + p] = w.gt[c] as f32;
        }
        d[dout::ALPHA * np + p] = w.alpha as f32;
        d[dout::DEPTH * np + p] = w.depth as f32;
    }
    ctx.upload(b.dout().unwrap(), 0, &d).unwrap();
    let g = Gradients::with_reduction(ctx, &gpu, reduction).unwrap();
    ctx.submit_and_wait(|cmd| {
        b.record(
            cmd,
            &frame,
            &stats,
            &gpu,
            k,
            &g,
            &EntryLosses {
                lambda_dist: spec.lambda_dist as f32,
                lambda_r: spec.lambda_r as f32,
                lambda_r_colour: spec.lambda_r_colour as f32,
                lambda_t: spec.lambda_t as f32,
                lambda_t_inside: spec.lambda_t_inside as f32,
                r_target_bilinear: spec.r_target_bilinear,
            },
        )
    })?;
    assert_eq!(b.read_lost().unwrap(), 0, "CAS adds gave up");
    let n = scene.num_voxels();
    Ok(GpuGrads {
        geo: ctx.download(&g.geo, 0, scene.num_grid_points()).unwrap(),
        sh0: ctx.download(&g.sh0, 0, n * 3).unwrap(),
        shs: g.download_shs(ctx).unwrap(),
        priority: ctx.download(&g.priority, 0, n).unwrap(),
        max_tile: stats.max_tile_entries,
    })
}

/// Largest |gpu − ref| relative to the largest |ref| of the group.
pub fn rel_err(gpu: &[f32], reference: &[f64]) -> f64 {
    assert_eq!(gpu.len(), reference.len());
    let scale = reference.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let err = gpu
        .iter()
        .zip(reference)
        .fold(0.0f64, |m, (&g, &r)| m.max((g as f64 - r).abs()));
    assert!(gpu.iter().all(|v| v.is_finite()), "non-finite GPU gradient");
    if scale == 0.0 {
        err
    } else {
        err / scale
    }
}

pub fn random_weights(rng: &mut Rng, n: usize, on: [bool; 5]) -> Vec<PixelWeights> {
    (0..n)
        .map(|_| {
            let mut u = || rng.range(-1.0, 1.0);
            let mut w = PixelWeights::default();
            if on[0] {
                w.rgb = [u(), u(), u()];
            }
            if on[1] {
                w.alpha = u();
            }
            if on[2] {
                w.depth = u();
            }
            if on[3] {
                w.normal = [u(), u(), u()];
            }
            w.gt = [rng.unit(), rng.unit(), rng.unit()];
            w
        })
        .collect()
}

/// The reference forward of every pixel of `cam` with K = `k` (no loss weights): which
/// entries each pixel composites, with their transmittance and alpha.
pub fn forward_eval(scene: &Scene, cam: &Camera, k: u32) -> Eval {
    let rays = pixel_rays(scene, cam);
    let np = rays.len();
    evaluate(
        scene,
        &Params::of(scene),
        &rays,
        k as usize,
        &vec![PixelWeights::default(); np],
        &LossSpec::default(),
        None,
    )
}

/// Whether f32 and f64 may legitimately disagree about which entries a pixel
/// composites: the transmittance after an entry within 0.1 % of the early-stop
/// threshold, or a contributor's alpha within 1 % of the skip threshold. Early
/// termination is a discontinuity whose effect on ∂L/∂α of the entries before it is
/// O(1) (∂(T·α_next)/∂α = −α_next however small T is), so such cases are redrawn.
pub fn ambiguous(scene: &Scene, cam: &Camera, k: u32) -> bool {
    let ev = forward_eval(scene, cam, k);
    ev.contributors.iter().flatten().any(|c| {
        let after = c.t * (1.0 - c.alpha);
        (after / 1e-4 - 1.0).abs() < 1e-3 || (c.alpha / 1e-5 - 1.0).abs() < 1e-2
    })
}

/// Stated bound: every gradient group within 2e-4 of its largest reference magnitude
/// (measured worst: 1.2e-5 for densities, 1.5e-6 for SH and priority).
pub const BOUND: f64 = 2e-4;

pub fn compare(tag: &str, g: &GpuGrads, r: &RefGrads, worst: &mut [f64; 4]) {
    compare_within(tag, g, r, worst, BOUND)
}

pub fn compare_within(tag: &str, g: &GpuGrads, r: &RefGrads, worst: &mut [f64; 4], bound: f64) {
    let sh0: Vec<f64> = r.sh0.iter().flatten().copied().collect();
    let e = [
        rel_err(&g.geo, &r.geo),
        rel_err(&g.sh0, &sh0),
        if r.shs.is_empty() {
            0.0
        } else {
            rel_err(&g.shs, &r.shs)
        },
        rel_err(&g.priority, &r.priority),
    ];
    for i in 0..4 {
        worst[i] = worst[i].max(e[i]);
    }

    assert!(
        e.iter().all(|&x| x <= bound),
        "{tag}: relative errors geo {:.2e} sh0 {:.2e} shs {:.2e} priority {:.2e} exceed {bound:e}",
        e[0],
        e[1],
        e[2],
        e[3]
    );
}
