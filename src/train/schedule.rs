//! A run's milestones in iterations ([`TrainConfig::schedule`]): the SH degree steps,
//! supersampling, learning-rate decay, loss switches, checkpoints and the adaptive steps,
//! from the configuration's fractions of the run.

use serde::Serialize;

use super::config::{Layout, TrainConfig};

/// Milestones of a run, in iterations (recorded in config.json).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Schedule {
    /// The density learning rate used (before the decay), see [`TrainConfig::lr_geo_used`].
    pub lr_geo: f32,
    /// The SH learning rates used (before the decay), see
    /// [`TrainConfig::lr_colour_used`].
    pub lr_sh0: f32,
    pub lr_shs: f32,
    /// Iterations at which the SH degree goes up by one.
    pub sh_degree_up: Vec<u32>,
    pub ss_from: u32,
    pub lr_decay_at: u32,
    pub dist_from: u32,
    pub normal_dmed_from: u32,
    pub normal_dmean_from: u32,
    pub tv_until: u32,
    pub checkpoints: Vec<u32>,
    /// Adaptive steps (after this many iterations), in order.
    pub adapt: Vec<AdaptStep>,
}

/// One adaptive step of the schedule.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct AdaptStep {
    /// Runs after this many completed iterations.
    pub iter: u32,
    /// Max-blend-weight threshold of the pruning (None: no pruning at this step).
    pub prune_below: Option<f32>,
    /// Whether this step subdivides.
    pub subdivide: bool,
    /// Whether it subdivides every candidate (`subdivide_all_until`).
    pub subdivide_all: bool,
}

fn at(frac: f64, iters: u32) -> u32 {
    (frac * iters as f64).round().clamp(0.0, iters as f64) as u32
}

impl TrainConfig {
    /// The run's milestones in iterations.
    pub fn schedule(&self) -> Schedule {
        // Milestones are fractions of the schedule's length; a run extended past it
        // (`schedule_iters` < `iters`) goes on in the final state.
        let n = self.schedule_iters.unwrap_or(self.iters).min(self.iters);
        let end = self.iters;
        let mut sh = Vec::new();
        // sh_every = 0: every degree from the first iteration (the reference's
        // sh_degree_init = 3).
        for d in 1..=self.sh_degree {
            sh.push(if self.svraster_schedule && self.sh_every > 0.0 {
                // train.py:177: up before the render of 1-based iteration 1000·d, i.e.
                // from our 0-based iteration 1000·d − 1, whatever the run's length.
                (1000 * d - 1).min(n)
            } else {
                at(self.sh_every * d as f64, n)
            });
        }
        let mut checkpoints = Vec::new();
        if self.checkpoint_every > 0.0 {
            let mut k = 1;
            loop {
                // At the same spacing past the schedule's length, up to the end.
                let it = (self.checkpoint_every * k as f64 * n as f64).round() as u64;
                if it >= u64::from(end) || it == 0 {
                    break;
                }
                let it = it as u32;
                if checkpoints.last() != Some(&it) {
                    checkpoints.push(it);
                }
                k += 1;
            }
        }
        let mut adapt = Vec::new();
        if self.layout != Layout::Fixed && self.adapt_every > 0.0 {
            let prune_until = at(self.prune_until, n);
            let subdivide_until = at(self.subdivide_until, n);
            let subdivide_all_until = at(self.subdivide_all_until, n);
            let warmup = ((-self.geo_init).max(0.0) / self.lr_geo_used()).ceil() as u32;
            // Step k at from + k·every (iterations), every ≥ adapt_min_spacing.
            let every = (self.adapt_every * n as f64)
                .max(f64::from(self.adapt_min_spacing))
                .max(1.0);
            let mut k = 0;
            loop {
                let it = (self.adapt_from * n as f64 + every * k as f64)
                    .round()
                    .clamp(0.0, n as f64) as u32;
                k += 1;
                if it >= n || it > prune_until.max(subdivide_until) {
                    break;
                }
                if it == 0 || it < warmup {
                    continue;
                }
                if adapt.last().map(|s: &AdaptStep| s.iter) != Some(it) {
                    adapt.push(AdaptStep {
                        iter: it,
                        prune_below: (it <= prune_until).then_some(0.0),
                        subdivide: it <= subdivide_until && n - it >= self.subdivide_min_after,
                        subdivide_all: it <= subdivide_all_until,
                    });
                }
            }
            // Threshold ramps linearly from the first pruning to the last.
            let prunes = adapt.iter().filter(|s| s.prune_below.is_some()).count();
            let mut i = 0;
            for s in adapt.iter_mut() {
                if s.prune_below.is_some() {
                    let f = if prunes > 1 {
                        i as f32 / (prunes - 1) as f32
                    } else {
                        0.0
                    };
                    s.prune_below = Some(
                        self.prune_thres_init
                            + f * (self.prune_thres_final - self.prune_thres_init),
                    );
                    i += 1;
                }
            }
        }
        let (lr_sh0, lr_shs) = self.lr_colour_used();
        Schedule {
            lr_geo: self.lr_geo_used(),
            lr_sh0,
            lr_shs,
            adapt,
            sh_degree_up: sh,
            // train.py:188: supersampling for 1-based iterations > 1000.
            ss_from: if self.svraster_schedule {
                1000.min(n)
            } else {
                at(self.ss_from, n)
            },
            lr_decay_at: at(self.lr_decay_at, n),
            // train.py:199: `iteration >= dist_from`, 1-based.
            dist_from: if self.svraster_schedule {
                at(self.dist_from, n).saturating_sub(1)
            } else {
                at(self.dist_from, n)
            },
            normal_dmed_from: at(self.normal_dmed_from, n),
            normal_dmean_from: at(self.normal_dmean_from, n),
            tv_until: at(self.tv_until, n),
            checkpoints,
        }
    }
}

impl Schedule {
    /// Active SH degree at iteration `it` (0-based).
    pub fn sh_degree(&self, it: u32) -> u32 {
        self.sh_degree_up.iter().filter(|&&m| it >= m).count() as u32
    }
}
