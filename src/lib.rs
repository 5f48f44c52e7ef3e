//! svraster: sparse-voxel radiance fields (SVRaster) on raw Vulkan compute.
//!
//! - [`gpu`]: the Vulkan layer (owned or borrowed device, buffers, kernels, timestamps).
//! - [`sort`]: onesweep radix sort of u64 keys with u32 values, and the u32 prefix scan.

pub mod error;
pub mod gpu;
pub mod scan;
pub mod sort;

pub use error::{Error, Result};
