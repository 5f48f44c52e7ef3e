//! Training: backward pass, losses, optimiser, adaptive layout and the training loop
//! (paper §3.2).

mod adapt_step;
pub mod backward;
pub mod bounds;
pub mod config;
mod config_modes;
mod init;
mod iteration;
pub mod loss;
pub mod optim;
mod presets;
mod queue;
mod schedule;
pub mod ssim;
pub mod trainer;
mod update;
pub mod views;
