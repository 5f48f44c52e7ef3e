//! The training loop (paper §3.2; DESIGN §4): one random training view per iteration,
//! forward → losses → backward → Adam, and at the schedule's adaptive steps the layout
//! changes (paper §3.2.2): prune voxels whose max blend weight over every training view
//! is below a ramped threshold, subdivide the top few percent by accumulated priority.
//!
//! An iteration is two submissions: the frame (which may grow its buffers and re-render,
//! so its completeness is known before any gradient is taken) and everything after it.
//!
//! Optimiser state across a layout change is *carried*, not reset: surviving parameters
//! keep their Adam moments, children copy their parent's, new grid points interpolate and
//! average them like their densities. A reset would hand every new parameter a first
//! step of ≈ lr·(1−β₁)/√(1−β₂) = 9·lr (zero moments, bias correction of a late step).

use ash::vk;
use rand::{Rng, SeedableRng};

use std::time::Instant;

use super::adapt_stats::StatsPass;
use super::backward::{Backward, EntryLosses, Gradients};
use super::config::{AdaptStep, Layout, Schedule, TrainConfig};
use super::loss::PixelLoss;
use super::optim::{Adam, AdamConfig, Tv};
use super::ssim::Ssim;
use super::topology::Topology;
use crate::data::blender::Dataset;
use crate::data::Camera;
use crate::gpu::{recorder, Buffer, Context, Memory, Timestamps};
use crate::raster::{RenderOptions, Renderer};
use crate::scene::SceneGpu;
use crate::scene::{octpath_from_ijk, Scene};
use crate::{Error, Result};

/// Loss values of one iteration (read back only on logged iterations).
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct StepLosses {
    /// Total weighted loss.
    pub loss: f64,
    pub mse: f64,
    pub psnr: f64,
    pub ssim: f64,
    pub t_concentration: f64,
    pub distortion: f64,
    pub tv: f64,
}

/// What one iteration did.
#[derive(Clone, Debug, Default)]
pub struct StepInfo {
    /// Iteration just completed (1-based).
    pub iter: u32,
    pub view: usize,
    pub sh_degree: u32,
    pub supersample: f32,
    pub entries: u64,
    /// Loss values when this iteration was asked to measure them.
    pub losses: Option<StepLosses>,
    /// What the adaptive step after this iteration did, if one was scheduled.
    pub adapt: Option<AdaptReport>,
}

/// What one adaptive step did (a line of stats.jsonl).
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct AdaptReport {
    /// After this many completed iterations.
    pub iter: u32,
    pub voxels_before: u32,
    /// Max-blend-weight threshold (None: this step did not prune).
    pub prune_below: Option<f32>,
    pub pruned: u32,
    /// Voxels replaced by their 8 children.
    pub subdivided: u32,
    /// Subdivision candidates the budget or the layout's rules left out.
    pub subdivide_skipped: u32,
    pub voxels: u32,
    pub grid_points: u32,
    pub max_level: u32,
    /// The voxel budget in force.
    pub budget: u64,
    /// Whether the budget cut this step's subdivision short.
    pub budget_reached: bool,
    /// Device memory allocated after the step (bytes).
    pub device_memory: u64,
    pub seconds: f64,
    /// Of `seconds`: the statistics pass (every training view rendered).
    pub stats_seconds: f64,
    /// Of `seconds`: selection and topology change (host round trip, reinstall).
    pub topology_seconds: f64,
}

/// Adam moments of one parameter group.
struct Moments {
    m: Buffer,
    v: Buffer,
}

impl Moments {
    fn new(ctx: &Context, name: &str, count: u64) -> Result<Moments> {
        let bytes = count.max(1) * 4;
        let m = ctx.buffer(&format!("{name}.adam-m"), bytes, Memory::Device)?;
        let v = ctx.buffer(&format!("{name}.adam-v"), bytes, Memory::Device)?;
        ctx.submit_and_wait(|cmd| {
            recorder::fill(ctx, cmd, &m, 0, vk::WHOLE_SIZE, 0);
            recorder::fill(ctx, cmd, &v, 0, vk::WHOLE_SIZE, 0);
            Ok(())
        })?;
        Ok(Moments { m, v })
    }
}

/// A uniform grid of `8^level` voxels filling the box (before visibility pruning).
pub fn uniform_grid(cfg: &TrainConfig) -> Result<Scene> {
    let l = cfg.grid_level;
    let n = 1u32 << l;
    let mut paths = Vec::with_capacity((n as usize).pow(3));
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                paths.push(octpath_from_ijk([i, j, k], l));
            }
        }
    }
    paths.sort_unstable();
    let levels = vec![l as u8; paths.len()];
    let mut scene = Scene::from_voxels(
        cfg.center,
        cfg.extent,
        cfg.sh_degree,
        paths,
        levels,
        cfg.geo_init,
    )?;
    scene.background = cfg.background;
    scene.supersample = cfg.ss;
    let dc = (cfg.sh0_init - 0.5) / 0.282_094_8;
    scene.sh0.iter_mut().for_each(|c| *c = [dc; 3]);
    Ok(scene)
}

/// Removes the voxels no training camera sees (paper §3.2.1, bounded scenes): a voxel
/// is seen when a view's preprocess gives it at least one tile entry.
pub fn visible_only(
    ctx: &Context,
    scene: Scene,
    cams: &[Camera],
    renderer: &mut Renderer,
    stats: &mut StatsPass,
    topology: &mut Topology,
) -> Result<Scene> {
    let gpu = SceneGpu::upload(ctx, &scene)?;
    stats.begin(gpu.voxels)?;
    for cam in cams {
        stats.add_view_intervals(renderer, &gpu, cam)?;
    }
    drop(gpu);
    let keep: Vec<bool> = stats
        .read()?
        .min_interval
        .iter()
        .map(|v| v.is_finite())
        .collect();
    if !keep.contains(&true) {
        return Err(Error::Invalid(
            "no training camera sees any voxel of the scene box: check the config's \
             center/extent against the cameras"
                .into(),
        ));
    }
    if !keep.contains(&false) {
        return Ok(scene);
    }
    let split = vec![false; keep.len()];
    Ok(topology.apply(&scene, None, &keep, &split)?.0)
}

/// Refuses, before building it, a uniform grid whose largest per-voxel buffer (the
/// higher-order SH coefficients, or the 8 corner indices at degree 0) exceeds the
/// device's allocation limit.
fn check_grid_fits(ctx: &Context, cfg: &TrainConfig) -> Result<()> {
    let voxels = 1u64 << (3 * cfg.grid_level);
    let per_voxel = (crate::scene::sh_coeffs(cfg.sh_degree) as u64 - 1) * 12;
    let largest = voxels * per_voxel.max(32);
    let limit = ctx.info().max_memory_allocation_size;
    if limit > 0 && largest > limit {
        return Err(Error::Capacity(format!(
            "a level-{} uniform grid has {voxels} voxels: its largest buffer ({:.1} GiB) \
             exceeds this device's {:.1} GiB allocation limit. Use --set grid_level={} (or \
             a lower sh_degree)",
            cfg.grid_level,
            largest as f64 / (1u64 << 30) as f64,
            limit as f64 / (1u64 << 30) as f64,
            cfg.grid_level - 1
        )));
    }
    Ok(())
}

/// Device bytes one voxel costs while training at SH degree `sh_degree`: parameters,
/// gradients and Adam moments (sh0 + shs), ~2 grid points (key, density, gradient,
/// moments), the renderer's per-voxel frame data, the adaptive statistics, and the
/// transient candidate corners of a layout change (8 per voxel, sorted with scratch).
pub fn bytes_per_voxel(sh_degree: u32) -> u64 {
    let sh = 3 * crate::scene::sh_coeffs(sh_degree) as u64 * 4; // sh0 + shs, bytes
    let layout = 8 + 4 + 32; // octpath, level, corners
    let params = sh * 3 + 4; // values, gradients, priority
    let adam = sh * 2;
    let grid = 2 * (8 + 4 + 4 + 8);
    let frame = 92 + 8;
    let candidates = 8 * (8 * 2 + 4 * 2 + 12 + 4 + 8);
    layout + params + adam + grid + frame + candidates
}

/// The voxel budget: `max_voxels` when set, else what fits in half of the device's
/// memory (the rest is left to the frame's entry lists and images), capped by the
/// largest per-voxel buffer (higher-order SH) fitting one allocation and by the 29-bit
/// voxel ids.
pub fn voxel_budget(ctx: &Context, cfg: &TrainConfig) -> u64 {
    if cfg.max_voxels > 0 {
        return cfg.max_voxels;
    }
    let info = ctx.info();
    let mut budget = info.device_local_heap_bytes / 2 / bytes_per_voxel(cfg.sh_degree);
    let shs = (crate::scene::sh_coeffs(cfg.sh_degree) as u64 - 1) * 12;
    let largest = shs.max(8 * 8); // higher-order SH, or 8 candidate keys per voxel
    if info.max_memory_allocation_size > 0 {
        budget = budget.min(info.max_memory_allocation_size / largest);
    }
    budget.min(crate::scene::MAX_VOXELS as u64)
}

/// Per-stage timestamps of the last iteration (ms), when enabled.
pub type StageTimes = Vec<(String, f64)>;

/// The trainer: scene and optimiser state on the device plus the training views.
pub struct Trainer {
    ctx: Context,
    cfg: TrainConfig,
    schedule: Schedule,
    host: Scene,
    scene: SceneGpu,
    grads: Gradients,
    mom: [Moments; 3],
    renderer: Renderer,
    backward: Backward,
    ssim: Ssim,
    adam: Adam,
    tv: Tv,
    loss: PixelLoss,
    gt: Buffer,
    cams: Vec<Camera>,
    width: u32,
    height: u32,
    rng: rand_pcg::Pcg64,
    order: Vec<usize>,
    iter: u32,
    timing: Option<(Timestamps, Timestamps)>,
    last_times: StageTimes,
    stats: StatsPass,
    topology: Topology,
    budget: u64,
    /// Whether the budget stopped a subdivision already (logged once).
    budget_logged: bool,
}

impl Trainer {
    /// Sets up training on `train` from `init` (or a fresh uniform grid).
    pub fn new(
        ctx: &Context,
        cfg: TrainConfig,
        train: &Dataset,
        init: Option<Scene>,
    ) -> Result<Trainer> {
        cfg.validate()?;
        if train.frames.is_empty() {
            return Err(Error::Invalid(format!(
                "the {} split has no frames to train on",
                train.split
            )));
        }
        let mut renderer = Renderer::new(ctx)?;
        let mut stats = StatsPass::new(ctx)?;
        let mut topology = Topology::new(ctx)?;
        let cams = train.cameras();
        let host = match init {
            Some(s) => s,
            None => {
                check_grid_fits(ctx, &cfg)?;
                let dense = uniform_grid(&cfg)?;
                visible_only(ctx, dense, &cams, &mut renderer, &mut stats, &mut topology)?
            }
        };
        host.validate()?;
        let budget = voxel_budget(ctx, &cfg);
        if cfg.layout != Layout::Fixed && host.num_voxels() as u64 > budget {
            return Err(Error::Invalid(format!(
                "the voxel budget ({budget}) is below the {} voxels the run starts with \
                 (the level-{} grid's voxels the training views see): no voxel could ever be \
                 subdivided; raise --max-voxels (set max_voxels=0 for the device's budget), \
                 lower grid_level, or use layout=fixed",
                host.num_voxels(),
                cfg.grid_level
            )));
        }
        let mut scene = SceneGpu::upload(ctx, &host)?;
        scene.sh_degree = 0;
        let grads = Gradients::new(ctx, &scene)?;
        let mom = Self::moments(ctx, &scene, None)?;
        let (w, h) = (train.width, train.height);
        let np = (w * h) as usize;
        let mut planar = vec![0f32; train.frames.len() * 3 * np];
        for (i, f) in train.frames.iter().enumerate() {
            if f.rgb.len() != np {
                return Err(Error::Invalid(format!(
                    "training image {} has {} pixels, expected {w}×{h}",
                    f.name,
                    f.rgb.len()
                )));
            }
            for (p, c) in f.rgb.iter().enumerate() {
                for ch in 0..3 {
                    planar[(i * 3 + ch) * np + p] = c[ch];
                }
            }
        }
        let gt = ctx.buffer_from("train.ground-truth", &planar)?;
        let float_atomics = std::env::var("SVRASTER_NO_FLOAT_ATOMICS").is_err();
        let schedule = cfg.schedule();
        Ok(Trainer {
            ctx: ctx.clone(),
            rng: rand_pcg::Pcg64::seed_from_u64(cfg.seed),
            cfg,
            schedule,
            host,
            scene,
            grads,
            mom,
            renderer,
            backward: Backward::new(ctx, float_atomics)?,
            ssim: Ssim::new(ctx)?,
            adam: Adam::new(ctx)?,
            tv: Tv::new(ctx, float_atomics)?,
            loss: PixelLoss::new(ctx)?,
            gt,
            cams,
            width: w,
            height: h,
            order: Vec::new(),
            iter: 0,
            timing: None,
            last_times: Vec::new(),
            stats,
            topology,
            budget,
            budget_logged: false,
        })
    }

    /// Adam moments for `scene`'s parameter groups: zero, or `state` (the six arrays of
    /// [`Trainer::optimizer_state`]).
    fn moments(
        ctx: &Context,
        scene: &SceneGpu,
        state: Option<&[Vec<f32>]>,
    ) -> Result<[Moments; 3]> {
        let n = scene.voxels as u64;
        let mom = [
            Moments::new(ctx, "geo", scene.grid_points as u64)?,
            Moments::new(ctx, "sh0", n * 3)?,
            Moments::new(ctx, "shs", n * 3 * scene.shs_per_voxel as u64)?,
        ];
        if let Some(state) = state {
            for (i, m) in mom.iter().enumerate() {
                if !state[2 * i].is_empty() {
                    ctx.upload(&m.m, 0, &state[2 * i])?;
                    ctx.upload(&m.v, 0, &state[2 * i + 1])?;
                }
            }
        }
        Ok(mom)
    }

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

    /// Turns the work counters of the frame and backward walks on or off (benchmarks:
    /// the counting kernels are slower; see [`Renderer::set_counters`]).
    pub fn set_counters(&mut self, on: bool) -> Result<()> {
        self.renderer.set_counters(on)
    }

    /// Work counters of the last iteration (forward and backward), when on.
    pub fn counters(&self) -> Result<Option<crate::raster::WorkCounters>> {
        self.renderer.counters()
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

    /// Runs one iteration; with `measure`, reads back the loss values.
    pub fn step(&mut self, measure: bool) -> Result<StepInfo> {
        let it = self.iter;
        let view = self.next_view();
        let ss = self.draw_ss(it);
        let cfg = self.cfg.clone();
        let degree = self.schedule.sh_degree(it).min(cfg.sh_degree);
        self.scene.sh_degree = degree;
        let cam = self.cams[view].clone();
        let opts = RenderOptions {
            samples: cfg.samples,
            supersample: ss,
        };
        let mut timing = self.timing.take();
        let stats = self.renderer.render_to_device(
            &self.scene,
            &cam,
            &opts,
            timing.as_mut().map(|t| &mut t.0),
        );
        let stats = match stats {
            Ok(s) => s,
            Err(e) => {
                self.timing = timing;
                return Err(e);
            }
        };
        let frame = self.renderer.last_frame()?;
        self.backward.prepare(&frame, self.scene.voxels)?;
        let nout = frame.out_width * frame.out_height;
        let nrender = frame.render_width * frame.render_height;
        self.ssim.prepare(frame.out_width, frame.out_height)?;
        let gt_addr = self.gt.address() + (view as u64 * 3 * nout as u64) * 4;
        let out_addr = self.renderer.output_address()?;
        let dout_addr = self.backward.dout()?.address();

        let lr_scale = if it >= self.schedule.lr_decay_at {
            cfg.lr_decay
        } else {
            1.0
        };
        let lambda_dist = if it >= self.schedule.dist_from {
            cfg.lambda_dist
        } else {
            0.0
        };
        let lambda_tv = if it < self.schedule.tv_until {
            cfg.lambda_tv
        } else {
            0.0
        };
        let step = it + 1;
        let ctx = self.ctx.clone();
        let res = ctx.submit_and_wait(|cmd| {
            if let Some(t) = timing.as_mut() {
                t.1.begin(cmd);
            }
            self.loss.record(
                cmd,
                &frame,
                out_addr,
                gt_addr,
                dout_addr,
                cfg.lambda_mse,
                cfg.lambda_t,
            )?;
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
            self.backward.record(
                cmd,
                &frame,
                &stats,
                &self.scene,
                cfg.samples,
                &self.grads,
                &EntryLosses {
                    lambda_dist: lambda_dist / nrender as f32,
                    lambda_r: cfg.lambda_r / nrender as f32,
                },
            )?;
            if lambda_tv > 0.0 {
                self.tv.record(
                    cmd,
                    self.scene.corners.address(),
                    self.scene.geo.address(),
                    self.grads.geo.address(),
                    self.scene.voxels,
                    lambda_tv,
                )?;
                recorder::barrier(&ctx, cmd);
            }
            if let Some(t) = timing.as_mut() {
                t.1.mark(cmd, "backward");
            }
            let groups = [
                (
                    &self.scene.geo,
                    &self.grads.geo,
                    &self.mom[0],
                    self.scene.grid_points as u64,
                    self.schedule.lr_geo,
                ),
                (
                    &self.scene.sh0,
                    &self.grads.sh0,
                    &self.mom[1],
                    self.scene.voxels as u64 * 3,
                    cfg.lr_sh0,
                ),
                (
                    &self.scene.shs,
                    &self.grads.shs,
                    &self.mom[2],
                    self.scene.voxels as u64 * 3 * self.scene.shs_per_voxel as u64,
                    cfg.lr_shs,
                ),
            ];
            for (p, g, m, count, lr) in groups {
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
                        lr: lr * lr_scale,
                        beta1: cfg.beta1,
                        beta2: cfg.beta2,
                        eps: cfg.eps,
                    },
                );
            }
            recorder::barrier(&ctx, cmd);
            if let Some(t) = timing.as_mut() {
                t.1.mark(cmd, "optimizer");
            }
            Ok(())
        });
        if let Some(t) = timing.as_ref() {
            let mut all = t.0.stages()?;
            all.extend(t.1.stages()?);
            self.last_times = all;
        }
        self.timing = timing;
        res?;
        if self.backward.read_lost()? != 0 || self.tv.read_lost()? != 0 {
            return Err(Error::Gpu(
                "compare-and-swap float adds gave up under contention: gradients are incomplete"
                    .into(),
            ));
        }
        self.iter += 1;
        let losses = if measure {
            Some(self.read_losses(lambda_dist, lambda_tv)?)
        } else {
            None
        };
        let adapt = match self.schedule.adapt.iter().find(|s| s.iter == self.iter) {
            Some(&step) => Some(self.adapt(step)?),
            None => None,
        };
        Ok(StepInfo {
            iter: self.iter,
            view,
            sh_degree: degree,
            supersample: ss,
            entries: stats.entries,
            losses,
            adapt,
        })
    }

    /// The voxel budget in force (see [`voxel_budget`]).
    pub fn budget(&self) -> u64 {
        self.budget
    }

    pub fn grid_points(&self) -> u32 {
        self.scene.grid_points
    }

    /// Device memory the engine holds now (bytes).
    pub fn device_memory(&self) -> u64 {
        self.ctx.memory_allocated()
    }

    /// One adaptive step (paper §3.2.2): statistics over every training view, pruning,
    /// subdivision within the budget, and the rebuilt device state.
    pub fn adapt(&mut self, step: AdaptStep) -> Result<AdaptReport> {
        let t0 = Instant::now();
        let cfg = self.cfg.clone();
        let n = self.scene.voxels as usize;
        self.stats.begin(n as u32)?;
        for cam in &self.cams {
            self.stats
                .add_view(&mut self.renderer, &self.scene, cam, cfg.samples)?;
        }
        let vs = self.stats.read()?;
        let stats_seconds = t0.elapsed().as_secs_f64();
        self.scene.download_params(&self.ctx, &mut self.host)?;
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
                    let mut cand: Vec<usize> = (0..n)
                        .filter(|&i| {
                            keep[i]
                                && below_max(i)
                                && rate[i] >= cfg.subdivide_min_rate
                                && priority[i] > 0.0
                        })
                        .collect();
                    let wanted =
                        ((kept as f64 * cfg.subdivide_percent).ceil() as usize).min(cand.len());
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
            let state = self.optimizer_state()?;
            let (scene, state) = self
                .topology
                .apply(&self.host, Some(&state), &keep, &split)?;
            self.install(scene, state.as_deref())?;
        } else {
            let ctx = self.ctx.clone();
            ctx.submit_and_wait(|cmd| {
                self.grads.record_clear_priority(&ctx, cmd);
                Ok(())
            })?;
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

    /// Replaces the model (new layout) and everything sized by it.
    fn install(&mut self, scene: Scene, state: Option<&[Vec<f32>]>) -> Result<()> {
        let degree = self.scene.sh_degree;
        // Release the old moments first (the largest per-voxel state after the SH).
        self.mom = [
            Moments::new(&self.ctx, "geo", 0)?,
            Moments::new(&self.ctx, "sh0", 0)?,
            Moments::new(&self.ctx, "shs", 0)?,
        ];
        let mut gpu = SceneGpu::upload(&self.ctx, &scene)?;
        gpu.sh_degree = degree;
        self.scene = gpu;
        self.grads = Gradients::new(&self.ctx, &self.scene)?;
        self.mom = Self::moments(&self.ctx, &self.scene, state)?;
        self.host = scene;
        Ok(())
    }

    fn read_losses(&self, lambda_dist: f32, lambda_tv: f32) -> Result<StepLosses> {
        let cfg = &self.cfg;
        let sums = self.loss.read()?;
        let mse = sums.squared_error / (3.0 * sums.out_pixels as f64);
        let tconc = sums.t_concentration / sums.out_pixels as f64;
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
        let ssim_term = if ssim.is_finite() { 1.0 - ssim } else { 0.0 };
        // The per-point RGB term is folded into the backward and not measured.
        let loss = cfg.lambda_mse as f64 * mse
            + cfg.lambda_ssim as f64 * ssim_term
            + cfg.lambda_t as f64 * tconc
            + lambda_dist as f64 * dist
            + lambda_tv as f64 * tv;
        Ok(StepLosses {
            loss,
            mse,
            psnr: -10.0 * mse.max(1e-20).log10(),
            ssim,
            t_concentration: tconc,
            distortion: dist,
            tv,
        })
    }

    /// Whether a non-finite gradient or parameter appeared since the last check.
    pub fn check_finite(&self) -> Result<()> {
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
        self.scene.download_params(&self.ctx, &mut self.host)?;
        Ok(self.host.clone())
    }

    /// Adam moments and iteration, for resuming: (geo m, geo v, sh0 m, sh0 v, shs m, shs v).
    pub fn optimizer_state(&self) -> Result<Vec<Vec<f32>>> {
        let counts = self.group_counts();
        let mut out = Vec::new();
        for (m, &c) in self.mom.iter().zip(&counts) {
            for b in [&m.m, &m.v] {
                out.push(if c == 0 {
                    Vec::new()
                } else {
                    self.ctx.download(b, 0, c)?
                });
            }
        }
        Ok(out)
    }

    /// Restores Adam moments saved by [`Trainer::optimizer_state`].
    pub fn set_optimizer_state(&mut self, state: &[Vec<f32>]) -> Result<()> {
        let counts = self.group_counts();
        if state.len() != 6 || (0..6).any(|i| state[i].len() != counts[i / 2]) {
            return Err(Error::Invalid(
                "optimizer state does not match the model's parameter counts".into(),
            ));
        }
        for (i, m) in self.mom.iter().enumerate() {
            if counts[i] > 0 {
                self.ctx.upload(&m.m, 0, &state[2 * i])?;
                self.ctx.upload(&m.v, 0, &state[2 * i + 1])?;
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

    /// Training image size.
    pub fn image_size(&self) -> (u32, u32) {
        (self.width, self.height)
    }
}
