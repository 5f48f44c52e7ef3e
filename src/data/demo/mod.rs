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
//! [`super::blender::load_split`] reads. [`voxelize`] builds a sparse-voxel [`Scene`](crate::scene::Scene) of
//! the same primitives directly, without training.

use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

use super::blender::parse_matrix;
use super::image::{io_error, save_rgba_png, write_atomic};
use super::Camera;

mod scene;
mod voxelize;
use crate::error::{Error, Result};
pub use scene::{
    label_value, light_dir, nearest_primitive, ray_hit, render_labels, render_rgba, shade,
    signed_distance, Hit, Primitive, Shape, AMBIENT, DIFFUSE, PRIMITIVES, SUPERSAMPLE,
};
pub use voxelize::{
    diffuse_color, explin, inverse_explin, raw_density, solid_density, surface_samples, voxelize,
    MAX_VOXELIZE_LEVEL, RAW_EMPTY, SH_C0, VOXEL_CENTER, VOXEL_EXTENT,
};

/// Horizontal field of view of the demo cameras (as NeRF-synthetic).
pub const CAMERA_ANGLE_X: f64 = 0.6911112070083618;
/// Distance of the demo cameras from the origin.
pub const CAMERA_RADIUS: f64 = 4.0;

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

/// Writes per-primitive label images of every split ([`render_labels`]: 40 times the
/// primitive's index plus one, background 0) as 8-bit gray PNGs `{train,val,test}/r_i.png`
/// in `dir`, named like the frames, for field fusion (`svraster fuse --from DIR/train`).
pub fn write_labels(dir: &Path, opts: &DemoOptions) -> Result<()> {
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
        crate::data::image::save_gray8_png(
            path,
            camera.width,
            camera.height,
            &render_labels(camera),
        )
    })
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
