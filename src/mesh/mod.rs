//! Meshes from a trained model (paper §3.2.4): depth maps of the training views fused
//! into a truncated signed distance on sparse grid points, and its zero level set
//! extracted by marching cubes over the sparse voxels.
//!
//! - [`extract`](mod@extract): depth renders → surface cells at one level → TSDF → marching cubes.
//! - [`mc`]: marching cubes over sparse voxels (watertight, vertices shared on grid-point
//!   edges).
//! - [`metrics`]: accuracy, completeness, Chamfer distance and F-score against points.
//! - [`ply`]: binary PLY output (and input, binary or ASCII).
//! - [`glb`]: glTF 2.0 binary output.
//! - [`view`]: a CPU rasterizer for looking at meshes and measuring silhouettes.
//! - [`tsdf`]: truncated signed distance fusion of rendered depth maps on the GPU.

pub mod extract;
pub mod glb;
pub mod mc;
pub mod metrics;
pub mod ply;
pub mod tsdf;
pub mod view;

pub use extract::{extract, render_depths, DepthKind, Extraction, MeshOptions, Report};
pub use mc::{marching_cubes, TriMesh};
pub use tsdf::{DepthView, FuseParams, TsdfFuser};
