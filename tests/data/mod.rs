//! Dataset loading, PNG I/O, the demo dataset writer and the demo voxelizer.

use std::collections::HashMap;
use std::path::Path;

use svraster::data::demo::{self, DemoOptions, PRIMITIVES};
use svraster::data::image::{load_rgba, save_gray_png, save_rgb_png, save_rgba_png};
use svraster::data::Camera;
use svraster::data::{area_resample, load_split};
use svraster::scene::{ijk_from_octpath, Scene};
use tempfile::TempDir;

/// A fresh folder `svraster-data-<tag>-…` under the system temp dir, removed on drop.
fn temp_dir(tag: &str) -> TempDir {
    tempfile::Builder::new()
        .prefix(&format!("svraster-data-{tag}-"))
        .tempdir()
        .unwrap()
}

const ANGLE: f64 = 0.6911112070083618;
const POSE: &str = "[[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]";

/// The 4×2 test image (RGBA 8-bit).
fn tiny_pixels() -> Vec<[u8; 4]> {
    vec![
        [255, 0, 0, 255],
        [0, 255, 0, 128],
        [0, 0, 255, 0],
        [10, 20, 30, 200],
        [200, 100, 50, 255],
        [255, 255, 255, 64],
        [0, 0, 0, 255],
        [90, 180, 45, 17],
    ]
}

fn write_png8(path: &Path, w: u32, h: u32, px: &[[u8; 4]]) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    let raw: Vec<u8> = px.iter().flatten().copied().collect();
    image::RgbaImage::from_raw(w, h, raw)
        .unwrap()
        .save(path)
        .unwrap();
}

fn transforms(frames: &[&str]) -> String {
    let frames: Vec<String> = frames
        .iter()
        .map(|f| format!(r#"{{"file_path": "{f}", "transform_matrix": {POSE}}}"#))
        .collect();
    format!(
        r#"{{"camera_angle_x": {ANGLE}, "frames": [{}]}}"#,
        frames.join(",")
    )
}

/// A dataset with split `train`: two 4×2 frames `./train/r_0` (png, no extension in
/// the JSON) and `./train/r_1.png` (extension given).
fn tiny_dataset(tag: &str) -> TempDir {
    let dir = temp_dir(tag);
    write_png8(&dir.path().join("train/r_0.png"), 4, 2, &tiny_pixels());
    let mut second = tiny_pixels();
    second.reverse();
    write_png8(&dir.path().join("train/r_1.png"), 4, 2, &second);
    std::fs::write(
        dir.path().join("transforms_train.json"),
        transforms(&["./train/r_0", "./train/r_1.png"]),
    )
    .unwrap();
    dir
}

fn composite(p: [u8; 4], bg: [f32; 3]) -> [f32; 3] {
    let a = p[3] as f32 / 255.0;
    std::array::from_fn(|c| p[c] as f32 / 255.0 * a + bg[c] * (1.0 - a))
}

fn assert_close(a: f64, b: f64, tol: f64, what: &str) {
    assert!((a - b).abs() <= tol, "{what}: {a} vs {b}");
}

/// Writes `json` as `transforms_train.json` next to the tiny images and returns the
/// loader's error message.
fn error_for(tag: &str, json: &str, downscale: f64) -> String {
    let dir = tiny_dataset(tag);
    std::fs::write(dir.path().join("transforms_train.json"), json).unwrap();
    let e = load_split(dir.path(), "train", downscale, [0.0; 3])
        .expect_err("expected an error")
        .to_string();
    assert!(
        e.contains("transforms_train.json") || e.contains(".png"),
        "{e}"
    );
    e
}

fn assert_contains(msg: &str, parts: &[&str]) {
    for p in parts {
        assert!(msg.contains(p), "message lacks {p:?}: {msg}");
    }
}

fn small_demo() -> DemoOptions {
    DemoOptions {
        width: 32,
        height: 32,
        train: 4,
        val: 2,
        test: 2,
        seed: 7,
    }
}

/// Whether any ray of an `n × n` grid spanning pixel `(px, py)` (edges included) hits
/// a demo primitive, and whether all do.
fn pixel_hits(cam: &Camera, px: u32, py: u32, n: u32) -> (bool, bool) {
    let (mut any, mut all) = (false, true);
    for j in 0..n {
        for i in 0..n {
            let u = px as f64 + i as f64 / (n - 1) as f64;
            let v = py as f64 + j as f64 / (n - 1) as f64;
            let d = cam.rotate(cam.camera_dir(u, v));
            let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let hit = demo::ray_hit(cam.origin().into(), d.map(|x| x / l).into()).is_some();
            any |= hit;
            all &= hit;
        }
    }
    (any, all)
}

/// Point → voxel lookup and the renderer's density field (trilinear raw, explin).
struct Field<'a> {
    scene: &'a Scene,
    index: HashMap<(u8, [u32; 3]), usize>,
}

impl<'a> Field<'a> {
    fn new(scene: &'a Scene) -> Self {
        let index = (0..scene.num_voxels())
            .map(|i| {
                let l = scene.octlevel[i];
                ((l, ijk_from_octpath(scene.octpath[i], l as u32)), i)
            })
            .collect();
        Field { scene, index }
    }

    fn density(&self, p: [f64; 3]) -> f64 {
        let lo = -1.5;
        for level in 1..=self.scene.max_level() {
            let size = 3.0 / (1u64 << level) as f64;
            let ijk: [u32; 3] = std::array::from_fn(|a| ((p[a] - lo) / size).floor() as u32);
            if let Some(&i) = self.index.get(&(level as u8, ijk)) {
                let m = self.scene.voxel_min(i);
                let f: [f64; 3] = std::array::from_fn(|a| (p[a] - m[a]) / size);
                let mut raw = 0.0;
                for c in 0..8 {
                    let b = [(c >> 2) & 1, (c >> 1) & 1, c & 1];
                    let w: f64 = (0..3)
                        .map(|a| if b[a] == 1 { f[a] } else { 1.0 - f[a] })
                        .product();
                    raw += w * self.scene.geo[self.scene.corners[i][c] as usize] as f64;
                }
                return demo::explin(raw);
            }
        }
        0.0
    }
}

mod blender_loader;
mod demo_scene;
mod jpeg;
