//! Recording the backward of a frame (after the losses wrote the output gradients):
//! gradient preparation at render resolution, the walk (per tile in chunks, last chunk
//! first, or per segment from the state behind each), the ordered reduction's gathers,
//! the per-voxel stage and the caller's further density terms.

use ash::vk;

use super::*;

impl Backward {
    /// Records the backward of the renderer's last frame into `cmd`: overwrites
    /// `grads.geo`, `grads.sh0`, `grads.shs` and adds to `grads.priority`.
    /// `stats` are the frame's completed [`FrameStats`] (its longest tile list sets
    /// the number of chunks).
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &mut self,
        cmd: vk::CommandBuffer,
        frame: &FrameGeometry,
        stats: &FrameStats,
        scene: &SceneGpu,
        samples: u32,
        grads: &Gradients,
        losses: &EntryLosses,
    ) -> Result<()> {
        self.record_timed(
            cmd,
            frame,
            stats,
            scene,
            samples,
            grads,
            losses,
            None,
            |_, _| Ok(()),
        )
    }

    /// [`Backward::record`] with timestamps after each part (`backward.prepare`,
    /// `backward.walk`, `backward.voxel`, `backward.points` for the ordered reduction)
    /// when `ts` is given, and `geo_terms(cmd, target)` recorded after the per-voxel
    /// stage to add further density-gradient terms (TV) to `target`: the grid-point
    /// gradient buffer, or for [`Reduction::Ordered`] the per-voxel-corner buffer
    /// (8 floats per voxel) that the grid-point gather then sums.
    #[allow(clippy::too_many_arguments)]
    pub fn record_timed(
        &mut self,
        cmd: vk::CommandBuffer,
        frame: &FrameGeometry,
        stats: &FrameStats,
        scene: &SceneGpu,
        samples: u32,
        grads: &Gradients,
        losses: &EntryLosses,
        mut ts: Option<&mut Timestamps>,
        geo_terms: impl FnOnce(vk::CommandBuffer, u64) -> Result<()>,
    ) -> Result<()> {
        if !(1..=3).contains(&samples) {
            return Err(Error::Invalid(format!(
                "samples must be 1..=3, got {samples}"
            )));
        }
        if !grads.matches(scene) {
            return Err(Error::Invalid(
                "gradient buffers were made for a different scene".into(),
            ));
        }
        if !stats.complete() {
            return Err(Error::Invalid(
                "the backward needs a complete frame (see Renderer::grow_for)".into(),
            ));
        }
        if losses.lambda_dist != 0.0 && !frame.outputs.distortion {
            return Err(Error::Invalid(
                "the distortion loss needs a frame recorded with its sums \
                 (Renderer::set_outputs with distortion on)"
                    .into(),
            ));
        }
        let points = match (self.reduction, grads.points.as_ref()) {
            (Reduction::Ordered, None) => {
                return Err(Error::Invalid(
                    "the ordered reduction needs gradients made with Reduction::Ordered".into(),
                ))
            }
            (Reduction::Ordered, Some(p)) => Some(p),
            _ => None,
        };
        self.prepare(frame, scene.voxels)?;
        if points.is_some() {
            self.records.ensure(
                &self.ctx,
                u64::from(stats.entries_used).max(1) * VG_STRIDE * 4,
            )?;
        }
        let ctx = self.ctx.clone();
        let chunks = stats.max_tile_entries.div_ceil(self.chunk_size).max(1);
        let get = |b: &GrowBuffer| b.address();
        let params = BackParams {
            lambda_dist: losses.lambda_dist,
            lambda_r: losses.lambda_r,
            chunks,
            chunk_size: self.chunk_size,
            voxels: scene.voxels,
            lambda_r_colour: losses.lambda_r_colour,
            out_size: [frame.out_width, frame.out_height],
            render_size: [frame.render_width, frame.render_height],
            dimg: get(&self.dimg),
            dout: get(&self.dout),
            bstate: get(&self.bstate),
            vgrad: get(&self.vgrad),
            grad_geo: grads.geo.address(),
            grad_sh0: grads.sh0.address(),
            grad_shs: grads.shs.address(),
            priority: grads.priority.address(),
            lost: self.lost.address(),
            records: points.map_or(0, |_| self.records.address()),
            vcorner: points.map_or(0, |p| p.vcorner.address()),
            point_off: points.map_or(0, |p| p.off.address()),
            point_list: points.map_or(0, |p| p.list.address()),
            gather_span: self.gather_span,
            colour_straight: u32::from(self.clamp_grad == ClampGrad::Straight),
            alpha_straight: u32::from(self.alpha_clamp_grad == ClampGrad::Straight),
            lambda_t: losses.lambda_t,
            lambda_t_inside: losses.lambda_t_inside,
            r_bilinear: u32::from(losses.r_target_bilinear),
            pad4: 0,
            pad5: 0,
        };
        let dev = ctx.device();
        unsafe {
            dev.cmd_update_buffer(cmd, self.params.raw(), 0, bytemuck::bytes_of(&params));
        }
        recorder::zero(&ctx, cmd, self.vgrad.get());
        if points.is_some() {
            let used = u64::from(stats.entries_used).max(1) * VG_STRIDE * 4;
            recorder::fill(&ctx, cmd, self.records.get(), 0, used, 0);
        } else {
            recorder::zero(&ctx, cmd, &grads.geo);
        }
        recorder::barrier(&ctx, cmd);
        let p2 = Push2 {
            frame: frame.params,
            back: self.params.address(),
        };
        let rpix = frame.render_width * frame.render_height;
        self.prepare_k.dispatch_1d(cmd, &p2, rpix);
        recorder::barrier(&ctx, cmd);
        if frame.frame_mean_background {
            // The gradient through the frame's mean colour, into every pixel's C:
            // (1/N) Σ_q T_q ∂L/∂out_q (raster/frame_mean.comp).
            let fm = |mode, dst| FrameMeanPush {
                frame: frame.params,
                back: self.params.address(),
                mode,
                dst,
            };
            let groups = rpix.div_ceil(glsl::FM_PIXELS);
            let k = &self.frame_mean;
            k.dispatch_1d(cmd, &fm(glsl::FM_SUM_TGRAD, 0), groups * 256);
            recorder::barrier(&ctx, cmd);
            k.dispatch(cmd, &fm(glsl::FM_TOTAL, glsl::FM_SLOT_GRAD), [1, 1, 1]);
            recorder::barrier(&ctx, cmd);
            k.dispatch_1d(cmd, &fm(glsl::FM_APPLY, 0), rpix);
            recorder::barrier(&ctx, cmd);
        }
        if let Some(t) = ts.as_deref_mut() {
            t.mark(cmd, "backward.prepare");
        }
        let si = samples as usize - 1;
        let k = if !frame.counters && !frame.outputs.normals {
            self.nonormal[si].get(&ctx)?
        } else {
            &self.backward[frame.counters as usize][si]
        };
        if let Some((args, offset)) = frame.segment_args {
            // Segmented frame: the state behind every segment, then every segment
            // walked by its own workgroup (train/seg_bmerge.comp, backward.glsl).
            self.seg_bmerge
                .dispatch(cmd, &p2, [frame.tiles_x, frame.tiles_y, 1]);
            recorder::barrier(&ctx, cmd);
            let push = ChunkPush {
                frame: frame.params,
                back: self.params.address(),
                chunk: 0,
                mode: glsl::SEG_EXACT,
            };
            k.dispatch_indirect(cmd, &push, args, offset);
            recorder::barrier(&ctx, cmd);
        } else {
            for chunk in (0..chunks).rev() {
                k.dispatch(
                    cmd,
                    &ChunkPush {
                        frame: frame.params,
                        back: self.params.address(),
                        chunk,
                        mode: glsl::SEG_OFF,
                    },
                    [frame.tiles_x, frame.tiles_y, 1],
                );
                recorder::barrier(&ctx, cmd);
            }
        }
        if let (Some(_), Some(kk)) = (points, self.ordered.as_ref()) {
            // A voxel has at most one entry per tile and sign octant.
            let most = (u64::from(frame.tiles_x) * u64::from(frame.tiles_y) * 8)
                .min(u64::from(stats.entries_used).max(1));
            let passes = most.div_ceil(u64::from(self.gather_span)) as u32;
            for pass in 0..passes {
                kk.records.dispatch_1d(
                    cmd,
                    &ChunkPush {
                        frame: frame.params,
                        back: self.params.address(),
                        chunk: pass,
                        mode: 0,
                    },
                    scene.voxels.max(1),
                );
                recorder::barrier(&ctx, cmd);
            }
        }
        if let Some(t) = ts.as_deref_mut() {
            t.mark(cmd, "backward.walk");
        }
        self.voxel.dispatch_1d(cmd, &p2, scene.voxels.max(1));
        recorder::barrier(&ctx, cmd);
        if let Some(t) = ts.as_deref_mut() {
            t.mark(cmd, "backward.voxel");
        }
        match (points, self.ordered.as_ref()) {
            (Some(p), Some(kk)) => {
                geo_terms(cmd, p.vcorner.address())?;
                kk.points.dispatch_1d(
                    cmd,
                    &PointPush {
                        frame: frame.params,
                        back: self.params.address(),
                        points: scene.grid_points,
                        pad: 0,
                    },
                    scene.grid_points.max(1),
                );
                recorder::barrier(&ctx, cmd);
                if let Some(t) = ts {
                    t.mark(cmd, "backward.points");
                }
            }
            _ => geo_terms(cmd, grads.geo.address())?,
        }
        Ok(())
    }
}
