//! `svraster view`: the windowed viewer (`svraster::viewer`) on a run, a checkpoint or a
//! quantized checkpoint, with the dataset's training cameras as frusta to jump between.

use std::path::PathBuf;

use anyhow::{bail, Context as _};
use glam::DVec3;
use svraster::data;
use svraster::viewer::{frusta_lines, orbit_view, ViewMode, ViewerOptions};
use svraster::Camera;

use super::inputs::load_model;
use super::DataArgs;

#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum Mode {
    Colour,
    Depth,
    Normal,
}

/// `svraster view`.
#[derive(clap::Args, Debug)]
pub struct ViewArgs {
    /// A run directory, a .safetensors checkpoint or a quantized checkpoint
    /// (`export --format quantized`).
    model: PathBuf,
    /// Dataset whose training cameras are drawn as frusta and visited with `]` and `[`
    /// (default: the run's own when MODEL is a run directory; without one the view
    /// starts in an orbit around the model).
    #[arg(long)]
    data: Option<PathBuf>,
    /// Downscale of the dataset's cameras (default: the run's own, else 1).
    #[arg(long)]
    downscale: Option<f64>,
    /// Start at this training camera (its index in the train split; default: the first).
    #[arg(long)]
    camera: Option<usize>,
    /// Window size WxH (default: the start camera's image size, at most 1600 wide;
    /// 960x720 without cameras).
    #[arg(long, value_parser = super::parse_size)]
    size: Option<(u32, u32)>,
    /// What the pixels show at the start (M cycles): colour, depth (grey, near =
    /// bright) or normal (as `render --normal`).
    #[arg(long, value_enum, default_value = "colour")]
    mode: Mode,
    /// Samples per ray-voxel segment at the start (1..=3; K cycles).
    #[arg(long, default_value_t = 1)]
    samples: u32,
    /// Do not draw the training cameras' frusta (C toggles them).
    #[arg(long)]
    hide_cameras: bool,
    /// Do not draw the text overlay (Tab toggles it).
    #[arg(long)]
    no_hud: bool,
    /// Render --frames frames, write the last one here (PNG) and exit: headless use
    /// under a virtual display (`xvfb-run -a svraster view … --screenshot out.png`).
    #[arg(long)]
    screenshot: Option<PathBuf>,
    #[arg(long, default_value_t = 10)]
    frames: u32,
    /// With --screenshot: print a JSON summary (frames, size, median frame and field
    /// times, device) instead of the line.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    source: DataArgs,
}

/// The training cameras (model frame), or none with the reason printed where the
/// dataset was only implied by the run.
fn training_cameras(a: &ViewArgs, scene: &svraster::Scene) -> anyhow::Result<Vec<Camera>> {
    let (dir, explicit) = match &a.data {
        Some(d) => (d.clone(), true),
        None => {
            match super::run_config(&a.model).and_then(|v| v["data"].as_str().map(PathBuf::from)) {
                Some(d) => (d, false),
                None => return Ok(vec![]),
            }
        }
    };
    let downscale = a
        .downscale
        .unwrap_or_else(|| super::run_downscale(&a.model));
    let source = super::run_source(&a.model, &a.source);
    eprintln!("reading the training cameras of {}", dir.display());
    match data::load(&dir, "train", downscale, scene.background, &source) {
        Ok(mut ds) => {
            ds.to_model(&scene.world);
            Ok(ds.cameras())
        }
        Err(e) if !explicit => {
            eprintln!(
                "warning: the run's dataset {} cannot be read ({e}): no training cameras \
                 (pass --data to name it)",
                dir.display()
            );
            Ok(vec![])
        }
        Err(e) => Err(e).with_context(|| format!("--data {}", dir.display())),
    }
}

pub fn run(a: ViewArgs, validation: bool) -> anyhow::Result<()> {
    if !(1..=3).contains(&a.samples) {
        bail!("--samples must be 1, 2 or 3");
    }
    if a.json && a.screenshot.is_none() {
        bail!("--json summarises a --screenshot run; add --screenshot OUT.png");
    }
    if let Some(p) = &a.screenshot {
        let model = super::inputs::model_path(&a.model)?;
        let target = super::outputs::check_file(
            p,
            &super::outputs::OutputFile {
                flag: "--screenshot",
                what: "the screenshot",
                extensions: &["png"],
                inputs: &[("the model", &model)],
            },
        )?;
        if let Some(dir) = target.path().parent().filter(|d| !d.as_os_str().is_empty()) {
            if !dir.is_dir() {
                bail!(
                    "--screenshot {}: folder {} not found",
                    p.display(),
                    dir.display()
                );
            }
        }
    }
    let scene = load_model(&a.model)?;
    let cams = training_cameras(&a, &scene)?;
    if let Some(i) = a.camera {
        if i >= cams.len() {
            bail!(
                "--camera {i}: the train split has {} cameras{}",
                cams.len(),
                if cams.is_empty() {
                    " (no dataset: pass --data)"
                } else {
                    ""
                }
            );
        }
    }
    let centre = DVec3::from(scene.center.map(f64::from));
    let extent = f64::from(scene.extent);
    // Up: the training cameras' mean up (−y of OpenCV axes), else z (Blender).
    let up = {
        let s: DVec3 = cams
            .iter()
            .map(|c| -DVec3::from(c.rotate([0.0, 1.0, 0.0])))
            .sum();
        if s.length() > 1e-6 {
            s.normalize()
        } else {
            DVec3::Z
        }
    };
    let start_cam = cams.get(a.camera.unwrap_or(0));
    let size = a.size.unwrap_or(match start_cam {
        Some(c) if c.width <= 1600 => (c.width, c.height),
        Some(c) => (
            1600,
            ((1600 * c.height as u64) / c.width as u64).max(1) as u32,
        ),
        None => (960, 720),
    });
    if size.0 == 0 || size.1 == 0 || size.0 > 8192 || size.1 > 8192 {
        bail!("--size {}x{}: each side must be 1 to 8192", size.0, size.1);
    }
    let start = match start_cam {
        Some(c) => c.clone(),
        None => {
            // An orbit view: 30° around, 25° up, 1.6 extents away.
            orbit_view(&scene, up.into(), 30.0, 25.0, 1.6, size.0, size.1)
        }
    };
    // Frusta a twentieth of the cameras' mean distance to the centre deep.
    let depth = if cams.is_empty() {
        0.0
    } else {
        cams.iter()
            .map(|c| (DVec3::from(c.origin()) - centre).length())
            .sum::<f64>()
            / cams.len() as f64
            * 0.05
    };
    let lines = frusta_lines(&cams, depth.max(1e-3 * extent), [1.0, 0.35, 0.05]);
    let opts = ViewerOptions {
        title: format!("svraster view {}", a.model.display()),
        width: size.0,
        height: size.1,
        screenshot: a.screenshot.clone(),
        frames: a.frames.max(1),
        samples: a.samples,
        mode: match a.mode {
            Mode::Colour => ViewMode::Colour,
            Mode::Depth => ViewMode::Depth,
            Mode::Normal => ViewMode::Normal,
        },
        validation,
        triangles: vec![],
        lines,
        draw_field: true,
        draw_geometry: !a.hide_cameras,
        display_blend: true,
        clear: scene.background,
        up: up.into(),
        start,
        start_index: start_cam.map(|_| a.camera.unwrap_or(0)),
        cameras: cams,
        hud: !a.no_hud,
    };
    let r = svraster::viewer::run(&scene, opts)?;
    if let Some(p) = &a.screenshot {
        if a.json {
            println!(
                "{}",
                serde_json::json!({
                    "screenshot": p,
                    "frames": r.frames,
                    "width": r.width,
                    "height": r.height,
                    "median_frame_ms": r.median_frame_ms,
                    "median_field_ms": r.median_field_ms,
                    "device": r.device,
                })
            );
        } else {
            println!("{r}; screenshot {}", p.display());
        }
    }
    if r.validation_messages > 0 {
        bail!(
            "{} validation messages (printed above)",
            r.validation_messages
        );
    }
    Ok(())
}
