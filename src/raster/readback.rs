//! What a recorded frame produced, read back after it completed: its statistics
//! (shortfalls to grow for), its image and its tile lists.

use super::plan::{FrameGeometry, Plan};
use super::{
    Renderer, CHANNELS, STATS_WORDS, STAT_FLAGS, STAT_MAX_TILE, STAT_USED, STAT_VISIBLE, TILE,
};
use crate::gpu::glsl::{self, FLAG_ENTRY_OVERFLOW, FLAG_NEED_CHUNKS};
use crate::{Error, Result};

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
    /// The stats of a frame recorded with `plan`, from the words of its stats buffer.
    pub(super) fn from_words(s: &[u32], plan: &Plan) -> FrameStats {
        let flags = s[STAT_FLAGS];
        FrameStats {
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
        }
    }

    /// True when the frame is complete (nothing was truncated).
    pub fn complete(&self) -> bool {
        !self.entry_overflow && !self.need_chunks
    }
}

impl Renderer {
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
            outputs: p.outputs,
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

    pub(super) fn last_plan(&self) -> Result<Plan> {
        self.last
            .ok_or_else(|| Error::Invalid("no frame was recorded".into()))
    }

    /// Reads the counters of the last recorded frame (it must have completed).
    pub fn stats(&self) -> Result<FrameStats> {
        let plan = self.last_plan()?;
        let s: Vec<u32> = self.ctx.download(&self.stats, 0, STATS_WORDS)?;
        Ok(FrameStats::from_words(&s, &plan))
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
        let ch = |c: u32| &raw[c as usize * np..(c as usize + 1) * np];
        let (r, g, b) = (ch(glsl::CH_R), ch(glsl::CH_G), ch(glsl::CH_B));
        let (nx, ny, nz) = (ch(glsl::CH_NX), ch(glsl::CH_NY), ch(glsl::CH_NZ));
        Ok(Image {
            width: w,
            height: h,
            rgb: (0..np).map(|i| [r[i], g[i], b[i]]).collect(),
            // finalize turns CH_T (transmittance) into alpha = 1 - T.
            alpha: ch(glsl::CH_T).to_vec(),
            depth: ch(glsl::CH_DEPTH).to_vec(),
            depth_median: ch(glsl::CH_DMED).to_vec(),
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
}
