//! The update recorded after a training frame (paper §3.2): losses against the view,
//! backward with TV, the Adam step of every parameter group; and the loss values read
//! back on logged iterations.

use ash::vk;

use super::backward::EntryLosses;
use super::iteration::IterWeights;
use super::loss::LossWeights;
use super::optim::AdamConfig;
use super::trainer::{StepLosses, Trainer};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::gpu::{recorder, Timestamps};
use crate::raster::FrameStats;

impl Trainer {
    /// Records the update of the frame just recorded (`stats`: its stats, or what the
    /// frame's plan lets the update assume): losses against view `view`, backward with
    /// TV, and the Adam step of every parameter group.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn record_update(
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
        let t_render = cfg.t_losses_at_render;
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
                // At render resolution the backward applies them (grad_prepare.comp);
                // the output-resolution sums are still logged.
                t_concentration: if t_render { 0.0 } else { cfg.lambda_t },
                t_inside: if t_render { 0.0 } else { cfg.lambda_t_inside },
            },
            cfg.clamp_rgb_loss,
        )?;
        if w.nmed > 0.0 || w.nmean > 0.0 {
            self.normal
                .record(cmd, cam, out_addr, dout_addr, w.nmed, w.nmean)?;
        }
        if cfg.lambda_ssim > 0.0 {
            // SVRaster's rule (`clamp_rgb_loss`): SSIM of the clamped image, its
            // gradient passed back through the clamp to the raw output.
            let (x, raw) = match self.loss.clamped_rgb() {
                Some(clamped) => (clamped.address(), out_addr),
                None => (out_addr, 0),
            };
            self.ssim.record_with(
                cmd,
                x,
                gt_addr,
                dout_addr,
                -cfg.lambda_ssim,
                frame.out_width,
                frame.out_height,
                raw,
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
                lambda_r_colour: cfg.lambda_r_colour / nrender as f32,
                lambda_t: if t_render {
                    cfg.lambda_t / nrender as f32
                } else {
                    0.0
                },
                lambda_t_inside: if t_render {
                    cfg.lambda_t_inside / nrender as f32
                } else {
                    0.0
                },
                r_target_bilinear: cfg.r_target_bilinear,
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
                self.schedule.lr_sh0,
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
                self.schedule.lr_shs,
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

    pub(super) fn read_losses(
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
}
