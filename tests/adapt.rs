//! Adaptive training end to end (paper §3.2.1–3.2.2): the schedule, initialisation
//! without unseen voxels, pruning and subdivision on the demo scene, the voxel budget and
//! the uniform baseline.

use crate::common;

use common::{context, finish, mean_psnr, Rng};
use svraster::adapt::topology::Topology;
use svraster::data::{self, demo};
use svraster::train::config::{Layout, TrainConfig};
use svraster::train::trainer::{uniform_grid, AdaptReport, Trainer};
use tempfile::TempDir;

/// The demo dataset in a fresh directory named `svraster-adapt-<name>-…`, removed when
/// dropped.
fn demo_data(name: &str, size: u32) -> TempDir {
    let dir = tempfile::Builder::new()
        .prefix(&format!("svraster-adapt-{name}-"))
        .tempdir()
        .unwrap();
    demo::write_dataset(
        dir.path(),
        &demo::DemoOptions {
            width: size,
            height: size,
            train: 30,
            val: 4,
            test: 1,
            seed: 5,
        },
    )
    .unwrap();
    dir
}

#[test]
fn adaptive_schedule_follows_the_paper_and_scales() {
    let c = TrainConfig::default();
    assert_eq!(c.layout, Layout::Adaptive);
    assert_eq!(c.grid_level, 6);
    let s = c.schedule();
    let iters: Vec<u32> = s.adapt.iter().map(|a| a.iter).collect();
    assert_eq!(iters, (1..=18).map(|k| k * 1000).collect::<Vec<_>>());
    let prunes: Vec<f32> = s.adapt.iter().filter_map(|a| a.prune_below).collect();
    assert_eq!(prunes.len(), 18);
    assert!((prunes[0] - 1e-4).abs() < 1e-9 && (prunes[17] - 0.05).abs() < 1e-7);
    for w in prunes.windows(2) {
        assert!(w[1] > w[0], "threshold ramps up: {prunes:?}");
    }
    let subdiv: Vec<u32> = s
        .adapt
        .iter()
        .filter(|a| a.subdivide)
        .map(|a| a.iter)
        .collect();
    assert_eq!(subdiv, (1..=15).map(|k| k * 1000).collect::<Vec<_>>());
    assert!(s.adapt.iter().all(|a| !a.subdivide_all), "off by default");
    // SVRaster's synthetic config: subdivide everything at its first adaptive step.
    let mut all = c.clone();
    all.set("subdivide_all_until=0.05").unwrap();
    let every: Vec<u32> = all
        .schedule()
        .adapt
        .iter()
        .filter(|a| a.subdivide_all)
        .map(|a| a.iter)
        .collect();
    assert_eq!(every, vec![1000]);

    // A short run scales the milestones but waits |geo_init|/lr_geo iterations (here
    // 10/0.1 = 100) before the first step: earlier, no density has reached a surface.
    let mut c = TrainConfig::preset("quick").unwrap();
    c.set("iters=300").unwrap();
    let s = c.schedule();
    let iters: Vec<u32> = s.adapt.iter().map(|a| a.iter).collect();
    // Steps at least adapt_min_spacing = 100 iterations apart (15 + 100k).
    assert_eq!(iters, vec![115, 215]);
    // No step of a 300-iteration run has the 500 iterations after it that subdivided
    // children need (subdivide_min_after): it only prunes. Without that guard it would
    // subdivide up to 0.75 of the run.
    assert!(s.adapt.iter().all(|a| !a.subdivide), "{:?}", s.adapt);
    assert_eq!(s.adapt[0].prune_below, Some(1e-4));
    let mut c2 = c.clone();
    c2.set("subdivide_min_after=0").unwrap();
    let last = c2
        .schedule()
        .adapt
        .into_iter()
        .rfind(|a| a.subdivide)
        .unwrap();
    assert_eq!(last.iter, 215);
    // Without the spacing floor: a step every 15 iterations (5 % of the run).
    c2.set("adapt_min_spacing=0").unwrap();
    let iters: Vec<u32> = c2.schedule().adapt.iter().map(|a| a.iter).collect();
    assert_eq!(iters, (7..=18).map(|k| k * 15).collect::<Vec<_>>());
    c2.set("adapt_min_spacing=100").unwrap();
    // 1 000 iterations: steps up to 500 subdivide (the first at 100).
    c2.set("subdivide_min_after=500").unwrap();
    c2.set("iters=1000").unwrap();
    let sub: Vec<u32> = c2
        .schedule()
        .adapt
        .iter()
        .filter(|a| a.subdivide)
        .map(|a| a.iter)
        .collect();
    assert_eq!(sub, vec![150, 250, 350, 450]);
    // The paper's learning rate unscaled needs 400 iterations: a 300-iteration run
    // never adapts.
    c.set("lr_geo=0.025").unwrap();
    c.set("lr_geo_scale_max=1").unwrap();
    assert!(c.schedule().adapt.is_empty());
    c.set("layout=fixed").unwrap();
    assert!(c.schedule().adapt.is_empty());
    let e = c.set("layout=octree").unwrap_err().to_string();
    assert!(e.contains("layout"), "{e}");
}

fn reports_of(t: &mut Trainer) -> Vec<AdaptReport> {
    let mut out = Vec::new();
    while t.iter() < t.config().iters {
        let info = t.step(false).unwrap();
        if let Some(r) = info.adapt {
            out.push(r);
        }
    }
    t.check_finite().unwrap();
    out
}

/// A subdivide-all step (`subdivide_all_until`, SVRaster's synthetic first step) splits
/// every candidate, not the top few percent: the same run's first subdivision with it
/// splits far more voxels, and the layout stays consistent.
#[test]
fn subdivide_all_step_splits_every_candidate() {
    let ctx = context();
    let dir = demo_data("all", 32);
    let train = data::load_split(dir.path(), "train", 1.0, [1.0; 3]).unwrap();
    let mut cfg = TrainConfig::preset("quick").unwrap();
    cfg.iters = 200;
    cfg.grid_level = 4;
    cfg.subdivide_percent = 0.05;
    cfg.subdivide_min_after = 0;
    // The sampling-rate guard is not under test (32² views see coarse voxels only).
    cfg.subdivide_min_rate = 0.0;
    let first = |all: f64| {
        let mut c = cfg.clone();
        c.subdivide_all_until = all;
        let mut t = Trainer::new(&ctx, c, &train, None).unwrap();
        let r = reports_of(&mut t)
            .into_iter()
            .next()
            .expect("an adaptive step");
        assert_eq!(r.voxels, r.voxels_before - r.pruned + 7 * r.subdivided);
        r
    };
    let top = first(0.0);
    let all = first(1.0);
    eprintln!(
        "first step: {} of {} kept voxels split by priority, {} of {} with subdivide-all",
        top.subdivided,
        top.voxels_before - top.pruned,
        all.subdivided,
        all.voxels_before - all.pruned
    );
    assert!(top.subdivided > 0, "{top:?}");
    assert!(all.subdivided >= 8 * top.subdivided, "{all:?} vs {top:?}");
    finish(&ctx);
}

/// `reset_adam_at_adapt` (SVRaster's new optimiser at every adaptive step): right after
/// a step the Adam moments are zero (carried otherwise), and training goes on.
#[test]
fn adam_reset_at_adaptive_steps() {
    let ctx = context();
    let dir = demo_data("reset", 32);
    let train = data::load_split(dir.path(), "train", 1.0, [1.0; 3]).unwrap();
    let mut cfg = TrainConfig::preset("quick").unwrap();
    cfg.iters = 200;
    cfg.grid_level = 4;
    let moments_after_first_step = |reset: bool| {
        let mut c = cfg.clone();
        c.reset_adam_at_adapt = reset;
        let mut t = Trainer::new(&ctx, c, &train, None).unwrap();
        while t.step(false).unwrap().adapt.is_none() {}
        let zero = t
            .optimizer_state()
            .unwrap()
            .iter()
            .all(|m| m.iter().all(|&x| x == 0.0));
        for _ in 0..3 {
            t.step(false).unwrap();
        }
        t.check_finite().unwrap();
        let moved = t
            .optimizer_state()
            .unwrap()
            .iter()
            .any(|m| m.iter().any(|&x| x != 0.0));
        (zero, moved)
    };
    assert_eq!(moments_after_first_step(true), (true, true));
    assert_eq!(moments_after_first_step(false), (false, true));
    finish(&ctx);
}

/// The demo's content fills a small part of a box twice the usual size: pruning and
/// subdivision must end with a model far smaller than a uniform grid of its finest level,
/// and still fit the views.
#[test]
fn adaptive_layout_models_only_what_the_scene_requires() {
    let ctx = context();
    let dir = demo_data("small", 48);
    let train = data::load_split(dir.path(), "train", 1.0, [1.0; 3]).unwrap();
    let mut cfg = TrainConfig::preset("quick").unwrap();
    cfg.iters = 240;
    cfg.grid_level = 4;
    cfg.extent = 6.0;
    cfg.background = train.background;
    // Subdivide more per step than the paper so a short run reaches fine levels, and up
    // to its end (the default stops 500 iterations before it).
    cfg.subdivide_percent = 0.2;
    cfg.subdivide_min_after = 0;
    cfg.adapt_min_spacing = 0;
    let dense = uniform_grid(&cfg).unwrap().num_voxels();
    let mut t = Trainer::new(&ctx, cfg.clone(), &train, None).unwrap();
    let initial = t.voxels() as usize;
    assert!(initial <= dense);
    let reports = reports_of(&mut t);
    assert_eq!(reports.len(), cfg.schedule().adapt.len());
    let pruned: u32 = reports.iter().map(|r| r.pruned).sum();
    let subdivided: u32 = reports.iter().map(|r| r.subdivided).sum();
    assert!(
        pruned > 0 && subdivided > 0,
        "pruned {pruned}, subdivided {subdivided}"
    );
    for r in &reports {
        assert_eq!(r.voxels, r.voxels_before - r.pruned + 7 * r.subdivided);
        assert!(r.device_memory > 0);
    }
    let scene = t.scene().unwrap();
    scene.validate().unwrap();
    let finest = scene.max_level();
    assert!(finest >= cfg.grid_level + 2, "max level {finest}");
    let uniform = 1usize << (3 * finest);
    eprintln!(
        "dense level-{} grid {dense}, visible {initial}, final {} voxels (max level {finest}; a \
         uniform level-{finest} grid has {uniform}); pruned {pruned}, subdivided {subdivided}",
        cfg.grid_level,
        scene.num_voxels()
    );
    assert!(
        scene.num_voxels() * 50 < uniform,
        "{} voxels vs {uniform}",
        scene.num_voxels()
    );
    let val = data::load_split(dir.path(), "val", 1.0, train.background).unwrap();
    let psnr = mean_psnr(&ctx, &scene, &val);
    eprintln!("val PSNR {psnr:.2} dB");
    // An emptied model scores ~9 dB here; the fixed level-4 grid ~20 dB.
    assert!(psnr > 18.0, "val PSNR {psnr}");
    finish(&ctx);
}

/// Subdivision never takes the model past the voxel budget, and says so when it stops.
#[test]
fn voxel_budget_stops_subdivision() {
    let ctx = context();
    let dir = demo_data("budget", 32);
    let train = data::load_split(dir.path(), "train", 1.0, [1.0; 3]).unwrap();
    let mut cfg = TrainConfig::preset("quick").unwrap();
    cfg.iters = 80;
    cfg.subdivide_min_after = 0;
    cfg.adapt_min_spacing = 0;
    cfg.geo_init = -2.0; // adaptive steps from iteration 20 (see the schedule test)
    cfg.grid_level = 4;
    cfg.subdivide_percent = 0.5;
    cfg.prune_thres_init = 0.0;
    cfg.prune_thres_final = 0.0;
    cfg.background = train.background;
    let probe = Trainer::new(&ctx, cfg.clone(), &train, None).unwrap();
    let start = probe.voxels() as u64;
    drop(probe);
    cfg.max_voxels = start + 7 * 20 + 3;
    let mut t = Trainer::new(&ctx, cfg.clone(), &train, None).unwrap();
    assert_eq!(t.budget(), cfg.max_voxels);
    let reports = reports_of(&mut t);
    assert!(reports.iter().any(|r| r.budget_reached), "{reports:?}");
    for r in &reports {
        assert!(r.voxels as u64 <= cfg.max_voxels, "{r:?}");
    }
    let last = reports.last().unwrap();
    assert!(
        last.voxels as u64 + 7 > cfg.max_voxels,
        "budget filled: {last:?}"
    );
    finish(&ctx);
}

/// The uniform baseline subdivides every voxel at once, up to its max level.
#[test]
fn uniform_layout_subdivides_everything_to_its_level() {
    let ctx = context();
    let dir = demo_data("uniform", 32);
    let train = data::load_split(dir.path(), "train", 1.0, [1.0; 3]).unwrap();
    let mut cfg = TrainConfig::preset("quick").unwrap();
    cfg.iters = 60;
    cfg.subdivide_min_after = 0;
    cfg.adapt_min_spacing = 0;
    cfg.geo_init = -2.0;
    cfg.grid_level = 3;
    cfg.layout = Layout::Uniform;
    cfg.max_level = 5;
    // Keep every voxel: this test is about subdivision.
    cfg.prune_thres_init = 0.0;
    cfg.prune_thres_final = 0.0;
    cfg.background = train.background;
    let mut t = Trainer::new(&ctx, cfg.clone(), &train, None).unwrap();
    let reports = reports_of(&mut t);
    let scene = t.scene().unwrap();
    assert_eq!(scene.max_level(), 5, "{reports:?}");
    assert!(scene.octlevel.iter().all(|&l| l == 5));
    let splits: Vec<u32> = reports
        .iter()
        .map(|r| r.subdivided)
        .filter(|&s| s > 0)
        .collect();
    assert_eq!(splits.len(), 2, "{reports:?}");
    finish(&ctx);
}

/// The trainer's layout change (on the device, parameters and Adam moments never leave
/// it) gives bit for bit what `Topology::apply` gives for the host snapshot of the same
/// model and optimiser state, and training goes on from it.
#[test]
fn layout_change_on_the_device_matches_the_host_snapshot() {
    let ctx = context();
    let dir = demo_data("layout", 32);
    let train = data::load_split(dir.path(), "train", 1.0, [1.0; 3]).unwrap();
    let mut cfg = TrainConfig::preset("quick").unwrap();
    cfg.iters = 100;
    cfg.grid_level = 4;
    cfg.extent = 6.0;
    cfg.background = train.background;
    cfg.sh_every = 0.0; // the final degree from the first step: SH moments are non-zero
    let mut t = Trainer::new(&ctx, cfg, &train, None).unwrap();
    for _ in 0..4 {
        t.step(false).unwrap();
    }
    let before = t.scene().unwrap();
    let state = t.optimizer_state().unwrap();
    assert!(!before.shs.is_empty(), "stored SH degree > 0");
    assert!(state[5].iter().any(|&v| v != 0.0), "shs moments trained");
    let n = before.num_voxels();
    let mut rng = Rng(23);
    let keep: Vec<bool> = (0..n).map(|_| rng.below(5) != 0).collect();
    let split: Vec<bool> = (0..n).map(|_| rng.below(4) == 0).collect();
    let mut topo = Topology::new(&ctx).unwrap();
    let (want, want_state) = topo.apply(&before, Some(&state), &keep, &split).unwrap();
    let want_state = want_state.unwrap();

    t.change_layout(&keep, &split).unwrap();
    let got = t.scene().unwrap();
    let got_state = t.optimizer_state().unwrap();
    assert_eq!(got.octpath, want.octpath, "octpaths");
    assert_eq!(got.octlevel, want.octlevel, "levels");
    assert_eq!(got.grid_keys, want.grid_keys, "grid keys");
    assert_eq!(got.corners, want.corners, "corners");
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&got.geo), bits(&want.geo), "geo");
    let flat = |v: &[[f32; 3]]| bits(&v.iter().flatten().copied().collect::<Vec<_>>());
    assert_eq!(flat(&got.sh0), flat(&want.sh0), "sh0");
    assert_eq!(bits(&got.shs), bits(&want.shs), "shs");
    let names = ["geo m", "geo v", "sh0 m", "sh0 v", "shs m", "shs v"];
    for k in 0..6 {
        assert_eq!(bits(&got_state[k]), bits(&want_state[k]), "{}", names[k]);
    }
    // Training continues on the new layout (buffers sized for it).
    let info = t.step(true).unwrap();
    assert!(info.entries.is_some_and(|e| e > 0), "{:?}", info.entries);
    t.check_finite().unwrap();
    assert_eq!(t.voxels() as usize, want.num_voxels());
    finish(&ctx);
}
