//! `svraster`: the command-line front end of the svraster library (see `svraster
//! --help`): clap commands, progress bars, plots, signals.

mod bench;
mod bench_report;
mod bench_sort;
mod demo;
mod export;
mod field;
mod import;
mod info;
mod inputs;
mod mesh;
mod outputs;
mod paths;
mod plot;
mod progress;
mod render;
mod run_dir;
mod trade;
mod train;
mod train_loop;
mod view;

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

/// How to read a dataset (captures).
#[derive(clap::Args, Clone, Debug, Default)]
pub struct DataArgs {
    /// Dataset layout (default: detected — transforms_*.json: blender; sparse/0: colmap;
    /// transforms.json: nerfstudio; poses_bounds.npy: llff; cameras_sphere.npz: neus).
    #[arg(long, value_parser = svraster::data::Format::NAMES)]
    format: Option<String>,
    /// Image folder of a capture, e.g. images_4 (intrinsics scaled to its images;
    /// default: images/, else the only images_N folder).
    #[arg(long)]
    images: Option<String>,
    /// Every N-th view of a capture (natural name order, from the first) is held out as
    /// the `test` split (default 8; 0: none).
    #[arg(long)]
    holdout: Option<usize>,
}

impl DataArgs {
    pub fn source(&self) -> svraster::data::SourceOptions {
        svraster::data::SourceOptions {
            format: self
                .format
                .as_deref()
                .and_then(svraster::data::Format::from_name),
            images: self.images.clone(),
            holdout: self.holdout,
        }
    }
}

/// `explicit` where given, else the run's own (from `model`'s config.json when it is a
/// run directory or a file in one), else the defaults.
fn run_source(model: &std::path::Path, explicit: &DataArgs) -> svraster::data::SourceOptions {
    let run: svraster::data::SourceOptions = run_config(model)
        .and_then(|v| serde_json::from_value(v["source"].clone()).ok())
        .unwrap_or_default();
    let e = explicit.source();
    svraster::data::SourceOptions {
        format: e.format.or(run.format),
        images: e.images.or(run.images),
        holdout: e.holdout.or(run.holdout),
    }
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
    /// evaluate the test views and render them (rgb, depth, normal and photo-beside-render
    /// PNGs).
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
        /// Also write per-primitive label images, OUT/labels/{train,val,test}/r_i.png
        /// (8-bit: 40·(primitive + 1), background 0), for `svraster fuse`.
        #[arg(long)]
        labels: bool,
    },
    /// Train a model on the train split of a dataset (Blender, COLMAP, nerfstudio or LLFF).
    Train {
        /// Dataset directory: Blender (transforms_*.json), COLMAP (sparse/0 + images),
        /// nerfstudio (transforms.json), LLFF (poses_bounds.npy) or NeuS
        /// (cameras_sphere.npz + image/ + mask/); see --format.
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
        /// Configuration preset: synthetic, real, forward, object, mesh, quick,
        /// svraster-synthetic or svraster-real (SVRaster's own rules, docs/PARITY.md),
        /// optionally
        /// with a speed modifier: `fast-train` or `fast-render` alone (on the data's preset)
        /// or appended, e.g. real-fast-render (docs/PERFORMANCE.md "Speed ↔ accuracy") (default: the
        /// data's — Blender: synthetic, COLMAP/nerfstudio: real, LLFF: forward, NeuS:
        /// object; with --resume: the run's).
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
        /// Bitwise-reproducible training: gradients summed in a fixed order instead of
        /// with float atomics, so two runs with the same seed and data on the same device
        /// write identical checkpoints (slower: docs/NUMERICS.md "Deterministic training"; same as
        /// --set deterministic=true).
        #[arg(long)]
        deterministic: bool,
        /// Continue the run in --out from its last checkpoint.
        #[arg(long)]
        resume: bool,
        /// Print a JSON summary on stdout at the end (run, model, iterations, seconds,
        /// voxels, interrupted).
        #[arg(long)]
        json: bool,
        /// Evaluate the held-out split (test, else val) every N iterations and at the end:
        /// PSNR and SSIM into stats.jsonl (`{"eval": …}` lines), the progress and
        /// training.png.
        #[arg(long)]
        eval_every: Option<u32>,
        /// A config.json (another run's, or a bare configuration object) as the base of
        /// this run instead of a preset; --iters, --seed and --set apply on top.
        #[arg(long)]
        config: Option<PathBuf>,
        #[command(flatten)]
        source: DataArgs,
    },
    /// Evaluate a model on a dataset split: mean PSNR and SSIM, frame time.
    Eval {
        /// A .safetensors checkpoint, or a run directory holding model.safetensors.
        model: PathBuf,
        /// Dataset directory whose held-out views are scored (Blender, COLMAP,
        /// nerfstudio, LLFF or NeuS; see --format; default: the run's own when MODEL is
        /// a run directory).
        #[arg(long)]
        data: Option<PathBuf>,
        /// Split to evaluate (default: test, else val when the dataset has no test split;
        /// captures: test = every --holdout-th view, all = every view).
        #[arg(long, value_parser = ["train", "val", "test", "all"])]
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
        /// (default: the run's own when MODEL is a run directory)
        #[command(flatten)]
        source: DataArgs,
    },
    /// Render every frame of a dataset split with a model.
    Render {
        /// A .safetensors checkpoint, or a run directory holding model.safetensors.
        model: PathBuf,
        /// Dataset directory (Blender, COLMAP, nerfstudio, LLFF or NeuS; see --format;
        /// default: the run's own when MODEL is a run directory).
        #[arg(long)]
        data: Option<PathBuf>,
        /// Split to render (default: test, else val when the dataset has no test split;
        /// captures: test = every --holdout-th view, all = every view).
        #[arg(long, value_parser = ["train", "val", "test", "all"])]
        split: Option<String>,
        /// Downscale factor of the images (area averaging; intrinsics scaled; default: the
        /// run's own when MODEL is a run directory, else 1).
        #[arg(long)]
        downscale: Option<f64>,
        /// Output directory: one PNG per frame, named after the frame's file.
        #[arg(long)]
        out: PathBuf,
        /// Also write the depth: NAME_depth16.png (16-bit metric camera-z depth, 0 where
        /// there is no surface), NAME_depth.json (its scale and range) and NAME_depth.png
        /// (an 8-bit visualisation).
        #[arg(long)]
        depth: bool,
        /// Also write NAME_normal.png.
        #[arg(long)]
        normal: bool,
        /// Also write NAME_compare.png: the photo (left) beside the render (right).
        #[arg(long)]
        compare: bool,
        /// Samples per ray-voxel segment (1..=3).
        #[arg(long, default_value_t = 1)]
        samples: u32,
        /// Supersampling factor (>= 1; anti-aliased downsample; default: the model's, i.e.
        /// the `ss` it was trained with).
        #[arg(long)]
        ss: Option<f32>,
        /// Render a field made by `svraster fuse` instead of colour: per frame
        /// NAME_field.png (labels: the arg-max class's 8-bit value, 0 where nothing is
        /// hit; features: the first three principal components as colour, the
        /// projection in field_pca.json) and NAME_field.npy (H×W×C float32: class
        /// probabilities or features).
        #[arg(long)]
        field: Option<PathBuf>,
        /// With a label --field: folder of truth label PNGs (NAME.png per frame) to score
        /// it against: IoU per class, printed and written to field_scores.json.
        #[arg(long)]
        truth: Option<PathBuf>,
        /// Read the --truth images as masks: {0, 255}, 255 where the mean of their
        /// channels is above one half (soft masks such as DTU's).
        #[arg(long)]
        mask: bool,
        /// Pair the --truth files with the dataset's views in natural name order (one per
        /// view of the whole dataset) instead of by name: NeuS/DTU masks.
        #[arg(long)]
        by_order: bool,
        /// Print a JSON summary (split, out, frames, PSNR, ms per frame; with --field its
        /// scores) instead of the line.
        #[arg(long)]
        json: bool,
        /// Render a camera path instead of a split: `orbit` (around what the training
        /// cameras look at, at their mean distance and height), `spiral` (NeRF's, for
        /// forward-facing captures), `train` (a smooth
        /// fly-through of the training cameras in order) or a nerfstudio
        /// camera_path.json (camera_to_world in the dataset's world, OpenGL axes; fov
        /// vertical). --out DIR writes frame_NNNNN.png; --out X.mp4 also encodes H.264
        /// with the system's ffmpeg (frames kept in X.mp4.frames/).
        #[arg(long)]
        path: Option<String>,
        /// Frames of an orbit or fly-through.
        #[arg(long, default_value_t = 120)]
        frames: usize,
        /// Image size of the path's frames, WxH (default: the training images', or the
        /// camera_path.json's render_width × render_height).
        #[arg(long, value_parser = parse_size)]
        size: Option<(u32, u32)>,
        /// Horizontal field of view of the path's frames, degrees (default: the first
        /// training camera's).
        #[arg(long)]
        fov: Option<f64>,
        /// (default: the run's own when MODEL is a run directory)
        #[command(flatten)]
        source: DataArgs,
    },
    /// Fuse per-view labels or features into a model's voxels (paper §3.2.4): each voxel
    /// takes the mean of the values of the pixels its rays contribute to, weighted by its
    /// blending weight in each. Render the field with `render --field`.
    Fuse {
        /// A .safetensors checkpoint, or a run directory holding model.safetensors.
        model: PathBuf,
        /// Dataset the model was trained on (default: the run's own when MODEL is a run
        /// directory).
        #[arg(long)]
        data: Option<PathBuf>,
        /// Folder with one file per frame of the split, named after the frame's image:
        /// NAME.png (8-bit labels: each distinct value a class; masks are {0, 255}) or
        /// NAME.npy (H×W×C float features, C ≤ 1024, any size of the image's aspect
        /// ratio: resampled by area).
        #[arg(long)]
        from: PathBuf,
        /// Split whose views are fused.
        #[arg(long, default_value = "train", value_parser = ["train", "val", "test", "all"])]
        split: String,
        /// Downscale factor of the views (default: the run's own when MODEL is a run
        /// directory, else 1); the files are resampled to the downscaled views.
        #[arg(long)]
        downscale: Option<f64>,
        /// Output field (safetensors, written atomically).
        #[arg(long)]
        out: PathBuf,
        /// Read the label images as masks: {0, 255}, 255 where the mean of their channels
        /// is above one half (soft-edged masks such as DTU's).
        #[arg(long)]
        mask: bool,
        /// Pair the files of --from with the dataset's views in natural name order
        /// (one file per view of the whole dataset) instead of by name: NeuS/DTU masks
        /// (mask/000.png … for image/000000.png …).
        #[arg(long)]
        by_order: bool,
        /// Supersampling factor (default: the model's).
        #[arg(long)]
        ss: Option<f32>,
        /// Print a JSON summary.
        #[arg(long)]
        json: bool,
        /// (default: the run's own when MODEL is a run directory)
        #[command(flatten)]
        source: DataArgs,
    },
    /// Extract a triangle mesh (binary PLY, world coordinates) from a model: the surface
    /// depth of the training views fused into a truncated signed distance on sparse
    /// voxels of one level, then marching cubes.
    Mesh {
        /// A .safetensors checkpoint, or a run directory holding model.safetensors.
        model: PathBuf,
        /// Dataset the model was trained on (its views are fused; default: the run's own
        /// when MODEL is a run directory).
        #[arg(long)]
        data: Option<PathBuf>,
        /// Output mesh, written atomically: binary PLY, or glTF 2.0 binary when it ends in
        /// .glb (vertex colours as COLOR_0; Blender, three.js, game engines).
        #[arg(long)]
        out: PathBuf,
        /// Split whose views are fused.
        #[arg(long, default_value = "train", value_parser = ["train", "val", "test", "all"])]
        split: String,
        /// Downscale factor of the views (default: the run's own when MODEL is a run
        /// directory, else 1).
        #[arg(long)]
        downscale: Option<f64>,
        /// Octree level of the marching-cubes voxels (default: the level most of the
        /// model's voxels in the region have; each level down halves the resolution and
        /// quarters the triangles).
        #[arg(long)]
        level: Option<u32>,
        /// Truncation band of the signed distance, in voxels of the mesh level.
        #[arg(long, default_value_t = 5.0)]
        trunc: f64,
        /// Box to mesh, world coordinates: min x y z then max x y z (default: the run's
        /// main region, else the whole model).
        #[arg(long, num_args = 6, allow_negative_numbers = true, value_names = ["X0", "Y0", "Z0", "X1", "Y1", "Z1"])]
        bbox: Option<Vec<f64>>,
        /// Depth fused: median (where transmittance crosses 0.5) or mean.
        #[arg(long, default_value = "median", value_parser = ["median", "mean"])]
        depth: String,
        /// Samples per ray-voxel segment of the depth renders (1..=3).
        #[arg(long, default_value_t = 1)]
        samples: u32,
        /// Write per-vertex colours (the model's view-independent colour).
        #[arg(long)]
        vertex_colors: bool,
        /// Most voxels the extraction may fuse.
        #[arg(long, default_value_t = 64 << 20)]
        max_voxels: u64,
        /// Write N views (evenly spaced over the split) as OUT_NAME.png: the photo beside
        /// the mesh, shaded.
        #[arg(long, default_value_t = 0)]
        preview: usize,
        /// Print a JSON summary (file, vertices, triangles, area, open edges, level,
        /// seconds per stage) instead of the line.
        #[arg(long)]
        json: bool,
        /// (default: the run's own when MODEL is a run directory)
        #[command(flatten)]
        source: DataArgs,
    },
    /// Measure a mesh (PLY, world coordinates) against a ground truth: accuracy,
    /// completeness, Chamfer distance and F-score (DTU protocol terms), and the silhouette
    /// IoU against the masks of a NeuS capture.
    EvalMesh {
        /// The mesh (binary little-endian PLY, e.g. from `svraster mesh`).
        mesh: PathBuf,
        /// The dataset: its cameras decide what is visible (--demo); a NeuS capture's
        /// masks are compared with the mesh's silhouettes.
        #[arg(long)]
        data: PathBuf,
        /// Split whose cameras are used.
        #[arg(long, default_value = "train", value_parser = ["train", "val", "test", "all"])]
        split: String,
        /// Downscale of the views the silhouettes are compared at.
        #[arg(long, default_value_t = 1.0)]
        downscale: f64,
        /// Ground truth: the built-in demo scene's analytic surface, where the split's
        /// cameras see it.
        #[arg(long)]
        demo: bool,
        /// Ground truth: a point cloud (PLY, world coordinates).
        #[arg(long)]
        truth: Option<PathBuf>,
        /// Distance below which a point counts as matched (F-score; default: demo 0.02,
        /// else 0.5 % of the truth's bounding-box diagonal).
        #[arg(long)]
        threshold: Option<f64>,
        /// Distances are clamped at this (outlier threshold; default 5× (demo) or 10× the
        /// threshold).
        #[arg(long)]
        max_dist: Option<f64>,
        /// Print one JSON object.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        source: DataArgs,
    },
    /// Export a model for other tools: `ply` (one point per voxel: centre, size, level,
    /// density, DC colour; world coordinates) or `quantized` (an 8-bit checkpoint, ~70 %
    /// smaller, that render, eval, mesh and the viewer load like any model).
    Export {
        /// A .safetensors model or a run directory holding model.safetensors.
        model: PathBuf,
        #[arg(long, value_enum, default_value = "ply")]
        format: export::ExportFormat,
        /// The file to write (atomically).
        #[arg(long)]
        out: PathBuf,
        /// Print a JSON summary (file, format, bytes, voxels) instead of the line.
        #[arg(long)]
        json: bool,
    },
    /// Convert a model trained by SVRaster (NVlabs/svraster: MODEL_DIR/checkpoints/
    /// iterNNNNNN_model.pt, plain or quantized) into a checkpoint of ours: the same
    /// voxels, grid-point densities and SH, copied. `render`, `eval`, `mesh`, `export`
    /// and `view` also read the .pt directly, with the defaults below.
    /// Background and supersampling come from the `config.yaml` SVRaster wrote beside
    /// `checkpoints/` when there is one; the options override it.
    Import {
        /// SVRaster's checkpoint (`torch.save` of its SVInOut.save; read without PyTorch).
        checkpoint: PathBuf,
        /// The model to write (.safetensors, atomically).
        #[arg(long)]
        out: PathBuf,
        /// The background, which SVRaster's checkpoint does not record: white
        /// (NeRF-synthetic, `white_background`), black (DTU), frame-mean (each frame's
        /// own mean colour: Mip-NeRF 360 and other captures trained with neither) or
        /// R,G,B. Default: MODEL_DIR/config.yaml's, else black.
        #[arg(long, value_parser = import::parse_background)]
        background: Option<import::Background>,
        /// The supersampling it was trained with (SVRaster's `ss`; renders use it).
        /// Default: MODEL_DIR/config.yaml's, else 1.5.
        #[arg(long)]
        ss: Option<f32>,
        /// Print a JSON summary instead of the line.
        #[arg(long)]
        json: bool,
    },
    /// Look at a model in a window: orbit/fly, the training cameras as frusta to jump
    /// between (`]` `[`), colour/depth/normal (M), SH degree (H), samples (K), frame
    /// time on screen; --screenshot for headless use.
    View(view::ViewArgs),
    /// Benchmarks.
    Bench {
        #[command(subcommand)]
        what: bench::BenchCmd,
    },
}

pub fn run() -> anyhow::Result<()> {
    let cli = Cli::parse();
    // The viewer opens its own device, one that can present to its window.
    let cli = match cli.cmd {
        Command::View(a) => {
            if cli.device.is_some() {
                anyhow::bail!(
                    "view picks the first device that can present to its window; --device                      applies to the other commands"
                );
            }
            return view::run(a, cli.validation);
        }
        cmd => Cli { cmd, ..cli },
    };
    let ctx = Context::new(&ContextOptions {
        device: cli.device.clone(),
        validation: cli.validation,
    })?;
    match cli.cmd {
        Command::View(_) => unreachable!("handled before the context is made"),
        Command::Info { json } => info::run(&ctx, json)?,
        Command::Bench { what } => bench::run(&ctx, what)?,
        Command::Export {
            model,
            format,
            out,
            json,
        } => export::run(&model, format, &out, json)?,
        Command::Import {
            checkpoint,
            out,
            background,
            ss,
            json,
        } => import::run(&checkpoint, &out, background, ss, json)?,
        Command::Demo {
            out,
            size,
            iters,
            level,
            seed,
            voxelize,
            labels,
        } => demo::run_demo(
            &ctx,
            demo::DemoArgs {
                out,
                size,
                iters,
                level,
                seed,
                voxelize,
                labels,
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
            deterministic,
            resume,
            json,
            eval_every,
            config,
            source,
        } => {
            if let Some(n) = max_voxels {
                set.push(format!("max_voxels={n}"));
            }
            if deterministic {
                if resume {
                    anyhow::bail!(
                        "--deterministic: a resumed run keeps the setting it was started with \
                         (RUN/config.json); drop --deterministic"
                    );
                }
                set.push("deterministic=true".into());
            }
            let out_dir = out.clone();
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
                    source: source.source(),
                    eval_every,
                    config,
                },
            )?;
            if json {
                println!("{}", serde_json::to_string_pretty(&s.json(&out_dir))?);
            }
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
            source,
        } => {
            let data = data_or_run(data, &model)?;
            let split = split.unwrap_or_else(|| default_split(&data));
            let downscale = downscale.unwrap_or_else(|| run_downscale(&model));
            let source = run_source(&model, &source);
            let views = train::Views {
                data: &data,
                split: &split,
                downscale,
                source: &source,
            };
            train::run_eval(&ctx, &model, &views, ss, json)?
        }
        Command::Mesh {
            model,
            data,
            out,
            split,
            downscale,
            level,
            trunc,
            bbox,
            depth,
            samples,
            vertex_colors,
            max_voxels,
            preview,
            json,
            source,
        } => {
            let data = data_or_run(data, &model)?;
            // Where the run writes it: config.json's `config` (the top level has none).
            let main_region = run_config(&model).and_then(|v| {
                let c: [f64; 3] = serde_json::from_value(v["config"]["center"].clone()).ok()?;
                let e = v["config"]["extent"].as_f64()?;
                Some((c, e))
            });
            mesh::run_mesh(
                &ctx,
                mesh::MeshArgs {
                    downscale: downscale.unwrap_or_else(|| run_downscale(&model)),
                    source: run_source(&model, &source),
                    model,
                    data,
                    out,
                    split,
                    level,
                    trunc,
                    bbox,
                    depth: if depth == "mean" {
                        svraster::mesh::DepthKind::Mean
                    } else {
                        svraster::mesh::DepthKind::Median
                    },
                    samples,
                    vertex_colors,
                    max_voxels,
                    preview,
                    main_region,
                    json,
                },
            )?
        }
        Command::EvalMesh {
            mesh,
            data,
            split,
            downscale,
            demo,
            truth,
            threshold,
            max_dist,
            json,
            source,
        } => mesh::run_eval_mesh(mesh::EvalMeshArgs {
            mesh,
            data,
            split,
            downscale,
            source: source.source(),
            demo,
            truth,
            threshold,
            max_dist,
            json,
        })?,
        Command::Render {
            model,
            data,
            split,
            downscale,
            out,
            depth,
            normal,
            compare,
            samples,
            ss,
            field,
            truth,
            mask,
            by_order,
            json,
            path,
            frames,
            size,
            fov,
            source,
        } => {
            let data = data_or_run(data, &model)?;
            render::run_render(
                &ctx,
                render::RenderArgs {
                    split: split.unwrap_or_else(|| default_split(&data)),
                    downscale: downscale.unwrap_or_else(|| run_downscale(&model)),
                    source: run_source(&model, &source),
                    model,
                    data,
                    out,
                    depth,
                    normal,
                    compare,
                    samples,
                    ss,
                    field,
                    truth,
                    mask,
                    by_order,
                    json,
                    path,
                    frames,
                    size,
                    fov,
                },
            )?
        }
        Command::Fuse {
            model,
            data,
            from,
            split,
            downscale,
            out,
            mask,
            by_order,
            ss,
            json,
            source,
        } => {
            let data = data_or_run(data, &model)?;
            field::run_fuse(
                &ctx,
                field::FuseArgs {
                    downscale: downscale.unwrap_or_else(|| run_downscale(&model)),
                    source: run_source(&model, &source),
                    model,
                    data,
                    from,
                    split,
                    out,
                    mask,
                    by_order,
                    ss,
                    json,
                },
            )?
        }
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

/// The run's config.json when `model` is a run directory or a file in one.
/// `--data`, else the dataset recorded in the run's config.json when MODEL is a run
/// directory (or a file in one).
fn data_or_run(data: Option<PathBuf>, model: &std::path::Path) -> anyhow::Result<PathBuf> {
    if let Some(d) = data {
        return Ok(d);
    }
    match run_config(model).and_then(|v| v["data"].as_str().map(PathBuf::from)) {
        Some(d) => {
            eprintln!("data {} (the run's; --data to choose)", d.display());
            Ok(d)
        }
        None => anyhow::bail!(
            "--data is needed: {} is not a run directory whose config.json names its dataset; \
             pass --data DATASET",
            model.display()
        ),
    }
}

/// `--size WxH`.
fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("`{s}`: expected WxH, e.g. 1280x720"))?;
    let p = |v: &str| {
        v.trim()
            .parse::<u32>()
            .map_err(|_| format!("`{s}`: expected WxH, e.g. 1280x720"))
    };
    Ok((p(w)?, p(h)?))
}

fn run_config(model: &std::path::Path) -> Option<serde_json::Value> {
    let dir = if model.is_dir() {
        model
    } else {
        model.parent()?
    };
    let text = std::fs::read_to_string(dir.join("config.json")).ok()?;
    serde_json::from_str(&text).ok()
}

/// The downscale a model was trained at when `model` is a run directory (or a file in
/// one) with config.json; else 1.
fn run_downscale(model: &std::path::Path) -> f64 {
    let d = run_config(model)
        .and_then(|v| v["downscale"].as_f64())
        .filter(|d| d.is_finite() && *d >= 1.0);
    if let Some(d) = d {
        if d != 1.0 {
            eprintln!("downscale {d} (the run's; --downscale to choose)");
        }
    }
    d.unwrap_or(1.0)
}

fn main() {
    if let Err(e) = run() {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
