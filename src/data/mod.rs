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
pub mod neus;
pub mod pixels;
pub mod ply;
pub mod shot;

/// The pinhole camera (its home is [`crate::camera`]; re-exported for loaders).
pub use crate::camera::Camera;
pub use capture::CaptureOptions;
pub use dataset::{area_resample, downscaled_size, Dataset, Frame};

/// Dataset layouts [`load_split`] reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    /// Blender / NeRF-synthetic: `transforms_{split}.json` + images.
    Blender,
    /// A COLMAP sparse model (`sparse/0`) + photos.
    Colmap,
    /// nerfstudio's `transforms.json` + photos.
    Nerfstudio,
    /// LLFF's `poses_bounds.npy` + photos.
    Llff,
    /// NeuS / IDR object captures (DTU): `cameras_sphere.npz` + `image/` + `mask/`.
    Neus,
}

impl Format {
    /// Every format, as `--format` names them.
    pub const NAMES: [&'static str; 5] = ["blender", "colmap", "nerfstudio", "llff", "neus"];

    pub fn from_name(name: &str) -> Option<Format> {
        match name {
            "blender" => Some(Format::Blender),
            "colmap" => Some(Format::Colmap),
            "nerfstudio" => Some(Format::Nerfstudio),
            "llff" => Some(Format::Llff),
            "neus" => Some(Format::Neus),
            _ => None,
        }
    }
}

/// How to read a dataset beyond its split and scale: the layout (None: detected), the
/// image folder of a capture (None: `images/`, else the lone `images_N`), and the
/// hold-out interval of captures (None: 8).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SourceOptions {
    pub format: Option<Format>,
    pub images: Option<String>,
    pub holdout: Option<usize>,
}

/// The layout of the dataset in `dir`: COLMAP when it has a sparse model
/// ([`colmap::find_model`]) and no `transforms_*.json` (a COLMAP model wins over a
/// `poses_bounds.npy` beside it), else nerfstudio when it has a `transforms.json`, else
/// LLFF when it has a `poses_bounds.npy`, else NeuS when it has a `cameras_sphere.npz`,
/// else Blender (whose loader explains what is
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
    } else if !transforms && dir.join("cameras_sphere.npz").is_file() {
        Format::Neus
    } else {
        Format::Blender
    }
}

/// Loads split `split` of the dataset in `dir`, whatever its layout ([`detect_format`]):
/// images downscaled by `downscale`; Blender RGBA composited over `background`.
/// Captures use the `images/` folder (or a lone `images_N`) and hold out every 8th view
/// as `test` ([`load`] chooses otherwise).
pub fn load_split(
    dir: &std::path::Path,
    split: &str,
    downscale: f64,
    background: [f32; 3],
) -> crate::error::Result<Dataset> {
    load(dir, split, downscale, background, &SourceOptions::default())
}

/// [`load_split`] with the layout, image folder and hold-out of `source`.
pub fn load(
    dir: &std::path::Path,
    split: &str,
    downscale: f64,
    background: [f32; 3],
    source: &SourceOptions,
) -> crate::error::Result<Dataset> {
    if !dir.is_dir() {
        return Err(crate::error::Error::Invalid(if dir.exists() {
            format!("{}: is a file, not a dataset folder", dir.display())
        } else {
            format!(
                "{}: dataset folder not found; pass the folder that holds transforms_*.json \
                 (Blender), sparse/0 (COLMAP), transforms.json (nerfstudio), poses_bounds.npy \
                 (LLFF) or cameras_sphere.npz (NeuS)",
                dir.display()
            )
        }));
    }
    let format = source.format.unwrap_or_else(|| detect_format(dir));
    let opts = CaptureOptions {
        images: source.images.clone(),
        downscale,
        holdout: source.holdout.unwrap_or(8),
    };
    if format == Format::Blender && (source.images.is_some() || source.holdout.is_some()) {
        return Err(crate::error::Error::Invalid(format!(
            "{}: --images and --holdout apply to captures (COLMAP, nerfstudio, LLFF), not to \
             a Blender dataset, whose splits are its transforms_*.json files",
            dir.display()
        )));
    }
    match format {
        Format::Blender => blender::load_split(dir, split, downscale, background),
        Format::Colmap => capture::load_colmap(dir, split, &opts),
        Format::Llff => capture::load_llff(dir, split, &opts),
        Format::Nerfstudio => capture::load_nerfstudio(dir, split, &opts),
        Format::Neus => {
            if source.images.is_some() {
                return Err(crate::error::Error::Invalid(format!(
                    "{}: a NeuS capture's photos are in image/ (--images does not apply)",
                    dir.display()
                )));
            }
            neus::load(dir, split, downscale, background, opts.holdout)
        }
    }
}
