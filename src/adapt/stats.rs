//! Per-voxel statistics of the adaptive pass (paper §3.2.2, Eq. 7): over a set of
//! views, the largest blending weight `T·α` each voxel receives on any pixel ray (the
//! pruning criterion) and the smallest sampling interval over the views that show it
//! (the subdivision guard: sampling rate = voxel size / interval).
//!
//! * **Max weight** comes from the forward composite itself: with a target set
//!   ([`Renderer::set_max_weight_target`]) every contributing ray–voxel segment folds
//!   its `w = T·α` (exactly as composited: after the α < 1e-5 skip and the α clamp, up
//!   to the early stop) into its voxel's word with an atomic max on the float bits.
//! * **Min interval** (kernel `adapt/sampling_interval`, thread per voxel, after the
//!   frame): for each voxel with at least one (tile, sign) entry in the view (the
//!   renderer's own visibility: its near-clipped projected box covers a pixel centre),
//!   `min(old, max(z, near) / fx)` with z the camera depth of the voxel centre and fx
//!   the focal length in pixels at the view's own resolution, also when its frame is
//!   supersampled (Eq. 7b: `z·tan(fov_x/2)/(W/2)`). Never-visible voxels keep +inf.
//!   [`StatsRule`] chooses SVRaster's rule instead (docs/PARITY.md item 9): frames
//!   supersampled like the model's, and a view shows only the voxels it gives a
//!   non-zero weight (each view's weights go to a buffer of their own first, then the
//!   fold takes their max and those voxels' intervals).
//!
//! Grow-and-retry: [`StatsPass::add_views`] renders a view again (through
//! [`Renderer::render_to_device`], which may render it several times while it grows its
//! buffers) when its first frame came out incomplete. A retried frame leaves nothing stale: a frame whose entries overflowed
//! folds no weights at all (the composite checks the entry total against the capacity;
//! its tile lists miss voxels, which would *inflate* the weights of those behind them,
//! so this case is not harmless for a max), a frame short of composite chunks folds the
//! exact weights of the prefix of each tile list it composited (a subset of the complete
//! frame's, harmless for a max), and the interval kernel runs once, after the complete
//! frame.

use ash::vk;
use bytemuck::{Pod, Zeroable};
use serde::{Deserialize, Serialize};

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::gpu::kernels::push_constants;
use crate::gpu::{kernels, recorder, Buffer, Context, GrowBuffer, Kernel, Ticket};
use crate::raster::{FrameCheck, FrameGeometry, FrameStats, RenderOptions, Renderer};
use crate::scene::Scene;
use crate::scene::SceneGpu;

/// Per-voxel statistics gathered over a set of views (host copy).
#[derive(Clone, Debug, Default)]
pub struct VoxelStats {
    /// Largest blending weight `T·α` on any pixel ray of any view (0: never contributed).
    pub max_weight: Vec<f32>,
    /// Smallest sampling interval `max(z, near) / fx` over the views showing the voxel
    /// (world units per pixel at the voxel's depth; +inf: never visible).
    pub min_interval: Vec<f32>,
}

impl VoxelStats {
    /// Sampling rate `size / min_interval` per voxel (paper Eq. 7a; 0 where never
    /// visible). `scene` must be the scene the statistics were gathered on; the result
    /// has one entry per voxel of the shorter of the two.
    pub fn sampling_rate(&self, scene: &Scene) -> Vec<f32> {
        let n = self.min_interval.len().min(scene.num_voxels());
        (0..n)
            .map(|i| {
                let int = self.min_interval[i];
                if int.is_finite() && int > 0.0 {
                    (scene.voxel_size(i) / f64::from(int)) as f32
                } else {
                    0.0
                }
            })
            .collect()
    }
}

/// Which voxels a view counts as showing, for the min interval (docs/PARITY.md item 9).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum StatsVisible {
    /// Every voxel with at least one (tile, sign) entry in the frame: the renderer's
    /// own visibility (ours; also voxels hidden behind others).
    #[default]
    Entries,
    /// Every voxel with a non-zero blending weight in the frame (SVRaster's
    /// `compute_training_stat`: `max_w_i > 0`).
    Weight,
}

/// How the statistics pass renders its views (docs/PARITY.md item 9).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StatsRule {
    /// Supersampling of the views' frames (the max weights are those of the
    /// supersampled rays; the intervals stay those of the views' own resolution).
    /// Ours 1; SVRaster renders them at the model's (1.5).
    pub supersample: f32,
    /// Which voxels a view counts as showing.
    pub visible: StatsVisible,
}

impl Default for StatsRule {
    fn default() -> Self {
        StatsRule {
            supersample: 1.0,
            visible: StatsVisible::Entries,
        }
    }
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct IntervalPush {
    frame: u64,
    minint: u64,
    view_w: u64,
    maxw: u64,
    count: u32,
    fx_scale: f32,
    skip_near: u32,
    pad: u32,
}
push_constants!(ADAPT_SAMPLING_INTERVAL, IntervalPush);

/// The statistics pass: the interval kernel and the device accumulators.
pub struct StatsPass {
    ctx: Context,
    kernel: Kernel,
    /// One `u32` (f32 bits) per voxel.
    max_weight: GrowBuffer,
    /// One `f32` per voxel.
    min_interval: GrowBuffer,
    /// One `u32` (f32 bits) per voxel: the current view's max weights
    /// ([`StatsVisible::Weight`] only).
    view_weight: GrowBuffer,
    voxels: u32,
    rule: StatsRule,
}

impl StatsPass {
    pub fn new(ctx: &Context) -> Result<StatsPass> {
        Ok(StatsPass {
            ctx: ctx.clone(),
            kernel: Kernel::new(ctx, &kernels::ADAPT_SAMPLING_INTERVAL)?,
            max_weight: GrowBuffer::new("adapt.max-weight"),
            min_interval: GrowBuffer::new("adapt.min-interval"),
            view_weight: GrowBuffer::new("adapt.view-weight"),
            voxels: 0,
            rule: StatsRule::default(),
        })
    }

    /// How [`StatsPass::add_views`] renders and counts its views (default: supersampling
    /// 1, visibility by entries).
    pub fn set_rule(&mut self, rule: StatsRule) -> Result<()> {
        if !(rule.supersample.is_finite() && (1.0..=8.0).contains(&rule.supersample)) {
            return Err(Error::Invalid(format!(
                "statistics supersampling must be in 1..=8, got {}",
                rule.supersample
            )));
        }
        self.rule = rule;
        Ok(())
    }

    /// The rule [`StatsPass::add_views`] follows.
    pub fn rule(&self) -> StatsRule {
        self.rule
    }

    /// The device context the pass runs on.
    pub fn context(&self) -> &Context {
        &self.ctx
    }

    /// Voxels of the current accumulation (set by [`StatsPass::begin`]).
    pub fn voxels(&self) -> u32 {
        self.voxels
    }

    /// Resets the accumulators for `voxels` voxels: max weight 0, min interval +inf.
    /// Grows the device buffers as needed ([`GrowBuffer`]'s policy; no frame using them may be in
    /// flight).
    pub fn begin(&mut self, voxels: u32) -> Result<()> {
        let bytes = u64::from(voxels.max(1)) * 4;
        // Both freed before either grows, so peak memory stays low.
        if self.max_weight.bytes() < bytes || self.min_interval.bytes() < bytes {
            self.max_weight.release();
            self.min_interval.release();
        }
        self.max_weight.ensure(&self.ctx, bytes)?;
        self.min_interval.ensure(&self.ctx, bytes)?;
        let (mw, mi) = self.buffers()?;
        self.ctx.submit_and_wait(|cmd| {
            recorder::zero(&self.ctx, cmd, mw);
            recorder::fill(
                &self.ctx,
                cmd,
                mi,
                0,
                vk::WHOLE_SIZE,
                f32::INFINITY.to_bits(),
            );
            recorder::barrier(&self.ctx, cmd);
            Ok(())
        })?;
        self.voxels = voxels;
        Ok(())
    }

    fn buffers(&self) -> Result<(&Buffer, &Buffer)> {
        match (self.max_weight.buffer(), self.min_interval.buffer()) {
            (Some(a), Some(b)) => Ok((a, b)),
            _ => Err(Error::Invalid(
                "StatsPass: call begin() before adding views".into(),
            )),
        }
    }

    /// Renders `cam` (`samples` per voxel segment, supersampled and counted as
    /// [`StatsPass::set_rule`] says) and folds its weights and intervals into the
    /// accumulators. `scene` must have the voxel count
    /// given to [`StatsPass::begin`]. Handles the renderer's grow-and-retry (see the
    /// module notes: a retried frame leaves nothing stale). Leaves the renderer's
    /// max-weight target unset afterwards, also on error.
    pub fn add_view(
        &mut self,
        renderer: &mut Renderer,
        scene: &SceneGpu,
        cam: &Camera,
        samples: u32,
    ) -> Result<()> {
        self.add_views(renderer, scene, std::slice::from_ref(cam), samples)
    }

    /// [`StatsPass::add_view`] for every camera of `cams`, each frame queued behind the
    /// next: one submission per view, the frame and its interval fold together, and the
    /// host waits for view i only after submitting view i+1 (no queue drain but the
    /// last). A view whose frame came out incomplete is rendered again, waited for, as
    /// in `add_view`: its first frame folded nothing stale (an overflowed frame folds no
    /// weights, a frame short of chunks an exact prefix of them, and the interval fold
    /// is a min over the same values), so the accumulators are those of `add_view`.
    pub fn add_views(
        &mut self,
        renderer: &mut Renderer,
        scene: &SceneGpu,
        cams: &[Camera],
        samples: u32,
    ) -> Result<()> {
        if scene.voxels != self.voxels {
            return Err(Error::Invalid(format!(
                "StatsPass::add_view(s): the scene has {} voxels, the accumulators {} \
                 (call begin() for this scene)",
                scene.voxels, self.voxels
            )));
        }
        let target = if self.rule.visible == StatsVisible::Weight {
            // No frame of ours is in flight here.
            let bytes = u64::from(self.voxels.max(1)) * 4;
            self.view_weight.ensure(&self.ctx, bytes)?;
            self.view_weight_buffer()?.address()
        } else {
            self.buffers()?.0.address()
        };
        renderer.set_max_weight_target(Some(target));
        let done = self.add_views_queued(renderer, scene, cams, samples);
        renderer.set_max_weight_target(None);
        done
    }

    fn add_views_queued(
        &mut self,
        renderer: &mut Renderer,
        scene: &SceneGpu,
        cams: &[Camera],
        samples: u32,
    ) -> Result<()> {
        let opts = RenderOptions {
            samples,
            supersample: self.rule.supersample,
        };
        let per_view = self.rule.visible == StatsVisible::Weight;
        let ctx = self.ctx.clone();
        // (view, submission, checks, stats read early)
        type Queued = (usize, Ticket, FrameCheck, Option<FrameStats>);
        let mut queued: Option<Queued> = None;
        let submit = |me: &Self, renderer: &mut Renderer, i: usize| -> Result<Queued> {
            renderer.prepare(scene, &cams[i], &opts)?;
            let (check, ticket) = ctx.submit(|cmd| {
                if per_view {
                    // After the previous view's fold (its barrier) in queue order.
                    me.record_view_weight_reset(cmd)?;
                }
                renderer.record(cmd, scene, &cams[i], &opts, None)?;
                let check = renderer.record_checks(cmd, None)?;
                if scene.voxels > 0 {
                    me.record_fold(cmd, &renderer.last_frame()?, per_view, false)?;
                }
                Ok(check)
            })?;
            Ok((i, ticket, check, None))
        };
        for i in 0..=cams.len() {
            let mut next = match i < cams.len() {
                true => Some(submit(self, renderer, i)?),
                false => None,
            };
            let Some((j, ticket, check, early)) = queued.take() else {
                queued = next;
                continue;
            };
            ctx.wait(ticket)?;
            let stats = match early {
                Some(s) => s,
                None => renderer.checked_stats(&check)?,
            };
            if !stats.complete() {
                // The view queued behind keeps its checks: read them before the redo
                // reuses the slots.
                if let Some(n) = next.as_mut() {
                    ctx.wait(n.1)?;
                    n.3 = Some(renderer.checked_stats(&n.2)?);
                }
                renderer.grow_for(&stats)?;
                if per_view {
                    ctx.submit_and_wait(|cmd| self.record_view_weight_reset(cmd))?;
                }
                renderer.render_to_device(scene, &cams[j], &opts, None)?;
                if scene.voxels > 0 {
                    let frame = renderer.last_frame()?;
                    ctx.submit_and_wait(|cmd| self.record_fold(cmd, &frame, per_view, false))?;
                }
            }
            queued = next;
        }
        Ok(())
    }

    /// Folds one view into the min-interval accumulator only (the max weights are left
    /// as they are): runs the frame's preprocess, not its sort or compositing, so it costs
    /// a small fraction of [`StatsPass::add_view`]. The initialisation's visibility test:
    /// a view does not show a voxel whose centre is within its near plane (SVRaster's
    /// `mark_max_samp_rate`, `zdist > near`), where the adaptive steps' fold clamps the
    /// depth to it.
    pub fn add_view_intervals(
        &mut self,
        renderer: &mut Renderer,
        scene: &SceneGpu,
        cam: &Camera,
    ) -> Result<()> {
        if scene.voxels != self.voxels {
            return Err(Error::Invalid(format!(
                "StatsPass::add_view_intervals: the scene has {} voxels, the accumulators {} \
                 (call begin() for this scene)",
                scene.voxels, self.voxels
            )));
        }
        if scene.voxels == 0 {
            return Ok(());
        }
        let opts = RenderOptions {
            samples: 1,
            supersample: 1.0,
        };
        renderer.prepare(scene, cam, &opts)?;
        let ctx = self.ctx.clone();
        ctx.submit_and_wait(|cmd| {
            renderer.record_preprocess(cmd, scene, cam, &opts)?;
            self.record_interval_fold(cmd, &renderer.last_frame()?)
        })
    }

    /// The min sampling interval of every voxel of `scene` over `cams` (the max weights
    /// stay zero): uploads the scene, folds each view's preprocess, reads back.
    pub fn intervals(
        &mut self,
        renderer: &mut Renderer,
        scene: &Scene,
        cams: &[Camera],
    ) -> Result<VoxelStats> {
        let gpu = SceneGpu::upload(&self.ctx, scene)?;
        self.begin(gpu.voxels)?;
        for cam in cams {
            self.add_view_intervals(renderer, &gpu, cam)?;
        }
        drop(gpu);
        self.read()
    }

    /// Records the interval fold of a frame recorded earlier (for callers recording
    /// their own frames, e.g. in one command buffer after [`Renderer::record`]):
    /// `frame` is [`Renderer::last_frame`], which must have the voxel count given to
    /// [`StatsPass::begin`] and turn out complete; the frame's entries decide which
    /// voxels it shows. Needs a compute barrier after the frame (as
    /// [`Renderer::record`] leaves one); records one after the dispatch.
    pub fn record_interval_fold(
        &self,
        cmd: vk::CommandBuffer,
        frame: &FrameGeometry,
    ) -> Result<()> {
        self.record_fold(cmd, frame, false, true)
    }

    /// The interval fold; with `per_view`, only voxels with a weight in the frame's
    /// own max-weight target (the view-weight buffer) count as shown, and their weights
    /// are folded into the max-weight accumulator. With `skip_near` a view does not show
    /// a voxel whose centre is within its near plane (SVRaster's `mark_max_samp_rate`,
    /// `zdist > near`: the initial layout's rule); without, the depth is clamped to the
    /// near plane (the adaptive steps').
    fn record_fold(
        &self,
        cmd: vk::CommandBuffer,
        frame: &FrameGeometry,
        per_view: bool,
        skip_near: bool,
    ) -> Result<()> {
        let (mw, mi) = self.buffers()?;
        let view_w = match per_view {
            true => self.view_weight_buffer()?.address(),
            false => 0,
        };
        let push = IntervalPush {
            frame: frame.params,
            minint: mi.address(),
            view_w,
            maxw: mw.address(),
            count: self.voxels,
            // The render-resolution fx back to the view's own (exactly 1 unsupersampled).
            fx_scale: (f64::from(frame.out_width) / f64::from(frame.render_width)) as f32,
            skip_near: u32::from(skip_near),
            pad: 0,
        };
        self.kernel.dispatch_1d(cmd, &push, self.voxels);
        recorder::barrier(&self.ctx, cmd);
        Ok(())
    }

    /// Zeroes the view-weight buffer (and a barrier) before a view's frame.
    fn record_view_weight_reset(&self, cmd: vk::CommandBuffer) -> Result<()> {
        recorder::zero(&self.ctx, cmd, self.view_weight_buffer()?);
        recorder::barrier(&self.ctx, cmd);
        Ok(())
    }

    fn view_weight_buffer(&self) -> Result<&Buffer> {
        self.view_weight.buffer().ok_or_else(|| {
            Error::Invalid("StatsPass: the view-weight buffer was not allocated".into())
        })
    }

    /// Device address of the max-weight accumulator (one `u32` of `f32` bits per voxel).
    pub fn max_weight_address(&self) -> u64 {
        self.max_weight.buffer().map_or(0, |b| b.address())
    }

    /// Device address of the min-interval accumulator (one `f32` per voxel).
    pub fn min_interval_address(&self) -> u64 {
        self.min_interval.buffer().map_or(0, |b| b.address())
    }

    /// Downloads the accumulators (waits for the device).
    pub fn read(&self) -> Result<VoxelStats> {
        if self.voxels == 0 {
            return Ok(VoxelStats::default());
        }
        let (mw, mi) = self.buffers()?;
        let n = self.voxels as usize;
        let bits: Vec<u32> = self.ctx.download(mw, 0, n)?;
        Ok(VoxelStats {
            max_weight: bits.into_iter().map(f32::from_bits).collect(),
            min_interval: self.ctx.download(mi, 0, n)?,
        })
    }
}
