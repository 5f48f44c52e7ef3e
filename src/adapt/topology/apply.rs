//! [`Topology::apply_device`] in its steps: check the inputs, build the new voxels'
//! structure on the host, stage it and allocate the new per-voxel buffers, one
//! submission that gathers, sorts and merges the grid-point candidates, then read back
//! the unique grid points and assemble the result.

use std::time::Instant;

use super::gpu::*;
use super::{check_input, Changed, DeviceMoments, Topology, TopologyStats};
use crate::error::{Error, Result};
use crate::gpu::{recorder, Buffer, Memory};
use crate::scan::SCAN_TILE;
use crate::scene::{shs_device_len, Scene, SceneGpu, MAX_LEVEL, MAX_VOXELS};
use crate::sort::{Count, RadixSort, SortBuffers, Sorted};

/// The new voxels' structure, built on the host (step 1).
struct NewLayout {
    new_n: usize,
    /// Grid-point candidates: 8 per new voxel.
    cand_n: u32,
    /// Value planes per candidate: geo, with moments also its two Adam moments.
    planes: u32,
    octpath: Vec<u64>,
    octlevel: Vec<u8>,
    /// Per new voxel: level | split flag << 8 | child index << 9.
    info: Vec<u32>,
    /// Per new voxel: the old voxel it comes from.
    src: Vec<u32>,
    level32: Vec<u32>,
    finest: u32,
    shift: u32,
    bits: u32,
    sort_bits: u32,
}

/// The new scene's per-voxel device buffers (the SH and its moments are gathered
/// straight into them).
struct NewVoxels {
    octpath: Buffer,
    level: Buffer,
    sh0: Buffer,
    shs: Buffer,
    sh_mom: Option<[Buffer; 4]>,
}

impl Topology {
    /// [`Topology::apply`] on the device: `gpu` (and `moments`) are the scene's device
    /// buffers, `host` its structure (octpaths, levels, corners and grid keys must
    /// match `gpu`; its parameters are not read). Only the new voxels' structure goes up
    /// (octpath, level, source voxel: 20 bytes per voxel) and only the unique count,
    /// the grid keys and the corner indices come back; densities, SH coefficients and
    /// Adam moments stay on the device. The old buffers are left as they were.
    pub fn apply_device(
        &mut self,
        host: &Scene,
        gpu: &SceneGpu,
        moments: Option<DeviceMoments>,
        keep: &[bool],
        split: &[bool],
    ) -> Result<Changed> {
        let t0 = Instant::now();
        let (n, g, nc) = check_device_input(host, gpu, moments, keep, split)?;
        let l = NewLayout::build(host, keep, split, moments.is_some(), nc)?;
        let (layout, new) = self.stage(&l, moments.is_some(), nc)?;
        let t1 = Instant::now();
        let sorted = self.record_dedup(gpu, moments, &l, &layout, &new, nc)?;
        let t2 = Instant::now();
        self.finish(
            host,
            gpu,
            moments.is_some(),
            l,
            new,
            sorted,
            (n, g, nc),
            [t0, t1, t2],
        )
    }

    /// Steps 2–3: the new structure into the upload buffer, the candidate buffers sized,
    /// and the new per-voxel buffers allocated.
    fn stage(
        &mut self,
        l: &NewLayout,
        moments: bool,
        nc: usize,
    ) -> Result<(InputLayout, NewVoxels)> {
        let (new_n, cand_n) = (l.new_n, l.cand_n);
        let layout = InputLayout::new(new_n as u64);
        let ctx = self.ctx.clone();
        {
            self.staging.ensure(&ctx, layout.end)?;
            let dst = self
                .staging
                .buffer_mut()
                .ok_or_else(|| Error::Gpu("topology staging buffer missing".into()))?
                .mapped_mut()
                .ok_or_else(|| Error::Gpu("topology staging buffer is not host-visible".into()))?;
            write_bytes(dst, layout.path, bytemuck::cast_slice(&l.octpath));
            write_bytes(dst, layout.info, bytemuck::cast_slice(&l.info));
            write_bytes(dst, layout.src, bytemuck::cast_slice(&l.src));
            write_bytes(dst, layout.level, bytemuck::cast_slice(&l.level32));
        }
        self.input.ensure(&ctx, layout.end)?;
        if self.bufs.as_ref().is_none_or(|b| b.capacity < cand_n) {
            self.bufs = None;
            let cap = cand_n
                .saturating_add(cand_n / 4)
                .min(RadixSort::MAX_CAPACITY)
                .min(u32::MAX - SCAN_TILE);
            self.bufs = Some(CandidateBuffers::new(&ctx, cap)?);
        }
        self.readback.ensure(&ctx, 16)?;
        // The new per-voxel buffers (the SH and its moments are gathered straight into
        // them); the per-grid-point ones wait for the unique count.
        let nn = new_n as u64;
        let new_octpath = ctx.buffer("scene.octpath", nn * 8, Memory::Device)?;
        let new_level = ctx.buffer("scene.level", nn * 4, Memory::Device)?;
        let new_sh0 = ctx.buffer("scene.sh0", nn * 12, Memory::Device)?;
        // The SH and its moments in the blocked device layout: zeroed, so the padding of
        // the last block is zero.
        let sh_len = shs_device_len(new_n, nc) as u64;
        let new_shs = ctx.zeroed_buffer("scene.shs", sh_len * 4)?;
        let new_sh_mom: Option<[Buffer; 4]> = match moments {
            false => None,
            true => {
                let mk =
                    |name: &str, floats: u64| ctx.buffer(name, floats.max(1) * 4, Memory::Device);
                Some([
                    mk("sh0.adam-m", nn * 3)?,
                    mk("sh0.adam-v", nn * 3)?,
                    ctx.zeroed_buffer("shs.adam-m", sh_len * 4)?,
                    ctx.zeroed_buffer("shs.adam-v", sh_len * 4)?,
                ])
            }
        };
        Ok((
            layout,
            NewVoxels {
                octpath: new_octpath,
                level: new_level,
                sh0: new_sh0,
                shs: new_shs,
                sh_mom: new_sh_mom,
            },
        ))
    }

    /// Step 4, one submission: upload, candidates, SH gather, sort, dedup (heads, scan,
    /// merge). Returns which key buffer holds the sorted candidates.
    fn record_dedup(
        &mut self,
        gpu: &SceneGpu,
        moments: Option<DeviceMoments>,
        l: &NewLayout,
        layout: &InputLayout,
        new: &NewVoxels,
        nc: usize,
    ) -> Result<Sorted> {
        let ctx = self.ctx.clone();
        let (new_n, cand_n, planes) = (l.new_n, l.cand_n, l.planes);
        let (shift, bits, sort_bits) = (l.shift, l.bits, l.sort_bits);
        let nn = new_n as u64;
        let (new_sh0, new_shs, new_sh_mom) = (&new.sh0, &new.shs, &new.sh_mom);
        let (new_octpath, new_level) = (&new.octpath, &new.level);
        let (Some(b), Some(staging), Some(input), Some(readback)) = (
            self.bufs.as_ref(),
            self.staging.buffer(),
            self.input.buffer(),
            self.readback.buffer(),
        ) else {
            return Err(Error::Gpu("topology buffers missing".into()));
        };
        let ts = &mut self.timestamps;
        let gather = &self.gather;
        let sorted = ctx.submit_and_wait(|cmd| {
            ts.begin(cmd);
            recorder::copy(&ctx, cmd, staging, input, 0, 0, layout.end);
            recorder::fill(&ctx, cmd, &self.counters, 0, 16, 0);
            recorder::barrier(&ctx, cmd);
            ts.mark(cmd, "upload");
            let a = input.address();
            let geo = gpu.geo.address();
            let (gm, gv) = moments.map_or((geo, geo), |m| (m[0].address(), m[1].address()));
            self.candidates.dispatch_1d(
                cmd,
                &CandidatesPush {
                    path: a + layout.path,
                    info: a + layout.info,
                    src: a + layout.src,
                    old_corners: gpu.corners.address(),
                    old_geo: geo,
                    old_m: gm,
                    old_v: gv,
                    keys: b.keys.address(),
                    vals: b.vals.address(),
                    cand: b.cand.address(),
                    voxels: new_n as u32,
                    shift,
                    bits,
                    planes,
                },
                new_n as u32,
            );
            // (source, destination, values per voxel, blocked SH layout)
            let mut rows = vec![(&gpu.sh0, new_sh0, 3u32, 0u32)];
            if nc > 0 {
                rows.push((&gpu.shs, new_shs, nc as u32, 1));
            }
            if let (Some(m), Some(nm)) = (moments, new_sh_mom.as_ref()) {
                rows.push((m[2], &nm[0], 3, 0));
                rows.push((m[3], &nm[1], 3, 0));
                if nc > 0 {
                    rows.push((m[4], &nm[2], nc as u32, 1));
                    rows.push((m[5], &nm[3], nc as u32, 1));
                }
            }
            for (from, to, width, blocked) in rows {
                gather.dispatch_1d(
                    cmd,
                    &GatherPush {
                        index: a + layout.src,
                        src: from.address(),
                        dst: to.address(),
                        rows: new_n as u32,
                        width,
                        blocked,
                        pad: 0,
                    },
                    new_n as u32 * width,
                );
            }
            recorder::copy(&ctx, cmd, input, new_octpath, layout.path, 0, nn * 8);
            recorder::copy(&ctx, cmd, input, new_level, layout.level, 0, nn * 4);
            recorder::barrier(&ctx, cmd);
            ts.mark(cmd, "candidates");
            let which = b.sort.record(
                cmd,
                &SortBuffers {
                    keys: &b.keys,
                    values: &b.vals,
                    keys_alt: &b.keys_alt,
                    values_alt: &b.vals_alt,
                },
                Count::Host(cand_n),
                0..sort_bits,
                Some(&mut *ts),
            )?;
            // The other key buffer of the ping-pong is free: it takes the unique keys.
            let (skeys, svals, free_keys) = match which {
                Sorted::Primary => (&b.keys, &b.vals, &b.keys_alt),
                Sorted::Alternate => (&b.keys_alt, &b.vals_alt, &b.keys),
            };
            self.heads.dispatch_1d(
                cmd,
                &HeadsPush {
                    keys: skeys.address(),
                    heads: b.heads.address(),
                    flags: self.counters.address() + 4,
                    count: cand_n,
                    pad: 0,
                },
                cand_n,
            );
            recorder::barrier(&ctx, cmd);
            ts.mark(cmd, "heads");
            b.scan.record(
                cmd,
                &b.heads,
                &b.scan_out,
                Count::Host(cand_n),
                Some((&self.counters, 0)),
            )?;
            ts.mark(cmd, "scan");
            self.merge.dispatch_1d(
                cmd,
                &MergePush {
                    keys: skeys.address(),
                    vals: svals.address(),
                    heads: b.heads.address(),
                    scan: b.scan_out.address(),
                    cand: b.cand.address(),
                    corners: b.corners.address(),
                    out_keys: free_keys.address(),
                    out_vals: b.out_vals.address(),
                    count: cand_n,
                    shift,
                    bits,
                    planes,
                },
                cand_n,
            );
            recorder::barrier(&ctx, cmd);
            ts.mark(cmd, "merge");
            recorder::copy(&ctx, cmd, &self.counters, readback, 0, 0, 16);
            Ok(which)
        })?;
        Ok(sorted)
    }

    /// Step 5: errors and the unique count, the grid-point buffers, the structure read
    /// back, and the result assembled.
    #[allow(clippy::too_many_arguments)]
    fn finish(
        &mut self,
        host: &Scene,
        gpu: &SceneGpu,
        moments: bool,
        l: NewLayout,
        new: NewVoxels,
        sorted: Sorted,
        (n, g, nc): (usize, usize, usize),
        [t0, t1, t2]: [Instant; 3],
    ) -> Result<Changed> {
        let ctx = self.ctx.clone();
        let (new_n, cand_n, finest, sort_bits) = (l.new_n, l.cand_n, l.finest, l.sort_bits);
        let (octpath, octlevel) = (l.octpath, l.octlevel);
        let NewVoxels {
            octpath: new_octpath,
            level: new_level,
            sh0: new_sh0,
            shs: new_shs,
            sh_mom: new_sh_mom,
        } = new;
        let b = self
            .bufs
            .as_ref()
            .ok_or_else(|| Error::Gpu("topology buffers missing".into()))?;
        let readback = self
            .readback
            .buffer()
            .ok_or_else(|| Error::Gpu("topology read-back missing".into()))?;
        let sort_errors = b.sort.take_errors()?;
        let scan_errors = b.scan.take_errors()?;
        if sort_errors | scan_errors != 0 {
            return Err(Error::Gpu(format!(
                "grid-point dedup: radix sort error bits {sort_errors:#x}, scan error bits {scan_errors:#x}"
            )));
        }
        let counters: Vec<u32> = bytemuck::pod_collect_to_vec(
            &readback
                .mapped()
                .ok_or_else(|| Error::Gpu("topology read-back is not host-visible".into()))?[..8],
        );
        let (unique, flags) = (counters[0] as usize, counters[1]);
        if flags & FLAG_LONG_RUN != 0 {
            // Voxels around a point are disjoint, so a validated scene never gets here.
            return Err(Error::Gpu(
                "grid-point dedup: more than 8 voxel corners meet at one grid point \
                 (overlapping voxels)"
                    .into(),
            ));
        }
        if unique == 0 || unique > cand_n as usize {
            return Err(Error::Gpu(format!(
                "grid-point dedup returned {unique} unique points for {cand_n} candidates"
            )));
        }
        let u = unique as u64;
        let new_geo = ctx.buffer("scene.geo", u * 4, Memory::Device)?;
        let new_corners = ctx.buffer("scene.corners", u64::from(cand_n) * 4, Memory::Device)?;
        let new_geo_mom: Option<[Buffer; 2]> = match moments {
            false => None,
            true => Some([
                ctx.buffer("geo.adam-m", u * 4, Memory::Device)?,
                ctx.buffer("geo.adam-v", u * 4, Memory::Device)?,
            ]),
        };
        let off_corners = (u * 8).next_multiple_of(16);
        let rb_end = off_corners + u64::from(cand_n) * 4;
        self.readback.ensure(&ctx, rb_end)?;
        let readback = self
            .readback
            .buffer()
            .ok_or_else(|| Error::Gpu("topology read-back missing".into()))?;
        let free_keys = match sorted {
            Sorted::Primary => &b.keys_alt,
            Sorted::Alternate => &b.keys,
        };
        ctx.submit_and_wait(|cmd| {
            let cn = u64::from(cand_n);
            recorder::copy(&ctx, cmd, &b.out_vals, &new_geo, 0, 0, u * 4);
            if let Some(gm) = new_geo_mom.as_ref() {
                recorder::copy(&ctx, cmd, &b.out_vals, &gm[0], cn * 4, 0, u * 4);
                recorder::copy(&ctx, cmd, &b.out_vals, &gm[1], 2 * cn * 4, 0, u * 4);
            }
            recorder::copy(&ctx, cmd, &b.corners, &new_corners, 0, 0, cn * 4);
            recorder::copy(&ctx, cmd, free_keys, readback, 0, 0, u * 8);
            recorder::copy(&ctx, cmd, &b.corners, readback, 0, off_corners, cn * 4);
            Ok(())
        })?;
        let bytes = readback
            .mapped()
            .ok_or_else(|| Error::Gpu("topology read-back is not host-visible".into()))?;
        let range = |off: u64, len: u64| &bytes[off as usize..(off + len) as usize];
        let grid_keys: Vec<u64> = bytemuck::pod_collect_to_vec(range(0, u * 8));
        let corners: Vec<[u32; 8]> =
            bytemuck::pod_collect_to_vec(range(off_corners, u64::from(cand_n) * 4));
        let max_level = finest;
        let out = Scene {
            center: host.center,
            extent: host.extent,
            sh_degree: host.sh_degree,
            background: host.background,
            background_frame_mean: host.background_frame_mean,
            supersample: host.supersample,
            world: host.world,
            octpath,
            octlevel,
            grid_keys,
            geo: vec![0.0; unique],
            corners,
            sh0: vec![[0.0; 3]; new_n],
            shs: vec![0.0; new_n * nc],
        };
        let scene = SceneGpu {
            octpath: new_octpath,
            level: new_level,
            corners: new_corners,
            geo: new_geo,
            sh0: new_sh0,
            shs: new_shs,
            voxels: new_n as u32,
            grid_points: unique as u32,
            max_level,
            sh_degree: gpu.sh_degree,
            shs_per_voxel: gpu.shs_per_voxel,
            center: gpu.center,
            extent: gpu.extent,
            background: gpu.background,
            background_frame_mean: gpu.background_frame_mean,
        };
        let moments = match (new_geo_mom, new_sh_mom) {
            (Some([gm, gv]), Some([sm, sv, hm, hv])) => Some([gm, gv, sm, sv, hm, hv]),
            _ => None,
        };
        let t3 = Instant::now();
        let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
        let gpu_stages = self.timestamps.stages()?;
        self.stats = TopologyStats {
            voxels_in: n,
            voxels_out: new_n,
            grid_points_in: g,
            grid_points_out: unique,
            candidates: cand_n as usize,
            sort_bits,
            prepare_ms: ms(t0, t1),
            gpu_ms: ms(t1, t2),
            finish_ms: ms(t2, t3),
            total_ms: ms(t0, t3),
            gpu_stages,
        };
        Ok(Changed {
            scene,
            moments,
            host: out,
        })
    }
}

/// The device scene must be the host layout; moment buffers large enough. Returns
/// (voxels, grid points, SH values per voxel).
fn check_device_input(
    host: &Scene,
    gpu: &SceneGpu,
    moments: Option<DeviceMoments>,
    keep: &[bool],
    split: &[bool],
) -> Result<(usize, usize, usize)> {
    let n = host.num_voxels();
    let g = host.num_grid_points();
    check_input(host, None, keep, split)?;
    let nc = host.shs_per_voxel() * 3;
    if (n as u64) * (nc.max(3) as u64) > u64::from(u32::MAX) {
        return Err(Error::Capacity(format!(
            "{n} voxels with {nc} SH values each exceed the SH copy's u32 index"
        )));
    }
    if gpu.voxels as usize != n
        || gpu.grid_points as usize != g
        || gpu.shs_per_voxel as usize * 3 != nc
    {
        return Err(Error::Invalid(format!(
            "topology: the device scene ({} voxels, {} grid points) is not the host \
             layout ({n} voxels, {g} grid points)",
            gpu.voxels, gpu.grid_points
        )));
    }
    if let Some(m) = moments {
        let sh = shs_device_len(n, nc);
        let need = [g, g, 3 * n, 3 * n, sh, sh];
        if let Some(k) = (0..6).find(|&k| m[k].size() < need[k] as u64 * 4) {
            return Err(Error::Invalid(format!(
                "topology: moment buffer {k} holds {} bytes, the scene needs {}",
                m[k].size(),
                need[k] * 4
            )));
        }
    }

    Ok((n, g, nc))
}

impl NewLayout {
    /// Step 1: the kept voxels, each split one into its 8 children, with the checks of
    /// the sizes the dedup and the SH copy index in u32.
    fn build(
        host: &Scene,
        keep: &[bool],
        split: &[bool],
        moments: bool,
        nc: usize,
    ) -> Result<NewLayout> {
        let n = host.num_voxels();
        if n == 0 {
            return Err(Error::Invalid("the scene has no voxels to change".into()));
        }
        let new_n: usize = (0..n)
            .filter(|&i| keep[i])
            .map(|i| if split[i] { 8 } else { 1 })
            .sum();
        if new_n == 0 {
            return Err(Error::Invalid(
                "every voxel was pruned: the result would be an empty scene".into(),
            ));
        }
        if new_n > MAX_VOXELS {
            return Err(Error::Capacity(format!(
                "the change makes {new_n} voxels, more than the supported {MAX_VOXELS}"
            )));
        }
        // Candidate values are indexed `candidate · planes + plane` in u32 (and the sort
        // and scan count in u32): at most ~178 M voxels with moments, ~536 M without;
        // the SH gather indexes `voxel · 3·coefficients` in u32.
        let planes: u32 = if moments { 3 } else { 1 };
        let cand_n = u32::try_from(new_n * 8)
            .ok()
            .filter(|&c| {
                c <= RadixSort::MAX_CAPACITY.min(u32::MAX - SCAN_TILE)
                    && u64::from(c) * u64::from(planes) <= u64::from(u32::MAX)
                    && (new_n as u64) * (nc.max(3) as u64) <= u64::from(u32::MAX)
            })
            .ok_or_else(|| {
                Error::Capacity(format!(
                    "{new_n} voxels after the change are too many for the grid-point dedup \
                     and the SH copy (at most {} {} moments, and {} at {} SH values per \
                     voxel)",
                    u32::MAX / 8 / planes,
                    if moments { "with" } else { "without" },
                    u32::MAX as usize / nc.max(3),
                    nc.max(3)
                ))
            })?;
        let mut octpath = Vec::with_capacity(new_n);
        let mut octlevel = Vec::with_capacity(new_n);
        let mut info = Vec::with_capacity(new_n);
        let mut src: Vec<u32> = Vec::with_capacity(new_n);
        for i in 0..n {
            if !keep[i] {
                continue;
            }
            let level = u32::from(host.octlevel[i]);
            let copies = if split[i] { 8 } else { 1 };
            for c in 0..copies {
                if split[i] {
                    octpath.push(host.octpath[i] | (c as u64) << (3 * (MAX_LEVEL - level - 1)));
                    octlevel.push((level + 1) as u8);
                    info.push((level + 1) | 1 << 8 | (c as u32) << 9);
                } else {
                    octpath.push(host.octpath[i]);
                    octlevel.push(level as u8);
                    info.push(level);
                }
                src.push(i as u32);
            }
        }
        let level32: Vec<u32> = octlevel.iter().map(|&l| u32::from(l)).collect();
        let finest = level32.iter().copied().max().unwrap_or(1);
        let shift = MAX_LEVEL - finest;
        let bits = finest + 1;
        let sort_bits = 3 * bits;

        Ok(NewLayout {
            new_n,
            cand_n,
            planes,
            octpath,
            octlevel,
            info,
            src,
            level32,
            finest,
            shift,
            bits,
            sort_bits,
        })
    }
}
