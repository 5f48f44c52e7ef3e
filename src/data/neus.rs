//! NeuS / IDR object captures (the DTU layout): `cameras_sphere.npz` + `image/` +
//! optional `mask/`.
//!
//! `cameras_sphere.npz` holds, per view `i`, `world_mat_i` (the 4×4 projection `K·[R|t]`
//! from world to pixels) and `scale_mat_i` (the similarity from the unit sphere around
//! the object to the world: scale on the diagonal, centre in the last column; the same
//! for every view). The projection is decomposed as NeuS does (`cv2.decomposeProjection
//! Matrix`): `K` upper triangular with positive diagonal from `M·Mᵀ = K·Kᵀ` (M the left
//! 3×3), `R = K⁻¹·M`, camera centre `−M⁻¹·p₄`. NeuS puts pixel centres at integer
//! coordinates, this engine at `+0.5`: the principal point moves by half a pixel. The
//! skew (≈1e-4 px on DTU) is dropped.
//!
//! Images (`image/*.png|jpg`, natural name order, matched to `i` in order) are loaded
//! like every capture's; a mask (`mask/`, same order, grey or RGB, soft edges kept) is
//! the photo's alpha: the photo is composited over the requested background and the
//! dataset has alpha. The world stays the capture's own (DTU millimetres); the unit
//! sphere is offered as the main region (`bound` `auto` or `sphere`), so meshes come
//! out in DTU coordinates. Splits as captures: every `holdout`-th view is `test`.

use std::io::Read;
use std::path::{Path, PathBuf};

use glam::{DMat3, DVec3};
use rayon::prelude::*;

use super::capture::{check_split, in_split};
use super::image::load_rgba;
use super::shot::{natural_cmp, IMAGE_EXTENSIONS};
use super::{area_resample, downscaled_size, Camera, Dataset, Frame};
use crate::error::{Error, Result};

/// Named arrays: shape and values (f64).
pub type Arrays = std::collections::BTreeMap<String, (Vec<u64>, Vec<f64>)>;

/// The arrays of an `.npz` file (stored or deflated members) as f64, by name (without
/// `.npy`), each with its shape.
pub fn read_npz(path: &Path) -> Result<Arrays> {
    let bad = |m: String| Error::Invalid(format!("{}: {m}", path.display()));
    let file = std::fs::File::open(path).map_err(|error| Error::Io {
        path: path.display().to_string(),
        error,
    })?;
    let mut zip =
        zip::ZipArchive::new(file).map_err(|e| bad(format!("not an .npz (zip) archive ({e})")))?;
    let mut out = std::collections::BTreeMap::new();
    for i in 0..zip.len() {
        let mut f = zip
            .by_index(i)
            .map_err(|e| bad(format!("member {i}: {e}")))?;
        let name = f.name().trim_end_matches(".npy").to_string();
        let mut bytes = Vec::new();
        f.read_to_end(&mut bytes)
            .map_err(|e| bad(format!("member {name}: {e}")))?;
        let npy = npyz::NpyFile::new(&bytes[..])
            .map_err(|e| bad(format!("member {name} is not a .npy array ({e})")))?;
        let shape = npy.shape().to_vec();
        let values: Vec<f64> = match npy.dtype() {
            npyz::DType::Plain(t)
                if t.type_char() == npyz::TypeChar::Float && t.size_field() == 4 =>
            {
                npy.into_vec::<f32>()
                    .map(|v| v.into_iter().map(f64::from).collect())
            }
            _ => npy.into_vec::<f64>(),
        }
        .map_err(|e| {
            bad(format!(
                "member {name}: cannot read its values as floats ({e})"
            ))
        })?;
        out.insert(name, (shape, values));
    }
    Ok(out)
}

/// A 4×4 matrix member of the archive.
fn mat4(arrays: &Arrays, name: &str, path: &Path) -> Result<[[f64; 4]; 4]> {
    let bad = |m: String| Error::Invalid(format!("{}: {m}", path.display()));
    let (shape, v) = arrays
        .get(name)
        .ok_or_else(|| bad(format!("no `{name}` array")))?;
    if shape.as_slice() != [4, 4] && shape.as_slice() != [3, 4] {
        return Err(bad(format!(
            "`{name}` has shape {shape:?}, expected [4, 4]"
        )));
    }
    if v.iter().any(|x| !x.is_finite()) {
        return Err(bad(format!("`{name}` has a non-finite value")));
    }
    let mut m = [[0.0, 0.0, 0.0, 1.0]; 4];
    m[3] = [0.0, 0.0, 0.0, 1.0];
    for r in 0..shape[0] as usize {
        for c in 0..4 {
            m[r][c] = v[r * 4 + c];
        }
    }
    Ok(m)
}

/// `K` (fx, fy, cx, cy with pixel centres at integer coordinates) and the
/// camera-to-world `[R | c]` of a 3×4 projection `P = K·[R|t]`.
pub fn decompose_projection(p: &[[f64; 4]; 4]) -> Option<([f64; 4], [[f64; 4]; 3])> {
    let m = DMat3::from_cols_array_2d(&std::array::from_fn(|c| std::array::from_fn(|r| p[r][c])));
    let p4 = DVec3::new(p[0][3], p[1][3], p[2][3]);
    // P is defined up to scale: make det(M) > 0 so that R is a rotation.
    let (m, p4) = if m.determinant() < 0.0 {
        (-m, -p4)
    } else {
        (m, p4)
    };
    if m.determinant() == 0.0 || m.determinant().is_nan() {
        return None;
    }
    // K·Kᵀ = M·Mᵀ = A with K upper triangular: from the bottom row up.
    let a = m * m.transpose();
    let col = |c: usize| a.col(c);
    let a = |r: usize, c: usize| col(c)[r];
    let k22 = a(2, 2).sqrt();
    let k12 = a(1, 2) / k22;
    let k02 = a(0, 2) / k22;
    let k11 = (a(1, 1) - k12 * k12).sqrt();
    let k01 = (a(0, 1) - k02 * k12) / k11;
    let k00 = (a(0, 0) - k01 * k01 - k02 * k02).sqrt();
    let k = DMat3::from_cols(
        DVec3::new(k00, 0.0, 0.0),
        DVec3::new(k01, k11, 0.0),
        DVec3::new(k02, k12, k22),
    );
    let r = k.inverse() * m;
    let centre = -(m.inverse() * p4);
    let kn = k * (1.0 / k22);
    let intr = [kn.col(0)[0], kn.col(1)[1], kn.col(2)[0], kn.col(2)[1]];
    if intr.iter().any(|x| !x.is_finite()) || !centre.is_finite() {
        return None;
    }
    // c2w rotation = Rᵀ (columns = camera axes in world).
    let rt = r.transpose();
    let c2w =
        std::array::from_fn(|row| [rt.col(0)[row], rt.col(1)[row], rt.col(2)[row], centre[row]]);
    Some((intr, c2w))
}

/// Image files of `dir` (PNG/JPEG), in natural name order.
fn image_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|error| Error::Io {
            path: dir.display().to_string(),
            error,
        })?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| IMAGE_EXTENSIONS.contains(&e))
        })
        .collect();
    files.sort_by(|a, b| natural_cmp(&a.to_string_lossy(), &b.to_string_lossy()));
    Ok(files)
}

/// The views of a NeuS capture: (image, mask, intrinsics, c2w) per view, and the unit
/// sphere (centre, radius) in world coordinates.
#[allow(clippy::type_complexity)]
fn views(
    dir: &Path,
) -> Result<(
    Vec<(PathBuf, Option<PathBuf>, [f64; 4], [[f64; 4]; 3])>,
    ([f64; 3], f64),
)> {
    let npz = dir.join("cameras_sphere.npz");
    let arrays = read_npz(&npz)?;
    let n = (0..)
        .take_while(|i| arrays.contains_key(&format!("world_mat_{i}")))
        .count();
    let images = image_files(&dir.join("image"))?;
    if n == 0 || images.len() != n {
        return Err(Error::Invalid(format!(
            "{}: {n} world_mat_i arrays but {} images in {}; a NeuS capture has one \
             projection per image",
            npz.display(),
            images.len(),
            dir.join("image").display()
        )));
    }
    let mask_dir = dir.join("mask");
    let masks = if mask_dir.is_dir() {
        let m = image_files(&mask_dir)?;
        if m.len() != n {
            return Err(Error::Invalid(format!(
                "{}: {} masks for {n} images (one per image, or no mask/ folder)",
                mask_dir.display(),
                m.len()
            )));
        }
        m.into_iter().map(Some).collect()
    } else {
        vec![None; n]
    };
    let s = mat4(&arrays, "scale_mat_0", &npz)?;
    let sphere = ([s[0][3], s[1][3], s[2][3]], s[0][0]);
    if sphere.1 <= 0.0 || (s[1][1] - s[0][0]).abs() > 1e-6 * s[0][0] {
        return Err(Error::Invalid(format!(
            "{}: scale_mat_0 is not a uniform scale and a translation",
            npz.display()
        )));
    }
    let mut out = Vec::with_capacity(n);
    for (i, (img, mask)) in images.into_iter().zip(masks).enumerate() {
        let w = mat4(&arrays, &format!("world_mat_{i}"), &npz)?;
        let (intr, c2w) = decompose_projection(&w).ok_or_else(|| {
            Error::Invalid(format!(
                "{}: world_mat_{i} is not a camera projection (singular)",
                npz.display()
            ))
        })?;
        out.push((img, mask, intr, c2w));
    }
    Ok((out, sphere))
}

/// Loads split `split` of the NeuS capture in `dir`: photos (composited over
/// `background` with their masks), downscaled by `downscale`.
pub fn load(
    dir: &Path,
    split: &str,
    downscale: f64,
    background: [f32; 3],
    holdout: usize,
) -> Result<Dataset> {
    check_split(split, holdout)?;
    if !downscale.is_finite() || downscale < 1.0 {
        return Err(Error::Invalid(format!(
            "downscale must be ≥ 1, got {downscale}"
        )));
    }
    let (views, sphere) = views(dir)?;
    let has_masks = views.iter().all(|v| v.1.is_some());
    let frames: Vec<Frame> = views
        .par_iter()
        .enumerate()
        .filter(|(i, _)| in_split(*i, split, holdout))
        .map(|(_, (img, mask, intr, c2w))| {
            let (w, h, rgba) = load_rgba(img)?;
            let mut rgb: Vec<[f32; 3]> = rgba.iter().map(|p| [p[0], p[1], p[2]]).collect();
            if let Some(m) = mask {
                let a = load_mask(m, w, h)?;
                for (p, a) in rgb.iter_mut().zip(a) {
                    for c in 0..3 {
                        p[c] = p[c] * a + background[c] * (1.0 - a);
                    }
                }
            }
            let (ow, oh) = downscaled_size(w, h, downscale);
            let camera = Camera {
                width: w,
                height: h,
                fx: intr[0],
                fy: intr[1],
                cx: intr[2] + 0.5,
                cy: intr[3] + 0.5,
                c2w: *c2w,
                near: crate::camera::DEFAULT_NEAR,
            }
            .resized(ow, oh);
            Ok(Frame {
                name: img
                    .file_stem()
                    .map_or(String::new(), |s| s.to_string_lossy().into_owned()),
                camera,
                rgb: area_resample(w, h, &rgb, ow, oh),
            })
        })
        .collect::<Result<_>>()?;
    let (Some(width), Some(height)) = (
        frames.iter().map(|f| f.camera.width).max(),
        frames.iter().map(|f| f.camera.height).max(),
    ) else {
        return Err(Error::Invalid(format!(
            "{}: split `{split}` has no views (holdout {holdout})",
            dir.display()
        )));
    };
    Ok(Dataset {
        frames,
        width,
        height,
        background,
        alpha: has_masks,
        split: split.into(),
        points: Vec::new(),
        sphere: Some(sphere),
    })
}

/// A mask image as per-pixel alpha (mean of its colour channels), checked against the
/// photo's size.
fn load_mask(path: &Path, w: u32, h: u32) -> Result<Vec<f32>> {
    let (mw, mh, m) = load_rgba(path)?;
    if (mw, mh) != (w, h) {
        return Err(Error::Invalid(format!(
            "{}: mask is {mw}×{mh}, its photo {w}×{h}",
            path.display()
        )));
    }
    Ok(m.iter().map(|p| (p[0] + p[1] + p[2]) / 3.0).collect())
}

/// The masks of split `split` (alpha per pixel, downscaled by area like the photos), in
/// the order of [`load`]'s frames; an error when the capture has none.
pub fn load_masks(
    dir: &Path,
    split: &str,
    downscale: f64,
    holdout: usize,
) -> Result<Vec<Vec<f32>>> {
    let (views, _) = views(dir)?;
    views
        .par_iter()
        .enumerate()
        .filter(|(i, _)| in_split(*i, split, holdout))
        .map(|(_, (img, mask, _, _))| {
            let m = mask
                .as_ref()
                .ok_or_else(|| Error::Invalid(format!("{}: no mask/ folder", dir.display())))?;
            let (w, h) = image::image_dimensions(img)
                .map_err(|e| Error::Invalid(format!("{}: {e}", img.display())))?;
            let a = load_mask(m, w, h)?;
            let rgb: Vec<[f32; 3]> = a.iter().map(|&x| [x; 3]).collect();
            let (ow, oh) = downscaled_size(w, h, downscale);
            Ok(area_resample(w, h, &rgb, ow, oh)
                .iter()
                .map(|p| p[0])
                .collect())
        })
        .collect()
}
