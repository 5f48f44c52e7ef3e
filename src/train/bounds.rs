//! The main (foreground) region of a capture from its training cameras (paper §3.2.1;
//! the reference implementation's `bounding_utils.py`).
//!
//! - `camera_median` / `camera_max`: centre = mean camera position, radius = median / max
//!   distance of the cameras from it (360° captures: the cameras surround the scene).
//! - `forward`: the cameras all look one way (LLFF): centre = mean position +
//!   `e`·(mean viewing direction), radius = 0.8·`e`, with `e` = twice the largest
//!   camera distance from their mean position.
//! - `points`: from the capture's sparse points (COLMAP `points3D`): centre = per-axis
//!   median, radius = the smallest L∞ distance beyond the densest ball (at least 5 % of
//!   the points in it) where the point density falls below 10 % of its peak (the
//!   reference's `pcd` heuristic).
//! - `sphere`: the capture's own bounding sphere of the object (NeuS/DTU `scale_mat`: the
//!   unit sphere of its normalisation), when it has one.
//! - `auto`: `sphere` when the capture has one; else for forward-facing cameras (every pair of viewing directions has a positive
//!   dot product) `points` when the capture has sparse points, else `forward`; for the
//!   others `camera_median`. `forward` assumes the scene lies about as far in front of
//!   the cameras as they are spread apart, true of NeRF's normalised LLFF poses but not
//!   of a COLMAP model's arbitrary scale: on llff_flower it puts the main region at depth
//!   4–20 while the flower is at 22–222 (COLMAP units), so `auto` prefers the points.
//!
//! The scene's root cube is the main region's cube (edge 2·radius) times
//! `2^outside_level`; the ring between them holds the background shells
//! ([`crate::adapt::shells`]).

use glam::DVec3;

use super::config::BOUND_MODES;
use crate::camera::Camera;
use crate::error::{Error, Result};

/// For a run whose `bound` is not "box": the main region of the training data, made the
/// run's world frame (model = (world − centre) / radius, so the region is [-1, 1]³:
/// `center` 0, `extent` 2). Returns the region found (None for "box"). The dataset is
/// left in world coordinates: map it with [`Dataset::to_model`](crate::data::Dataset).
pub fn resolve_world(
    cfg: &mut super::config::TrainConfig,
    train: &crate::data::Dataset,
) -> Result<Option<MainRegion>> {
    if cfg.bound == "box" {
        return Ok(None);
    }
    let r = match (&train.sphere, cfg.bound.as_str()) {
        (Some((center, radius)), "auto" | "sphere") => MainRegion {
            center: *center,
            radius: *radius,
            mode: "sphere",
            forward: false,
        },
        _ => main_region(&train.cameras(), &train.points, &cfg.bound)?,
    };
    cfg.world_center = r.center;
    cfg.world_scale = r.radius;
    cfg.center = [0.0; 3];
    cfg.extent = 2.0;
    Ok(Some(r))
}

/// Resolves what a new run takes from its training data — the background colour (with
/// `background_from_photos`) and the world frame ([`resolve_world`]) — and maps `train`
/// into the model's frame. Returns the main region found (None for a "box" bound).
pub fn resolve_run(
    cfg: &mut super::config::TrainConfig,
    train: &mut crate::data::Dataset,
) -> Result<Option<MainRegion>> {
    if cfg.background_from_photos {
        if train.alpha {
            return Err(Error::Invalid(format!(
                "background_from_photos takes the mean colour of opaque photos (a capture); \
                 the {} photos carry alpha and are composited over the background: set \
                 background=[r,g,b] instead (or background_from_photos=false)",
                train.split
            )));
        }
        cfg.background = train.mean_color();
    }
    let r = resolve_world(cfg, train)?;
    train.to_model(&cfg.world());
    Ok(r)
}

/// A main region: centre, half edge, and the mode that produced it (`auto` resolved).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MainRegion {
    pub center: [f64; 3],
    pub radius: f64,
    pub mode: &'static str,
    /// Every camera looks into the same half-space (a forward-facing capture).
    pub forward: bool,
}

/// The main region of `cams` (and the capture's sparse `points`, possibly none) under
/// `mode` (one of [`BOUND_MODES`] but `box`).
pub fn main_region(cams: &[Camera], points: &[[f64; 3]], mode: &str) -> Result<MainRegion> {
    if cams.len() < 2 {
        return Err(Error::Invalid(format!(
            "bounding the scene from the cameras needs at least 2 training views, got {}",
            cams.len()
        )));
    }
    let pos: Vec<DVec3> = cams.iter().map(|c| DVec3::from(c.origin())).collect();
    let look: Vec<DVec3> = cams
        .iter()
        .map(|c| DVec3::from(c.rotate([0.0, 0.0, 1.0])).normalize())
        .collect();
    let forward = look.iter().all(|a| look.iter().all(|b| a.dot(*b) > 0.0));
    let mode: &'static str = match mode {
        "auto" => match (forward, points.len() >= 8) {
            (true, true) => "points",
            (true, false) => "forward",
            _ => "camera_median",
        },
        "points" if points.len() < 8 => {
            return Err(Error::Invalid(format!(
                "bound mode `points` needs the capture's sparse points; it has {}",
                points.len()
            )))
        }
        "points" => "points",
        "sphere" => {
            return Err(Error::Invalid(
                "bound mode `sphere` needs a capture that gives its object's bounding sphere \
                 (NeuS/DTU cameras_sphere.npz); use auto, camera_median, camera_max, forward, \
                 points or box"
                    .into(),
            ))
        }
        "camera_median" => "camera_median",
        "camera_max" => "camera_max",
        "forward" => "forward",
        other => {
            return Err(Error::Invalid(format!(
                "bound mode `{other}` is not one of {}",
                BOUND_MODES.join(", ")
            )))
        }
    };
    let mean = pos.iter().copied().sum::<DVec3>() / pos.len() as f64;
    let mut dist: Vec<f64> = pos.iter().map(|p| (*p - mean).length()).collect();
    dist.sort_by(f64::total_cmp);
    let (center, radius) = match mode {
        "forward" => {
            let dir = look.iter().copied().sum::<DVec3>().normalize();
            let e = 2.0 * dist[dist.len() - 1];
            (mean + e * dir, 0.8 * e)
        }
        "camera_max" => (mean, dist[dist.len() - 1]),
        "points" => points_region(points),
        _ => {
            // numpy's median: the mean of the two middle values for an even count.
            let n = dist.len();
            let median = if n % 2 == 1 {
                dist[n / 2]
            } else {
                0.5 * (dist[n / 2 - 1] + dist[n / 2])
            };
            (mean, median)
        }
    };
    if !(radius.is_finite() && radius > 0.0 && center.is_finite()) {
        return Err(Error::Invalid(format!(
            "the training cameras give no usable main region ({mode}: centre {center:?}, \
             radius {radius}): are all cameras at one place? Set the region with --set \
             bound=box --set center=[x,y,z] --set extent=E"
        )));
    }
    Ok(MainRegion {
        center: center.to_array(),
        radius,
        mode,
        forward,
    })
}

/// The reference's `main_scene_bound_pcd_heuristic` (density rate 0.1).
fn points_region(points: &[[f64; 3]]) -> (DVec3, f64) {
    let median = |a: usize| {
        let mut v: Vec<f64> = points.iter().map(|p| p[a]).collect();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        }
    };
    let center = DVec3::new(median(0), median(1), median(2));
    let mut dist: Vec<f64> = points
        .iter()
        .map(|p| (DVec3::from(*p) - center).abs().max_element())
        .collect();
    dist.sort_by(f64::total_cmp);
    let density: Vec<f64> = dist
        .iter()
        .enumerate()
        .map(|(i, &d)| {
            let count = if d > 0.0 { (i + 1) as f64 } else { 0.0 };
            count / ((2.0 * d).powi(3) + 1e-6)
        })
        .collect();
    let begin = (density.len() as f64 * 0.05).round() as usize;
    let peak = (begin..density.len())
        .max_by(|&a, &b| density[a].total_cmp(&density[b]).then(b.cmp(&a)))
        .unwrap_or(0);
    let target = 0.1 * density[peak];
    let end = (peak..density.len())
        .find(|&i| density[i] < target)
        .unwrap_or(density.len() - 1);
    (center, dist[end])
}
