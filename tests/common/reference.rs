//! The f64 CPU reference renderer, written for clarity: per pixel, collect every voxel
//! the ray hits, order the hits by entry distance, composite. No sorting keys, tiles,
//! Morton orders or screen rectangles are involved, so it checks all of those.
#![allow(clippy::needless_range_loop, clippy::too_many_arguments)]

use svraster::data::Camera;
use svraster::scene::Scene;

pub const STEP_SZ_SCALE: f64 = 100.0;
pub const MAX_ALPHA: f64 = 0.99999;
pub const MIN_ALPHA: f64 = 0.00001;
pub const EARLY_STOP_T: f64 = 0.0001;

pub fn explin(x: f64) -> f64 {
    if x > 1.1 {
        x
    } else {
        (x / 1.1 - 1.0 + 1.1f64.ln()).exp()
    }
}

/// Trilinear interpolation, corner index x<<2 | y<<1 | z (paper Eq. 13).
pub fn trilinear(g: &[f64; 8], q: [f64; 3]) -> f64 {
    let mut v = 0.0;
    for (c, gc) in g.iter().enumerate() {
        let wx = if c & 4 != 0 { q[0] } else { 1.0 - q[0] };
        let wy = if c & 2 != 0 { q[1] } else { 1.0 - q[1] };
        let wz = if c & 1 != 0 { q[2] } else { 1.0 - q[2] };
        v += wx * wy * wz * gc;
    }
    v
}

/// Real SH basis values (3DGS constants and signs) for a unit direction.
pub fn sh_basis(d: [f64; 3], degree: u32) -> Vec<f64> {
    let (x, y, z) = (d[0], d[1], d[2]);
    let c1 = 0.4886025119029199;
    let c2 = [
        1.0925484305920792,
        -1.0925484305920792,
        0.31539156525252005,
        -1.0925484305920792,
        0.5462742152960396,
    ];
    let c3 = [
        -0.5900435899266435,
        2.890611442640554,
        -0.4570457994644658,
        0.3731763325901154,
        -0.4570457994644658,
        1.445305721320277,
        -0.5900435899266435,
    ];
    let mut b = vec![0.28209479177387814];
    if degree >= 1 {
        b.extend([-c1 * y, c1 * z, -c1 * x]);
    }
    if degree >= 2 {
        let (xx, yy, zz) = (x * x, y * y, z * z);
        b.extend([
            c2[0] * x * y,
            c2[1] * y * z,
            c2[2] * (2.0 * zz - xx - yy),
            c2[3] * x * z,
            c2[4] * (xx - yy),
        ]);
        if degree >= 3 {
            b.extend([
                c3[0] * y * (3.0 * xx - yy),
                c3[1] * x * y * z,
                c3[2] * y * (4.0 * zz - xx - yy),
                c3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
                c3[4] * x * (4.0 * zz - xx - yy),
                c3[5] * z * (xx - yy),
                c3[6] * x * (xx - 3.0 * yy),
            ]);
        }
    }
    b
}

/// Colour of voxel `i` seen from `origin`: max(0, 0.5 + Σ sh·Y(normalize(centre − o))).
pub fn voxel_rgb(scene: &Scene, i: usize, origin: [f64; 3]) -> [f64; 3] {
    let c = scene.voxel_center(i);
    let d = normalize(sub(c, origin));
    let basis = sh_basis(d, scene.sh_degree);
    let nc = scene.shs_per_voxel();
    let mut rgb = [0.0; 3];
    for ch in 0..3 {
        let mut v = basis[0] * scene.sh0[i][ch] as f64;
        for k in 1..=nc {
            v += basis[k] * scene.shs[(i * nc + k - 1) * 3 + ch] as f64;
        }
        rgb[ch] = (v + 0.5).max(0.0);
    }
    rgb
}

/// Unit density gradient at the voxel centre (paper Eq. 16), 0 for a flat voxel.
pub fn voxel_normal(g: &[f64; 8]) -> [f64; 3] {
    let n = [
        (g[4] + g[5] + g[6] + g[7]) - (g[0] + g[1] + g[2] + g[3]),
        (g[2] + g[3] + g[6] + g[7]) - (g[0] + g[1] + g[4] + g[5]),
        (g[1] + g[3] + g[5] + g[7]) - (g[0] + g[2] + g[4] + g[6]),
    ];
    let r = 1.0 / dot(n, n).max(1e-30).sqrt();
    [n[0] * r, n[1] * r, n[2] * r]
}

/// Ray–box intersection of the ray o + t·d: (entry, exit); no hit when entry > exit.
/// A zero direction component means the ray is in the slab iff lo ≤ o < hi.
pub fn ray_aabb(lo: [f64; 3], hi: [f64; 3], o: [f64; 3], d: [f64; 3]) -> (f64, f64) {
    let mut a = f64::NEG_INFINITY;
    let mut b = f64::INFINITY;
    for ax in 0..3 {
        if d[ax] == 0.0 {
            if !(lo[ax] <= o[ax] && o[ax] < hi[ax]) {
                return (f64::INFINITY, f64::NEG_INFINITY);
            }
            continue;
        }
        let t0 = (lo[ax] - o[ax]) / d[ax];
        let t1 = (hi[ax] - o[ax]) / d[ax];
        a = a.max(t0.min(t1));
        b = b.min(t0.max(t1));
    }
    (a, b)
}

/// One reference pixel.
#[derive(Clone, Copy, Debug, Default)]
pub struct RefPixel {
    pub rgb: [f64; 3],
    pub alpha: f64,
    pub depth: f64,
    pub depth_median: f64,
    pub normal: [f64; 3],
    /// The median depth is decided within 1e-3 of T = 0.5 (a float rendering may pick
    /// another voxel or sample there).
    pub median_ambiguous: bool,
    /// Voxels the ray hits (before alpha skipping / early stop).
    pub hits: usize,
}

/// The reference direction of pixel (px, py): unit direction with |components| < 1e-20
/// flushed to zero (as the GPU), and |camera direction| (z = 1) for depth conversion.
pub fn pixel_ray(cam: &Camera, px: f64, py: f64) -> ([f64; 3], [f64; 3], f64) {
    let cd = cam.camera_dir(px, py);
    let norm = dot(cd, cd).sqrt();
    let w = cam.rotate(cd);
    let mut d = [w[0] / norm, w[1] / norm, w[2] / norm];
    for v in d.iter_mut() {
        if v.abs() < 1e-20 {
            *v = 0.0;
        }
    }
    (cam.origin(), d, norm)
}

/// α of the segment [a, b] of the ray o + t·d through a voxel with K samples (clamped
/// to MAX_ALPHA), the per-sample α and the step length.
pub fn alpha_of(
    g: &[f64; 8],
    vmin: [f64; 3],
    size: f64,
    o: [f64; 3],
    d: [f64; 3],
    a: f64,
    b: f64,
    k: usize,
) -> (f64, Vec<f64>, f64) {
    let step = (b - a) / k as f64;
    let mut vol = 0.0;
    let mut local = Vec::with_capacity(k);
    for s in 0..k {
        let t = a + (s as f64 + 0.5) * step;
        let q: [f64; 3] = std::array::from_fn(|ax| (o[ax] + t * d[ax] - vmin[ax]) / size);
        let lv = STEP_SZ_SCALE * step * explin(trilinear(g, q));
        vol += lv;
        local.push((1.0 - (-lv).exp()).min(MAX_ALPHA));
    }
    ((1.0 - (-vol).exp()).min(MAX_ALPHA), local, step)
}

/// Renders one pixel centre (u, v) (pixel coordinates, centres at i + 0.5).
/// Every voxel the ray `o + t·d` (t ≥ t_near) meets, as (entry, exit, voxel), in
/// compositing order (entry distance, then exit).
pub fn ray_hits(scene: &Scene, o: [f64; 3], d: [f64; 3], t_near: f64) -> Vec<(f64, f64, usize)> {
    let mut hits: Vec<(f64, f64, usize)> = Vec::new();
    for i in 0..scene.num_voxels() {
        let lo = scene.voxel_min(i);
        let s = scene.voxel_size(i);
        let hi = [lo[0] + s, lo[1] + s, lo[2] + s];
        let (a, b) = ray_aabb(lo, hi, o, d);
        let a = a.max(t_near);
        if a <= b {
            hits.push((a, b, i));
        }
    }
    hits.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.total_cmp(&y.1)));
    hits
}

pub fn render_pixel(scene: &Scene, cam: &Camera, u: f64, v: f64, k: usize) -> RefPixel {
    render_pixel_cut(scene, cam, u, v, k, f64::INFINITY)
}

/// [`render_pixel`] with the ray ending at camera depth `far` (a host's surface): each
/// voxel segment is clipped to it, voxels entered behind it are not composited.
pub fn render_pixel_cut(
    scene: &Scene,
    cam: &Camera,
    u: f64,
    v: f64,
    k: usize,
    far: f64,
) -> RefPixel {
    let (o, d, norm) = pixel_ray(cam, u, v);
    let t_near = cam.near * norm;
    let t_far = far * norm;
    let hits: Vec<(f64, f64, usize)> = ray_hits(scene, o, d, t_near)
        .into_iter()
        .map(|(a, b, i)| (a, b.min(t_far), i))
        .filter(|&(a, b, _)| a <= b)
        .collect();
    let mut px = RefPixel {
        hits: hits.len(),
        ..Default::default()
    };
    let mut t = 1.0;
    let mut med: Option<(usize, f64, f64, f64)> = None;
    for &(a, b, i) in &hits {
        let g: [f64; 8] = std::array::from_fn(|c| scene.geo[scene.corners[i][c] as usize] as f64);
        let vmin = scene.voxel_min(i);
        let size = scene.voxel_size(i);
        let (alpha, local, step) = alpha_of(&g, vmin, size, o, d, a, b, k);
        // A float rendering may keep or skip a voxel this close to the threshold,
        // which moves the median depth by a whole voxel.
        if (alpha - MIN_ALPHA).abs() < 2e-7 {
            px.median_ambiguous = true;
        }
        if alpha < MIN_ALPHA {
            continue;
        }
        let w = t * alpha;
        let rgb = voxel_rgb(scene, i, o);
        let n = voxel_normal(&g);
        for c in 0..3 {
            px.rgb[c] += w * rgb[c];
            px.normal[c] += w * n[c];
        }
        let dval = if k == 1 {
            alpha * 0.5 * (a + b)
        } else {
            let mut tr = 1.0;
            let mut dv = 0.0;
            for (s, la) in local.iter().enumerate() {
                dv += tr * la * (a + (s as f64 + 0.5) * step);
                tr *= 1.0 - la;
            }
            dv
        };
        px.depth += t * dval;
        if (t - 0.5).abs() < 1e-3 {
            px.median_ambiguous = true;
        }
        if t > 0.5 {
            med = Some((i, t, a, b));
        }
        t *= 1.0 - alpha;
        if t < EARLY_STOP_T {
            break;
        }
    }
    for c in 0..3 {
        px.rgb[c] += t * scene.background[c] as f64;
    }
    px.alpha = 1.0 - t;
    px.depth /= norm;
    if let Some((i, mut mt, a, b)) = med {
        let g: [f64; 8] = std::array::from_fn(|c| scene.geo[scene.corners[i][c] as usize] as f64);
        let vmin = scene.voxel_min(i);
        let size = scene.voxel_size(i);
        let n = 16;
        let step = (b - a) / n as f64;
        let mut dm = a - 0.5 * step;
        for s in 0..n {
            if mt <= 0.5 {
                break;
            }
            dm += step;
            let tt = a + (s as f64 + 0.5) * step;
            let q: [f64; 3] = std::array::from_fn(|ax| (o[ax] + tt * d[ax] - vmin[ax]) / size);
            mt *= (-STEP_SZ_SCALE * step * explin(trilinear(&g, q))).exp();
            if (mt - 0.5).abs() < 1e-3 {
                px.median_ambiguous = true;
            }
        }
        px.depth_median = dm / norm;
    }
    px
}

/// Renders every pixel of `cam` at its resolution. With `background_frame_mean` the
/// background behind every pixel is the frame's mean composited colour
/// m = (1/N) Σ_p C_p (C = Σ w c, before any background): rgb = C + T·m.
pub fn render(scene: &Scene, cam: &Camera, k: usize) -> Vec<RefPixel> {
    let mut out = Vec::with_capacity((cam.width * cam.height) as usize);
    let plain;
    let src = if scene.background_frame_mean {
        let mut s = scene.clone();
        s.background = [0.0; 3];
        plain = s;
        &plain
    } else {
        scene
    };
    for py in 0..cam.height {
        for px in 0..cam.width {
            out.push(render_pixel(src, cam, px as f64 + 0.5, py as f64 + 0.5, k));
        }
    }
    if scene.background_frame_mean {
        let n = out.len() as f64;
        let m: [f64; 3] = std::array::from_fn(|c| out.iter().map(|p| p.rgb[c]).sum::<f64>() / n);
        for p in &mut out {
            for c in 0..3 {
                p.rgb[c] += (1.0 - p.alpha) * m[c];
            }
        }
    }
    out
}

pub fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
pub fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
pub fn normalize(a: [f64; 3]) -> [f64; 3] {
    let n = dot(a, a).sqrt();
    [a[0] / n, a[1] / n, a[2] / n]
}
