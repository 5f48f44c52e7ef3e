//! The sparse-voxel model (paper §3.1.1, supp. A.1).
//!
//! Voxels are leaves of an octree *layout* without any tree structure: each voxel is an
//! `(octpath, level)` pair stored in a flat array in arbitrary order. `octpath` is the
//! Morton code of the paper's Listing 1: 3 bits per level (`x<<2 | y<<1 | z`), level 1
//! in the top three bits of 48, levels below the voxel's own level zero.
//!
//! Densities live on *grid points*: the unique voxel corners, keyed by their integer
//! coordinates at the finest level (`x<<34 | y<<17 | z`, each coordinate 0..=65536).
//! Adjacent voxels share corners, which makes the density field continuous. The grid
//! points are kept sorted by key, and each voxel resolves its 8 corners (corner order
//! `x<<2 | y<<1 | z`) to indices into that array. Nothing here is dense in 3-D: memory
//! follows the number of voxels.

pub mod checkpoint;
mod device;
pub mod quantize;
pub mod svraster;
pub use device::SceneGpu;
pub(crate) use device::{download_shs, upload_shs};

use crate::error::{Error, Result};

/// Deepest octree level (finest grid 65536³).
pub const MAX_LEVEL: u32 = crate::gpu::glsl::MAX_LEVEL;
/// Grid-point coordinates at the finest level run over `0..=GRID_MAX`.
pub const GRID_MAX: u32 = 1 << MAX_LEVEL;
/// Highest supported SH degree.
pub const MAX_SH_DEGREE: u32 = 3;

/// Number of SH coefficients (per colour channel) of degree `d`: `(d+1)²`.
pub fn sh_coeffs(degree: u32) -> usize {
    ((degree + 1) * (degree + 1)) as usize
}

/// Voxels per block of the device layout of the higher-order SH coefficients (and their
/// gradients and Adam moments). The host keeps `shs` per voxel (`[N][coeffs][3]`); on the
/// device, value `e` (0..w, w = 3·coeffs) of voxel `v` sits at
/// `(v / 8)·8w + 8e + v % 8` ([`shs_device_index`]): the 8 voxels of a block interleave
/// their values, so a kernel with a thread per voxel reads and writes whole cache lines
/// across a subgroup instead of a 180-byte stride per lane (lavapipe turns each such
/// access into a gather that touches 8 lines: preprocess and the per-voxel backward
/// spent about a third of their time there). The buffers hold [`shs_device_len`]
/// values: the last block is padded with zeros, which the kernels never read and Adam
/// leaves at zero (their gradient stays zero).
pub const SHS_BLOCK: usize = 8;

/// Index of value `e` of voxel `v` in the device layout of `w` values per voxel
/// (glsl/lib/sh.glsl `shs_index`).
pub fn shs_device_index(v: usize, e: usize, w: usize) -> usize {
    (v / SHS_BLOCK) * SHS_BLOCK * w + SHS_BLOCK * e + v % SHS_BLOCK
}

/// Values in the device layout of `n` voxels with `w` values each (whole blocks).
pub fn shs_device_len(n: usize, w: usize) -> usize {
    n.div_ceil(SHS_BLOCK) * SHS_BLOCK * w
}

/// Per-voxel values (`n` voxels × `w`) in the device layout (zero padding).
pub fn shs_to_device(host: &[f32], n: usize, w: usize) -> Vec<f32> {
    assert_eq!(host.len(), n * w, "shs_to_device: {n} voxels of {w} values");
    let mut out = vec![0.0; shs_device_len(n, w)];
    for v in 0..n {
        for e in 0..w {
            out[shs_device_index(v, e, w)] = host[v * w + e];
        }
    }
    out
}

/// The per-voxel values of `n` voxels × `w` from the device layout.
pub fn shs_from_device(dev: &[f32], n: usize, w: usize) -> Vec<f32> {
    assert!(
        dev.len() >= shs_device_len(n, w),
        "shs_from_device: short buffer"
    );
    let mut out = vec![0.0; n * w];
    for v in 0..n {
        for e in 0..w {
            out[v * w + e] = dev[shs_device_index(v, e, w)];
        }
    }
    out
}

/// Morton code of voxel index `(i, j, k)` at `level` (paper Listing 1).
pub fn octpath_from_ijk(ijk: [u32; 3], level: u32) -> u64 {
    debug_assert!((1..=MAX_LEVEL).contains(&level));
    let mut path = 0u64;
    for n in 0..level {
        let bits =
            (((ijk[0] >> n) & 1) << 2 | ((ijk[1] >> n) & 1) << 1 | ((ijk[2] >> n) & 1)) as u64;
        path |= bits << (3 * n);
    }
    path << (3 * (MAX_LEVEL - level))
}

/// Voxel index `(i, j, k)` at `level` of a Morton code (inverse of [`octpath_from_ijk`]).
pub fn ijk_from_octpath(path: u64, level: u32) -> [u32; 3] {
    let mut p = path >> (3 * (MAX_LEVEL - level));
    let mut ijk = [0u32; 3];
    for n in 0..level {
        ijk[0] |= (((p >> 2) & 1) as u32) << n;
        ijk[1] |= (((p >> 1) & 1) as u32) << n;
        ijk[2] |= ((p & 1) as u32) << n;
        p >>= 3;
    }
    ijk
}

/// Key of a grid point from integer coordinates at the finest level (each 0..=65536).
pub fn corner_key(c: [u32; 3]) -> u64 {
    (c[0] as u64) << 34 | (c[1] as u64) << 17 | c[2] as u64
}

/// Coordinates of a grid-point key (inverse of [`corner_key`]).
pub fn key_coords(key: u64) -> [u32; 3] {
    let m = (1u64 << 17) - 1;
    [
        ((key >> 34) & m) as u32,
        ((key >> 17) & m) as u32,
        (key & m) as u32,
    ]
}

/// Integer coordinates (finest level) of a voxel's minimum corner, and its edge length
/// in finest-level units.
pub fn voxel_fine_box(path: u64, level: u32) -> ([u32; 3], u32) {
    let ijk = ijk_from_octpath(path, level);
    let shift = MAX_LEVEL - level;
    (
        [ijk[0] << shift, ijk[1] << shift, ijk[2] << shift],
        1 << shift,
    )
}

/// The 8 grid-point keys of a voxel, in corner order `x<<2 | y<<1 | z`.
pub fn voxel_corner_keys(path: u64, level: u32) -> [u64; 8] {
    let (o, s) = voxel_fine_box(path, level);
    std::array::from_fn(|c| {
        corner_key([
            o[0] + s * ((c as u32 >> 2) & 1),
            o[1] + s * ((c as u32 >> 1) & 1),
            o[2] + s * (c as u32 & 1),
        ])
    })
}

/// The similarity from a capture's world coordinates to the model's: `model = (world −
/// center) / scale` (rotation-free). Real captures are trained in a frame where the main
/// region is `[-1, 1]³`, so COLMAP's arbitrary world scale does not change how densities,
/// step lengths and the near plane act; synthetic scenes use the identity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WorldFrame {
    pub center: [f64; 3],
    pub scale: f64,
}

impl WorldFrame {
    pub const IDENTITY: WorldFrame = WorldFrame {
        center: [0.0; 3],
        scale: 1.0,
    };

    pub fn is_identity(&self) -> bool {
        *self == WorldFrame::IDENTITY
    }

    /// A world point in model coordinates.
    pub fn point_to_model(&self, p: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|a| (p[a] - self.center[a]) / self.scale)
    }

    /// A model point in world coordinates (inverse of [`WorldFrame::point_to_model`]).
    pub fn point_to_world(&self, p: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|a| p[a] * self.scale + self.center[a])
    }

    /// A world camera in model coordinates (same rotation, intrinsics and near plane in
    /// model units).
    pub fn camera_to_model(&self, cam: &crate::camera::Camera) -> crate::camera::Camera {
        if self.is_identity() {
            return cam.clone();
        }
        let mut c = cam.clone();
        let t = self.point_to_model(cam.origin());
        for (row, t) in c.c2w.iter_mut().zip(t) {
            row[3] = t;
        }
        c
    }

    /// A model-space length (e.g. a depth) in world units.
    pub fn length_to_world(&self, d: f64) -> f64 {
        d * self.scale
    }

    /// Checks the frame is usable.
    pub fn validate(&self) -> Result<()> {
        if !(self.scale.is_finite() && self.scale > 0.0)
            || self.center.iter().any(|v| !v.is_finite())
        {
            return Err(Error::Invalid(format!(
                "world frame: centre {:?} and scale {} must be finite, scale > 0",
                self.center, self.scale
            )));
        }
        Ok(())
    }
}

/// A sparse-voxel radiance field.
#[derive(Clone, Debug, PartialEq)]
pub struct Scene {
    /// Centre of the root cube in world space.
    pub center: [f32; 3],
    /// Full edge length of the root cube.
    pub extent: f32,
    /// SH degree 0..=3.
    pub sh_degree: u32,
    /// Background colour composited behind the voxels.
    pub background: [f32; 3],
    /// Composite each frame's own mean colour behind the voxels instead of `background`:
    /// out = C + T·mean(C), the mean of the premultiplied colour C = Σ w c over the frame
    /// at render resolution, recomputed every frame and differentiated through in
    /// training. SVRaster's background for scenes that are neither white nor black (its
    /// mip-NeRF 360 configuration, renderer.py). Host frames and field renders have no
    /// background either way.
    pub background_frame_mean: bool,
    /// Supersampling the model renders at by default (1 = none): the training run's `ss`.
    /// A model trained on supersampled, downsampled frames (the paper's h_ss = 1.5) is
    /// fitted to that anti-aliased image formation, and renders it best the same way.
    pub supersample: f32,
    /// Where the model sits in its capture's world (cameras are mapped into the model's
    /// frame before rendering).
    pub world: WorldFrame,
    /// Per voxel: Morton code (Listing 1).
    pub octpath: Vec<u64>,
    /// Per voxel: octree level 1..=16.
    pub octlevel: Vec<u8>,
    /// Unique grid-point keys, strictly ascending.
    pub grid_keys: Vec<u64>,
    /// Raw density per grid point (activation `explin` applies after interpolation).
    pub geo: Vec<f32>,
    /// Per voxel: indices of its 8 corners into `grid_keys`/`geo` (derived data).
    pub corners: Vec<[u32; 8]>,
    /// Per voxel: degree-0 SH coefficient per channel.
    pub sh0: Vec<[f32; 3]>,
    /// Per voxel: higher-degree SH, `[N][(D+1)²−1][3]` flattened.
    pub shs: Vec<f32>,
}

impl Scene {
    /// Builds a scene from voxels: creates the unique grid points (density `geo_init`)
    /// and resolves corners; SH start at zero. Validates the voxel set.
    pub fn from_voxels(
        center: [f32; 3],
        extent: f32,
        sh_degree: u32,
        octpath: Vec<u64>,
        octlevel: Vec<u8>,
        geo_init: f32,
    ) -> Result<Scene> {
        if octpath.len() != octlevel.len() {
            return Err(Error::Invalid(format!(
                "{} octpaths but {} levels",
                octpath.len(),
                octlevel.len()
            )));
        }
        check_voxels(&octpath, &octlevel)?;
        let mut keys: Vec<u64> = Vec::with_capacity(octpath.len() * 2);
        for (&p, &l) in octpath.iter().zip(&octlevel) {
            keys.extend_from_slice(&voxel_corner_keys(p, l as u32));
        }
        keys.sort_unstable();
        keys.dedup();
        let n = octpath.len();
        let coeffs = sh_coeffs(sh_degree.min(MAX_SH_DEGREE)) - 1;
        let mut scene = Scene {
            center,
            extent,
            sh_degree,
            background: [0.0; 3],
            background_frame_mean: false,
            supersample: 1.0,
            world: WorldFrame::IDENTITY,
            geo: vec![geo_init; keys.len()],
            grid_keys: keys,
            corners: Vec::new(),
            octpath,
            octlevel,
            sh0: vec![[0.0; 3]; n],
            shs: vec![0.0; n * coeffs * 3],
        };
        scene.resolve_corners()?;
        scene.validate_arrays()?;
        Ok(scene)
    }

    pub fn num_voxels(&self) -> usize {
        self.octpath.len()
    }

    pub fn num_grid_points(&self) -> usize {
        self.grid_keys.len()
    }

    /// Deepest level in use (0 for an empty scene).
    pub fn max_level(&self) -> u32 {
        self.octlevel.iter().copied().max().unwrap_or(0) as u32
    }

    /// Higher-degree SH coefficients per voxel and channel.
    pub fn shs_per_voxel(&self) -> usize {
        sh_coeffs(self.sh_degree) - 1
    }

    /// Edge length of voxel `i` in world units.
    pub fn voxel_size(&self, i: usize) -> f64 {
        self.extent as f64 * (0.5f64).powi(self.octlevel[i] as i32)
    }

    /// Minimum corner of voxel `i` in world units.
    pub fn voxel_min(&self, i: usize) -> [f64; 3] {
        let (o, _) = voxel_fine_box(self.octpath[i], self.octlevel[i] as u32);
        self.fine_to_world(o)
    }

    /// Centre of voxel `i` in world units.
    pub fn voxel_center(&self, i: usize) -> [f64; 3] {
        let m = self.voxel_min(i);
        let h = 0.5 * self.voxel_size(i);
        [m[0] + h, m[1] + h, m[2] + h]
    }

    /// Number of voxels whose centre lies in the cube of edge `extent` around `center`
    /// (with background shells, the main region's voxels: shell voxels never straddle
    /// the main region, an octree node of the root).
    pub fn voxels_inside(&self, center: [f32; 3], extent: f32) -> usize {
        let h = 0.5 * extent as f64;
        (0..self.num_voxels())
            .filter(|&i| {
                let c = self.voxel_center(i);
                (0..3).all(|a| (c[a] - center[a] as f64).abs() < h)
            })
            .count()
    }

    /// World position of integer finest-level coordinates.
    pub fn fine_to_world(&self, c: [u32; 3]) -> [f64; 3] {
        let unit = self.extent as f64 / GRID_MAX as f64;
        std::array::from_fn(|a| {
            self.center[a] as f64 - 0.5 * self.extent as f64 + c[a] as f64 * unit
        })
    }

    /// Resolves every voxel's 8 corner keys to grid-point indices.
    pub fn resolve_corners(&mut self) -> Result<()> {
        let mut corners = Vec::with_capacity(self.octpath.len());
        for (i, (&p, &l)) in self.octpath.iter().zip(&self.octlevel).enumerate() {
            let keys = voxel_corner_keys(p, l as u32);
            let mut idx = [0u32; 8];
            for c in 0..8 {
                idx[c] = self.grid_keys.binary_search(&keys[c]).map_err(|_| {
                    Error::Invalid(format!(
                        "voxel {i}: corner {c} (grid key {:#x}) is not among the grid points",
                        keys[c]
                    ))
                })? as u32;
            }
            corners.push(idx);
        }
        self.corners = corners;
        Ok(())
    }

    /// Checks every invariant of the model; the error names the first problem found.
    pub fn validate(&self) -> Result<()> {
        self.check(true)
    }

    /// [`Scene::validate`] for a scene whose voxels (levels, path bits, no overlap) were
    /// just checked, e.g. built by [`Scene::from_voxels`]: skips that O(n log n) part.
    pub(crate) fn validate_arrays(&self) -> Result<()> {
        self.check(false)
    }

    fn check(&self, voxels: bool) -> Result<()> {
        let n = self.octpath.len();
        let bad = |m: String| Err(Error::Invalid(m));
        if !self.extent.is_finite() || self.extent <= 0.0 {
            return bad(format!(
                "scene_extent must be finite and > 0, got {}",
                self.extent
            ));
        }
        if self.center.iter().any(|c| !c.is_finite()) {
            return bad(format!("scene_center is not finite: {:?}", self.center));
        }
        if self.background.iter().any(|c| !c.is_finite()) {
            return bad(format!("background is not finite: {:?}", self.background));
        }
        self.world.validate()?;
        if !(1.0..=8.0).contains(&self.supersample) {
            return bad(format!(
                "supersample must be in [1, 8], got {}",
                self.supersample
            ));
        }
        if self.sh_degree > MAX_SH_DEGREE {
            return bad(format!(
                "sh_degree {} is above the supported maximum {MAX_SH_DEGREE}",
                self.sh_degree
            ));
        }
        if self.octlevel.len() != n || self.sh0.len() != n || self.corners.len() != n {
            return bad(format!(
                "per-voxel arrays disagree: octpath {n}, octlevel {}, sh0 {}, corners {}",
                self.octlevel.len(),
                self.sh0.len(),
                self.corners.len()
            ));
        }
        if self.shs.len() != n * self.shs_per_voxel() * 3 {
            return bad(format!(
                "shs has {} values, expected {n} voxels × {} coefficients × 3",
                self.shs.len(),
                self.shs_per_voxel()
            ));
        }
        if self.geo.len() != self.grid_keys.len() {
            return bad(format!(
                "{} grid-point densities for {} grid points",
                self.geo.len(),
                self.grid_keys.len()
            ));
        }
        if n > MAX_VOXELS {
            return bad(format!(
                "{n} voxels: at most {MAX_VOXELS} are supported (29-bit voxel ids)"
            ));
        }
        if voxels {
            check_voxels(&self.octpath, &self.octlevel)?;
        }
        for w in self.grid_keys.windows(2) {
            if w[0] >= w[1] {
                return bad(format!(
                    "grid-point keys are not strictly ascending ({:#x} then {:#x})",
                    w[0], w[1]
                ));
            }
        }
        for &k in &self.grid_keys {
            let c = key_coords(k);
            if k >> 51 != 0 || c.iter().any(|&v| v > GRID_MAX) {
                return bad(format!(
                    "grid-point key {k:#x} has a coordinate outside 0..={GRID_MAX}"
                ));
            }
        }
        let mut used = vec![false; self.grid_keys.len()];
        for i in 0..n {
            let keys = voxel_corner_keys(self.octpath[i], self.octlevel[i] as u32);
            for (c, key) in keys.iter().enumerate() {
                let g = self.corners[i][c] as usize;
                if g >= self.grid_keys.len() || self.grid_keys[g] != *key {
                    return bad(format!(
                        "voxel {i}: corner {c} does not resolve to its grid point"
                    ));
                }
                used[g] = true;
            }
        }
        if let Some(g) = used.iter().position(|u| !u) {
            return bad(format!(
                "grid point {g} (key {:#x}) is a corner of no voxel",
                self.grid_keys[g]
            ));
        }
        if let Some(g) = self.geo.iter().position(|v| !v.is_finite()) {
            return bad(format!("geo_grid_pts[{g}] is not finite ({})", self.geo[g]));
        }
        if let Some(i) = self
            .sh0
            .iter()
            .position(|v| v.iter().any(|x| !x.is_finite()))
        {
            return bad(format!("sh0[{i}] is not finite ({:?})", self.sh0[i]));
        }
        if let Some(i) = self.shs.iter().position(|v| !v.is_finite()) {
            return bad(format!("shs value {i} is not finite ({})", self.shs[i]));
        }
        Ok(())
    }
}

/// Voxel ids travel in 29 bits of the sort value (paper supp. B.1).
pub const MAX_VOXELS: usize = 1 << 29;

/// Levels in range, no bits below the level, no duplicate or overlapping voxels.
fn check_voxels(octpath: &[u64], octlevel: &[u8]) -> Result<()> {
    for (i, (&p, &l)) in octpath.iter().zip(octlevel).enumerate() {
        if !(1..=MAX_LEVEL as u8).contains(&l) {
            return Err(Error::Invalid(format!(
                "octlevel[{i}] is {l}, outside 1..={MAX_LEVEL}"
            )));
        }
        let low = 3 * (MAX_LEVEL - l as u32);
        if p >> 48 != 0 || (low > 0 && p & ((1u64 << low) - 1) != 0) {
            return Err(Error::Invalid(format!(
                "octpath[{i}] = {p:#x} has bits outside the path of its level {l} (3 bits per \
                 level from bit 47 down)"
            )));
        }
    }
    // Sorted by path, a voxel overlapping another is overlapped by its successor:
    // a voxel's descendants form one contiguous range of paths starting at its own.
    let mut order: Vec<usize> = (0..octpath.len()).collect();
    order.sort_unstable_by_key(|&i| (octpath[i], octlevel[i]));
    for w in order.windows(2) {
        let (a, b) = (w[0], w[1]);
        let span = 1u64 << (3 * (MAX_LEVEL - octlevel[a] as u32));
        if octpath[b] < octpath[a] + span {
            return Err(Error::Invalid(format!(
                "voxels {a} (level {}) and {b} (level {}) overlap or are duplicates",
                octlevel[a], octlevel[b]
            )));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The device layout is a bijection onto the padded buffer, blocks of 8 voxels
    /// interleaved value by value, and converts back exactly.
    #[test]
    fn shs_device_layout() {
        for (n, w) in [(1, 45), (7, 9), (8, 24), (9, 45), (33, 3)] {
            let host: Vec<f32> = (0..n * w).map(|i| i as f32 + 0.5).collect();
            let dev = shs_to_device(&host, n, w);
            assert_eq!(dev.len(), n.div_ceil(8) * 8 * w);
            let mut seen = vec![false; dev.len()];
            for v in 0..n {
                for e in 0..w {
                    let i = shs_device_index(v, e, w);
                    assert!(!seen[i]);
                    seen[i] = true;
                    assert_eq!(dev[i], host[v * w + e]);
                }
            }
            // Consecutive voxels of a block are consecutive values.
            if n >= 2 {
                assert_eq!(shs_device_index(1, 0, w), shs_device_index(0, 0, w) + 1);
            }
            assert_eq!(dev.iter().filter(|&&x| x == 0.0).count(), dev.len() - n * w);
            assert_eq!(shs_from_device(&dev, n, w), host);
        }
    }
}
