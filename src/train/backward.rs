//! The training backward (paper §3.2; docs/ARCHITECTURE.md §4): from the loss gradients of a rendered
//! frame to the gradients of every model parameter.
//!
//! Recorded after the frame (same [`Renderer`](crate::raster::Renderer), nothing recorded in between):
//! **grad_prepare** (output → render resolution: transposed downsample and finalize) →
//! **backward** chunks, last first (workgroup per tile, back to front; subgroup
//! reductions, one float atomic per subgroup and voxel) → **voxel_backward** (SH
//! coefficients, normals, scatter to grid points). Devices without
//! `shaderBufferFloat32AtomicAdd` get compare-and-swap variants of the two atomic kernels.
//!
//! [`Reduction::Ordered`] (`--deterministic`) replaces every float atomic by sums in a
//! fixed order: the walk writes one record per entry (subgroups of a tile take turns),
//! **records_gather** sums a voxel's records in emission order, voxel_backward and TV
//! write per voxel corner, and **point_gather** sums each grid point's corners in
//! ascending order ([`Gradients`] holds the grid point → corner lists). Two runs on one
//! device then give the same bits.

use ash::vk;

pub use super::config::ClampGrad;
use crate::error::{Error, Result};
use crate::gpu::kernels::push_constants;
use crate::gpu::{
    glsl, gpu_layout, kernels, recorder, Buffer, Context, GrowBuffer, Kernel, LazyKernel, Memory,
    Timestamps,
};
use crate::raster::{FrameGeometry, FrameMeanPush, FrameStats};
use crate::scene::SceneGpu;

mod record;

/// Planar channels of the output-resolution gradient image the losses write
/// (`DO_*` in glsl/lib/backward_params.glsl).
pub mod dout {
    use crate::gpu::glsl;
    pub const R: usize = glsl::DO_R as usize;
    pub const G: usize = glsl::DO_G as usize;
    pub const B: usize = glsl::DO_B as usize;
    pub const ALPHA: usize = glsl::DO_ALPHA as usize;
    pub const DEPTH: usize = glsl::DO_DEPTH as usize;
    pub const NX: usize = glsl::DO_NX as usize;
    pub const NY: usize = glsl::DO_NY as usize;
    pub const NZ: usize = glsl::DO_NZ as usize;
    pub const GT_R: usize = glsl::DO_GTR as usize;
    pub const GT_G: usize = glsl::DO_GTG as usize;
    pub const GT_B: usize = glsl::DO_GTB as usize;
    pub const CHANNELS: usize = glsl::DO_CHANNELS as usize;
}
const DI_CHANNELS: u64 = crate::gpu::glsl::DI_CHANNELS as u64;
const BS_CHANNELS: u64 = crate::gpu::glsl::BS_CHANNELS as u64;
/// Floats per voxel of the per-voxel gradient record.
const VG_STRIDE: u64 = crate::gpu::glsl::VG_STRIDE as u64;

/// How gradient contributions that meet at one parameter are summed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reduction {
    /// Native float atomic adds (VK_EXT_shader_atomic_float): the fastest; the order of
    /// the adds, and with it the last bits of the sums, varies from run to run.
    Atomic,
    /// Compare-and-swap loops on the bits (any device); the order varies likewise.
    CompareSwap,
    /// No float atomics: per-entry and per-corner records summed in a fixed order, so two
    /// runs with the same inputs on one device give bitwise-identical gradients
    /// (`--deterministic`; costs one record of 64 bytes per entry and 68 bytes per voxel).
    Ordered,
}

impl Reduction {
    /// Index of the reduction in the variant families (`glsl/variants.rs`: native
    /// atomics, compare-and-swap, ordered).
    pub(crate) fn index(self) -> usize {
        match self {
            Reduction::Atomic => 0,
            Reduction::CompareSwap => 1,
            Reduction::Ordered => 2,
        }
    }

    /// Ordered when `deterministic`, else native float atomics where the device has
    /// them and `float_atomics` allows it, else compare-and-swap.
    pub fn choose(ctx: &Context, float_atomics: bool, deterministic: bool) -> Reduction {
        if deterministic {
            Reduction::Ordered
        } else if float_atomics && ctx.info().float_atomic_add {
            Reduction::Atomic
        } else {
            Reduction::CompareSwap
        }
    }

    /// Name in logs and JSON: "float-atomics", "compare-and-swap" or "ordered".
    pub fn name(self) -> &'static str {
        match self {
            Reduction::Atomic => "float-atomics",
            Reduction::CompareSwap => "compare-and-swap",
            Reduction::Ordered => "ordered",
        }
    }
}

/// The grid point → voxel corner lists of a layout, for [`Reduction::Ordered`]: grid
/// point g's corners are `list[off[g]..off[g + 1]]`, each `8 · voxel + corner`, ascending,
/// with the per-corner gradient buffer they index.
pub struct PointLists {
    off: Buffer,
    list: Buffer,
    vcorner: Buffer,
}

impl PointLists {
    /// Builds the lists of `scene` on the host from its corner indices (downloaded).
    pub fn new(ctx: &Context, scene: &SceneGpu) -> Result<PointLists> {
        let corners: Vec<u32> = if scene.voxels == 0 {
            Vec::new()
        } else {
            ctx.download(&scene.corners, 0, scene.voxels as usize * 8)?
        };
        let (off, list) = point_lists(&corners, scene.grid_points)?;
        Ok(PointLists {
            off: ctx.buffer_from("grad.point-offsets", &off)?,
            list: ctx.buffer_from(
                "grad.point-corners",
                if list.is_empty() { &[0u32][..] } else { &list },
            )?,
            vcorner: ctx.zeroed_buffer("grad.voxel-corners", (corners.len().max(1) * 4) as u64)?,
        })
    }

    /// Device bytes per voxel the lists and the per-corner gradients take (8 corners:
    /// 4 bytes of list and 4 of gradient each; the offsets, one per grid point, add
    /// about 4 more).
    pub const BYTES_PER_VOXEL: u64 = 68;
}

/// Counting sort of corner indices by grid point: `(off, list)` with grid point g's
/// corners (`8 · voxel + corner`) in `list[off[g]..off[g + 1]]`, ascending.
pub fn point_lists(corners: &[u32], grid_points: u32) -> Result<(Vec<u32>, Vec<u32>)> {
    let mut off = vec![0u32; grid_points as usize + 1];
    for (i, &g) in corners.iter().enumerate() {
        if g >= grid_points {
            return Err(Error::Invalid(format!(
                "voxel {} corner {} names grid point {g}, but the layout has {grid_points}",
                i / 8,
                i % 8
            )));
        }
        off[g as usize + 1] += 1;
    }
    for g in 0..grid_points as usize {
        off[g + 1] += off[g];
    }
    let mut next = off.clone();
    let mut list = vec![0u32; corners.len()];
    for (i, &g) in corners.iter().enumerate() {
        list[next[g as usize] as usize] = i as u32;
        next[g as usize] += 1;
    }
    Ok((off, list))
}

/// Gradients of the model parameters (same layouts as [`SceneGpu`]'s buffers: `shs` in
/// the blocked device layout, [`Gradients::download_shs`] gives the host's), and the
/// per-voxel subdivision priority Σ|α·∂L/∂α|, which accumulates over backward passes
/// until [`Gradients::record_clear_priority`].
pub struct Gradients {
    pub geo: Buffer,
    pub sh0: Buffer,
    pub shs: Buffer,
    pub priority: Buffer,
    pub voxels: u32,
    pub grid_points: u32,
    pub shs_per_voxel: u32,
    /// The grid point lists of [`Reduction::Ordered`] (None for the atomic reductions).
    points: Option<PointLists>,
}

impl Gradients {
    /// Zeroed gradient buffers for `scene` (for the atomic reductions).
    pub fn new(ctx: &Context, scene: &SceneGpu) -> Result<Gradients> {
        Self::with_reduction(ctx, scene, Reduction::Atomic)
    }

    /// Zeroed gradient buffers for `scene` and a backward with `reduction` (Ordered also
    /// builds the grid point lists: the scene's corners are downloaded once).
    pub fn with_reduction(
        ctx: &Context,
        scene: &SceneGpu,
        reduction: Reduction,
    ) -> Result<Gradients> {
        let n = scene.voxels.max(1) as u64;
        let mk = |name: &str, floats: u64| ctx.zeroed_buffer(name, floats * 4);
        Ok(Gradients {
            geo: mk("grad.geo", scene.grid_points as u64)?,
            sh0: mk("grad.sh0", n * 3)?,
            shs: mk(
                "grad.shs",
                crate::scene::shs_device_len(n as usize, 3 * scene.shs_per_voxel as usize) as u64,
            )?,
            priority: mk("grad.priority", n)?,
            voxels: scene.voxels,
            grid_points: scene.grid_points,
            shs_per_voxel: scene.shs_per_voxel,
            points: match reduction {
                Reduction::Ordered => Some(PointLists::new(ctx, scene)?),
                _ => None,
            },
        })
    }

    /// Gradient buffers for no scene (4 bytes each): what a trainer holds while a layout
    /// change builds the new scene, so the old gradients do not add to its peak memory.
    pub fn empty(ctx: &Context) -> Result<Gradients> {
        let mk = |name: &str| ctx.zeroed_buffer(name, 4);
        Ok(Gradients {
            geo: mk("grad.geo")?,
            sh0: mk("grad.sh0")?,
            shs: mk("grad.shs")?,
            priority: mk("grad.priority")?,
            voxels: 0,
            grid_points: 0,
            shs_per_voxel: 0,
            points: None,
        })
    }

    /// The SH coefficient gradients in the host layout (`[N][coeffs][3]`; the buffer
    /// holds them in the blocked device layout, [`crate::scene::SHS_BLOCK`]).
    pub fn download_shs(&self, ctx: &Context) -> Result<Vec<f32>> {
        let (n, w) = (self.voxels as usize, 3 * self.shs_per_voxel as usize);
        if n * w == 0 {
            return Ok(Vec::new());
        }
        crate::scene::download_shs(ctx, &self.shs, n, w)
    }

    /// Records zeroing the accumulated priority.
    pub fn record_clear_priority(&self, ctx: &Context, cmd: vk::CommandBuffer) {
        recorder::zero(ctx, cmd, &self.priority);
    }

    fn matches(&self, scene: &SceneGpu) -> bool {
        self.voxels == scene.voxels
            && self.grid_points == scene.grid_points
            && self.shs_per_voxel == scene.shs_per_voxel
    }
}

/// Loss weights the backward applies per entry (per render pixel: divide the loss
/// weight by the number of render pixels for a mean).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EntryLosses {
    /// Distortion loss weight.
    pub lambda_dist: f32,
    /// Per-point RGB loss weight (ours: λ·Σ_k w_k |c_k − gt|²/3, differentiated through
    /// the colours, the opacities and so the priority).
    pub lambda_r: f32,
    /// Per-point RGB loss weight in SVRaster's form (`backward.cu`, `lambda_R_concen`):
    /// λ·Σ_k w_k |c_k − gt|² with the blending weights w_k held constant, so its only
    /// gradient is 2λ·w_k·(c_k − gt) on the colours (no opacity, no priority).
    pub lambda_r_colour: f32,
    /// Transmittance concentration T²(1−T)² on the render-resolution final
    /// transmittance, per render pixel (SVRaster's `prob_concen_loss(raw_T)`; the
    /// output-resolution form is [`super::loss::PixelLoss`]'s).
    pub lambda_t: f32,
    /// The inside term T² on the render-resolution transmittance, per render pixel
    /// (SVRaster's `raw_T.square().mean()`).
    pub lambda_t_inside: f32,
    /// The per-point RGB target at render resolution: the photo bilinearly resized
    /// (SVRaster's `resize_rendering`), instead of the photo pixel containing the render
    /// pixel's centre. Only differs on supersampled frames.
    pub r_target_bilinear: bool,
}

/// Mirror of `BackParams` in glsl/lib/backward_params.glsl (checked by `gpu_layout!`).
#[repr(C)]
#[derive(Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct BackParams {
    lambda_dist: f32,
    lambda_r: f32,
    chunks: u32,
    chunk_size: u32,
    voxels: u32,
    lambda_r_colour: f32,
    out_size: [u32; 2],
    render_size: [u32; 2],
    dimg: u64,
    dout: u64,
    bstate: u64,
    vgrad: u64,
    grad_geo: u64,
    grad_sh0: u64,
    grad_shs: u64,
    priority: u64,
    lost: u64,
    records: u64,
    vcorner: u64,
    point_off: u64,
    point_list: u64,
    gather_span: u32,
    /// 1: the colour gradient passes the clamp straight through ([`ClampGrad::Straight`]).
    colour_straight: u32,
    /// 1: the density gradient passes the α clamp straight through
    /// (`alpha_clamp_grad` = [`ClampGrad::Straight`]).
    alpha_straight: u32,
    lambda_t: f32,
    lambda_t_inside: f32,
    /// 1: the per-point RGB target is the photo bilinearly resized.
    r_bilinear: u32,
    pad4: u32,
    pad5: u32,
}
gpu_layout!(BackParams, BackParams);

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Push2 {
    frame: u64,
    back: u64,
}
push_constants!(TRAIN_GRAD_PREPARE, Push2);
push_constants!(TRAIN_SEG_BMERGE, Push2);
push_constants!(TRAIN_VOXEL_BACKWARD_VARIANTS, Push2);

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ChunkPush {
    frame: u64,
    back: u64,
    chunk: u32,
    /// The walk: `SEG_OFF` (per tile, in chunks) or `SEG_EXACT` (per segment); 0
    /// for the other kernels.
    mode: u32,
}
push_constants!(TRAIN_BACKWARD_VARIANTS, ChunkPush);
push_constants!(TRAIN_BACKWARD_COUNTERS_VARIANTS, ChunkPush);
push_constants!(TRAIN_BACKWARD_NONORMAL_VARIANTS, ChunkPush);
push_constants!(TRAIN_RECORDS_GATHER, ChunkPush);

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct PointPush {
    frame: u64,
    back: u64,
    points: u32,
    pad: u32,
}
push_constants!(TRAIN_POINT_GATHER, PointPush);

/// Kernels of the ordered reduction's two gathers.
struct OrderedKernels {
    records: Kernel,
    points: Kernel,
}

/// The backward pass with its kernels and scratch buffers.
pub struct Backward {
    ctx: Context,
    prepare_k: Kernel,
    /// The gradient through a frame-mean background (raster/frame_mean.comp).
    frame_mean: Kernel,
    seg_bmerge: Kernel,
    /// [plain, work counters][samples - 1].
    backward: [[Kernel; 3]; 2],
    /// [samples - 1]: for frames without a normal image, made on first use.
    nonormal: [LazyKernel; 3],
    voxel: Kernel,
    reduction: Reduction,
    ordered: Option<OrderedKernels>,
    chunk_size: u32,
    /// Records per voxel one records_gather pass sums (the loop limit).
    gather_span: u32,
    clamp_grad: ClampGrad,
    alpha_clamp_grad: ClampGrad,
    params: Buffer,
    lost: Buffer,
    dout: GrowBuffer,
    dimg: GrowBuffer,
    bstate: GrowBuffer,
    vgrad: GrowBuffer,
    records: GrowBuffer,
}

impl Backward {
    /// Kernels for this device: native float atomics when the device has them and
    /// `float_atomics` allows it, compare-and-swap otherwise.
    pub fn new(ctx: &Context, float_atomics: bool) -> Result<Backward> {
        Self::with_reduction(ctx, Reduction::choose(ctx, float_atomics, false))
    }

    /// Kernels for `reduction` ([`Reduction::Atomic`] needs the device's float atomics).
    pub fn with_reduction(ctx: &Context, reduction: Reduction) -> Result<Backward> {
        if reduction == Reduction::Atomic && !ctx.info().float_atomic_add {
            return Err(Error::Invalid(
                "this device has no float atomic adds; use Reduction::choose".into(),
            ));
        }
        let r = reduction.index();
        let (k, kc, kl, v) = (
            kernels::TRAIN_BACKWARD_VARIANTS[r],
            kernels::TRAIN_BACKWARD_COUNTERS_VARIANTS[r],
            kernels::TRAIN_BACKWARD_NONORMAL_VARIANTS[r],
            kernels::TRAIN_VOXEL_BACKWARD_VARIANTS[r],
        );
        let ordered = match reduction {
            Reduction::Ordered => Some(OrderedKernels {
                records: Kernel::new(ctx, &kernels::TRAIN_RECORDS_GATHER)?,
                points: Kernel::new(ctx, &kernels::TRAIN_POINT_GATHER)?,
            }),
            _ => None,
        };
        let lost = ctx.counter_buffer("backward.lost", 4)?;
        Ok(Backward {
            ctx: ctx.clone(),
            prepare_k: Kernel::new(ctx, &kernels::TRAIN_GRAD_PREPARE)?,
            frame_mean: Kernel::new(ctx, &kernels::RASTER_FRAME_MEAN)?,
            seg_bmerge: Kernel::new(ctx, &kernels::TRAIN_SEG_BMERGE)?,
            backward: [
                [
                    Kernel::new(ctx, k[0])?,
                    Kernel::new(ctx, k[1])?,
                    Kernel::new(ctx, k[2])?,
                ],
                [
                    Kernel::new(ctx, kc[0])?,
                    Kernel::new(ctx, kc[1])?,
                    Kernel::new(ctx, kc[2])?,
                ],
            ],
            nonormal: kl.map(LazyKernel::new),
            voxel: Kernel::new(ctx, v)?,
            reduction,
            ordered,
            // The ordered walk adds a turn per subgroup and batch (16 per 128 entries on
            // 8-lane subgroups); where a driver runs a skipped turn's loops with every
            // lane masked off (llvmpipe without real branches) each turn costs a few
            // loop iterations more, so it keeps the compare-and-swap chunk's margin.
            chunk_size: ctx
                .info()
                .backward_chunk_entries(reduction == Reduction::Atomic),
            gather_span: if ctx.info().loop_limit() {
                16384
            } else {
                u32::MAX
            },
            clamp_grad: ClampGrad::Masked,
            alpha_clamp_grad: ClampGrad::Masked,
            params: ctx.buffer(
                "backward.params",
                std::mem::size_of::<BackParams>() as u64,
                Memory::Device,
            )?,
            lost,
            dout: GrowBuffer::new("backward.dout"),
            dimg: GrowBuffer::new("backward.dimg"),
            bstate: GrowBuffer::new("backward.state"),
            vgrad: GrowBuffer::new("backward.voxel-grads"),
            records: GrowBuffer::new("backward.entry-records"),
        })
    }

    /// Whether the native float-atomic kernels are in use.
    pub fn float_atomics(&self) -> bool {
        self.reduction == Reduction::Atomic
    }

    /// How the gradients are summed.
    pub fn reduction(&self) -> Reduction {
        self.reduction
    }

    /// Records per voxel one records_gather pass sums (tests shrink it to exercise
    /// several passes).
    pub fn set_gather_span(&mut self, records: u32) {
        self.gather_span = records.max(1);
    }

    /// How the colour gradient passes the clamp max(0, 0.5 + SH) (default: masked).
    pub fn set_colour_clamp_grad(&mut self, mode: ClampGrad) {
        self.clamp_grad = mode;
    }

    /// The colour clamp's gradient rule in use.
    pub fn colour_clamp_grad(&self) -> ClampGrad {
        self.clamp_grad
    }

    /// How the density gradient passes the clamp α = min(MAX_ALPHA, 1 − exp(−vol))
    /// (default: masked, the clamp's derivative 0; straight: exp(−vol) as if
    /// unclamped, SVRaster's `backward.cu`).
    pub fn set_alpha_clamp_grad(&mut self, mode: ClampGrad) {
        self.alpha_clamp_grad = mode;
    }

    /// Entries per backward dispatch (tests shrink it to exercise chunking).
    pub fn set_chunk_size(&mut self, entries: u32) {
        self.chunk_size = entries.max(1);
    }

    /// Allocates the scratch a frame of this geometry and voxel count needs.
    pub fn prepare(&mut self, frame: &FrameGeometry, voxels: u32) -> Result<()> {
        let ctx = self.ctx.clone();
        let opix = frame.out_width as u64 * frame.out_height as u64;
        let rpix = frame.render_width as u64 * frame.render_height as u64;
        self.dout.ensure(&ctx, opix * dout::CHANNELS as u64 * 4)?;
        self.dimg.ensure(&ctx, rpix * DI_CHANNELS * 4)?;
        self.bstate.ensure(&ctx, rpix * BS_CHANNELS * 4)?;
        self.vgrad
            .ensure(&ctx, voxels.max(1) as u64 * VG_STRIDE * 4)?;
        Ok(())
    }

    /// The output-resolution gradient image (planar [`dout::CHANNELS`] channels) the
    /// losses write before [`Backward::record`]; every channel must be written.
    pub fn dout(&self) -> Result<&Buffer> {
        self.dout
            .buffer()
            .ok_or_else(|| Error::Invalid("Backward::dout before Backward::prepare".into()))
    }

    /// The per-voxel gradients of the last recorded backward before its per-voxel
    /// stage (`VG_STRIDE` floats per voxel: 8 corner densities, then rgb at `VG_RGB`,
    /// normal, priority), valid once it completed: with only colour gradients in
    /// [`Backward::dout`], the rgb of voxel k are Σ_pixels T_k α_k · dout (the adjoint
    /// of compositing, which field fusion reads: `crate::field`).
    pub(crate) fn voxel_gradients(&self) -> Result<&Buffer> {
        self.vgrad.buffer().ok_or_else(|| {
            Error::Invalid("Backward::voxel_gradients before Backward::prepare".into())
        })
    }

    /// Compare-and-swap float adds that gave up (must stay 0; see atomic_f32.glsl).
    /// Reads host-visible memory: no submission, the backward must have completed.
    pub fn read_lost(&self) -> Result<u32> {
        self.lost.read_word(0)
    }
}
