//! Topology change of a scene (paper §3.2.2): prune voxels, subdivide voxels into their
//! 8 children, and rebuild the grid points with a GPU dedup — on the device:
//! [`Topology::apply_device`] takes the scene's device buffers (and Adam moments) with
//! per-voxel `keep` / `split` masks and returns new device buffers. Densities, SH
//! coefficients and moments never leave the device; [`Topology::apply`] is the same
//! change for a host [`Scene`] (upload, apply_device, download).
//!
//! 1. **Host, O(N), structure only**: the new voxel list. Survivors keep their relative
//!    order; a split voxel is replaced, in place, by its 8 children in child order
//!    `x<<2 | y<<1 | z` (child `c` has octpath `parent | c << 3·(16 − level − 1)`, i.e.
//!    Morton order, the same order as the corners). Uploaded: octpath, level, and the
//!    source voxel of every new voxel (20 bytes per voxel). A `split` flag on a pruned
//!    voxel is ignored.
//!    **GPU** (`glsl/adapt/gather_rows.comp`): every new voxel copies its source
//!    voxel's SH (sh0 and shs) and SH Adam moments.
//! 2. **GPU** (`glsl/adapt/topology_candidates.comp`, thread per new voxel): 8 candidate
//!    grid points per voxel, candidate `8·voxel + corner`: the corner's key and its
//!    density — the voxel's own grid-point value, or for a child the parent's trilinear
//!    interpolation at that corner (exactly the parent's value at the parent's own
//!    corners) — and likewise for the geo Adam moments.
//! 3. **GPU sort**: (key, candidate index) pairs by key with [`RadixSort`]. The key is
//!    the 51-bit grid key `x<<34 | y<<17 | z` compacted to the bits in use: at finest
//!    level L every coordinate is a multiple of 2^(16−L) and at most 2^L, so
//!    `x'<<2b | y'<<b | z'` with `c' = c >> (16−L)`, `b = L + 1` has the same order in
//!    3·(L+1) bits (51 bits at L = 16; 21 instead of 51 for a level-6 scene, 3 digit
//!    passes instead of 7). The sort is stable, so a run lists its candidates by index.
//! 4. **GPU dedup** (`dedup_heads.comp` → [`PrefixScan`](crate::scan::PrefixScan) → `dedup_merge.comp`): run
//!    heads, their exclusive scan (the unique count is the scan total), then thread per
//!    sorted candidate `uid = scan[i] + head[i] − 1`; every thread writes its voxel
//!    corner `corners[candidate] = uid`, the head of a run writes the unique full key
//!    and the mean of the run's values (`v0 + Σ(vj − v0)/count`: a run of equal values
//!    keeps its value bit for bit). Voxels around a point are disjoint, so a run is at
//!    most 8 long; a longer one is reported as an error. (A variant splitting the merge
//!    into a scatter to key order and a thread-per-unique-point mean measured the same
//!    on lavapipe and needs one more kernel.)
//! 5. Read-back of the unique count; the unique densities (and geo moments) and the
//!    corner indices are copied into the new scene's buffers on the device, and only
//!    the structure (grid keys, corner indices) is read back for the host layout.
//!    Grid points that are a corner of no surviving voxel never become candidates, so
//!    they disappear.
//!
//! Every kernel takes its arrays by device address (no 128 MiB descriptor limit), loops
//! at most 16 times per invocation, and dispatches in 2-D grids. Buffers, the sort and
//! the scan are kept and grown (×1.25) across calls.
//!
//! Pruning every voxel is an error: an empty scene cannot be rendered or trained, and
//! a caller that wants to start over should say so explicitly.

use std::time::Instant;

use crate::error::{Error, Result};
use crate::gpu::{kernels, recorder, Buffer, Context, GrowBuffer, Kernel, Memory, Timestamps};
use crate::scan::SCAN_TILE;
use crate::scene::{
    download_shs, shs_device_len, shs_to_device, Scene, SceneGpu, MAX_LEVEL, MAX_VOXELS,
};
use crate::sort::{Count, RadixSort, SortBuffers, Sorted};

mod gpu;
use gpu::*;

/// Adam moments aligned with a scene's parameters: [geo m, geo v, sh0 m, sh0 v, shs m,
/// shs v], each laid out exactly like the parameter it belongs to (geo per grid point,
/// `sh0 [N][3]`, `shs [N][coeffs][3]`).
pub type Moments = Vec<Vec<f32>>;

/// Sizes and host wall-clock times of the last [`Topology::apply`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TopologyStats {
    pub voxels_in: usize,
    pub voxels_out: usize,
    pub grid_points_in: usize,
    pub grid_points_out: usize,
    /// Candidate grid points sorted (8 per new voxel).
    pub candidates: usize,
    /// Key bits sorted (3·(finest level + 1)).
    pub sort_bits: u32,
    /// Building the voxel arrays and filling the upload buffer.
    pub prepare_ms: f64,
    /// Upload, candidates, sort, dedup (one submission, waited for).
    pub gpu_ms: f64,
    /// Error checks, read-back and assembly of the result.
    pub finish_ms: f64,
    pub total_ms: f64,
    /// GPU time per stage in milliseconds (timestamps), in order: upload, candidates,
    /// sort stages, heads, scan, merge.
    pub gpu_stages: Vec<(String, f64)>,
}

/// Adam moments of a scene on the device, laid out like [`Moments`]: [geo m, geo v,
/// sh0 m, sh0 v, shs m, shs v], except that the SH moments (like the SH coefficients)
/// are in the blocked device layout ([`crate::scene::SHS_BLOCK`]).
pub type DeviceMoments<'a> = [&'a Buffer; 6];

/// The result of [`Topology::apply_device`].
pub struct Changed {
    /// The new scene's device buffers (active SH degree carried over).
    pub scene: SceneGpu,
    /// The moments carried to the new layout, when moments were given.
    pub moments: Option<[Buffer; 6]>,
    /// The new layout on the host: octpaths, levels, grid keys and corners exact; the
    /// parameters (geo, sh0, shs) are zeros of the right sizes — the device holds them
    /// ([`SceneGpu::download_params`] fills them in).
    pub host: Scene,
}

/// Prune + subdivide with the grid points rebuilt on the GPU. See the module docs.
pub struct Topology {
    ctx: Context,
    candidates: Kernel,
    heads: Kernel,
    merge: Kernel,
    gather: Kernel,
    /// [0] unique count (scan total), [1] flags.
    counters: Buffer,
    bufs: Option<CandidateBuffers>,
    staging: GrowBuffer,
    input: GrowBuffer,
    readback: GrowBuffer,
    timestamps: Timestamps,
    stats: TopologyStats,
}

impl Topology {
    pub fn new(ctx: &Context) -> Result<Topology> {
        Ok(Topology {
            ctx: ctx.clone(),
            candidates: Kernel::new(ctx, &kernels::ADAPT_TOPOLOGY_CANDIDATES)?,
            heads: Kernel::new(ctx, &kernels::ADAPT_DEDUP_HEADS)?,
            merge: Kernel::new(ctx, &kernels::ADAPT_DEDUP_MERGE)?,
            gather: Kernel::new(ctx, &kernels::ADAPT_GATHER_ROWS)?,
            counters: ctx.buffer("topology.counters", 16, Memory::Device)?,
            bufs: None,
            staging: GrowBuffer::with_memory("topology.staging", Memory::Upload),
            input: GrowBuffer::new("topology.input"),
            readback: GrowBuffer::with_memory("topology.readback", Memory::Readback),
            timestamps: Timestamps::new(ctx, 32)?,
            stats: TopologyStats::default(),
        })
    }

    /// Sizes and times of the last successful [`Topology::apply`].
    pub fn last_stats(&self) -> &TopologyStats {
        &self.stats
    }

    /// The scene after removing every voxel with `keep[i] == false` and replacing every
    /// kept voxel with `split[i] == true` by its 8 children (level + 1; error if a split
    /// voxel is at level 16). Children copy the parent's SH (sh0 and shs); every child
    /// corner's density is the parent's trilinear interpolation at that corner (so at
    /// the parent's own corners it is exactly the parent's value). Grid points are
    /// rebuilt from the surviving voxels' corners on the GPU (sort of the candidate keys
    /// with [`RadixSort`], duplicates averaged), and each voxel's corner indices come
    /// from that merge. Grid points no longer a corner of any voxel disappear.
    ///
    /// `moments`, when given, are carried like the parameters they belong to (pruned
    /// with their voxel, copied to children, geo moments interpolated and averaged
    /// exactly like geo).
    ///
    /// Voxel order of the result: survivors keep their relative order; the children of
    /// a split voxel take 8 consecutive slots where the parent was, in child order
    /// `x<<2 | y<<1 | z` (Morton order). `split` on a pruned voxel is ignored.
    ///
    /// The input must pass [`Scene::validate`] (checked here), so the result does too.
    /// Pruning every voxel is an error (an empty scene cannot be rendered or trained).
    ///
    /// Host in, host out: uploads the scene, runs [`Topology::apply_device`] and
    /// downloads the result (tests and the initial layout use it; training keeps its
    /// model on the device).
    pub fn apply(
        &mut self,
        scene: &Scene,
        moments: Option<&Moments>,
        keep: &[bool],
        split: &[bool],
    ) -> Result<(Scene, Option<Moments>)> {
        check_input(scene, moments, keep, split)?;
        let ctx = self.ctx.clone();
        let gpu = SceneGpu::upload(&ctx, scene)?;
        let mom_bufs = match moments {
            None => None,
            Some(m) => {
                let mut v = Vec::with_capacity(6);
                let (n, w) = (scene.num_voxels(), scene.shs_per_voxel() * 3);
                for (k, data) in m.iter().enumerate() {
                    let name = format!("topology.moments{k}");
                    v.push(if data.is_empty() {
                        ctx.zeroed_buffer(&name, 4)?
                    } else if k >= 4 {
                        // The SH moments in the blocked device layout.
                        ctx.buffer_from(&name, &shs_to_device(data, n, w))?
                    } else {
                        ctx.buffer_from(&name, data)?
                    });
                }
                Some(v)
            }
        };
        let refs: Option<DeviceMoments> = mom_bufs.as_ref().map(|v| std::array::from_fn(|k| &v[k]));
        let changed = self.apply_device(scene, &gpu, refs, keep, split)?;
        drop(mom_bufs);
        drop(gpu);
        let mut out = changed.host;
        changed.scene.download_params(&ctx, &mut out)?;
        let new_moments = match changed.moments {
            None => None,
            Some(b) => {
                let g = out.num_grid_points();
                let n = out.num_voxels();
                let nc = out.shs_per_voxel() * 3;
                let lens = [g, g, 3 * n, 3 * n, n * nc, n * nc];
                let mut v = Vec::with_capacity(6);
                for (k, (buf, len)) in b.iter().zip(lens).enumerate() {
                    v.push(if len == 0 {
                        Vec::new()
                    } else if k >= 4 {
                        download_shs(&ctx, buf, n, nc)?
                    } else {
                        ctx.download(buf, 0, len)?
                    });
                }
                Some(v)
            }
        };
        Ok((out, new_moments))
    }

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

        // 1. The new voxels' structure (host, O(N)).
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
        let planes: u32 = if moments.is_some() { 3 } else { 1 };
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
                    if moments.is_some() { "with" } else { "without" },
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
            write_bytes(dst, layout.path, bytemuck::cast_slice(&octpath));
            write_bytes(dst, layout.info, bytemuck::cast_slice(&info));
            write_bytes(dst, layout.src, bytemuck::cast_slice(&src));
            write_bytes(dst, layout.level, bytemuck::cast_slice(&level32));
        }
        drop(info);
        drop(src);
        drop(level32);
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
            None => None,
            Some(_) => {
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
        let t1 = Instant::now();

        // 2.-4. One submission: upload, candidates, SH gather, sort, dedup.
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
            let mut rows = vec![(&gpu.sh0, &new_sh0, 3u32, 0u32)];
            if nc > 0 {
                rows.push((&gpu.shs, &new_shs, nc as u32, 1));
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
            recorder::copy(&ctx, cmd, input, &new_octpath, layout.path, 0, nn * 8);
            recorder::copy(&ctx, cmd, input, &new_level, layout.level, 0, nn * 4);
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
        let t2 = Instant::now();

        // 5. Errors and the unique count; the grid-point buffers; structure read-back.
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
            None => None,
            Some(_) => Some([
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

/// The scene must validate (≈ 17 ms for 350 k voxels on the development machine, 2 %
/// of the change; it makes the result valid too); masks and moments must match it and
/// no kept voxel at level 16 may be split.
fn check_input(
    scene: &Scene,
    moments: Option<&Moments>,
    keep: &[bool],
    split: &[bool],
) -> Result<()> {
    scene.validate()?;
    let n = scene.num_voxels();
    let g = scene.num_grid_points();
    let nc = scene.shs_per_voxel() * 3;
    let bad = |m: String| Err(Error::Invalid(m));
    if keep.len() != n || split.len() != n {
        return bad(format!(
            "topology masks: keep has {} and split {} entries for {n} voxels",
            keep.len(),
            split.len()
        ));
    }
    if g > u32::MAX as usize / 3 {
        return bad(format!("{g} grid points are too many"));
    }
    if let Some(i) =
        (0..n).find(|&i| keep[i] && split[i] && u32::from(scene.octlevel[i]) >= MAX_LEVEL)
    {
        return bad(format!(
            "voxel {i} is at the finest level {MAX_LEVEL} and cannot be subdivided"
        ));
    }
    if let Some(m) = moments {
        let expect = [g, g, 3 * n, 3 * n, n * nc, n * nc];
        let got: Vec<usize> = m.iter().map(|v| v.len()).collect();
        if got != expect {
            return bad(format!(
                "moments must be [geo m, geo v, sh0 m, sh0 v, shs m, shs v] with lengths \
                 {expect:?}, got {got:?}"
            ));
        }
    }
    Ok(())
}
