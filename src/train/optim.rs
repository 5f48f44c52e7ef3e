//! The optimiser (Adam, thread per parameter) and the total-variation regulariser on
//! the grid-point densities, recorded into any command buffer.
//!
//! Adam follows the paper's settings by default (β₁ = 0.1, β₂ = 0.99, ε = 1e-15): the
//! bias corrections are computed on the host in f64 and folded into two scalars, the
//! kernel is safe for gradients up to ~1e20 (no f32 overflow in g² or v/bc₂; v saturates
//! at `f32::MAX`), and a zero first moment gives an update of exactly 0. Non-finite
//! gradients or parameters raise a sticky flag ([`Adam::read_nonfinite`]).
//!
//! TV: L_tv = Σ_voxels Σ over the 12 cube edges (a, b) of `(geo[a] − geo[b])²`; [`Tv::record`] adds
//! `weight · ∂L_tv/∂geo` into a gradient buffer and leaves per-workgroup partial sums of
//! L_tv (unweighted) for [`Tv::read_value`]. With [`TvForm::L1`] ([`Tv::set_form`]) the
//! penalty is SVRaster's instead: `Σ |geo[a] − geo[b]|` over the same edges, with its
//! gradient rule `weight · Σ_3 edges (geo[c] > geo[nb] ? 1 : −1)` (equal ends give −1 to
//! both, as its `cuda/src/tv_compute.cu`).

use ash::vk;
use bytemuck::{Pod, Zeroable};

use super::backward::Reduction;
pub use super::config::TvForm;
use crate::error::{Error, Result};
use crate::gpu::kernels::push_constants;
use crate::gpu::{kernels, recorder, Buffer, Context, GrowBuffer, Kernel};

/// Adam moments of one parameter group.
pub(super) struct Moments {
    pub(super) m: Buffer,
    pub(super) v: Buffer,
}

impl Moments {
    pub(super) fn new(ctx: &Context, name: &str, count: u64) -> Result<Moments> {
        let bytes = count.max(1) * 4;
        Ok(Moments {
            m: ctx.zeroed_buffer(&format!("{name}.adam-m"), bytes)?,
            v: ctx.zeroed_buffer(&format!("{name}.adam-v"), bytes)?,
        })
    }
}

/// Bit of the Adam flags word set by a non-finite gradient or parameter.
pub const ADAM_FLAG_NONFINITE: u32 = 1;

/// Adam hyper-parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamConfig {
    pub lr: f32,
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    /// Skip parameters whose gradient is exactly zero (selective Adam: no moment decay,
    /// no update, no memory traffic beyond reading the gradient).
    pub skip_zero: bool,
}

impl Default for AdamConfig {
    /// lr 1e-3, β₁ 0.1, β₂ 0.99, ε 1e-15 (SVRaster's settings), dense.
    fn default() -> Self {
        AdamConfig {
            lr: 1e-3,
            beta1: 0.1,
            beta2: 0.99,
            eps: 1e-15,
            skip_zero: false,
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct AdamPush {
    param: u64,
    grad: u64,
    m: u64,
    v: u64,
    flags: u64,
    count: u32,
    b1: f32,
    omb1: f32,
    b2: f32,
    omb2: f32,
    step: f32,
    rsqrt_bc2: f32,
    eps: f32,
    skip_zero: u32,
    pad: u32,
}
push_constants!(TRAIN_ADAM, AdamPush);

impl AdamPush {
    /// The block for step `t` (≥ 1; 0 is treated as 1), the bias corrections in f64.
    #[allow(clippy::too_many_arguments)]
    fn new(
        param: u64,
        grad: u64,
        m: u64,
        v: u64,
        flags: u64,
        count: u32,
        t: u32,
        cfg: &AdamConfig,
    ) -> AdamPush {
        let t = t.clamp(1, i32::MAX as u32) as i32;
        let b1 = f64::from(cfg.beta1);
        let b2 = f64::from(cfg.beta2);
        let bc1 = 1.0 - b1.powi(t);
        let bc2 = 1.0 - b2.powi(t);
        AdamPush {
            param,
            grad,
            m,
            v,
            flags,
            count,
            b1: cfg.beta1,
            omb1: (1.0 - b1) as f32,
            b2: cfg.beta2,
            omb2: (1.0 - b2) as f32,
            step: (f64::from(cfg.lr) / bc1) as f32,
            rsqrt_bc2: (1.0 / bc2.sqrt()) as f32,
            eps: cfg.eps,
            skip_zero: cfg.skip_zero as u32,
            pad: 0,
        }
    }
}

/// The Adam step kernel and its sticky non-finite flag.
pub struct Adam {
    ctx: Context,
    kernel: Kernel,
    flags: Buffer,
}

impl Adam {
    pub fn new(ctx: &Context) -> Result<Adam> {
        Ok(Adam {
            ctx: ctx.clone(),
            kernel: Kernel::new(ctx, &kernels::TRAIN_ADAM)?,
            flags: ctx.buffer_from("adam.flags", &[0u32; 4])?,
        })
    }

    /// Records one step for `count` elements (buffers by device address, f32 each),
    /// t = `step` (≥ 1; 0 is treated as 1), followed by a compute barrier. Needs
    /// 0 ≤ β < 1 (β = 1 makes a bias correction 0: every moved parameter becomes
    /// non-finite and is flagged). A non-finite gradient leaves its element's parameter
    /// and moments untouched. All parameter groups share one flag.
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &self,
        cmd: vk::CommandBuffer,
        param: u64,
        grad: u64,
        m: u64,
        v: u64,
        count: u32,
        step: u32,
        cfg: &AdamConfig,
    ) {
        if count == 0 {
            return;
        }
        assert!(
            [param, grad, m, v].iter().all(|a| a % 16 == 0),
            "Adam buffers must be 16-byte aligned"
        );
        // The kernel indexes 4·invocation in u32.
        assert!(
            count <= u32::MAX - 1024,
            "Adam: {count} elements exceed the u32 index"
        );
        let push = AdamPush::new(param, grad, m, v, self.flags.address(), count, step, cfg);
        // Four elements per invocation (glsl/train/adam.comp).
        self.kernel.dispatch_1d(cmd, &push, count.div_ceil(4));
        recorder::barrier(&self.ctx, cmd);
    }

    /// Non-finite gradient/parameter seen since the last reset (waits for the device).
    pub fn read_nonfinite(&self) -> Result<bool> {
        let f: Vec<u32> = self.ctx.download(&self.flags, 0, 1)?;
        Ok(f[0] & ADAM_FLAG_NONFINITE != 0)
    }

    /// Records a clear of the flag (followed by a barrier).
    pub fn record_reset(&self, cmd: vk::CommandBuffer) {
        recorder::zero(&self.ctx, cmd, &self.flags);
        recorder::barrier(&self.ctx, cmd);
    }
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct TvPush {
    corners: u64,
    geo: u64,
    grad: u64,
    partials: u64,
    lost: u64,
    voxels: u32,
    weight: f32,
    form: u32,
    pad_: u32,
}
push_constants!(TRAIN_TV_VARIANTS, TvPush);

/// The TV regulariser on the grid-point densities.
pub struct Tv {
    ctx: Context,
    kernel: Kernel,
    reduction: Reduction,
    partials: GrowBuffer,
    /// Partials buffers replaced by a larger one: a command buffer recorded but not yet
    /// completed may still write them, so they live as long as `self` (growth by 1.25×
    /// bounds them by 4× the current one, 4 bytes per 256 voxels).
    retired: Vec<Buffer>,
    lost: Buffer,
    last_groups: u32,
    form: TvForm,
}

impl Tv {
    /// `float_atomics`: use native float atomic adds where the device has them; false
    /// forces the compare-and-swap variant.
    pub fn new(ctx: &Context, float_atomics: bool) -> Result<Tv> {
        Self::with_reduction(ctx, Reduction::choose(ctx, float_atomics, false))
    }

    /// The variant for `reduction`: with [`Reduction::Ordered`], [`Tv::record`]'s `grad`
    /// is the backward's per-voxel-corner buffer (8 floats per voxel), not the
    /// grid-point gradients (see [`super::backward::Backward::record_timed`]).
    pub fn with_reduction(ctx: &Context, reduction: Reduction) -> Result<Tv> {
        let src = match reduction {
            Reduction::Atomic if !ctx.info().float_atomic_add => {
                return Err(Error::Invalid(
                    "this device has no float atomic adds; use Reduction::choose".into(),
                ))
            }
            r => kernels::TRAIN_TV_VARIANTS[r.index()],
        };
        Ok(Tv {
            ctx: ctx.clone(),
            kernel: Kernel::new(ctx, src)?,
            reduction,
            partials: GrowBuffer::new("tv.partials"),
            retired: Vec::new(),
            lost: ctx.counter_buffer("tv.lost", 4)?,
            last_groups: 0,
            form: TvForm::L2,
        })
    }

    /// The penalty recorded from now on (L2 unless set).
    pub fn set_form(&mut self, form: TvForm) {
        self.form = form;
    }

    /// The penalty [`Tv::record`] records.
    pub fn form(&self) -> TvForm {
        self.form
    }

    /// Whether the native float-atomic variant is in use.
    pub fn uses_float_atomics(&self) -> bool {
        self.reduction == Reduction::Atomic
    }

    /// How the gradient adds are made.
    pub fn reduction(&self) -> Reduction {
        self.reduction
    }

    /// Records the TV of `voxels` voxels: `grad[i] += weight · ∂L_tv/∂geo[i]` (grid-point
    /// indices from `corners`, 8 u32 per voxel), and the partial sums of L_tv, followed
    /// by a compute barrier. Grows the partials buffer as needed (call before the
    /// command buffer is submitted).
    pub fn record(
        &mut self,
        cmd: vk::CommandBuffer,
        corners: u64,
        geo: u64,
        grad: u64,
        voxels: u32,
        weight: f32,
    ) -> Result<()> {
        if !weight.is_finite() {
            return Err(Error::Invalid(format!("TV weight {weight} is not finite")));
        }
        let groups = self.kernel.groups_1d(voxels);
        let need = u64::from(groups.max(1)) * 4;
        self.partials
            .ensure_retiring(&self.ctx, need, &mut self.retired)?;
        self.last_groups = groups;
        if groups == 0 {
            return Ok(());
        }
        let push = TvPush {
            corners,
            geo,
            grad,
            partials: self.partials.buffer().map_or(0, |b| b.address()),
            lost: self.lost.address(),
            voxels,
            weight,
            form: match self.form {
                TvForm::L2 => 0,
                TvForm::L1 => 1,
            },
            pad_: 0,
        };
        self.kernel.dispatch_1d(cmd, &push, voxels);
        recorder::barrier(&self.ctx, cmd);
        Ok(())
    }

    /// L_tv (unweighted) of the last record, summed in f64 (after it completed).
    pub fn read_value(&self) -> Result<f64> {
        if self.last_groups == 0 {
            return Ok(0.0);
        }
        let buf = self
            .partials
            .buffer()
            .ok_or_else(|| Error::Gpu("TV partials missing".into()))?;
        let p: Vec<f32> = self.ctx.download(buf, 0, self.last_groups as usize)?;
        Ok(p.iter().map(|&x| f64::from(x)).sum())
    }

    /// Compare-and-swap give-ups since creation (must be 0; always 0 with float atomics).
    /// Reads host-visible memory: no submission, the TV must have completed.
    pub fn read_lost(&self) -> Result<u32> {
        self.lost.read_word(0)
    }
}
