//! The frame's parameter block and the push-constant blocks of the raster kernels, as
//! `#[repr(C)]` mirrors of their GLSL declarations (checked at compile time).

use crate::gpu::kernels::push_constants;
use crate::gpu::{glsl, gpu_layout};

/// Mirror of `FrameParams` in glsl/lib/raster_params.glsl, checked field by field against
/// the compiled SPIR-V (`gpu_layout!`).
#[repr(C)]
#[derive(Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct FrameParams {
    pub(super) w2c: [[f32; 4]; 3],
    pub(super) c2w: [[f32; 4]; 3],
    pub(super) intr: [f32; 4],
    pub(super) cam_frac: [f32; 3],
    pub(super) unit: f32,
    pub(super) bg: [f32; 3],
    pub(super) near: f32,
    pub(super) render_size: [u32; 2],
    pub(super) tiles: [u32; 2],
    pub(super) voxels: u32,
    pub(super) sh_degree: u32,
    pub(super) max_level: u32,
    pub(super) entry_capacity: u32,
    pub(super) chunks: u32,
    pub(super) chunk_size: u32,
    pub(super) key_shift: u32,
    pub(super) supersampled: u32,
    pub(super) out_size: [u32; 2],
    pub(super) shs_stride: u32,
    /// 1: the sort keys are u32 (key bits ≤ 32, [`crate::sort::KeyWidth::U32`]).
    pub(super) key32: u32,
    pub(super) ss_scale: [f32; 2],
    pub(super) filter_radius: [f32; 2],
    pub(super) cam_int: [i32; 3],
    /// `FRAME_*` bits (glsl/lib/raster_params.glsl): generic walk, normals, distortion.
    pub(super) flags: u32,
    /// Host depth convention (see `host::DepthConvention`).
    pub(super) depth_map: [f32; 4],
    pub(super) octpath: u64,
    pub(super) level: u64,
    pub(super) corners: u64,
    pub(super) geo: u64,
    pub(super) sh0: u64,
    pub(super) shs: u64,
    pub(super) bbox: u64,
    pub(super) signs: u64,
    pub(super) counts: u64,
    pub(super) offsets: u64,
    pub(super) geo8: u64,
    pub(super) rgb: u64,
    pub(super) nrm: u64,
    pub(super) cs: u64,
    pub(super) keys: u64,
    pub(super) vals: u64,
    pub(super) skeys: u64,
    pub(super) svals: u64,
    pub(super) ranges: u64,
    pub(super) img: u64,
    pub(super) med_id: u64,
    pub(super) med_t: u64,
    pub(super) out_img: u64,
    pub(super) stats: u64,
    pub(super) last: u64,
    pub(super) aux: u64,
    /// Optional per-voxel max-weight target (0: off), see [`Renderer::set_max_weight_target`].
    pub(super) maxw: u64,
    /// Optional work counters (0: off), see [`Renderer::set_counters`].
    pub(super) counters: u64,
    /// Optional host depth values at output resolution (0: off), see `host/`.
    pub(super) host_depth: u64,
    /// Segmented compositing (0 when off): slot → tile, and the slots' per-pixel state.
    pub(super) seg_tile: u64,
    pub(super) seg_state: u64,
    /// Entries per segment (0: off) and slots held by the two buffers above.
    pub(super) seg_size: u32,
    pub(super) slot_cap: u32,
    /// The frame-mean background's sums (0: the constant `bg`), see frame_mean.comp.
    pub(super) bgsum: u64,
}
gpu_layout!(FrameParams, FrameParams);
/// Planar channels of the per-pixel training aux buffer (`AUX_*` in raster_params.glsl).
pub(crate) const AUX_CHANNELS: u64 = glsl::AUX_CHANNELS as u64;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct ParamsPush {
    pub(super) frame: u64,
}
push_constants!(RASTER_PREPROCESS, ParamsPush);
push_constants!(RASTER_EMIT_KEYS, ParamsPush);
push_constants!(RASTER_TILE_RANGES, ParamsPush);
push_constants!(RASTER_FINALIZE, ParamsPush);
push_constants!(RASTER_DOWNSAMPLE, ParamsPush);

/// Push constants of raster/frame_mean.comp (the forward's modes and the training
/// backward's).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct FrameMeanPush {
    pub(crate) frame: u64,
    /// The backward's parameter block (0 in the forward's modes).
    pub(crate) back: u64,
    /// `FM_*` mode.
    pub(crate) mode: u32,
    /// `FM_TOTAL`: the slot written.
    pub(crate) dst: u32,
}
push_constants!(RASTER_FRAME_MEAN, FrameMeanPush);

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct SetupPush {
    pub(super) frame: u64,
    pub(super) max_groups_x: u32,
    pub(super) pad: u32,
}
push_constants!(RASTER_FRAME_SETUP, SetupPush);

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct FieldPush {
    pub(super) frame: u64,
    pub(super) field: u64,
    pub(super) channels: u32,
    pub(super) first: u32,
}
push_constants!(RASTER_FIELD_COLOUR, FieldPush);

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct FrameOkPush {
    pub(super) stats: u64,
    pub(super) sort_state: u64,
    pub(super) scan_state: u64,
    pub(super) ok: u64,
    pub(super) after: u64,
}
push_constants!(RASTER_FRAME_OK, FrameOkPush);

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct SegComposePush {
    pub(super) frame: u64,
    /// `SEG_PREFIX` or `SEG_MERGE` (raster_params.glsl).
    pub(super) mode: u32,
    pub(super) pad: u32,
}
push_constants!(RASTER_SEG_COMPOSE, SegComposePush);
push_constants!(RASTER_SEG_PLAN, ParamsPush);

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct ChunkPush {
    pub(super) frame: u64,
    pub(super) chunk: u32,
    /// `SEG_OFF`, `SEG_TRANSMIT` or `SEG_EXACT` (raster_params.glsl).
    pub(super) mode: u32,
}
push_constants!(RASTER_COMPOSITE_VARIANTS, ChunkPush);
push_constants!(RASTER_COMPOSITE_NONORMAL_VARIANTS, ChunkPush);

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(super) struct HostOutputPush {
    pub(super) frame: u64,
    pub(super) color: u64,
    pub(super) depth: u64,
    pub(super) host_depth: u64,
    pub(super) format: u32,
    pub(super) depth_mode: u32,
    pub(super) depth_clear: f32,
    pub(super) reverse: u32,
    pub(super) image: u32,
    pub(super) near_depth: f32,
    pub(super) far_depth: f32,
    pub(super) pad_: u32,
}
push_constants!(RASTER_HOST_OUTPUT, HostOutputPush);
