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
//! 3. **GPU sort**: (key, candidate index) pairs by key with [`RadixSort`](crate::sort::RadixSort). The key is
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

use crate::error::{Error, Result};
use crate::gpu::{kernels, Buffer, Context, GrowBuffer, Kernel, Memory, Timestamps};
use crate::scene::{download_shs, shs_to_device, Scene, SceneGpu, MAX_LEVEL};

mod apply;
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
    /// with [`RadixSort`](crate::sort::RadixSort), duplicates averaged), and each voxel's corner indices come
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
