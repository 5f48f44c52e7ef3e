//! `svraster fuse` (per-view labels or features fused into a model's voxels) and the
//! field renders of `svraster render --field`.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context as _};
use svraster::data::{self, pixels, Frame};
use svraster::field::{self, render_field, Field, FieldGpu, FieldKind, Fuser, Pca};
use svraster::gpu::Context;
use svraster::raster::{RenderOptions, Renderer};
use svraster::scene::{Scene, SceneGpu};

use super::inputs::{load_model, output_names};

pub struct FuseArgs {
    pub model: PathBuf,
    pub data: PathBuf,
    pub from: PathBuf,
    pub split: String,
    pub downscale: f64,
    pub source: data::SourceOptions,
    pub out: PathBuf,
    /// Labels thresholded at 128 into {0, 255} (soft masks).
    pub mask: bool,
    pub ss: Option<f32>,
    pub json: bool,
    /// Pair DIR's files with the dataset's views by natural name order instead of by
    /// name (NeuS pairs `mask/` with `image/` this way).
    pub by_order: bool,
}

/// One frame's source file.
enum Source {
    Labels(PathBuf),
    Features(PathBuf),
}

/// The file of every frame in `dir` (`STEM.png` labels or `STEM.npy` features, one kind
/// for all), refusing frames without one.
/// With `order` (view names, [`by_order_names`]), DIR's files in natural name order
/// are those views' files instead.
fn frame_sources(
    dir: &Path,
    frames: &[Frame],
    order: Option<&[String]>,
) -> anyhow::Result<Vec<Source>> {
    if !dir.is_dir() {
        bail!(
            "--from {}: not a folder; pass the folder holding one STEM.png (labels) or \
             STEM.npy (features) per frame",
            dir.display()
        );
    }
    let files = source_files(dir)?;
    let by_order: Option<std::collections::HashMap<&str, &PathBuf>> = match order {
        Some(names) => {
            if names.len() != files.len() {
                bail!(
                    "--by-order: {} holds {} .png/.npy files for {} views",
                    dir.display(),
                    files.len(),
                    names.len()
                );
            }
            Some(names.iter().map(String::as_str).zip(&files).collect())
        }
        None => None,
    };
    let mut out = Vec::with_capacity(frames.len());
    let mut missing = Vec::new();
    for f in frames {
        if let Some(map) = &by_order {
            let p = map[f.name.as_str()].clone();
            out.push(if p.extension().is_some_and(|e| e == "npy") {
                Source::Features(p)
            } else {
                Source::Labels(p)
            });
            continue;
        }
        let (png, npy) = (
            dir.join(format!("{}.png", f.name)),
            dir.join(format!("{}.npy", f.name)),
        );
        match (png.is_file(), npy.is_file()) {
            (true, false) => out.push(Source::Labels(png)),
            (false, true) => out.push(Source::Features(npy)),
            (true, true) => bail!(
                "{} and {} both exist: keep one source per frame",
                png.display(),
                npy.display()
            ),
            (false, false) => missing.push(f.name.clone()),
        }
    }
    if !missing.is_empty() {
        bail!(
            "{} has no STEM.png or STEM.npy for {} of the split's {} frames ({}{}): the \
             folder must hold one file per frame, named after the frame's image (or, with \
             --by-order, one per view of the dataset in the views' order: it holds {})",
            dir.display(),
            missing.len(),
            frames.len(),
            missing
                .iter()
                .take(5)
                .cloned()
                .collect::<Vec<_>>()
                .join(", "),
            if missing.len() > 5 { ", ..." } else { "" },
            files.len()
        );
    }
    let labels = out
        .iter()
        .filter(|s| matches!(s, Source::Labels(_)))
        .count();
    if labels != 0 && labels != out.len() {
        bail!(
            "{} mixes label images (.png, {labels}) and feature maps (.npy, {}): fuse one \
             kind at a time",
            dir.display(),
            out.len() - labels
        );
    }
    Ok(out)
}

/// The views `--by-order` pairs `dir`'s files with, in order: the split's frames when
/// `dir` holds one file per frame, else every view of the dataset (a capture's `all`
/// split) when it holds one per view.
pub fn by_order_names(
    dir: &Path,
    frames: &[Frame],
    all: impl FnOnce() -> anyhow::Result<Vec<String>>,
) -> anyhow::Result<Vec<String>> {
    let n = source_files(dir)?.len();
    if n == frames.len() {
        return Ok(frames.iter().map(|f| f.name.clone()).collect());
    }
    let all = all().ok();
    if let Some(names) = all.as_ref().filter(|a| a.len() == n) {
        return Ok(names.clone());
    }
    bail!(
        "--by-order: {} holds {n} .png/.npy files, but the split has {} frames{}: it needs \
         one file per frame of the split, or one per view of the dataset",
        dir.display(),
        frames.len(),
        all.map_or(String::new(), |a| format!(
            " and the dataset {} views",
            a.len()
        ))
    )
}

/// The `.png` and `.npy` files of `dir` in natural name order.
fn source_files(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("cannot read {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "png" || e == "npy"))
        .collect();
    files.sort_by(|a, b| data::shot::natural_cmp(&a.to_string_lossy(), &b.to_string_lossy()));
    Ok(files)
}

/// Refuses a source whose aspect ratio differs from its view's (more than 3 %, a
/// patch grid's rounding): such a map cannot be resampled onto the view.
fn check_aspect(path: &Path, w: u32, h: u32, frame: &Frame) -> anyhow::Result<()> {
    let (fw, fh) = (frame.camera.width as f64, frame.camera.height as f64);
    let (sx, sy) = (w as f64 / fw, h as f64 / fh);
    if (sx / sy - 1.0).abs() > 0.03 {
        bail!(
            "{} is {w}×{h} but its view is {}×{}: a different aspect ratio cannot be mapped \
             onto the view (crop or pad it to the image's shape)",
            path.display(),
            frame.camera.width,
            frame.camera.height
        );
    }
    Ok(())
}

/// Reads a label image, or with `mask` a mask as {0, 255} (mean of its channels
/// above one half).
fn read_labels(path: &Path, mask: bool) -> anyhow::Result<(u32, u32, Vec<u8>)> {
    Ok(if mask {
        pixels::load_mask(path)?
    } else {
        pixels::load_labels(path)?
    })
}

/// The planar `[channels][height][width]` values of frame `i` at its view's size.
fn frame_values(
    src: &Source,
    frame: &Frame,
    classes: &[u8],
    mask: bool,
    channels: u32,
) -> anyhow::Result<Vec<f32>> {
    let (cw, ch) = (frame.camera.width, frame.camera.height);
    let (w, h, c, vals) = match src {
        Source::Labels(p) => {
            let (w, h, l) = read_labels(p, mask)?;
            check_aspect(p, w, h, frame)?;
            let k = classes.len();
            let mut onehot = vec![0f32; l.len() * k];
            for (i, v) in l.iter().enumerate() {
                let Ok(c) = classes.binary_search(v) else {
                    bail!(
                        "{}: label {v} appeared after the classes were read",
                        p.display()
                    );
                };
                onehot[i * k + c] = 1.0;
            }
            (w, h, k as u32, onehot)
        }
        Source::Features(p) => {
            let (w, h, c, v) = pixels::load_features(p)?;
            check_aspect(p, w, h, frame)?;
            if c != channels {
                bail!(
                    "{} has {c} channels, the split's first feature map {channels}: every \
                     frame needs the same channels",
                    p.display()
                );
            }
            (w, h, c, v)
        }
    };
    Ok(pixels::resample_planar(w, h, c, &vals, cw, ch))
}

/// The classes of every label image (sorted values), or the features' channels.
fn field_kind(sources: &[Source], mask: bool) -> anyhow::Result<(FieldKind, u32)> {
    match &sources[0] {
        Source::Labels(_) => {
            let mut seen = BTreeSet::new();
            for s in sources {
                if let Source::Labels(p) = s {
                    seen.extend(read_labels(p, mask)?.2);
                }
            }
            let classes: Vec<u8> = seen.into_iter().collect();
            Ok((FieldKind::Labels(classes.clone()), classes.len() as u32))
        }
        Source::Features(p) => {
            let (_, _, c, _) = pixels::load_features(p)?;
            field::check_channels(c).with_context(|| p.display().to_string())?;
            Ok((FieldKind::Features, c))
        }
    }
}

pub fn run_fuse(ctx: &Context, a: FuseArgs) -> anyhow::Result<()> {
    let model = super::inputs::model_path(&a.model)?;
    super::outputs::check_file(
        &a.out,
        &super::outputs::OutputFile {
            flag: "--out",
            what: "the field",
            extensions: &["safetensors"],
            inputs: &[
                ("the model", &model),
                ("the dataset", &a.data),
                ("the labels or features", &a.from),
            ],
        },
    )?;
    let scene = load_model(&a.model)?;
    let mut ds = data::load(&a.data, &a.split, a.downscale, scene.background, &a.source)?;
    ds.to_model(&scene.world);
    if ds.frames.is_empty() {
        bail!("split `{}` of {} has no frames", a.split, a.data.display());
    }
    let order: Option<Vec<String>> = if a.by_order {
        Some(by_order_names(&a.from, &ds.frames, || {
            let all = data::load(&a.data, "all", a.downscale, scene.background, &a.source)?;
            Ok(all.frames.into_iter().map(|f| f.name).collect())
        })?)
    } else {
        None
    };
    let sources = frame_sources(&a.from, &ds.frames, order.as_deref())?;
    let (kind, channels) = field_kind(&sources, a.mask)?;
    if let FieldKind::Labels(c) = &kind {
        if c.len() > 32 && !a.mask {
            eprintln!(
                "note: {} distinct label values, each fused as a class; soft masks? pass --mask \
                 to threshold them at 128",
                c.len()
            );
        }
    }
    let opts = RenderOptions {
        samples: 1,
        supersample: a.ss.unwrap_or(scene.supersample),
    };
    let gpu = SceneGpu::upload(ctx, &scene)?;
    let mut fuser = Fuser::new(ctx, &gpu, channels)?;
    let classes: Vec<u8> = match &kind {
        FieldKind::Labels(c) => c.clone(),
        FieldKind::Features => Vec::new(),
    };
    let mut progress = super::progress::Progress::new("fuse", ds.frames.len() as u64);
    let t = Instant::now();
    let mut gpu_s = 0.0;
    for (i, (src, frame)) in sources.iter().zip(&ds.frames).enumerate() {
        let values = frame_values(src, frame, &classes, a.mask, channels)?;
        let tg = Instant::now();
        fuser.add_view(&gpu, &frame.camera, &opts, &values)?;
        gpu_s += tg.elapsed().as_secs_f64();
        progress.update(i as u64 + 1, || frame.name.clone());
    }
    progress.finish();
    let secs = t.elapsed().as_secs_f64();
    let mut f = fuser.field(kind, field::model_id(&scene))?;
    f.meta.insert("split".into(), a.split.clone());
    f.meta.insert("from".into(), a.from.display().to_string());
    f.meta.insert("data".into(), a.data.display().to_string());
    f.meta.insert("downscale".into(), a.downscale.to_string());
    f.meta
        .insert("supersample".into(), opts.supersample.to_string());
    f.meta.insert("mask".into(), a.mask.to_string());
    f.meta.insert("by_order".into(), a.by_order.to_string());
    if let Some(dir) = a.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create the folder of --out {}", a.out.display()))?;
    }
    f.save(&a.out)?;
    let seen = f.weights.iter().filter(|&&w| w > 0.0).count();
    let summary = serde_json::json!({
        "field": a.out,
        "kind": match &f.kind { FieldKind::Labels(_) => "labels", FieldKind::Features => "features" },
        "classes": classes,
        "channels": channels,
        "views": ds.frames.len(),
        "voxels": f.voxels,
        "voxels_seen": seen,
        "seconds": secs,
        "fusion_seconds": gpu_s,
        "ms_per_view": 1e3 * gpu_s / ds.frames.len() as f64,
        "device_bytes_of_sums": Field::fusion_bytes(f.voxels, channels),
        "device_bytes_per_channel": u64::from(f.voxels) * 4,
        "file_bytes": std::fs::metadata(&a.out).map(|m| m.len()).unwrap_or(0),
    });
    if a.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        println!(
            "fused {} views ({channels} channel{}) into {} of {} voxels in {secs:.1} s \
             ({:.0} ms per view on the device): {}",
            ds.frames.len(),
            if channels == 1 { "" } else { "s" },
            seen,
            f.voxels,
            1e3 * gpu_s / ds.frames.len() as f64,
            a.out.display()
        );
    }
    Ok(())
}

pub struct FieldRenderArgs<'a> {
    pub field: &'a Path,
    pub truth: Option<&'a Path>,
    pub mask: bool,
    /// `--by-order`: the views the truth files pair with in natural name order
    /// ([`by_order_names`]).
    pub order: Option<Vec<String>>,
}

/// Per-class intersection and union counts.
#[derive(Default, Clone)]
struct Overlap {
    inter: u64,
    union: u64,
}

/// Renders the field of every frame: `STEM_field.png` and `STEM_field.npy`; for
/// features also `field_pca.json`; with a truth folder, the IoU per class
/// (`field_scores.json`). Returns a line for the user and the same as JSON.
pub fn render_fields(
    ctx: &Context,
    scene: &Scene,
    frames: &[Frame],
    opts: &RenderOptions,
    out: &Path,
    data_dir: &Path,
    a: &FieldRenderArgs,
) -> anyhow::Result<(String, serde_json::Value)> {
    super::outputs::check_dir(out, &[("the dataset", data_dir)])?;
    let f = Field::load(a.field)?;
    f.check_model(scene)
        .with_context(|| format!("--field {}", a.field.display()))?;
    let made = super::outputs::create_dir(out)?;
    let pca = match f.kind {
        FieldKind::Features => {
            if a.truth.is_some() {
                bail!(
                    "--truth scores label fields; {} holds features",
                    a.field.display()
                );
            }
            let p = Pca::fit(&f)?;
            let path = out.join("field_pca.json");
            svraster::fsio::write_atomic(&path, serde_json::to_string_pretty(&p)?.as_bytes())?;
            Some(p)
        }
        FieldKind::Labels(_) => None,
    };
    let gpu = SceneGpu::upload(ctx, scene)?;
    let fg = FieldGpu::upload(ctx, &f)?;
    let mut r = Renderer::new(ctx)?;
    let names = output_names(&frames.iter().map(|f| f.name.as_str()).collect::<Vec<_>>());
    let classes = match &f.kind {
        FieldKind::Labels(c) => c.clone(),
        FieldKind::Features => Vec::new(),
    };
    let truth_files = match a.truth {
        Some(dir) => Some(frame_sources(dir, frames, a.order.as_deref())?),
        None => None,
    };
    let mut pooled = vec![Overlap::default(); classes.len()];
    let mut per_view: Vec<Vec<Option<f64>>> = Vec::new();
    let mut progress = super::progress::Progress::new("render field", frames.len() as u64);
    let t = Instant::now();
    for (i, frame) in frames.iter().enumerate() {
        let img = render_field(&mut r, &gpu, &fg, &frame.camera, opts)?;
        let (w, h) = (img.width, img.height);
        let shape = [u64::from(h), u64::from(w), u64::from(f.channels)];
        let stem = &names[i];
        if let Some(p) = &pca {
            let rgb = p.colours(&img)?;
            data::image::save_rgb_png(&out.join(format!("{stem}_field.png")), w, h, &rgb)?;
            pixels::save_npy(&out.join(format!("{stem}_field.npy")), &shape, &img.values)?;
        } else {
            let (labels, probs) = f.labels_of(&img)?;
            data::image::save_gray8_png(&out.join(format!("{stem}_field.png")), w, h, &labels)?;
            pixels::save_npy(&out.join(format!("{stem}_field.npy")), &shape, &probs)?;
            if let Some(t) = &truth_files {
                let path = match &t[i] {
                    Source::Labels(p) | Source::Features(p) => p,
                };
                let (tw, th, truth) = read_labels(path, a.mask)?;
                check_aspect(path, tw, th, frame)?;
                // Scored at the rendered size: the truth resampled by area (majority).
                let truth = pixels::resample_labels(tw, th, &truth, w, h);
                let mut view = Vec::new();
                for (k, &c) in classes.iter().enumerate() {
                    let (mut inter, mut union) = (0u64, 0u64);
                    for (&g, &t) in labels.iter().zip(&truth) {
                        inter += u64::from(g == c && t == c);
                        union += u64::from(g == c || t == c);
                    }
                    pooled[k].inter += inter;
                    pooled[k].union += union;
                    view.push((union > 0).then(|| inter as f64 / union as f64));
                }
                per_view.push(view);
            }
        }
        progress.update(i as u64 + 1, || frame.name.clone());
    }
    progress.finish();
    let ms = 1e3 * t.elapsed().as_secs_f64() / frames.len() as f64;
    let mut line = format!(
        "rendered the {}-channel field of {} frames to {} ({ms:.0} ms per frame, incl. files)",
        f.channels,
        frames.len(),
        out.display()
    );
    let mut summary = serde_json::json!({
        "out": out,
        "field": a.field,
        "channels": f.channels,
        "frames": frames.len(),
        "ms_per_frame": ms,
    });
    if a.truth.is_some() {
        let mut scores = Vec::new();
        let mut means = Vec::new();
        let mut per = Vec::new();
        for (k, &c) in classes.iter().enumerate() {
            let views: Vec<f64> = per_view.iter().filter_map(|v| v[k]).collect();
            if views.is_empty() {
                continue;
            }
            let mean_views = views.iter().sum::<f64>() / views.len() as f64;
            let pooled_iou = pooled[k].inter as f64 / pooled[k].union.max(1) as f64;
            means.push(pooled_iou);
            per.push(format!("{c}: {mean_views:.4}"));
            scores.push(serde_json::json!({
                "class": c,
                "iou_mean_over_views": mean_views,
                "iou_pooled": pooled_iou,
                "views": views.len(),
            }));
        }
        let mean = means.iter().sum::<f64>() / means.len().max(1) as f64;
        let doc = serde_json::json!({
            "classes": scores,
            "mean_iou_over_classes": mean,
            "frames": frames.len(),
        });
        let path = out.join("field_scores.json");
        svraster::fsio::write_atomic(&path, serde_json::to_string_pretty(&doc)?.as_bytes())?;
        summary["scores"] = doc;
        line += &format!(
            "\nIoU against the truth, mean over views per class: {}; mean over classes \
             (pooled pixels) {mean:.4} ({})",
            per.join(", "),
            path.display()
        );
    }
    made.keep();
    Ok((line, summary))
}
