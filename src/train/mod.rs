//! Training: backward pass, losses, optimiser, adaptive layout and the training loop
//! (paper §3.2).

pub mod adapt_stats;
pub mod backward;
pub mod config;
pub mod loss;
pub mod optim;
pub mod ssim;
pub mod topology;
pub mod trainer;
