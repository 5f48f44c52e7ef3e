//! The host-engine demo: the field embedded in a small windowed engine
//! (`svraster::viewer`, whose code is the reference for embedding) beside geometry of
//! the host's own — a ground grid and a cube — composited by depth: the cube occludes
//! voxels behind it, voxels in front of it cover it.
//!
//! ```text
//! cargo run --release --features viewer --example viewer -- RUN_OR_MODEL
//!     [--width 800 --height 600] [--screenshot out.png --frames N] [--up z|y|-y]
//!     [--no-mesh] [--no-field]
//! ```
//! Controls as `svraster view` (see `svraster::viewer`). With `--screenshot` the viewer
//! renders `--frames` frames, writes the last as a PNG, prints the timings and exits.

use std::path::PathBuf;

use clap::Parser;
use glam::DVec3;
use svraster::scene::Scene;
use svraster::viewer::{horizontal_axes, orbit_view, ViewMode, ViewerOptions};

#[derive(Parser, Debug, Clone)]
#[command(about = "Windowed host engine embedding a trained sparse-voxel model")]
struct Args {
    /// A `.safetensors` model or a run directory holding `model.safetensors`.
    model: PathBuf,
    #[arg(long, default_value_t = 800)]
    width: u32,
    #[arg(long, default_value_t = 600)]
    height: u32,
    /// Render `--frames` frames, write the last one here (PNG) and exit.
    #[arg(long)]
    screenshot: Option<PathBuf>,
    #[arg(long, default_value_t = 10)]
    frames: u32,
    /// The model's up axis: z (Blender, the demo), y or -y (COLMAP captures).
    #[arg(long, default_value = "z")]
    up: String,
    /// Orbit angles of the starting view (degrees) and its distance (model extents).
    #[arg(long, default_value_t = 30.0)]
    azimuth: f64,
    #[arg(long, default_value_t = 25.0)]
    elevation: f64,
    #[arg(long, default_value_t = 1.6)]
    distance: f64,
    /// Samples per voxel segment (1–3).
    #[arg(long, default_value_t = 1)]
    samples: u32,
    /// Do not draw the host's mesh (grid and cube).
    #[arg(long)]
    no_mesh: bool,
    /// Do not draw the radiance field.
    #[arg(long)]
    no_field: bool,
    /// Enable the Khronos validation layer (messages are printed and counted; the
    /// process exits with status 2 if any was reported).
    #[arg(long)]
    validation: bool,
}

/// The host's clear colour (linear).
const CLEAR: [f32; 3] = [0.013, 0.015, 0.022];

/// The host's own geometry: a ground grid below the model and a cube beside its centre
/// (6 floats per vertex: position, colour).
fn host_mesh(scene: &Scene, up: DVec3) -> Vec<f32> {
    let c = DVec3::from(scene.center.map(f64::from));
    let e = f64::from(scene.extent);
    let (e1, e2) = horizontal_axes(up);
    let mut v = vec![];
    let mut quad = |p: [DVec3; 4], col: [f32; 3]| {
        for i in [0, 1, 2, 0, 2, 3] {
            v.extend_from_slice(&[p[i].x as f32, p[i].y as f32, p[i].z as f32]);
            v.extend_from_slice(&col);
        }
    };
    // Grid: 17 lines each way over twice the extent, at the bottom of the main region.
    let base = c - 0.5 * e * up;
    let half = e;
    let w = e / 300.0;
    for k in 0..=16 {
        let s = -half + 2.0 * half * k as f64 / 16.0;
        for (u, t) in [(e1, e2), (e2, e1)] {
            let p0 = base + s * u - half * t;
            let p1 = base + s * u + half * t;
            quad([p0 - w * u, p0 + w * u, p1 + w * u, p1 - w * u], [0.55; 3]);
        }
    }
    // Cube: a quarter of the extent, beside the centre, shaded per face.
    let h = 0.125 * e;
    let cc = c + 0.2 * e * e1 - 0.2 * e * e2;
    let axes = [e1, e2, up];
    for (fi, n) in axes.iter().enumerate() {
        for sign in [-1.0, 1.0] {
            let nn = *n * sign;
            let (t1, t2) = (axes[(fi + 1) % 3], axes[(fi + 2) % 3]);
            let f = cc + h * nn;
            let shade = (0.55 + 0.4 * nn.dot(up).max(0.0) + 0.1 * fi as f64) as f32;
            quad(
                [
                    f - h * t1 - h * t2,
                    f + h * t1 - h * t2,
                    f + h * t1 + h * t2,
                    f - h * t1 + h * t2,
                ],
                [0.05 * shade, 0.2 * shade, 0.8 * shade],
            );
        }
    }
    v
}

fn main() {
    let args = Args::parse();
    let path = if args.model.is_dir() {
        args.model.join("model.safetensors")
    } else {
        args.model.clone()
    };
    let scene = match svraster::scene::checkpoint::load(&path) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: cannot load the model {}: {e}", path.display());
            std::process::exit(1);
        }
    };
    let up = match args.up.as_str() {
        "y" => DVec3::Y,
        "-y" => DVec3::NEG_Y,
        _ => DVec3::Z,
    };
    let start = orbit_view(
        &scene,
        up.into(),
        args.azimuth,
        args.elevation,
        args.distance,
        args.width,
        args.height,
    );
    let opts = ViewerOptions {
        title: "svraster viewer (host-engine demo)".into(),
        width: args.width,
        height: args.height,
        screenshot: args.screenshot.clone(),
        frames: args.frames,
        samples: args.samples,
        mode: ViewMode::Colour,
        validation: args.validation,
        triangles: host_mesh(&scene, up),
        lines: vec![],
        draw_field: !args.no_field,
        draw_geometry: !args.no_mesh,
        display_blend: false,
        clear: CLEAR,
        up: up.into(),
        start,
        cameras: vec![],
        start_index: None,
        hud: args.screenshot.is_none(),
    };
    match svraster::viewer::run(&scene, opts) {
        Ok(r) => {
            if let Some(p) = &args.screenshot {
                println!("{r}; screenshot {}", p.display());
            }
            if r.validation_messages > 0 {
                eprintln!("error: {} validation messages", r.validation_messages);
                std::process::exit(2);
            }
        }
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    }
}
