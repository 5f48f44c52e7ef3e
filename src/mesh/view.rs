//! A small CPU rasterizer for meshes: what a mesh looks like from a camera (shaded PNGs
//! beside the photos) and which pixels it covers (silhouette IoU against masks). Pixel
//! centres at `+0.5`, depth-tested per pixel; triangles with a vertex behind the near
//! plane are skipped (object-centred views never need them).

use crate::camera::Camera;

/// A rendered mesh view.
#[derive(Clone, Debug)]
pub struct MeshView {
    pub width: u32,
    pub height: u32,
    /// Camera z of the nearest triangle per pixel (+inf: none).
    pub depth: Vec<f32>,
    /// Headlight shading `|n·v|` of the nearest triangle (0 where none).
    pub shade: Vec<f32>,
}

impl MeshView {
    /// Whether pixel `i` is covered.
    pub fn covered(&self, i: usize) -> bool {
        self.depth[i].is_finite()
    }
}

/// Rasterizes `triangles` over `positions` (the camera's frame of reference) into `cam`.
pub fn rasterize(cam: &Camera, positions: &[[f64; 3]], triangles: &[[u32; 3]]) -> MeshView {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut depth = vec![f32::INFINITY; w * h];
    let mut shade = vec![0.0f32; w * h];
    let cs: Vec<[f64; 3]> = positions.iter().map(|&p| cam.world_to_camera(p)).collect();
    for t in triangles {
        let q = t.map(|i| cs[i as usize]);
        if q.iter().any(|p| p[2] <= cam.near) {
            continue;
        }
        let s = q.map(|p| [cam.fx * p[0] / p[2] + cam.cx, cam.fy * p[1] / p[2] + cam.cy]);
        let area =
            (s[1][0] - s[0][0]) * (s[2][1] - s[0][1]) - (s[2][0] - s[0][0]) * (s[1][1] - s[0][1]);
        if area == 0.0 || !area.is_finite() {
            continue;
        }
        // Face normal (camera frame) for the headlight.
        let u = [q[1][0] - q[0][0], q[1][1] - q[0][1], q[1][2] - q[0][2]];
        let v = [q[2][0] - q[0][0], q[2][1] - q[0][1], q[2][2] - q[0][2]];
        let n = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        let c = [
            (q[0][0] + q[1][0] + q[2][0]) / 3.0,
            (q[0][1] + q[1][1] + q[2][1]) / 3.0,
            (q[0][2] + q[1][2] + q[2][2]) / 3.0,
        ];
        let nl = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        let cl = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
        let lit = if nl > 0.0 && cl > 0.0 {
            ((n[0] * c[0] + n[1] * c[1] + n[2] * c[2]) / (nl * cl)).abs() as f32
        } else {
            0.0
        };
        let (x0, x1) = span(s.map(|p| p[0]), w);
        let (y0, y1) = span(s.map(|p| p[1]), h);
        for py in y0..y1 {
            for px in x0..x1 {
                let (x, y) = (px as f64 + 0.5, py as f64 + 0.5);
                let e = |a: usize, b: usize| {
                    (s[b][0] - s[a][0]) * (y - s[a][1]) - (s[b][1] - s[a][1]) * (x - s[a][0])
                };
                let b = [e(1, 2) / area, e(2, 0) / area, e(0, 1) / area];
                if b.iter().any(|&x| x < 0.0) {
                    continue;
                }
                // Perspective-correct depth: 1/z is affine in screen space.
                let iz = b[0] / q[0][2] + b[1] / q[1][2] + b[2] / q[2][2];
                let z = (1.0 / iz) as f32;
                let i = py * w + px;
                if z < depth[i] {
                    depth[i] = z;
                    shade[i] = lit;
                }
            }
        }
    }
    MeshView {
        width: cam.width,
        height: cam.height,
        depth,
        shade,
    }
}

/// The pixel range `[lo, hi)` covering coordinates `v`, clamped to `0..n`.
fn span(v: [f64; 3], n: usize) -> (usize, usize) {
    let lo = v
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min)
        .floor()
        .max(0.0);
    let hi = v
        .iter()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max)
        .ceil()
        .min(n as f64);
    (lo as usize, hi as usize)
}

/// Intersection over union of the covered pixels and the pixels where `mask` ≥ 0.5.
pub fn silhouette_iou(view: &MeshView, mask: &[f32]) -> f64 {
    let (mut inter, mut union) = (0usize, 0usize);
    for (i, &m) in mask.iter().enumerate() {
        let (a, b) = (view.covered(i), m >= 0.5);
        inter += usize::from(a && b);
        union += usize::from(a || b);
    }
    if union == 0 {
        1.0
    } else {
        inter as f64 / union as f64
    }
}
