//! Setting a run up: the starting grid (uniform, then only what the training views see),
//! the voxel budget, the optimiser moments and [`Trainer::new`].

use rand::SeedableRng;

use super::backward::{Backward, Gradients, PointLists, Reduction};
use super::config::{Layout, TrainConfig};
use super::loss::PixelLoss;
use super::optim::{Adam, Moments, Tv};
use super::ssim::Ssim;
use super::trainer::Trainer;
use super::views::TrainViews;
use crate::adapt::stats::StatsPass;
use crate::adapt::topology::Topology;
use crate::adapt::{shells, visible_only};
use crate::data::Dataset;
use crate::error::{Error, Result};
use crate::gpu::{Context, DeviceInfo, MemoryBudget};
use crate::raster::Renderer;
use crate::scene::{ijk_from_octpath, Scene, SceneGpu};

/// The starting grid before visibility pruning: `8^grid_level` voxels filling the main
/// region (`center`, `extent`); with background shells (`outside_level` > 0) the root
/// cube is `2^outside_level` times larger and the grid its central part.
pub fn uniform_grid(cfg: &TrainConfig) -> Result<Scene> {
    init_scene(cfg, &shells::inside_grid(cfg.outside_level, cfg.grid_level))
}

/// The root cube's edge: the main region's times `2^outside_level`.
pub fn root_extent(cfg: &TrainConfig) -> f32 {
    cfg.extent * (1u32 << cfg.outside_level) as f32
}

/// A scene of `cells` with the configuration's initial parameters.
fn init_scene(cfg: &TrainConfig, cells: &[([u32; 3], u32)]) -> Result<Scene> {
    let mut scene = shells::scene_of(cfg.center, root_extent(cfg), cells, cfg.geo_init)?;
    scene.sh_degree = cfg.sh_degree;
    scene.shs = vec![0.0; scene.num_voxels() * scene.shs_per_voxel() * 3];
    scene.background = cfg.background;
    scene.background_frame_mean = cfg.background_frame_mean;
    scene.supersample = cfg.ss;
    scene.world = cfg.world();
    let dc = (cfg.sh0_init - 0.5) / 0.282_094_8;
    scene.sh0.iter_mut().for_each(|c| *c = [dc; 3]);
    Ok(scene)
}

/// The starting layout: the main region's grid without the voxels no training view
/// sees, plus (with `outside_level` > 0) the background shells ([`shells`]).
fn initial_layout(
    ctx: &Context,
    cfg: &TrainConfig,
    cams: &[crate::camera::Camera],
    renderer: &mut Renderer,
    stats: &mut StatsPass,
    topology: &mut Topology,
) -> Result<Scene> {
    check_grid_fits(ctx, cfg)?;
    let dense = uniform_grid(cfg)?;
    let inside = visible_only(dense, cams, renderer, stats, topology)?;
    if cfg.outside_level == 0 {
        return Ok(inside);
    }
    let started = std::time::Instant::now();
    let mut cells: Vec<([u32; 3], u32)> = inside
        .octpath
        .iter()
        .zip(&inside.octlevel)
        .map(|(&p, &l)| (ijk_from_octpath(p, l as u32), l as u32))
        .collect();
    let want = (inside.num_voxels() as f64 * cfg.init_out_ratio as f64).ceil() as usize;
    let (outside, report) = shells::shell_layout(
        cfg.center,
        root_extent(cfg),
        cfg.outside_level,
        cfg.outside_level + cfg.grid_level,
        want,
        cams,
        renderer,
        stats,
    )?;
    eprintln!(
        "background: {} shell voxels (levels ≤ {}, {} subdivision rounds, {:.1} s) around \
         {} main-region voxels",
        report.voxels,
        report.max_level,
        report.rounds,
        started.elapsed().as_secs_f64(),
        cells.len()
    );
    cells.extend(outside);
    init_scene(cfg, &cells)
}

/// Refuses, before building it, a uniform grid whose largest per-voxel buffer (the
/// higher-order SH coefficients, or the 8 corner indices at degree 0) exceeds the
/// device's allocation limit.
pub(super) fn check_grid_fits(ctx: &Context, cfg: &TrainConfig) -> Result<()> {
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
/// moments), the renderer's per-voxel frame data, the adaptive statistics, and what a
/// layout change holds at once: the candidate corners (8 per voxel, sorted with
/// scratch) and the new SH with its moments beside the old ones (the gradients are
/// freed first, so that is two SH-sized arrays more, and the new structure).
pub fn bytes_per_voxel(sh_degree: u32) -> u64 {
    let sh = 3 * crate::scene::sh_coeffs(sh_degree) as u64 * 4; // sh0 + shs, bytes
    let layout = 8 + 4 + 32; // octpath, level, corners
    let params = sh * 3 + 4; // values, gradients, priority
    let adam = sh * 2;
    let grid = 2 * (8 + 4 + 4 + 8);
    let frame = 92 + 8;
    let candidates = 8 * (8 * 2 + 4 * 2 + 12 + 4 + 8);
    let change = sh * 2 + layout;
    layout + params + adam + grid + frame + candidates + change
}

/// The voxel budget: `max_voxels` when set, else what fits in half of the device memory
/// this process may still allocate (VK_EXT_memory_budget's budget minus usage where the
/// device offers it, else half the device-local heap; the rest is left to the frame's
/// entry lists and images), capped by the largest per-voxel buffer (higher-order SH)
/// fitting one allocation and by the 29-bit voxel ids. Reads the device's budget now;
/// [`voxel_budget_with`] is the same for a given reading.
pub fn voxel_budget(ctx: &Context, cfg: &TrainConfig) -> u64 {
    voxel_budget_with(ctx.info(), ctx.memory_budget(), cfg)
}

/// [`voxel_budget`] for the device `info` and a memory budget reading (`None`: the
/// device has no VK_EXT_memory_budget).
pub fn voxel_budget_with(
    info: &DeviceInfo,
    memory: Option<MemoryBudget>,
    cfg: &TrainConfig,
) -> u64 {
    if cfg.max_voxels > 0 {
        return cfg.max_voxels;
    }
    let memory = memory.map_or(info.device_local_heap_bytes, |b| b.available_bytes());
    let per_voxel = bytes_per_voxel(cfg.sh_degree)
        + if cfg.deterministic {
            PointLists::BYTES_PER_VOXEL
        } else {
            0
        };
    let mut budget = memory / 2 / per_voxel;
    let shs = (crate::scene::sh_coeffs(cfg.sh_degree) as u64 - 1) * 12;
    let largest = shs.max(8 * 8); // higher-order SH, or 8 candidate keys per voxel
    if info.max_memory_allocation_size > 0 {
        budget = budget.min(info.max_memory_allocation_size / largest);
    }
    budget.min(crate::scene::MAX_VOXELS as u64)
}

/// Where a voxel budget comes from, in words (the train log).
pub fn voxel_budget_source(
    info: &DeviceInfo,
    memory: Option<MemoryBudget>,
    cfg: &TrainConfig,
) -> String {
    let mib = |b: u64| b as f64 / 1048576.0;
    if cfg.max_voxels > 0 {
        "max_voxels".into()
    } else {
        match memory {
            Some(b) => format!(
                "half the {:.0} MiB the device's memory budget left when the run started",
                mib(b.available_bytes())
            ),
            None => format!(
                "half the {:.0} MiB device-local heap",
                mib(info.device_local_heap_bytes)
            ),
        }
    }
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
        // The device's memory budget before this run allocates anything (the initial
        // layout's renderer and topology buffers would otherwise count against it).
        let memory = ctx.memory_budget();
        let mut renderer = Renderer::new(ctx)?;
        let mut stats = StatsPass::new(ctx)?;
        let mut topology = Topology::new(ctx)?;
        let cams = train.cameras();
        let host = match init {
            Some(s) => s,
            None => initial_layout(ctx, &cfg, &cams, &mut renderer, &mut stats, &mut topology)?,
        };
        host.validate()?;
        let budget = voxel_budget_with(ctx.info(), memory, &cfg);
        let budget_source = voxel_budget_source(ctx.info(), memory, &cfg);
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
        let float_atomics = std::env::var("SVRASTER_NO_FLOAT_ATOMICS").is_err();
        let reduction = Reduction::choose(ctx, float_atomics, cfg.deterministic);
        let grads = Gradients::with_reduction(ctx, &scene, reduction)?;
        let mom = Self::moments(ctx, &scene)?;
        let views = TrainViews::upload(ctx, train, TrainViews::default_chunk_bytes(ctx))?;
        let schedule = cfg.schedule();
        let ssim_valid = cfg.ssim_valid;
        let mut tv = Tv::with_reduction(ctx, reduction)?;
        tv.set_form(cfg.tv_form);
        let mut backward = Backward::with_reduction(ctx, reduction)?;
        backward.set_colour_clamp_grad(cfg.colour_clamp_grad);
        backward.set_alpha_clamp_grad(cfg.alpha_clamp_grad);
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
            backward,
            ssim: {
                let mut s = Ssim::new(ctx)?;
                s.set_valid(ssim_valid);
                s
            },
            adam: Adam::new(ctx)?,
            tv,
            loss: PixelLoss::new(ctx)?,
            normal: super::loss::NormalLoss::new(ctx)?,
            views,
            cams,
            order: Vec::new(),
            iter: 0,
            timing: None,
            timing_spare: None,
            last_times: Vec::new(),
            stats,
            topology,
            budget,
            budget_source,
            budget_logged: false,
            go: ctx.zeroed_buffer("train.go", 4 * super::iteration::GO_WORDS)?,
            last_stats: None,
            single: ctx.info().conditional_rendering,
            redone: 0,
            pipelined: true,
            queued: None,
            go_seq: 0,
            counting: false,
            adam_base: 0,
            next_draw: None,
        })
    }

    /// Zero Adam moments for `scene`'s parameter groups (a resumed run then restores
    /// them with [`Trainer::set_optimizer_state`]).
    pub(super) fn moments(ctx: &Context, scene: &SceneGpu) -> Result<[Moments; 3]> {
        let n = scene.voxels as u64;
        let w = 3 * scene.shs_per_voxel as usize;
        Ok([
            Moments::new(ctx, "geo", scene.grid_points as u64)?,
            Moments::new(ctx, "sh0", n * 3)?,
            Moments::new(
                ctx,
                "shs",
                crate::scene::shs_device_len(n as usize, w) as u64,
            )?,
        ])
    }
}
