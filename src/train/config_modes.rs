//! The enumerated training switches of [`TrainConfig`](super::config::TrainConfig)
//! (`--set key=name`).

use serde::{Deserialize, Serialize};

/// How the voxel layout changes during training (see [`super::config::TrainConfig::layout`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Layout {
    Adaptive,
    Uniform,
    Fixed,
}

/// The total-variation penalty's form (see [`super::config::TrainConfig::tv_form`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TvForm {
    L2,
    L1,
}

/// How a gradient passes a clamp (see [`super::config::TrainConfig::colour_clamp_grad`]
/// and [`super::config::TrainConfig::alpha_clamp_grad`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ClampGrad {
    /// The clamp's own derivative: no gradient where the value is clamped.
    #[default]
    Masked,
    /// Straight through: the gradient passes as if there were no clamp.
    Straight,
}
