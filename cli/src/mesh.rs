//! `svraster mesh`: a triangle mesh of a trained model's surfaces as a PLY file
//! ([`svraster::mesh`]: depth renders of the training views fused into a TSDF on sparse
//! level-L voxels, marching cubes).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context as _};
use svraster::data;
use svraster::gpu::Context;
use svraster::mesh::{self, ply, DepthKind, MeshOptions};

pub struct MeshArgs {
    pub model: PathBuf,
    pub data: PathBuf,
    pub out: PathBuf,
    pub split: String,
    pub downscale: f64,
    pub source: data::SourceOptions,
    pub level: Option<u32>,
    pub trunc: f64,
    /// World coordinates: min x y z, max x y z.
    pub bbox: Option<Vec<f64>>,
    pub depth: DepthKind,
    pub samples: u32,
    pub vertex_colors: bool,
    pub max_voxels: u64,
    /// Views (evenly spaced over the split) written as photo-beside-mesh PNGs.
    pub preview: usize,
    /// The run's main region (model frame: centre, edge) from its config.json.
    pub main_region: Option<([f64; 3], f64)>,
    /// Print a JSON summary instead of the line.
    pub json: bool,
}

pub fn run_mesh(ctx: &Context, a: MeshArgs) -> anyhow::Result<()> {
    let t0 = Instant::now();
    check_output(&a)?;
    let scene = super::inputs::load_model(&a.model)?;
    let mut ds = data::load(&a.data, &a.split, a.downscale, scene.background, &a.source)?;
    ds.to_model(&scene.world);
    if ds.frames.is_empty() {
        bail!("split `{}` of {} has no frames", a.split, a.data.display());
    }
    let region = match (&a.bbox, a.main_region) {
        (Some(b), _) => {
            if b.len() != 6 || b.iter().any(|x| !x.is_finite()) || (0..3).any(|k| b[k] >= b[k + 3])
            {
                bail!(
                    "--bbox takes 6 finite numbers, the min then the max corner in world \
                     coordinates (min < max on each axis), got {b:?}"
                );
            }
            Some((
                scene.world.point_to_model([b[0], b[1], b[2]]),
                scene.world.point_to_model([b[3], b[4], b[5]]),
            ))
        }
        (None, Some((c, e))) => Some((c.map(|x| x - 0.5 * e), c.map(|x| x + 0.5 * e))),
        (None, None) => None,
    };
    let opts = MeshOptions {
        level: a.level,
        trunc: a.trunc,
        depth: a.depth,
        samples: a.samples,
        region,
        max_voxels: a.max_voxels,
        ..MeshOptions::default()
    };
    opts.validate()?;
    // The model's levels in the region, so a user sees what --level means.
    let hist = mesh::extract::level_histogram(&scene, region.as_ref());
    if hist.0.is_empty() {
        bail!(
            "the mesh region holds no voxel of the model: check --bbox (world coordinates, \
             min then max corner)"
        );
    }
    let level = a.level.unwrap_or_else(|| hist.default_level());
    let opts = MeshOptions {
        level: Some(level),
        ..opts
    };
    eprintln!(
        "model voxels in the mesh region by level (--level; default: the level most of \
         them have):"
    );
    for (l, n) in &hist.0 {
        let size = scene
            .world
            .length_to_world(f64::from(scene.extent) * 0.5f64.powi(i32::from(*l)));
        let mark = if u32::from(*l) == level {
            "  ← mesh level"
        } else {
            ""
        };
        eprintln!("  level {l:2} (edge {size:.4e}): {n:9}{mark}");
    }
    let mut progress = super::progress::Progress::new("depth", ds.frames.len() as u64);
    let views = mesh::render_depths(ctx, &scene, &ds.cameras(), a.depth, a.samples, |i| {
        progress.update(i as u64, String::new)
    })?;
    progress.finish();
    let render_s = t0.elapsed().as_secs_f64();
    let ex = mesh::extract(ctx, &scene, &views, &opts)?;
    drop(views);
    let r = &ex.report;
    eprintln!(
        "level {} (edge {:.4e}): {} surface samples in {} cells, {} voxels fused ({} grid points, \
         {} observed; band {:.4e}), {} triangles",
        ex.level,
        scene.world.length_to_world(ex.voxel_size),
        r.samples,
        r.cells,
        r.voxels,
        r.grid_points,
        r.observed,
        scene.world.length_to_world(r.band),
        ex.mesh.triangles.len()
    );
    if ex.mesh.triangles.is_empty() {
        bail!(
            "the fused surface is empty at level {}: no voxel has both sides of it observed. \
             Try a coarser --level, a wider --trunc, or check that --data/--split are the \
             views the model was trained on",
            ex.level
        );
    }
    let normals = ex.mesh.vertex_normals();
    let colors = if a.vertex_colors {
        mesh::extract::vertex_colors(&scene, &ex.mesh.positions, &normals, ex.voxel_size)
    } else {
        Vec::new()
    };
    let out = ply::PlyMesh {
        positions: ex
            .mesh
            .positions
            .iter()
            .map(|&p| scene.world.point_to_world(p))
            .collect(),
        normals,
        colors,
        triangles: ex.mesh.triangles.clone(),
    };
    if is_glb(&a.out) {
        let format = a
            .source
            .format
            .unwrap_or_else(|| data::detect_format(&a.data));
        mesh::glb::write(&a.out, &out, world_up(format, &ds.frames))?;
    } else {
        ply::write(&a.out, &out)?;
    }
    let n = ds.frames.len();
    for k in 0..a.preview.min(n) {
        let f = &ds.frames[k * n / a.preview.min(n)];
        let v = mesh::view::rasterize(&f.camera, &ex.mesh.positions, &ex.mesh.triangles);
        let (w, h) = (v.width as usize, v.height as usize);
        let both: Vec<[f32; 3]> = (0..h)
            .flat_map(|y| {
                let shade = &v.shade;
                let depth = &v.depth;
                f.rgb[y * w..(y + 1) * w]
                    .iter()
                    .copied()
                    .chain((0..w).map(move |x| {
                        let i = y * w + x;
                        if depth[i].is_finite() {
                            [0.15 + 0.8 * shade[i]; 3]
                        } else {
                            [0.0; 3]
                        }
                    }))
            })
            .collect();
        let stem = a
            .out
            .file_stem()
            .map_or("mesh".into(), |s| s.to_string_lossy().to_string());
        let path = a.out.with_file_name(format!("{stem}_{}.png", f.name));
        data::image::save_rgb_png(&path, 2 * v.width, v.height, &both)?;
        eprintln!("preview {}", path.display());
    }
    let open = ex.mesh.open_edges();
    let area = ex.mesh.area() * scene.world.scale * scene.world.scale;
    if a.json {
        let doc = serde_json::json!({
            "out": a.out,
            "vertices": out.positions.len(),
            "triangles": out.triangles.len(),
            "area": area,
            "open_edges": open,
            "level": ex.level,
            "seconds": t0.elapsed().as_secs_f64(),
            "depth_render_seconds": render_s,
            "cell_seconds": r.select_seconds,
            "fusion_seconds": r.fuse_seconds,
            "marching_cubes_seconds": r.mc_seconds,
        });
        println!("{}", serde_json::to_string_pretty(&doc)?);
        return Ok(());
    }
    println!(
        "wrote {}: {} vertices, {} triangles, area {area:.4e} (world units²), {open} open edges; \
         {:.1} s (depth renders {render_s:.1} s, cells {:.1} s, fusion {:.1} s, marching cubes {:.1} s)",
        a.out.display(),
        out.positions.len(),
        out.triangles.len(),
        t0.elapsed().as_secs_f64(),
        r.select_seconds,
        r.fuse_seconds,
        r.mc_seconds
    );
    Ok(())
}

/// The world's up for a Y-up file: +Z for Blender-format data (Blender's world, the
/// demo's), else the training cameras' mean up (a capture's world has no fixed axes;
/// COLMAP's is arbitrary), +Z when they cancel out.
fn world_up(format: data::Format, frames: &[data::Frame]) -> [f64; 3] {
    if format == data::Format::Blender {
        return [0.0, 0.0, 1.0];
    }
    // The model frame is the world's shifted and scaled: directions are the same.
    let s: glam::DVec3 = frames
        .iter()
        .map(|f| -glam::DVec3::from(f.camera.rotate([0.0, 1.0, 0.0])))
        .sum();
    s.try_normalize().map_or([0.0, 0.0, 1.0], |u| u.to_array())
}

/// Whether `out` names a glTF binary (`.glb`, any case); anything else is written as PLY.
fn is_glb(out: &std::path::Path) -> bool {
    out.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("glb"))
}

pub struct EvalMeshArgs {
    pub mesh: PathBuf,
    pub data: PathBuf,
    pub split: String,
    pub downscale: f64,
    pub source: data::SourceOptions,
    pub demo: bool,
    pub truth: Option<PathBuf>,
    pub threshold: Option<f64>,
    pub max_dist: Option<f64>,
    pub json: bool,
}

/// The mesh's output is checked before the work (fusion and extraction take minutes on
/// a real capture): the shared output rule (a .ply or .glb file, not the model, not in
/// the dataset, not a run's own file; a pipe or device is written in place), and a file's
/// folder can be made and written to.
fn check_output(a: &MeshArgs) -> anyhow::Result<()> {
    let out = &a.out;
    let model = super::inputs::model_path(&a.model)?;
    let target = super::outputs::check_file(
        out,
        &super::outputs::OutputFile {
            flag: "--out",
            what: "the mesh",
            extensions: &["ply", "glb"],
            inputs: &[("the model", &model), ("the dataset", &a.data)],
        },
    )?;
    let svraster::fsio::OutputTarget::File(file) = target else {
        if a.preview > 0 {
            bail!(
                "--preview writes OUT_NAME.png beside --out {}, which is not a file; name a                  mesh file, or leave out --preview",
                out.display()
            );
        }
        return Ok(());
    };
    let dir = file
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(std::path::Path::new("."));
    std::fs::create_dir_all(dir)
        .with_context(|| format!("cannot create the directory of {}", out.display()))?;
    let probe = dir.join(format!(".svraster-write-probe-{}", std::process::id()));
    std::fs::write(&probe, b"").with_context(|| {
        format!(
            "cannot write into {} (for {})",
            dir.display(),
            out.display()
        )
    })?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// `svraster eval-mesh`: surface errors against the demo's analytic surface or a point
/// cloud, and silhouette IoU against the masks of a NeuS capture; prints text or one
/// JSON object.
pub fn run_eval_mesh(a: EvalMeshArgs) -> anyhow::Result<()> {
    use svraster::mesh::metrics;
    if a.demo && a.truth.is_some() {
        bail!(
            "--demo and --truth are two ground truths (the demo scene's analytic surface, \
             a point cloud): give one"
        );
    }
    for (flag, v) in [("--threshold", a.threshold), ("--max-dist", a.max_dist)] {
        if let Some(v) = v.filter(|v| !(v.is_finite() && *v > 0.0)) {
            bail!("{flag} {v}: a distance, greater than 0");
        }
    }
    let (positions, triangles) = ply::read(&a.mesh)?;
    if triangles.is_empty() {
        bail!("{} has no triangles", a.mesh.display());
    }
    let format = a
        .source
        .format
        .unwrap_or_else(|| data::detect_format(&a.data));
    let neus_masks = format == data::Format::Neus && a.data.join("mask").is_dir();
    let ds = data::load(&a.data, &a.split, a.downscale, [0.0; 3], &a.source)?;
    let mut report = serde_json::Map::new();
    let mut lines = Vec::new();
    if neus_masks {
        let masks = data::neus::load_masks(
            &a.data,
            &a.split,
            a.downscale,
            a.source.holdout.unwrap_or(8),
        )?;
        let ious: Vec<f64> = ds
            .frames
            .iter()
            .zip(&masks)
            .map(|(f, m)| {
                let v = mesh::view::rasterize(&f.camera, &positions, &triangles);
                mesh::view::silhouette_iou(&v, m)
            })
            .collect();
        let mean = ious.iter().sum::<f64>() / ious.len().max(1) as f64;
        let min = ious.iter().copied().fold(f64::INFINITY, f64::min);
        lines.push(format!(
            "silhouette IoU against the masks of {} views (split `{}`): mean {mean:.4}, \
             min {min:.4}",
            ious.len(),
            a.split
        ));
        report.insert("iou_mean".into(), mean.into());
        report.insert("iou_min".into(), min.into());
        report.insert("iou_per_view".into(), ious.into());
    }
    let eyes: Vec<[f64; 3]> = ds.frames.iter().map(|f| f.camera.origin()).collect();
    if a.demo {
        // The demo's cameras all sit at CAMERA_RADIUS from the origin (NeRF-synthetic
        // scenes such as lego at other distances, captures anywhere).
        let r = data::demo::CAMERA_RADIUS;
        if let Some(e) = eyes
            .iter()
            .find(|e| ((e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt() - r).abs() > 1e-6 * r)
        {
            bail!(
                "--demo scores against the built-in demo scene, but {} is not the demo's \
                 dataset (a camera at {:?}, not at distance {r} from the origin); give its \
                 ground truth with --truth POINTS.ply",
                a.data.display(),
                e
            );
        }
    }
    let truth = if a.demo {
        let threshold = a.threshold.unwrap_or(0.02);
        Some((
            data::demo::surface_samples(&eyes, threshold / 5.0)?,
            threshold,
            a.max_dist.unwrap_or(5.0 * threshold),
            "the demo's analytic surface seen by the split's cameras".to_string(),
        ))
    } else if let Some(t) = &a.truth {
        let pts = data::ply::read_points(t)?;
        if pts.is_empty() {
            bail!("{} has no points", t.display());
        }
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for p in &pts {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        let diag = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
        let threshold = a.threshold.unwrap_or(0.005 * diag);
        Some((
            pts,
            threshold,
            a.max_dist.unwrap_or(10.0 * threshold),
            format!("the points of {}", t.display()),
        ))
    } else {
        None
    };
    if truth.is_none() && !neus_masks {
        bail!(
            "eval-mesh needs a ground truth: --demo (the built-in demo scene), --truth \
             POINTS.ply, or a NeuS capture with masks as --data"
        );
    }
    if let Some((truth, threshold, max_dist, what)) = truth {
        if !(threshold.is_finite() && threshold > 0.0 && max_dist.is_finite() && max_dist > 0.0) {
            bail!(
                "the F-score threshold ({threshold:e}) and the distance clamp ({max_dist:e}) \
                 must be positive: {}; pass --threshold and --max-dist",
                if a.threshold.is_none() && a.truth.is_some() {
                    "the truth's bounding box has no extent (a single point?)"
                } else {
                    "as given"
                }
            );
        }
        let samples = metrics::sample_mesh(&positions, &triangles, threshold / 5.0)
            .with_context(|| format!("{}", a.mesh.display()))?;
        let e = metrics::surface_errors(&samples, &truth, threshold, max_dist);
        lines.push(format!(
            "against {what}: accuracy {:.4e}, completeness {:.4e}, Chamfer {:.4e} (distances \
             clamped at {max_dist:.3e}); F-score {:.3} at {threshold:.3e} (precision {:.3}, \
             recall {:.3}); {} mesh samples, {} truth points",
            e.accuracy,
            e.completeness,
            e.chamfer,
            e.fscore,
            e.precision,
            e.recall,
            e.mesh_samples,
            e.truth_points
        ));
        if let serde_json::Value::Object(m) = serde_json::to_value(e)? {
            report.extend(m);
        }
    }
    if a.json {
        println!("{}", serde_json::Value::Object(report));
    } else {
        println!("{}:", a.mesh.display());
        for l in lines {
            println!("  {l}");
        }
    }
    Ok(())
}
