//! clap commands.

mod bench;
mod info;

use clap::{Parser, Subcommand};
use svraster::gpu::{Context, ContextOptions};

#[derive(Parser)]
#[command(
    name = "svraster",
    version,
    about = "Sparse-voxel radiance fields on Vulkan compute"
)]
struct Cli {
    /// Vulkan device: index or name substring (default: SVRASTER_DEVICE, else the best
    /// of discrete > integrated > virtual > CPU).
    #[arg(long, global = true)]
    device: Option<String>,
    /// Enable the Khronos validation layer; any validation message makes the command fail.
    #[arg(long, global = true)]
    validation: bool,
    #[command(subcommand)]
    cmd: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print the device, driver, limits and enabled features.
    Info {
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Benchmarks.
    Bench {
        #[command(subcommand)]
        what: bench::BenchCmd,
    },
}

pub fn run() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let ctx = Context::new(&ContextOptions {
        device: cli.device.clone(),
        validation: cli.validation,
    })?;
    match cli.cmd {
        Command::Info { json } => info::run(&ctx, json)?,
        Command::Bench { what } => bench::run(&ctx, what)?,
    }
    ctx.check_validation()?;
    Ok(())
}

/// Median of a non-empty slice.
pub fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(|a, b| a.total_cmp(b));
    let m = s.len() / 2;
    if s.len() % 2 == 1 {
        s[m]
    } else {
        0.5 * (s[m - 1] + s[m])
    }
}
