//! Real-capture input: COLMAP models (binary and text), COLMAP's camera models, lens
//! removal at load, splits, and the real captures in ../shared/data when present.

use crate::common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde_json::json;
use svraster::data::capture::{self, load_colmap, load_shots, natural_cmp, CaptureOptions, Shot};
use svraster::data::colmap::{self, ColmapCamera, ColmapImage, ColmapPoint, Reconstruction};
use svraster::data::image::save_rgb_png;
use svraster::data::lens::{CameraModel, Lens};
use tempfile::TempDir;

/// A fresh directory named `svraster-capture-<name>-…`, removed when dropped.
fn tmp(name: &str) -> TempDir {
    tempfile::Builder::new()
        .prefix(&format!("svraster-capture-{name}-"))
        .tempdir()
        .unwrap()
}

/// Realistic parameters for each model at `w × h` (moderate distortion).
fn params(model: CameraModel, w: f64, h: f64) -> Vec<f64> {
    let (f, cx, cy) = (0.9 * w, 0.5 * w + 1.3, 0.5 * h - 0.7);
    let extra: &[f64] = match model {
        CameraModel::SimpleRadial | CameraModel::SimpleRadialFisheye => &[0.03],
        CameraModel::Radial | CameraModel::RadialFisheye => &[-0.05, 0.01],
        CameraModel::OpenCv => &[-0.06, 0.012, 0.001, -0.0015],
        CameraModel::OpenCvFisheye => &[0.02, -0.01, 0.003, -0.001],
        CameraModel::FullOpenCv => &[-0.05, 0.01, 0.001, -0.001, 0.002, 0.01, -0.003, 0.001],
        CameraModel::Fov => &[0.3],
        CameraModel::ThinPrismFisheye => {
            &[0.02, -0.01, 0.001, -0.001, 0.003, -0.001, 0.0005, -0.0004]
        }
        CameraModel::RadTanThinPrismFisheye => &[
            0.02, -0.01, 0.003, -0.001, 0.0002, -0.0001, 0.001, -0.001, 0.0005, -0.0002, 0.0004,
            0.0001,
        ],
        CameraModel::SimpleDivision | CameraModel::Division => &[-0.04],
        CameraModel::Eucm => &[0.4, 1.1],
        _ => &[],
    };
    let mut p = if model.param_names()[0] == "f" {
        vec![f, cx, cy]
    } else if model == CameraModel::Equirectangular {
        return vec![w, h];
    } else {
        vec![f, 1.02 * f, cx, cy]
    };
    p.extend_from_slice(extra);
    p
}

/// A reconstruction using every camera model, with points and tracks.
fn every_model_reconstruction() -> Reconstruction {
    let mut rng = common::Rng(5);
    let mut rec = Reconstruction::default();
    for (k, model) in CameraModel::all().enumerate() {
        let id = 10 + k as u32;
        rec.cameras.insert(
            id,
            ColmapCamera {
                id,
                model,
                width: 640 + k as u64,
                height: 480,
                params: params(model, 640.0 + k as f64, 480.0),
            },
        );
        let q: [f64; 4] = std::array::from_fn(|_| rng.range(-1.0, 1.0));
        let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        rec.images.insert(
            100 + k as u32,
            ColmapImage {
                id: 100 + k as u32,
                qvec: q.map(|v| v / n),
                tvec: std::array::from_fn(|_| rng.range(-3.0, 3.0)),
                camera_id: id,
                name: format!("dir/img {k}.jpg"),
                points2d: (0..k)
                    .map(|j| ([rng.range(0.0, 640.0), rng.range(0.0, 480.0)], j as i64 - 1))
                    .collect(),
            },
        );
    }
    rec.points = (0..7)
        .map(|i| ColmapPoint {
            id: 1000 + i,
            xyz: std::array::from_fn(|_| rng.range(-5.0, 5.0)),
            rgb: [i as u8, 200, 17],
            error: rng.unit(),
            track: (0..i as u32).map(|j| (100 + j, 2 * j)).collect(),
        })
        .collect();
    rec
}

#[track_caller]
fn expect_err(dir: &Path, needles: &[&str]) {
    let e = match colmap::read_model(dir) {
        Ok(_) => panic!("a corrupt model was accepted (expected {needles:?})"),
        Err(e) => e.to_string(),
    };
    for n in needles {
        assert!(e.contains(n), "error `{e}` does not mention `{n}`");
    }
}

/// A smooth test pattern on the plane z = 1 of the camera: the colour a ray through the
/// normalised point `(u, v)` sees.
fn pattern(u: f64, v: f64) -> [f32; 3] {
    [
        (0.5 + 0.4 * (3.0 * u + 1.0).sin() * (2.0 * v).cos()) as f32,
        (0.5 + 0.4 * (2.5 * v - 0.5).sin()) as f32,
        (0.5 + 0.3 * (4.0 * (u + v)).cos()) as f32,
    ]
}

fn shared(name: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data")
        .join(name);
    if p.is_dir() {
        Some(p)
    } else {
        println!("skipped: {} is absent", p.display());
        None
    }
}

// ---------------------------------------------------------------------------------------
// Unbounded scenes: main region and background shells

use svraster::adapt::shells::{initial_shells, inside_grid, quantile, shell_layout};
use svraster::data::Camera;
use svraster::train::bounds::main_region;

/// The main grid fills exactly the central cube; the shells tile the rest of the root
/// cube without overlap (volumes add up to root³ − main³, no two cells overlap).
#[test]
fn shells_tile_the_root_outside_the_main_region() {
    assert_eq!(inside_grid(0, 3).len(), 512);
    for (o, g) in [(1u32, 2u32), (3, 2), (5, 1)] {
        let inside = inside_grid(o, g);
        let shells = initial_shells(o);
        assert_eq!(shells.len(), 56 * o as usize);
        // In units of the root edge, the main cube is [0.5 − 2^−(o+1), 0.5 + 2^−(o+1)]³.
        let half = 0.5f64.powi(o as i32 + 1);
        let boxes: Vec<([f64; 3], f64)> = inside
            .iter()
            .chain(&shells)
            .map(|&(ijk, l)| {
                let s = 0.5f64.powi(l as i32);
                (ijk.map(|v| v as f64 * s), s)
            })
            .collect();
        for (k, (lo, s)) in boxes.iter().enumerate() {
            let is_inside = k < inside.len();
            let within = lo
                .iter()
                .all(|&v| v >= 0.5 - half - 1e-12 && v + s <= 0.5 + half + 1e-12);
            assert_eq!(within, is_inside, "o {o}: cell {k} at {lo:?} size {s}");
        }
        let volume: f64 = boxes[inside.len()..].iter().map(|b| b.1.powi(3)).sum();
        assert!(
            (volume - (1.0 - (2.0 * half).powi(3))).abs() < 1e-12,
            "o {o}: {volume}"
        );
        let main: f64 = boxes[..inside.len()].iter().map(|b| b.1.powi(3)).sum();
        assert!((main - (2.0 * half).powi(3)).abs() < 1e-12);
        // Pairwise disjoint (cells of one level are distinct; cells of different levels
        // lie in different shells).
        let mut keys: Vec<_> = inside.iter().chain(&shells).collect();
        keys.sort();
        keys.dedup();
        assert_eq!(keys.len(), boxes.len());
    }
    assert_eq!(quantile(&[0.0, 1.0, 2.0, 3.0, 4.0], 0.9), 3.6);
}

fn ring_cameras(n: usize, radius: f64, center: [f64; 3], w: u32) -> Vec<Camera> {
    (0..n)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / n as f64;
            let eye = [
                center[0] + radius * a.cos(),
                center[1] + radius * a.sin(),
                center[2] + 0.3 * radius,
            ];
            Camera::look_at(eye, center, [0.0, 0.0, 1.0], 1.2, w, w)
        })
        .collect()
}

/// Writes a float64 C-order `.npy` file (format 1.0) of `rows × cols`.
fn write_npy(path: &Path, rows: usize, cols: usize, v: &[f64]) {
    let mut header =
        format!("{{'descr': '<f8', 'fortran_order': False, 'shape': ({rows}, {cols}), }}");
    while !(10 + header.len() + 1).is_multiple_of(64) {
        header.push(' ');
    }
    header.push('\n');
    let mut b = b"\x93NUMPY\x01\x00".to_vec();
    b.extend((header.len() as u16).to_le_bytes());
    b.extend(header.as_bytes());
    v.iter().for_each(|x| b.extend(x.to_le_bytes()));
    std::fs::write(path, b).unwrap();
}

// ---------------------------------------------------------------------------------
// NeuS / DTU layout: cameras_sphere.npz + image/ + mask/.

/// A `.npy` (v1.0, little-endian f64, C order) of a 4×4 matrix.
fn npy4(m: &[[f64; 4]; 4]) -> Vec<u8> {
    let mut header = "{'descr': '<f8', 'fortran_order': False, 'shape': (4, 4), }".to_string();
    while !(10 + header.len() + 1).is_multiple_of(64) {
        header.push(' ');
    }
    header.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for row in m {
        for x in row {
            out.extend_from_slice(&x.to_le_bytes());
        }
    }
    out
}

/// Writes a NeuS capture of the demo scene seen by `cams` (photos and masks from the
/// analytic renderer); the sphere is `centre`, `radius`. Returns the 8-bit photos and
/// masks as written.
#[allow(clippy::type_complexity)]
fn write_neus(
    dir: &Path,
    cams: &[svraster::Camera],
    centre: [f64; 3],
    radius: f64,
) -> Vec<(Vec<[f32; 3]>, Vec<f32>)> {
    use std::io::Write;
    std::fs::create_dir_all(dir.join("image")).unwrap();
    std::fs::create_dir_all(dir.join("mask")).unwrap();
    let f = std::fs::File::create(dir.join("cameras_sphere.npz")).unwrap();
    let mut zip = zip::ZipWriter::new(f);
    let opts: zip::write::SimpleFileOptions =
        zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    let scale = [
        [radius, 0.0, 0.0, centre[0]],
        [0.0, radius, 0.0, centre[1]],
        [0.0, 0.0, radius, centre[2]],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let mut written = Vec::new();
    for (i, c) in cams.iter().enumerate() {
        // K with NeuS's integer pixel centres, [R | t] world to camera; P up to a scale
        // (negative for one view: the decomposition must fix the sign).
        let k = [
            [c.fx, 0.0, c.cx - 0.5],
            [0.0, c.fy, c.cy - 0.5],
            [0.0, 0.0, 1.0],
        ];
        let w2c = c.w2c();
        let s = if i == 1 { -2.5 } else { 3.7 };
        let mut p = [[0.0; 4]; 4];
        for r in 0..3 {
            for col in 0..4 {
                p[r][col] = s * (0..3).map(|j| k[r][j] * w2c[j][col]).sum::<f64>();
            }
        }
        p[3] = [0.0, 0.0, 0.0, 1.0];
        for (name, m) in [
            (format!("world_mat_{i}"), p),
            (format!("scale_mat_{i}"), scale),
        ] {
            zip.start_file(format!("{name}.npy"), opts).unwrap();
            zip.write_all(&npy4(&m)).unwrap();
        }
        let rgba = svraster::data::demo::render_rgba(c);
        let q = |x: f32| (x.clamp(0.0, 1.0) * 255.0).round() / 255.0;
        let rgb: Vec<[f32; 3]> = rgba.iter().map(|p| [q(p[0]), q(p[1]), q(p[2])]).collect();
        let mask: Vec<f32> = rgba.iter().map(|p| q(p[3])).collect();
        save_rgb_png(
            &dir.join(format!("image/{i:06}.png")),
            c.width,
            c.height,
            &rgb,
        )
        .unwrap();
        svraster::data::image::save_gray_png(
            &dir.join(format!("mask/{i:03}.png")),
            c.width,
            c.height,
            &mask,
        )
        .unwrap();
        written.push((rgb, mask));
    }
    zip.finish().unwrap();
    written
}

mod colmap_lenses;
mod other_formats;
