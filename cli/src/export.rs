//! `svraster export`: a model for other tools. `ply`: one point per voxel (centre in the
//! dataset's world coordinates, edge length, level, density and DC colour), a point cloud
//! MeshLab, CloudCompare, Open3D or plyfile open. `splat`: one 3D Gaussian per voxel in
//! the 3D Gaussian Splatting PLY layout that splat viewers and editors open.
//! `quantized`: the 8-bit checkpoint of [`svraster::scene::quantize`] that `render`,
//! `eval`, `mesh` and the viewer load like any model.

use std::path::Path;

use svraster::data::demo::{explin, SH_C0};
use svraster::scene::{checkpoint, Scene};

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ExportFormat {
    Ply,
    Splat,
    Quantized,
}

pub fn run(model: &Path, format: ExportFormat, out: &Path, json: bool) -> anyhow::Result<()> {
    let model_file = super::inputs::model_path(model)?;
    let (what, extensions): (&str, &[&str]) = match format {
        ExportFormat::Ply => ("the voxel point cloud", &["ply"]),
        ExportFormat::Splat => ("the 3D Gaussian Splatting PLY", &["ply"]),
        ExportFormat::Quantized => ("the quantized model", &["safetensors"]),
    };
    super::outputs::check_file(
        out,
        &super::outputs::OutputFile {
            flag: "--out",
            what,
            extensions,
            inputs: &[("the model", &model_file)],
        },
    )?;
    let scene = super::inputs::load_model(model)?;
    // Counted here, not read back: a pipe or /dev/null has no size.
    let written;
    let (name, line) = match format {
        ExportFormat::Ply => {
            let bytes = voxel_ply(&scene);
            svraster::fsio::write_atomic(out, &bytes)?;
            written = bytes.len();
            (
                "ply",
                format!(
                    "wrote {}: {} voxels as points (x y z size level density red green blue), \
                     {:.1} MiB",
                    out.display(),
                    scene.num_voxels(),
                    bytes.len() as f64 / (1 << 20) as f64
                ),
            )
        }
        ExportFormat::Splat => {
            let bytes = gaussian_ply(&scene);
            svraster::fsio::write_atomic(out, &bytes)?;
            written = bytes.len();
            (
                "splat",
                format!(
                    "wrote {}: {} voxels as 3D Gaussians (3DGS PLY: x y z, f_dc, 45 f_rest, \
                     opacity, scale, rot), {:.1} MiB",
                    out.display(),
                    scene.num_voxels(),
                    bytes.len() as f64 / (1 << 20) as f64
                ),
            )
        }
        ExportFormat::Quantized => {
            let full = checkpoint::to_bytes(&scene)?.len();
            let bytes = checkpoint::to_bytes_quantized(&scene)?;
            svraster::fsio::write_atomic(out, &bytes)?;
            let q = bytes.len();
            written = q;
            (
                "quantized",
                format!(
                    "wrote {}: 8-bit quantized, {:.2} MiB ({:.0} % smaller than the {:.2} MiB \
                     checkpoint)",
                    out.display(),
                    q as f64 / (1 << 20) as f64,
                    100.0 * (1.0 - q as f64 / full as f64),
                    full as f64 / (1 << 20) as f64
                ),
            )
        }
    };
    if json {
        let doc = serde_json::json!({
            "out": out,
            "format": name,
            "bytes": written,
            "voxels": scene.num_voxels(),
        });
        println!("{}", serde_json::to_string_pretty(&doc)?);
    } else {
        println!("{line}");
    }
    Ok(())
}

/// Higher-order SH coefficients per colour channel in the 3DGS layout (degree 3).
const SPLAT_REST: usize = 15;

/// The binary little-endian 3D Gaussian Splatting PLY of the voxels: per voxel one
/// Gaussian (what splat viewers read, as the 3DGS reference writes it):
/// - `x y z`: the voxel's centre (world), `nx ny nz` 0;
/// - `f_dc_0..2`, `f_rest_0..44`: its SH coefficients (the same basis, constants and
///   signs as 3DGS, so copied as they are; `f_rest` channel-major, zeros above the
///   model's degree);
/// - `opacity`: logit of the voxel's opacity along an edge-long ray through its centre,
///   α = 1 − exp(−100·edge·explin(centre density)) in the model's units, clamped to
///   [1e-6, 0.99999];
/// - `scale_0..2`: ln σ with σ = edge/√12 (world), the standard deviation of the cube's
///   uniform density along each axis; `rot_0..3`: the identity quaternion (w first).
///
/// What a Gaussian cannot keep: the density's trilinear variation inside the voxel, the
/// cube's sharp faces and the exact depth order (splats are sorted by centre).
pub fn gaussian_ply(scene: &Scene) -> Vec<u8> {
    let n = scene.num_voxels();
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment svraster-vk voxels as 3D Gaussians\n\
         element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\n"
    );
    for c in 0..3 {
        header += &format!("property float f_dc_{c}\n");
    }
    for k in 0..3 * SPLAT_REST {
        header += &format!("property float f_rest_{k}\n");
    }
    header += "property float opacity\n";
    for a in 0..3 {
        header += &format!("property float scale_{a}\n");
    }
    for a in 0..4 {
        header += &format!("property float rot_{a}\n");
    }
    header += "end_header\n";
    let per = 9 + 3 * SPLAT_REST + 8;
    let mut out = Vec::with_capacity(header.len() + n * per * 4);
    out.extend_from_slice(header.as_bytes());
    let coeffs = scene.shs_per_voxel();
    let mut push = |v: f64| out.extend_from_slice(&(v as f32).to_le_bytes());
    for i in 0..n {
        let s = scene.voxel_size(i);
        let lo = scene.voxel_min(i);
        let c = scene
            .world
            .point_to_world(std::array::from_fn(|a| lo[a] + 0.5 * s));
        c.iter().for_each(|&v| push(v));
        (0..3).for_each(|_| push(0.0));
        scene.sh0[i].iter().for_each(|&v| push(f64::from(v)));
        for ch in 0..3 {
            for k in 0..SPLAT_REST {
                push(if k < coeffs {
                    f64::from(scene.shs[(i * coeffs + k) * 3 + ch])
                } else {
                    0.0
                });
            }
        }
        let mean = scene.corners[i]
            .iter()
            .map(|&g| scene.geo[g as usize] as f64)
            .sum::<f64>()
            / 8.0;
        let alpha = (1.0 - (-100.0 * s * explin(mean)).exp()).clamp(1e-6, 0.99999);
        push((alpha / (1.0 - alpha)).ln());
        let sigma = scene.world.length_to_world(s) / 12f64.sqrt();
        (0..3).for_each(|_| push(sigma.ln()));
        [1.0, 0.0, 0.0, 0.0].into_iter().for_each(&mut push);
    }
    out
}

/// The binary little-endian PLY of the voxels: `float x y z` (centre, world), `float
/// size` (edge, world), `uchar level`, `float density` (the activated density at the
/// centre, `explin` of the mean corner value, per model unit length), `uchar red green
/// blue` (the degree-0 colour 0.5 + C0·sh0, clamped).
pub fn voxel_ply(scene: &Scene) -> Vec<u8> {
    let n = scene.num_voxels();
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment svraster-vk voxels\nelement vertex {n}\n\
         property float x\nproperty float y\nproperty float z\nproperty float size\n\
         property uchar level\nproperty float density\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    );
    let mut out = Vec::with_capacity(header.len() + n * 24);
    out.extend_from_slice(header.as_bytes());
    for i in 0..n {
        let s = scene.voxel_size(i);
        let lo = scene.voxel_min(i);
        let c = scene
            .world
            .point_to_world(std::array::from_fn(|a| lo[a] + 0.5 * s));
        for v in c {
            out.extend_from_slice(&(v as f32).to_le_bytes());
        }
        out.extend_from_slice(&(scene.world.length_to_world(s) as f32).to_le_bytes());
        out.push(scene.octlevel[i]);
        let mean = scene.corners[i]
            .iter()
            .map(|&g| scene.geo[g as usize] as f64)
            .sum::<f64>()
            / 8.0;
        out.extend_from_slice(&(explin(mean) as f32).to_le_bytes());
        for ch in scene.sh0[i] {
            let v = (0.5 + SH_C0 * ch as f64).clamp(0.0, 1.0);
            out.push((v * 255.0).round() as u8);
        }
    }
    out
}
