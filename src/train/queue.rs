//! Iterations on the queue (see [`Trainer::step`]): what recording an iteration needs,
//! recording and submitting it with its update in the frame's conditional region,
//! settling it once the host waited for it (checks read from mapped memory; an
//! incomplete frame grown for and its iteration redone, with the one queued behind it),
//! and the waited path for devices without conditional rendering, timing and counters.

use ash::vk;

use super::iteration::{IterPlan, Queued, GO_WORDS};
use super::trainer::Trainer;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::gpu::{recorder, Timestamps};
use crate::raster::{FrameCheck, FrameStats, Gate};

impl Trainer {
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
        self.settle_timing(q.timing, stats.complete())?;
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
    pub(super) fn settle(&mut self, prev: Queued) -> Result<()> {
        self.ctx.wait(prev.ticket)?;
        self.check_lost()?;
        let stats = self.renderer.checked_stats(&prev.check)?;
        self.settle_timing(prev.timing, stats.complete())?;
        if stats.complete() {
            self.last_stats = Some(stats);
            return Ok(());
        }
        let cur = self
            .queued
            .take()
            .ok_or_else(|| Error::Gpu("no iteration queued behind a skipped one".into()))?;
        self.ctx.wait(cur.ticket)?;
        // Its update was skipped too: its timestamps time nothing.
        self.return_timing(cur.timing);
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

    /// Reads a settled iteration's stage times if `done` (its frame complete: an
    /// incomplete one's update was skipped, and its redo is timed by `run_now`) and
    /// frees its timestamp pair.
    fn settle_timing(
        &mut self,
        timing: Option<(Timestamps, Timestamps)>,
        done: bool,
    ) -> Result<()> {
        let read = match (timing.as_ref(), done) {
            (Some(t), true) => t.0.stages().and_then(|mut all| {
                all.extend(t.1.stages()?);
                Ok(all)
            }),
            _ => Ok(Vec::new()),
        };
        self.return_timing(timing);
        self.push_stage_times(read?);
        Ok(())
    }

    /// Errors if a compare-and-swap float add gave up since the run began (the
    /// counters are cumulative, so reading them an iteration late misses nothing).
    pub(super) fn check_lost(&self) -> Result<()> {
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
    pub(super) fn submit_iteration(
        &mut self,
        plan: &IterPlan,
        after: Option<u64>,
    ) -> Result<Queued> {
        self.apply(plan);
        let cam = self.cams[plan.view].clone();
        self.renderer.prepare(&self.scene, &cam, &plan.opts)?;
        let go_offset = self.next_go();
        let ctx = self.ctx.clone();
        let mut timing = self.timing.take().or_else(|| self.timing_spare.take());
        let submitted =
            ctx.submit(|cmd| self.record_gated(cmd, plan, &cam, go_offset, after, &mut timing));
        let (check, ticket) = match submitted {
            Ok(s) => s,
            Err(e) => {
                self.return_timing(timing);
                return Err(e);
            }
        };
        Ok(Queued {
            plan: plan.clone(),
            ticket,
            check,
            go_offset,
            timing,
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
    pub(super) fn run_now(&mut self, plan: &IterPlan) -> Result<FrameStats> {
        self.apply(plan);
        let cam = self.cams[plan.view].clone();
        let mut timing = self.timing.take().or_else(|| self.timing_spare.take());
        let res = self.run_now_timed(plan, &cam, &mut timing);
        self.settle_timing(timing, res.is_ok())?;
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
}
