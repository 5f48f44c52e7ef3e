//! What a recorded frame produced, read back after it completed: its statistics
//! (shortfalls to grow for), its image and its tile lists.

use super::plan::{FrameGeometry, Plan};
use ash::vk;

use super::{
    FrameOkPush, Renderer, CHANNELS, CHECK_STATE_WORDS, CHECK_WORDS, STATS_WORDS, STAT_FLAGS,
    STAT_MAX_TILE, STAT_SEG_ARGS, STAT_SLOTS, STAT_USED, STAT_VISIBLE, TILE,
};
use crate::error::{Error, Result};
use crate::gpu::glsl::{self, FLAG_ENTRY_OVERFLOW, FLAG_NEED_CHUNKS};
use crate::gpu::{recorder, Buffer};

/// Frames whose checks stay readable at once ([`Renderer::record_checks`]): the frame
/// running and the one queued behind it.
pub const CHECK_SLOTS: usize = 2;

/// Where a frame's checks landed ([`Renderer::record_checks`]); read them with
/// [`Renderer::checked_stats`] once the frame's submission completed.
#[derive(Clone, Copy, Debug)]
pub struct FrameCheck {
    slot: usize,
    seq: u64,
    pub(super) plan: Plan,
}

/// The go word a frame's checks write ([`Renderer::record_checks`]): the u32 of `go` at
/// byte `offset`. With `after`, an earlier frame's go word (buffer, byte offset) that
/// must be 1 too: work queued behind a skipped update is skipped with it.
#[derive(Clone, Copy)]
pub struct Gate<'a> {
    pub go: &'a Buffer,
    pub offset: u64,
    pub after: Option<(&'a Buffer, u64)>,
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
    /// Segmented frames: the slots (segment workgroups, one per segment, and the gaps
    /// between tiles' slot ranges) the frame's lists needed; 0 without segments.
    pub slots: u32,
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
            slots: s[STAT_SLOTS],
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
            segment_args: (p.seg_size > 0).then(|| (self.stats.raw(), STAT_SEG_ARGS * 4)),
            frame_mean_background: p.frame_mean,
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

    /// Records, after a frame in the same command buffer: its stats and its scan's and
    /// sort's state words copied to host-visible memory (for [`Renderer::checked_stats`]
    /// once the command buffer completed, with a [`recorder::host_barrier`] after this),
    /// their sticky error bits cleared, and with `gate`, the gate's go word set to 1 when
    /// the frame is complete and error-free (and the word it chains after is 1), else
    /// 0 — the predicate of the work recorded next ([`recorder::begin_conditional`]; the
    /// barrier to it is recorded here). The checks land in one of [`CHECK_SLOTS`] slots
    /// in turn: the returned [`FrameCheck`] reads them until as many newer frames
    /// recorded theirs.
    pub fn record_checks(
        &mut self,
        cmd: vk::CommandBuffer,
        gate: Option<Gate>,
    ) -> Result<FrameCheck> {
        let (Some(sort), Some(scan)) = (self.sort.as_ref(), self.scan.as_ref()) else {
            return Err(Error::Invalid(
                "Renderer::record_checks before a frame was recorded".into(),
            ));
        };
        let plan = self.last_plan()?;
        self.check_seq += 1;
        let seq = self.check_seq;
        let slot = (seq % CHECK_SLOTS as u64) as usize;
        let base = (slot * CHECK_WORDS * 4) as u64;
        let ctx = &self.ctx;
        let dev = ctx.device();
        let state_bytes = (CHECK_STATE_WORDS * 4) as u64;
        let stats_bytes = (STATS_WORDS * 4) as u64;
        let copy = |src: &Buffer, dst_offset: u64, size: u64| {
            let region = [vk::BufferCopy {
                src_offset: 0,
                dst_offset: base + dst_offset,
                size,
            }];
            unsafe { dev.cmd_copy_buffer(cmd, src.raw(), self.checks.raw(), &region) };
        };
        copy(&self.stats, 0, stats_bytes);
        copy(sort.state_buffer(), stats_bytes, state_bytes);
        copy(scan.state_buffer(), stats_bytes + state_bytes, state_bytes);
        if let Some(g) = &gate {
            self.k.frame_ok.dispatch(
                cmd,
                &FrameOkPush {
                    stats: self.stats.address(),
                    sort_state: sort.state_buffer().address(),
                    scan_state: scan.state_buffer().address(),
                    ok: g.go.address() + g.offset,
                    after: g.after.map_or(0, |(b, off)| b.address() + off),
                },
                [1, 1, 1],
            );
        }
        recorder::barrier(ctx, cmd);
        let err = (crate::sort::ST_ERRORS * 4) as u64;
        recorder::fill(ctx, cmd, sort.state_buffer(), err, 4, 0);
        recorder::fill(ctx, cmd, scan.state_buffer(), err, 4, 0);
        recorder::barrier(ctx, cmd);
        if gate.is_some() {
            recorder::conditional_barrier(ctx, cmd);
        }
        Ok(FrameCheck { slot, seq, plan })
    }

    /// What work recorded after the last frame in the same command buffer may assume
    /// without reading its stats back: the frame complete, every entry slot of the key
    /// buffers used, tile lists as long as the chunks recorded cover. Exact only once
    /// [`Renderer::checked_stats`] confirms the frame complete; until then, record that
    /// work in the frame's conditional region ([`Renderer::record_checks`] with a gate).
    pub fn planned_stats(&self) -> Result<FrameStats> {
        let plan = self.last_plan()?;
        Ok(FrameStats {
            entries: u64::from(self.entry_cap),
            entries_used: self.entry_cap,
            visible_voxels: 0,
            max_tile_entries: plan.chunks.saturating_mul(self.chunk_size),
            entry_overflow: false,
            need_chunks: false,
            tiles: plan.tiles,
            render_width: plan.render_w,
            render_height: plan.render_h,
            chunks: plan.chunks,
            sort_bits: plan.sort_bits,
            slots: 0,
        })
    }

    /// The stats of a frame recorded with [`Renderer::record_checks`], read from
    /// host-visible memory (no submission; its command buffer must have completed). A
    /// failed look-back in the frame's scan or sort is an error, and so is a check whose
    /// slot newer frames reused.
    pub fn checked_stats(&self, check: &FrameCheck) -> Result<FrameStats> {
        if self.check_seq - check.seq >= CHECK_SLOTS as u64 {
            return Err(Error::Invalid(format!(
                "the checks of frame {} were overwritten by frame {} (only the last {} are kept)",
                check.seq, self.check_seq, CHECK_SLOTS
            )));
        }
        let bytes = self
            .checks
            .mapped()
            .ok_or_else(|| Error::Gpu("raster.checks is not host-visible".into()))?;
        let base = check.slot * CHECK_WORDS * 4;
        let words: &[u32] = bytemuck::cast_slice(&bytes[base..base + CHECK_WORDS * 4]);
        let err = crate::sort::ST_ERRORS;
        let sort_errs = words[STATS_WORDS + err];
        let scan_errs = words[STATS_WORDS + CHECK_STATE_WORDS + err];
        if (sort_errs | scan_errs) & crate::sort::ERR_LOOKBACK != 0 {
            return Err(Error::Gpu(
                "decoupled look-back failed in the frame's scan or sort".into(),
            ));
        }
        Ok(FrameStats::from_words(&words[..STATS_WORDS], &check.plan))
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
        let (w, h) = plan.output_size();
        let buf = if plan.supersampled {
            self.out_img.get()
        } else {
            self.img.get()
        };
        let np = (w * h) as usize;
        let raw: Vec<f32> = self.ctx.download(buf, 0, np * CHANNELS)?;
        Ok(image_from_channels(&raw, w, h))
    }
}

/// An [`Image`] of `w`×`h` from the frame's output channels (`CHANNELS` planes).
pub(super) fn image_from_channels(raw: &[f32], w: u32, h: u32) -> Image {
    let np = (w * h) as usize;
    let ch = |c: u32| &raw[c as usize * np..(c as usize + 1) * np];
    let (r, g, b) = (ch(glsl::CH_R), ch(glsl::CH_G), ch(glsl::CH_B));
    let (nx, ny, nz) = (ch(glsl::CH_NX), ch(glsl::CH_NY), ch(glsl::CH_NZ));
    Image {
        width: w,
        height: h,
        rgb: (0..np).map(|i| [r[i], g[i], b[i]]).collect(),
        // finalize turns CH_T (transmittance) into alpha = 1 - T.
        alpha: ch(glsl::CH_T).to_vec(),
        depth: ch(glsl::CH_DEPTH).to_vec(),
        depth_median: ch(glsl::CH_DMED).to_vec(),
        normal: (0..np).map(|i| [nx[i], ny[i], nz[i]]).collect(),
    }
}

impl Renderer {
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
