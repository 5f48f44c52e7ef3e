//! The demo scene as sparse voxels without training ([`voxelize`]): densities from the
//! signed distance to the primitives, colours from their diffuse shading, and surface
//! samples for mesh evaluation.

use glam::DVec3;

use super::scene::{
    in_shadow, light_dir, nearest_primitive, ray_hit, signed_distance, Shape, AMBIENT, DIFFUSE,
    PRIMITIVES,
};
use crate::error::{Error, Result};
use crate::scene::{key_coords, octpath_from_ijk, Scene, MAX_SH_DEGREE};

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

/// Points on the demo scene's visible surface, about `spacing` apart: samples on every
/// primitive's surface (uniform by area, fixed seed) that lie on the union's boundary
/// (inside no other primitive) and that a camera at one of `eyes` sees (its ray to the
/// point hits nothing before it). The ground truth of mesh accuracy tests. A spacing
/// that asks for more than [`crate::mesh::metrics::MAX_MESH_SAMPLES`] samples is refused.
pub fn surface_samples(eyes: &[[f64; 3]], spacing: f64) -> crate::error::Result<Vec<[f64; 3]>> {
    use rand::{Rng, SeedableRng};
    let max = crate::mesh::metrics::MAX_MESH_SAMPLES;
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
        let wanted = (area / (spacing * spacing)).ceil();
        if !(spacing > 0.0 && wanted <= max) {
            return Err(crate::error::Error::Invalid(format!(
                "the demo's surface sampled every {spacing:.3e} takes more than {max} points: \
                 give a larger --threshold (samples are threshold/5 apart)"
            )));
        }
        for _ in 0..wanted as usize {
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
    Ok(out)
}
