//! `svraster demo`: the procedural dataset (checked against this machine's memory and
//! disk, written beside and moved into place), then training, evaluation and renders.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context as _};
use svraster::data;
use svraster::gpu::Context;
use svraster::raster::RenderOptions;
use svraster::scene::checkpoint;

use super::progress::fmt_duration;
use super::run_dir::lock_run;
use super::train::{canonical, evaluate, resolve_config, run_train, RunSummary, TrainArgs, Views};

pub struct DemoArgs {
    pub out: PathBuf,
    pub size: u32,
    pub iters: u32,
    pub level: u32,
    pub seed: u64,
    pub voxelize: bool,
    /// Also write per-primitive label images (OUT/labels/SPLIT/r_i.png).
    pub labels: bool,
}

/// Runs `write(tmp)` into `dir` + `.partial` (made afresh), then replaces `dir` with it;
/// on failure removes the partial folder and says nothing was kept.
fn staged(dir: &Path, write: impl FnOnce(&Path) -> anyhow::Result<()>) -> anyhow::Result<()> {
    let mut name = dir.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    let tmp = dir.with_file_name(name);
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp)
            .with_context(|| format!("cannot clear {} of an earlier demo", tmp.display()))?;
    }
    std::fs::create_dir_all(&tmp).with_context(|| format!("cannot create {}", tmp.display()))?;
    if let Err(e) = write(&tmp) {
        let _ = std::fs::remove_dir_all(&tmp);
        bail!("{e:#}; nothing of {} was kept", dir.display());
    }
    if dir.exists() {
        std::fs::remove_dir_all(dir)
            .with_context(|| format!("cannot replace {} of an earlier demo", dir.display()))?;
    }
    std::fs::rename(&tmp, dir)
        .with_context(|| format!("cannot move {} to {}", tmp.display(), dir.display()))
}

/// Refuses a demo this machine cannot hold, before anything is written: the training
/// views stay in memory as f32 RGB, 12 bytes per pixel on the host and as many on the
/// device (host memory too on a CPU device), and the dataset's PNGs take up to 4 bytes
/// per pixel on disk.
fn check_demo_resources(
    ctx: &Context,
    opts: &svraster::data::demo::DemoOptions,
    out: &Path,
) -> anyhow::Result<()> {
    let px = u64::from(opts.width) * u64::from(opts.height);
    let views = (opts.train + opts.val + opts.test) as u64;
    let train = opts.train as u64 * px * 12;
    let cpu = ctx.info().is_cpu;
    // The frame, loss and backward buffers at the image's size: ~64 floats per pixel.
    let frame = px * 256;
    let host = if cpu { 2 * train + frame } else { train };
    let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
    let smaller = |need: u64, have: u64| {
        // The edge at which the need fits (it scales with the pixel count).
        let f = (have as f64 / need as f64).sqrt();
        ((opts.width.max(opts.height) as f64 * f) as u32 / 16 * 16).max(16)
    };
    // A fifth of what is available left for everything else (measured: --size 4096 on
    // 23 GiB available, estimated at 22.5 GiB without the frame buffers, was killed).
    if let Some(avail) = mem_available().map(|a| a / 5 * 4) {
        if host > avail {
            bail!(
                "demo --size {}: its {} training views at {}×{} need about {:.1} GiB of \
                 memory{}, more than the {:.1} GiB this machine can spare (four fifths of what \
                 is available): use --size {} or less",
                opts.width,
                opts.train,
                opts.width,
                opts.height,
                gib(host),
                if cpu {
                    " (photos on the host and on the CPU device)"
                } else {
                    ""
                },
                gib(avail),
                smaller(host, avail)
            );
        }
    }
    if let Some(avail) = ctx.memory_budget().map(|b| b.available_bytes() / 5 * 4) {
        if !cpu && train + frame > avail {
            bail!(
                "demo --size {}: its training views need about {:.1} GiB of device memory, \
                 more than the {:.1} GiB the device can spare: use --size {} or less",
                opts.width,
                gib(train + frame),
                gib(avail),
                smaller(train + frame, avail)
            );
        }
    }
    let disk = views * px * 4;
    if let Some(free) = disk_free(out) {
        if disk > free {
            bail!(
                "demo --size {}: its {views} images may take up to {:.1} GiB, {} has {:.1} GiB \
                 free: use a smaller --size or free space",
                opts.width,
                gib(disk),
                out.display(),
                gib(free)
            );
        }
    }
    Ok(())
}

/// MemAvailable of /proc/meminfo (None where there is none).
fn mem_available() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Bytes free to this user on the file system that holds `path` (or its nearest
/// existing ancestor).
fn disk_free(path: &Path) -> Option<u64> {
    let mut p = super::inputs::resolved(path);
    while !p.exists() {
        p = p.parent()?.to_path_buf();
    }
    let s = rustix::fs::statvfs(&p).ok()?;
    Some(s.f_bavail.saturating_mul(s.f_frsize))
}

/// `svraster demo`: generate the procedural dataset, train on it, evaluate and render
/// the test views.
pub fn run_demo(ctx: &Context, a: DemoArgs) -> anyhow::Result<()> {
    use svraster::data::demo;
    let data_dir = a.out.join("data");
    let opts = demo::DemoOptions {
        width: a.size,
        height: a.size,
        seed: a.seed,
        ..Default::default()
    };
    // Every argument is checked before anything is written.
    demo::demo_splits(&opts)?;
    let train_args = TrainArgs {
        data: data_dir.clone(),
        out: a.out.join("run"),
        iters: Some(a.iters),
        downscale: Some(1.0),
        preset: Some("quick".into()),
        seed: Some(a.seed),
        set: vec![format!("grid_level={}", a.level)],
        resume: false,
        source: Default::default(),
        eval_every: None,
        config: None,
    };
    if !a.voxelize {
        resolve_config(&train_args)?;
    } else if !(1..=svraster::scene::MAX_LEVEL).contains(&a.level) {
        bail!(
            "--level must be in 1..={} for --voxelize",
            svraster::scene::MAX_LEVEL
        );
    }
    check_demo_resources(ctx, &opts, &a.out)?;
    // The demo replaces what it made before, in a directory it made (marked), and never
    // touches one it did not.
    let marker = a.out.join(".svraster-demo");
    let non_empty = a
        .out
        .read_dir()
        .map(|mut d| d.next().is_some())
        .unwrap_or(false);
    // A demo directory from before the mark: its run trained on its own data.
    let legacy_demo = || {
        std::fs::read_to_string(a.out.join("run/config.json"))
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .and_then(|v| v["data"].as_str().map(PathBuf::from))
            .is_some_and(|d| canonical(&d) == canonical(&data_dir))
    };
    if non_empty && !marker.is_file() && !legacy_demo() {
        bail!(
            "{} exists and was not made by `svraster demo`: choose another --out (the demo \
             only replaces files in a directory it created)",
            a.out.display()
        );
    }
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let _lock = lock_run(&a.out)?;
    std::fs::write(&marker, b"made by svraster demo\n")
        .with_context(|| format!("cannot write {}", marker.display()))?;
    let t = Instant::now();
    eprintln!(
        "generating the demo dataset ({}×{}, {} train / {} val / {} test views) in {} …",
        opts.width,
        opts.height,
        opts.train,
        opts.val,
        opts.test,
        data_dir.display()
    );
    // Written beside and renamed into place when complete: a failure (a full disk, a
    // kill) never leaves a half-written dataset where a run would read it.
    staged(&data_dir, |dir| Ok(demo::write_dataset(dir, &opts)?))?;
    if a.labels {
        staged(&a.out.join("labels"), |dir| {
            Ok(demo::write_labels(dir, &opts)?)
        })?;
    }
    eprintln!("  done in {:.1} s", t.elapsed().as_secs_f64());
    let run = a.out.join("run");
    if run.exists() {
        std::fs::remove_dir_all(&run)
            .with_context(|| format!("cannot clear the previous demo run {}", run.display()))?;
    }
    let summary = if a.voxelize {
        let t = Instant::now();
        let scene = demo::voxelize(a.level, 0)?;
        std::fs::create_dir_all(&run)
            .with_context(|| format!("cannot create {}", run.display()))?;
        checkpoint::save(&scene, &run.join("model.safetensors"))?;
        RunSummary {
            iters: 0,
            seconds: t.elapsed().as_secs_f64(),
            interrupted: false,
            voxels: scene.num_voxels() as u32,
        }
    } else {
        run_train(ctx, &train_args)?
    };
    if summary.interrupted {
        std::process::exit(130);
    }
    let scene = checkpoint::load(&run.join("model.safetensors"))?;
    let rep = evaluate(
        ctx,
        &scene,
        &Views {
            data: &data_dir,
            split: "test",
            downscale: 1.0,
            source: &data::SourceOptions::default(),
        },
        &RenderOptions::for_scene(&scene),
        false,
    )?;
    let renders = a.out.join("renders");
    super::render::render_split(
        ctx,
        &super::render::RenderArgs {
            model: run.clone(),
            data: data_dir,
            split: "test".into(),
            downscale: 1.0,
            source: data::SourceOptions::default(),
            out: renders.clone(),
            depth: true,
            normal: true,
            compare: true,
            samples: 1,
            ss: None,
            field: None,
            truth: None,
            mask: false,
            by_order: false,
            json: false,
            path: None,
            frames: 0,
            size: None,
            fov: None,
        },
    )?;
    let how = if a.voxelize {
        format!("voxelized the primitives down to level {}", a.level)
    } else {
        format!("trained for {} iterations", summary.iters)
    };
    println!(
        "demo: {} voxels, {how} in {}; test views: PSNR {:.2} dB, SSIM {:.4} \
         ({} views); renders (rgb, depth, normal PNGs) in {}",
        scene.num_voxels(),
        fmt_duration(summary.seconds),
        rep.psnr,
        rep.ssim,
        rep.views,
        renders.display()
    );
    Ok(())
}
