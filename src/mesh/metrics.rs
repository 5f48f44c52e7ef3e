//! Surface accuracy of a mesh against ground-truth points, in the DTU protocol's terms:
//! points sampled uniformly on the mesh (by area), nearest-neighbour distances both ways.
//!
//! * accuracy: mean distance from mesh samples to the nearest ground-truth point;
//! * completeness: mean distance from ground-truth points to the nearest mesh sample;
//! * Chamfer: their mean; distances above `max_dist` are clamped to it, as the DTU
//!   evaluation does (its outlier threshold, 20 mm there);
//! * precision / recall: fractions of those distances below `threshold`; F-score their
//!   harmonic mean (Tanks and Temples).
//!
//! Nearest neighbours come from a hash grid with cells of `max_dist` (distances beyond
//! it are clamped anyway, so only the 27 cells around a point are searched).

use std::collections::HashMap;

/// Distances between a mesh and ground-truth points.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct SurfaceErrors {
    pub accuracy: f64,
    pub completeness: f64,
    pub chamfer: f64,
    pub precision: f64,
    pub recall: f64,
    pub fscore: f64,
    pub threshold: f64,
    pub max_dist: f64,
    pub mesh_samples: usize,
    pub truth_points: usize,
}

/// The most points [`sample_mesh`] takes (24 bytes each: 384 MiB).
pub const MAX_MESH_SAMPLES: f64 = (1u64 << 24) as f64;

/// About one point per `spacing²` of area on the triangles, uniform by area (fixed
/// seed; at least one per triangle of area ≥ `spacing²`, none on degenerate ones).
/// Refused, before any allocation, when that is more than [`MAX_MESH_SAMPLES`] points or
/// not a number (a vertex at 3.4e38 or ∞, a spacing of 0).
pub fn sample_mesh(
    positions: &[[f64; 3]],
    triangles: &[[u32; 3]],
    spacing: f64,
) -> crate::error::Result<Vec<[f64; 3]>> {
    use rand::{Rng, SeedableRng};
    let corners = |t: &[u32; 3]| t.map(|i| glam::DVec3::from(positions[i as usize]));
    let area_of = |[a, b, c]: [glam::DVec3; 3]| 0.5 * (b - a).cross(c - a).length();
    let area: f64 = triangles.iter().map(|t| area_of(corners(t))).sum();
    let wanted = area / (spacing * spacing);
    if !(spacing > 0.0 && wanted.is_finite() && wanted <= MAX_MESH_SAMPLES) {
        return Err(crate::error::Error::Invalid(format!(
            "sampling the mesh (area {area:.4e}) every {spacing:.4e} takes {wanted:.4e} \
             points, more than the {MAX_MESH_SAMPLES} allowed: give a larger --threshold \
             (samples are threshold/5 apart), or check the mesh for vertices far out or not \
             finite"
        )));
    }
    let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
    let mut out = Vec::new();
    let mut carry = 0.0f64;
    for t in triangles {
        let [a, b, c] = corners(t);
        let area = area_of([a, b, c]);
        // Expected count area/spacing², with the fractional part carried over so small
        // triangles still add up.
        carry += area / (spacing * spacing);
        while carry >= 1.0 {
            carry -= 1.0;
            let (mut u, mut v): (f64, f64) = (rng.gen(), rng.gen());
            if u + v > 1.0 {
                u = 1.0 - u;
                v = 1.0 - v;
            }
            out.push((a + (b - a) * u + (c - a) * v).to_array());
        }
    }
    Ok(out)
}

struct Grid {
    cell: f64,
    map: HashMap<[i64; 3], Vec<u32>>,
    points: Vec<[f64; 3]>,
}

impl Grid {
    fn new(points: &[[f64; 3]], cell: f64) -> Grid {
        let mut map: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
        for (i, p) in points.iter().enumerate() {
            map.entry(p.map(|x| (x / cell).floor() as i64))
                .or_default()
                .push(i as u32);
        }
        Grid {
            cell,
            map,
            points: points.to_vec(),
        }
    }

    /// Distance to the nearest point, clamped to the cell size.
    fn nearest(&self, p: [f64; 3]) -> f64 {
        let c = p.map(|x| (x / self.cell).floor() as i64);
        let mut best = self.cell * self.cell;
        for d in 0..27i64 {
            let k = [c[0] + d / 9 - 1, c[1] + (d / 3) % 3 - 1, c[2] + d % 3 - 1];
            if let Some(ids) = self.map.get(&k) {
                for &i in ids {
                    let q = self.points[i as usize];
                    let e = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2);
                    best = best.min(e);
                }
            }
        }
        best.sqrt()
    }
}

/// Accuracy, completeness, Chamfer and F-score of `mesh` samples against `truth`.
pub fn surface_errors(
    mesh: &[[f64; 3]],
    truth: &[[f64; 3]],
    threshold: f64,
    max_dist: f64,
) -> SurfaceErrors {
    use rayon::prelude::*;
    let one_way = |from: &[[f64; 3]], to: &[[f64; 3]]| -> (f64, f64) {
        if from.is_empty() {
            return (max_dist, 0.0);
        }
        let g = Grid::new(to, max_dist);
        let d: Vec<f64> = from.par_iter().map(|&p| g.nearest(p)).collect();
        let mean = d.iter().sum::<f64>() / d.len() as f64;
        let within = d.iter().filter(|&&x| x < threshold).count() as f64 / d.len() as f64;
        (mean, within)
    };
    let (accuracy, precision) = one_way(mesh, truth);
    let (completeness, recall) = one_way(truth, mesh);
    let fscore = if precision + recall > 0.0 {
        2.0 * precision * recall / (precision + recall)
    } else {
        0.0
    };
    SurfaceErrors {
        accuracy,
        completeness,
        chamfer: 0.5 * (accuracy + completeness),
        precision,
        recall,
        fscore,
        threshold,
        max_dist,
        mesh_samples: mesh.len(),
        truth_points: truth.len(),
    }
}
