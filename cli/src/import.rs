//! `svraster import`: a model trained by the reference implementation (SVRaster's
//! `iterNNNNNN_model.pt`, plain or quantized) as a checkpoint of ours, for `render`,
//! `eval`, `mesh`, `export`, `view` and host embedding.

use std::path::Path;

use anyhow::{bail, Context as _};
use svraster::scene::checkpoint;
use svraster::scene::svraster::{import_options_from_config, import_svraster, SvrasterImport};

/// The imported model's background (`--background`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Background {
    Colour([f32; 3]),
    /// Each frame's own mean colour (`Scene::background_frame_mean`).
    FrameMean,
}

/// `--background`: `white`, `black`, `frame-mean` or `R,G,B` (display values in 0..1).
pub fn parse_background(s: &str) -> Result<Background, String> {
    let expected = || format!("`{s}`: expected white, black, frame-mean or R,G,B in 0..1");
    match s {
        "white" => Ok(Background::Colour([1.0; 3])),
        "black" => Ok(Background::Colour([0.0; 3])),
        "frame-mean" => Ok(Background::FrameMean),
        _ => {
            let v: Vec<f32> = s
                .split(',')
                .map(|x| x.trim().parse::<f32>())
                .collect::<Result<_, _>>()
                .map_err(|_| expected())?;
            if v.len() != 3 || v.iter().any(|c| !(0.0..=1.0).contains(c)) {
                return Err(expected());
            }
            Ok(Background::Colour([v[0], v[1], v[2]]))
        }
    }
}

pub fn run(
    ckpt: &Path,
    out: &Path,
    background: Option<Background>,
    ss: Option<f32>,
    json: bool,
) -> anyhow::Result<()> {
    if !ckpt.is_file() {
        bail!(
            "{}: not found; pass an SVRaster checkpoint (MODEL_DIR/checkpoints/iterNNNNNN_model.pt)",
            ckpt.display()
        );
    }
    // What SVRaster's own config says, under what the options say.
    let config = import_options_from_config(ckpt)?;
    let background = background.unwrap_or(match &config {
        Some((o, _)) if o.background_frame_mean => Background::FrameMean,
        Some((o, _)) => Background::Colour(o.background),
        None => Background::Colour([0.0; 3]),
    });
    let ss = ss.unwrap_or(config.as_ref().map_or(1.5, |(o, _)| o.supersample));
    if let (Some((_, path)), false) = (&config, json) {
        eprintln!("{}: SVRaster's settings for this model", path.display());
    }
    if !(1.0..=4.0).contains(&ss) {
        bail!("--ss {ss}: the supersampling must be 1 to 4 (SVRaster's default is 1.5)");
    }
    super::outputs::check_file(
        out,
        &super::outputs::OutputFile {
            flag: "--out",
            what: "the model",
            extensions: &["safetensors"],
            inputs: &[("the checkpoint", ckpt)],
        },
    )?;
    let scene = import_svraster(
        ckpt,
        &SvrasterImport {
            background: match background {
                Background::Colour(c) => c,
                Background::FrameMean => [0.0; 3],
            },
            background_frame_mean: background == Background::FrameMean,
            supersample: ss,
        },
    )?;
    checkpoint::save(&scene, out).with_context(|| format!("cannot write {}", out.display()))?;
    let bytes = std::fs::metadata(out).map(|m| m.len()).unwrap_or(0);
    if json {
        println!(
            "{}",
            serde_json::json!({
                "model": out,
                "voxels": scene.num_voxels(),
                "grid_points": scene.num_grid_points(),
                "max_level": scene.max_level(),
                "sh_degree": scene.sh_degree,
                "background": if scene.background_frame_mean {
                    serde_json::json!("frame-mean")
                } else {
                    serde_json::json!(scene.background)
                },
                "supersample": scene.supersample,
                "bytes": bytes,
            })
        );
    } else {
        println!(
            "imported {}: {} voxels (levels up to {}), {} grid points, SH degree {}, \
             background {}, ss {} → {} ({:.1} MiB)",
            ckpt.display(),
            scene.num_voxels(),
            scene.max_level(),
            scene.num_grid_points(),
            scene.sh_degree,
            if scene.background_frame_mean {
                "frame-mean".to_string()
            } else {
                format!("{:?}", scene.background)
            },
            scene.supersample,
            out.display(),
            bytes as f64 / (1 << 20) as f64
        );
    }
    Ok(())
}
