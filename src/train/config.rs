//! Training configuration: every hyperparameter, with the paper's / reference config's
//! NeRF-synthetic defaults (docs/ARCHITECTURE.md §4), presets, `key=value` overrides and the schedule
//! resolved from fractions of the run.

use serde::{Deserialize, Serialize};

pub use super::schedule::{AdaptStep, Schedule};

pub use super::config_modes::{ClampGrad, Layout, TvForm};
pub use super::presets::PRESETS;
pub use crate::adapt::stats::StatsVisible;
use crate::error::{Error, Result};

/// Bound modes accepted by the `bound` config key (`box`: use `center`/`extent` as set).
pub const BOUND_MODES: [&str; 7] = [
    "box",
    "auto",
    "camera_median",
    "camera_max",
    "forward",
    "points",
    "sphere",
];

/// The defaults' run length: milestones are given for it and scale with `iters`.
pub const REFERENCE_ITERS: u32 = 20_000;

/// All training hyperparameters. Milestones are fractions of `iters` (the reference
/// values are for 20 000 iterations: e.g. SH degree +1 every 1000 = 0.05).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    /// Iterations (one random training view each).
    pub iters: u32,
    /// The run length the schedule's fractions refer to (None: `iters`). A run extended
    /// past its end (`train --resume --iters N`) keeps its milestones where they were
    /// and trains the extra iterations in the schedule's final state: full SH degree,
    /// decayed learning rates, no further pruning or subdivision, TV off, checkpoints
    /// at the same spacing.
    pub schedule_iters: Option<u32>,
    /// Random seed (view order, supersampling draws).
    pub seed: u64,
    /// Level of the initial dense grid (paper h_lv: 2^level voxels per edge); voxels no
    /// training camera sees are removed before training.
    pub grid_level: u32,
    /// Main region: centre and edge length (NeRF-synthetic: [-1.5, 1.5]³). With a `bound`
    /// other than "box" they are derived from the training cameras when the run starts
    /// (and saved resolved in config.json).
    pub center: [f32; 3],
    pub extent: f32,
    /// How the main region is chosen: "box" (`center`/`extent` as set), or from the
    /// training cameras: "auto", "camera_median", "camera_max", "forward"
    /// ([`super::bounds`]).
    pub bound: String,
    /// Background shells around the main region (paper h_out; 0: a bounded object). The
    /// root cube is the main region's times 2^outside_level.
    pub outside_level: u32,
    /// Background voxels at the start, as a multiple of the main region's (paper
    /// h_ratio).
    pub init_out_ratio: f32,
    /// The capture's world frame (model = (world − world_center) / world_scale): set when
    /// the main region comes from the cameras, which then train in a frame where it is
    /// [-1, 1]³ (`center` 0, `extent` 2); identity for a "box" bound.
    pub world_center: [f64; 3],
    pub world_scale: f64,
    /// Background composited behind the voxels (the dataset's; with
    /// `background_from_photos`, resolved when the run starts and saved here).
    pub background: [f32; 3],
    /// The background is the mean colour of the training photos (paper §3.2.1's
    /// "average frame color" coming from infinity; the real and forward presets): a
    /// ray that leaves the model unabsorbed sees the scene's average colour, not black.
    /// Setting `background` turns it off; photos with alpha (Blender) refuse it.
    pub background_from_photos: bool,
    /// Behind each frame, its own mean colour instead of `background`
    /// ([`crate::scene::Scene::background_frame_mean`]): SVRaster's background for
    /// captures that are neither white nor black (its mip-NeRF 360 configuration;
    /// docs/PARITY.md, presets). Setting `background` turns it off.
    pub background_frame_mean: bool,
    /// Final SH degree, raised by one every `sh_every` of the run from 0 (0: the final
    /// degree from the first iteration, as the reference's `sh_degree_init = 3`).
    pub sh_degree: u32,
    pub sh_every: f64,
    /// Initial raw density and colour (colour 0.5 = zero DC coefficient).
    pub geo_init: f32,
    pub sh0_init: f32,
    /// Samples per voxel segment (1 for view synthesis).
    pub samples: u32,
    /// Supersampling: 1 before `ss_from`, then uniform in [1, ss].
    pub ss: f32,
    pub ss_from: f64,
    /// Learning rates per parameter group, multiplied by `lr_decay` at `lr_decay_at`.
    /// The density rate used is `lr_geo · clamp(sqrt(20 000 / iters), 1,
    /// lr_geo_scale_max)` (see [`TrainConfig::lr_geo_used`]); by default 0.1 at every
    /// run length (the paper: 0.025 for 20 000 iterations of 800² views).
    pub lr_geo: f32,
    pub lr_sh0: f32,
    pub lr_shs: f32,
    pub lr_decay: f32,
    pub lr_decay_at: f64,
    /// Largest factor by which a run shorter than 20 000 iterations raises `lr_geo`
    /// (1, the default: never; the paper's rate with the square-root rule is
    /// `lr_geo=0.025 lr_geo_scale_max=4`).
    pub lr_geo_scale_max: f32,
    /// Largest factor by which a run shorter than 20 000 iterations raises `lr_sh0` and
    /// `lr_shs`: the rates used are `lr · clamp(20 000 / iters, 1, lr_colour_scale_max)`,
    /// SVRaster's `sche_mult` rule (train.py divides every rate by it) with its
    /// multiplier capped. 1 (the default): never; the synthetic preset: 1/0.3, so that
    /// from 6 000 iterations on the rates are SVRaster's and shorter runs keep its
    /// 6 000-iteration rates (see [`TrainConfig::lr_colour_used`]).
    #[serde(default = "one_f32")]
    pub lr_colour_scale_max: f32,
    /// Adam.
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    /// Selective Adam: a parameter whose gradient is exactly zero this step (a voxel no
    /// pixel of the view reached) keeps its value and moments; off (the default) is the
    /// paper's dense Adam, where such parameters still move by their decaying momentum.
    #[serde(default)]
    pub sparse_adam: bool,
    /// Deterministic training (`--deterministic`): gradients summed in a fixed order
    /// instead of with float atomics ([`super::backward::Reduction::Ordered`]), so two
    /// runs with the same seed and data on the same device write identical checkpoints.
    #[serde(default)]
    pub deterministic: bool,
    /// Loss weights and their windows.
    pub lambda_mse: f32,
    pub lambda_ssim: f32,
    /// SSIM averaged over the window centres whose whole 11×11 window lies in the image
    /// ("valid", SVRaster's `fused_ssim(..., padding="valid")`, loss_utils.py:58-61), and
    /// its gradient, instead of over every pixel with zero padding (off by default; on in
    /// the synthetic presets, measured there; docs/PARITY.md, SSIM). The logged `ssim` is
    /// the one trained.
    #[serde(default)]
    pub ssim_valid: bool,
    pub lambda_t: f32,
    /// The inside term mean(T²) on the transmittance left after the model (the
    /// reference's `lambda_T_inside`): with background shells every ray should end in
    /// the model; 0.01 in the real preset (the reference's Mip-NeRF 360 configuration).
    pub lambda_t_inside: f32,
    /// Distortion loss (Mip-NeRF 360's, paper Eq. 10) from `dist_from` of the run on.
    /// Off by default: on lego 100² (val, model's ss 1.5, density rate 0.1) the paper's
    /// 0.1 from half the run cost 0.42 dB at 3 000 iterations (31.54 vs 31.96 dB) and
    /// 0.67 dB at 6 000 (29.89 vs 30.56, the old rate rule) — a synthetic object has
    /// no floaters for it to remove. `lambda_dist=0.1` is the paper's.
    pub lambda_dist: f32,
    pub dist_from: f64,
    /// The distortion loss on SVRaster's contracted axis (`depth_contracted`: distance
    /// x along the ray, x < 1 ? x : 2 − 1/x) instead of the distance itself, as SVRaster
    /// (docs/PARITY.md item 8): beyond distance 1 its slope is 1/x², so the same λ is
    /// far weaker on distant content.
    pub dist_contracted: bool,
    /// Depth–normal consistency with the median depth (paper §3.2.3, the reference's
    /// `lambda_normal_dmed`): mean(1 − N·n_med), n_med the normal of the median-depth
    /// map (glsl/train/normal_loss.comp), from `normal_dmed_from` of the run on (the
    /// reference: 3 000 of 20 000). 0.001 in the `mesh` preset.
    pub lambda_normal_dmed: f32,
    pub normal_dmed_from: f64,
    /// The same with the mean depth, differentiated through the depth too
    /// (`lambda_normal_dmean`): mean(α² − α N·n_mean), from `normal_dmean_from` (the
    /// reference: 10 000 of 20 000). 0.001 in the `mesh` preset.
    pub lambda_normal_dmean: f32,
    pub normal_dmean_from: f64,
    /// Per-point RGB loss (paper Eq. 12, R_concen): λ·mean over render pixels of
    /// Σ_k w_k |c_k − gt|²/3, differentiated through colours and opacities (so it also
    /// enters the subdivision priority).
    pub lambda_r: f32,
    /// The same loss in SVRaster's form (`cuda/src/backward.cu`, `lambda_R_concen`):
    /// Σ_k w_k |c_k − gt|² (summed over channels) with the weights held constant, so its
    /// only gradient is 2λ·w_k·(c_k − gt) on the colours. `lambda_r=0
    /// lambda_r_colour=0.01` is SVRaster's setting (docs/PARITY.md item 5).
    pub lambda_r_colour: f32,
    /// How the colour loss gradient passes the clamp c = max(0, 0.5 + SH): "masked"
    /// (the clamp's derivative: zero where the colour is clamped) or "straight"
    /// (straight through, as SVRaster: its `sh_compute.cu` backward has the mask
    /// commented out, so a clamped colour's SH keep receiving the gradient and can come
    /// back; docs/PARITY.md, the colour clamp's gradient).
    pub colour_clamp_grad: ClampGrad,
    /// How the density gradient passes the opacity clamp α = min(0.99999, 1 − exp(−vol)):
    /// "masked" (its derivative: a sample whose α is clamped passes none) or "straight"
    /// (exp(−vol) as if unclamped, SVRaster's `backward.cu`: tiny, but Adam scales a
    /// grid point's step by its gradient's own size; docs/PARITY.md item 10).
    pub alpha_clamp_grad: ClampGrad,
    /// The rgb losses (MSE, SSIM) on the output clamped to [0, 1], as SVRaster trains
    /// (`renderer.py:176` clamps before its loss) and as eval measures: a pixel
    /// brighter than 1 (or below 0) costs nothing more and passes no rgb gradient.
    /// Off: the losses see the raw output (docs/PARITY.md item 10).
    pub clamp_rgb_loss: bool,
    /// The transmittance losses (`lambda_t` concentration, `lambda_t_inside`) on the
    /// render-resolution transmittance, mean over render pixels, as SVRaster
    /// (`prob_concen_loss(raw_T)`, train.py:259-262), instead of on the output alpha
    /// after the downsample (off; docs/PARITY.md item 10). The logged values stay the
    /// output-resolution ones.
    pub t_losses_at_render: bool,
    /// The per-point RGB loss's target at render resolution: the photo bilinearly
    /// resized, as SVRaster (`resize_rendering`, renderer.py:117-118), instead of the
    /// photo pixel containing the render pixel's centre (off; docs/PARITY.md item 10).
    pub r_target_bilinear: bool,
    pub lambda_tv: f32,
    pub tv_until: f64,
    /// The TV penalty's form: "l2" (ours: Σ Δ² over the cube edges, zero gradient on
    /// flat regions) or "l1" (SVRaster's `total_variation_bw`: Σ |Δ|, gradient ±1 per
    /// edge with equal ends counting −1, so flat regions are pushed up; docs/PARITY.md
    /// item 6).
    pub tv_form: TvForm,
    /// How the voxel layout changes during training: "adaptive" (the paper: prune and
    /// subdivide the top `subdivide_percent` by priority), "uniform" (prune the same way,
    /// subdivide every voxel until `max_level`: the paper's Tab. 6 baseline) or "fixed"
    /// (never change the layout after initialisation).
    pub layout: Layout,
    /// Adaptive steps: every `adapt_every` of the run, the first at `adapt_from` (the
    /// paper: 1000 of 20 000 iterations), but none before iteration |geo_init|/lr_geo:
    /// Adam moves a density by about `lr_geo` per step, and pruning before the densities
    /// could have risen from `geo_init` to the surfaces would remove the surfaces too
    /// (100 iterations at the default rate 0.1; 400 at the paper's 0.025).
    pub adapt_every: f64,
    pub adapt_from: f64,
    /// Adaptive steps are at least this many iterations apart, however short the run:
    /// each step renders every training view for its statistics, and a step every few
    /// iterations measures a model that has barely changed. Measured on lego 100², 300
    /// iterations: 12 steps 27.24 dB val, 2 steps (100 apart) 27.22 dB with 57 % of the
    /// step time (docs/PERFORMANCE.md).
    pub adapt_min_spacing: u32,
    /// Pruning at adaptive steps up to `prune_until`, threshold on the voxel's max blend
    /// weight ramped linearly from `prune_thres_init` (first) to `prune_thres_final` (last).
    pub prune_until: f64,
    pub prune_thres_init: f32,
    pub prune_thres_final: f32,
    /// Subdivision at adaptive steps up to `subdivide_until`: the top `subdivide_percent`
    /// (fraction) of the voxels by accumulated priority, among voxels whose max sampling
    /// rate (Eq. 7: size / min pixel footprint) is at least `subdivide_min_rate` (the
    /// paper's 2·h_rate, h_rate = 1) and whose level is below `max_level`.
    pub subdivide_until: f64,
    /// A step subdivides only if at least this many iterations follow it: children start
    /// as copies of their parent and pay off only once trained (the paper leaves 5 000
    /// after its last subdivision). Measured on lego 100², 300 iterations: subdividing
    /// at iterations 105–225 gave 26.79 dB val, not subdividing 27.24 dB (docs/PERFORMANCE.md).
    pub subdivide_min_after: u32,
    pub subdivide_percent: f64,
    pub subdivide_min_rate: f32,
    /// Adaptive steps up to this fraction of the run that subdivide split *every*
    /// candidate (kept, below `max_level`, sampling-rate guard passed), not only the top
    /// `subdivide_percent`, within the budget: SVRaster's `subdivide_all_until` (its
    /// synthetic config: 1 000 of 20 000 iterations, i.e. its first adaptive step). 0:
    /// off, the default until measured at the paper's resolution (docs/PARITY.md).
    pub subdivide_all_until: f64,
    /// Zero the Adam moments and restart its bias-correction count at every adaptive
    /// step that prunes or subdivides, as SVRaster does (it builds a new optimiser
    /// there; docs/PARITY.md item 4). Off by default: moments are carried to the new
    /// layout (a research switch, unmeasured at the paper's resolution).
    pub reset_adam_at_adapt: bool,
    /// SVRaster's way of scaling a schedule to the run's length (train.py:584-609 with
    /// `--sche_mult iters/20 000`), for the `svraster` preset: all three learning rates
    /// times 20 000/iters (no caps, either way), and what train.py leaves unscaled at
    /// its iterations — the SH degree up at iterations 1000, 2000, 3000 (`iteration %
    /// 1000`, train.py:177), supersampling from iteration 1001 (:188) — with the
    /// distortion loss from its own `dist_from` iteration on (`>=`, 1-based). Off: every
    /// milestone a fraction of the run, the rates as `lr_geo_used`/`lr_colour_used` say.
    #[serde(default)]
    pub svraster_schedule: bool,
    /// Supersampling of the adaptive step's statistics frames: the max weights of
    /// pruning are those of its rays, the sampling intervals stay those of the views'
    /// own resolution. 1: ours; SVRaster renders them at the model's `ss` (1.5;
    /// docs/PARITY.md item 9).
    pub stats_ss: f32,
    /// Which voxels a view shows, for the sampling-rate guard: "entries" (ours: every
    /// voxel the frame lists, also those hidden behind others) or "weight" (SVRaster:
    /// those it gives a non-zero blending weight; docs/PARITY.md item 9).
    pub stats_visible: StatsVisible,
    pub max_level: u32,
    /// Voxel budget: subdivision stops here (0: derived from the device's memory).
    pub max_voxels: u64,
    /// Log a stats line every this many iterations.
    pub log_every: u32,
    /// Write a checkpoint every this fraction of the run (0: only at the end).
    pub checkpoint_every: f64,
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig {
            iters: REFERENCE_ITERS,
            schedule_iters: None,
            seed: 0,
            grid_level: 6,
            center: [0.0; 3],
            extent: 3.0,
            bound: "box".into(),
            outside_level: 0,
            init_out_ratio: 2.0,
            world_center: [0.0; 3],
            world_scale: 1.0,
            background: [1.0; 3],
            background_from_photos: false,
            background_frame_mean: false,
            sh_degree: 3,
            sh_every: 0.05,
            geo_init: -10.0,
            sh0_init: 0.5,
            samples: 1,
            ss: 1.5,
            ss_from: 0.05,
            lr_geo: 0.1,
            lr_sh0: 0.01,
            lr_shs: 0.00025,
            lr_decay: 0.1,
            lr_decay_at: 0.95,
            lr_geo_scale_max: 1.0,
            lr_colour_scale_max: 1.0,
            beta1: 0.1,
            beta2: 0.99,
            eps: 1e-15,
            sparse_adam: false,
            deterministic: false,
            lambda_mse: 1.0,
            lambda_ssim: 0.02,
            ssim_valid: false,
            lambda_t: 0.1,
            lambda_t_inside: 0.0,
            lambda_dist: 0.0,
            dist_from: 0.5,
            dist_contracted: false,
            lambda_normal_dmed: 0.0,
            normal_dmed_from: 0.15,
            lambda_normal_dmean: 0.0,
            normal_dmean_from: 0.5,
            lambda_r: 0.01,
            lambda_r_colour: 0.0,
            colour_clamp_grad: ClampGrad::Masked,
            alpha_clamp_grad: ClampGrad::Masked,
            clamp_rgb_loss: false,
            t_losses_at_render: false,
            r_target_bilinear: false,
            lambda_tv: 1e-10,
            tv_until: 0.5,
            tv_form: TvForm::L2,
            layout: Layout::Adaptive,
            adapt_every: 0.05,
            adapt_from: 0.05,
            adapt_min_spacing: 100,
            prune_until: 0.9,
            prune_thres_init: 1e-4,
            prune_thres_final: 0.05,
            subdivide_until: 0.75,
            subdivide_min_after: 500,
            subdivide_percent: 0.05,
            subdivide_min_rate: 2.0,
            subdivide_all_until: 0.0,
            reset_adam_at_adapt: false,
            svraster_schedule: false,
            stats_ss: 1.0,
            stats_visible: StatsVisible::Entries,
            max_level: crate::scene::MAX_LEVEL,
            max_voxels: 0,
            log_every: 100,
            checkpoint_every: 0.25,
        }
    }
}

fn one_f32() -> f32 {
    1.0
}

impl TrainConfig {
    /// The capture's world frame ([`crate::scene::WorldFrame`]).
    pub fn world(&self) -> crate::scene::WorldFrame {
        crate::scene::WorldFrame {
            center: self.world_center,
            scale: self.world_scale,
        }
    }

    /// Applies `key=value` (value parsed as JSON, or as a string if that fails).
    pub fn set(&mut self, kv: &str) -> Result<()> {
        let (k, v) = kv
            .split_once('=')
            .ok_or_else(|| Error::Invalid(format!("--set expects key=value, got {kv:?}")))?;
        let mut obj = serde_json::to_value(&*self).expect("config serialises");
        let map = obj.as_object_mut().expect("config is an object");
        if !map.contains_key(k) {
            let mut keys: Vec<&String> = map.keys().collect();
            keys.sort();
            let keys: Vec<&str> = keys.iter().map(|s| s.as_str()).collect();
            return Err(Error::Invalid(format!(
                "unknown config key {k:?}; keys: {}",
                keys.join(", ")
            )));
        }
        let val: serde_json::Value =
            serde_json::from_str(v).unwrap_or(serde_json::Value::String(v.to_string()));
        map.insert(k.to_string(), val);
        *self =
            serde_json::from_value(obj).map_err(|e| Error::Invalid(format!("--set {kv}: {e}")))?;
        // A colour given is the colour used (not replaced by the photos' mean).
        if k == "background" {
            self.background_from_photos = false;
            self.background_frame_mean = false;
        }
        Ok(())
    }

    /// Checks ranges; errors say which key is wrong.
    pub fn validate(&self) -> Result<()> {
        let bad = |k: &str, why: &str| Err(Error::Invalid(format!("config {k}: {why}")));
        if self.iters == 0 {
            return bad("iters", "must be ≥ 1");
        }
        if self
            .schedule_iters
            .is_some_and(|s| s == 0 || s > self.iters)
        {
            return bad("schedule_iters", "must be in 1..=iters");
        }
        if !(1..=10).contains(&self.grid_level) {
            return bad(
                "grid_level",
                "must be in 1..=10 (a uniform grid of 8^level voxels)",
            );
        }
        if self.sh_degree > crate::scene::MAX_SH_DEGREE {
            return bad("sh_degree", "must be in 0..=3");
        }
        if !(1..=3).contains(&self.samples) {
            return bad("samples", "must be 1, 2 or 3");
        }
        if !(self.ss.is_finite() && (1.0..=4.0).contains(&self.ss)) {
            return bad("ss", "must be in [1, 4]");
        }
        if !BOUND_MODES.contains(&self.bound.as_str()) {
            return bad(
                "bound",
                &format!("must be one of {}", BOUND_MODES.join(", ")),
            );
        }
        if self.outside_level > 8 || self.outside_level + self.grid_level > crate::scene::MAX_LEVEL
        {
            return bad(
                "outside_level",
                "must be in 0..=8, and outside_level + grid_level at most 16",
            );
        }
        if self.world().validate().is_err() {
            return bad(
                "world_center/world_scale",
                "must be finite, world_scale > 0",
            );
        }
        if !(self.init_out_ratio.is_finite() && self.init_out_ratio >= 0.0) {
            return bad("init_out_ratio", "must be ≥ 0");
        }
        if !(self.extent.is_finite() && self.extent > 0.0)
            || self.center.iter().any(|c| !c.is_finite())
        {
            return bad("extent/center", "must be finite, extent > 0");
        }
        for (k, f) in [
            ("sh_every", self.sh_every),
            ("ss_from", self.ss_from),
            ("lr_decay_at", self.lr_decay_at),
            ("dist_from", self.dist_from),
            ("normal_dmed_from", self.normal_dmed_from),
            ("normal_dmean_from", self.normal_dmean_from),
            ("tv_until", self.tv_until),
            ("checkpoint_every", self.checkpoint_every),
            ("adapt_every", self.adapt_every),
            ("adapt_from", self.adapt_from),
            ("prune_until", self.prune_until),
            ("subdivide_until", self.subdivide_until),
            ("subdivide_percent", self.subdivide_percent),
            ("subdivide_all_until", self.subdivide_all_until),
        ] {
            if !(f.is_finite() && (0.0..=1.0).contains(&f)) {
                return bad(k, "is a fraction of the run: must be in [0, 1]");
            }
        }
        for (k, v) in [
            ("lr_geo", self.lr_geo),
            ("lr_sh0", self.lr_sh0),
            ("lr_shs", self.lr_shs),
            ("lr_decay", self.lr_decay),
            ("lr_geo_scale_max", self.lr_geo_scale_max),
            ("lr_colour_scale_max", self.lr_colour_scale_max),
            ("eps", self.eps),
            ("lambda_mse", self.lambda_mse),
            ("lambda_ssim", self.lambda_ssim),
            ("lambda_t", self.lambda_t),
            ("lambda_t_inside", self.lambda_t_inside),
            ("lambda_dist", self.lambda_dist),
            ("lambda_normal_dmed", self.lambda_normal_dmed),
            ("lambda_normal_dmean", self.lambda_normal_dmean),
            ("lambda_r", self.lambda_r),
            ("lambda_r_colour", self.lambda_r_colour),
            ("lambda_tv", self.lambda_tv),
            ("geo_init", self.geo_init.abs()),
            ("prune_thres_init", self.prune_thres_init),
            ("prune_thres_final", self.prune_thres_final),
            ("subdivide_min_rate", self.subdivide_min_rate),
            ("sh0_init", self.sh0_init.abs()),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(k, "must be finite and ≥ 0");
            }
        }
        if !(self.stats_ss.is_finite() && (1.0..=8.0).contains(&self.stats_ss)) {
            return bad("stats_ss", "must be in [1, 8]");
        }
        if !((0.0..1.0).contains(&self.beta1) && (0.0..1.0).contains(&self.beta2)) {
            return bad("beta1/beta2", "must be in [0, 1)");
        }
        if !(self.grid_level..=crate::scene::MAX_LEVEL).contains(&self.max_level) {
            return bad("max_level", "must be in grid_level..=16");
        }
        if self.log_every == 0 {
            return bad("log_every", "must be ≥ 1");
        }
        Ok(())
    }
}

impl TrainConfig {
    /// The density learning rate of this run: `lr_geo` times `clamp(sqrt(20 000 /
    /// iters), 1, lr_geo_scale_max)` — with the defaults (0.1, 1) a constant 0.1.
    ///
    /// Why 0.1 and not the paper's 0.025: Adam moves a density by about the learning
    /// rate per step, and densities must travel from `geo_init` (−10) to surface values.
    /// On lego 100² (val, synthetic preset, model's ss 1.5) 0.025 with the square-root
    /// rule (0.1 at ≤ 1 250 iterations, 0.065 at 3 000, 0.025 at 20 000) gave 31.45 dB
    /// at 3 000 iterations, 29.89 at 6 000 and 25.66 at 20 000 — quality fell as the rate
    /// fell — while 0.1 throughout gave 31.54 dB at 3 000 and 32.42 at 20 000 (without
    /// the distortion loss; 32.25 at 6 000). Short runs are unchanged (they had 0.1).
    pub fn lr_geo_used(&self) -> f32 {
        // The schedule's length: an extended run keeps its rate.
        let n = self.schedule_iters.unwrap_or(self.iters);
        if self.svraster_schedule {
            return self.lr_geo * self.sche_factor(n);
        }
        let f = (REFERENCE_ITERS as f64 / n.max(1) as f64).sqrt();
        self.lr_geo * f.clamp(1.0, self.lr_geo_scale_max.max(1.0) as f64) as f32
    }

    /// The SH learning rates of this run, `(lr_sh0, lr_shs)` times `clamp(20 000 /
    /// iters, 1, lr_colour_scale_max)` — with the default maximum 1 the rates as set.
    ///
    /// SVRaster scales every rate by `1 / sche_mult` for shorter schedules (its fast
    /// configuration, 6 000 iterations: 3.33× the 20 000-iteration rates). On the H200
    /// (lego 400², 6 000 iterations) these colour rates, with the straight-through colour
    /// gradient that lets them train, the density rate 0.0833 and the Adam resets, gave
    /// 35.04 dB against 34.71 (docs/PARITY.md item 3); on lavapipe at 3 000 iterations the
    /// uncapped 1/0.15 cost 0.30 dB at 100² and 0.39 at 200², so the synthetic preset
    /// caps the factor at 1/0.3.
    pub fn lr_colour_used(&self) -> (f32, f32) {
        let n = self.schedule_iters.unwrap_or(self.iters);
        if self.svraster_schedule {
            let f = self.sche_factor(n);
            return (self.lr_sh0 * f, self.lr_shs * f);
        }
        let f = (REFERENCE_ITERS as f64 / n.max(1) as f64)
            .clamp(1.0, self.lr_colour_scale_max.max(1.0) as f64) as f32;
        (self.lr_sh0 * f, self.lr_shs * f)
    }

    /// SVRaster's rate factor 1/sche_mult = 20 000/n (train.py:588-589).
    fn sche_factor(&self, n: u32) -> f32 {
        (REFERENCE_ITERS as f64 / n.max(1) as f64) as f32
    }
}
