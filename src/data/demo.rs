//! The built-in procedural demo scene.
//!
//! Six analytic primitives ([`PRIMITIVES`]) on and around the origin, all inside the
//! cube `[-1.5, 1.5]³`, world z up (as Blender): a flat grey pedestal, a glossy red
//! sphere (strong Blinn-Phong highlight, so its colour is view dependent), a green box
//! with a small orange sphere on top, a semi-glossy blue sphere and a tall yellow box.
//! They are lit by one directional light ([`light_dir`], with hard shadows) plus
//! ambient light. Nothing else is in the scene: the background is transparent.
//!
//! [`write_dataset`] ray traces the scene (f64, [`SUPERSAMPLE`]² samples per pixel, so
//! silhouettes get fractional alpha) into a NeRF-synthetic style dataset that
//! [`super::blender::load_split`] reads. [`voxelize`] builds a sparse-voxel [`Scene`] of
//! the same primitives directly, without training.

use std::path::{Path, PathBuf};

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

use super::blender::parse_matrix;
use super::image::{io_error, save_rgba_png, write_atomic};
use super::Camera;
use crate::error::{Error, Result};
use crate::scene::{key_coords, octpath_from_ijk, Scene, MAX_SH_DEGREE};

/// Horizontal field of view of the demo cameras (as NeRF-synthetic).
pub const CAMERA_ANGLE_X: f64 = 0.6911112070083618;
/// Distance of the demo cameras from the origin.
pub const CAMERA_RADIUS: f64 = 4.0;
/// Samples per pixel along each axis (the centre sample is the pixel's own ray).
pub const SUPERSAMPLE: u32 = 3;
/// Ambient light intensity.
pub const AMBIENT: f64 = 0.3;
/// Directional light intensity.
pub const DIFFUSE: f64 = 0.75;
/// Degree-0 SH constant: colour = 0.5 + `SH_C0`·sh0.
pub const SH_C0: f64 = 0.28209479177387814;
/// Centre of the voxelized scene's root cube.
pub const VOXEL_CENTER: [f32; 3] = [0.0; 3];
/// Edge length of the voxelized scene's root cube (`[-1.5, 1.5]³`).
pub const VOXEL_EXTENT: f32 = 3.0;
/// Deepest level [`voxelize`] accepts (level 11 is already ~10⁷ voxels).
pub const MAX_VOXELIZE_LEVEL: u32 = 11;
/// Raw density of empty space (`explin(−10) ≈ 5·10⁻⁵`).
pub const RAW_EMPTY: f32 = -10.0;

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
fn in_shadow(p: DVec3, n: DVec3) -> bool {
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

/// Options of [`write_dataset`].
#[derive(Clone, Debug, PartialEq)]
pub struct DemoOptions {
    pub width: u32,
    pub height: u32,
    /// Frames per split.
    pub train: usize,
    pub val: usize,
    pub test: usize,
    /// Seeds the random training cameras.
    pub seed: u64,
}

impl Default for DemoOptions {
    fn default() -> Self {
        DemoOptions {
            width: 200,
            height: 200,
            train: 60,
            val: 10,
            test: 10,
            seed: 0,
        }
    }
}

/// OpenGL camera-to-world matrix (Blender `transform_matrix`) of a camera at
/// [`CAMERA_RADIUS`], azimuth `azimuth` and elevation `elevation` (radians, z up),
/// looking at the origin with world z up on screen.
pub fn orbit_pose(azimuth: f64, elevation: f64) -> [[f64; 4]; 4] {
    let eye = [
        CAMERA_RADIUS * elevation.cos() * azimuth.cos(),
        CAMERA_RADIUS * elevation.cos() * azimuth.sin(),
        CAMERA_RADIUS * elevation.sin(),
    ];
    let cv = Camera::look_at(eye, [0.0; 3], [0.0, 0.0, 1.0], CAMERA_ANGLE_X, 1, 1);
    // OpenCV (x right, y down, z forward) → OpenGL (x right, y up, looking down −z).
    let mut gl = [[0.0; 4]; 4];
    for (row, c) in gl.iter_mut().zip(&cv.c2w) {
        *row = [c[0], -c[1], -c[2], c[3]];
    }
    gl[3] = [0.0, 0.0, 0.0, 1.0];
    gl
}

/// The OpenGL poses of each split (`train`, `val`, `test`), deterministic from the
/// seed. Training cameras are uniform over the band of the sphere from 6° below to 72°
/// above the horizon; validation and test cameras lie on rings at 20° and 30° elevation.
pub fn split_poses(opts: &DemoOptions) -> [(&'static str, Vec<[[f64; 4]; 4]>); 3] {
    use std::f64::consts::TAU;
    let mut rng = Pcg64::seed_from_u64(opts.seed);
    let train = (0..opts.train)
        .map(|_| {
            let azimuth = rng.gen_range(0.0..TAU);
            let z: f64 = rng.gen_range(-0.1..0.95);
            orbit_pose(azimuth, z.asin())
        })
        .collect();
    let ring = |n: usize, elevation_deg: f64, phase: f64| -> Vec<[[f64; 4]; 4]> {
        (0..n)
            .map(|k| {
                orbit_pose(
                    TAU * (k as f64 + phase) / n as f64,
                    elevation_deg.to_radians(),
                )
            })
            .collect()
    };
    [
        ("train", train),
        ("val", ring(opts.val, 20.0, 0.5)),
        ("test", ring(opts.test, 30.0, 0.0)),
    ]
}

/// One split of the demo dataset: its name, the text of its transforms file, and the
/// cameras exactly as a loader reads them back from that text (JSON numbers may parse
/// back an ulp off what was written, so the images are rendered with these).
#[derive(Clone, Debug, PartialEq)]
pub struct DemoSplit {
    pub name: &'static str,
    pub transforms: String,
    pub cameras: Vec<Camera>,
}

/// The transforms files and cameras of the demo dataset (see [`split_poses`]).
pub fn demo_splits(opts: &DemoOptions) -> Result<Vec<DemoSplit>> {
    if opts.width == 0 || opts.height == 0 || opts.width > 16384 || opts.height > 16384 {
        return Err(Error::Invalid(format!(
            "demo image size {}×{} must be between 1 and 16384 per side",
            opts.width, opts.height
        )));
    }
    if opts.train == 0 || opts.val == 0 || opts.test == 0 {
        return Err(Error::Invalid(format!(
            "demo dataset needs at least one frame per split (train {}, val {}, test {})",
            opts.train, opts.val, opts.test
        )));
    }
    let internal = |what: String| Error::Invalid(format!("demo transforms: {what}"));
    let mut out = Vec::new();
    for (name, poses) in split_poses(opts) {
        let frames: Vec<serde_json::Value> = poses
            .iter()
            .enumerate()
            .map(|(i, pose)| {
                serde_json::json!({
                    "file_path": format!("./{name}/r_{i}"),
                    "rotation": 0.0,
                    "transform_matrix": pose,
                })
            })
            .collect();
        let doc = serde_json::json!({ "camera_angle_x": CAMERA_ANGLE_X, "frames": frames });
        let transforms = serde_json::to_string_pretty(&doc).map_err(|e| internal(e.to_string()))?;
        // Read it back the way the loader does.
        let back: serde_json::Value =
            serde_json::from_str(&transforms).map_err(|e| internal(e.to_string()))?;
        let angle = back["camera_angle_x"]
            .as_f64()
            .ok_or_else(|| internal("camera_angle_x".into()))?;
        let cameras = (0..poses.len())
            .map(|i| {
                let m = parse_matrix(&back["frames"][i]["transform_matrix"]).map_err(internal)?;
                Ok(Camera::from_opengl(m, angle, opts.width, opts.height))
            })
            .collect::<Result<Vec<_>>>()?;
        out.push(DemoSplit {
            name,
            transforms,
            cameras,
        });
    }
    Ok(out)
}

/// Writes the demo dataset to `dir`: `transforms_{train,val,test}.json` (NeRF-synthetic
/// format, `file_path` like `./train/r_0` without extension) and 8-bit RGBA PNGs with a
/// transparent background in `train/`, `val/`, `test/`. Everything is deterministic
/// from `opts.seed`. Images are rendered in parallel (rayon); the JSON files are written last,
/// so they never reference missing images.
pub fn write_dataset(dir: &Path, opts: &DemoOptions) -> Result<()> {
    let splits = demo_splits(opts)?;
    let mut jobs: Vec<(PathBuf, &Camera)> = Vec::new();
    for split in &splits {
        let sub_dir = dir.join(split.name);
        std::fs::create_dir_all(&sub_dir).map_err(|e| io_error(&sub_dir, e))?;
        for (i, camera) in split.cameras.iter().enumerate() {
            jobs.push((sub_dir.join(format!("r_{i}.png")), camera));
        }
    }

    use rayon::prelude::*;
    jobs.par_iter().try_for_each(|(path, camera)| {
        let rgba = render_rgba(camera);
        save_rgba_png(path, camera.width, camera.height, &rgba)
    })?;
    for split in &splits {
        let path = dir.join(format!("transforms_{}.json", split.name));
        write_atomic(&path, split.transforms.as_bytes())?;
    }
    Ok(())
}

/// Inverse of the density activation `explin(x) = x if x > 1.1 else
/// exp(x/1.1 − 1 + ln 1.1)`, for `sigma > 0`.
pub fn inverse_explin(sigma: f64) -> f64 {
    if sigma > 1.1 {
        sigma
    } else {
        1.1 * ((sigma / 1.1).ln() + 1.0)
    }
}

/// Density activation (as the renderer applies it after interpolating raw values).
pub fn explin(x: f64) -> f64 {
    if x > 1.1 {
        x
    } else {
        (x / 1.1 - 1.0 + 1.1f64.ln()).exp()
    }
}

/// Target density inside the voxelized primitives for finest voxel size `w`: 50, or more
/// for very fine voxels, so that `100 · w · density ≥ 10` (a finest voxel is opaque).
pub fn solid_density(w: f64) -> f64 {
    50f64.max(0.1 / w)
}

/// Raw grid-point density at signed distance `d` for finest voxel size `w`: the
/// inverse-explin of a target density that ramps smoothly (smoothstep) from
/// [`solid_density`] at `d = −w/2` to 0 at `d = +w/2`, floored at [`RAW_EMPTY`].
pub fn raw_density(d: f64, w: f64) -> f32 {
    let t = (0.5 - d / w).clamp(0.0, 1.0);
    let s = t * t * (3.0 - 2.0 * t);
    let sigma = solid_density(w) * s;
    if sigma <= 0.0 {
        return RAW_EMPTY;
    }
    (inverse_explin(sigma) as f32).max(RAW_EMPTY)
}

/// Diffuse colour of primitive `prim` at surface point `p` with normal `n` (ambient +
/// shadowed directional light, no highlight), clamped to `[0, 1]`.
pub fn diffuse_color(prim: usize, p: DVec3, n: DVec3) -> DVec3 {
    let ndl = n.dot(light_dir()).max(0.0);
    let lit = if ndl > 0.0 && !in_shadow(p, n) {
        1.0
    } else {
        0.0
    };
    (PRIMITIVES[prim].color * (AMBIENT + DIFFUSE * ndl * lit)).clamp(DVec3::ZERO, DVec3::ONE)
}

/// Builds a sparse-voxel [`Scene`] of the demo primitives directly (no training).
///
/// Root cube: centre [`VOXEL_CENTER`], extent [`VOXEL_EXTENT`] (`[-1.5, 1.5]³`);
/// white background. Refinement starts at level 1: a voxel whose box may meet the
/// surface (`|signed distance at its centre| ≤ half its diagonal`) is subdivided until
/// `max_level`; voxels wholly inside a primitive are kept at their level; empty ones are
/// dropped. Grid points get [`raw_density`] of their signed distance (transition over
/// one finest voxel). Each voxel's sh0 encodes the diffuse colour of its nearest
/// primitive, shaded for the normal and shadowing at the nearest surface point; higher
/// SH are zero.
pub fn voxelize(max_level: u32, sh_degree: u32) -> Result<Scene> {
    if !(1..=MAX_VOXELIZE_LEVEL).contains(&max_level) {
        return Err(Error::Invalid(format!(
            "voxelize: max_level {max_level} must be in 1..={MAX_VOXELIZE_LEVEL}"
        )));
    }
    if sh_degree > MAX_SH_DEGREE {
        return Err(Error::Invalid(format!(
            "voxelize: sh_degree {sh_degree} is above the supported maximum {MAX_SH_DEGREE}"
        )));
    }
    let extent = VOXEL_EXTENT as f64;
    let lo = DVec3::from(VOXEL_CENTER.map(f64::from)) - 0.5 * extent;
    let mut octpath = Vec::new();
    let mut octlevel = Vec::new();
    let mut frontier: Vec<[u32; 3]> = (0..8u32).map(|c| [c >> 2, (c >> 1) & 1, c & 1]).collect();
    for level in 1..=max_level {
        let size = extent / (1u64 << level) as f64;
        let half_diag = 0.5 * size * 3f64.sqrt();
        let mut next = Vec::new();
        for ijk in frontier {
            let c = lo + (DVec3::from(ijk.map(f64::from)) + 0.5) * size;
            let d = signed_distance(c);
            if d.abs() <= half_diag && level < max_level {
                for k in 0..8u32 {
                    next.push([
                        2 * ijk[0] + (k >> 2),
                        2 * ijk[1] + ((k >> 1) & 1),
                        2 * ijk[2] + (k & 1),
                    ]);
                }
            } else if d <= half_diag {
                octpath.push(octpath_from_ijk(ijk, level));
                octlevel.push(level as u8);
            }
        }
        frontier = next;
    }

    let mut scene = Scene::from_voxels(
        VOXEL_CENTER,
        VOXEL_EXTENT,
        sh_degree,
        octpath,
        octlevel,
        RAW_EMPTY,
    )?;
    scene.background = [1.0; 3];
    let w = extent / (1u64 << max_level) as f64;
    for (g, &key) in scene.grid_keys.iter().enumerate() {
        let p = scene.fine_to_world(key_coords(key));
        scene.geo[g] = raw_density(signed_distance(p.into()), w);
    }
    for i in 0..scene.num_voxels() {
        let c = DVec3::from(scene.voxel_center(i));
        let (prim, d) = nearest_primitive(c);
        let n = PRIMITIVES[prim].shape.normal(c);
        let color = diffuse_color(prim, c - n * d, n);
        scene.sh0[i] = ((color - 0.5) / SH_C0).as_vec3().to_array();
    }
    scene.validate()?;
    Ok(scene)
}

/// `v` scaled to unit length (a true division, as the f64 references in tests/ do).
fn unit(v: DVec3) -> DVec3 {
    v / v.length()
}

/// Points on the demo scene's visible surface, about `spacing` apart: samples on every
/// primitive's surface (uniform by area, fixed seed) that lie on the union's boundary
/// (inside no other primitive) and that a camera at one of `eyes` sees (its ray to the
/// point hits nothing before it). The ground truth of mesh accuracy tests.
pub fn surface_samples(eyes: &[[f64; 3]], spacing: f64) -> Vec<[f64; 3]> {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(17);
    let mut out = Vec::new();
    for (pi, prim) in PRIMITIVES.iter().enumerate() {
        type Sampler = Box<dyn Fn(&mut rand_pcg::Pcg64) -> DVec3>;
        let (area, sample): (f64, Sampler) = match prim.shape {
            Shape::Sphere { center, radius } => (
                4.0 * std::f64::consts::PI * radius * radius,
                Box::new(move |r: &mut rand_pcg::Pcg64| {
                    let z: f64 = r.gen_range(-1.0..1.0);
                    let phi: f64 = r.gen_range(0.0..std::f64::consts::TAU);
                    let s = (1.0 - z * z).sqrt();
                    center + DVec3::new(s * phi.cos(), s * phi.sin(), z) * radius
                }),
            ),
            Shape::Box { center, half } => {
                let faces = [half.y * half.z, half.x * half.z, half.x * half.y];
                let total = 8.0 * (faces[0] + faces[1] + faces[2]);
                (
                    total,
                    Box::new(move |r: &mut rand_pcg::Pcg64| {
                        let pick = r.gen_range(0.0..faces[0] + faces[1] + faces[2]);
                        let axis = if pick < faces[0] {
                            0
                        } else if pick < faces[0] + faces[1] {
                            1
                        } else {
                            2
                        };
                        let mut p = DVec3::new(
                            r.gen_range(-1.0..1.0),
                            r.gen_range(-1.0..1.0),
                            r.gen_range(-1.0..1.0),
                        );
                        p[axis] = if r.gen_bool(0.5) { 1.0 } else { -1.0 };
                        center + p * half
                    }),
                )
            }
        };
        let n = (area / (spacing * spacing)).ceil() as usize;
        for _ in 0..n {
            let p = sample(&mut rng);
            let inside_other = PRIMITIVES
                .iter()
                .enumerate()
                .any(|(j, q)| j != pi && q.shape.signed_distance(p) < 0.0);
            if inside_other {
                continue;
            }
            let seen = eyes.iter().any(|e| {
                let e = DVec3::from(*e);
                let to = p - e;
                let dist = to.length();
                match ray_hit(e, to / dist) {
                    Some(h) => h.t > dist - 1e-6 * dist.max(1.0),
                    None => true,
                }
            });
            if seen {
                out.push(p.to_array());
            }
        }
    }
    out
}
