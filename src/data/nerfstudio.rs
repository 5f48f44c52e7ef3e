//! nerfstudio `transforms.json` captures (what `ns-process-data` writes).
//!
//! ```text
//! { "camera_model": "OPENCV" | "OPENCV_FISHEYE" | "PINHOLE" | "SIMPLE_PINHOLE",
//!   "fl_x", "fl_y", "cx", "cy", "w", "h", "k1", "k2", "k3", "k4", "p1", "p2",
//!   "frames": [ { "file_path": "images/frame_00001.jpg",
//!                 "transform_matrix": [[4] × 4],      // camera-to-world, OpenGL axes
//!                 ...optional per-frame fl_x, fl_y, cx, cy, w, h, k1..k4, p1, p2 } ] }
//! ```
//!
//! Intrinsics are in pixels of `w × h`; a frame's own keys override the global ones.
//! Poses are in nerfstudio's world (its `applied_transform` of the COLMAP world is kept:
//! a rigid change of axes does not change what is trained). Distortion: OPENCV with
//! `k1, k2, p1, p2` (plus `k3` as FULL_OPENCV's r⁶ term), OPENCV_FISHEYE with `k1..k4`.

use std::path::{Path, PathBuf};

use serde_json::Value;

use super::lens::{CameraModel, Lens};
use super::shot::{natural_cmp, Shot};
use crate::error::{Error, Result};

/// The shots of `dir/transforms.json`, sorted by image path, and the image folder their
/// names are relative to (`images/` for the usual layout).
pub fn shots(dir: &Path) -> Result<(PathBuf, Vec<Shot>)> {
    let path = dir.join("transforms.json");
    let text = std::fs::read_to_string(&path).map_err(|error| Error::Io {
        path: path.display().to_string(),
        error,
    })?;
    let bad = |m: String| Error::Invalid(format!("{}: {m}", path.display()));
    let root: Value =
        serde_json::from_str(&text).map_err(|e| bad(format!("not valid JSON ({e})")))?;
    let frames = root["frames"]
        .as_array()
        .ok_or_else(|| bad("no `frames` array".into()))?;
    let mut shots = Vec::with_capacity(frames.len());
    let mut folders = Vec::new();
    for (k, f) in frames.iter().enumerate() {
        let what = |m: String| bad(format!("frame {k}: {m}"));
        let file = f["file_path"]
            .as_str()
            .ok_or_else(|| what("no `file_path`".into()))?;
        // A key that is there must be a number (`"w": "512"` is not a missing `w`).
        for key in [
            "fl_x", "fl_y", "cx", "cy", "w", "h", "k1", "k2", "k3", "k4", "p1", "p2",
        ] {
            if let Some(v) = f.get(key).or_else(|| root.get(key)) {
                if !v.is_null() && v.as_f64().is_none() {
                    return Err(what(format!("`{key}` is {v}, not a number")));
                }
            }
        }
        let get = |key: &str| f.get(key).or_else(|| root.get(key)).and_then(Value::as_f64);
        let need =
            |key: &str| get(key).ok_or_else(|| what(format!("no `{key}` (frame or global)")));
        let (fx, fy) = (need("fl_x")?, get("fl_y").unwrap_or(need("fl_x")?));
        let (w, h) = (need("w")?, need("h")?);
        let (cx, cy) = (get("cx").unwrap_or(0.5 * w), get("cy").unwrap_or(0.5 * h));
        let d = |key: &str| get(key).unwrap_or(0.0);
        let model = f
            .get("camera_model")
            .or_else(|| root.get("camera_model"))
            .and_then(Value::as_str)
            .unwrap_or("OPENCV");
        let lens = match model {
            "OPENCV" | "PINHOLE" | "SIMPLE_PINHOLE" => {
                if d("k4") != 0.0 {
                    return Err(what(
                        "OPENCV with k4 ≠ 0 (an r⁸ term) has no COLMAP equivalent; \
                         re-run ns-process-data with the OPENCV model"
                            .into(),
                    ));
                }
                if d("k3") != 0.0 {
                    Lens::new(
                        CameraModel::FullOpenCv,
                        vec![
                            fx,
                            fy,
                            cx,
                            cy,
                            d("k1"),
                            d("k2"),
                            d("p1"),
                            d("p2"),
                            d("k3"),
                            0.0,
                            0.0,
                            0.0,
                        ],
                    )
                } else {
                    Lens::new(
                        CameraModel::OpenCv,
                        vec![fx, fy, cx, cy, d("k1"), d("k2"), d("p1"), d("p2")],
                    )
                }
            }
            "OPENCV_FISHEYE" => Lens::new(
                CameraModel::OpenCvFisheye,
                vec![fx, fy, cx, cy, d("k1"), d("k2"), d("k3"), d("k4")],
            ),
            other => {
                return Err(what(format!(
                    "camera_model `{other}` is not supported (OPENCV, OPENCV_FISHEYE, PINHOLE)"
                )))
            }
        }
        .map_err(&what)?;
        let m = parse_matrix(&f["transform_matrix"]).ok_or_else(|| {
            what("`transform_matrix` is not a 4×4 (or 3×4) matrix of finite numbers".into())
        })?;
        let full = [m[0], m[1], m[2], [0.0, 0.0, 0.0, 1.0]];
        super::blender::check_rigid(&full).map_err(|why| {
            what(format!(
                "`transform_matrix` is not a rigid camera-to-world transform ({why})"
            ))
        })?;
        // OpenGL (y up, looking down −z) → OpenCV (y down, z forward).
        let c2w = std::array::from_fn(|r| [m[r][0], -m[r][1], -m[r][2], m[r][3]]);
        let p = Path::new(file.trim_start_matches("./"));
        let (folder, name) = match (p.parent(), p.file_name()) {
            (Some(d), Some(n)) => (d.to_path_buf(), n.to_string_lossy().into_owned()),
            _ => (PathBuf::new(), file.to_string()),
        };
        folders.push(folder);
        shots.push(Shot {
            name,
            lens,
            lens_size: (w.round() as u64, h.round() as u64),
            c2w,
        });
    }
    folders.sort();
    folders.dedup();
    let folder = match folders.as_slice() {
        [one] => dir.join(one),
        [] => dir.to_path_buf(),
        _ => {
            return Err(bad(
                "frames are in several folders; this loader expects one image folder".into(),
            ))
        }
    };
    shots.sort_by(|a, b| natural_cmp(&a.name, &b.name));
    Ok((folder, shots))
}

fn parse_matrix(v: &Value) -> Option<[[f64; 4]; 3]> {
    let rows = v.as_array()?;
    if rows.len() != 4 && rows.len() != 3 {
        return None;
    }
    let mut m = [[0.0; 4]; 3];
    for (r, row) in rows.iter().take(3).enumerate() {
        let row = row.as_array()?;
        if row.len() != 4 {
            return None;
        }
        for (c, x) in row.iter().enumerate() {
            m[r][c] = x.as_f64().filter(|x| x.is_finite())?;
        }
    }
    Some(m)
}

/// The capture's sparse points (`ply_file_path` of `dir/transforms.json`, in the frames'
/// world), or none when it names no file.
pub fn points(dir: &Path) -> Result<Vec<[f64; 3]>> {
    let path = dir.join("transforms.json");
    let text = std::fs::read_to_string(&path).map_err(|error| Error::Io {
        path: path.display().to_string(),
        error,
    })?;
    let root: Value = serde_json::from_str(&text)
        .map_err(|e| Error::Invalid(format!("{}: not valid JSON ({e})", path.display())))?;
    match root["ply_file_path"].as_str() {
        Some(p) => super::ply::read_points(&dir.join(p)),
        None => Ok(Vec::new()),
    }
}
