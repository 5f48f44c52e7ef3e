//! clap commands.

mod bench;
mod bench_sort;
mod info;
mod plot;
mod progress;
mod render;
mod run_dir;
mod trade;
mod train;

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
    /// Generate the built-in procedural scene (Blender-format dataset), train on it,
    /// evaluate the test views and render them (rgb, depth, normal PNGs).
    Demo {
        /// Output directory: dataset in OUT/data, the run in OUT/run, renders in OUT/renders.
        #[arg(long, default_value = "demo_out")]
        out: PathBuf,
        /// Image edge in pixels.
        #[arg(long, default_value_t = 80)]
        size: u32,
        /// Training iterations.
        #[arg(long, default_value_t = 300)]
        iters: u32,
        /// Level of the initial voxel grid (5: 32 768 voxels), pruned and subdivided during
        /// training (with --voxelize: the finest level).
        #[arg(long, default_value_t = 5)]
        level: u32,
        /// Seed of the camera positions and of training.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Skip training: voxelize the analytic primitives adaptively down to --level
        /// (a reference model for rendering benchmarks; tools/bench_render.sh).
        #[arg(long)]
        voxelize: bool,
    },
    /// Train a model on the train split of a Blender-format dataset.
    Train {
        /// Dataset directory (transforms_train.json + images).
        data: PathBuf,
        /// Run directory: config.json, stats.jsonl, model.safetensors, optimizer.safetensors.
        #[arg(long)]
        out: PathBuf,
        /// Iterations (default 20 000; every milestone scales with it).
        #[arg(long)]
        iters: Option<u32>,
        /// Downscale factor of the images (area averaging; default 1, or the run's own
        /// with --resume).
        #[arg(long)]
        downscale: Option<f64>,
        /// Configuration preset: synthetic (default) or quick (with --resume: the run's).
        #[arg(long)]
        preset: Option<String>,
        /// Random seed.
        #[arg(long)]
        seed: Option<u64>,
        /// Override a config value, e.g. --set grid_level=6 --set lambda_ssim=0 (keys as
        /// in RUN/config.json).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Voxel budget: subdivision stops at this many voxels (default: derived from
        /// the device's memory; same as --set max_voxels=N).
        #[arg(long)]
        max_voxels: Option<u64>,
        /// Continue the run in --out from its last checkpoint.
        #[arg(long)]
        resume: bool,
    },
    /// Evaluate a model on a dataset split: mean PSNR and SSIM, frame time.
    Eval {
        /// A .safetensors checkpoint, or a run directory holding model.safetensors.
        model: PathBuf,
        #[arg(long)]
        data: PathBuf,
        /// Split to evaluate (default: test, else val when the dataset has no test split).
        #[arg(long, value_parser = ["train", "val", "test"])]
        split: Option<String>,
        /// Downscale factor of the images (default: the run's own when MODEL is a run
        /// directory, else 1).
        #[arg(long)]
        downscale: Option<f64>,
        /// Print one JSON object (psnr, ssim, views, ms_per_frame, per_view …) on stdout.
        #[arg(long)]
        json: bool,
        /// Supersampling factor of the renders (default: the model's, i.e. the `ss` it was
        /// trained with; 1 = none).
        #[arg(long)]
        ss: Option<f32>,
    },
    /// Render every frame of a dataset split with a model.
    Render {
        /// A .safetensors checkpoint, or a run directory holding model.safetensors.
        model: PathBuf,
        /// Blender-format dataset directory (transforms_{split}.json + images).
        #[arg(long)]
        data: PathBuf,
        /// Split to render (default: test, else val when the dataset has no test split).
        #[arg(long, value_parser = ["train", "val", "test"])]
        split: Option<String>,
        /// Downscale factor of the images (area averaging; intrinsics scaled; default: the
        /// run's own when MODEL is a run directory, else 1).
        #[arg(long)]
        downscale: Option<f64>,
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
        /// Supersampling factor (>= 1; anti-aliased downsample; default: the model's, i.e.
        /// the `ss` it was trained with).
        #[arg(long)]
        ss: Option<f32>,
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
            iters,
            level,
            seed,
            voxelize,
        } => train::run_demo(
            &ctx,
            train::DemoArgs {
                out,
                size,
                iters,
                level,
                seed,
                voxelize,
            },
        )?,
        Command::Train {
            data,
            out,
            iters,
            downscale,
            preset,
            seed,
            mut set,
            max_voxels,
            resume,
        } => {
            if let Some(n) = max_voxels {
                set.push(format!("max_voxels={n}"));
            }
            let s = train::run_train(
                &ctx,
                &train::TrainArgs {
                    data,
                    out,
                    iters,
                    downscale,
                    preset,
                    seed,
                    set,
                    resume,
                },
            )?;
            if s.interrupted {
                ctx.check_validation()?;
                std::process::exit(130);
            }
        }
        Command::Eval {
            model,
            data,
            split,
            downscale,
            json,
            ss,
        } => {
            let split = split.unwrap_or_else(|| default_split(&data));
            let downscale = downscale.unwrap_or_else(|| run_downscale(&model));
            train::run_eval(&ctx, &model, &data, &split, downscale, ss, json)?
        }
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
                split: split.unwrap_or_else(|| default_split(&data)),
                downscale: downscale.unwrap_or_else(|| run_downscale(&model)),
                model,
                data,
                out,
                depth,
                normal,
                samples,
                ss,
            },
        )?,
    }
    ctx.check_validation()?;
    Ok(())
}

/// The split `eval`/`render` use by default: `test`, else `val` when the dataset has no
/// `transforms_test.json` (e.g. lego_400, whose test split is held back).
fn default_split(data: &std::path::Path) -> String {
    let split = if data.join("transforms_test.json").is_file()
        || !data.join("transforms_val.json").is_file()
    {
        "test"
    } else {
        "val"
    };
    if split != "test" {
        eprintln!(
            "{} has no test split: using `val` (--split to choose)",
            data.display()
        );
    }
    split.to_string()
}

/// The downscale a model was trained at when `model` is a run directory (or a file in
/// one) with config.json; else 1.
fn run_downscale(model: &std::path::Path) -> f64 {
    let dir = if model.is_dir() {
        Some(model)
    } else {
        model.parent()
    };
    let d = dir
        .and_then(|d| std::fs::read_to_string(d.join("config.json")).ok())
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .and_then(|v| v["downscale"].as_f64())
        .filter(|d| d.is_finite() && *d >= 1.0);
    if let Some(d) = d {
        if d != 1.0 {
            eprintln!("downscale {d} (the run's; --downscale to choose)");
        }
    }
    d.unwrap_or(1.0)
}
