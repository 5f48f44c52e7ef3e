//! Frame planning: the growable frame buffers, what a recorded frame needs (resolution,
//! tiles, chunks, sort bits) and the capacity reservations made before recording.

use super::{RenderOptions, Renderer, AUX_CHANNELS, CHANNELS, MAX_IMAGE_EDGE, TILE};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::gpu::glsl;
use crate::scan::PrefixScan;
use crate::scene::SceneGpu;
use crate::sort::RadixSort;

/// Floats of the frame-mean background's buffer for `rpix` render pixels: its slots and
/// one partial (4 floats) per workgroup of `FM_PIXELS` (raster/frame_mean.comp).
pub(super) fn frame_mean_floats(rpix: u64) -> u64 {
    u64::from(glsl::FM_PARTIALS) + 4 * rpix.div_ceil(u64::from(glsl::FM_PIXELS))
}

/// Everything a recorded frame needs to interpret its results.
#[derive(Clone, Copy, Debug)]
pub(super) struct Plan {
    pub(super) out_w: u32,
    pub(super) out_h: u32,
    pub(super) render_w: u32,
    pub(super) render_h: u32,
    pub(super) tiles: u32,
    pub(super) chunks: u32,
    pub(super) sort_bits: u32,
    pub(super) supersampled: bool,
    /// Recorded with work counters on.
    pub(super) counters: bool,
    /// What the composite accumulated besides colour, opacity and depth.
    pub(super) outputs: FrameOutputs,
    /// Entries per segment (0: composited per tile in chunks).
    pub(super) seg_size: u32,
    /// Composited over the frame's own mean colour ([`crate::scene::Scene::background_frame_mean`]).
    pub(super) frame_mean: bool,
}

/// What a frame accumulates besides colour, opacity, depth and median depth (see
/// [`Renderer::set_outputs`]). Each costs the composite a few operations and two or
/// three state updates per contributing (pixel, voxel) pair, and the training backward
/// as many: a frame computes only what its consumers read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameOutputs {
    /// The normal image (the normal channels; zero when off) and, in the training
    /// backward, the normal losses' gradient.
    pub normals: bool,
    /// The per-pixel distortion sums (mip-NeRF 360) that the distortion loss and its
    /// gradient read; the backward refuses a frame without them when λ_dist ≠ 0.
    pub distortion: bool,
    /// Those sums on SVRaster's contracted axis (`depth_contracted` of the distance
    /// along the ray: x < 1 ? x : 2 − 1/x) instead of the distance itself: its
    /// distortion loss, weak beyond distance 1 (docs/PARITY.md item 8). Only with
    /// `distortion`.
    pub distortion_contracted: bool,
}

impl Default for FrameOutputs {
    /// Normals on (renders write them), distortion sums off (only training reads them).
    fn default() -> Self {
        FrameOutputs {
            normals: true,
            distortion: false,
            distortion_contracted: false,
        }
    }
}

impl Plan {
    /// Size of the frame's output image: the downsampled copy of a supersampled frame,
    /// else the render itself.
    pub(super) fn output_size(&self) -> (u32, u32) {
        if self.supersampled {
            (self.out_w, self.out_h)
        } else {
            (self.render_w, self.render_h)
        }
    }

    /// The sort result lands in the alternate buffers after an odd number of passes.
    pub(super) fn sorted_in_alt(&self) -> bool {
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
    /// What the frame accumulated besides colour, opacity and depth.
    pub outputs: FrameOutputs,
    /// Segmented frames ("Segments" in raster_params.glsl): the buffer and byte offset
    /// of the indirect dispatch arguments over the slots, for the backward's walk of
    /// the same segments; `None` when the frame was composited per tile.
    pub segment_args: Option<(ash::vk::Buffer, u64)>,
    /// Composited over its own mean colour (`Scene::background_frame_mean`): the
    /// backward then adds the gradient through that mean.
    pub frame_mean_background: bool,
}

impl Renderer {
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
            g.release();
            g.ensure(&ctx, cap as u64 * w)?;
        }
        self.sort = Some(RadixSort::new(&ctx, cap)?);
        self.entry_cap = cap;
        Ok(())
    }

    pub(super) fn reserve_voxels(&mut self, n: u32) -> Result<()> {
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
    pub(super) fn plan(
        &self,
        scene: &SceneGpu,
        cam: &Camera,
        opts: &RenderOptions,
    ) -> Result<Plan> {
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
            outputs: self.outputs,
            seg_size: self.frame_segment_entries(tiles),
            // Host frames are premultiplied over the host's image and fields over
            // nothing: neither has a background.
            frame_mean: scene.background_frame_mean
                && self.host.is_none()
                && self.voxel_colours.is_none(),
        })
    }

    /// Allocates what a frame of `scene` seen by `cam` needs. Call before recording. A
    /// buffer it replaces is freed once the submissions pending on the context complete
    /// (`gpu/queue.rs`); a host engine's own pending command buffers are its business
    /// (see `host/`).
    pub fn prepare(&mut self, scene: &SceneGpu, cam: &Camera, opts: &RenderOptions) -> Result<()> {
        self.plan(scene, cam, opts)?;
        self.reserve_voxels(scene.voxels)?;
        if self.entry_cap == 0 {
            self.reserve_entries(scene.voxels as u64 * 2 + 4096)?;
        }
        // The segment length may depend on the entry capacity just reserved.
        let plan = self.plan(scene, cam, opts)?;
        let ctx = self.ctx.clone();
        let rpix = plan.render_w as u64 * plan.render_h as u64;
        self.ranges.ensure(&ctx, plan.tiles as u64 * 8)?;
        self.img.ensure(&ctx, rpix * CHANNELS as u64 * 4)?;
        self.med_id.ensure(&ctx, rpix * 4)?;
        self.med_t.ensure(&ctx, rpix * 4)?;
        self.last_id.ensure(&ctx, rpix * 4)?;
        self.aux.ensure(&ctx, rpix * AUX_CHANNELS * 4)?;
        if plan.frame_mean {
            self.bgsum.ensure(&ctx, frame_mean_floats(rpix) * 4)?;
        }
        if let Some(per_entries) = self.entry_cap.checked_div(plan.seg_size) {
            // Slots stay below tiles + entries / S ("Segments" in raster_params.glsl).
            let slots = u64::from(plan.tiles) + u64::from(per_entries) + 1;
            let state = slots * u64::from(glsl::SEG_CHANNELS) * 256 * 4;
            let limit = ctx.info().max_memory_allocation_size;
            if state > limit || slots * 256 * u64::from(glsl::SEG_CHANNELS) > u64::from(u32::MAX) {
                return Err(Error::Capacity(format!(
                    "{slots} segments of {} entries need {state} bytes of segment state, more \
                     than one allocation may hold ({limit}): use longer segments \
                     (Renderer::set_segment_entries) or render smaller",
                    plan.seg_size
                )));
            }
            self.slot_cap = slots as u32;
            self.seg_tile.ensure(&ctx, slots * 4)?;
            self.seg_state.ensure(&ctx, state)?;
        }
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
}
