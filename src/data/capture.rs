//! Real captures: posed photos with a lens model (from COLMAP, and next LLFF and
//! nerfstudio) turned into a [`Dataset`] of pinhole frames.
//!
//! - **Images**: PNG or JPEG, 8/16-bit, EXIF orientation applied, from the capture's image
//!   folder (`images/`, or `--images images_4`, or a lone `images_N` folder). A camera's
//!   intrinsics are given for its own `width × height`; they are scaled per axis to the
//!   size of the image file (the Mip-NeRF 360 / LLFF `images_N` convention).
//! - **Lens distortion** is removed at load: every frame is resampled (bilinear, at the
//!   file's resolution) into a pinhole image of the same size, principal point and aspect,
//!   whose focal length is the smallest zoom ≥ 1 at which every output pixel sees the
//!   photo ([`pinhole_crop`]); no pixel is invented, so no mask is needed. Pinhole
//!   cameras are not resampled. The renderer and the f64 references therefore stay
//!   pinhole; the lens models themselves are in [`super::lens`] and checked against
//!   COLMAP's formulas in tests/capture/.
//! - **Downscaling** (`downscale` > 1) is the exact area average of [`area_resample`],
//!   applied after undistortion.
//! - **Splits**: frames sorted by image name; every `holdout`-th (0, 8, 16, …) is `test`,
//!   the rest `train` (the Mip-NeRF 360 / SVRaster convention); `all` is every frame.

use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::colmap::{self, Reconstruction};
use super::image::load_rgba;
use super::lens::Lens;
pub use super::shot::{image_folder, natural_cmp, Shot, IMAGE_EXTENSIONS};
use super::{area_resample, downscaled_size, Camera, Dataset, Frame};
use crate::error::{Error, Result};

/// How to read a capture.
#[derive(Clone, Debug, PartialEq)]
pub struct CaptureOptions {
    /// Image folder relative to the capture (`images_4`); `None`: `images/`, else the only
    /// `images_N` folder.
    pub images: Option<String>,
    /// Further downscaling of the image files (≥ 1, may be fractional).
    pub downscale: f64,
    /// Every `holdout`-th frame (by name) is a test view; 0: none.
    pub holdout: usize,
}

impl Default for CaptureOptions {
    fn default() -> Self {
        CaptureOptions {
            images: None,
            downscale: 1.0,
            holdout: 8,
        }
    }
}

/// Whether view `i` (in name order) belongs to `split`: every `holdout`-th view (0, N,
/// 2N, …) is `test`, the rest `train`; `all` is every view.
pub fn in_split(i: usize, split: &str, holdout: usize) -> bool {
    let test = holdout > 0 && i.is_multiple_of(holdout);
    match split {
        "train" => !test,
        "test" => test,
        _ => true,
    }
}

/// Errors unless `split` is one a capture has (train, test, all).
pub fn check_split(split: &str, holdout: usize) -> Result<()> {
    if ["train", "test", "all"].contains(&split) {
        Ok(())
    } else {
        Err(Error::Invalid(format!(
            "a capture has the splits train, test (every {holdout}th view) and all, not `{split}`"
        )))
    }
}

/// The shots of a COLMAP model, sorted by image name.
pub fn colmap_shots(rec: &Reconstruction, model_dir: &Path) -> Result<Vec<Shot>> {
    let mut shots: Vec<Shot> = rec
        .images
        .values()
        .map(|img| {
            let cam = &rec.cameras[&img.camera_id];
            let lens = Lens::new(cam.model, cam.params.clone()).map_err(|e| {
                Error::Invalid(format!(
                    "{}: camera {}: {e}",
                    model_dir.join("cameras").display(),
                    cam.id
                ))
            })?;
            Ok(Shot {
                name: img.name.clone(),
                lens,
                lens_size: (cam.width, cam.height),
                c2w: img.c2w(),
            })
        })
        .collect::<Result<_>>()?;
    shots.sort_by(|a, b| natural_cmp(&a.name, &b.name));
    Ok(shots)
}

/// Loads split `split` (`train`, `test` or `all`) of a COLMAP capture in `dir`.
pub fn load_colmap(dir: &Path, split: &str, opts: &CaptureOptions) -> Result<Dataset> {
    let model_dir = colmap::find_model(dir).ok_or_else(|| {
        Error::Invalid(format!(
            "{}: no COLMAP model (looked for sparse/0, sparse, colmap/sparse/0 with cameras.bin or cameras.txt)",
            dir.display()
        ))
    })?;
    let rec = colmap::read_model(&model_dir)?;
    let shots = colmap_shots(&rec, &model_dir)?;
    let mut ds = load_shots(dir, shots, split, opts)?;
    ds.points = rec.points.iter().map(|p| p.xyz).collect();
    Ok(ds)
}

/// Loads split `split` (`train`, `test` or `all`) of a nerfstudio capture in `dir`
/// (`transforms.json`; `opts.images` replaces the frames' image folder).
pub fn load_nerfstudio(dir: &Path, split: &str, opts: &CaptureOptions) -> Result<Dataset> {
    let (folder, shots) = super::nerfstudio::shots(dir)?;
    let folder = match &opts.images {
        Some(_) => image_folder(dir, opts.images.as_deref())?,
        None => folder,
    };
    let mut ds = load_shots_from(dir, &folder, shots, split, opts)?;
    ds.points = super::nerfstudio::points(dir)?;
    Ok(ds)
}

/// Loads split `split` of an LLFF capture in `dir` (`poses_bounds.npy`). Its depth
/// bounds become the dataset's points: each camera's centre and corner rays at its near
/// and far depth (what bounds the scene, as sparse points would).
pub fn load_llff(dir: &Path, split: &str, opts: &CaptureOptions) -> Result<Dataset> {
    let (folder, rows) = super::llff::shots(dir, opts.images.as_deref())?;
    let mut points = Vec::with_capacity(rows.len() * 10);
    for (s, [near, far]) in &rows {
        let (fx, fy, cx, cy) = s.lens.pinhole();
        let (w, h) = (s.lens_size.0 as f64, s.lens_size.1 as f64);
        for (x, y) in [(cx, cy), (0.0, 0.0), (w, 0.0), (0.0, h), (w, h)] {
            let d = [(x - cx) / fx, (y - cy) / fy, 1.0];
            for z in [*near, *far] {
                points.push(std::array::from_fn(|r| {
                    s.c2w[r][3] + z * (s.c2w[r][0] * d[0] + s.c2w[r][1] * d[1] + s.c2w[r][2])
                }));
            }
        }
    }
    let shots = rows.into_iter().map(|r| r.0).collect();
    let mut ds = load_shots_from(dir, &folder, shots, split, opts)?;
    ds.points = points;
    Ok(ds)
}

/// Loads the frames of `split` from `shots` (sorted): images, lens removal, downscaling.
pub fn load_shots(
    dir: &Path,
    shots: Vec<Shot>,
    split: &str,
    opts: &CaptureOptions,
) -> Result<Dataset> {
    let folder = image_folder(dir, opts.images.as_deref())?;
    load_shots_from(dir, &folder, shots, split, opts)
}

/// [`load_shots`] with the images in `folder` (shot names relative to it).
pub fn load_shots_from(
    dir: &Path,
    folder: &Path,
    shots: Vec<Shot>,
    split: &str,
    opts: &CaptureOptions,
) -> Result<Dataset> {
    if !opts.downscale.is_finite() || opts.downscale < 1.0 {
        return Err(Error::Invalid(format!(
            "downscale must be ≥ 1, got {}",
            opts.downscale
        )));
    }
    if shots.len() < 2 {
        return Err(Error::Invalid(format!(
            "{}: {} registered image(s); training needs at least 2",
            dir.display(),
            shots.len()
        )));
    }
    let keep: Vec<Shot> = shots
        .into_iter()
        .enumerate()
        .filter(|(i, _)| in_split(*i, split, opts.holdout))
        .map(|(_, s)| s)
        .collect();
    check_split(split, opts.holdout)?;
    let frames: Vec<Frame> = keep
        .par_iter()
        .map(|s| load_frame(folder, s, opts.downscale))
        .collect::<Result<_>>()?;
    // Frames may differ in size (several cameras in one model); the dataset's size is
    // the largest width and height, each frame's camera carries its own.
    let (Some(width), Some(height)) = (
        frames.iter().map(|f| f.camera.width).max(),
        frames.iter().map(|f| f.camera.height).max(),
    ) else {
        return Err(Error::Invalid(format!(
            "{}: split `{split}` has no frames (holdout {})",
            dir.display(),
            opts.holdout
        )));
    };
    Ok(Dataset {
        frames,
        width,
        height,
        background: [0.0; 3],
        alpha: false,
        split: split.into(),
        points: Vec::new(),
        sphere: None,
    })
}

/// Reads one photo, removes the lens distortion and downscales it.
fn load_frame(folder: &Path, shot: &Shot, downscale: f64) -> Result<Frame> {
    let path = find_image(folder, &shot.name)?;
    let (w, h, rgba) = load_rgba(&path)?;
    let rgb: Vec<[f32; 3]> = rgba.iter().map(|p| [p[0], p[1], p[2]]).collect();
    let lens = shot.lens.scaled(
        w as f64 / shot.lens_size.0 as f64,
        h as f64 / shot.lens_size.1 as f64,
    );
    let (pinhole, rgb) = if lens.is_pinhole() {
        (lens.pinhole(), rgb)
    } else {
        let k = pinhole_crop(&lens, w, h)
            .map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))?;
        (k, undistort(&lens, k, w, h, &rgb))
    };
    let (ow, oh) = downscaled_size(w, h, downscale);
    let rgb = area_resample(w, h, &rgb, ow, oh);
    let (fx, fy, cx, cy) = pinhole;
    let camera = Camera {
        width: w,
        height: h,
        fx,
        fy,
        cx,
        cy,
        c2w: shot.c2w,
        near: crate::camera::DEFAULT_NEAR,
    }
    .resized(ow, oh);
    camera.validate().map_err(|e| {
        Error::Invalid(format!(
            "{}: camera of {}: {e}",
            folder.display(),
            shot.name
        ))
    })?;
    let stem = Path::new(&shot.name)
        .with_extension("")
        .to_string_lossy()
        .into_owned();
    Ok(Frame {
        name: stem,
        camera,
        rgb,
    })
}

/// The image file for `name`: as named, else with the extension swapped among
/// `.png`, `.jpg`, `.JPG`, `.jpeg` (COLMAP runs on JPEGs, `images_N` folders are often PNG).
fn find_image(folder: &Path, name: &str) -> Result<PathBuf> {
    let p = folder.join(name);
    if p.is_file() {
        return Ok(p);
    }
    for ext in IMAGE_EXTENSIONS {
        let q = p.with_extension(ext);
        if q.is_file() {
            return Ok(q);
        }
    }
    Err(Error::Invalid(format!(
        "image `{name}` of the model is not in {} (nor with a .png/.jpg extension): \
         is --images the right folder?",
        folder.display()
    )))
}

/// The pinhole `(fx, fy, cx, cy)` that [`undistort`] resamples into, for an image of
/// `w × h`: the lens's principal point and focal lengths times the smallest zoom `s ≥ 1`
/// at which every output pixel (sampled along the border at every pixel and on a grid
/// inside) maps inside the photo; found by bisection to 1e-9.
pub fn pinhole_crop(
    lens: &Lens,
    w: u32,
    h: u32,
) -> std::result::Result<(f64, f64, f64, f64), String> {
    let (fx, fy, cx, cy) = lens.pinhole();
    let (wf, hf) = (w as f64, h as f64);
    let mut samples = Vec::new();
    for x in 0..=w {
        samples.push((x as f64, 0.0));
        samples.push((x as f64, hf));
    }
    for y in 0..=h {
        samples.push((0.0, y as f64));
        samples.push((wf, y as f64));
    }
    for j in 0..=16 {
        for i in 0..=16 {
            samples.push((wf * i as f64 / 16.0, hf * j as f64 / 16.0));
        }
    }
    let fits = |s: f64| {
        samples.iter().all(|&(x, y)| {
            let (u, v) = ((x - cx) / (s * fx), (y - cy) / (s * fy));
            match lens.distort(u, v) {
                Some((px, py)) => {
                    (-1e-9..=wf + 1e-9).contains(&px) && (-1e-9..=hf + 1e-9).contains(&py)
                }
                None => false,
            }
        })
    };
    let mut hi = 1.0f64;
    if !fits(hi) {
        while !fits(hi) {
            hi *= 2.0;
            if hi > 64.0 {
                return Err(
                    "the lens cannot be undistorted into a pinhole image (field of view too wide \
                     or the principal point outside the image)"
                        .into(),
                );
            }
        }
        let mut lo = hi / 2.0;
        while hi - lo > 1e-9 * hi {
            let mid = 0.5 * (lo + hi);
            if fits(mid) {
                hi = mid;
            } else {
                lo = mid;
            }
        }
    }
    Ok((hi * fx, hi * fy, cx, cy))
}

/// Resamples a `w × h` photo taken through `lens` into the pinhole image `k = (fx, fy,
/// cx, cy)` of the same size: each output pixel centre's ray is projected through the
/// lens and the photo is sampled bilinearly there (clamped at the border, which
/// [`pinhole_crop`] keeps within half a pixel).
pub fn undistort(
    lens: &Lens,
    k: (f64, f64, f64, f64),
    w: u32,
    h: u32,
    rgb: &[[f32; 3]],
) -> Vec<[f32; 3]> {
    let (fx, fy, cx, cy) = k;
    let (wu, hu) = (w as usize, h as usize);
    (0..wu * hu)
        .into_par_iter()
        .map(|i| {
            let (x, y) = ((i % wu) as f64 + 0.5, (i / wu) as f64 + 0.5);
            let (px, py) = lens.distort((x - cx) / fx, (y - cy) / fy).unwrap_or((x, y));
            bilinear(rgb, wu, hu, px - 0.5, py - 0.5)
        })
        .collect()
}

/// Bilinear sample at continuous pixel-index position `(x, y)` (pixel `i` at `i`),
/// clamped to the image.
fn bilinear(rgb: &[[f32; 3]], w: usize, h: usize, x: f64, y: f64) -> [f32; 3] {
    let x = x.clamp(0.0, (w - 1) as f64);
    let y = y.clamp(0.0, (h - 1) as f64);
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (tx, ty) = (x - x0 as f64, y - y0 as f64);
    let p = |xx: usize, yy: usize| rgb[yy * w + xx];
    std::array::from_fn(|c| {
        let top = p(x0, y0)[c] as f64 * (1.0 - tx) + p(x1, y0)[c] as f64 * tx;
        let bot = p(x0, y1)[c] as f64 * (1.0 - tx) + p(x1, y1)[c] as f64 * tx;
        (top * (1.0 - ty) + bot * ty) as f32
    })
}
