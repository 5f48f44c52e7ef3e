//! The training loop (paper §3.2; docs/ARCHITECTURE.md §4): one random training view per iteration,
//! forward → losses → backward → Adam, and at the schedule's adaptive steps the layout
//! changes (paper §3.2.2; `adapt_step.rs`, kernels and topology in [`crate::adapt`]):
//! prune voxels whose max blend weight over every training view is below a ramped
//! threshold, subdivide the top few percent by accumulated priority. Setting a run up
//! (starting grid, budget, [`Trainer::new`]) is in `init.rs`.
//!
//! An iteration is one submission (where the device has conditional rendering): the
//! frame, its checks, and the update in a region the GPU skips when the frame came out
//! incomplete. The host waits for it only after submitting the next one behind it, then
//! reads its stats and give-up counters from host-visible memory; an incomplete frame
//! skips the iteration queued behind it too, and the host grows the buffers and runs
//! both again (see [`Trainer::step`]; recording and settling are in `queue.rs`, the
//! update in `update.rs`).
//!
//! Optimiser state across a layout change is *carried*, not reset: surviving parameters
//! keep their Adam moments, children copy their parent's, new grid points interpolate and
//! average them like their densities. A reset would hand every new parameter a first
//! step of ≈ lr·(1−β₁)/√(1−β₂) = 9·lr (zero moments, bias correction of a late step).

use rand::Rng;

use super::backward::{Backward, Gradients, Reduction};
use super::config::{Schedule, TrainConfig};
use super::iteration::{IterPlan, IterWeights, Queued};
use super::loss::{NormalLoss, PixelLoss};
use super::optim::Moments;
use super::optim::{Adam, Tv};
use super::ssim::Ssim;
use super::views::TrainViews;
use crate::adapt::stats::StatsPass;
use crate::adapt::topology::Topology;
use crate::camera::Camera;

use crate::error::{Error, Result};
use crate::gpu::{Context, Timestamps};
use crate::raster::{FrameOutputs, FrameStats, RenderOptions, Renderer};
use crate::scene::{Scene, SceneGpu};

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

/// Per-stage timestamps of one iteration (ms, in recording order), when enabled.
pub type StageTimes = Vec<(String, f64)>;

/// Settled iterations whose stage times [`Trainer::take_stage_times`] keeps.
pub const KEPT_STAGE_TIMES: usize = 64;

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
    /// Stage timestamps (frame, update) for the next iteration recorded, when timing
    /// is on; `timing_spare` is the second pair, so that the iteration queued behind
    /// another records into its own while the first one's are still to be read.
    pub(super) timing: Option<(Timestamps, Timestamps)>,
    pub(super) timing_spare: Option<(Timestamps, Timestamps)>,
    pub(super) last_times: Vec<StageTimes>,
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
    /// The iteration Adam's bias-correction count starts from (0, or the last adaptive
    /// step with `reset_adam_at_adapt`).
    pub(super) adam_base: u32,
    /// The next iteration's view and supersampling, fixed ([`Trainer::set_next_draw`]).
    pub(super) next_draw: Option<(usize, f32)>,
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

    /// Records per-stage GPU timestamps from now on (see [`Trainer::take_stage_times`]).
    /// Iterations stay queued: each one's timestamps are read when the host settles
    /// it, while the next one runs, so they time the iterations as training runs them.
    pub fn enable_timing(&mut self) -> Result<()> {
        if self.timing.is_none() && self.timing_spare.is_none() {
            let pair = || -> Result<(Timestamps, Timestamps)> {
                Ok((
                    Timestamps::new(&self.ctx, 16)?,
                    Timestamps::new(&self.ctx, 16)?,
                ))
            };
            self.timing = Some(pair()?);
            self.timing_spare = Some(pair()?);
        }
        Ok(())
    }

    /// Starts or stops recording stage timestamps.
    pub fn set_timing(&mut self, on: bool) -> Result<()> {
        if on {
            return self.enable_timing();
        }
        self.flush()?;
        self.timing = None;
        self.timing_spare = None;
        self.last_times.clear();
        Ok(())
    }

    /// A timestamp pair back to the free slots after its iteration was read.
    pub(super) fn return_timing(&mut self, t: Option<(Timestamps, Timestamps)>) {
        if let Some(p) = t {
            if self.timing.is_none() {
                self.timing = Some(p);
            } else {
                self.timing_spare = Some(p);
            }
        }
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

    /// Queue traffic of the trainer's context so far ([`Context::queue_counters`]).
    pub fn queue_counters(&self) -> crate::gpu::QueueCounters {
        self.ctx.queue_counters()
    }

    /// Entries per segment of the frame's walks (0: off).
    pub fn segment_entries(&self) -> u32 {
        self.renderer.segment_entries()
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

    /// Stage times (ms) of each iteration the host settled since the last call, oldest
    /// first (with queued iterations a step's own are settled by the next step or a
    /// flush; at most the last [`KEPT_STAGE_TIMES`]): the frame's stages, then losses,
    /// backward, optimizer.
    pub fn take_stage_times(&mut self) -> Vec<StageTimes> {
        std::mem::take(&mut self.last_times)
    }

    /// Keeps one settled iteration's stage times (the oldest dropped beyond
    /// [`KEPT_STAGE_TIMES`]).
    pub(super) fn push_stage_times(&mut self, times: StageTimes) {
        if times.is_empty() {
            return;
        }
        if self.last_times.len() >= KEPT_STAGE_TIMES {
            self.last_times.remove(0);
        }
        self.last_times.push(times);
    }

    /// Fast-forwards the iteration counter and random state to `iter` (resume); the
    /// scene and optimiser state must be restored separately.
    pub fn skip_to(&mut self, iter: u32) {
        while self.iter < iter {
            self.next_view();
            self.draw_ss(self.iter);
            self.iter += 1;
        }
        // The optimiser's count restarts at the schedule's last resetting step, as in
        // the run that saved the checkpoint.
        self.adam_base = self.adam_base_at(self.iter);
    }

    /// Where Adam's count starts for iterations after `iter` completed ones: the last
    /// adaptive step up to `iter` that prunes or subdivides, with `reset_adam_at_adapt`.
    pub(super) fn adam_base_at(&self, iter: u32) -> u32 {
        if !self.cfg.reset_adam_at_adapt {
            return 0;
        }
        self.schedule
            .adapt
            .iter()
            .filter(|s| s.iter <= iter && (s.prune_below.is_some() || s.subdivide))
            .map(|s| s.iter)
            .max()
            .unwrap_or(0)
    }

    /// Fixes the next iteration's training view and supersampling factor, as replaying
    /// another trainer's iteration needs (the step-level parity test, tests/parity.rs).
    /// The random draws are still taken, so the iterations after it draw as before.
    pub fn set_next_draw(&mut self, view: usize, supersample: f32) -> Result<()> {
        if view >= self.cams.len() || supersample.is_nan() || supersample < 1.0 {
            return Err(Error::Invalid(format!(
                "next draw: view {view} of {} training views, supersampling {supersample} \
                 (must be ≥ 1)",
                self.cams.len()
            )));
        }
        self.next_draw = Some((view, supersample));
        Ok(())
    }

    /// Sets Adam's step count: the next iteration is its step `next` (≥ 1), as an
    /// optimiser made afresh `next − 1` iterations ago counts (SVRaster re-creates its
    /// optimiser at every adaptive step).
    pub fn set_adam_count(&mut self, next: u32) -> Result<()> {
        if next == 0 || next > self.iter + 1 {
            return Err(Error::Invalid(format!(
                "Adam step {next} cannot come next after {} iterations",
                self.iter
            )));
        }
        self.adam_base = self.iter + 1 - next;
        Ok(())
    }

    /// The gradients of the last iteration, in the host layouts: grid-point densities,
    /// sh0 (`[N][3]`), shs (`[N][coeffs][3]`), and the subdivision priority accumulated
    /// since the last adaptive step (`[N]`).
    pub fn gradients(&mut self) -> Result<[Vec<f32>; 4]> {
        self.flush()?;
        let g = &self.grads;
        Ok([
            self.ctx.download(&g.geo, 0, g.grid_points as usize)?,
            self.ctx.download(&g.sh0, 0, 3 * g.voxels as usize)?,
            g.download_shs(&self.ctx)?,
            self.ctx.download(&g.priority, 0, g.voxels as usize)?,
        ])
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
        let mut view = self.next_view();
        let mut ss = self.draw_ss(it);
        if let Some((v, s)) = self.next_draw.take() {
            (view, ss) = (v, s);
        }
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
            step: it + 1 - self.adam_base,
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
                distortion_contracted: w.dist != 0.0 && cfg.dist_contracted,
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
    /// submission; with work counters on, each iteration is waited for (stage timestamps
    /// stay queued: read when the iteration is settled).
    pub fn step(&mut self, measure: bool) -> Result<StepInfo> {
        let plan = self.plan_iteration();
        let queue = self.single && self.pipelined && !self.counting;
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

    /// Whether a non-finite gradient or parameter appeared since the last check.
    pub fn check_finite(&mut self) -> Result<()> {
        self.flush()?;
        if self.adam.read_nonfinite()? {
            return Err(Error::Invalid(format!(
                "a NaN or infinite value appeared in the gradients or parameters by \
                 iteration {}; the run stopped without saving it. Resume from its last \
                 checkpoint (--resume), or start a new run (another --out) with lower \
                 learning rates, e.g. --set lr_geo=0.01 (--resume keeps the run's own)",
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
