//! Training: backward pass, losses, optimiser and the training loop (paper §3.2).

pub mod backward;
pub mod config;
pub mod loss;
pub mod optim;
pub mod ssim;
pub mod trainer;
