//! LLFF captures: `poses_bounds.npy` + `images[_N]/` (the NeRF forward-facing data).
//!
//! `poses_bounds.npy` is an `N × 17` float array, one row per image in sorted file-name
//! order: a row-major `3 × 5` matrix `[R | t | hwf]` followed by the near and far depth
//! bounds. `R`'s columns are the camera's down, right and backwards axes in world
//! coordinates (LLFF's convention), `t` the camera centre and `hwf` the height, width and
//! focal length in pixels of the full-resolution photos (square pixels, principal point at
//! the centre, no distortion). Converted to OpenCV axes: x = right, y = down, z =
//! −backwards.

use std::path::Path;

use super::lens::{CameraModel, Lens};
use super::shot::{image_folder, natural_cmp, Shot};
use crate::error::{Error, Result};

/// One LLFF row: the shot (its `name` filled in from the image folder) and the depth
/// bounds.
pub struct LlffRow {
    pub c2w: [[f64; 4]; 3],
    pub height: f64,
    pub width: f64,
    pub focal: f64,
    pub near: f64,
    pub far: f64,
}

/// Parses `poses_bounds.npy`.
pub fn read_poses_bounds(path: &Path) -> Result<Vec<LlffRow>> {
    let bytes = std::fs::read(path).map_err(|error| Error::Io {
        path: path.display().to_string(),
        error,
    })?;
    let bad = |m: String| Error::Invalid(format!("{}: {m}", path.display()));
    let npy = npyz::NpyFile::new(&bytes[..]).map_err(|e| bad(format!("not a .npy file ({e})")))?;
    let shape = npy.shape().to_vec();
    if shape.len() != 2 || shape[1] != 17 {
        return Err(bad(format!(
            "shape {shape:?}, expected [N, 17] (3×5 pose + near/far per image)"
        )));
    }
    let v: Vec<f64> = npy
        .into_vec()
        .map_err(|e| bad(format!("cannot read the values as float64 ({e})")))?;
    v.chunks_exact(17)
        .enumerate()
        .map(|(i, r)| {
            if r.iter().any(|x| !x.is_finite()) {
                return Err(bad(format!("row {i} has a non-finite value")));
            }
            let m = |row: usize, col: usize| r[row * 5 + col];
            // Columns of R: down, right, backwards → OpenCV x = right, y = down, z = fwd.
            let c2w = std::array::from_fn(|row| [m(row, 1), m(row, 0), -m(row, 2), m(row, 3)]);
            let full = [c2w[0], c2w[1], c2w[2], [0.0, 0.0, 0.0, 1.0]];
            super::blender::check_rigid(&full)
                .map_err(|why| bad(format!("row {i}: the pose is not rigid ({why})")))?;
            let (height, width, focal) = (m(0, 4), m(1, 4), m(2, 4));
            if !(height >= 1.0 && width >= 1.0 && focal > 0.0) {
                return Err(bad(format!(
                    "row {i}: hwf = ({height}, {width}, {focal}) is not an image size and a focal length"
                )));
            }
            Ok(LlffRow {
                c2w,
                height,
                width,
                focal,
                near: r[15],
                far: r[16],
            })
        })
        .collect()
}

/// The shots of the LLFF capture in `dir` (images from `images/` or the folder chosen by
/// `images`, sorted by name, matched to the rows in order) with their near/far bounds.
#[allow(clippy::type_complexity)]
pub fn shots(
    dir: &Path,
    images: Option<&str>,
) -> Result<(std::path::PathBuf, Vec<(Shot, [f64; 2])>)> {
    let path = dir.join("poses_bounds.npy");
    let rows = read_poses_bounds(&path)?;
    let folder = image_folder(dir, images)?;
    let mut names: Vec<String> = std::fs::read_dir(&folder)
        .map_err(|error| Error::Io {
            path: folder.display().to_string(),
            error,
        })?
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| {
            let l = n.to_ascii_lowercase();
            l.ends_with(".png") || l.ends_with(".jpg") || l.ends_with(".jpeg")
        })
        .collect();
    names.sort_by(|a, b| natural_cmp(a, b));
    if names.len() != rows.len() {
        return Err(Error::Invalid(format!(
            "{} has {} poses but {} has {} images: they must match one to one (sorted by name)",
            path.display(),
            rows.len(),
            folder.display(),
            names.len()
        )));
    }
    let shots = rows
        .into_iter()
        .zip(names)
        .map(|(r, name)| {
            let lens = Lens::new(
                CameraModel::Pinhole,
                vec![r.focal, r.focal, 0.5 * r.width, 0.5 * r.height],
            )
            .map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))?;
            Ok((
                Shot {
                    name,
                    lens,
                    lens_size: (r.width.round() as u64, r.height.round() as u64),
                    c2w: r.c2w,
                },
                [r.near, r.far],
            ))
        })
        .collect::<Result<_>>()?;
    Ok((folder, shots))
}
