//! The demo scene itself: six analytic primitives lit by one directional light with hard
//! shadows plus ambient light, ray traced in f64 ([`render_rgba`], [`SUPERSAMPLE`]²
//! samples per pixel).

use glam::DVec3;

use crate::camera::Camera;

/// Samples per pixel along each axis (the centre sample is the pixel's own ray).
pub const SUPERSAMPLE: u32 = 3;

/// Ambient light intensity.
pub const AMBIENT: f64 = 0.3;

/// Directional light intensity.
pub const DIFFUSE: f64 = 0.75;

/// Unit vector from the surface towards the light.
pub fn light_dir() -> DVec3 {
    unit(DVec3::new(0.45, -0.35, 0.82))
}

/// Geometry of a primitive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    Sphere {
        center: DVec3,
        radius: f64,
    },
    /// Axis-aligned box.
    Box {
        center: DVec3,
        half: DVec3,
    },
}

/// A coloured primitive with a Blinn-Phong material.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Primitive {
    pub name: &'static str,
    pub shape: Shape,
    /// Diffuse albedo.
    pub color: DVec3,
    /// Specular (white highlight) strength.
    pub specular: f64,
    /// Blinn-Phong exponent.
    pub shininess: f64,
}

/// The demo scene.
pub const PRIMITIVES: [Primitive; 6] = [
    Primitive {
        name: "pedestal",
        shape: Shape::Box {
            center: DVec3::new(0.0, 0.0, -0.6),
            half: DVec3::new(0.8, 0.8, 0.1),
        },
        color: DVec3::new(0.72, 0.72, 0.75),
        specular: 0.05,
        shininess: 8.0,
    },
    Primitive {
        name: "glossy red sphere",
        shape: Shape::Sphere {
            center: DVec3::new(-0.3, -0.3, -0.1),
            radius: 0.4,
        },
        color: DVec3::new(0.85, 0.12, 0.1),
        specular: 0.9,
        shininess: 80.0,
    },
    Primitive {
        name: "green box",
        shape: Shape::Box {
            center: DVec3::new(0.45, -0.25, -0.2),
            half: DVec3::new(0.25, 0.25, 0.3),
        },
        color: DVec3::new(0.2, 0.7, 0.25),
        specular: 0.1,
        shininess: 10.0,
    },
    Primitive {
        name: "orange sphere",
        shape: Shape::Sphere {
            center: DVec3::new(0.45, -0.25, 0.28),
            radius: 0.18,
        },
        color: DVec3::new(0.9, 0.5, 0.1),
        specular: 0.5,
        shininess: 40.0,
    },
    Primitive {
        name: "blue sphere",
        shape: Shape::Sphere {
            center: DVec3::new(0.3, 0.5, -0.22),
            radius: 0.28,
        },
        color: DVec3::new(0.15, 0.3, 0.9),
        specular: 0.4,
        shininess: 30.0,
    },
    Primitive {
        name: "yellow box",
        shape: Shape::Box {
            center: DVec3::new(-0.4, 0.5, -0.05),
            half: DVec3::new(0.18, 0.18, 0.45),
        },
        color: DVec3::new(0.95, 0.8, 0.2),
        specular: 0.1,
        shininess: 10.0,
    },
];

impl Shape {
    /// Exact signed distance (negative inside).
    pub fn signed_distance(&self, p: DVec3) -> f64 {
        match *self {
            Shape::Sphere { center, radius } => (p - center).length() - radius,
            Shape::Box { center, half } => {
                let q = (p - center).abs() - half;
                let outside = q.max(DVec3::ZERO).length();
                let inside = q.max_element().min(0.0);
                outside + inside
            }
        }
    }

    /// Outward unit normal of the surface point nearest to `p` (the gradient of the
    /// signed distance).
    pub fn normal(&self, p: DVec3) -> DVec3 {
        match *self {
            Shape::Sphere { center, .. } => {
                let v = p - center;
                if v.length() > 0.0 {
                    unit(v)
                } else {
                    DVec3::Z
                }
            }
            Shape::Box { center, half } => {
                let r = p - center;
                let sign = DVec3::select(r.cmplt(DVec3::ZERO), -DVec3::ONE, DVec3::ONE);
                let q = r.abs() - half;
                if q.cmpgt(DVec3::ZERO).any() {
                    unit(q.max(DVec3::ZERO) * sign)
                } else {
                    let a = (0..3).max_by(|&i, &j| q[i].total_cmp(&q[j])).unwrap_or(2);
                    let mut n = DVec3::ZERO;
                    n[a] = sign[a];
                    n
                }
            }
        }
    }

    /// First intersection of the ray `o + t·d` (unit `d`) with `t > t_min`: distance and
    /// outward unit normal.
    pub fn intersect(&self, o: DVec3, d: DVec3, t_min: f64) -> Option<(f64, DVec3)> {
        match *self {
            Shape::Sphere { center, radius } => {
                let oc = o - center;
                let b = oc.dot(d);
                let c = oc.dot(oc) - radius * radius;
                let disc = b * b - c;
                if disc < 0.0 {
                    return None;
                }
                let s = disc.sqrt();
                let t = [-b - s, -b + s].into_iter().find(|&t| t > t_min)?;
                let p = o + d * t;
                Some((t, (p - center) * (1.0 / radius)))
            }
            Shape::Box { center, half } => {
                let (lo, hi) = (center - half, center + half);
                let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
                let (mut a0, mut a1) = (0usize, 0usize);
                for a in 0..3 {
                    if d[a] == 0.0 {
                        if o[a] < lo[a] || o[a] > hi[a] {
                            return None;
                        }
                        continue;
                    }
                    let (mut ta, mut tb) = ((lo[a] - o[a]) / d[a], (hi[a] - o[a]) / d[a]);
                    if ta > tb {
                        std::mem::swap(&mut ta, &mut tb);
                    }
                    if ta > t0 {
                        t0 = ta;
                        a0 = a;
                    }
                    if tb < t1 {
                        t1 = tb;
                        a1 = a;
                    }
                }
                if t0 > t1 {
                    return None;
                }
                let axis_normal = |a: usize, s: f64| {
                    let mut n = DVec3::ZERO;
                    n[a] = s;
                    n
                };
                if t0 > t_min {
                    Some((t0, axis_normal(a0, -d[a0].signum())))
                } else if t1 > t_min {
                    Some((t1, axis_normal(a1, d[a1].signum())))
                } else {
                    None
                }
            }
        }
    }
}

/// A ray's first hit in the demo scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the (unit) ray direction.
    pub t: f64,
    pub point: DVec3,
    /// Outward unit surface normal.
    pub normal: DVec3,
    /// Index into [`PRIMITIVES`].
    pub primitive: usize,
}

/// Analytic hit test: the nearest intersection of the ray `origin + t·dir` (`dir` of
/// unit length, `t > 0`) with the demo primitives, if any.
pub fn ray_hit(origin: DVec3, dir: DVec3) -> Option<Hit> {
    let mut best: Option<Hit> = None;
    for (i, prim) in PRIMITIVES.iter().enumerate() {
        if let Some((t, normal)) = prim.shape.intersect(origin, dir, 1e-9) {
            if best.is_none_or(|b| t < b.t) {
                best = Some(Hit {
                    t,
                    point: origin + dir * t,
                    normal,
                    primitive: i,
                });
            }
        }
    }
    best
}

/// Signed distance to the union of the primitives (exact outside, a lower bound of the
/// distance to the surface inside).
pub fn signed_distance(p: DVec3) -> f64 {
    nearest_primitive(p).1
}

/// The primitive with the smallest signed distance at `p`, and that distance.
pub fn nearest_primitive(p: DVec3) -> (usize, f64) {
    let mut best = (0, f64::INFINITY);
    for (i, prim) in PRIMITIVES.iter().enumerate() {
        let d = prim.shape.signed_distance(p);
        if d < best.1 {
            best = (i, d);
        }
    }
    best
}

/// Whether the light is blocked seen from surface point `p` with normal `n`.
pub(super) fn in_shadow(p: DVec3, n: DVec3) -> bool {
    ray_hit(p + n * 1e-6, light_dir()).is_some()
}

/// Shaded colour of a hit seen along unit direction `dir`: ambient + shadowed diffuse
/// + Blinn-Phong highlight, clamped to `[0, 1]`.
pub fn shade(hit: &Hit, dir: DVec3) -> DVec3 {
    let prim = &PRIMITIVES[hit.primitive];
    let n = hit.normal;
    let l = light_dir();
    let ndl = n.dot(l).max(0.0);
    let lit = if ndl > 0.0 && !in_shadow(hit.point, n) {
        1.0
    } else {
        0.0
    };
    let h = unit(l - dir);
    let spec = prim.specular * n.dot(h).max(0.0).powf(prim.shininess) * lit;
    (prim.color * (AMBIENT + DIFFUSE * ndl * lit) + spec).clamp(DVec3::ZERO, DVec3::ONE)
}

/// Ray traces the demo scene for `camera`: row-major straight-alpha RGBA, alpha the
/// fraction of the pixel's [`SUPERSAMPLE`]² sub-samples that hit a primitive (0 on the
/// transparent background). Rays are built as [`Camera::pixel_ray`] builds them.
pub fn render_rgba(camera: &Camera) -> Vec<[f32; 4]> {
    let o = DVec3::from(camera.origin());
    let n = SUPERSAMPLE;
    let mut out = Vec::with_capacity(camera.width as usize * camera.height as usize);
    for py in 0..camera.height {
        for px in 0..camera.width {
            let mut sum = DVec3::ZERO;
            let mut hits = 0u32;
            for sy in 0..n {
                for sx in 0..n {
                    let u = px as f64 + (sx as f64 + 0.5) / n as f64;
                    let v = py as f64 + (sy as f64 + 0.5) / n as f64;
                    let d = unit(camera.rotate(camera.camera_dir(u, v)).into());
                    if let Some(hit) = ray_hit(o, d) {
                        sum += shade(&hit, d);
                        hits += 1;
                    }
                }
            }
            let a = hits as f64 / (n * n) as f64;
            let rgb = if hits > 0 {
                (sum / hits as f64).as_vec3().to_array()
            } else {
                [0.0; 3]
            };
            out.push([rgb[0], rgb[1], rgb[2], a as f32]);
        }
    }
    out
}

/// The 8-bit value of primitive `prim` in the demo's label images (`demo --labels`):
/// 40·(prim + 1); the background is 0.
pub fn label_value(prim: usize) -> u8 {
    (40 * (prim + 1)) as u8
}

/// Per-pixel labels of the demo scene for `camera` (row-major, [`label_value`]): the
/// most frequent of the pixel's [`SUPERSAMPLE`]² sub-samples (background 0 counts as a
/// label; ties go to the lower value), the sub-sample rays as [`render_rgba`]'s.
pub fn render_labels(camera: &Camera) -> Vec<u8> {
    let o = DVec3::from(camera.origin());
    let n = SUPERSAMPLE;
    let mut out = Vec::with_capacity(camera.width as usize * camera.height as usize);
    for py in 0..camera.height {
        for px in 0..camera.width {
            let mut votes = [0u32; PRIMITIVES.len() + 1];
            for sy in 0..n {
                for sx in 0..n {
                    let u = px as f64 + (sx as f64 + 0.5) / n as f64;
                    let v = py as f64 + (sy as f64 + 0.5) / n as f64;
                    let d = unit(camera.rotate(camera.camera_dir(u, v)).into());
                    votes[ray_hit(o, d).map_or(0, |h| h.primitive + 1)] += 1;
                }
            }
            let best = (0..votes.len()).fold(0, |b, i| if votes[i] > votes[b] { i } else { b });
            out.push(if best == 0 { 0 } else { label_value(best - 1) });
        }
    }
    out
}

/// `v` scaled to unit length (a true division, as the f64 references in tests/ do).
pub(super) fn unit(v: DVec3) -> DVec3 {
    v / v.length()
}
