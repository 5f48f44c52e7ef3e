//! svraster: sparse-voxel radiance fields (SVRaster) on raw Vulkan compute.
//!
//! - [`gpu`]: the Vulkan layer (owned or borrowed device, buffers, kernels, timestamps).
//! - [`sort`]: onesweep radix sort of u64 keys with u32 values, and the u32 prefix scan.
//! - [`scene`]: the sparse-voxel model and its checkpoint format.
//! - [`data`]: cameras and datasets.
//! - [`eval`]: PSNR, SSIM and model evaluation (the numbers every report quotes).

pub mod adapt;
pub mod data;
pub mod error;
pub mod eval;
pub mod fsio;
#[macro_use]
pub mod gpu;
pub mod raster;
pub mod scan;
pub mod scene;
pub mod sort;
pub mod train;

pub use error::{Error, Result};
