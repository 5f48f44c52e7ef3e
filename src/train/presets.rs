//! The named presets ([`PRESETS`], [`TrainConfig::preset`]) and the speed modifiers
//! (`fast-train`, `fast-render`): what each changes from [`TrainConfig::default`], and
//! the measurements behind it.

use super::config::{ClampGrad, TrainConfig};
use crate::error::{Error, Result};

/// Named presets (applied before `--set` overrides).
pub const PRESETS: &[(&str, &str)] = &[
    (
        "synthetic",
        "the paper's NeRF-synthetic configuration: level-6 initial grid, adaptive pruning \
         and subdivision down to about one pixel per voxel at its closest training view, as \
         the reference's synthetic config, with its learning rules at its 6 000-iteration \
         schedule (SH rates 3.3x, density 0.0833, the colour clamp's gradient passed \
         through, Adam reset at each adaptive step) and its valid-padded SSIM; default)",
    ),
    (
        "real",
        "real captures, unbounded (Mip-NeRF 360-like; the default for COLMAP data): main \
         region from the cameras, 5 background shell levels holding twice the main \
         region's voxels, the photos' mean colour behind them, no distortion loss (it \
         cost quality on every test view of the captures measured) and no \
         transmittance-concentration loss, inside loss mean(T²) 0.01",
    ),
    (
        "forward",
        "real forward-facing captures (the default for LLFF data): the real preset with 2 \
         background shell levels instead of 5 (nothing behind the cameras is seen, and the \
         sparse points or LLFF depth bounds already reach the far background), a black \
         background and no inside loss",
    ),
    (
        "object",
        "object captures with a bounding sphere (the default for NeuS/DTU data; the \
         reference's dtu_mesh configuration without its depth-normal losses): main region \
         = the capture's sphere, one background shell level with few voxels, black \
         background, 3 samples per ray-voxel segment, transmittance-concentration loss \
         0.01, ray-colour concentration 0.1",
    ),
    (
        "mesh",
        "surfaces for meshes (the reference's dtu_mesh configuration): the object preset \
         plus the depth-normal consistency losses, 0.001 each, on the median depth from 15 % \
         and on the mean depth from 50 % of the run",
    ),
    (
        "svraster-synthetic",
        "SVRaster's own NeRF-synthetic training, rule for rule (cfg/synthetic_nerf.yaml at \
         f0e7fa0; the step-level test tests/parity.rs replays its steps with this preset): \
         the synthetic preset with its 20 000-iteration rates scaled by its sche_mult rule, \
         its unscaled SH and supersampling milestones, valid-padded SSIM, colour-only \
         R_concen, L1 TV, straight-through clamps, distortion 0.1 from half the run, \
         subdivide-all at its first adaptive step, statistics at ss 1.5 over the voxels \
         given weight",
    ),
    (
        "svraster-real",
        "SVRaster's own Mip-NeRF 360 training, rule for rule (cfg/mipnerf360.yaml at \
         f0e7fa0): the real preset with the svraster-synthetic rules that are not \
         synthetic-only — each frame's own mean colour behind the model, inside loss \
         0.01, no T concentration, every SH degree from the start, voxels stopping at \
         two pixels",
    ),
    (
        "quick",
        "short runs on CPU devices: the synthetic configuration without supersampling \
         (the density learning rate scales with the run length in every preset: 0.1 up to \
         1 250 iterations)",
    ),
    (
        "fast-train",
        "a speed modifier on the data's preset (or appended to any: e.g. \
         real-fast-train): no supersampling, and a starting grid one level coarser with \
         voxels stopping at two pixels on synthetic scenes (lego 100², 1 000 iterations: \
         3.2× faster training, −0.5 dB against the synthetic preset with that guard) or \
         SH degree 1 on captures (llff_flower: 1.43× faster, −0.6 dB)",
    ),
    (
        "fast-render",
        "a speed modifier on the data's preset (or appended to any): no supersampling, \
         and pruning threshold 0.15 with voxels stopping at two pixels on synthetic scenes \
         (lego: 1.8× faster frames, −0.14 dB against the synthetic preset with that \
         guard; llff_flower without the threshold: 1.3×, −0.11 dB)",
    ),
];

impl TrainConfig {
    /// The defaults of a preset.
    pub fn preset(name: &str) -> Result<TrainConfig> {
        // Speed modifiers on any preset: `<preset>-fast-train`, `<preset>-fast-render`
        // (bare `fast-train`/`fast-render`: on the synthetic preset here; the CLI puts
        // the data format's preset in front, see `resolve_preset`).
        for (suffix, apply) in [
            ("fast-train", Self::fast_train as fn(&mut TrainConfig, &str)),
            ("fast-render", Self::fast_render),
        ] {
            if name == suffix {
                return Self::preset(&format!("synthetic-{suffix}"));
            }
            if let Some(base) = name.strip_suffix(&format!("-{suffix}")) {
                if ["fast-train", "fast-render"]
                    .iter()
                    .any(|m| base == *m || base.ends_with(&format!("-{m}")))
                {
                    return Err(Error::Invalid(format!(
                        "preset {name:?}: one speed modifier at a time"
                    )));
                }
                let mut c = Self::preset(base)?;
                apply(&mut c, base);
                return Ok(c);
            }
        }
        let mut c = TrainConfig::default();
        match name {
            "synthetic" => {
                // SVRaster's NeRF-synthetic configuration lets voxels subdivide down to
                // about one pixel at their closest training view (`subdivide_samp_thres`
                // 0.5 in cfg/synthetic_nerf.yaml: rate > 1) where its default (and the
                // paper's 2·h_rate) stops at two. Lego, val, 3 000 iterations on lavapipe:
                // 100² 33.12 vs 31.96 dB (122 k vs 27 k voxels, 1.9× the training time);
                // 200² 33.77 vs 32.81 dB (646 k vs 140 k voxels, 2.2×); on the H200 at 400²
                // and 6 000 iterations 33.95 vs 33.29 dB (1.23×). docs/PARITY.md, item 2.
                c.subdivide_min_rate = 1.0;
                // SVRaster's learning rates at its 6 000-iteration schedule (train.py
                // divides every rate by sche_mult 0.3): SH 0.0333 / 0.000833, density
                // 0.0833, with what lets such colour steps train — the colour clamp's
                // gradient passed straight through (sh_compute.cu:118-121) — and its Adam
                // resets at every adaptive step (train.py:356-360). On the H200, lego
                // 400², 6 000 iterations: 35.04 dB (twice) against 34.71; docs/PARITY.md
                // items 3 and 4 have the lavapipe runs at 100² and 200².
                c.colour_clamp_grad = ClampGrad::Straight;
                c.lr_colour_scale_max = 1.0 / 0.3;
                c.lr_geo = 0.0833;
                c.reset_adam_at_adapt = true;
                // SVRaster's "valid" SSIM (the step-level test found it; docs/PARITY.md):
                // lego 100², 3 000 iterations, val: 33.21 dB / 0.9833 against 33.19 /
                // 0.9832, better on 69 of 100 views (median +0.015 dB, −0.06 … +0.15;
                // tools/parity_lavapipe.sh, 2026-12-04).
                c.ssim_valid = true;
            }
            "real" | "forward" => {
                c.bound = "auto".into();
                c.outside_level = if name == "real" { 5 } else { 2 };
                c.background = [0.0; 3];
                // No distortion loss (the paper's 0.1 is `--set lambda_dist=0.1`): it
                // costs quality on both real captures measured (docs/PARITY.md item 8),
                // on every test view, at the real-captures sizes and 3 000 iterations:
                // the garden (`real`, 128², 24 views) 27.64 dB without, 26.57 with (+0.24
                // to +1.83 dB per view, 2.2× the voxels, 2.1× the frame time);
                // llff_flower (`forward`, 504×378, 5 views) 28.30 without, 27.39 with
                // (+0.55 to +1.31 dB, 1.17× the voxels, 1.22× the frame time).
                c.lambda_dist = 0.0;
                // The reference's Mip-NeRF 360 configuration: no transmittance
                // concentration (an object-on-background prior; the shells fill the
                // background here).
                c.lambda_t = 0.0;
                // Every ray ends inside the model (its shells hold the background);
                // the reference sets it for Mip-NeRF 360 only, and so do we.
                // Behind the model, the photos' mean colour (the paper's unbounded
                // setting). Not for forward-facing captures: on llff_flower (126×95,
                // 1 000 iterations) it cost 0.57 dB against black (24.96 vs 25.52 dB,
                // 41 486 vs 28 584 voxels: dark shadows must be filled with voxels).
                if name == "real" {
                    c.lambda_t_inside = 0.01;
                    c.background_from_photos = true;
                }
            }
            "object" | "mesh" => {
                c.bound = "auto".into();
                c.outside_level = 1;
                c.init_out_ratio = 0.01;
                c.background = [0.0; 3];
                c.samples = 3;
                c.lambda_t = 0.01;
                c.lambda_r = 0.1;
                if name == "mesh" {
                    c.lambda_normal_dmed = 0.001;
                    c.lambda_normal_dmean = 0.001;
                }
            }
            "svraster-synthetic" => {
                c = Self::preset("synthetic")?;
                c.apply_svraster_rules();
                // cfg/synthetic_nerf.yaml: subdivide_all_until 1000, samp_thres 0.5.
                c.subdivide_all_until = 0.05;
                c.subdivide_min_rate = 1.0;
            }
            "svraster-real" => {
                c = Self::preset("real")?;
                c.apply_svraster_rules();
                // cfg/mipnerf360.yaml over config.py: neither white nor black (each
                // frame's mean colour, renderer.py:158-159), lambda_T_inside 0.01, no
                // T concentration, sh_degree_init 3, subdivide_samp_thres 1.0.
                c.background_from_photos = false;
                c.background_frame_mean = true;
                c.lambda_t = 0.0;
                c.lambda_t_inside = 0.01;
                c.sh_every = 0.0;
                c.subdivide_all_until = 0.0;
                c.subdivide_min_rate = 2.0;
            }
            "quick" => {
                c.grid_level = 6;
                c.ss = 1.0;
            }
            _ => {
                let names: Vec<&str> = PRESETS.iter().map(|p| p.0).collect();
                return Err(Error::Invalid(format!(
                    "unknown preset {name:?}; available: {}",
                    names.join(", ")
                )));
            }
        }
        Ok(c)
    }

    /// SVRaster's rules common to its configurations (the `svraster-*` presets): each
    /// line a switch whose own entry in config.rs and docs/PARITY.md says what it is.
    fn apply_svraster_rules(&mut self) {
        self.svraster_schedule = true;
        self.lr_geo = 0.025;
        self.lr_sh0 = 0.01;
        self.lr_shs = 0.00025;
        self.lr_colour_scale_max = 1.0;
        self.ssim_valid = true;
        self.clamp_rgb_loss = true;
        self.lambda_r = 0.0;
        self.lambda_r_colour = 0.01;
        self.colour_clamp_grad = ClampGrad::Straight;
        self.alpha_clamp_grad = ClampGrad::Straight;
        self.t_losses_at_render = true;
        self.r_target_bilinear = true;
        self.tv_form = super::config::TvForm::L1;
        self.lambda_dist = 0.1;
        self.dist_contracted = true;
        self.reset_adam_at_adapt = true;
        self.stats_ss = 1.5;
        self.stats_visible = super::config::StatsVisible::Weight;
    }

    /// The name a `--preset` stands for: a bare speed modifier (`fast-train`,
    /// `fast-render`) applies to `format_default`, the data format's preset.
    pub fn resolve_preset(name: &str, format_default: &str) -> String {
        match name {
            "fast-train" | "fast-render" => format!("{format_default}-{name}"),
            _ => name.to_string(),
        }
    }

    /// The `fast-train` modifier, chosen from the training-time Pareto fronts of `bench
    /// trade` (docs/PERFORMANCE.md "Speed ↔ accuracy", 1 000 iterations): on the synthetic presets no
    /// supersampling and a starting grid one level coarser (lego 100²: 3.2× faster
    /// training, −0.5 dB; the dense first phase is most of a short run), on the capture
    /// presets no supersampling and SH degree 1 (llff_flower 126×95: 1.43× faster,
    /// −0.58 dB; a coarser grid cost 2.65 dB there).
    fn fast_train(&mut self, base: &str) {
        self.ss = 1.0;
        if matches!(base, "synthetic" | "quick") {
            self.grid_level = self.grid_level.saturating_sub(1).max(1);
            // The measured combination: voxels stop at two pixels (see `fast_render`).
            self.subdivide_min_rate = 2.0;
            self.synthetic_rates_as_measured_fast();
        } else {
            self.sh_degree = self.sh_degree.min(1);
        }
    }

    /// The `fast-render` modifier, chosen from the frame-time Pareto fronts likewise:
    /// models render at the resolution they were trained at, so no supersampling; on the
    /// synthetic presets also the paper's fast-rendering pruning threshold, 0.15 (lego:
    /// 1.8× faster frames, −0.14 dB); not on the capture presets, where it cost 2.3 dB
    /// (llff_flower; no supersampling alone: 1.3× faster frames, −0.11 dB).
    fn fast_render(&mut self, base: &str) {
        self.ss = 1.0;
        if matches!(base, "synthetic" | "quick") {
            self.prune_thres_final = 0.15;
            // Voxels stop at two pixels, as in the measured combination (the synthetic
            // preset's guard before it followed SVRaster's, rate ≥ 1: 3× the frame time
            // at lego 200²).
            self.subdivide_min_rate = 2.0;
            self.synthetic_rates_as_measured_fast();
        }
    }

    /// The speed modifiers' learning rules, as their combinations were measured (before
    /// the synthetic preset took SVRaster's 6 000-iteration rates): masked colour
    /// gradient, SH rates as set, density 0.1, moments carried across adaptive steps.
    fn synthetic_rates_as_measured_fast(&mut self) {
        let d = TrainConfig::default();
        self.colour_clamp_grad = d.colour_clamp_grad;
        self.lr_colour_scale_max = d.lr_colour_scale_max;
        self.lr_geo = d.lr_geo;
        self.reset_adam_at_adapt = d.reset_adam_at_adapt;
    }
}
