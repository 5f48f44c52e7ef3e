//! The forward rasterizer (paper §3.1.2, supp. B; DESIGN §3).
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

use ash::vk;

mod counters;
pub(crate) use counters::COUNTER_WORDS;
pub use counters::{WalkCounters, WorkCounters};

use crate::data::Camera;
use crate::gpu::{kernels, recorder, Buffer, Context, Kernel, Memory, Timestamps};
use crate::push_constants;
use crate::scan::PrefixScan;
use crate::scene::{Scene, MAX_LEVEL};
use crate::sort::{Count, RadixSort, SortBuffers, Sorted};
use crate::{Error, Result};

/// Tile edge in pixels.
pub const TILE: u32 = 16;
/// Image channels of the planar output: r, g, b, alpha, depth, median depth, normal.
pub const CHANNELS: usize = 9;
/// Largest image edge (pixel rectangles pack 16-bit coordinates).
pub const MAX_IMAGE_EDGE: u32 = 65535;

const STATS_WORDS: usize = 16;
const STAT_USED: usize = 2;
const STAT_FLAGS: usize = 3;
const STAT_MAX_TILE: usize = 4;
const STAT_VISIBLE: usize = 5;
const STAT_ARGS: u64 = 8;
const FLAG_ENTRY_OVERFLOW: u32 = 1;
const FLAG_NEED_CHUNKS: u32 = 2;

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

/// A rendered frame (row-major, at the camera's resolution).
#[derive(Clone, Debug, Default)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<[f32; 3]>,
    pub alpha: Vec<f32>,
    /// Mean depth Σ Tᵢ dᵢ as camera z (0 where nothing is hit; divide by alpha for the
    /// expected depth of the surface).
    pub depth: Vec<f32>,
    /// Median depth (camera z) where the transmittance crosses 0.5; 0 if it never does.
    pub depth_median: Vec<f32>,
    /// Σ Tᵢ αᵢ nᵢ of the voxels' unit density gradients (world space; not normalised).
    pub normal: Vec<[f32; 3]>,
}

/// What the last recorded frame needed (read after it completed).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameStats {
    /// (tile, sign) entries requested by the preprocess.
    pub entries: u64,
    /// Entries actually emitted and sorted (`entries` clamped to the capacity).
    pub entries_used: u32,
    /// Voxels with at least one entry.
    pub visible_voxels: u32,
    /// Longest tile list.
    pub max_tile_entries: u32,
    /// More entries than the key buffers hold: the frame is incomplete.
    pub entry_overflow: bool,
    /// A tile list is longer than the composite chunks recorded: incomplete.
    pub need_chunks: bool,
    /// Tiles and render resolution of the frame.
    pub tiles: u32,
    pub render_width: u32,
    pub render_height: u32,
    /// Composite chunks recorded and sort bits used.
    pub chunks: u32,
    pub sort_bits: u32,
}

impl FrameStats {
    /// True when the frame is complete (nothing was truncated).
    pub fn complete(&self) -> bool {
        !self.entry_overflow && !self.need_chunks
    }
}

/// A scene's parameters on the device.
pub struct SceneGpu {
    pub(crate) octpath: Buffer,
    pub(crate) level: Buffer,
    pub(crate) corners: Buffer,
    pub(crate) geo: Buffer,
    pub(crate) sh0: Buffer,
    pub(crate) shs: Buffer,
    pub voxels: u32,
    pub grid_points: u32,
    pub max_level: u32,
    /// Active SH degree (≤ the stored degree; training raises it progressively).
    pub sh_degree: u32,
    /// SH coefficients stored per voxel besides the DC term, `(D+1)² − 1` of the stored
    /// degree D.
    pub shs_per_voxel: u32,
    pub center: [f32; 3],
    pub extent: f32,
    pub background: [f32; 3],
}

impl SceneGpu {
    /// Validates and uploads a scene.
    pub fn upload(ctx: &Context, scene: &Scene) -> Result<SceneGpu> {
        scene.validate()?;
        let level: Vec<u32> = scene.octlevel.iter().map(|&l| l as u32).collect();
        let corners: Vec<u32> = scene.corners.iter().flatten().copied().collect();
        let sh0: Vec<f32> = scene.sh0.iter().flatten().copied().collect();
        Ok(SceneGpu {
            octpath: ctx.buffer_from("scene.octpath", &scene.octpath)?,
            level: ctx.buffer_from("scene.level", &level)?,
            corners: ctx.buffer_from("scene.corners", &corners)?,
            geo: ctx.buffer_from("scene.geo", &scene.geo)?,
            sh0: ctx.buffer_from("scene.sh0", &sh0)?,
            shs: ctx.buffer_from("scene.shs", &scene.shs)?,
            voxels: scene.num_voxels() as u32,
            grid_points: scene.num_grid_points() as u32,
            max_level: scene.max_level(),
            sh_degree: scene.sh_degree,
            shs_per_voxel: scene.shs_per_voxel() as u32,
            center: scene.center,
            extent: scene.extent,
            background: scene.background,
        })
    }

    /// Downloads the current parameters (density, SH) into `scene`, whose topology
    /// must be the one this was uploaded from.
    pub fn download_params(&self, ctx: &Context, scene: &mut Scene) -> Result<()> {
        if scene.num_voxels() != self.voxels as usize
            || scene.num_grid_points() != self.grid_points as usize
            || scene.shs_per_voxel() != self.shs_per_voxel as usize
        {
            return Err(Error::Invalid(
                "download_params: the scene's topology differs from the device copy".into(),
            ));
        }
        scene.geo = ctx.download(&self.geo, 0, scene.geo.len())?;
        let sh0: Vec<f32> = ctx.download(&self.sh0, 0, scene.sh0.len() * 3)?;
        scene.sh0 = sh0.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        if !scene.shs.is_empty() {
            scene.shs = ctx.download(&self.shs, 0, scene.shs.len())?;
        }
        Ok(())
    }

    /// Device bytes held by the scene.
    pub fn bytes(&self) -> u64 {
        [
            &self.octpath,
            &self.level,
            &self.corners,
            &self.geo,
            &self.sh0,
            &self.shs,
        ]
        .iter()
        .map(|b| b.size())
        .sum()
    }
}

/// Mirror of `FrameParams` in glsl/lib/raster_params.glsl (std430: vec4s, then u64s).
#[repr(C)]
#[derive(Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct FrameParams {
    w2c: [[f32; 4]; 3],
    c2w: [[f32; 4]; 3],
    intr: [f32; 4],
    cam_frac: [f32; 4],
    bg: [f32; 4],
    dims: [u32; 4],
    cfg: [u32; 4],
    cfg2: [u32; 4],
    cfg3: [u32; 4],
    ss: [f32; 4],
    cam_int: [i32; 4],
    octpath: u64,
    level: u64,
    corners: u64,
    geo: u64,
    sh0: u64,
    shs: u64,
    bbox: u64,
    signs: u64,
    counts: u64,
    offsets: u64,
    geo8: u64,
    rgb: u64,
    nrm: u64,
    cs: u64,
    keys: u64,
    vals: u64,
    skeys: u64,
    svals: u64,
    ranges: u64,
    img: u64,
    med_id: u64,
    med_t: u64,
    out_img: u64,
    stats: u64,
    last: u64,
    aux: u64,
    /// Optional per-voxel max-weight target (0: off), see [`Renderer::set_max_weight_target`].
    maxw: u64,
    /// Optional work counters (0: off), see [`Renderer::set_counters`].
    counters: u64,
}
const _: () = assert!(std::mem::size_of::<FrameParams>() == 240 + 28 * 8);
/// Planar channels of the per-pixel training aux buffer (`AUX_*` in raster_params.glsl).
pub(crate) const AUX_CHANNELS: u64 = 4;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ParamsPush {
    params: u64,
}
push_constants!(ParamsPush, kernels::RASTER_PREPROCESS);
push_constants!(ParamsPush, kernels::RASTER_EMIT_KEYS);
push_constants!(ParamsPush, kernels::RASTER_TILE_RANGES);
push_constants!(ParamsPush, kernels::RASTER_FINALIZE);
push_constants!(ParamsPush, kernels::RASTER_DOWNSAMPLE);

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SetupPush {
    params: u64,
    max_groups_x: u32,
    pad: u32,
}
push_constants!(SetupPush, kernels::RASTER_FRAME_SETUP);

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ChunkPush {
    params: u64,
    chunk: u32,
    pad: u32,
}
push_constants!(ChunkPush, kernels::RASTER_COMPOSITE_K1);
push_constants!(ChunkPush, kernels::RASTER_COMPOSITE_K2);
push_constants!(ChunkPush, kernels::RASTER_COMPOSITE_K3);
push_constants!(ChunkPush, kernels::RASTER_COMPOSITE_K1_MAXW);
push_constants!(ChunkPush, kernels::RASTER_COMPOSITE_K2_MAXW);
push_constants!(ChunkPush, kernels::RASTER_COMPOSITE_K3_MAXW);
push_constants!(ChunkPush, kernels::RASTER_COMPOSITE_K1_COUNTERS);
push_constants!(ChunkPush, kernels::RASTER_COMPOSITE_K2_COUNTERS);
push_constants!(ChunkPush, kernels::RASTER_COMPOSITE_K3_COUNTERS);

/// A buffer that grows (by 1.5×) when more is needed.
struct Grow {
    name: &'static str,
    buf: Option<Buffer>,
}

impl Grow {
    fn new(name: &'static str) -> Grow {
        Grow { name, buf: None }
    }
    fn ensure(&mut self, ctx: &Context, bytes: u64) -> Result<()> {
        let bytes = bytes.max(16);
        if self.buf.as_ref().is_some_and(|b| b.size() >= bytes) {
            return Ok(());
        }
        self.buf = None;
        let want = bytes.saturating_add(bytes / 2);
        let limit = ctx.info().max_memory_allocation_size;
        let size = if want > limit && bytes <= limit {
            limit
        } else {
            want
        };
        self.buf = Some(ctx.buffer(self.name, size, Memory::Device)?);
        Ok(())
    }
    fn get(&self) -> &Buffer {
        self.buf.as_ref().expect("buffer ensured before use")
    }
    fn address(&self) -> u64 {
        self.get().address()
    }
    fn bytes(&self) -> u64 {
        self.buf.as_ref().map_or(0, |b| b.size())
    }
}

/// Everything a recorded frame needs to interpret its results.
#[derive(Clone, Copy, Debug)]
struct Plan {
    out_w: u32,
    out_h: u32,
    render_w: u32,
    render_h: u32,
    tiles: u32,
    chunks: u32,
    sort_bits: u32,
    supersampled: bool,
    /// Recorded with work counters on.
    counters: bool,
}

impl Plan {
    /// The sort result lands in the alternate buffers after an odd number of passes.
    fn sorted_in_alt(&self) -> bool {
        self.sort_bits.div_ceil(8) % 2 == 1
    }
}

/// Geometry of a recorded frame (see [`Renderer::last_frame`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameGeometry {
    pub out_width: u32,
    pub out_height: u32,
    pub render_width: u32,
    pub render_height: u32,
    pub tiles_x: u32,
    pub tiles_y: u32,
    pub supersampled: bool,
    /// Device address of the frame's parameter block (`FrameParams` in GLSL).
    pub params: u64,
    /// Whether the frame was recorded with work counters on (the backward then counts
    /// into the same buffer).
    pub counters: bool,
}

/// The forward rasterizer with its kernels and growable frame buffers.
pub struct Renderer {
    ctx: Context,
    preprocess: Kernel,
    setup: Kernel,
    emit: Kernel,
    ranges_k: Kernel,
    /// Composite variants: [plain, max-weight statistics, counters][samples - 1].
    composite: [[Kernel; 3]; 3],
    finalize: Kernel,
    downsample: Kernel,
    scan: Option<PrefixScan>,
    sort: Option<RadixSort>,
    voxel_cap: u32,
    entry_cap: u32,
    chunk_size: u32,
    chunks: u32,
    // per voxel
    bbox: Grow,
    signs: Grow,
    counts: Grow,
    offsets: Grow,
    geo8: Grow,
    rgb: Grow,
    nrm: Grow,
    cs: Grow,
    // entries
    keys: Grow,
    vals: Grow,
    keys_alt: Grow,
    vals_alt: Grow,
    // tiles / pixels
    ranges: Grow,
    img: Grow,
    med_id: Grow,
    med_t: Grow,
    out_img: Grow,
    last_id: Grow,
    aux: Grow,
    stats: Buffer,
    params: Buffer,
    last: Option<Plan>,
    maxw_target: u64,
    counters: Option<Buffer>,
    counters_on: bool,
}

impl Renderer {
    pub fn new(ctx: &Context) -> Result<Renderer> {
        Ok(Renderer {
            ctx: ctx.clone(),
            preprocess: Kernel::new(ctx, &kernels::RASTER_PREPROCESS)?,
            setup: Kernel::new(ctx, &kernels::RASTER_FRAME_SETUP)?,
            emit: Kernel::new(ctx, &kernels::RASTER_EMIT_KEYS)?,
            ranges_k: Kernel::new(ctx, &kernels::RASTER_TILE_RANGES)?,
            composite: [
                [
                    Kernel::new(ctx, &kernels::RASTER_COMPOSITE_K1)?,
                    Kernel::new(ctx, &kernels::RASTER_COMPOSITE_K2)?,
                    Kernel::new(ctx, &kernels::RASTER_COMPOSITE_K3)?,
                ],
                [
                    Kernel::new(ctx, &kernels::RASTER_COMPOSITE_K1_MAXW)?,
                    Kernel::new(ctx, &kernels::RASTER_COMPOSITE_K2_MAXW)?,
                    Kernel::new(ctx, &kernels::RASTER_COMPOSITE_K3_MAXW)?,
                ],
                [
                    Kernel::new(ctx, &kernels::RASTER_COMPOSITE_K1_COUNTERS)?,
                    Kernel::new(ctx, &kernels::RASTER_COMPOSITE_K2_COUNTERS)?,
                    Kernel::new(ctx, &kernels::RASTER_COMPOSITE_K3_COUNTERS)?,
                ],
            ],
            finalize: Kernel::new(ctx, &kernels::RASTER_FINALIZE)?,
            downsample: Kernel::new(ctx, &kernels::RASTER_DOWNSAMPLE)?,
            scan: None,
            sort: None,
            voxel_cap: 0,
            entry_cap: 0,
            // llvmpipe before Mesa 25 stops an invocation's loops after 65 535
            // iterations in total: keep each composite dispatch far below (≤ ~7 trips
            // per entry even if nothing unrolls). GPUs and Mesa 25 have no such limit.
            chunk_size: if ctx.info().loop_limit() {
                8192
            } else {
                1 << 22
            },
            chunks: 1,
            bbox: Grow::new("raster.bbox"),
            signs: Grow::new("raster.signs"),
            counts: Grow::new("raster.counts"),
            offsets: Grow::new("raster.offsets"),
            geo8: Grow::new("raster.geo8"),
            rgb: Grow::new("raster.rgb"),
            nrm: Grow::new("raster.normal"),
            cs: Grow::new("raster.centre-size"),
            keys: Grow::new("raster.keys"),
            vals: Grow::new("raster.values"),
            keys_alt: Grow::new("raster.keys-alt"),
            vals_alt: Grow::new("raster.values-alt"),
            ranges: Grow::new("raster.tile-ranges"),
            img: Grow::new("raster.image"),
            med_id: Grow::new("raster.median-id"),
            med_t: Grow::new("raster.median-t"),
            out_img: Grow::new("raster.out-image"),
            last_id: Grow::new("raster.last-contributor"),
            aux: Grow::new("raster.aux"),
            stats: ctx.buffer("raster.stats", STATS_WORDS as u64 * 4, Memory::Device)?,
            params: ctx.buffer(
                "raster.params",
                std::mem::size_of::<FrameParams>() as u64,
                Memory::Device,
            )?,
            last: None,
            maxw_target: 0,
            counters: None,
            counters_on: false,
        })
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
        Ok(Some(WorkCounters {
            forward: WalkCounters::from_words(&w[0..8]),
            backward: WalkCounters::from_words(&w[8..16]),
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

    /// Reserves key buffers for at least `entries` (tile, sign) entries.
    pub fn reserve_entries(&mut self, entries: u64) -> Result<()> {
        if entries <= self.entry_cap as u64 {
            return Ok(());
        }
        let max = RadixSort::MAX_CAPACITY as u64;
        if entries > max {
            return Err(Error::Capacity(format!(
                "a frame needs {entries} (tile, sign) entries; at most {max} are supported. \
                 Render at a lower resolution or with fewer voxels"
            )));
        }
        let cap = (entries + entries / 4).clamp(1 << 16, max) as u32;
        let ctx = self.ctx.clone();
        // Drop the old buffers first so peak memory stays low.
        self.sort = None;
        for (g, w) in [
            (&mut self.keys, 8u64),
            (&mut self.keys_alt, 8),
            (&mut self.vals, 4),
            (&mut self.vals_alt, 4),
        ] {
            g.buf = None;
            g.ensure(&ctx, cap as u64 * w)?;
        }
        self.sort = Some(RadixSort::new(&ctx, cap)?);
        self.entry_cap = cap;
        Ok(())
    }

    fn reserve_voxels(&mut self, n: u32) -> Result<()> {
        if n <= self.voxel_cap && self.scan.is_some() {
            return Ok(());
        }
        let cap = n.max(1024).saturating_add(n / 4);
        let ctx = self.ctx.clone();
        for (g, w) in [
            (&mut self.bbox, 8u64),
            (&mut self.signs, 4),
            (&mut self.counts, 4),
            (&mut self.offsets, 4),
            (&mut self.geo8, 32),
            (&mut self.rgb, 12),
            (&mut self.nrm, 12),
            (&mut self.cs, 16),
        ] {
            g.ensure(&ctx, cap as u64 * w)?;
        }
        self.scan = Some(PrefixScan::new(&ctx, cap)?);
        self.voxel_cap = cap;
        Ok(())
    }

    /// Checks the frame can be rendered and works out its plan.
    fn plan(&self, scene: &SceneGpu, cam: &Camera, opts: &RenderOptions) -> Result<Plan> {
        cam.validate()?;
        if !(1..=3).contains(&opts.samples) {
            return Err(Error::Invalid(format!(
                "samples per voxel must be 1, 2 or 3, got {}",
                opts.samples
            )));
        }
        if !(opts.supersample.is_finite() && (1.0..=8.0).contains(&opts.supersample)) {
            return Err(Error::Invalid(format!(
                "supersampling factor must be in 1..=8, got {}",
                opts.supersample
            )));
        }
        let ss = opts.supersample as f64;
        let render_w = ((cam.width as f64 * ss).round() as u64).max(1);
        let render_h = ((cam.height as f64 * ss).round() as u64).max(1);
        if render_w > MAX_IMAGE_EDGE as u64 || render_h > MAX_IMAGE_EDGE as u64 {
            return Err(Error::Invalid(format!(
                "render size {render_w}×{render_h} exceeds {MAX_IMAGE_EDGE} pixels per edge"
            )));
        }
        let (render_w, render_h) = (render_w as u32, render_h as u32);
        let tiles_x = render_w.div_ceil(TILE);
        let tiles_y = render_h.div_ceil(TILE);
        let tiles = tiles_x * tiles_y;
        let tile_bits = 32 - (tiles - 1).leading_zeros();
        let level_bits = 3 * scene.max_level;
        if tile_bits + level_bits > 64 {
            let max_tiles = 1u64 << (64 - level_bits);
            return Err(Error::Invalid(format!(
                "a {render_w}×{render_h} render has {tiles} tiles of {TILE}×{TILE}, but 64-bit \
                 sort keys with voxels down to level {} leave room for {max_tiles} tiles \
                 (e.g. 4096×4096 at level 16). Render smaller (or with less supersampling)",
                scene.max_level
            )));
        }
        if (scene.sh_degree + 1).pow(2) - 1 > scene.shs_per_voxel {
            return Err(Error::Invalid(format!(
                "active SH degree {} exceeds the {} coefficients stored per voxel",
                scene.sh_degree, scene.shs_per_voxel
            )));
        }
        if scene.voxels as usize > crate::scene::MAX_VOXELS {
            return Err(Error::Invalid(format!(
                "{} voxels exceed the 29-bit voxel id limit",
                scene.voxels
            )));
        }
        Ok(Plan {
            out_w: cam.width,
            out_h: cam.height,
            render_w,
            render_h,
            tiles,
            chunks: self.chunks,
            sort_bits: if scene.voxels == 0 {
                0
            } else {
                tile_bits + level_bits
            },
            supersampled: render_w != cam.width || render_h != cam.height,
            counters: self.counters_on,
        })
    }

    /// Allocates what a frame of `scene` seen by `cam` needs. Call before recording;
    /// it may replace buffers, so no earlier frame of this renderer may be in flight.
    pub fn prepare(&mut self, scene: &SceneGpu, cam: &Camera, opts: &RenderOptions) -> Result<()> {
        let plan = self.plan(scene, cam, opts)?;
        self.reserve_voxels(scene.voxels)?;
        if self.entry_cap == 0 {
            self.reserve_entries(scene.voxels as u64 * 2 + 4096)?;
        }
        let ctx = self.ctx.clone();
        let rpix = plan.render_w as u64 * plan.render_h as u64;
        self.ranges.ensure(&ctx, plan.tiles as u64 * 8)?;
        self.img.ensure(&ctx, rpix * CHANNELS as u64 * 4)?;
        self.med_id.ensure(&ctx, rpix * 4)?;
        self.med_t.ensure(&ctx, rpix * 4)?;
        self.last_id.ensure(&ctx, rpix * 4)?;
        self.aux.ensure(&ctx, rpix * AUX_CHANNELS * 4)?;
        let opix = plan.out_w as u64 * plan.out_h as u64;
        self.out_img.ensure(
            &ctx,
            if plan.supersampled {
                opix * CHANNELS as u64 * 4
            } else {
                16
            },
        )?;
        Ok(())
    }

    /// Records only the first stage of a frame (after [`Renderer::prepare`]): the frame's
    /// parameter block and the per-voxel preprocess (projection, per-voxel tile-entry
    /// counts, camera-relative centres). No image is produced; [`Renderer::last_frame`]
    /// then describes this frame, for passes that only need which voxels it shows
    /// (the adaptive layout's visibility test at initialisation).
    pub fn record_preprocess(
        &mut self,
        cmd: vk::CommandBuffer,
        scene: &SceneGpu,
        cam: &Camera,
        opts: &RenderOptions,
    ) -> Result<()> {
        self.record_preprocess_stage(cmd, scene, cam, opts, None)
            .map(|_| ())
    }

    fn record_preprocess_stage(
        &mut self,
        cmd: vk::CommandBuffer,
        scene: &SceneGpu,
        cam: &Camera,
        opts: &RenderOptions,
        mut ts: Option<&mut Timestamps>,
    ) -> Result<Plan> {
        let plan = self.plan(scene, cam, opts)?;
        if plan.counters && self.maxw_target != 0 {
            return Err(Error::Invalid(
                "work counters and max-weight statistics cannot be recorded in one frame \
                 (the counting kernels do not fold weights): turn the counters off"
                    .into(),
            ));
        }
        if self.voxel_cap < scene.voxels
            || self.scan.is_none()
            || self.sort.is_none()
            || self.img.bytes() < plan.render_w as u64 * plan.render_h as u64 * CHANNELS as u64 * 4
            || self.ranges.bytes() < plan.tiles as u64 * 8
        {
            return Err(Error::Invalid(
                "Renderer::record before Renderer::prepare for this scene and camera".into(),
            ));
        }
        let ctx = self.ctx.clone();
        let rcam = cam.resized(plan.render_w, plan.render_h);
        let o = rcam.origin();
        let mut w2c = [[0f32; 4]; 3];
        let mut c2w = [[0f32; 4]; 3];
        for r in 0..3 {
            for c in 0..3 {
                w2c[r][c] = rcam.c2w[c][r] as f32;
                c2w[r][c] = rcam.c2w[r][c] as f32;
            }
        }
        // Camera position in finest-grid units, split into an integer part (exact
        // in the kernels' integer arithmetic) and the rest.
        let half = 0.5 * scene.extent as f64;
        let unit = scene.extent as f64 / crate::scene::GRID_MAX as f64;
        let cam_fine: [(i32, f64); 3] = std::array::from_fn(|a| {
            let f = (o[a] - (scene.center[a] as f64 - half)) / unit;
            let i = f.floor().clamp(-1073741824.0, 1073741824.0);
            (i as i32, f - i)
        });
        let (skeys, svals) = if plan.sorted_in_alt() {
            (&self.keys_alt, &self.vals_alt)
        } else {
            (&self.keys, &self.vals)
        };
        let sx = plan.render_w as f32 / plan.out_w as f32;
        let sy = plan.render_h as f32 / plan.out_h as f32;
        let params = FrameParams {
            w2c,
            c2w,
            intr: [
                rcam.fx as f32,
                rcam.fy as f32,
                rcam.cx as f32,
                rcam.cy as f32,
            ],
            cam_frac: [
                cam_fine[0].1 as f32,
                cam_fine[1].1 as f32,
                cam_fine[2].1 as f32,
                unit as f32,
            ],
            bg: [
                scene.background[0],
                scene.background[1],
                scene.background[2],
                cam.near as f32,
            ],
            dims: [
                plan.render_w,
                plan.render_h,
                plan.render_w.div_ceil(TILE),
                plan.render_h.div_ceil(TILE),
            ],
            cfg: [
                scene.voxels,
                scene.sh_degree,
                scene.max_level,
                self.entry_cap,
            ],
            cfg2: [
                plan.chunks,
                self.chunk_size,
                3 * scene.max_level,
                plan.out_w,
            ],
            cfg3: [plan.out_h, plan.supersampled as u32, scene.shs_per_voxel, 0],
            ss: [sx, sy, sx.max(1.0), sy.max(1.0)],
            cam_int: [cam_fine[0].0, cam_fine[1].0, cam_fine[2].0, 0],
            octpath: scene.octpath.address(),
            level: scene.level.address(),
            corners: scene.corners.address(),
            geo: scene.geo.address(),
            sh0: scene.sh0.address(),
            shs: scene.shs.address(),
            bbox: self.bbox.address(),
            signs: self.signs.address(),
            counts: self.counts.address(),
            offsets: self.offsets.address(),
            geo8: self.geo8.address(),
            rgb: self.rgb.address(),
            nrm: self.nrm.address(),
            cs: self.cs.address(),
            keys: self.keys.address(),
            vals: self.vals.address(),
            skeys: skeys.address(),
            svals: svals.address(),
            ranges: self.ranges.address(),
            img: self.img.address(),
            med_id: self.med_id.address(),
            med_t: self.med_t.address(),
            out_img: self.out_img.address(),
            stats: self.stats.address(),
            last: self.last_id.address(),
            aux: self.aux.address(),
            maxw: self.maxw_target,
            counters: self.counters_address(),
        };
        let dev = ctx.device();
        let pa = ParamsPush {
            params: self.params.address(),
        };
        if let Some(t) = ts.as_deref_mut() {
            t.begin(cmd);
        }
        unsafe {
            dev.cmd_update_buffer(cmd, self.params.raw(), 0, bytemuck::bytes_of(&params));
        }
        recorder::fill(&ctx, cmd, &self.stats, 0, vk::WHOLE_SIZE, 0);
        recorder::fill(&ctx, cmd, self.ranges.get(), 0, plan.tiles as u64 * 8, 0);
        if let (Some(c), true) = (&self.counters, plan.counters) {
            recorder::fill(&ctx, cmd, c, 0, vk::WHOLE_SIZE, 0);
        }
        recorder::barrier(&ctx, cmd);
        let max_x = ctx.info().max_compute_work_group_count[0];
        let n = scene.voxels;
        self.preprocess
            .dispatch(cmd, &pa, crate::gpu::grid_2d(n.div_ceil(256), max_x));
        recorder::barrier(&ctx, cmd);
        if let Some(t) = ts {
            t.mark(cmd, "preprocess");
        }
        self.last = Some(plan);
        Ok(plan)
    }

    /// Records a frame into `cmd` (after [`Renderer::prepare`]). Reads no host data from
    /// the device; check [`Renderer::stats`] once it completed.
    pub fn record(
        &mut self,
        cmd: vk::CommandBuffer,
        scene: &SceneGpu,
        cam: &Camera,
        opts: &RenderOptions,
        mut ts: Option<&mut Timestamps>,
    ) -> Result<FrameStats> {
        let plan = self.record_preprocess_stage(cmd, scene, cam, opts, ts.as_deref_mut())?;
        let ctx = self.ctx.clone();
        let max_x = ctx.info().max_compute_work_group_count[0];
        let n = scene.voxels;
        let pa = ParamsPush {
            params: self.params.address(),
        };
        let passes = plan.sort_bits.div_ceil(8);
        let scan = self.scan.as_ref().expect("prepared");
        scan.record(
            cmd,
            self.counts.get(),
            self.offsets.get(),
            Count::Host(n),
            None,
        )?;
        self.setup.dispatch(
            cmd,
            &SetupPush {
                params: self.params.address(),
                max_groups_x: max_x,
                pad: 0,
            },
            [1, 1, 1],
        );
        recorder::barrier(&ctx, cmd);
        if let Some(t) = ts.as_deref_mut() {
            t.mark(cmd, "scan");
        }
        self.emit
            .dispatch_indirect(cmd, &pa, self.stats.raw(), STAT_ARGS * 4);
        recorder::barrier(&ctx, cmd);
        if let Some(t) = ts.as_deref_mut() {
            t.mark(cmd, "emit_keys");
        }
        let sort = self.sort.as_ref().expect("prepared");
        let sorted = sort.record(
            cmd,
            &SortBuffers {
                keys: self.keys.get(),
                values: self.vals.get(),
                keys_alt: self.keys_alt.get(),
                values_alt: self.vals_alt.get(),
            },
            Count::Device {
                buffer: &self.stats,
                offset: STAT_USED as u64 * 4,
            },
            0..plan.sort_bits,
            None,
        )?;
        debug_assert_eq!(
            sorted,
            if passes % 2 == 0 {
                Sorted::Primary
            } else {
                Sorted::Alternate
            }
        );
        if let Some(t) = ts.as_deref_mut() {
            t.mark(cmd, "sort");
        }
        self.ranges_k
            .dispatch_indirect(cmd, &pa, self.stats.raw(), STAT_ARGS * 4);
        recorder::barrier(&ctx, cmd);
        if let Some(t) = ts.as_deref_mut() {
            t.mark(cmd, "tile_ranges");
        }
        let tiles_xy = [
            plan.render_w.div_ceil(TILE),
            plan.render_h.div_ceil(TILE),
            1,
        ];
        // Counters win over statistics: both are for measurement, never mixed in a run.
        let variant = if plan.counters {
            2
        } else if self.maxw_target != 0 {
            1
        } else {
            0
        };
        let k = &self.composite[variant][opts.samples as usize - 1];
        for chunk in 0..plan.chunks {
            k.dispatch(
                cmd,
                &ChunkPush {
                    params: self.params.address(),
                    chunk,
                    pad: 0,
                },
                tiles_xy,
            );
            recorder::barrier(&ctx, cmd);
        }
        if let Some(t) = ts.as_deref_mut() {
            t.mark(cmd, "composite");
        }
        let rpix = plan.render_w * plan.render_h;
        self.finalize
            .dispatch(cmd, &pa, crate::gpu::grid_2d(rpix.div_ceil(256), max_x));
        recorder::barrier(&ctx, cmd);
        if plan.supersampled {
            let opix = plan.out_w * plan.out_h;
            self.downsample
                .dispatch(cmd, &pa, crate::gpu::grid_2d(opix.div_ceil(256), max_x));
            recorder::barrier(&ctx, cmd);
        }
        if let Some(t) = ts {
            t.mark(cmd, "finalize");
        }
        self.last = Some(plan);
        Ok(FrameStats {
            tiles: plan.tiles,
            render_width: plan.render_w,
            render_height: plan.render_h,
            chunks: plan.chunks,
            sort_bits: plan.sort_bits,
            ..Default::default()
        })
    }

    /// Geometry and parameter block of the last recorded frame, for passes recorded
    /// after it that read its per-pixel state (the training backward).
    pub fn last_frame(&self) -> Result<FrameGeometry> {
        let p = self.last_plan()?;
        Ok(FrameGeometry {
            out_width: p.out_w,
            out_height: p.out_h,
            render_width: p.render_w,
            render_height: p.render_h,
            tiles_x: p.render_w.div_ceil(TILE),
            tiles_y: p.render_h.div_ceil(TILE),
            supersampled: p.supersampled,
            params: self.params.address(),
            counters: p.counters,
        })
    }

    /// The device image of the last frame at output resolution (planar, [`CHANNELS`]
    /// channels): the supersampled frame's downsampled copy, else the render itself.
    pub fn output_address(&self) -> Result<u64> {
        let p = self.last_plan()?;
        Ok(if p.supersampled {
            self.out_img.address()
        } else {
            self.img.address()
        })
    }

    fn last_plan(&self) -> Result<Plan> {
        self.last
            .ok_or_else(|| Error::Invalid("no frame was recorded".into()))
    }

    /// Reads the counters of the last recorded frame (it must have completed).
    pub fn stats(&self) -> Result<FrameStats> {
        let plan = self.last_plan()?;
        let s: Vec<u32> = self.ctx.download(&self.stats, 0, STATS_WORDS)?;
        let flags = s[STAT_FLAGS];
        Ok(FrameStats {
            entries: s[0] as u64 | (s[1] as u64) << 32,
            entries_used: s[STAT_USED],
            visible_voxels: s[STAT_VISIBLE],
            max_tile_entries: s[STAT_MAX_TILE],
            entry_overflow: flags & FLAG_ENTRY_OVERFLOW != 0,
            need_chunks: flags & FLAG_NEED_CHUNKS != 0,
            tiles: plan.tiles,
            render_width: plan.render_w,
            render_height: plan.render_h,
            chunks: plan.chunks,
            sort_bits: plan.sort_bits,
        })
    }

    /// Grows whatever the last frame found short (entries, chunks). Returns whether
    /// anything changed, i.e. whether the frame must be rendered again.
    pub fn grow_for(&mut self, stats: &FrameStats) -> Result<bool> {
        let mut changed = false;
        if stats.entry_overflow {
            self.reserve_entries(stats.entries)?;
            changed = true;
        }
        let want = stats.max_tile_entries.div_ceil(self.chunk_size).max(1);
        if want > self.chunks {
            self.chunks = want;
            changed = true;
        } else if stats.need_chunks {
            // The longest list is only measured by the chunks that ran; with entries
            // clamped this frame, re-measure next time.
            self.chunks += 1;
            changed = true;
        }
        Ok(changed)
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
            ctx.submit_and_wait(|cmd| self.record(cmd, scene, cam, opts, ts.as_deref_mut()))?;
            let stats = self.stats()?;
            let sort_errs = self.sort.as_ref().map_or(Ok(0), |s| s.take_errors())?;
            let scan_errs = self.scan.as_ref().map_or(Ok(0), |s| s.take_errors())?;
            if (sort_errs | scan_errs) & crate::sort::ERR_LOOKBACK != 0 {
                return Err(Error::Gpu(
                    "decoupled look-back failed in the frame's scan or sort".into(),
                ));
            }
            if stats.complete() {
                return Ok(stats);
            }
            if !self.grow_for(&stats)? {
                return Err(Error::Gpu(format!(
                    "frame incomplete but nothing to grow: {stats:?}"
                )));
            }
        }
        Err(Error::Gpu("frame still incomplete after 8 attempts".into()))
    }

    /// Reads the image of the last completed frame.
    pub fn read_image(&self) -> Result<Image> {
        let plan = self.last_plan()?;
        let (buf, w, h) = if plan.supersampled {
            (self.out_img.get(), plan.out_w, plan.out_h)
        } else {
            (self.img.get(), plan.render_w, plan.render_h)
        };
        let np = (w * h) as usize;
        let raw: Vec<f32> = self.ctx.download(buf, 0, np * CHANNELS)?;
        let ch = |c: usize| &raw[c * np..(c + 1) * np];
        let (r, g, b) = (ch(0), ch(1), ch(2));
        let (nx, ny, nz) = (ch(6), ch(7), ch(8));
        Ok(Image {
            width: w,
            height: h,
            rgb: (0..np).map(|i| [r[i], g[i], b[i]]).collect(),
            alpha: ch(3).to_vec(),
            depth: ch(4).to_vec(),
            depth_median: ch(5).to_vec(),
            normal: (0..np).map(|i| [nx[i], ny[i], nz[i]]).collect(),
        })
    }

    /// The sorted entry values (`sign << 29 | voxel`) of every tile of the last completed
    /// frame, in compositing order (for tests and debugging; reads back everything).
    pub fn tile_lists(&self) -> Result<Vec<Vec<u32>>> {
        let plan = self.last_plan()?;
        let stats = self.stats()?;
        let ranges: Vec<u32> = self
            .ctx
            .download(self.ranges.get(), 0, plan.tiles as usize * 2)?;
        let vals = if plan.sorted_in_alt() {
            &self.vals_alt
        } else {
            &self.vals
        };
        let sorted: Vec<u32> = self
            .ctx
            .download(vals.get(), 0, stats.entries_used as usize)?;
        Ok((0..plan.tiles as usize)
            .map(|t| sorted[ranges[2 * t] as usize..ranges[2 * t + 1] as usize].to_vec())
            .collect())
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
        ]
        .iter()
        .map(|g| g.bytes())
        .sum()
    }
}

/// Largest supported level, re-exported for users computing key budgets.
pub const MAX_SCENE_LEVEL: u32 = MAX_LEVEL;
