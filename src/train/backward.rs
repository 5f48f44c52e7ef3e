//! The training backward (paper §3.2; DESIGN §4): from the loss gradients of a rendered
//! frame to the gradients of every model parameter.
//!
//! Recorded after the frame (same [`Renderer`](crate::raster::Renderer), nothing recorded in between):
//! **grad_prepare** (output → render resolution: transposed downsample and finalize) →
//! **backward** chunks, last first (workgroup per tile, back to front; subgroup
//! reductions, one float atomic per subgroup and voxel) → **voxel_backward** (SH
//! coefficients, normals, scatter to grid points). Devices without
//! `shaderBufferFloat32AtomicAdd` get compare-and-swap variants of the two atomic kernels.

use ash::vk;

use crate::gpu::{kernels, recorder, Buffer, Context, GrowBuffer, Kernel, Memory, Timestamps};
use crate::push_constants;
use crate::raster::{FrameGeometry, FrameStats};
use crate::scene::SceneGpu;
use crate::{Error, Result};

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

/// Gradients of the model parameters (same layouts as [`SceneGpu`]'s buffers), and the
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
}

impl Gradients {
    /// Zeroed gradient buffers for `scene`.
    pub fn new(ctx: &Context, scene: &SceneGpu) -> Result<Gradients> {
        let n = scene.voxels.max(1) as u64;
        let mk = |name: &str, floats: u64| ctx.zeroed_buffer(name, floats * 4);
        Ok(Gradients {
            geo: mk("grad.geo", scene.grid_points as u64)?,
            sh0: mk("grad.sh0", n * 3)?,
            shs: mk("grad.shs", n * 3 * scene.shs_per_voxel as u64)?,
            priority: mk("grad.priority", n)?,
            voxels: scene.voxels,
            grid_points: scene.grid_points,
            shs_per_voxel: scene.shs_per_voxel,
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
        })
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
    /// Per-point RGB loss weight.
    pub lambda_r: f32,
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
    pad0: u32,
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
}
gpu_layout!(BackParams, BackParams);

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Push2 {
    frame: u64,
    back: u64,
}
push_constants!(Push2, kernels::TRAIN_GRAD_PREPARE);
push_constants!(Push2, kernels::TRAIN_VOXEL_BACKWARD);
push_constants!(Push2, kernels::TRAIN_VOXEL_BACKWARD_CAS);

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ChunkPush {
    frame: u64,
    back: u64,
    chunk: u32,
    pad: u32,
}
push_constants!(ChunkPush, kernels::TRAIN_BACKWARD_K1);
push_constants!(ChunkPush, kernels::TRAIN_BACKWARD_K2);
push_constants!(ChunkPush, kernels::TRAIN_BACKWARD_K3);
push_constants!(ChunkPush, kernels::TRAIN_BACKWARD_K1_CAS);
push_constants!(ChunkPush, kernels::TRAIN_BACKWARD_K2_CAS);
push_constants!(ChunkPush, kernels::TRAIN_BACKWARD_K3_CAS);
push_constants!(ChunkPush, kernels::TRAIN_BACKWARD_K1_COUNTERS);
push_constants!(ChunkPush, kernels::TRAIN_BACKWARD_K2_COUNTERS);
push_constants!(ChunkPush, kernels::TRAIN_BACKWARD_K3_COUNTERS);
push_constants!(ChunkPush, kernels::TRAIN_BACKWARD_K1_CAS_COUNTERS);
push_constants!(ChunkPush, kernels::TRAIN_BACKWARD_K2_CAS_COUNTERS);
push_constants!(ChunkPush, kernels::TRAIN_BACKWARD_K3_CAS_COUNTERS);

/// The backward pass with its kernels and scratch buffers.
pub struct Backward {
    ctx: Context,
    prepare_k: Kernel,
    /// [plain, work counters][samples - 1].
    backward: [[Kernel; 3]; 2],
    voxel: Kernel,
    float_atomics: bool,
    chunk_size: u32,
    params: Buffer,
    lost: Buffer,
    dout: GrowBuffer,
    dimg: GrowBuffer,
    bstate: GrowBuffer,
    vgrad: GrowBuffer,
}

impl Backward {
    /// Kernels for this device: native float atomics when the device has them and
    /// `float_atomics` allows it, compare-and-swap otherwise.
    pub fn new(ctx: &Context, float_atomics: bool) -> Result<Backward> {
        let fa = float_atomics && ctx.info().float_atomic_add;
        let (k, kc, v) = if fa {
            (
                [
                    &kernels::TRAIN_BACKWARD_K1,
                    &kernels::TRAIN_BACKWARD_K2,
                    &kernels::TRAIN_BACKWARD_K3,
                ],
                [
                    &kernels::TRAIN_BACKWARD_K1_COUNTERS,
                    &kernels::TRAIN_BACKWARD_K2_COUNTERS,
                    &kernels::TRAIN_BACKWARD_K3_COUNTERS,
                ],
                &kernels::TRAIN_VOXEL_BACKWARD,
            )
        } else {
            (
                [
                    &kernels::TRAIN_BACKWARD_K1_CAS,
                    &kernels::TRAIN_BACKWARD_K2_CAS,
                    &kernels::TRAIN_BACKWARD_K3_CAS,
                ],
                [
                    &kernels::TRAIN_BACKWARD_K1_CAS_COUNTERS,
                    &kernels::TRAIN_BACKWARD_K2_CAS_COUNTERS,
                    &kernels::TRAIN_BACKWARD_K3_CAS_COUNTERS,
                ],
                &kernels::TRAIN_VOXEL_BACKWARD_CAS,
            )
        };
        let lost = ctx.zeroed_buffer("backward.lost", 16)?;
        Ok(Backward {
            ctx: ctx.clone(),
            prepare_k: Kernel::new(ctx, &kernels::TRAIN_GRAD_PREPARE)?,
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
            voxel: Kernel::new(ctx, v)?,
            float_atomics: fa,
            chunk_size: ctx.info().backward_chunk_entries(fa),
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
        })
    }

    /// Whether the native float-atomic kernels are in use.
    pub fn float_atomics(&self) -> bool {
        self.float_atomics
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

    /// Records the backward of the renderer's last frame into `cmd`: overwrites
    /// `grads.geo`, `grads.sh0`, `grads.shs` and adds to `grads.priority`.
    /// `stats` are the frame's completed [`FrameStats`] (its longest tile list sets
    /// the number of chunks).
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &mut self,
        cmd: vk::CommandBuffer,
        frame: &FrameGeometry,
        stats: &FrameStats,
        scene: &SceneGpu,
        samples: u32,
        grads: &Gradients,
        losses: &EntryLosses,
    ) -> Result<()> {
        self.record_timed(cmd, frame, stats, scene, samples, grads, losses, None)
    }

    /// [`Backward::record`] with timestamps after each part (`backward.prepare`,
    /// `backward.walk`, `backward.voxel`) when `ts` is given.
    #[allow(clippy::too_many_arguments)]
    pub fn record_timed(
        &mut self,
        cmd: vk::CommandBuffer,
        frame: &FrameGeometry,
        stats: &FrameStats,
        scene: &SceneGpu,
        samples: u32,
        grads: &Gradients,
        losses: &EntryLosses,
        mut ts: Option<&mut Timestamps>,
    ) -> Result<()> {
        if !(1..=3).contains(&samples) {
            return Err(Error::Invalid(format!(
                "samples must be 1..=3, got {samples}"
            )));
        }
        if !grads.matches(scene) {
            return Err(Error::Invalid(
                "gradient buffers were made for a different scene".into(),
            ));
        }
        if !stats.complete() {
            return Err(Error::Invalid(
                "the backward needs a complete frame (see Renderer::grow_for)".into(),
            ));
        }
        self.prepare(frame, scene.voxels)?;
        let ctx = self.ctx.clone();
        let chunks = stats.max_tile_entries.div_ceil(self.chunk_size).max(1);
        let get = |b: &GrowBuffer| b.address();
        let params = BackParams {
            lambda_dist: losses.lambda_dist,
            lambda_r: losses.lambda_r,
            chunks,
            chunk_size: self.chunk_size,
            voxels: scene.voxels,
            pad0: 0,
            out_size: [frame.out_width, frame.out_height],
            render_size: [frame.render_width, frame.render_height],
            dimg: get(&self.dimg),
            dout: get(&self.dout),
            bstate: get(&self.bstate),
            vgrad: get(&self.vgrad),
            grad_geo: grads.geo.address(),
            grad_sh0: grads.sh0.address(),
            grad_shs: grads.shs.address(),
            priority: grads.priority.address(),
            lost: self.lost.address(),
        };
        let dev = ctx.device();
        unsafe {
            dev.cmd_update_buffer(cmd, self.params.raw(), 0, bytemuck::bytes_of(&params));
        }
        recorder::zero(&ctx, cmd, self.vgrad.get());
        recorder::zero(&ctx, cmd, &grads.geo);
        recorder::barrier(&ctx, cmd);
        let p2 = Push2 {
            frame: frame.params,
            back: self.params.address(),
        };
        let rpix = frame.render_width * frame.render_height;
        self.prepare_k.dispatch_1d(cmd, &p2, rpix);
        recorder::barrier(&ctx, cmd);
        if let Some(t) = ts.as_deref_mut() {
            t.mark(cmd, "backward.prepare");
        }
        let k = &self.backward[frame.counters as usize][samples as usize - 1];
        for chunk in (0..chunks).rev() {
            k.dispatch(
                cmd,
                &ChunkPush {
                    frame: frame.params,
                    back: self.params.address(),
                    chunk,
                    pad: 0,
                },
                [frame.tiles_x, frame.tiles_y, 1],
            );
            recorder::barrier(&ctx, cmd);
        }
        if let Some(t) = ts.as_deref_mut() {
            t.mark(cmd, "backward.walk");
        }
        self.voxel.dispatch_1d(cmd, &p2, scene.voxels.max(1));
        recorder::barrier(&ctx, cmd);
        if let Some(t) = ts {
            t.mark(cmd, "backward.voxel");
        }
        Ok(())
    }

    /// Compare-and-swap float adds that gave up (must stay 0; see atomic_f32.glsl).
    pub fn read_lost(&self) -> Result<u32> {
        Ok(self.ctx.download::<u32>(&self.lost, 0, 1)?[0])
    }
}
