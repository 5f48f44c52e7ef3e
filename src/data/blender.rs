//! Loader for Blender / NeRF-synthetic datasets.
//!
//! A dataset folder holds `transforms_{split}.json` per split and the images they name:
//!
//! ```text
//! { "camera_angle_x": 0.6911,
//!   "frames": [ { "file_path": "./train/r_0", "transform_matrix": [[...4...] ×4] }, ... ] }
//! ```
//!
//! `file_path` is relative to the folder, with or without extension (without one,
//! `.png` is appended). `transform_matrix` is the OpenGL camera-to-world matrix, converted
//! with [`Camera::from_opengl`]. Instant-ngp style intrinsics (`fl_x`, `fl_y`, `cx`, `cy`,
//! `w`, `h`, in pixels of the stored images) are honoured when `fl_x` is present; then
//! `camera_angle_x` is not needed.
//!
//! RGBA images are composited over the chosen background (`rgb·a + bg·(1−a)`) and may be
//! downscaled by any factor `F ≥ 1`: the output is `round(W/F) × round(H/F)` and each
//! output pixel is the exact area average of the input pixels it covers.

use std::path::{Path, PathBuf};

use serde_json::Value;

use super::image::{io_error, load_rgba};
use super::{area_resample, downscaled_size, Camera, Dataset, Frame};
use crate::error::{Error, Result};

/// Intrinsics as stored in the transforms file.
#[derive(Clone, Copy, Debug)]
enum Intrinsics {
    /// NeRF-synthetic: horizontal field of view, square pixels, centred principal point.
    AngleX(f64),
    /// Instant-ngp: focal lengths and principal point in pixels; optional image size.
    Pixels {
        fl_x: f64,
        fl_y: f64,
        cx: Option<f64>,
        cy: Option<f64>,
        w: Option<f64>,
        h: Option<f64>,
    },
}

/// A parsed, not yet loaded frame.
struct FrameSpec {
    name: String,
    image: PathBuf,
    c2w_gl: [[f64; 4]; 4],
}

/// Loads split `split` of the dataset in `dir`: reads `transforms_{split}.json` and its
/// images, composites them over `background` and downscales them by `downscale` (≥ 1,
/// may be fractional). Errors name the offending file and what to do about it.
pub fn load_split(
    dir: &Path,
    split: &str,
    downscale: f64,
    background: [f32; 3],
) -> Result<Dataset> {
    if !downscale.is_finite() || downscale < 1.0 {
        return Err(Error::Invalid(format!(
            "downscale factor must be a finite number ≥ 1, got {downscale}"
        )));
    }
    if background.iter().any(|c| !c.is_finite()) {
        return Err(Error::Invalid(format!(
            "background colour must be finite, got {background:?}"
        )));
    }
    if !dir.is_dir() {
        return Err(io_error(
            dir,
            std::io::Error::new(
                std::io::ErrorKind::NotFound,
                "dataset folder not found; pass the folder that holds transforms_*.json (Blender) \
                 or sparse/0 (COLMAP)",
            ),
        ));
    }
    let transforms = dir.join(format!("transforms_{split}.json"));
    let text = std::fs::read_to_string(&transforms).map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            let found = available_splits(dir);
            let hint = if found.is_empty() {
                "the folder has neither transforms_*.json (Blender / NeRF-synthetic) nor a \
                 COLMAP model in sparse/0 (cameras, images, points3D .bin or .txt)"
                    .to_string()
            } else {
                format!("splits present: {}", found.join(", "))
            };
            io_error(
                &transforms,
                std::io::Error::new(e.kind(), format!("transforms file not found ({hint})")),
            )
        } else {
            io_error(&transforms, e)
        }
    })?;
    let (intrinsics, specs) = parse_transforms(&transforms, dir, &text)?;

    // Decode, composite and downscale in parallel; results keep frame order.
    let results = load_images(&specs, downscale, background);
    let mut loaded = Vec::with_capacity(specs.len());
    for r in results {
        loaded.push(r?);
    }
    let (w0, h0) = (loaded[0].0, loaded[0].1);
    for (i, l) in loaded.iter().enumerate() {
        if (l.0, l.1) != (w0, h0) {
            return Err(Error::Invalid(format!(
                "{}: image {} is {}×{} but {} is {w0}×{h0}; all frames of a split must have \
                 one size",
                transforms.display(),
                specs[i].image.display(),
                l.0,
                l.1,
                specs[0].image.display()
            )));
        }
    }
    let (width, height) = (loaded[0].2, loaded[0].3);

    let mut frames = Vec::with_capacity(specs.len());
    for (spec, (_, _, _, _, rgb)) in specs.into_iter().zip(loaded) {
        let full = full_camera(&transforms, intrinsics, spec.c2w_gl, w0, h0)?;
        let camera = if (width, height) == (w0, h0) {
            full
        } else {
            full.resized(width, height)
        };
        camera.validate().map_err(|e| {
            Error::Invalid(format!(
                "{}: frame {}: {e}",
                transforms.display(),
                spec.name
            ))
        })?;
        frames.push(Frame {
            name: spec.name,
            camera,
            rgb,
        });
    }
    Ok(Dataset {
        frames,
        width,
        height,
        background,
        alpha: true,
        split: split.to_string(),
        points: Vec::new(),
        sphere: None,
    })
}

/// `transforms_*.json` present in `dir`, as split names.
fn available_splits(dir: &Path) -> Vec<String> {
    let mut out: Vec<String> = std::fs::read_dir(dir)
        .map(|rd| {
            rd.filter_map(|e| e.ok())
                .filter_map(|e| {
                    let name = e.file_name().to_string_lossy().into_owned();
                    name.strip_prefix("transforms_")
                        .and_then(|s| s.strip_suffix(".json"))
                        .map(str::to_string)
                })
                .collect()
        })
        .unwrap_or_default();
    out.sort();
    out
}

/// Parses the transforms file: intrinsics and per-frame image path and pose.
fn parse_transforms(
    transforms: &Path,
    dir: &Path,
    text: &str,
) -> Result<(Intrinsics, Vec<FrameSpec>)> {
    let bad = |msg: String| Error::Invalid(format!("{}: {msg}", transforms.display()));
    let root: Value = serde_json::from_str(text).map_err(|e| {
        bad(format!(
            "malformed JSON ({e}); fix the syntax at that position"
        ))
    })?;
    let root = root
        .as_object()
        .ok_or_else(|| bad("the top level must be a JSON object".into()))?;

    let number = |key: &str| -> Result<Option<f64>> {
        match root.get(key) {
            None | Some(Value::Null) => Ok(None),
            Some(v) => match v.as_f64() {
                Some(x) if x.is_finite() => Ok(Some(x)),
                _ => Err(bad(format!("key `{key}` must be a finite number, got {v}"))),
            },
        }
    };
    let intrinsics = if let Some(fl_x) = number("fl_x")? {
        let fl_y = number("fl_y")?.unwrap_or(fl_x);
        if fl_x <= 0.0 || fl_y <= 0.0 {
            return Err(bad(format!(
                "focal lengths fl_x {fl_x}, fl_y {fl_y} must be > 0"
            )));
        }
        Intrinsics::Pixels {
            fl_x,
            fl_y,
            cx: number("cx")?,
            cy: number("cy")?,
            w: number("w")?,
            h: number("h")?,
        }
    } else {
        let angle = number("camera_angle_x")?.ok_or_else(|| {
            bad(
                "missing key `camera_angle_x` (horizontal field of view in radians; \
                 instant-ngp files may give `fl_x` instead)"
                    .into(),
            )
        })?;
        if !(angle > 0.0 && angle < std::f64::consts::PI) {
            return Err(bad(format!(
                "camera_angle_x {angle} is outside (0, π); it is the horizontal field of \
                 view in radians"
            )));
        }
        Intrinsics::AngleX(angle)
    };

    let frames = match root.get("frames") {
        None => return Err(bad("missing key `frames` (the list of views)".into())),
        Some(Value::Array(a)) => a,
        Some(v) => {
            return Err(bad(format!(
                "key `frames` must be an array, got {}",
                type_name(v)
            )))
        }
    };
    if frames.is_empty() {
        return Err(bad(
            "the `frames` list is empty; the split needs at least one view".into(),
        ));
    }
    let mut specs = Vec::with_capacity(frames.len());
    for (i, f) in frames.iter().enumerate() {
        let f = f
            .as_object()
            .ok_or_else(|| bad(format!("frames[{i}] must be an object")))?;
        let file_path = match f.get("file_path") {
            Some(Value::String(s)) if !s.is_empty() => s.as_str(),
            Some(v) => {
                return Err(bad(format!(
                    "frames[{i}].file_path must be a non-empty string, got {v}"
                )))
            }
            None => return Err(bad(format!("frames[{i}] is missing key `file_path`"))),
        };
        let m = f
            .get("transform_matrix")
            .ok_or_else(|| bad(format!("frames[{i}] is missing key `transform_matrix`")))?;
        let c2w_gl = parse_matrix(m).map_err(|why| {
            bad(format!(
                "frames[{i}].transform_matrix must be a 4×4 array of finite numbers \
                 (camera-to-world): {why}"
            ))
        })?;
        check_rigid(&c2w_gl).map_err(|why| {
            bad(format!(
                "frames[{i}] ({file_path}).transform_matrix is not a rigid camera-to-world \
                 transform: {why}; fix or drop this pose (the rotation must be orthonormal \
                 with determinant +1, the bottom row [0, 0, 0, 1])"
            ))
        })?;
        let image = resolve_image(dir, file_path);
        let name = Path::new(file_path)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| format!("frame_{i}"));
        specs.push(FrameSpec {
            name,
            image,
            c2w_gl,
        });
    }
    Ok((intrinsics, specs))
}

/// Checks that a camera-to-world matrix is a rigid transform: orthonormal rotation
/// (`RᵀR = I` to 1e-3 per entry), determinant +1, bottom row `[0, 0, 0, 1]`, and a camera
/// position within 1e6 of the origin. Zero, rank-deficient, scaled or mirrored rotations
/// would render a different image than the photo's without any error.
pub(crate) fn check_rigid(m: &[[f64; 4]; 4]) -> std::result::Result<(), String> {
    const TOL: f64 = 1e-3;
    for (c, want) in [0.0, 0.0, 0.0, 1.0].iter().enumerate() {
        if (m[3][c] - want).abs() > TOL {
            return Err(format!("bottom row is {:?}", m[3]));
        }
    }
    for a in 0..3 {
        for b in 0..3 {
            let dot: f64 = (0..3).map(|r| m[r][a] * m[r][b]).sum();
            let want = if a == b { 1.0 } else { 0.0 };
            if (dot - want).abs() > TOL {
                return Err(if a == b {
                    format!("rotation column {a} has length {:.6}, not 1", dot.sqrt())
                } else {
                    format!("rotation columns {a} and {b} are not orthogonal (dot {dot:.6})")
                });
            }
        }
    }
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    if det < 0.0 {
        return Err(format!(
            "the rotation is a reflection (determinant {det:.6})"
        ));
    }
    let t = (m[0][3] * m[0][3] + m[1][3] * m[1][3] + m[2][3] * m[2][3]).sqrt();
    if t > 1e6 {
        return Err(format!("the camera position is {t:.3e} from the origin"));
    }
    Ok(())
}

/// A 4×4 matrix of finite numbers from JSON; the error says what is wrong.
pub(crate) fn parse_matrix(m: &Value) -> std::result::Result<[[f64; 4]; 4], String> {
    let rows = m
        .as_array()
        .ok_or_else(|| format!("got {}", type_name(m)))?;
    if rows.len() != 4 {
        return Err(format!("it has {} rows", rows.len()));
    }
    let mut out = [[0.0; 4]; 4];
    for (r, row) in rows.iter().enumerate() {
        let row = row
            .as_array()
            .ok_or_else(|| format!("row {r} is {}", type_name(row)))?;
        if row.len() != 4 {
            return Err(format!("row {r} has {} entries", row.len()));
        }
        for (c, v) in row.iter().enumerate() {
            out[r][c] = match v.as_f64() {
                Some(x) if x.is_finite() => x,
                _ => return Err(format!("entry [{r}][{c}] is {v}")),
            };
        }
    }
    Ok(out)
}

fn type_name(v: &Value) -> &'static str {
    match v {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "an array",
        Value::Object(_) => "an object",
    }
}

/// The image file of `file_path`: as given if that file exists, else with `.png`
/// appended (NeRF-synthetic paths carry no extension).
fn resolve_image(dir: &Path, file_path: &str) -> PathBuf {
    let given = dir.join(file_path);
    if given.is_file() {
        return given;
    }
    let mut with_ext = given.clone().into_os_string();
    with_ext.push(".png");
    let with_ext = PathBuf::from(with_ext);
    if with_ext.is_file() || Path::new(file_path).extension().is_none() {
        with_ext
    } else {
        given
    }
}

/// Decoded image: full size, output size, composited and downscaled RGB.
type Loaded = (u32, u32, u32, u32, Vec<[f32; 3]>);

/// Loads every frame's image in parallel (rayon's pool: one thread per core); results in
/// frame order.
fn load_images(specs: &[FrameSpec], downscale: f64, bg: [f32; 3]) -> Vec<Result<Loaded>> {
    use rayon::prelude::*;
    specs
        .par_iter()
        .map(|spec| load_one(spec, downscale, bg))
        .collect()
}

fn load_one(spec: &FrameSpec, downscale: f64, bg: [f32; 3]) -> Result<Loaded> {
    if !spec.image.is_file() {
        return Err(io_error(
            &spec.image,
            std::io::Error::new(
                std::io::ErrorKind::NotFound,
                format!(
                    "image of frame `{}` not found; check its file_path in the transforms file",
                    spec.name
                ),
            ),
        ));
    }
    let (w, h, rgba) = load_rgba(&spec.image)?;
    if downscale > w as f64 || downscale > h as f64 {
        return Err(Error::Invalid(format!(
            "{}: downscale factor {downscale} is larger than the {w}×{h} image; use a \
             smaller factor",
            spec.image.display()
        )));
    }
    let rgb: Vec<[f32; 3]> = rgba
        .iter()
        .map(|p| std::array::from_fn(|c| p[c] * p[3] + bg[c] * (1.0 - p[3])))
        .collect();
    let (ow, oh) = downscaled_size(w, h, downscale);
    let rgb = area_resample(w, h, &rgb, ow, oh);
    Ok((w, h, ow, oh, rgb))
}

/// The camera of a frame at the full stored image size.
fn full_camera(
    transforms: &Path,
    intr: Intrinsics,
    c2w_gl: [[f64; 4]; 4],
    w: u32,
    h: u32,
) -> Result<Camera> {
    match intr {
        Intrinsics::AngleX(angle) => Ok(Camera::from_opengl(c2w_gl, angle, w, h)),
        Intrinsics::Pixels {
            fl_x,
            fl_y,
            cx,
            cy,
            w: jw,
            h: jh,
        } => {
            for (key, stated, actual) in [("w", jw, w), ("h", jh, h)] {
                if let Some(s) = stated {
                    if (s - actual as f64).abs() > 0.5 {
                        return Err(Error::Invalid(format!(
                            "{}: key `{key}` says {s} pixels but the images have {actual}; \
                             fix `w`/`h` or the images",
                            transforms.display()
                        )));
                    }
                }
            }
            let mut cam = Camera::from_opengl(c2w_gl, 1.0, w, h);
            cam.fx = fl_x;
            cam.fy = fl_y;
            cam.cx = cx.unwrap_or(0.5 * w as f64);
            cam.cy = cy.unwrap_or(0.5 * h as f64);
            Ok(cam)
        }
    }
}
