//! Adaptive sparse voxels (paper §3.2.2; kernels in glsl/adapt/): the statistics pass
//! (max blend weight per voxel over every training view), the topology change on the
//! device (prune, subdivide, rebuild the shared grid points and carry parameters and
//! optimiser moments), and what an adaptive step reports.

pub mod shells;
pub mod stats;
pub mod topology;

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::raster::Renderer;
use crate::scene::Scene;
use stats::StatsPass;
use topology::Topology;

/// What one adaptive step did (a line of stats.jsonl).
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct AdaptReport {
    /// After this many completed iterations.
    pub iter: u32,
    pub voxels_before: u32,
    /// Max-blend-weight threshold (None: this step did not prune).
    pub prune_below: Option<f32>,
    pub pruned: u32,
    /// Voxels replaced by their 8 children.
    pub subdivided: u32,
    /// Subdivision candidates the budget or the layout's rules left out.
    pub subdivide_skipped: u32,
    pub voxels: u32,
    pub grid_points: u32,
    pub max_level: u32,
    /// The voxel budget in force.
    pub budget: u64,
    /// Whether the budget cut this step's subdivision short.
    pub budget_reached: bool,
    /// Device memory allocated after the step (bytes).
    pub device_memory: u64,
    pub seconds: f64,
    /// Of `seconds`: the statistics pass (every training view rendered).
    pub stats_seconds: f64,
    /// Of `seconds`: selection and topology change (host round trip, reinstall).
    pub topology_seconds: f64,
}

/// Removes the voxels no training camera sees (paper §3.2.1, bounded scenes): a voxel
/// is seen when a view's preprocess gives it at least one tile entry.
pub fn visible_only(
    scene: Scene,
    cams: &[Camera],
    renderer: &mut Renderer,
    stats: &mut StatsPass,
    topology: &mut Topology,
) -> Result<Scene> {
    let keep: Vec<bool> = stats
        .intervals(renderer, &scene, cams)?
        .min_interval
        .iter()
        .map(|v| v.is_finite())
        .collect();
    if !keep.contains(&true) {
        return Err(Error::Invalid(
            "no training camera sees any voxel of the scene box: check the config's \
             center/extent against the cameras"
                .into(),
        ));
    }
    if !keep.contains(&false) {
        return Ok(scene);
    }
    let split = vec![false; keep.len()];
    Ok(topology.apply(&scene, None, &keep, &split)?.0)
}
