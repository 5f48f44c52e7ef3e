//! Datasets and cameras.
//!
//! - [`Camera`] (home: [`crate::camera`]): the pinhole camera, re-exported for loaders.
//! - [`blender`]: Blender / NeRF-synthetic dataset loader.
//! - [`colmap`]: COLMAP sparse models (binary and text), [`lens`]: COLMAP's camera
//!   models, [`capture`]: real captures (photos + lens + poses) to pinhole frames.
//! - [`image`]: PNG input and output.
//! - [`demo`]: the built-in procedural demo scene (dataset writer and voxelizer).

pub mod blender;
pub mod capture;
pub mod colmap;
mod dataset;
pub mod demo;
pub mod image;
pub mod lens;
pub mod llff;
pub mod nerfstudio;

/// The pinhole camera (its home is [`crate::camera`]; re-exported for loaders).
pub use crate::camera::Camera;
pub use capture::CaptureOptions;
pub use dataset::{area_resample, downscaled_size, Dataset, Frame};

/// Dataset layouts [`load_split`] reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Blender / NeRF-synthetic: `transforms_{split}.json` + images.
    Blender,
    /// A COLMAP sparse model (`sparse/0`) + photos.
    Colmap,
    /// nerfstudio's `transforms.json` + photos.
    Nerfstudio,
    /// LLFF's `poses_bounds.npy` + photos.
    Llff,
}

/// The layout of the dataset in `dir`: COLMAP when it has a sparse model
/// ([`colmap::find_model`]) and no `transforms_*.json` (a COLMAP model wins over a
/// `poses_bounds.npy` beside it), else nerfstudio when it has a `transforms.json`, else
/// LLFF when it has a `poses_bounds.npy`, else Blender (whose loader explains what is
/// missing).
pub fn detect_format(dir: &std::path::Path) -> Format {
    let transforms = std::fs::read_dir(dir).is_ok_and(|entries| {
        entries.filter_map(|e| e.ok()).any(|e| {
            let n = e.file_name();
            let n = n.to_string_lossy();
            n.starts_with("transforms_") && n.ends_with(".json")
        })
    });
    if !transforms && colmap::find_model(dir).is_some() {
        Format::Colmap
    } else if !transforms && dir.join("transforms.json").is_file() {
        Format::Nerfstudio
    } else if !transforms && dir.join("poses_bounds.npy").is_file() {
        Format::Llff
    } else {
        Format::Blender
    }
}

/// Loads split `split` of the dataset in `dir`, whatever its layout ([`detect_format`]):
/// images downscaled by `downscale`; Blender RGBA composited over `background`.
/// COLMAP captures use [`CaptureOptions::default`] (the `images/` folder or a lone
/// `images_N`, every 8th view held out as `test`).
pub fn load_split(
    dir: &std::path::Path,
    split: &str,
    downscale: f64,
    background: [f32; 3],
) -> crate::Result<Dataset> {
    match detect_format(dir) {
        Format::Blender => blender::load_split(dir, split, downscale, background),
        Format::Colmap => capture::load_colmap(
            dir,
            split,
            &CaptureOptions {
                downscale,
                ..CaptureOptions::default()
            },
        ),
        Format::Llff => capture::load_llff(
            dir,
            split,
            &CaptureOptions {
                downscale,
                ..CaptureOptions::default()
            },
        ),
        Format::Nerfstudio => capture::load_nerfstudio(
            dir,
            split,
            &CaptureOptions {
                downscale,
                ..CaptureOptions::default()
            },
        ),
    }
}
