//! An adaptive step of a run (paper §3.2.2): the statistics pass over every training
//! view, the selection (prune below a ramped max-weight threshold, subdivide the top
//! few percent by priority within the budget), the topology change on the device, and
//! the optimiser state carried over to the new layout.

use std::time::Instant;

use super::backward::Gradients;
use super::config::{AdaptStep, Layout};
use super::optim::Moments;
use super::trainer::Trainer;
use crate::adapt::stats::StatsRule;
use crate::adapt::topology::Changed;
use crate::adapt::AdaptReport;
use crate::error::{Error, Result};
use crate::gpu::recorder;

impl Trainer {
    /// One adaptive step (paper §3.2.2): statistics over every training view, pruning,
    /// subdivision within the budget, and the rebuilt device state.
    pub fn adapt(&mut self, step: AdaptStep) -> Result<AdaptReport> {
        let t0 = Instant::now();
        let cfg = self.cfg.clone();
        let n = self.scene.voxels as usize;
        self.stats.begin(n as u32)?;
        self.stats.set_rule(StatsRule {
            supersample: cfg.stats_ss,
            visible: cfg.stats_visible,
        })?;
        // Every view queued behind the next (one submission each, no drain but the last).
        self.stats
            .add_views(&mut self.renderer, &self.scene, &self.cams, cfg.samples)?;
        let vs = self.stats.read()?;
        let stats_seconds = t0.elapsed().as_secs_f64();
        let priority: Vec<f32> = self.ctx.download(&self.grads.priority, 0, n)?;
        let keep: Vec<bool> = match step.prune_below {
            Some(t) => vs.max_weight.iter().map(|&w| w >= t).collect(),
            None => vec![true; n],
        };
        let kept = keep.iter().filter(|&&k| k).count();
        let mut split = vec![false; n];
        let mut skipped = 0usize;
        let mut budget_reached = false;
        if step.subdivide && kept > 0 {
            let rate = vs.sampling_rate(&self.host);
            let below_max = |i: usize| (self.host.octlevel[i] as u32) < cfg.max_level;
            let room = (self.budget.saturating_sub(kept as u64) / 7) as usize;
            match cfg.layout {
                Layout::Adaptive => {
                    // Priority 0 where the sampling-rate guard fails (Eq. 7: too few
                    // rays see the voxel for its children to be constrained).
                    // A subdivide-all step (`subdivide_all_until`) takes every candidate,
                    // also those that received no gradient yet, highest priority first
                    // when the budget binds.
                    let mut cand: Vec<usize> = (0..n)
                        .filter(|&i| {
                            keep[i]
                                && below_max(i)
                                && rate[i] >= cfg.subdivide_min_rate
                                && (priority[i] > 0.0 || step.subdivide_all)
                        })
                        .collect();
                    let wanted = if step.subdivide_all {
                        cand.len()
                    } else {
                        ((kept as f64 * cfg.subdivide_percent).ceil() as usize).min(cand.len())
                    };
                    let take = wanted.min(room);
                    if take < wanted {
                        budget_reached = true;
                        skipped = wanted - take;
                    }
                    if take > 0 && take < cand.len() {
                        cand.select_nth_unstable_by(take - 1, |&a, &b| {
                            priority[b].total_cmp(&priority[a])
                        });
                    }
                    for &i in cand.iter().take(take) {
                        split[i] = true;
                    }
                }
                Layout::Uniform => {
                    // Every voxel below max_level, or none: a partly subdivided layout
                    // would no longer be the uniform baseline.
                    let cand: Vec<usize> = (0..n).filter(|&i| keep[i] && below_max(i)).collect();
                    if cand.len() <= room {
                        for &i in &cand {
                            split[i] = true;
                        }
                    } else {
                        budget_reached = true;
                        skipped = cand.len();
                    }
                }
                Layout::Fixed => {}
            }
        }
        if budget_reached && !self.budget_logged {
            eprintln!(
                "\nvoxel budget of {} reached at iteration {}: subdivision stops growing the \
                 model (raise it with --max-voxels)",
                self.budget, self.iter
            );
            self.budget_logged = true;
        }
        let subdivided = split.iter().filter(|&&s| s).count();
        if kept == 0 {
            return Err(Error::Invalid(format!(
                "pruning at iteration {} would remove every voxel (no voxel reached a blend \
                 weight of {:?} in any training view): the model is empty. Check the scene \
                 box (center/extent) against the cameras, or lower prune_thres_init",
                self.iter, step.prune_below
            )));
        }
        if kept < n || subdivided > 0 {
            self.change_layout(&keep, &split)?;
        } else {
            let ctx = self.ctx.clone();
            ctx.submit_and_wait(|cmd| {
                self.grads.record_clear_priority(&ctx, cmd);
                Ok(())
            })?;
        }
        if cfg.reset_adam_at_adapt && (step.prune_below.is_some() || step.subdivide) {
            // SVRaster's new optimiser at this step: zero moments, count from here.
            let ctx = self.ctx.clone();
            ctx.submit_and_wait(|cmd| {
                for m in &self.mom {
                    recorder::zero(&ctx, cmd, &m.m);
                    recorder::zero(&ctx, cmd, &m.v);
                }
                recorder::barrier(&ctx, cmd);
                Ok(())
            })?;
            self.adam_base = self.adam_base_at(self.iter);
        }
        Ok(AdaptReport {
            iter: self.iter,
            voxels_before: n as u32,
            prune_below: step.prune_below,
            pruned: (n - kept) as u32,
            subdivided: subdivided as u32,
            subdivide_skipped: skipped as u32,
            voxels: self.scene.voxels,
            grid_points: self.scene.grid_points,
            max_level: self.scene.max_level,
            budget: self.budget,
            budget_reached,
            device_memory: self.ctx.memory_allocated(),
            seconds: t0.elapsed().as_secs_f64(),
            stats_seconds,
            topology_seconds: t0.elapsed().as_secs_f64() - stats_seconds,
        })
    }

    /// Prunes the voxels with `keep[i] == false` and subdivides those with `split[i]`
    /// ([`Topology::apply_device`](crate::adapt::topology::Topology::apply_device)):
    /// parameters and Adam moments move to the new layout on the device; the
    /// accumulated priorities restart at zero. [`Trainer::adapt`] chooses the masks.
    pub fn change_layout(&mut self, keep: &[bool], split: &[bool]) -> Result<()> {
        // Rebuilt for the new layout anyway: freed first, they do not add to the peak
        // while the old and new parameters and moments coexist.
        self.grads = Gradients::empty(&self.ctx)?;
        let m = &self.mom;
        let moments = [&m[0].m, &m[0].v, &m[1].m, &m[1].v, &m[2].m, &m[2].v];
        let changed =
            self.topology
                .apply_device(&self.host, &self.scene, Some(moments), keep, split)?;
        self.install(changed)
    }

    /// Replaces the model (new layout, built on the device) and everything sized by it.
    fn install(&mut self, changed: Changed) -> Result<()> {
        let degree = self.scene.sh_degree;
        let Some([gm, gv, sm, sv, hm, hv]) = changed.moments else {
            return Err(Error::Gpu("topology change returned no moments".into()));
        };
        self.mom = [
            Moments { m: gm, v: gv },
            Moments { m: sm, v: sv },
            Moments { m: hm, v: hv },
        ];
        self.scene = changed.scene;
        self.scene.sh_degree = degree;
        self.grads = Gradients::with_reduction(&self.ctx, &self.scene, self.backward.reduction())?;
        // Structure only: the parameters live on the device (download_params).
        self.host = changed.host;
        Ok(())
    }
}
