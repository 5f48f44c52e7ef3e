//! Datasets and cameras.

pub mod camera;

pub use camera::Camera;
