//! `svraster render` and `svraster demo` (the built-in procedural scene), plus the
//! helpers they share with `bench render`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context as _};

use super::inputs::{load_model, output_names};
use super::outputs;
use svraster::data::{self, image, Camera};
use svraster::gpu::Context;
use svraster::raster::{Image, RenderOptions, Renderer};
use svraster::scene::SceneGpu;

/// Writes `NAME.png` (rgb); with `depth`, the metric depth `NAME_depth16.png` (16-bit:
/// camera-z depth = value × scale, with `scale` and the meaning in `NAME_depth.json`;
/// 0 where alpha ≤ 0.5, i.e. no surface) and its visualisation `NAME_depth.png` (8-bit:
/// near = bright, 1st–99th percentile of the frame's depths mapped to 1.0–0.2, no
/// surface = 0); with `normal`, `NAME_normal.png` (outward unit normal
/// −∇density/|∇density| mapped to colour n·0.5 + 0.5, times alpha: black where there is
/// no surface; the rendered normal channel is the paper's ∇density, which points into
/// surfaces).
pub fn write_image(
    out: &Path,
    name: &str,
    img: &Image,
    depth: bool,
    normal: bool,
    world: &svraster::scene::WorldFrame,
) -> anyhow::Result<()> {
    image::save_rgb_png(
        &out.join(format!("{name}.png")),
        img.width,
        img.height,
        &img.rgb,
    )?;
    if depth {
        let d: Vec<f32> = img
            .depth
            .iter()
            .zip(&img.alpha)
            .map(|(&d, &a)| {
                if a > 0.5 {
                    world.length_to_world(f64::from(d / a)) as f32
                } else {
                    f32::NAN
                }
            })
            .collect();
        let mut valid: Vec<f32> = d.iter().copied().filter(|v| v.is_finite()).collect();
        valid.sort_by(|a, b| a.total_cmp(b));
        let (lo, hi) = if valid.is_empty() {
            (0.0, 1.0)
        } else {
            (
                valid[valid.len() / 100],
                valid[(valid.len() * 99 / 100).min(valid.len() - 1)],
            )
        };
        let span = (hi - lo).max(1e-6);
        let g: Vec<f32> = d
            .iter()
            .map(|&v| {
                if v.is_finite() {
                    1.0 - 0.8 * ((v - lo) / span).clamp(0.0, 1.0)
                } else {
                    0.0
                }
            })
            .collect();
        image::save_gray_png(
            &out.join(format!("{name}_depth.png")),
            img.width,
            img.height,
            &g,
        )?;
        // Metric: the largest depth maps to 65 535 (at least 1 count per 1e-6 units).
        let far = valid.last().copied().unwrap_or(0.0).max(0.0);
        let scale = (f64::from(far) / 65535.0).max(1e-6);
        let q: Vec<u16> = d
            .iter()
            .map(|&v| {
                if v.is_finite() && v > 0.0 {
                    (f64::from(v) / scale).round().clamp(1.0, 65535.0) as u16
                } else {
                    0
                }
            })
            .collect();
        image::save_gray16_png(
            &out.join(format!("{name}_depth16.png")),
            img.width,
            img.height,
            &q,
        )?;
        let side = serde_json::json!({
            "image": format!("{name}_depth16.png"),
            "scale": scale,
            "meaning": "camera-z depth in world units = value * scale; 0 = no surface (alpha <= 0.5)",
            "min_depth": valid.first(),
            "max_depth": valid.last(),
        });
        let p = out.join(format!("{name}_depth.json"));
        std::fs::write(&p, serde_json::to_string_pretty(&side)?)
            .with_context(|| format!("cannot write {}", p.display()))?;
    }
    if normal {
        let n: Vec<[f32; 3]> = img
            .normal
            .iter()
            .zip(&img.alpha)
            .map(|(v, &a)| {
                let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                let a = a.clamp(0.0, 1.0);
                if l < 1e-6 {
                    [0.0; 3]
                } else {
                    [
                        (-v[0] / l * 0.5 + 0.5) * a,
                        (-v[1] / l * 0.5 + 0.5) * a,
                        (-v[2] / l * 0.5 + 0.5) * a,
                    ]
                }
            })
            .collect();
        image::save_rgb_png(
            &out.join(format!("{name}_normal.png")),
            img.width,
            img.height,
            &n,
        )?;
    }
    Ok(())
}

pub struct RenderArgs {
    pub model: PathBuf,
    pub data: PathBuf,
    pub split: String,
    pub downscale: f64,
    /// How to read the dataset.
    pub source: data::SourceOptions,
    pub out: PathBuf,
    pub depth: bool,
    pub normal: bool,
    /// Also write `NAME_compare.png`: the photo beside the render.
    pub compare: bool,
    /// Samples per ray–voxel segment.
    pub samples: u32,
    /// Supersampling (None: the model's, [`svraster::scene::Scene::supersample`]).
    pub ss: Option<f32>,
    /// Render this field (`svraster fuse`) instead of colour.
    pub field: Option<PathBuf>,
    /// Label images to score a label field against (IoU per class).
    pub truth: Option<PathBuf>,
    /// Read the truth labels as masks ({0, 255}).
    pub mask: bool,
    /// Pair the truth files with the dataset's views by natural name order.
    pub by_order: bool,
    /// Print a JSON summary instead of the line.
    pub json: bool,
    /// A camera path (`orbit`, `train` or a camera_path.json) instead of a split.
    pub path: Option<String>,
    /// Frames of an orbit or fly-through.
    pub frames: usize,
    /// Image size of a path's frames (None: the training images', or the JSON's).
    pub size: Option<(u32, u32)>,
    /// Horizontal field of view of a path's frames, degrees (None: the first training
    /// camera's).
    pub fov: Option<f64>,
}

/// Renders every frame of a split; returns (mean PSNR against the photos, ms per frame,
/// frames).
pub fn render_split(ctx: &Context, a: &RenderArgs) -> anyhow::Result<(f64, f64, usize)> {
    let scene = load_model(&a.model)?;
    // The output before the work (the dataset's photos, the renders).
    outputs::check_dir(&a.out, &[("the dataset", &a.data)])?;
    let mut ds = data::load(&a.data, &a.split, a.downscale, scene.background, &a.source)?;
    ds.to_model(&scene.world);
    if ds.frames.is_empty() {
        bail!("split `{}` of {} has no frames", a.split, a.data.display());
    }
    let made = outputs::create_dir(&a.out)?;
    let opts = RenderOptions {
        samples: a.samples,
        supersample: a.ss.unwrap_or(scene.supersample),
    };
    let gpu = SceneGpu::upload(ctx, &scene)?;
    let mut r = Renderer::new(ctx)?;
    let mut total_psnr = 0.0;
    let names = output_names(
        &ds.frames
            .iter()
            .map(|f| f.name.as_str())
            .collect::<Vec<_>>(),
    );
    let mut progress = super::progress::Progress::new("render", ds.frames.len() as u64);
    // Frames queued behind each other: PNGs are written while the next frame renders.
    let cams: Vec<Camera> = ds.frames.iter().map(|f| f.camera.clone()).collect();
    let t = Instant::now();
    r.render_each(&gpu, &cams, &opts, |i, img, _| -> anyhow::Result<()> {
        let f = &ds.frames[i];
        let p = svraster::eval::psnr(&img.rgb, &f.rgb);
        total_psnr += p;
        write_image(&a.out, &names[i], &img, a.depth, a.normal, &scene.world)?;
        if a.compare {
            let (w, h) = (img.width as usize, img.height as usize);
            let both: Vec<[f32; 3]> = (0..h)
                .flat_map(|y| {
                    f.rgb[y * w..(y + 1) * w]
                        .iter()
                        .chain(&img.rgb[y * w..(y + 1) * w])
                        .copied()
                })
                .collect();
            image::save_rgb_png(
                &a.out.join(format!("{}_compare.png", names[i])),
                2 * img.width,
                img.height,
                &both,
            )?;
        }
        progress.update(i as u64 + 1, || format!("{}: PSNR {p:.2} dB", f.name));
        Ok(())
    })?;
    let ms = t.elapsed().as_secs_f64() * 1e3;
    progress.finish();
    made.keep();
    let n = ds.frames.len() as f64;
    Ok((total_psnr / n, ms / n, ds.frames.len()))
}

/// `render --path`: the frames of a camera path as `frame_NNNNN.png` in a folder, or
/// encoded to an MP4 (the PNGs kept beside it in `OUT.frames/`).
fn render_path(ctx: &Context, a: &RenderArgs, kind: &str) -> anyhow::Result<()> {
    use super::paths;
    if let Some(f) = a.fov.filter(|f| !(*f > 0.0 && *f < 180.0)) {
        // 180 rendered white frames; 0, NaN and negatives failed inside the renderer.
        bail!("--fov {f}: the horizontal field of view, degrees between 0 and 180 (exclusive)");
    }
    let scene = load_model(&a.model)?;
    // The output before the work (the dataset's cameras, the frames).
    let (dir, mp4) = paths::frames_dir(&a.out);
    if mp4 {
        let model = super::inputs::model_path(&a.model)?;
        outputs::check_file(
            &a.out,
            &outputs::OutputFile {
                flag: "--out",
                what: "the video",
                extensions: &["mp4"],
                inputs: &[("the model", &model), ("the dataset", &a.data)],
            },
        )?;
    }
    outputs::check_dir(&dir, &[("the dataset", &a.data)])?;
    let mut ds = data::load(&a.data, "train", a.downscale, scene.background, &a.source)?;
    ds.to_model(&scene.world);
    let size = a
        .size
        .or_else(|| paths::nerfstudio_size(Path::new(kind)))
        .unwrap_or((ds.width, ds.height));
    if size.0 == 0
        || size.1 == 0
        || size.0 > svraster::raster::MAX_IMAGE_EDGE
        || size.1 > svraster::raster::MAX_IMAGE_EDGE
    {
        bail!(
            "--size {}x{}: each side must be 1 to {}",
            size.0,
            size.1,
            svraster::raster::MAX_IMAGE_EDGE
        );
    }
    let cams = paths::path_cameras(
        kind,
        &ds.cameras(),
        a.frames,
        size,
        a.fov.map(f64::to_radians),
        &scene.world,
        Some(scene.center.map(f64::from)),
    )?;
    let made = outputs::create_dir(&dir)?;
    let opts = RenderOptions {
        samples: a.samples,
        supersample: a.ss.unwrap_or(scene.supersample),
    };
    let gpu = SceneGpu::upload(ctx, &scene)?;
    let mut r = Renderer::new(ctx)?;
    let mut progress = super::progress::Progress::new("render path", cams.len() as u64);
    let t = Instant::now();
    r.render_each(&gpu, &cams, &opts, |i, img, _| -> anyhow::Result<()> {
        image::save_rgb_png(
            &dir.join(format!("frame_{i:05}.png")),
            img.width,
            img.height,
            &img.rgb,
        )?;
        progress.update(i as u64 + 1, || format!("frame {i}"));
        Ok(())
    })?;
    progress.finish();
    let ms = 1e3 * t.elapsed().as_secs_f64() / cams.len() as f64;
    // Every frame is written: they stay, also when the encoding fails (its error says
    // where they are).
    made.keep();
    if mp4 {
        paths::encode_mp4(&dir, &a.out, 30)?;
    }
    let doc = serde_json::json!({
        "path": kind, "frames": cams.len(), "width": size.0, "height": size.1,
        "out": a.out, "frames_dir": dir, "mp4": mp4, "ms_per_frame": ms,
    });
    if a.json {
        println!("{}", serde_json::to_string_pretty(&doc)?);
    } else {
        println!(
            "rendered the {kind} path: {} frames of {}×{} ({ms:.0} ms each) to {}{}",
            cams.len(),
            size.0,
            size.1,
            a.out.display(),
            if mp4 {
                format!(" (H.264, 30 fps; frames in {})", dir.display())
            } else {
                String::new()
            }
        );
    }
    Ok(())
}

pub fn run_render(ctx: &Context, a: RenderArgs) -> anyhow::Result<()> {
    if let Some(kind) = &a.path {
        if a.field.is_some() || a.depth || a.normal || a.compare || a.truth.is_some() {
            bail!("--path renders colour frames: leave out --field, --depth, --normal, --compare and --truth");
        }
        return render_path(ctx, &a, kind);
    }
    if let Some(field) = &a.field {
        if a.by_order && a.truth.is_none() {
            bail!("--by-order pairs the --truth files with the views: pass --truth DIR");
        }
        if a.depth || a.normal || a.compare {
            bail!("--depth, --normal and --compare render colour; leave them out with --field");
        }
        let scene = load_model(&a.model)?;
        let mut ds = data::load(&a.data, &a.split, a.downscale, scene.background, &a.source)?;
        ds.to_model(&scene.world);
        if ds.frames.is_empty() {
            bail!("split `{}` of {} has no frames", a.split, a.data.display());
        }
        let opts = RenderOptions {
            samples: a.samples,
            supersample: a.ss.unwrap_or(scene.supersample),
        };
        let (line, summary) = super::field::render_fields(
            ctx,
            &scene,
            &ds.frames,
            &opts,
            &a.out,
            &a.data,
            &super::field::FieldRenderArgs {
                field,
                truth: a.truth.as_deref(),
                mask: a.mask,
                order: match (a.by_order, &a.truth) {
                    (true, Some(dir)) => {
                        Some(super::field::by_order_names(dir, &ds.frames, || {
                            let all = data::load(
                                &a.data,
                                "all",
                                a.downscale,
                                scene.background,
                                &a.source,
                            )?;
                            Ok(all.frames.into_iter().map(|f| f.name).collect())
                        })?)
                    }
                    _ => None,
                },
            },
        )?;
        if a.json {
            println!("{}", serde_json::to_string_pretty(&summary)?);
        } else {
            println!("{line}");
        }
        return Ok(());
    }
    if a.truth.is_some() || a.mask || a.by_order {
        bail!(
            "--truth, --mask and --by-order score a field: pass it with --field FIELD.safetensors"
        );
    }
    let (psnr, ms, frames) = render_split(ctx, &a)?;
    if a.json {
        let doc = serde_json::json!({
            "split": a.split,
            "out": a.out,
            "frames": frames,
            "psnr": psnr,
            "ms_per_frame": ms,
        });
        println!("{}", serde_json::to_string_pretty(&doc)?);
        return Ok(());
    }
    println!(
        "rendered split `{}` to {}: mean PSNR {psnr:.2} dB against the photos, {ms:.1} ms per frame (wall, incl. read-back and PNG)",
        a.split,
        a.out.display()
    );
    Ok(())
}

/// The cameras of a split, for benchmarks.
pub fn split_cameras(
    data: &Path,
    split: &str,
    downscale: f64,
    source: &data::SourceOptions,
    scene: &svraster::scene::Scene,
) -> anyhow::Result<Vec<Camera>> {
    let mut ds = data::load(data, split, downscale, scene.background, source)?;
    ds.to_model(&scene.world);
    Ok(ds.frames.into_iter().map(|f| f.camera).collect())
}
