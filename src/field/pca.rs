//! Feature fields as colours: the first three principal components of the voxels'
//! features (weighted by each voxel's Σ w), mapped to r, g, b.

use serde::{Deserialize, Serialize};

use super::{Field, FieldImage};
use crate::error::{Error, Result};

/// Voxels the components are fitted on at most (an even stride through the voxels
/// with weight; all of them below this).
const MAX_SAMPLES: usize = 16384;

/// The projection of a feature field to colour. A voxel's colour is
/// `(P·(f − mean) − lo) / (hi − lo)` per component; a pixel composites those colours
/// over black: `(P·(F − α·mean) − α·lo) / (hi − lo)` of its composited features F and
/// opacity α, clamped to [0, 1].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pca {
    /// Weighted mean feature.
    pub mean: Vec<f64>,
    /// Up to three unit principal directions, largest variance first; each one's
    /// largest-magnitude entry is positive (a deterministic sign).
    pub components: Vec<Vec<f64>>,
    /// Per component, the weighted 1st and 99th percentiles of the voxels' projections.
    pub lo: Vec<f64>,
    pub hi: Vec<f64>,
    /// Variance along each component.
    pub variance: Vec<f64>,
}

impl Pca {
    /// Fits the projection to `field`'s voxels with Σ w > 0 (weighted by Σ w).
    pub fn fit(field: &Field) -> Result<Pca> {
        let c = field.channels as usize;
        let seen: Vec<usize> = (0..field.voxels as usize)
            .filter(|&v| field.weights[v] > 0.0)
            .collect();
        if seen.is_empty() {
            return Err(Error::Invalid(
                "the field has no voxel with weight: nothing was fused".into(),
            ));
        }
        let step = seen.len().div_ceil(MAX_SAMPLES);
        let sample: Vec<usize> = seen.iter().step_by(step).copied().collect();
        let w: Vec<f64> = sample
            .iter()
            .map(|&v| f64::from(field.weights[v]))
            .collect();
        let total: f64 = w.iter().sum();
        let feat = |v: usize| &field.values[v * c..(v + 1) * c];
        let mut mean = vec![0f64; c];
        for (&v, &wv) in sample.iter().zip(&w) {
            for (m, &x) in mean.iter_mut().zip(feat(v)) {
                *m += wv * f64::from(x);
            }
        }
        mean.iter_mut().for_each(|m| *m /= total);
        let centred: Vec<Vec<f64>> = sample
            .iter()
            .map(|&v| {
                feat(v)
                    .iter()
                    .zip(&mean)
                    .map(|(&x, m)| f64::from(x) - m)
                    .collect()
            })
            .collect();
        // Σ w (f − μ)(f − μ)ᵀ x / Σ w without forming the matrix.
        let cov_mul = |x: &[f64]| -> Vec<f64> {
            let mut y = vec![0f64; c];
            for (d, &wv) in centred.iter().zip(&w) {
                let s = wv * dot(d, x) / total;
                for (yi, di) in y.iter_mut().zip(d) {
                    *yi += s * di;
                }
            }
            y
        };
        let k = c.min(3);
        let components = top_eigenvectors(c, k, cov_mul);
        let mut lo = Vec::with_capacity(k);
        let mut hi = Vec::with_capacity(k);
        let mut variance = Vec::with_capacity(k);
        for comp in &components {
            let mut proj: Vec<(f64, f64)> = centred
                .iter()
                .zip(&w)
                .map(|(d, &wv)| (dot(d, comp), wv))
                .collect();
            variance.push(proj.iter().map(|(y, wv)| wv * y * y).sum::<f64>() / total);
            proj.sort_by(|a, b| a.0.total_cmp(&b.0));
            let (l, mut h) = (
                percentile(&proj, total, 0.01),
                percentile(&proj, total, 0.99),
            );
            if h - l < 1e-12 {
                h = l + 1.0;
            }
            lo.push(l);
            hi.push(h);
        }
        Ok(Pca {
            mean,
            components,
            lo,
            hi,
            variance,
        })
    }

    /// Colours of a rendered feature field (see the type's docs); a component that does
    /// not exist (fewer than three channels) reads 0.
    pub fn colours(&self, img: &FieldImage) -> Result<Vec<[f32; 3]>> {
        let c = img.channels as usize;
        if c != self.mean.len() {
            return Err(Error::Invalid(format!(
                "a {c}-channel image for a projection of {} channels",
                self.mean.len()
            )));
        }
        Ok(img
            .alpha
            .iter()
            .enumerate()
            .map(|(i, &a)| {
                let f = &img.values[i * c..(i + 1) * c];
                let a = f64::from(a);
                let mut rgb = [0f32; 3];
                for (j, comp) in self.components.iter().enumerate() {
                    let y: f64 = comp
                        .iter()
                        .zip(f.iter().zip(&self.mean))
                        .map(|(p, (&x, m))| p * (f64::from(x) - a * m))
                        .sum();
                    rgb[j] =
                        ((y - a * self.lo[j]) / (self.hi[j] - self.lo[j])).clamp(0.0, 1.0) as f32;
                }
                rgb
            })
            .collect())
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The weighted `q`-quantile of `sorted` (value, weight) pairs.
fn percentile(sorted: &[(f64, f64)], total: f64, q: f64) -> f64 {
    let mut acc = 0.0;
    for &(y, wv) in sorted {
        acc += wv;
        if acc >= q * total {
            return y;
        }
    }
    sorted.last().map_or(0.0, |p| p.0)
}

/// The `k` leading eigenvectors of the symmetric positive semi-definite `n × n` matrix
/// applied by `mul`: orthogonal (subspace) iteration with Gram–Schmidt, then a
/// Rayleigh–Ritz rotation within the subspace so the vectors come out in order of
/// their eigenvalues.
fn top_eigenvectors(n: usize, k: usize, mul: impl Fn(&[f64]) -> Vec<f64>) -> Vec<Vec<f64>> {
    // A fixed start with weight on every axis (deterministic, rarely orthogonal to an
    // eigenvector).
    let mut q: Vec<Vec<f64>> = (0..k)
        .map(|j| {
            (0..n)
                .map(|i| {
                    1.0 + ((i * 7 + j * 13) % 11) as f64 * 0.1 + if i == j { 3.0 } else { 0.0 }
                })
                .collect()
        })
        .collect();
    orthonormalise(&mut q);
    for _ in 0..1000 {
        let mut z: Vec<Vec<f64>> = q.iter().map(|v| mul(v)).collect();
        orthonormalise(&mut z);
        let change: f64 = z
            .iter()
            .zip(&q)
            .map(|(a, b)| 1.0 - dot(a, b).abs())
            .fold(0.0, f64::max);
        q = z;
        if change < 1e-15 {
            break;
        }
    }
    // Rayleigh–Ritz: H = Qᵀ A Q (k × k), its eigenvectors by Jacobi rotations.
    let aq: Vec<Vec<f64>> = q.iter().map(|v| mul(v)).collect();
    let mut h: Vec<Vec<f64>> = (0..k)
        .map(|a| (0..k).map(|b| dot(&q[a], &aq[b])).collect())
        .collect();
    let (vals, vecs) = jacobi(&mut h);
    let mut order: Vec<usize> = (0..k).collect();
    order.sort_by(|&a, &b| vals[b].total_cmp(&vals[a]));
    order
        .iter()
        .map(|&e| {
            let mut v: Vec<f64> = (0..n)
                .map(|i| (0..k).map(|a| vecs[a][e] * q[a][i]).sum())
                .collect();
            let norm = dot(&v, &v).sqrt().max(1e-300);
            v.iter_mut().for_each(|x| *x /= norm);
            let big = v
                .iter()
                .copied()
                .fold(0.0, |m: f64, x| if x.abs() > m.abs() { x } else { m });
            if big < 0.0 {
                v.iter_mut().for_each(|x| *x = -*x);
            }
            v
        })
        .collect()
}

/// Gram–Schmidt (twice, for stability); a vector that vanishes is replaced by the
/// first axis not yet spanned.
fn orthonormalise(q: &mut [Vec<f64>]) {
    for j in 0..q.len() {
        for _ in 0..2 {
            for i in 0..j {
                let p = dot(&q[i], &q[j]);
                let (a, b) = q.split_at_mut(j);
                for (x, y) in b[0].iter_mut().zip(&a[i]) {
                    *x -= p * y;
                }
            }
        }
        let norm = dot(&q[j], &q[j]).sqrt();
        if norm > 1e-150 {
            q[j].iter_mut().for_each(|x| *x /= norm);
        } else {
            let n = q[j].len();
            q[j] = (0..n).map(|i| if i == j % n { 1.0 } else { 0.0 }).collect();
        }
    }
}

/// Eigen-decomposition of a small symmetric matrix by cyclic Jacobi rotations:
/// (eigenvalues, eigenvectors as columns of the returned matrix).
pub(crate) fn jacobi(a: &mut [Vec<f64>]) -> (Vec<f64>, Vec<Vec<f64>>) {
    let n = a.len();
    let mut v: Vec<Vec<f64>> = (0..n)
        .map(|i| (0..n).map(|j| if i == j { 1.0 } else { 0.0 }).collect())
        .collect();
    for _ in 0..100 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        if off < 1e-30 {
            break;
        }
        for p in 0..n {
            for r in p + 1..n {
                if a[p][r].abs() < 1e-300 {
                    continue;
                }
                let theta = (a[r][r] - a[p][p]) / (2.0 * a[p][r]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let cs = 1.0 / (t * t + 1.0).sqrt();
                let sn = t * cs;
                for row in a.iter_mut() {
                    let (akp, akr) = (row[p], row[r]);
                    row[p] = cs * akp - sn * akr;
                    row[r] = sn * akp + cs * akr;
                }
                let (top, bottom) = a.split_at_mut(r);
                for (apk, ark) in top[p].iter_mut().zip(bottom[0].iter_mut()) {
                    let (x, y) = (*apk, *ark);
                    *apk = cs * x - sn * y;
                    *ark = sn * x + cs * y;
                }
                for row in v.iter_mut() {
                    let (vp, vr) = (row[p], row[r]);
                    row[p] = cs * vp - sn * vr;
                    row[r] = sn * vp + cs * vr;
                }
            }
        }
    }
    ((0..n).map(|i| a[i][i]).collect(), v)
}
