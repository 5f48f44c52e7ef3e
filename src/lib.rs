//! svraster: sparse-voxel radiance fields (SVRaster) on raw Vulkan compute.
//!
//! - [`gpu`]: the Vulkan layer (owned or borrowed device, buffers, kernels, timestamps).
//! - [`mod@sort`], [`scan`]: onesweep radix sort of u64 keys with u32 values; u32 prefix scan.
//! - [`scene`]: the sparse-voxel model, its checkpoint format and its device copy.
//! - [`camera`]: pinhole cameras; [`data`]: datasets (Blender/NeRF-synthetic, the demo).
//! - [`raster`]: the forward rasterizer (record into any command buffer).
//! - [`train`]: losses, backward, Adam and the training loop; [`adapt`]: pruning and
//!   subdivision of the voxel layout.
//! - [`eval`]: PSNR, SSIM and model evaluation (the numbers every report quotes).
//! - [`mesh`]: TSDF fusion and marching cubes over sparse voxels, PLY output.
//! - `viewer` (feature `viewer`): a windowed viewer, a small host engine embedding the
//!   field (`svraster view`).
//!
//! The types most programs need are re-exported here.

pub mod adapt;
pub mod camera;
pub mod data;
pub mod error;
pub mod eval;
pub mod field;
pub mod fsio;
pub mod gpu;
pub mod mesh;
pub mod raster;
pub mod scan;
pub mod scene;
pub mod sort;
pub mod train;
#[cfg(feature = "viewer")]
pub mod viewer;

/// The pinhole camera a frame is rendered from.
pub use camera::Camera;
/// The errors of this crate and its `Result`.
pub use error::{Error, Result};
/// The Vulkan device the engine runs on (owned, or borrowed from a host engine).
pub use gpu::Context;
/// Records frames into a host engine's command buffers, images and depth (embedding).
pub use raster::host::{HostRenderer, HostTarget, HostView};
/// Records a frame of a scene into a command buffer, or renders and reads it back.
pub use raster::{RenderOptions, Renderer};
/// Exclusive prefix sum of u32 counts on the device.
pub use scan::PrefixScan;
/// A sparse-voxel model (host) and its device copy.
pub use scene::{Scene, SceneGpu};
/// Onesweep radix sort of u64 keys with u32 values on the device.
pub use sort::RadixSort;
/// Every hyperparameter of a run.
pub use train::config::TrainConfig;
/// Trains a scene: one iteration per call, adaptive steps on the schedule.
pub use train::trainer::Trainer;
