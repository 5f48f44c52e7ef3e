//! Datasets and cameras.
//!
//! - [`camera`]: the pinhole [`Camera`] and its conventions.
//! - [`blender`]: Blender / NeRF-synthetic dataset loader.
//! - [`image`]: PNG input and output.
//! - [`demo`]: the built-in procedural demo scene (dataset writer and voxelizer).

pub mod blender;
pub mod camera;
mod dataset;
pub mod demo;
pub mod image;

pub use blender::load_split;
pub use camera::Camera;
pub use dataset::{area_resample, downscaled_size, Dataset, Frame};
