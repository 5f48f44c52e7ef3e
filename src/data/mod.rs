//! Datasets and cameras.
//!
//! - [`Camera`] (home: [`crate::camera`]): the pinhole camera, re-exported for loaders.
//! - [`blender`]: Blender / NeRF-synthetic dataset loader.
//! - [`image`]: PNG input and output.
//! - [`demo`]: the built-in procedural demo scene (dataset writer and voxelizer).

pub mod blender;
mod dataset;
pub mod demo;
pub mod image;

/// The pinhole camera (its home is [`crate::camera`]; re-exported for loaders).
pub use crate::camera::Camera;
pub use blender::load_split;
pub use dataset::{area_resample, downscaled_size, Dataset, Frame};
