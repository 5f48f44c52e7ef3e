//! The forward rasterizer (paper §3.1.2, supp. B; docs/ARCHITECTURE.md §3).
//!
//! A frame is: **preprocess** (thread per voxel: camera-relative geometry, near-plane
//! clipping, pixel rectangle, ray-sign octants, entry count, corner densities, SH colour,
//! normal) → **scan** of the counts → **setup** (clamp to capacity, indirect arguments) →
//! **emit keys** (thread per entry: `tile << 3L | direction-dependent Morton order`,
//! value `sign << 29 | voxel`) → **onesweep sort** over only the bits in use
//! (`3·max_level + ceil(log2 tiles)`) → **tile ranges** → **composite** (workgroup per
//! 16×16 tile, in chunks that respect lavapipe's loop limit) → **finalize** (background,
//! alpha, depths) → optional anti-aliased **downsample** from the supersampled
//! resolution.
//!
//! Recording needs no host read-back: counts flow through GPU buffers into indirect
//! dispatches, and the frame parameters are written into the command buffer itself
//! (`vkCmdUpdateBuffer`). Capacity shortfalls (more entries than the key buffers hold,
//! a tile list longer than the recorded chunks) are flagged in [`FrameStats`];
//! [`Renderer::render`] grows and re-renders, an embedding engine does the same after
//! reading [`Renderer::stats`].
//!
//! Semantics match the reference implementation (unit ray directions; `α = min(0.99999,
//! 1 − exp(−100·(b−a)/K·Σ explin(trilerp)))`; α < 1e-5 skipped; colour `max(0, 0.5 +
//! SH)` towards the voxel centre; early stop at T < 1e-4; depth as camera z), with two
//! documented refinements: the ray segment is clipped to the near plane (the reference
//! lets a voxel around the camera contribute its part behind the camera), and the
//! screen rectangle of a voxel crossing the near plane is that of its clipped part
//! (the reference uses only its front corners, which can miss pixels).

use std::sync::Arc;

mod counters;
pub mod host;
mod params;
mod plan;
mod readback;
mod record;
mod segments;
mod stream;
use crate::scene::SceneGpu;
pub(crate) use counters::COUNTER_WORDS;
pub use counters::{WalkCounters, WorkCounters};
pub(crate) use params::{FrameMeanPush, AUX_CHANNELS};
use params::{FrameOkPush, FrameParams};
use plan::Plan;
pub use plan::{FrameGeometry, FrameOutputs};
pub use readback::{FrameCheck, FrameStats, Gate, Image, CHECK_SLOTS};
pub use segments::auto_segment_entries;
pub use stream::StageTimes;

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::gpu::{
    glsl, kernels, Buffer, Context, GrowBuffer, Kernel, LazyKernel, Memory, Timestamps,
};
use crate::scan::PrefixScan;
use crate::scene::{Scene, MAX_LEVEL};
use crate::sort::RadixSort;

/// Tile edge in pixels.
pub const TILE: u32 = 16;
/// Image channels of the planar output: r, g, b, alpha, depth, median depth, normal.
pub const CHANNELS: usize = glsl::IMG_CHANNELS as usize;
/// Largest image edge (pixel rectangles pack 16-bit coordinates).
pub const MAX_IMAGE_EDGE: u32 = 65535;

// Words of the frame's stats buffer and its flags (defined in raster_params.glsl).
const STATS_WORDS: usize = glsl::STATS_WORDS as usize;
const STAT_USED: usize = glsl::STAT_USED as usize;
const STAT_FLAGS: usize = glsl::STAT_FLAGS as usize;
const STAT_MAX_TILE: usize = glsl::STAT_MAX_TILE as usize;
const STAT_VISIBLE: usize = glsl::STAT_VISIBLE as usize;
const STAT_SLOTS: usize = glsl::STAT_SLOTS as usize;
const STAT_ARGS: u64 = glsl::STAT_ARGS as u64;
const STAT_SEG_ARGS: u64 = glsl::STAT_SEG_ARGS as u64;
/// Words of `Renderer::checks`: the stats, then the sort's and the scan's first state
/// words (their sticky errors at `ST_ERRORS`).
const CHECK_WORDS: usize = STATS_WORDS + 2 * CHECK_STATE_WORDS;
const CHECK_STATE_WORDS: usize = 8;

/// Rendering options.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderOptions {
    /// Samples per ray–voxel segment, 1..=3 (paper: 1 for view synthesis, 3 for meshes).
    pub samples: u32,
    /// Supersampling factor `h_ss` ≥ 1: render at this multiple of the camera's size,
    /// then downsample with an anti-aliasing (tent) filter.
    pub supersample: f32,
}

impl RenderOptions {
    /// The options a model renders with by default: one sample per segment and the
    /// supersampling it was trained for ([`Scene::supersample`]).
    pub fn for_scene(scene: &Scene) -> Self {
        RenderOptions {
            samples: 1,
            supersample: scene.supersample,
        }
    }
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            samples: 1,
            supersample: 1.0,
        }
    }
}

/// The rasterizer's pipelines (immutable once made; shared between renderers).
struct RasterKernels {
    preprocess: Kernel,
    setup: Kernel,
    emit: Kernel,
    ranges_k: Kernel,
    /// Composite variants: [plain, max-weight statistics, counters][samples - 1].
    composite: [[Kernel; 3]; 3],
    /// The plain and statistics variants for frames without a normal image
    /// (`FrameOutputs`), made on first use.
    composite_nonormal: [[LazyKernel; 3]; 2],
    finalize: Kernel,
    downsample: Kernel,
    frame_mean: Kernel,
    host_output: Kernel,
    frame_ok: Kernel,
    seg_plan: Kernel,
    seg_compose: Kernel,
    /// Field channels in place of colour ([`Renderer::set_voxel_colours`]), made on
    /// first use.
    field_colour: LazyKernel,
}

/// Three channels of a per-voxel field that frames composite in place of colour (see
/// [`Renderer::set_voxel_colours`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct VoxelColours {
    /// Device address of the field: `voxels × channels` f32, voxel-major.
    pub address: u64,
    /// Channels per voxel.
    pub channels: u32,
    /// First of the three channels rendered as r, g, b (channels past the last read 0).
    pub first: u32,
}

/// Host-frame settings of the frames recorded from now on (see `host/`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct HostFrame {
    /// Device address of the host depth values at output resolution (0: none).
    pub(crate) depth: u64,
    /// `host::DepthConvention` as (x', y', 1) coefficients and the 1/d coefficient.
    pub(crate) depth_map: [f32; 4],
}

/// The forward rasterizer with its kernels and growable frame buffers.
pub struct Renderer {
    ctx: Context,
    /// The pipelines, shared by renderers made with [`Renderer::sharing`].
    k: Arc<RasterKernels>,
    scan: Option<PrefixScan>,
    sort: Option<RadixSort>,
    voxel_cap: u32,
    entry_cap: u32,
    chunk_size: u32,
    chunks: u32,
    // per voxel
    bbox: GrowBuffer,
    signs: GrowBuffer,
    counts: GrowBuffer,
    offsets: GrowBuffer,
    geo8: GrowBuffer,
    rgb: GrowBuffer,
    nrm: GrowBuffer,
    cs: GrowBuffer,
    // entries
    keys: GrowBuffer,
    vals: GrowBuffer,
    keys_alt: GrowBuffer,
    vals_alt: GrowBuffer,
    // tiles / pixels
    ranges: GrowBuffer,
    img: GrowBuffer,
    med_id: GrowBuffer,
    med_t: GrowBuffer,
    out_img: GrowBuffer,
    last_id: GrowBuffer,
    aux: GrowBuffer,
    /// The frame-mean background's sums (`plan::frame_mean_floats`).
    bgsum: GrowBuffer,
    /// Host-visible copies of queued frames' images ([`Renderer::render_each`]).
    image_slots: [GrowBuffer; 2],
    /// Entries per segment (0: segments off; [`Renderer::set_segment_entries`]), or
    /// with `seg_auto` the longest a frame's tile count may choose
    /// ([`auto_segment_entries`]), the slots the segment buffers hold, slot → tile, and
    /// the slots' per-pixel state.
    seg_size: u32,
    seg_auto: bool,
    slot_cap: u32,
    seg_tile: GrowBuffer,
    seg_state: GrowBuffer,
    stats: Buffer,
    /// Host-visible copy of a frame's stats and its scan's and sort's state words
    /// (`record_checks`): read without a submission once the frame completed.
    checks: Buffer,
    /// Frames that recorded their checks so far (picks the slot, dates a FrameCheck).
    check_seq: u64,
    params: Buffer,
    last: Option<Plan>,
    maxw_target: u64,
    counters: Option<Buffer>,
    counters_on: bool,
    generic_walk: bool,
    outputs: FrameOutputs,
    /// Frames are recorded for a host (transparent background, host depth); see `host/`.
    host: Option<HostFrame>,
    /// Incomplete frames rendered again (`render_to_device`).
    grown: u64,
    /// A field composited in place of colour ([`Renderer::set_voxel_colours`]).
    voxel_colours: Option<VoxelColours>,
}

impl Renderer {
    pub fn new(ctx: &Context) -> Result<Renderer> {
        let k = RasterKernels {
            preprocess: Kernel::new(ctx, &kernels::RASTER_PREPROCESS)?,
            setup: Kernel::new(ctx, &kernels::RASTER_FRAME_SETUP)?,
            emit: Kernel::new(ctx, &kernels::RASTER_EMIT_KEYS)?,
            ranges_k: Kernel::new(ctx, &kernels::RASTER_TILE_RANGES)?,
            composite: crate::gpu::kernel_grid(ctx, &kernels::RASTER_COMPOSITE_VARIANTS)?,
            composite_nonormal: kernels::RASTER_COMPOSITE_NONORMAL_VARIANTS
                .map(|row| row.map(LazyKernel::new)),
            finalize: Kernel::new(ctx, &kernels::RASTER_FINALIZE)?,
            downsample: Kernel::new(ctx, &kernels::RASTER_DOWNSAMPLE)?,
            frame_mean: Kernel::new(ctx, &kernels::RASTER_FRAME_MEAN)?,
            host_output: Kernel::new(ctx, &kernels::RASTER_HOST_OUTPUT)?,
            frame_ok: Kernel::new(ctx, &kernels::RASTER_FRAME_OK)?,
            seg_plan: Kernel::new(ctx, &kernels::RASTER_SEG_PLAN)?,
            seg_compose: Kernel::new(ctx, &kernels::RASTER_SEG_COMPOSE)?,
            field_colour: LazyKernel::new(&kernels::RASTER_FIELD_COLOUR),
        };
        Self::with_kernels(ctx, Arc::new(k))
    }

    /// A renderer with its own frame buffers that shares `other`'s pipelines (one per
    /// frame in flight, without compiling the kernels again).
    pub fn sharing(other: &Renderer) -> Result<Renderer> {
        Self::with_kernels(&other.ctx, other.k.clone())
    }

    fn with_kernels(ctx: &Context, k: Arc<RasterKernels>) -> Result<Renderer> {
        let stats = ctx.buffer("raster.stats", STATS_WORDS as u64 * 4, Memory::Device)?;
        let checks = ctx.buffer(
            "raster.checks",
            (CHECK_SLOTS * CHECK_WORDS) as u64 * 4,
            Memory::Readback,
        )?;
        let params = ctx.buffer(
            "raster.params",
            std::mem::size_of::<FrameParams>() as u64,
            Memory::Device,
        )?;
        let mut r = Renderer {
            ctx: ctx.clone(),
            k,
            scan: None,
            sort: None,
            voxel_cap: 0,
            entry_cap: 0,
            chunk_size: ctx.info().forward_chunk_entries(),
            chunks: 1,
            bbox: GrowBuffer::new("raster.bbox"),
            signs: GrowBuffer::new("raster.signs"),
            counts: GrowBuffer::new("raster.counts"),
            offsets: GrowBuffer::new("raster.offsets"),
            geo8: GrowBuffer::new("raster.geo8"),
            rgb: GrowBuffer::new("raster.rgb"),
            nrm: GrowBuffer::new("raster.normal"),
            cs: GrowBuffer::new("raster.centre-size"),
            keys: GrowBuffer::new("raster.keys"),
            vals: GrowBuffer::new("raster.values"),
            keys_alt: GrowBuffer::new("raster.keys-alt"),
            vals_alt: GrowBuffer::new("raster.values-alt"),
            ranges: GrowBuffer::new("raster.tile-ranges"),
            img: GrowBuffer::new("raster.image"),
            med_id: GrowBuffer::new("raster.median-id"),
            med_t: GrowBuffer::new("raster.median-t"),
            out_img: GrowBuffer::new("raster.out-image"),
            last_id: GrowBuffer::new("raster.last-contributor"),
            aux: GrowBuffer::new("raster.aux"),
            bgsum: GrowBuffer::new("raster.background-sums"),
            image_slots: [
                GrowBuffer::with_memory("raster.image-slot-0", Memory::Readback),
                GrowBuffer::with_memory("raster.image-slot-1", Memory::Readback),
            ],
            seg_size: 0,
            seg_auto: false,
            slot_cap: 0,
            seg_tile: GrowBuffer::new("raster.seg-tile"),
            seg_state: GrowBuffer::new("raster.seg-state"),
            stats,
            checks,
            check_seq: 0,
            params,
            last: None,
            maxw_target: 0,
            counters: None,
            generic_walk: false,
            outputs: FrameOutputs::default(),
            counters_on: false,
            host: None,
            grown: 0,
            voxel_colours: None,
        };
        // The device's default, bounded by its chunks like any other choice.
        r.set_segment_entries(ctx.info().segment_entries());
        r.seg_auto = r.seg_size > 0 && ctx.info().segments_adapt();
        Ok(r)
    }

    /// Makes the tile walks of the frames (and training backwards) recorded from now on
    /// build their visit sets by the path for any subgroup size instead of the 8-lane
    /// register transpose (`glsl/lib/tile_walk.glsl`), so that path, which real GPUs
    /// (32 or 64 lanes) take, is exercised on lavapipe. The images and gradients are
    /// the same; for tests.
    #[doc(hidden)]
    pub fn set_generic_walk(&mut self, on: bool) {
        self.generic_walk = on;
    }

    /// Makes the frames recorded from now on composite three channels of a per-voxel
    /// field instead of the voxels' SH colour, over a zero background: the image's
    /// r, g, b are then Σ_k T_k α_k f_k of channels `first..first + 3` (unclamped, any
    /// sign), its alpha, depth and normals unchanged. `None` restores colour. The field
    /// must hold `voxels × channels` floats of the scene rendered and stay alive until
    /// the frames complete (the library's field renderer: `crate::field`).
    pub fn set_voxel_colours(&mut self, colours: Option<VoxelColours>) {
        self.voxel_colours = colours;
    }

    /// Chooses what the frames recorded from now on accumulate besides colour, opacity,
    /// depth and median depth ([`FrameOutputs::default`]: normals, no distortion sums).
    /// An output that is off reads as zero.
    pub fn set_outputs(&mut self, outputs: FrameOutputs) {
        self.outputs = outputs;
    }

    /// What the frames recorded from now on accumulate (see [`Renderer::set_outputs`]).
    pub fn outputs(&self) -> FrameOutputs {
        self.outputs
    }

    /// Turns the work counters on or off for the frames (and training backwards)
    /// recorded from now on. With counters on, each frame zeroes them at its start and
    /// the composite (and the backward recorded after it) adds its walk's work; read
    /// them with [`Renderer::counters`]. The counting kernel variants cost extra
    /// subgroup votes and atomics: for benchmarks, not for timing. They do not fold
    /// max-weight statistics: recording a frame with both set is an error. The buffer
    /// stays allocated once made (work in flight may still write it).
    pub fn set_counters(&mut self, on: bool) -> Result<()> {
        if on && self.counters.is_none() {
            self.counters = Some(self.ctx.buffer(
                "raster.counters",
                COUNTER_WORDS as u64 * 8,
                Memory::Device,
            )?);
        }
        self.counters_on = on;
        Ok(())
    }

    /// Device address of the work counters (0: off), for the training backward.
    pub(crate) fn counters_address(&self) -> u64 {
        match (&self.counters, self.counters_on) {
            (Some(b), true) => b.address(),
            _ => 0,
        }
    }

    /// The work counters of the last frame (and backward) recorded with counters on;
    /// `None` when they are off. The recorded work must have completed.
    pub fn counters(&self) -> Result<Option<WorkCounters>> {
        let (Some(b), true) = (&self.counters, self.counters_on) else {
            return Ok(None);
        };
        let w: Vec<u64> = self.ctx.download(b, 0, COUNTER_WORDS)?;
        let (f, b, n) = (
            crate::gpu::glsl::CTR_FWD as usize,
            crate::gpu::glsl::CTR_BWD as usize,
            crate::gpu::glsl::CTR_WALK_WORDS as usize,
        );
        Ok(Some(WorkCounters {
            forward: WalkCounters::from_words(&w[f..f + n]),
            backward: WalkCounters::from_words(&w[b..b + n]),
        }))
    }

    /// Sets (or with `None` clears) the per-voxel max-weight target of the frames
    /// recorded from now on: the device address of a `u32` buffer with one word per
    /// voxel of the scenes rendered, holding non-negative `f32` bits. Every contributing
    /// ray–voxel segment folds its blending weight `T·α` into its voxel's word with an
    /// atomic max (paper §3.2.2, the pruning statistic). A frame whose entries overflow
    /// the key buffers folds nothing (it is rendered again after growing); a frame short
    /// of composite chunks folds the exact weights of the part it composited. Without a
    /// target frames are unaffected.
    pub fn set_max_weight_target(&mut self, address: Option<u64>) {
        self.maxw_target = address.unwrap_or(0);
    }

    /// The current max-weight target (see [`Renderer::set_max_weight_target`]).
    pub fn max_weight_target(&self) -> Option<u64> {
        (self.maxw_target != 0).then_some(self.maxw_target)
    }

    /// Entries per composite dispatch (the loop-limit guard on CPU devices).
    pub fn chunk_size(&self) -> u32 {
        self.chunk_size
    }

    /// Overrides the chunk size (tests use small chunks to exercise chunking).
    pub fn set_chunk_size(&mut self, entries: u32) {
        self.chunk_size = entries.max(1);
    }

    /// Entry capacity of the key buffers.
    pub fn entry_capacity(&self) -> u32 {
        self.entry_cap
    }

    /// Renders a frame and reads it back, growing and re-rendering on any shortfall.
    pub fn render(
        &mut self,
        scene: &SceneGpu,
        cam: &Camera,
        opts: &RenderOptions,
    ) -> Result<(Image, FrameStats)> {
        let stats = self.render_to_device(scene, cam, opts, None)?;
        Ok((self.read_image()?, stats))
    }

    /// Renders into the device image buffers (no image read-back), growing and
    /// re-rendering on any shortfall; with `ts`, the last attempt's stage times.
    pub fn render_to_device(
        &mut self,
        scene: &SceneGpu,
        cam: &Camera,
        opts: &RenderOptions,
        mut ts: Option<&mut Timestamps>,
    ) -> Result<FrameStats> {
        for _attempt in 0..8 {
            self.prepare(scene, cam, opts)?;
            let ctx = self.ctx.clone();
            // One submission and one wait: the frame, then its stats and error words
            // copied to host-visible memory.
            let check = ctx.submit_and_wait(|cmd| {
                self.record(cmd, scene, cam, opts, ts.as_deref_mut())?;
                self.record_checks(cmd, None)
            })?;
            let stats = self.checked_stats(&check)?;
            if stats.complete() {
                return Ok(stats);
            }
            self.grown += 1;
            if !self.grow_for(&stats)? {
                return Err(Error::Gpu(format!(
                    "frame incomplete but nothing to grow: {stats:?}"
                )));
            }
        }
        Err(Error::Gpu("frame still incomplete after 8 attempts".into()))
    }

    /// Frames [`Renderer::render_to_device`] found incomplete and rendered again.
    pub fn frames_grown(&self) -> u64 {
        self.grown
    }

    /// Device bytes held by the frame buffers.
    pub fn bytes(&self) -> u64 {
        [
            &self.bbox,
            &self.signs,
            &self.counts,
            &self.offsets,
            &self.geo8,
            &self.rgb,
            &self.nrm,
            &self.cs,
            &self.keys,
            &self.vals,
            &self.keys_alt,
            &self.vals_alt,
            &self.ranges,
            &self.img,
            &self.med_id,
            &self.med_t,
            &self.out_img,
            &self.last_id,
            &self.aux,
            &self.seg_tile,
            &self.seg_state,
        ]
        .iter()
        .map(|g| g.bytes())
        .sum()
    }
}

/// Largest supported level, re-exported for users computing key budgets.
pub const MAX_SCENE_LEVEL: u32 = MAX_LEVEL;
