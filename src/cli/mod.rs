//! clap commands.

mod bench;
mod info;
mod render;

use std::path::PathBuf;

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
    /// Generate the built-in procedural scene (Blender-format dataset), build a
    /// checkpoint from it and render its test views.
    Demo {
        /// Output directory (dataset in OUT/data, model, renders in OUT/renders).
        #[arg(long, default_value = "demo_out")]
        out: PathBuf,
        /// Image edge in pixels.
        #[arg(long, default_value_t = 200)]
        size: u32,
        /// Finest octree level of the voxelized scene (7 ≈ 66k voxels, 9 ≈ 1.1M).
        #[arg(long, default_value_t = 7)]
        level: u32,
        /// Seed of the training camera positions.
        #[arg(long, default_value_t = 0)]
        seed: u64,
    },
    /// Render every frame of a dataset split with a model.
    Render {
        /// A .safetensors checkpoint, or a run directory holding model.safetensors.
        model: PathBuf,
        /// Blender-format dataset directory (transforms_{split}.json + images).
        #[arg(long)]
        data: PathBuf,
        /// Split to render.
        #[arg(long, default_value = "test", value_parser = ["train", "val", "test"])]
        split: String,
        /// Downscale factor of the images (area averaging; intrinsics scaled).
        #[arg(long, default_value_t = 1.0)]
        downscale: f64,
        /// Output directory: one PNG per frame, named after the frame's file.
        #[arg(long)]
        out: PathBuf,
        /// Also write NAME_depth.png.
        #[arg(long)]
        depth: bool,
        /// Also write NAME_normal.png.
        #[arg(long)]
        normal: bool,
        /// Samples per ray-voxel segment (1..=3).
        #[arg(long, default_value_t = 1)]
        samples: u32,
        /// Supersampling factor (>= 1; anti-aliased downsample).
        #[arg(long, default_value_t = 1.0)]
        ss: f32,
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
        Command::Demo {
            out,
            size,
            level,
            seed,
        } => render::run_demo(
            &ctx,
            render::DemoArgs {
                out,
                size,
                level,
                seed,
            },
        )?,
        Command::Render {
            model,
            data,
            split,
            downscale,
            out,
            depth,
            normal,
            samples,
            ss,
        } => render::run_render(
            &ctx,
            render::RenderArgs {
                model,
                data,
                split,
                downscale,
                out,
                depth,
                normal,
                opts: svraster::raster::RenderOptions {
                    samples,
                    supersample: ss,
                },
            },
        )?,
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
