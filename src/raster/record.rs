//! Recording a frame into a command buffer (after [`Renderer::prepare`]): the parameter
//! block and preprocess, then scan, key emission, the sort, tile ranges, the composite
//! (per tile in chunks, or per segment: `segments.rs`), finalize and downsample.

use ash::vk;

use super::params::{ChunkPush, FieldPush, FrameMeanPush, FrameParams, ParamsPush, SetupPush};
use super::plan::Plan;
use super::{FrameStats, RenderOptions, Renderer, CHANNELS, STAT_ARGS, STAT_USED, TILE};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::gpu::{glsl, recorder, Timestamps};
use crate::scene::SceneGpu;
use crate::sort::{Count, KeyWidth, SortBuffers, Sorted};

impl Renderer {
    /// Records only the first stage of a frame (after [`Renderer::prepare`]): the frame's
    /// parameter block and the per-voxel preprocess (projection, per-voxel tile-entry
    /// counts, camera-relative centres). No image is produced; [`Renderer::last_frame`]
    /// then describes this frame, for passes that only need which voxels it shows
    /// (the adaptive layout's visibility test at initialisation).
    pub fn record_preprocess(
        &mut self,
        cmd: vk::CommandBuffer,
        scene: &SceneGpu,
        cam: &Camera,
        opts: &RenderOptions,
    ) -> Result<()> {
        self.record_preprocess_stage(cmd, scene, cam, opts, None)
            .map(|_| ())
    }

    pub(super) fn record_preprocess_stage(
        &mut self,
        cmd: vk::CommandBuffer,
        scene: &SceneGpu,
        cam: &Camera,
        opts: &RenderOptions,
        mut ts: Option<&mut Timestamps>,
    ) -> Result<Plan> {
        let plan = self.plan(scene, cam, opts)?;
        if plan.counters && self.maxw_target != 0 {
            return Err(Error::Invalid(
                "work counters and max-weight statistics cannot be recorded in one frame \
                 (the counting kernels do not fold weights): turn the counters off"
                    .into(),
            ));
        }
        if self.voxel_cap < scene.voxels
            || self.scan.is_none()
            || self.sort.is_none()
            || self.img.bytes() < plan.render_w as u64 * plan.render_h as u64 * CHANNELS as u64 * 4
            || self.ranges.bytes() < plan.tiles as u64 * 8
            || (plan.seg_size > 0
                && u64::from(self.slot_cap)
                    < u64::from(plan.tiles) + u64::from(self.entry_cap / plan.seg_size) + 1)
        {
            return Err(Error::Invalid(
                "Renderer::record before Renderer::prepare for this scene and camera".into(),
            ));
        }
        let ctx = self.ctx.clone();
        let rcam = cam.resized(plan.render_w, plan.render_h);
        let o = rcam.origin();
        let mut w2c = [[0f32; 4]; 3];
        let mut c2w = [[0f32; 4]; 3];
        for r in 0..3 {
            for c in 0..3 {
                w2c[r][c] = rcam.c2w[c][r] as f32;
                c2w[r][c] = rcam.c2w[r][c] as f32;
            }
        }
        // Camera position in finest-grid units, split into an integer part (exact
        // in the kernels' integer arithmetic) and the rest.
        let half = 0.5 * scene.extent as f64;
        let unit = scene.extent as f64 / crate::scene::GRID_MAX as f64;
        let cam_fine: [(i32, f64); 3] = std::array::from_fn(|a| {
            let f = (o[a] - (scene.center[a] as f64 - half)) / unit;
            let i = f.floor().clamp(-1073741824.0, 1073741824.0);
            (i as i32, f - i)
        });
        let (skeys, svals) = if plan.sorted_in_alt() {
            (&self.keys_alt, &self.vals_alt)
        } else {
            (&self.keys, &self.vals)
        };
        let sx = plan.render_w as f32 / plan.out_w as f32;
        let sy = plan.render_h as f32 / plan.out_h as f32;
        let params = FrameParams {
            w2c,
            c2w,
            intr: [
                rcam.fx as f32,
                rcam.fy as f32,
                rcam.cx as f32,
                rcam.cy as f32,
            ],
            cam_frac: [
                cam_fine[0].1 as f32,
                cam_fine[1].1 as f32,
                cam_fine[2].1 as f32,
            ],
            unit: unit as f32,
            // Host frames are premultiplied over the host's own image, and fields are
            // composited over nothing: no background.
            bg: if self.host.is_some() || self.voxel_colours.is_some() {
                [0.0; 3]
            } else {
                scene.background
            },
            near: cam.near as f32,
            render_size: [plan.render_w, plan.render_h],
            tiles: [plan.render_w.div_ceil(TILE), plan.render_h.div_ceil(TILE)],
            voxels: scene.voxels,
            sh_degree: scene.sh_degree,
            max_level: scene.max_level,
            entry_capacity: self.entry_cap,
            chunks: plan.chunks,
            chunk_size: self.chunk_size,
            key_shift: 3 * scene.max_level,
            supersampled: plan.supersampled as u32,
            out_size: [plan.out_w, plan.out_h],
            shs_stride: scene.shs_per_voxel,
            key32: (plan.sort_bits <= 32) as u32,
            ss_scale: [sx, sy],
            filter_radius: [sx.max(1.0), sy.max(1.0)],
            cam_int: [cam_fine[0].0, cam_fine[1].0, cam_fine[2].0],
            flags: (self.generic_walk as u32 * glsl::FRAME_GENERIC_WALK)
                | (self.outputs.normals as u32 * glsl::FRAME_NORMALS)
                | (self.outputs.distortion as u32 * glsl::FRAME_DISTORTION)
                | (self.outputs.distortion_contracted as u32 * glsl::FRAME_DIST_CONTRACT),
            depth_map: self.host.map_or([0.0; 4], |h| h.depth_map),
            octpath: scene.octpath.address(),
            level: scene.level.address(),
            corners: scene.corners.address(),
            geo: scene.geo.address(),
            sh0: scene.sh0.address(),
            shs: scene.shs.address(),
            bbox: self.bbox.address(),
            signs: self.signs.address(),
            counts: self.counts.address(),
            offsets: self.offsets.address(),
            geo8: self.geo8.address(),
            rgb: self.rgb.address(),
            nrm: self.nrm.address(),
            cs: self.cs.address(),
            keys: self.keys.address(),
            vals: self.vals.address(),
            skeys: skeys.address(),
            svals: svals.address(),
            ranges: self.ranges.address(),
            img: self.img.address(),
            med_id: self.med_id.address(),
            med_t: self.med_t.address(),
            out_img: self.out_img.address(),
            stats: self.stats.address(),
            last: self.last_id.address(),
            aux: self.aux.address(),
            maxw: self.maxw_target,
            counters: self.counters_address(),
            host_depth: self.host.map_or(0, |h| h.depth),
            seg_tile: if plan.seg_size > 0 {
                self.seg_tile.address()
            } else {
                0
            },
            seg_state: if plan.seg_size > 0 {
                self.seg_state.address()
            } else {
                0
            },
            seg_size: plan.seg_size,
            slot_cap: self.slot_cap,
            bgsum: if plan.frame_mean {
                self.bgsum.address()
            } else {
                0
            },
        };
        let dev = ctx.device();
        let pa = ParamsPush {
            frame: self.params.address(),
        };
        if let Some(t) = ts.as_deref_mut() {
            t.begin(cmd);
        }
        unsafe {
            dev.cmd_update_buffer(cmd, self.params.raw(), 0, bytemuck::bytes_of(&params));
        }
        recorder::zero(&ctx, cmd, &self.stats);
        recorder::fill(&ctx, cmd, self.ranges.get(), 0, plan.tiles as u64 * 8, 0);
        if plan.seg_size > 0 {
            let words = u64::from(self.slot_cap) * 4;
            recorder::fill(&ctx, cmd, self.seg_tile.get(), 0, words, u32::MAX);
        }
        if let (Some(c), true) = (&self.counters, plan.counters) {
            recorder::zero(&ctx, cmd, c);
        }
        recorder::barrier(&ctx, cmd);
        let n = scene.voxels;
        self.k.preprocess.dispatch_1d(cmd, &pa, n);
        recorder::barrier(&ctx, cmd);
        if let Some(f) = self.voxel_colours {
            let push = FieldPush {
                frame: self.params.address(),
                field: f.address,
                channels: f.channels,
                first: f.first,
            };
            self.k.field_colour.get(&ctx)?.dispatch_1d(cmd, &push, n);
            recorder::barrier(&ctx, cmd);
        }
        if let Some(t) = ts {
            t.mark(cmd, "preprocess");
        }
        self.last = Some(plan);
        Ok(plan)
    }

    /// Records a frame into `cmd` (after [`Renderer::prepare`]). Reads no host data from
    /// the device; check [`Renderer::stats`] once it completed.
    pub fn record(
        &mut self,
        cmd: vk::CommandBuffer,
        scene: &SceneGpu,
        cam: &Camera,
        opts: &RenderOptions,
        mut ts: Option<&mut Timestamps>,
    ) -> Result<FrameStats> {
        let plan = self.record_preprocess_stage(cmd, scene, cam, opts, ts.as_deref_mut())?;
        let ctx = self.ctx.clone();
        let max_x = ctx.info().max_compute_work_group_count[0];
        let n = scene.voxels;
        let pa = ParamsPush {
            frame: self.params.address(),
        };
        let passes = plan.sort_bits.div_ceil(8);
        let scan = self.scan.as_ref().expect("prepared");
        scan.record(
            cmd,
            self.counts.get(),
            self.offsets.get(),
            Count::Host(n),
            None,
        )?;
        self.k.setup.dispatch(
            cmd,
            &SetupPush {
                frame: self.params.address(),
                max_groups_x: max_x,
                pad: 0,
            },
            [1, 1, 1],
        );
        recorder::barrier(&ctx, cmd);
        if let Some(t) = ts.as_deref_mut() {
            t.mark(cmd, "scan");
        }
        self.k
            .emit
            .dispatch_indirect(cmd, &pa, self.stats.raw(), STAT_ARGS * 4);
        recorder::barrier(&ctx, cmd);
        if let Some(t) = ts.as_deref_mut() {
            t.mark(cmd, "emit_keys");
        }
        let sort = self.sort.as_ref().expect("prepared");
        // Keys whose bits fit in 32 are sorted as u32 (a third less traffic per pass).
        let width = if plan.sort_bits <= 32 {
            KeyWidth::U32
        } else {
            KeyWidth::U64
        };
        let sorted = sort.record_keys(
            cmd,
            &SortBuffers {
                keys: self.keys.get(),
                values: self.vals.get(),
                keys_alt: self.keys_alt.get(),
                values_alt: self.vals_alt.get(),
            },
            Count::Device {
                buffer: &self.stats,
                offset: STAT_USED as u64 * 4,
            },
            0..plan.sort_bits,
            width,
            None,
        )?;
        debug_assert_eq!(
            sorted,
            if passes % 2 == 0 {
                Sorted::Primary
            } else {
                Sorted::Alternate
            }
        );
        if let Some(t) = ts.as_deref_mut() {
            t.mark(cmd, "sort");
        }
        self.k
            .ranges_k
            .dispatch_indirect(cmd, &pa, self.stats.raw(), STAT_ARGS * 4);
        recorder::barrier(&ctx, cmd);
        if let Some(t) = ts.as_deref_mut() {
            t.mark(cmd, "tile_ranges");
        }
        let tiles_xy = [
            plan.render_w.div_ceil(TILE),
            plan.render_h.div_ceil(TILE),
            1,
        ];
        // Counters win over statistics: both are for measurement, never mixed in a run.
        let variant = if plan.counters {
            2
        } else if self.maxw_target != 0 {
            1
        } else {
            0
        };
        let si = opts.samples as usize - 1;
        let nonormal = !self.outputs.normals;
        let k = if nonormal && variant < 2 {
            self.k.composite_nonormal[variant][si].get(&ctx)?
        } else {
            &self.k.composite[variant][si]
        };
        if plan.seg_size > 0 {
            self.record_segments(cmd, k, tiles_xy, plan.tiles);
        } else {
            for chunk in 0..plan.chunks {
                k.dispatch(
                    cmd,
                    &ChunkPush {
                        frame: self.params.address(),
                        chunk,
                        mode: glsl::SEG_OFF,
                    },
                    tiles_xy,
                );
                recorder::barrier(&ctx, cmd);
            }
        }
        if let Some(t) = ts.as_deref_mut() {
            t.mark(cmd, "composite");
        }
        let rpix = plan.render_w * plan.render_h;
        if plan.frame_mean {
            // The frame's mean colour, before finalize composites it behind T.
            let fm = |mode, dst| FrameMeanPush {
                frame: self.params.address(),
                back: 0,
                mode,
                dst,
            };
            let groups = rpix.div_ceil(glsl::FM_PIXELS);
            let k = &self.k.frame_mean;
            k.dispatch_1d(cmd, &fm(glsl::FM_SUM_COLOUR, 0), groups * 256);
            recorder::barrier(&ctx, cmd);
            k.dispatch(cmd, &fm(glsl::FM_TOTAL, glsl::FM_SLOT_MEAN), [1, 1, 1]);
            recorder::barrier(&ctx, cmd);
        }
        self.k.finalize.dispatch_1d(cmd, &pa, rpix);
        recorder::barrier(&ctx, cmd);
        if plan.supersampled {
            let opix = plan.out_w * plan.out_h;
            self.k.downsample.dispatch_1d(cmd, &pa, opix);
            recorder::barrier(&ctx, cmd);
        }
        if let Some(t) = ts {
            t.mark(cmd, "finalize");
        }
        self.last = Some(plan);
        Ok(FrameStats {
            tiles: plan.tiles,
            render_width: plan.render_w,
            render_height: plan.render_h,
            chunks: plan.chunks,
            sort_bits: plan.sort_bits,
            ..Default::default()
        })
    }
}
