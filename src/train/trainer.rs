//! The training loop (paper §3.2; DESIGN §4): one random training view per iteration,
//! forward → losses → backward → Adam, and at the schedule's adaptive steps the layout
//! changes (paper §3.2.2; `adapt_step.rs`, kernels and topology in [`crate::adapt`]):
//! prune voxels whose max blend weight over every training view is below a ramped
//! threshold, subdivide the top few percent by accumulated priority. Setting a run up
//! (starting grid, budget, [`Trainer::new`]) is in `init.rs`.
//!
//! An iteration is one submission and one fence wait (where the device has conditional
//! rendering): the frame, its checks, and the update in a region the GPU skips when the
//! frame came out incomplete; the host then grows the buffers and runs the iteration
//! again (see [`Trainer::step`]). Stats and give-up counters are read from host-visible
//! memory, not downloaded.
//!
//! Optimiser state across a layout change is *carried*, not reset: surviving parameters
//! keep their Adam moments, children copy their parent's, new grid points interpolate and
//! average them like their densities. A reset would hand every new parameter a first
//! step of ≈ lr·(1−β₁)/√(1−β₂) = 9·lr (zero moments, bias correction of a late step).

use rand::Rng;

use super::backward::{Backward, EntryLosses, Gradients, Reduction};
use super::config::{Schedule, TrainConfig};
use super::init::Moments;
use super::loss::{LossWeights, NormalLoss, PixelLoss};
use super::optim::{Adam, AdamConfig, Tv};
use super::ssim::Ssim;
use super::views::TrainViews;
use crate::adapt::stats::StatsPass;
use crate::adapt::topology::Topology;
use crate::camera::Camera;
use ash::vk;

use crate::gpu::{recorder, Context, Ticket, Timestamps};
use crate::raster::{FrameCheck, FrameOutputs, FrameStats, Gate, RenderOptions, Renderer};
use crate::scene::{Scene, SceneGpu};
use crate::{Error, Result};

pub use super::init::{
    bytes_per_voxel, root_extent, uniform_grid, voxel_budget, voxel_budget_source,
    voxel_budget_with,
};
pub use crate::adapt::{visible_only, AdaptReport};

/// Loss values of one iteration (read back only on logged iterations).
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct StepLosses {
    /// Total weighted loss.
    pub loss: f64,
    pub mse: f64,
    pub psnr: f64,
    pub ssim: f64,
    pub t_concentration: f64,
    /// mean(T²) (the inside term).
    pub t_inside: f64,
    /// Mean distortion (mip-NeRF 360) per render pixel; 0 while the distortion loss is
    /// off (its sums are then not accumulated, see `FrameOutputs`).
    pub distortion: f64,
    pub tv: f64,
    /// mean(1 − N·n_med) and mean(α² − α N·n_mean) where defined (0 while inactive).
    pub normal_dmed: f64,
    pub normal_dmean: f64,
}

/// What one iteration did.
#[derive(Clone, Debug, Default)]
pub struct StepInfo {
    /// Iteration just completed (1-based).
    pub iter: u32,
    pub view: usize,
    pub sh_degree: u32,
    pub supersample: f32,
    /// Entries of this iteration's frame when the step waited for it (logged
    /// iterations, adaptive steps, timing or counters on); `None` while it is still
    /// queued (see [`Trainer::step`]).
    pub entries: Option<u64>,
    /// Loss values when this iteration was asked to measure them.
    pub losses: Option<StepLosses>,
    /// What the adaptive step after this iteration did, if one was scheduled.
    pub adapt: Option<AdaptReport>,
}

/// The loss weights and learning-rate scale of one iteration (the schedule's switches
/// applied).
#[derive(Clone, Copy)]
struct IterWeights {
    dist: f32,
    nmed: f32,
    nmean: f32,
    tv: f32,
    lr_scale: f32,
}

/// One iteration's draws and switches: what recording it (again) needs.
#[derive(Clone)]
struct IterPlan {
    /// Adam step number (the 1-based iteration).
    step: u32,
    view: usize,
    ss: f32,
    degree: u32,
    opts: RenderOptions,
    outputs: FrameOutputs,
    w: IterWeights,
}

/// An iteration submitted and not yet checked.
pub(super) struct Queued {
    plan: IterPlan,
    ticket: Ticket,
    check: FrameCheck,
    /// Byte offset of its go word in `Trainer::go`.
    go_offset: u64,
}

/// Go words in `Trainer::go`, used in turn.
pub(super) const GO_WORDS: u64 = 2;

/// Per-stage timestamps of the last iteration (ms), when enabled.
pub type StageTimes = Vec<(String, f64)>;

/// The trainer: scene and optimiser state on the device plus the training views.
pub struct Trainer {
    pub(super) ctx: Context,
    pub(super) cfg: TrainConfig,
    pub(super) schedule: Schedule,
    /// The model's layout on the host (octpaths, levels, grid keys, corners). Its
    /// parameters are stale: the device holds them, and `download_params` refreshes
    /// them when a host copy is needed (snapshots, checkpoints).
    pub(super) host: Scene,
    pub(super) scene: SceneGpu,
    pub(super) grads: Gradients,
    pub(super) mom: [Moments; 3],
    pub(super) renderer: Renderer,
    pub(super) backward: Backward,
    pub(super) ssim: Ssim,
    pub(super) adam: Adam,
    pub(super) tv: Tv,
    pub(super) loss: PixelLoss,
    pub(super) normal: NormalLoss,
    pub(super) views: TrainViews,
    pub(super) cams: Vec<Camera>,
    pub(super) rng: rand_pcg::Pcg64,
    pub(super) order: Vec<usize>,
    pub(super) iter: u32,
    pub(super) timing: Option<(Timestamps, Timestamps)>,
    pub(super) last_times: StageTimes,
    pub(super) stats: StatsPass,
    pub(super) topology: Topology,
    pub(super) budget: u64,
    /// Where `budget` comes from, in words.
    pub(super) budget_source: String,
    /// Whether the budget stopped a subdivision already (logged once).
    pub(super) budget_logged: bool,
    /// The frame's go word (1: complete), the predicate of the update's conditional
    /// region (see [`Trainer::step`]).
    pub(super) go: crate::gpu::Buffer,
    pub(super) last_stats: Option<FrameStats>,
    /// One submission per iteration ([`Trainer::set_single_submission`]).
    pub(super) single: bool,
    /// Iterations run again over an incomplete frame.
    pub(super) redone: u64,
    /// Queue an iteration behind the next ([`Trainer::set_pipelined`]).
    pub(super) pipelined: bool,
    /// The iteration submitted and not yet checked.
    pub(super) queued: Option<Queued>,
    /// Go words handed out so far (picks the next one).
    pub(super) go_seq: u64,
    /// Work counters on (each iteration is then waited for).
    pub(super) counting: bool,
}

impl Trainer {
    pub fn config(&self) -> &TrainConfig {
        &self.cfg
    }
    pub fn schedule(&self) -> &Schedule {
        &self.schedule
    }
    /// Iterations completed.
    pub fn iter(&self) -> u32 {
        self.iter
    }
    pub fn voxels(&self) -> u32 {
        self.scene.voxels
    }
    /// Whether the backward uses native float atomics.
    pub fn float_atomics(&self) -> bool {
        self.backward.float_atomics()
    }

    /// How the backward sums gradients ([`Reduction::Ordered`] with `deterministic`).
    pub fn reduction(&self) -> Reduction {
        self.backward.reduction()
    }

    /// Records per-stage GPU timestamps from now on (see [`Trainer::stage_times`]).
    pub fn enable_timing(&mut self) -> Result<()> {
        if self.timing.is_none() {
            self.timing = Some((
                Timestamps::new(&self.ctx, 16)?,
                Timestamps::new(&self.ctx, 16)?,
            ));
        }
        Ok(())
    }

    /// Stops recording stage timestamps (iterations are queued again).
    pub fn set_timing(&mut self, on: bool) -> Result<()> {
        if on {
            return self.enable_timing();
        }
        self.flush()?;
        self.timing = None;
        Ok(())
    }

    /// Turns the work counters of the frame and backward walks on or off (benchmarks:
    /// the counting kernels are slower; see [`Renderer::set_counters`]).
    pub fn set_counters(&mut self, on: bool) -> Result<()> {
        self.flush()?;
        self.counting = on;
        self.renderer.set_counters(on)
    }

    /// Work counters of the last iteration (forward and backward), when on.
    pub fn counters(&mut self) -> Result<Option<crate::raster::WorkCounters>> {
        self.flush()?;
        self.renderer.counters()
    }

    /// Whether [`Trainer::step`] leaves its iteration queued behind the next (the
    /// default where an iteration is one submission) or waits for each one (tests
    /// compare the two).
    pub fn set_pipelined(&mut self, on: bool) -> Result<()> {
        self.flush()?;
        self.pipelined = on;
        Ok(())
    }

    /// Whether an iteration is one submission (the default where the device has
    /// conditional rendering) or two, the frame checked on the host before the update
    /// is recorded (the path for devices without it; tests compare the two).
    pub fn set_single_submission(&mut self, on: bool) -> Result<()> {
        if on && !self.ctx.info().conditional_rendering {
            return Err(Error::Invalid(
                "one submission per iteration needs VK_EXT_conditional_rendering, which \
                 this device (or the host that made it) did not enable"
                    .into(),
            ));
        }
        self.flush()?;
        self.single = on;
        Ok(())
    }

    /// Entries per segment of the frame's composite (0: off; see
    /// [`Renderer::set_segment_entries`]).
    pub fn set_segment_entries(&mut self, entries: u32) -> Result<()> {
        self.flush()?;
        self.renderer.set_segment_entries(entries);
        Ok(())
    }

    /// Entries per composite and backward dispatch (tests: a small size makes the first
    /// frames need more dispatches than recorded, so iterations are redone).
    pub fn set_chunk_size(&mut self, entries: u32) {
        self.renderer.set_chunk_size(entries);
        self.backward.set_chunk_size(entries);
    }

    /// Iterations whose frame came out incomplete and that were run again with grown
    /// buffers (their first update skipped on the GPU, or never recorded).
    pub fn frames_redone(&self) -> u64 {
        self.redone
    }

    /// The stats of the last complete frame the host checked: this iteration's after a
    /// [`Trainer::flush`], else the one before it while this one is queued.
    pub fn frame_stats(&self) -> Option<FrameStats> {
        self.last_stats
    }

    /// Stage times (ms) of the last iteration: the frame's stages, then losses,
    /// backward, optimizer.
    pub fn stage_times(&self) -> &StageTimes {
        &self.last_times
    }

    /// Fast-forwards the iteration counter and random state to `iter` (resume); the
    /// scene and optimiser state must be restored separately.
    pub fn skip_to(&mut self, iter: u32) {
        while self.iter < iter {
            self.next_view();
            self.draw_ss(self.iter);
            self.iter += 1;
        }
    }

    fn next_view(&mut self) -> usize {
        if self.order.is_empty() {
            self.order = (0..self.cams.len()).collect();
            // Fisher–Yates with our seeded generator (reproducible).
            for i in (1..self.order.len()).rev() {
                let j = self.rng.gen_range(0..=i);
                self.order.swap(i, j);
            }
        }
        self.order.pop().expect("non-empty")
    }

    fn draw_ss(&mut self, it: u32) -> f32 {
        let u: f32 = self.rng.gen();
        if it < self.schedule.ss_from || self.cfg.ss <= 1.0 {
            1.0
        } else {
            1.0 + u * (self.cfg.ss - 1.0)
        }
    }

    /// The draws and switches of iteration `self.iter` (0-based): the view, the
    /// supersampling factor, the SH degree, the loss weights.
    fn plan_iteration(&mut self) -> IterPlan {
        let it = self.iter;
        let view = self.next_view();
        let ss = self.draw_ss(it);
        let cfg = &self.cfg;
        let after = |from: u32, value: f32| if it >= from { value } else { 0.0 };
        let w = IterWeights {
            dist: after(self.schedule.dist_from, cfg.lambda_dist),
            nmed: after(self.schedule.normal_dmed_from, cfg.lambda_normal_dmed),
            nmean: after(self.schedule.normal_dmean_from, cfg.lambda_normal_dmean),
            tv: if it < self.schedule.tv_until {
                cfg.lambda_tv
            } else {
                0.0
            },
            lr_scale: if it >= self.schedule.lr_decay_at {
                cfg.lr_decay
            } else {
                1.0
            },
        };
        IterPlan {
            step: it + 1,
            view,
            ss,
            degree: self.schedule.sh_degree(it).min(cfg.sh_degree),
            opts: RenderOptions {
                samples: cfg.samples,
                supersample: ss,
            },
            // The frame accumulates only what this iteration's losses read.
            outputs: FrameOutputs {
                normals: w.nmed > 0.0 || w.nmean > 0.0,
                distortion: w.dist != 0.0,
            },
            w,
        }
    }

    /// Runs one iteration; with `measure`, reads back the loss values.
    ///
    /// Where the device has conditional rendering, an iteration is one submission and
    /// the host does not wait for it: the frame, its checks (stats and error words
    /// copied to host-visible memory, a go word written on the GPU) and, in a region
    /// that runs only if the frame came out complete, losses, backward, TV and Adam.
    /// The iteration stays queued while the next one is recorded and submitted behind
    /// it; only then does the host wait for it (the device is busy with the next one)
    /// and read its checks. An incomplete frame skips its update on the GPU, and its go
    /// word skips the update queued behind it too; the host then grows the buffers and
    /// runs both again, in order, so the result is the same as checking each frame
    /// before its update. Logged iterations, adaptive steps and anything that reads the
    /// model ([`Trainer::flush`]) wait for the queue to drain. Without conditional
    /// rendering (a host's device that did not enable it) the frame is its own
    /// submission; with stage timing or work counters on, each iteration is waited for.
    pub fn step(&mut self, measure: bool) -> Result<StepInfo> {
        let plan = self.plan_iteration();
        let queue = self.single && self.pipelined && self.timing.is_none() && !self.counting;
        let mut own = None;
        if queue {
            let after = self.queued.as_ref().map(|q| q.go_offset);
            let q = self.submit_iteration(&plan, after)?;
            if let Some(prev) = self.queued.replace(q) {
                self.settle(prev)?;
            }
        } else {
            self.flush()?;
            let stats = self.run_now(&plan)?;
            self.check_lost()?;
            self.last_stats = Some(stats);
            own = Some(stats);
        }
        self.iter += 1;
        let adapt = self
            .schedule
            .adapt
            .iter()
            .find(|s| s.iter == self.iter)
            .copied();
        if own.is_none() && (measure || adapt.is_some()) {
            own = self.flush()?;
        }
        let losses = if measure {
            Some(self.read_losses(plan.w.dist, plan.w.tv, (plan.w.nmed, plan.w.nmean))?)
        } else {
            None
        };
        let adapt = match adapt {
            Some(step) => Some(self.adapt(step)?),
            None => None,
        };
        Ok(StepInfo {
            iter: self.iter,
            view: plan.view,
            sh_degree: plan.degree,
            supersample: plan.ss,
            entries: own.map(|s| s.entries),
            losses,
            adapt,
        })
    }

    /// Waits for the iteration still queued (if any) and settles it: its frame
    /// checked, its update redone if the frame came out incomplete. Returns that
    /// frame's stats. Everything that reads the model or optimiser state calls this
    /// first.
    pub fn flush(&mut self) -> Result<Option<FrameStats>> {
        let Some(q) = self.queued.take() else {
            return Ok(None);
        };
        self.ctx.wait(q.ticket)?;
        self.check_lost()?;
        let mut stats = self.renderer.checked_stats(&q.check)?;
        if !stats.complete() {
            self.redone += 1;
            if !self.renderer.grow_for(&stats)? {
                return Err(Error::Gpu(format!(
                    "frame incomplete but nothing to grow: {stats:?}"
                )));
            }
            stats = self.run_now(&q.plan)?;
            self.check_lost()?;
        }
        self.last_stats = Some(stats);
        Ok(Some(stats))
    }

    /// Waits for iteration `prev` while the one queued behind it runs, and checks its
    /// frame. If it came out incomplete, both updates were skipped on the GPU: the
    /// buffers grow, `prev` runs again (waited for) and the queued one is submitted
    /// again behind it.
    fn settle(&mut self, prev: Queued) -> Result<()> {
        self.ctx.wait(prev.ticket)?;
        self.check_lost()?;
        let stats = self.renderer.checked_stats(&prev.check)?;
        if stats.complete() {
            self.last_stats = Some(stats);
            return Ok(());
        }
        let cur = self
            .queued
            .take()
            .ok_or_else(|| Error::Gpu("no iteration queued behind a skipped one".into()))?;
        self.ctx.wait(cur.ticket)?;
        // Measured on parameters one update stale: a capacity hint, grown for as well.
        let cur_stats = self.renderer.checked_stats(&cur.check)?;
        self.redone += 2;
        if !self.renderer.grow_for(&stats)? {
            return Err(Error::Gpu(format!(
                "frame incomplete but nothing to grow: {stats:?}"
            )));
        }
        if !cur_stats.complete() {
            self.renderer.grow_for(&cur_stats)?;
        }
        let stats = self.run_now(&prev.plan)?;
        self.check_lost()?;
        self.last_stats = Some(stats);
        let q = self.submit_iteration(&cur.plan, None)?;
        self.queued = Some(q);
        Ok(())
    }

    /// Errors if a compare-and-swap float add gave up since the run began (the
    /// counters are cumulative, so reading them an iteration late misses nothing).
    fn check_lost(&self) -> Result<()> {
        if self.backward.read_lost()? != 0 || self.tv.read_lost()? != 0 {
            return Err(Error::Gpu(
                "compare-and-swap float adds gave up under contention: gradients are incomplete"
                    .into(),
            ));
        }
        Ok(())
    }

    /// Sets the host-side state iteration `plan` records with.
    fn apply(&mut self, plan: &IterPlan) {
        self.scene.sh_degree = plan.degree;
        self.renderer.set_outputs(plan.outputs);
    }

    /// Records and submits iteration `plan` (frame, checks, its update in the frame's
    /// conditional region) without waiting; `after`: the go word of the iteration
    /// queued before it, whose skip this one follows.
    fn submit_iteration(&mut self, plan: &IterPlan, after: Option<u64>) -> Result<Queued> {
        self.apply(plan);
        let cam = self.cams[plan.view].clone();
        self.renderer.prepare(&self.scene, &cam, &plan.opts)?;
        let go_offset = self.next_go();
        let ctx = self.ctx.clone();
        let (check, ticket) =
            ctx.submit(|cmd| self.record_gated(cmd, plan, &cam, go_offset, after, &mut None))?;
        Ok(Queued {
            plan: plan.clone(),
            ticket,
            check,
            go_offset,
        })
    }

    /// The byte offset of the next go word (they alternate, so a queued iteration's
    /// word outlives the recording of the next).
    fn next_go(&mut self) -> u64 {
        self.go_seq += 1;
        4 * (self.go_seq % GO_WORDS)
    }

    /// Records iteration `plan`'s frame, checks, and update in the frame's conditional
    /// region (go word at `go_offset`, chained after the word at `after`).
    fn record_gated(
        &mut self,
        cmd: vk::CommandBuffer,
        plan: &IterPlan,
        cam: &Camera,
        go_offset: u64,
        after: Option<u64>,
        timing: &mut Option<(Timestamps, Timestamps)>,
    ) -> Result<FrameCheck> {
        let ctx = self.ctx.clone();
        self.renderer.record(
            cmd,
            &self.scene,
            cam,
            &plan.opts,
            timing.as_mut().map(|t| &mut t.0),
        )?;
        let check = self.renderer.record_checks(
            cmd,
            Some(Gate {
                go: &self.go,
                offset: go_offset,
                after: after.map(|o| (&self.go, o)),
            }),
        )?;
        let planned = self.renderer.planned_stats()?;
        recorder::begin_conditional(&ctx, cmd, &self.go, go_offset)?;
        self.record_update(cmd, plan.view, cam, &planned, &plan.w, plan.step, timing)?;
        recorder::end_conditional(&ctx, cmd)?;
        Ok(check)
    }

    /// Renders view `plan.view` and takes its training step, waiting for it, growing
    /// the frame buffers and repeating until the frame is complete; returns the
    /// complete frame's stats (and, with timing on, its stage times).
    fn run_now(&mut self, plan: &IterPlan) -> Result<FrameStats> {
        self.apply(plan);
        let cam = self.cams[plan.view].clone();
        let mut timing = self.timing.take();
        let res = self.run_now_timed(plan, &cam, &mut timing);
        if let (Some(t), Ok(_)) = (timing.as_ref(), res.as_ref()) {
            let mut all = t.0.stages()?;
            all.extend(t.1.stages()?);
            self.last_times = all;
        }
        self.timing = timing;
        res
    }

    fn run_now_timed(
        &mut self,
        plan: &IterPlan,
        cam: &Camera,
        timing: &mut Option<(Timestamps, Timestamps)>,
    ) -> Result<FrameStats> {
        let ctx = self.ctx.clone();
        if !self.single {
            let redone = self.renderer.frames_grown();
            let stats = self.renderer.render_to_device(
                &self.scene,
                cam,
                &plan.opts,
                timing.as_mut().map(|t| &mut t.0),
            )?;
            ctx.submit_and_wait(|cmd| {
                self.record_update(cmd, plan.view, cam, &stats, &plan.w, plan.step, timing)
            })?;
            self.redone += self.renderer.frames_grown() - redone;
            return Ok(stats);
        }
        for _attempt in 0..8 {
            self.renderer.prepare(&self.scene, cam, &plan.opts)?;
            let go_offset = self.next_go();
            let check = ctx.submit_and_wait(|cmd| {
                self.record_gated(cmd, plan, cam, go_offset, None, timing)
            })?;
            let stats = self.renderer.checked_stats(&check)?;
            if stats.complete() {
                return Ok(stats);
            }
            // The update was skipped on the GPU: grow and run the iteration again.
            self.redone += 1;
            if !self.renderer.grow_for(&stats)? {
                return Err(Error::Gpu(format!(
                    "frame incomplete but nothing to grow: {stats:?}"
                )));
            }
        }
        Err(Error::Gpu("frame still incomplete after 8 attempts".into()))
    }

    /// Records the update of the frame just recorded (`stats`: its stats, or what the
    /// frame's plan lets the update assume): losses against view `view`, backward with
    /// TV, and the Adam step of every parameter group.
    #[allow(clippy::too_many_arguments)]
    fn record_update(
        &mut self,
        cmd: vk::CommandBuffer,
        view: usize,
        cam: &Camera,
        stats: &FrameStats,
        w: &IterWeights,
        step: u32,
        timing: &mut Option<(Timestamps, Timestamps)>,
    ) -> Result<()> {
        let cfg = self.cfg.clone();
        let ctx = self.ctx.clone();
        let frame = self.renderer.last_frame()?;
        if (frame.out_width, frame.out_height) != (cam.width, cam.height) {
            return Err(Error::Invalid(format!(
                "frame rendered at {}×{}, but training view {view} is {}×{}",
                frame.out_width, frame.out_height, cam.width, cam.height
            )));
        }
        self.backward.prepare(&frame, self.scene.voxels)?;
        let nrender = frame.render_width * frame.render_height;
        self.ssim.prepare(frame.out_width, frame.out_height)?;
        let gt_addr = self.views.address(view);
        let out_addr = self.renderer.output_address()?;
        let dout_addr = self.backward.dout()?.address();
        if let Some(t) = timing.as_mut() {
            t.1.begin(cmd);
        }
        self.loss.record(
            cmd,
            &frame,
            out_addr,
            gt_addr,
            dout_addr,
            LossWeights {
                mse: cfg.lambda_mse,
                t_concentration: cfg.lambda_t,
                t_inside: cfg.lambda_t_inside,
            },
        )?;
        if w.nmed > 0.0 || w.nmean > 0.0 {
            self.normal
                .record(cmd, cam, out_addr, dout_addr, w.nmed, w.nmean)?;
        }
        if cfg.lambda_ssim > 0.0 {
            self.ssim.record(
                cmd,
                out_addr,
                gt_addr,
                dout_addr,
                -cfg.lambda_ssim,
                frame.out_width,
                frame.out_height,
            )?;
        }
        if let Some(t) = timing.as_mut() {
            t.1.mark(cmd, "losses");
        }
        let tv = &mut self.tv;
        let scene = &self.scene;
        let lambda_tv = w.tv;
        self.backward.record_timed(
            cmd,
            &frame,
            stats,
            scene,
            cfg.samples,
            &self.grads,
            &EntryLosses {
                lambda_dist: w.dist / nrender as f32,
                lambda_r: cfg.lambda_r / nrender as f32,
            },
            timing.as_mut().map(|t| &mut t.1),
            |cmd, geo_target| {
                // TV adds to the density gradients (the grid points', or the
                // ordered reduction's voxel corners before their gather).
                if lambda_tv > 0.0 {
                    tv.record(
                        cmd,
                        scene.corners.address(),
                        scene.geo.address(),
                        geo_target,
                        scene.voxels,
                        lambda_tv,
                    )?;
                    recorder::barrier(&ctx, cmd);
                }
                Ok(())
            },
        )?;
        if let Some(t) = timing.as_mut() {
            t.1.mark(cmd, "backward.tv");
        }
        let groups = [
            (
                "optimizer.geo",
                &self.scene.geo,
                &self.grads.geo,
                &self.mom[0],
                self.scene.grid_points as u64,
                self.schedule.lr_geo,
            ),
            (
                "optimizer.sh0",
                &self.scene.sh0,
                &self.grads.sh0,
                &self.mom[1],
                self.scene.voxels as u64 * 3,
                cfg.lr_sh0,
            ),
            (
                "optimizer.shs",
                &self.scene.shs,
                &self.grads.shs,
                &self.mom[2],
                // The whole blocked device layout (padding stays zero).
                crate::scene::shs_device_len(
                    self.scene.voxels as usize,
                    3 * self.scene.shs_per_voxel as usize,
                ) as u64,
                cfg.lr_shs,
            ),
        ];
        for (label, p, g, m, count, lr) in groups {
            if count == 0 {
                continue;
            }
            self.adam.record(
                cmd,
                p.address(),
                g.address(),
                m.m.address(),
                m.v.address(),
                count as u32,
                step,
                &AdamConfig {
                    lr: lr * w.lr_scale,
                    beta1: cfg.beta1,
                    beta2: cfg.beta2,
                    eps: cfg.eps,
                    skip_zero: cfg.sparse_adam,
                },
            );
            if let Some(t) = timing.as_mut() {
                t.1.mark(cmd, label);
            }
        }
        recorder::barrier(&ctx, cmd);
        Ok(())
    }

    /// The voxel budget in force (see [`voxel_budget`]).
    pub fn budget(&self) -> u64 {
        self.budget
    }

    /// Where [`Trainer::budget`] comes from, in words (`max_voxels`, or the device
    /// memory it was derived from when the run started).
    pub fn budget_source(&self) -> &str {
        &self.budget_source
    }

    pub fn grid_points(&self) -> u32 {
        self.scene.grid_points
    }

    /// Device memory the engine holds now (bytes).
    pub fn device_memory(&self) -> u64 {
        self.ctx.memory_allocated()
    }

    fn read_losses(
        &self,
        lambda_dist: f32,
        lambda_tv: f32,
        lambda_normal: (f32, f32),
    ) -> Result<StepLosses> {
        let cfg = &self.cfg;
        let sums = self.loss.read()?;
        let mse = sums.squared_error / (3.0 * sums.out_pixels as f64);
        let tconc = sums.t_concentration / sums.out_pixels as f64;
        let tin = sums.t_inside / sums.out_pixels as f64;
        let dist = sums.distortion / sums.render_pixels as f64;
        let ssim = if cfg.lambda_ssim > 0.0 {
            self.ssim.read_value()?
        } else {
            f64::NAN
        };
        let tv = if lambda_tv > 0.0 {
            self.tv.read_value()?
        } else {
            0.0
        };
        let (nmed, nmean) = if lambda_normal.0 > 0.0 || lambda_normal.1 > 0.0 {
            let s = self.normal.read()?;
            let n = f64::from(s.pixels.max(1));
            (s.median / n, s.mean / n)
        } else {
            (0.0, 0.0)
        };
        let ssim_term = if ssim.is_finite() { 1.0 - ssim } else { 0.0 };
        // The per-point RGB term is folded into the backward and not measured.
        let loss = cfg.lambda_mse as f64 * mse
            + cfg.lambda_ssim as f64 * ssim_term
            + cfg.lambda_t as f64 * tconc
            + cfg.lambda_t_inside as f64 * tin
            + lambda_dist as f64 * dist
            + lambda_tv as f64 * tv
            + f64::from(lambda_normal.0) * nmed
            + f64::from(lambda_normal.1) * nmean;
        Ok(StepLosses {
            loss,
            mse,
            psnr: -10.0 * mse.max(1e-20).log10(),
            ssim,
            t_concentration: tconc,
            t_inside: tin,
            normal_dmed: nmed,
            normal_dmean: nmean,
            distortion: dist,
            tv,
        })
    }

    /// Whether a non-finite gradient or parameter appeared since the last check.
    pub fn check_finite(&mut self) -> Result<()> {
        self.flush()?;
        if self.adam.read_nonfinite()? {
            return Err(Error::Invalid(format!(
                "a NaN or infinite value appeared in the gradients or parameters by \
                 iteration {}; the run stopped without saving it. Lower the learning rates \
                 (e.g. --set lr_geo=0.01) or resume from the last checkpoint",
                self.iter
            )));
        }
        Ok(())
    }

    /// The current model (downloads the parameters).
    pub fn scene(&mut self) -> Result<Scene> {
        self.flush()?;
        self.scene.download_params(&self.ctx, &mut self.host)?;
        Ok(self.host.clone())
    }

    /// Adam moments and iteration, for resuming: (geo m, geo v, sh0 m, sh0 v, shs m, shs v).
    pub fn optimizer_state(&mut self) -> Result<Vec<Vec<f32>>> {
        self.flush()?;
        let counts = self.group_counts();
        let (n, w) = (
            self.scene.voxels as usize,
            3 * self.scene.shs_per_voxel as usize,
        );
        let mut out = Vec::new();
        for (i, (m, &c)) in self.mom.iter().zip(&counts).enumerate() {
            for b in [&m.m, &m.v] {
                out.push(if c == 0 {
                    Vec::new()
                } else if i == 2 {
                    // The SH moments, from the blocked device layout.
                    crate::scene::download_shs(&self.ctx, b, n, w)?
                } else {
                    self.ctx.download(b, 0, c)?
                });
            }
        }
        Ok(out)
    }

    /// Restores Adam moments saved by [`Trainer::optimizer_state`].
    pub fn set_optimizer_state(&mut self, state: &[Vec<f32>]) -> Result<()> {
        self.flush()?;
        let counts = self.group_counts();
        if state.len() != 6 || (0..6).any(|i| state[i].len() != counts[i / 2]) {
            return Err(Error::Invalid(
                "optimizer state does not match the model's parameter counts".into(),
            ));
        }
        let (n, w) = (
            self.scene.voxels as usize,
            3 * self.scene.shs_per_voxel as usize,
        );
        for (i, m) in self.mom.iter().enumerate() {
            if counts[i] > 0 {
                for (buf, host) in [(&m.m, &state[2 * i]), (&m.v, &state[2 * i + 1])] {
                    if i == 2 {
                        crate::scene::upload_shs(&self.ctx, buf, host, n, w)?;
                    } else {
                        self.ctx.upload(buf, 0, host)?;
                    }
                }
            }
        }
        Ok(())
    }

    /// Element counts of the parameter groups (geo, sh0, shs).
    pub fn group_counts(&self) -> [usize; 3] {
        [
            self.scene.grid_points as usize,
            self.scene.voxels as usize * 3,
            self.scene.voxels as usize * 3 * self.scene.shs_per_voxel as usize,
        ]
    }
}
