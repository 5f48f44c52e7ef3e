//! The training step against SVRaster's own, tensor by tensor (issue 60; docs/PARITY.md).
//!
//! Each folder of tests/fixtures/parity/ holds a model (`model.pt`, SVRaster's checkpoint
//! layout) and what SVRaster's training computed from it over a few iterations
//! (`step.safetensors`, `step.json`: tools/svraster_step_dump.py; the folder's README
//! says which command and kernels made it). The test imports the model (`svraster
//! import`'s reader), trains from it with the same views, supersampling, iteration
//! numbers and Adam step counts, and compares every loss term, every gradient, the
//! parameters and Adam moments after each step, and, where the fixture has one, the
//! adaptive step's decisions.
//!
//! Tolerances are relative L2 errors ‖ours − theirs‖ / ‖theirs‖ per tensor, stated per
//! quantity below; a quantity where we differ from SVRaster on purpose names the rule and
//! the measurement that kept it.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use crate::common::context;
use svraster::camera::Camera;
use svraster::data::{Dataset, Frame};
use svraster::scene::svraster::{import_svraster, SvrasterImport};
use svraster::train::config::TrainConfig;
use svraster::train::trainer::Trainer;

/// One tensor of a fixture, as f64 whatever its stored type.
struct Tensor {
    shape: Vec<usize>,
    data: Vec<f64>,
}

struct Fixture {
    dir: PathBuf,
    meta: serde_json::Value,
    tensors: HashMap<String, Tensor>,
}

impl Fixture {
    fn load(dir: &Path) -> Fixture {
        let meta: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("step.json")).unwrap()).unwrap();
        let bytes = std::fs::read(dir.join("step.safetensors")).unwrap();
        let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        let mut tensors = HashMap::new();
        for (name, view) in st.tensors() {
            let raw = view.data();
            let data: Vec<f64> = match view.dtype() {
                safetensors::Dtype::F32 => raw
                    .chunks_exact(4)
                    .map(|c| f32::from_le_bytes(c.try_into().unwrap()) as f64)
                    .collect(),
                safetensors::Dtype::I64 => raw
                    .chunks_exact(8)
                    .map(|c| i64::from_le_bytes(c.try_into().unwrap()) as f64)
                    .collect(),
                safetensors::Dtype::U8 => raw.iter().map(|&b| b as f64).collect(),
                d => panic!("{}: tensor {name} of type {d:?}", dir.display()),
            };
            tensors.insert(
                name.to_string(),
                Tensor {
                    shape: view.shape().to_vec(),
                    data,
                },
            );
        }
        Fixture {
            dir: dir.to_path_buf(),
            meta,
            tensors,
        }
    }

    fn get(&self, name: &str) -> &Tensor {
        self.tensors
            .get(name)
            .unwrap_or_else(|| panic!("{}: no tensor {name}", self.dir.display()))
    }
}

/// ‖a − b‖ / ‖b‖ (‖a − b‖ when b is zero) and the largest |a − b|.
fn rel_err(a: &[f64], b: &[f64]) -> (f64, f64) {
    assert_eq!(a.len(), b.len());
    let (mut d2, mut b2, mut max) = (0.0f64, 0.0f64, 0.0f64);
    for (x, y) in a.iter().zip(b) {
        d2 += (x - y) * (x - y);
        b2 += y * y;
        max = max.max((x - y).abs());
    }
    let rel = if b2 > 0.0 {
        (d2 / b2).sqrt()
    } else {
        d2.sqrt()
    };
    (rel, max)
}

/// The fixture's camera of a step as ours (SVRaster's c2w has OpenCV axes, as ours).
fn camera(step: &serde_json::Value) -> Camera {
    let c = &step["camera"];
    let f = |k: &str| c[k].as_f64().unwrap();
    let (w, h) = (f("width") as u32, f("height") as u32);
    let m: Vec<Vec<f64>> = serde_json::from_value(c["c2w"].clone()).unwrap();
    Camera {
        width: w,
        height: h,
        fx: w as f64 / (2.0 * f("tanfovx")),
        fy: h as f64 / (2.0 * f("tanfovy")),
        cx: f("cx"),
        cy: f("cy"),
        c2w: std::array::from_fn(|r| std::array::from_fn(|k| m[r][k])),
        near: f("near"),
    }
}

/// The target of a step, `[3, H, W]` in the fixture, as our row-major RGB.
fn target(fx: &Fixture, i: usize) -> Vec<[f32; 3]> {
    let t = fx.get(&format!("{i}.gt"));
    let (h, w) = (t.shape[1], t.shape[2]);
    (0..h * w)
        .map(|p| std::array::from_fn(|c| t.data[c * h * w + p] as f32))
        .collect()
}

fn flat3(v: &[[f32; 3]]) -> Vec<f64> {
    v.iter().flatten().map(|&x| x as f64).collect()
}

fn f64s(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

/// Records one compared quantity: its name, ours, theirs.
type Push<'a> = dyn FnMut(String, &[f64], &[f64]) + 'a;

/// One compared quantity: its error and the bound it must stay under.
struct Row {
    what: String,
    rel: f64,
    max_abs: f64,
    bound: f64,
}

/// Replays the fixture's steps with `cfg` and compares; returns the rows.
fn replay(fx: &Fixture, cfg: TrainConfig, bounds: &dyn Fn(&str) -> f64) -> Vec<Row> {
    let ctx = context();
    let steps = fx.meta["steps"].as_array().unwrap();
    let model = &fx.meta["config"]["model"];
    let white = model["white_background"].as_bool().unwrap();
    let black = model["black_background"].as_bool().unwrap();
    // Neither: each frame's own mean colour (renderer.py:158-159), as the import says.
    let bg = if white { [1.0f32; 3] } else { [0.0; 3] };
    assert_eq!(
        cfg.background_frame_mean,
        !white && !black,
        "the preset's background"
    );
    // The training views: every camera where the fixture lists them (its adaptive step's
    // statistics render them all; only the steps' own views are trained on, and only
    // they carry their photo — the others' images are never read), else the steps' own.
    let all = fx.meta["train_cameras"].as_array();
    let frames: Vec<Frame> = match all {
        Some(cams) => cams
            .iter()
            .enumerate()
            .map(|(k, c)| {
                let step = steps
                    .iter()
                    .position(|s| s["view"].as_u64() == Some(k as u64));
                let cam = camera(&serde_json::json!({ "camera": c }));
                let n = (cam.width * cam.height) as usize;
                Frame {
                    name: c["image_name"].as_str().unwrap().to_string(),
                    rgb: step.map_or_else(|| vec![[0.0; 3]; n], |i| target(fx, i)),
                    camera: cam,
                }
            })
            .collect(),
        None => steps
            .iter()
            .enumerate()
            .map(|(i, s)| Frame {
                name: s["image_name"].as_str().unwrap().to_string(),
                camera: camera(s),
                rgb: target(fx, i),
            })
            .collect(),
    };
    let train = Dataset {
        width: frames[0].camera.width,
        height: frames[0].camera.height,
        frames,
        background: bg,
        alpha: true,
        split: "train".into(),
        points: Vec::new(),
        sphere: None,
    };
    let mut rows = Vec::new();
    if let Some(init) = fx.meta["init"].as_object() {
        compare_init(fx, init, cfg.clone(), &train, bounds, &mut rows);
    }
    if steps.is_empty() {
        return rows;
    }
    let scene = import_svraster(
        &fx.dir.join("model.pt"),
        &SvrasterImport {
            background: bg,
            background_frame_mean: !white && !black,
            supersample: 1.0,
        },
    )
    .unwrap();
    let first = steps[0]["iteration"].as_u64().unwrap() as u32;
    let mut t = Trainer::new(&ctx, cfg, &train, Some(scene)).unwrap();
    t.skip_to(first - 1);
    let mut push = |what: String, ours: &[f64], theirs: &[f64]| {
        let (rel, max_abs) = rel_err(ours, theirs);
        if std::env::var("PARITY_DEBUG").is_ok() {
            let k = ours.len().min(6);
            println!(
                "{what}: ours {:?}\n    theirs {:?}",
                &ours[..k],
                &theirs[..k]
            );
        }
        let bound = bounds(what.split_once('.').map_or(&what[..], |(_, k)| k));
        rows.push(Row {
            what,
            rel,
            max_abs,
            bound,
        });
    };
    for (i, s) in steps.iter().enumerate() {
        let adam = s["adam_step"][0].as_u64().unwrap() as u32;
        t.set_adam_count(adam).unwrap();
        let view = if all.is_some() {
            s["view"].as_u64().unwrap() as usize
        } else {
            i
        };
        t.set_next_draw(view, s["ss"].as_f64().unwrap() as f32)
            .unwrap();
        let info = t.step(true).unwrap();
        let want_adapt = i + 1 == steps.len() && !fx.meta["adapt"].is_null();
        assert_eq!(
            info.adapt.is_some(),
            want_adapt,
            "step {i}: our schedule and the fixture disagree on an adaptive step after it"
        );
        assert_eq!(info.iter, s["iteration"].as_u64().unwrap() as u32);
        assert_eq!(
            info.sh_degree,
            s["active_sh_degree"].as_u64().unwrap() as u32,
            "step {i}: SH degree"
        );
        let l = info.losses.unwrap();
        let theirs = &s["losses"];
        push(
            format!("{i}.mse"),
            &[l.mse],
            &[theirs["mse"].as_f64().unwrap()],
        );
        if let Some(v) = theirs["ssim"].as_f64() {
            push(format!("{i}.ssim"), &[1.0 - l.ssim], &[v]);
        }
        // Our logged T terms are the output-resolution sums (config.rs,
        // t_losses_at_render); SVRaster's are on the render-resolution raw_T, so the
        // values compare only where the two resolutions are one. The gradients, compared
        // below, carry the render-resolution term at every ss.
        let same_size = s["render_size"][0].as_u64() == s["camera"]["width"].as_u64()
            && s["render_size"][1].as_u64() == s["camera"]["height"].as_u64();
        if let (Some(v), true) = (theirs["T_concen"].as_f64(), same_size) {
            push(format!("{i}.T_concen"), &[l.t_concentration], &[v]);
        }
        if let (Some(v), true) = (theirs["T_inside"].as_f64(), same_size) {
            push(format!("{i}.T_inside"), &[l.t_inside], &[v]);
        }
        // After an adaptive step the layout is the new one: that step's gradients and
        // update are those of the old layout, checked through the step's outcome
        // (compare_adapt) instead.
        if info.adapt.is_some() {
            continue;
        }
        let [geo, sh0, shs, prio] = t.gradients().unwrap();
        push(
            format!("{i}.grad.geo"),
            &f64s(&geo),
            &fx.get(&format!("{i}.grad.geo")).data,
        );
        push(
            format!("{i}.grad.sh0"),
            &f64s(&sh0),
            &fx.get(&format!("{i}.grad.sh0")).data,
        );
        push(
            format!("{i}.grad.shs"),
            &f64s(&shs),
            &fx.get(&format!("{i}.grad.shs")).data,
        );
        push(
            format!("{i}.subdiv_p"),
            &f64s(&prio),
            &fx.get(&format!("{i}.subdiv_p")).data,
        );
        let m = t.scene().unwrap();
        push(
            format!("{i}.param.geo"),
            &f64s(&m.geo),
            &fx.get(&format!("{i}.param.geo")).data,
        );
        push(
            format!("{i}.param.sh0"),
            &flat3(&m.sh0),
            &fx.get(&format!("{i}.param.sh0")).data,
        );
        push(
            format!("{i}.param.shs"),
            &f64s(&m.shs),
            &fx.get(&format!("{i}.param.shs")).data,
        );
        let o = t.optimizer_state().unwrap();
        for (g, name) in ["geo", "sh0", "shs"].iter().enumerate() {
            for (k, mv) in ["m", "v"].iter().enumerate() {
                let key = format!("{i}.adam.{name}.{mv}");
                push(key.clone(), &f64s(&o[2 * g + k]), &fx.get(&key).data);
            }
        }
    }
    if let Some(a) = fx.meta["adapt"].as_object() {
        compare_adapt(fx, a, &mut t, &mut push);
    }
    rows
}

/// SVRaster's initial model (train.py's model_init on the training cameras) against
/// ours from the same main region: the layout as a set of voxels, the counts, the values.
fn compare_init(
    fx: &Fixture,
    init: &serde_json::Map<String, serde_json::Value>,
    mut cfg: TrainConfig,
    train: &Dataset,
    bounds: &dyn Fn(&str) -> f64,
    rows: &mut Vec<Row>,
) {
    let c = &fx.meta["config"];
    let b: Vec<Vec<f64>> = serde_json::from_value(init["bounding"].clone()).unwrap();
    // The main region as SVRaster chose it (decide_main_bounding, a rule of its own).
    cfg.bound = "box".into();
    cfg.center = std::array::from_fn(|k| (0.5 * (b[0][k] + b[1][k])) as f32);
    cfg.extent = (0..3).map(|k| b[1][k] - b[0][k]).fold(0.0, f64::max) as f32;
    cfg.grid_level = c["init"]["init_n_level"].as_u64().unwrap() as u32;
    cfg.outside_level = c["bounding"]["outside_level"].as_u64().unwrap() as u32;
    cfg.init_out_ratio = c["init"]["init_out_ratio"].as_f64().unwrap() as f32;
    cfg.geo_init = c["init"]["geo_init"].as_f64().unwrap() as f32;
    cfg.sh0_init = c["init"]["sh0_init"].as_f64().unwrap() as f32;
    let ctx = context();
    let mut t = Trainer::new(&ctx, cfg, train, None).unwrap();
    let m = t.scene().unwrap();
    let mut push = |what: &str, ours: &[f64], theirs: &[f64]| {
        let (rel, max_abs) = rel_err(ours, theirs);
        rows.push(Row {
            what: format!("init.{what}"),
            rel,
            max_abs,
            bound: bounds(what),
        });
    };
    let extent = init["scene_extent"].as_f64().unwrap();
    push("extent", &[m.extent as f64], &[extent]);
    let (path, level) = (fx.get("init.octpath"), fx.get("init.octlevel"));
    let theirs: std::collections::HashSet<(u64, u8)> = (0..path.data.len())
        .map(|v| (path.data[v] as u64, level.data[v] as u8))
        .collect();
    let ours: std::collections::HashSet<(u64, u8)> = m
        .octpath
        .iter()
        .copied()
        .zip(m.octlevel.iter().copied())
        .collect();
    push("voxels", &[ours.len() as f64], &[theirs.len() as f64]);
    let missing = theirs.symmetric_difference(&ours).count();
    push("layout", &[missing as f64 / theirs.len() as f64], &[0.0]);
    push(
        "grid_points",
        &[m.grid_keys.len() as f64],
        &[init["grid_points"].as_f64().unwrap()],
    );
    // model_init's constants: geo_init, rgb2shzero(sh0_init), shs_init.
    let v = &init["values"];
    let one = |k: &str| {
        let a = v[k].as_array().unwrap();
        assert_eq!(a.len(), 1, "SVRaster's initial {k} is not one value: {a:?}");
        a[0].as_f64().unwrap()
    };
    let ours_geo: Vec<f64> = m.geo.iter().map(|&g| g as f64).collect();
    push("geo", &ours_geo, &vec![one("geo"); ours_geo.len()]);
    let ours_sh0 = flat3(&m.sh0);
    push("sh0", &ours_sh0, &vec![one("sh0"); ours_sh0.len()]);
    let ours_shs = f64s(&m.shs);
    if !ours_shs.is_empty() {
        push("shs", &ours_shs, &vec![one("shs"); ours_shs.len()]);
    }
}

/// The adaptive step's outcome: the counts, the layout (as sets of voxels and of grid
/// points: the two engines may order them differently) and the values carried to it.
fn compare_adapt(
    fx: &Fixture,
    a: &serde_json::Map<String, serde_json::Value>,
    t: &mut Trainer,
    push: &mut Push,
) {
    let m = t.scene().unwrap();
    let voxels = a["voxels"].as_array().unwrap();
    let (path, level) = (fx.get("adapt.octpath"), fx.get("adapt.octlevel"));
    let theirs: HashMap<(u64, u8), usize> = (0..path.data.len())
        .map(|v| ((path.data[v] as u64, level.data[v] as u8), v))
        .collect();
    let n = m.octpath.len();
    push(
        "adapt.voxels".into(),
        &[n as f64],
        &[voxels[2].as_f64().unwrap()],
    );
    let matched: Vec<(usize, usize)> = (0..n)
        .filter_map(|v| theirs.get(&(m.octpath[v], m.octlevel[v])).map(|&w| (v, w)))
        .collect();
    // Voxels of one layout missing from the other, as a fraction of theirs.
    let missing = (n - matched.len()) + (theirs.len() - matched.len());
    push(
        "adapt.layout".into(),
        &[missing as f64 / theirs.len() as f64],
        &[0.0],
    );
    let (sh0, shs) = (fx.get("adapt.param.sh0"), fx.get("adapt.param.shs"));
    let k = shs.data.len() / path.data.len().max(1);
    let (mut o0, mut t0, mut o1, mut t1) = (vec![], vec![], vec![], vec![]);
    for &(v, w) in &matched {
        for c in 0..3 {
            o0.push(m.sh0[v][c] as f64);
            t0.push(sh0.data[3 * w + c]);
        }
        for j in 0..k {
            o1.push(m.shs[v * k + j] as f64);
            t1.push(shs.data[w * k + j]);
        }
    }
    push("adapt.param.sh0".into(), &o0, &t0);
    push("adapt.param.shs".into(), &o1, &t1);
    let key = fx.get("adapt.grid_pts_key");
    let geo = fx.get("adapt.param.geo");
    let (mut og, mut tg) = (vec![], vec![]);
    let mut unmatched = 0usize;
    for g in 0..geo.data.len() {
        let c = &key.data[3 * g..3 * g + 3];
        let packed = (c[0] as u64) << 34 | (c[1] as u64) << 17 | c[2] as u64;
        match m.grid_keys.binary_search(&packed) {
            Ok(i) => {
                og.push(m.geo[i] as f64);
                tg.push(geo.data[g]);
            }
            Err(_) => unmatched += 1,
        }
    }
    push(
        "adapt.grid_points".into(),
        &[(m.grid_keys.len() as f64 - og.len() as f64 + unmatched as f64) / geo.data.len() as f64],
        &[0.0],
    );
    push("adapt.param.geo".into(), &og, &tg);
}

fn report(fx: &Fixture, rows: &[Row]) -> Vec<String> {
    println!("{} ({}):", fx.dir.display(), fx.meta["kernels"]);
    println!(
        "{:<22} {:>11} {:>11} {:>9}",
        "quantity", "rel L2", "max |Δ|", "bound"
    );
    let mut bad = Vec::new();
    for r in rows {
        let ok = r.rel <= r.bound;
        println!(
            "{:<22} {:>11.3e} {:>11.3e} {:>9.0e}{}",
            r.what,
            r.rel,
            r.max_abs,
            r.bound,
            if ok { "" } else { "  ✗" }
        );
        if !ok {
            bad.push(format!("{} {:.3e} > {:.0e}", r.what, r.rel, r.bound));
        }
    }
    bad
}

fn fixtures() -> Vec<PathBuf> {
    // PARITY_FIXTURES: another folder of fixture folders (a new dump, before committing it).
    let root = std::env::var_os("PARITY_FIXTURES").map_or_else(
        || Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/parity"),
        PathBuf::from,
    );
    let mut v: Vec<PathBuf> = std::fs::read_dir(&root)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.join("step.json").is_file())
        .collect();
    v.sort();
    assert!(!v.is_empty(), "no fixtures in {}", root.display());
    v
}

#[test]
fn training_steps_match_svraster_tensor_by_tensor() {
    let mut failures = Vec::new();
    for dir in fixtures() {
        let fx = Fixture::load(&dir);
        // SVRaster's rules, the preset that names them; no exception.
        let preset = match fx.meta["cfg_file"].as_str() {
            Some("cfg/synthetic_nerf.yaml") => "svraster-synthetic",
            Some("cfg/mipnerf360.yaml") => "svraster-real",
            other => panic!("{}: no preset models SVRaster's {other:?}", dir.display()),
        };
        let mut cfg = TrainConfig::preset(preset).unwrap();
        // The fixture's run: its length and SH degree (set on both sides); every other
        // value of its config must be what the preset models.
        let c = &fx.meta["config"];
        let num = |g: &str, k: &str| c[g][k].as_f64().unwrap();
        cfg.iters = num("procedure", "n_iter") as u32;
        cfg.sh_degree = c["model"]["sh_degree"].as_u64().unwrap() as u32;
        let s = cfg.schedule();
        for (g, k, ours) in [
            ("regularizer", "lambda_ssim", cfg.lambda_ssim as f64),
            ("regularizer", "lambda_T_concen", cfg.lambda_t as f64),
            ("regularizer", "lambda_T_inside", cfg.lambda_t_inside as f64),
            ("regularizer", "lambda_R_concen", cfg.lambda_r_colour as f64),
            ("regularizer", "lambda_tv_density", cfg.lambda_tv as f64),
            ("regularizer", "lambda_dist", cfg.lambda_dist as f64),
            ("regularizer", "ss_aug_max", cfg.ss as f64),
            ("optimizer", "geo_lr", s.lr_geo as f64),
            ("optimizer", "sh0_lr", s.lr_sh0 as f64),
            ("optimizer", "shs_lr", s.lr_shs as f64),
            ("optimizer", "optim_beta1", cfg.beta1 as f64),
            ("optimizer", "optim_beta2", cfg.beta2 as f64),
            ("optimizer", "optim_eps", cfg.eps as f64),
            ("procedure", "prune_thres_init", cfg.prune_thres_init as f64),
            (
                "procedure",
                "prune_thres_final",
                cfg.prune_thres_final as f64,
            ),
            ("procedure", "subdivide_prop", cfg.subdivide_percent),
            (
                "procedure",
                "subdivide_samp_thres",
                cfg.subdivide_min_rate as f64 / 2.0,
            ),
        ] {
            let theirs = num(g, k);
            assert!(
                (ours - theirs).abs() <= 1e-6 * theirs.abs().max(1e-12),
                "{}: SVRaster's {g}.{k} is {theirs}, the preset's {ours}",
                dir.display()
            );
        }
        // The layout after an adaptive step must be the same voxels and grid points.
        let rows = replay(&fx, cfg, &|what| match what {
            "voxels" | "layout" | "grid_points" | "extent" => 0.0,
            _ => 1e-3,
        });
        failures.extend(report(&fx, &rows));
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
