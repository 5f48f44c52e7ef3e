//! The starting layout of unbounded scenes (paper §3.2.1, the reference's
//! `octlayout_inside_uniform` and `octlayout_outside_heuristic`).
//!
//! The root cube is the main region's cube times `2^h` (`h` = `outside_level`). The main
//! region gets a uniform grid of `2^grid_level` voxels per edge (level `h + grid_level`);
//! the background is `h` shells, shell `s` (1..=h) being the cube of half-size
//! `2^(1−s)` (root = 1) minus the cube of half-size `2^−s`, each first cut into the 56
//! level-`s+1` voxels around its inner cube. Shell voxels are then subdivided, the 10 %
//! with the highest sampling rate (Eq. 7: voxel size over the finest pixel footprint at
//! its depth in any training view) at a time, until the background holds `ratio` times
//! as many voxels as the main region, and unseen ones are removed.

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::raster::Renderer;
use crate::scene::{octpath_from_ijk, Scene, MAX_LEVEL};

use super::stats::StatsPass;

/// A voxel by its integer coordinates at its level.
type Cell = ([u32; 3], u32);

/// The main region's uniform grid: level `outside + grid` voxels inside the central
/// cube of half-size `2^−outside` (the whole root for `outside = 0`).
pub fn inside_grid(outside: u32, grid: u32) -> Vec<Cell> {
    let level = outside + grid;
    let c = 1u32 << (level - 1);
    let m = 1u32 << (grid - 1);
    let mut cells = Vec::with_capacity(1usize << (3 * grid));
    for i in c - m..c + m {
        for j in c - m..c + m {
            for k in c - m..c + m {
                cells.push(([i, j, k], level));
            }
        }
    }
    cells
}

/// The 56 voxels of each shell `1..=outside`, at level `shell + 1`.
pub fn initial_shells(outside: u32) -> Vec<Cell> {
    let mut cells = Vec::with_capacity(56 * outside as usize);
    for s in 1..=outside {
        let c = 1u32 << s;
        for i in c - 2..c + 2 {
            for j in c - 2..c + 2 {
                for k in c - 2..c + 2 {
                    let inner = [i, j, k].iter().all(|&v| (c - 1..c + 1).contains(&v));
                    if !inner {
                        cells.push(([i, j, k], s + 1));
                    }
                }
            }
        }
    }
    cells
}

/// A scene of `cells` (parameters at their initial values) for statistics.
pub fn scene_of(center: [f32; 3], extent: f32, cells: &[Cell], geo_init: f32) -> Result<Scene> {
    let mut v: Vec<(u64, u8)> = cells
        .iter()
        .map(|&(ijk, l)| (octpath_from_ijk(ijk, l), l as u8))
        .collect();
    v.sort_unstable();
    let (paths, levels) = v.into_iter().unzip();
    Scene::from_voxels(center, extent, 0, paths, levels, geo_init)
}

/// What [`shell_layout`] did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ShellReport {
    pub rounds: u32,
    pub voxels: usize,
    pub max_level: u32,
}

/// The background voxels: the initial shells, subdivided by sampling rate until there
/// are at least `min_voxels` seen ones (or nothing is left to subdivide below
/// `max_level`), unseen ones removed.
#[allow(clippy::too_many_arguments)]
pub fn shell_layout(
    center: [f32; 3],
    extent: f32,
    outside: u32,
    max_level: u32,
    min_voxels: usize,
    cams: &[Camera],
    renderer: &mut Renderer,
    stats: &mut StatsPass,
) -> Result<(Vec<Cell>, ShellReport)> {
    let max_level = max_level.min(MAX_LEVEL);
    let mut cells = initial_shells(outside);
    let mut report = ShellReport::default();
    loop {
        let scene = scene_of(center, extent, &cells, -10.0)?;
        let rate = stats
            .intervals(renderer, &scene, cams)?
            .sampling_rate(&scene);
        // The scene is in path order: pair each rate with its cell.
        let mut seen: Vec<(Cell, f32)> = scene
            .octpath
            .iter()
            .zip(&scene.octlevel)
            .zip(&rate)
            .filter(|(_, &r)| r > 0.0)
            .map(|((&p, &l), &r)| ((crate::scene::ijk_from_octpath(p, l as u32), l as u32), r))
            .collect();
        let need = (min_voxels as i64 - seen.len() as i64) / 7;
        let need = need.min(seen.len() as i64);
        if need <= 0 {
            cells = seen.into_iter().map(|s| s.0).collect();
            break;
        }
        // Rank by rate among voxels that may still be subdivided; subdivide the `need`
        // best, and of those only the top 10 % of all rates (quantile 0.9, zeros
        // included, as the reference's torch.quantile).
        let masked: Vec<f32> = seen
            .iter()
            .map(|&((_, l), r)| if l < max_level { r } else { 0.0 })
            .collect();
        let mut sorted = masked.clone();
        sorted.sort_by(|a, b| b.total_cmp(a));
        let cut = sorted[need as usize - 1];
        let ranked: Vec<f32> = masked
            .iter()
            .map(|&r| if r >= cut && r > 0.0 { r } else { 0.0 })
            .collect();
        let q = quantile(&ranked, 0.9);
        let split: Vec<bool> = ranked.iter().map(|&r| r > 0.0 && r >= q).collect();
        if !split.contains(&true) {
            cells = seen.into_iter().map(|s| s.0).collect();
            break;
        }
        let mut next = Vec::with_capacity(seen.len() + 7 * need as usize);
        for (((ijk, l), _), s) in seen.drain(..).zip(&split) {
            if *s {
                for b in 0..8u32 {
                    next.push((
                        [
                            2 * ijk[0] + (b >> 2),
                            2 * ijk[1] + ((b >> 1) & 1),
                            2 * ijk[2] + (b & 1),
                        ],
                        l + 1,
                    ));
                }
            } else {
                next.push((ijk, l));
            }
        }
        cells = next;
        report.rounds += 1;
        if report.rounds > 200 {
            return Err(Error::Invalid(
                "background shell layout did not settle in 200 rounds".into(),
            ));
        }
    }
    // The last round's cells are the seen ones of a measured layout, except after a
    // subdivision round that ended the loop by `need <= 0` (handled above: `seen`).
    report.voxels = cells.len();
    report.max_level = cells.iter().map(|c| c.1).max().unwrap_or(0);
    Ok((cells, report))
}

/// Linear-interpolation quantile (numpy/torch default) of `v` at `q` in [0, 1].
pub fn quantile(v: &[f32], q: f64) -> f32 {
    if v.is_empty() {
        return 0.0;
    }
    let mut s = v.to_vec();
    s.sort_by(f32::total_cmp);
    let pos = q * (s.len() - 1) as f64;
    let lo = pos.floor() as usize;
    let hi = pos.ceil() as usize;
    let t = (pos - lo as f64) as f32;
    s[lo] + (s[hi] - s[lo]) * t
}
