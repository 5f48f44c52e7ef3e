use super::*;
use svraster::train::config::ClampGrad;

/// The speed modifiers apply to any preset, bare ones to the data format's, and are the
/// measured combinations (README "Speed ↔ accuracy").
#[test]
fn speed_presets_modify_any_preset() {
    let p = |n: &str| TrainConfig::preset(n).unwrap();
    let (syn, fwd) = (p("synthetic"), p("forward"));
    // The synthetic preset subdivides down to rate 1 (SVRaster's synthetic config); the
    // speed modifiers keep the measured rate-2 guard.
    assert_eq!(syn.subdivide_min_rate, 1.0);
    assert_eq!(p("quick").subdivide_min_rate, 2.0);
    // SVRaster's 6 000-iteration learning rules in the synthetic preset; the speed
    // modifiers and the other presets keep the rules they were measured with.
    let rules = |c: &TrainConfig| {
        (
            c.colour_clamp_grad,
            c.lr_colour_scale_max,
            c.lr_geo,
            c.reset_adam_at_adapt,
        )
    };
    assert_eq!(rules(&syn), (ClampGrad::Straight, 1.0 / 0.3, 0.0833, true));
    let d = TrainConfig::default();
    assert_eq!(rules(&d), (ClampGrad::Masked, 1.0, 0.1, false));
    for n in [
        "synthetic-fast-train",
        "synthetic-fast-render",
        "quick",
        "real",
        "forward",
        "object",
        "mesh",
    ] {
        assert_eq!(rules(&p(n)), rules(&d), "{n}");
    }
    let ft = p("synthetic-fast-train");
    assert_eq!(
        (ft.ss, ft.grid_level, ft.sh_degree, ft.subdivide_min_rate),
        (1.0, syn.grid_level - 1, 3, 2.0)
    );
    let fr = p("synthetic-fast-render");
    assert_eq!(
        (
            fr.ss,
            fr.prune_thres_final,
            fr.grid_level,
            fr.subdivide_min_rate
        ),
        (1.0, 0.15, syn.grid_level, 2.0)
    );
    let ft = p("forward-fast-train");
    assert_eq!(
        (ft.ss, ft.grid_level, ft.sh_degree),
        (1.0, fwd.grid_level, 1)
    );
    assert_eq!(
        ft.outside_level, fwd.outside_level,
        "the rest is the base preset's"
    );
    let fr = p("forward-fast-render");
    assert_eq!((fr.ss, fr.prune_thres_final), (1.0, fwd.prune_thres_final));
    assert_eq!(
        serde_json::to_value(p("fast-train")).unwrap(),
        serde_json::to_value(p("synthetic-fast-train")).unwrap()
    );
    assert_eq!(
        TrainConfig::resolve_preset("fast-render", "real"),
        "real-fast-render"
    );
    assert_eq!(TrainConfig::resolve_preset("object", "real"), "object");
    for bad in [
        "nope-fast-train",
        "synthetic-fast-train-fast-render",
        "fast-render-fast-train",
        "fast-train-fast-render",
        "fast",
    ] {
        assert!(TrainConfig::preset(bad).is_err(), "{bad}");
    }
}

#[test]
fn schedule_is_fractions_of_the_run() {
    let c = TrainConfig::default();
    let s = c.schedule();
    assert_eq!(s.sh_degree_up, vec![1000, 2000, 3000]);
    assert_eq!(
        (s.ss_from, s.lr_decay_at, s.dist_from, s.tv_until),
        (1000, 19000, 10000, 10000)
    );
    assert_eq!(s.checkpoints, vec![5000, 10000, 15000]);
    // The reference's mesh schedule: median-depth term from 3 000, mean from 10 000.
    assert_eq!((s.normal_dmed_from, s.normal_dmean_from), (3000, 10000));
    let m = TrainConfig::preset("mesh").unwrap();
    assert_eq!(
        (m.lambda_normal_dmed, m.lambda_normal_dmean, m.samples),
        (0.001, 0.001, 3)
    );
    assert_eq!(
        TrainConfig::preset("object").unwrap().lambda_normal_dmed,
        0.0
    );
    let mut c = TrainConfig::default();
    c.set("iters=2000").unwrap();
    let s = c.schedule();
    assert_eq!(s.sh_degree_up, vec![100, 200, 300]);
    assert_eq!(
        (s.ss_from, s.lr_decay_at, s.dist_from, s.tv_until),
        (100, 1900, 1000, 1000)
    );
    assert_eq!((0..400).map(|i| s.sh_degree(i)).max(), Some(3));
    assert_eq!(s.sh_degree(99), 0);
    assert_eq!(s.sh_degree(100), 1);
    // Overrides and their errors.
    c.set("lambda_ssim=0").unwrap();
    assert_eq!(c.lambda_ssim, 0.0);
    let e = c.set("lamda_ssim=0").unwrap_err().to_string();
    assert!(
        e.contains("unknown config key") && e.contains("lambda_ssim"),
        "{e}"
    );
    let e = c.set("grid_level=seven").unwrap_err().to_string();
    assert!(e.contains("grid_level"), "{e}");
    // sh_every = 0: the final degree from the first iteration (bench train's regime).
    c.set("sh_every=0").unwrap();
    assert_eq!(c.schedule().sh_degree_up, vec![0, 0, 0]);
    assert_eq!(c.schedule().sh_degree(0), 3);
    c.set("sh_every=1.5").unwrap();
    assert!(c.validate().unwrap_err().to_string().contains("sh_every"));
    assert!(TrainConfig::preset("nope").is_err());
    // The paper's values, but for the density rate (0.1, constant: see lr_geo_used).
    let d = TrainConfig::default();
    assert_eq!((d.beta1, d.beta2, d.eps), (0.1, 0.99, 1e-15));
    assert_eq!((d.lr_geo, d.lr_sh0, d.lr_shs), (0.1, 0.01, 0.00025));
    for iters in [300, 3_000, 20_000, 40_000] {
        let c = TrainConfig {
            iters,
            ..TrainConfig::default()
        };
        assert_eq!(c.lr_geo_used(), 0.1, "{iters}");
    }
    // The paper's rate with the square-root rule: 0.025 at 20 000 iterations and beyond,
    // sqrt(20 000 / iters) times it for shorter runs, at most 4 times.
    let mut c = TrainConfig::default();
    c.set("lr_geo=0.025").unwrap();
    c.set("lr_geo_scale_max=4").unwrap();
    for (iters, want) in [
        (40_000, 0.025),
        (20_000, 0.025),
        (5_000, 0.05),
        (3_000, 0.0645497),
        (1_250, 0.1),
        (300, 0.1),
    ] {
        c.iters = iters;
        assert!(
            (c.lr_geo_used() - want).abs() < 1e-6,
            "{iters}: {}",
            c.lr_geo_used()
        );
        assert_eq!(c.schedule().lr_geo, c.lr_geo_used());
    }
    c.lr_geo_scale_max = 1.0;
    assert_eq!(c.lr_geo_used(), 0.025);
    // The SH rates: as set by default at every length; SVRaster's sche_mult rule,
    // 20 000 / iters times them, capped by lr_colour_scale_max (the synthetic preset:
    // 1/0.3, SVRaster's 6 000-iteration rates for every shorter run).
    for iters in [300, 3_000, 20_000, 40_000] {
        let c = TrainConfig {
            iters,
            ..TrainConfig::default()
        };
        assert_eq!(c.lr_colour_used(), (0.01, 0.00025), "{iters}");
    }
    let mut c = TrainConfig::preset("synthetic").unwrap();
    for (iters, f) in [
        (40_000, 1.0),
        (20_000, 1.0),
        (10_000, 2.0),
        (6_000, 1.0 / 0.3),
        (3_000, 1.0 / 0.3),
        (300, 1.0 / 0.3),
    ] {
        c.iters = iters;
        let (sh0, shs) = c.lr_colour_used();
        assert!(
            (sh0 / 0.01 - f).abs() < 1e-4 && (shs / 0.00025 - f).abs() < 1e-4,
            "{iters}: {sh0} {shs}"
        );
        assert_eq!((c.schedule().lr_sh0, c.schedule().lr_shs), (sh0, shs));
    }
    // An extended run keeps its schedule's rates.
    c.iters = 40_000;
    c.schedule_iters = Some(6_000);
    assert!((c.lr_colour_used().0 - 0.01 / 0.3).abs() < 1e-6);
}

/// The `svraster-synthetic` preset scales a run as SVRaster's `--sche_mult iters/20 000`
/// does (train.py:584-609): every rate by 20 000/iters, SH and supersampling at its
/// unscaled iterations, the distortion loss from its 1-based `dist_from`.
#[test]
fn svraster_preset_scales_as_sche_mult() {
    let mut c = TrainConfig::preset("svraster-synthetic").unwrap();
    for (iters, sh, dist_from) in [
        (20_000u32, vec![999, 1999, 2999], 9_999u32),
        (6_000, vec![999, 1999, 2999], 2_999),
        (2_000, vec![999, 1999, 2000], 999),
    ] {
        c.iters = iters;
        let s = c.schedule();
        let m = iters as f32 / 20_000.0;
        for (got, want) in [
            (s.lr_geo, 0.025 / m),
            (s.lr_sh0, 0.01 / m),
            (s.lr_shs, 0.00025 / m),
        ] {
            assert!(
                (got / want - 1.0).abs() < 1e-6,
                "{iters}: rate {got} vs {want}"
            );
        }
        assert_eq!(s.sh_degree_up, sh, "{iters}");
        assert_eq!(s.ss_from, 1000, "{iters}");
        assert_eq!(s.dist_from, dist_from, "{iters}");
        // SVRaster's adaptive steps: every 1000·m from 1000·m, the first subdividing all.
        let every = (1000.0 * m).round() as u32;
        assert_eq!(s.adapt[0].iter, every, "{iters}");
        assert!(s.adapt[0].subdivide_all && !s.adapt[1].subdivide_all);
    }
    // Longer than 20 000: the rates fall as sche_mult > 1 makes them.
    c.iters = 40_000;
    assert!((c.schedule().lr_geo - 0.0125).abs() < 1e-9);
}

#[test]
fn training_smoke_test_on_the_demo_scene() {
    // CI's training check: a few hundred iterations on the procedural scene must lift
    // the held-out PSNR far above the initial model's.
    let ctx = context();
    let dir = demo_data("smoke", 48);
    let train = data::load_split(dir.path(), "train", 1.0, [1.0; 3]).unwrap();
    let val = data::load_split(dir.path(), "val", 1.0, [1.0; 3]).unwrap();
    let cfg = quick(300);
    let init = uniform_grid(&cfg).unwrap();
    let before = mean_psnr(&ctx, &init, &val);
    let mut t = Trainer::new(&ctx, cfg.clone(), &train, Some(init)).unwrap();
    let mut first = None;
    let mut last = None;
    for i in 0..cfg.iters {
        let info = t.step(i == 0 || i + 1 == cfg.iters).unwrap();
        if let Some(l) = info.losses {
            assert!(l.loss.is_finite() && l.ssim.is_finite());
            if first.is_none() {
                first = Some(l);
            }
            last = Some(l);
        }
    }
    t.check_finite().unwrap();
    let scene = t.scene().unwrap();
    scene.validate().unwrap();
    let after = mean_psnr(&ctx, &scene, &val);
    let (first, last) = (first.unwrap(), last.unwrap());
    println!(
        "val PSNR {before:.2} → {after:.2} dB; train loss {:.4} → {:.4}, SSIM {:.3} → {:.3}",
        first.loss, last.loss, first.ssim, last.ssim
    );
    assert!(after > before + 6.0, "val PSNR {before:.2} → {after:.2}");
    assert!(after > 17.0, "val PSNR {after:.2}");
    assert!(last.loss < 0.5 * first.loss);
    // The scores do not depend on whether the frame time is measured (the held-out
    // curve during training skips it and renders each view once).
    let opts = svraster::raster::RenderOptions::default();
    let eval = |timing| {
        svraster::eval::evaluate(&ctx, &scene, &val, &opts, timing, |_, _, _, _, _| {}).unwrap()
    };
    let (timed, untimed) = (
        eval(svraster::eval::Timing::Measured),
        eval(svraster::eval::Timing::Skipped),
    );
    assert!(timed.ms_per_frame.is_some_and(|ms| ms > 0.0) && untimed.ms_per_frame.is_none());
    assert_eq!(timed.per_view, untimed.per_view);
    assert_eq!(untimed.psnr, after);
    finish(&ctx);
}

/// A capture whose photos differ in size (several cameras in one model): the views of
/// a 32×32 and a 28×20 rendering of the demo scene, interleaved, train together, and
/// `evaluate` scores each view at its own size (the mixed split's per-view PSNRs are
/// those of the two single-size splits).
#[test]
fn frames_of_different_sizes_train_and_evaluate_together() {
    let ctx = context();
    let a_dir = demo_data("mixed-a", 32);
    let b_dir = tempfile::Builder::new()
        .prefix("svraster-train-mixed-b-")
        .tempdir()
        .unwrap();
    demo::write_dataset(
        b_dir.path(),
        &demo::DemoOptions {
            width: 28,
            height: 20,
            train: 40,
            val: 6,
            test: 1,
            seed: 3,
        },
    )
    .unwrap();
    let load = |d: &TempDir, split: &str| data::load_split(d.path(), split, 1.0, [1.0; 3]).unwrap();
    let mix = |a: &data::Dataset, b: &data::Dataset| -> data::Dataset {
        let mut m = a.clone();
        m.frames = a
            .frames
            .iter()
            .zip(&b.frames)
            .enumerate()
            .map(|(i, (fa, fb))| if i % 2 == 0 { fa.clone() } else { fb.clone() })
            .collect();
        assert!(!m.uniform_size());
        m
    };
    let (a_val, b_val) = (load(&a_dir, "val"), load(&b_dir, "val"));
    let train = mix(&load(&a_dir, "train"), &load(&b_dir, "train"));
    let val = mix(&a_val, &b_val);
    let cfg = quick(200);
    let init = uniform_grid(&cfg).unwrap();
    let before = mean_psnr(&ctx, &init, &val);
    let mut t = Trainer::new(&ctx, cfg.clone(), &train, Some(init)).unwrap();
    for _ in 0..cfg.iters {
        t.step(false).unwrap();
    }
    t.check_finite().unwrap();
    let scene = t.scene().unwrap();
    let eval = |ds: &data::Dataset| {
        svraster::eval::evaluate(
            &ctx,
            &scene,
            ds,
            &svraster::raster::RenderOptions::default(),
            svraster::eval::Timing::Skipped,
            |_, _, _, _, _| {},
        )
        .unwrap()
    };
    let (m, a, b) = (eval(&val), eval(&a_val), eval(&b_val));
    assert!(m.sizes_differ && !a.sizes_differ && !b.sizes_differ);
    assert_eq!((m.width, m.height), (32, 32));
    println!(
        "mixed val PSNR {before:.2} → {:.2} dB (32×32 views {:.2}, 28×20 views {:.2})",
        m.psnr, a.psnr, b.psnr
    );
    assert!(
        m.psnr > before + 6.0 && m.psnr > 17.0,
        "val PSNR {before:.2} → {:.2}",
        m.psnr
    );
    for (i, v) in m.per_view.iter().enumerate() {
        let single = if i % 2 == 0 {
            &a.per_view[i]
        } else {
            &b.per_view[i]
        };
        assert_eq!(v.0, single.0);
        assert!(
            (v.1 - single.1).abs() < 1e-9 && (v.2 - single.2).abs() < 1e-9,
            "{v:?} vs {single:?}"
        );
    }
    finish(&ctx);
}

#[test]
fn same_seed_same_model_up_to_atomic_order() {
    let ctx = context();
    let dir = demo_data("repro", 32);
    let train = data::load_split(dir.path(), "train", 1.0, [1.0; 3]).unwrap();
    let run = |seed: u64| -> Scene {
        let mut cfg = quick(25);
        cfg.grid_level = 4;
        cfg.seed = seed;
        cfg.ss = 1.5;
        cfg.ss_from = 0.2;
        let mut t = Trainer::new(&ctx, cfg.clone(), &train, None).unwrap();
        for _ in 0..cfg.iters {
            t.step(false).unwrap();
        }
        t.scene().unwrap()
    };
    let (a, b, c) = (run(7), run(7), run(8));
    let diff = |x: &Scene, y: &Scene| -> f64 {
        x.geo
            .iter()
            .zip(&y.geo)
            .map(|(p, q)| (p - q).abs() as f64)
            .fold(0.0, f64::max)
    };
    let same = diff(&a, &b);
    let other = diff(&a, &c);
    println!("max |Δgeo|: same seed {same:.2e}, other seed {other:.2e}");
    assert!(same < 1e-3, "same seed differs by {same}");
    assert!(
        other > 100.0 * same.max(1e-6),
        "seeds should matter: {other}"
    );
    finish(&ctx);
}

/// Training with frames and backward walked in segments (here of 6 entries, so every
/// tile's list spans many) reaches the model trained without, up to rounding: same
/// held-out PSNR within 0.05 dB, iterations queued as usual.
#[test]
fn segmented_training_matches_unsegmented_training() {
    let ctx = context();
    let dir = demo_data("segments", 32);
    let train = data::load_split(dir.path(), "train", 1.0, [1.0; 3]).unwrap();
    let val = data::load_split(dir.path(), "val", 1.0, [1.0; 3]).unwrap();
    let mut cfg = quick(50);
    cfg.deterministic = true;
    let init = uniform_grid(&cfg).unwrap();
    let before = mean_psnr(&ctx, &init, &val);
    let run = |segments: u32| -> (f64, Option<u32>) {
        let mut t = Trainer::new(&ctx, cfg.clone(), &train, Some(init.clone())).unwrap();
        t.set_segment_entries(segments).unwrap();
        for i in 0..cfg.iters {
            t.step(i + 1 == cfg.iters).unwrap();
        }
        t.check_finite().unwrap();
        let slots = t.frame_stats().map(|s| s.slots);
        (mean_psnr(&ctx, &t.scene().unwrap(), &val), slots)
    };
    let (off, _) = run(0);
    let (on, slots) = run(6);
    println!("held-out PSNR: initial {before:.2}, unsegmented {off:.3}, segments of 6 {on:.3} ({slots:?} slots in the last frame)");
    assert!(
        slots.is_some_and(|s| s > 4 * 16),
        "{slots:?}: too few segments"
    );
    assert!(
        off > before + 1.0,
        "training did not learn: {before} → {off}"
    );
    assert!(
        (on - off).abs() < 0.05,
        "segmented {on} vs unsegmented {off}"
    );
    finish(&ctx);
}

/// SVRaster's loss on the clamped output (`clamp_rgb_loss`, docs/PARITY.md item 10),
/// wired through the trainer: where every rendered pixel is far above 1 the clamp
/// passes no gradient, from the MSE or from SSIM, so a few iterations leave the model
/// as it was; without the switch the same iterations move every visible colour. Fails
/// if either loss takes its gradient from the unclamped image.
#[test]
fn clamped_output_losses_pass_no_gradient_above_one() {
    let ctx = context();
    let dir = demo_data("clamp", 24);
    let train = data::load_split(dir.path(), "train", 1.0, [1.0; 3]).unwrap();
    let mut cfg = TrainConfig {
        grid_level: 3,
        ..quick(1000)
    };
    // Only the photometric losses: every other term would move the model by itself.
    cfg.lambda_mse = 1.0;
    cfg.lambda_ssim = 0.2;
    cfg.lambda_t = 0.0;
    cfg.lambda_t_inside = 0.0;
    cfg.lambda_dist = 0.0;
    cfg.lambda_normal_dmed = 0.0;
    cfg.lambda_normal_dmean = 0.0;
    cfg.lambda_r = 0.0;
    cfg.lambda_r_colour = 0.0;
    cfg.lambda_tv = 0.0;
    let mut init = uniform_grid(&cfg).unwrap();
    // Opaque voxels with colour ≈ 0.5 + 0.28 · 100: every pixel that sees a voxel is
    // far above 1 (one that sees none gets no colour gradient either way).
    init.geo.iter_mut().for_each(|g| *g = 5.0);
    init.sh0.iter_mut().for_each(|c| *c = [100.0; 3]);
    init.shs.iter_mut().for_each(|c| *c = 0.0);
    let run = |clamp: bool| {
        let mut t = Trainer::new(
            &ctx,
            TrainConfig {
                clamp_rgb_loss: clamp,
                ..cfg.clone()
            },
            &train,
            Some(init.clone()),
        )
        .unwrap();
        for _ in 0..3 {
            t.step(false).unwrap();
        }
        t.scene().unwrap()
    };
    let moved = |s: &Scene| {
        let geo = s.geo.iter().zip(&init.geo).filter(|(a, b)| a != b).count();
        let sh0 = s.sh0.iter().zip(&init.sh0).filter(|(a, b)| a != b).count();
        (geo, sh0)
    };
    let (clamped, raw) = (moved(&run(true)), moved(&run(false)));
    println!(
        "changed by 3 iterations (densities, colours) of {} / {}: clamped {clamped:?}, unclamped {raw:?}",
        init.geo.len(),
        init.sh0.len()
    );
    assert_eq!(clamped, (0, 0), "the clamped losses passed a gradient");
    // Three views see the surface voxels of the opaque grid (~a fifth of them).
    assert!(
        raw.0 > 50 && raw.1 > 50,
        "without the clamp only {raw:?} moved"
    );
    finish(&ctx);
}

#[test]
fn non_finite_values_stop_training_with_a_clear_error() {
    let ctx = context();
    let dir = demo_data("nan", 24);
    let train = data::load_split(dir.path(), "train", 1.0, [1.0; 3]).unwrap();
    let cfg = quick(5);
    let mut init = uniform_grid(&TrainConfig {
        grid_level: 3,
        ..cfg.clone()
    })
    .unwrap();
    // Finite but extreme densities overflow f32 inside the frame (the normal's centre
    // gradient): NaN reaches the gradients, and the trainer must say so.
    for (i, g) in init.geo.iter_mut().enumerate() {
        *g = if i % 2 == 0 { 3e38 } else { -3e38 };
    }
    init.validate().unwrap();
    let mut t = Trainer::new(
        &ctx,
        TrainConfig {
            grid_level: 3,
            ..cfg
        },
        &train,
        Some(init),
    )
    .unwrap();
    t.step(false).unwrap();
    let e = t.check_finite().unwrap_err().to_string();
    assert!(
        e.contains("NaN or infinite") && e.contains("learning rate"),
        "{e}"
    );
    // Bad training input: an empty split and a mismatched image.
    let mut empty = train.clone();
    empty.frames.clear();
    let e = Trainer::new(&ctx, quick(5), &empty, None)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("no frames"), "{e}");
    let mut odd = train.clone();
    odd.frames[3].rgb.pop();
    let e = Trainer::new(&ctx, quick(5), &odd, None)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("pixels, but its camera is"), "{e}");
    finish(&ctx);
}

#[test]
fn a_grid_too_large_for_the_device_is_refused_before_it_is_built() {
    let ctx = context();
    let dir = demo_data("big", 16);
    let train = data::load_split(dir.path(), "train", 1.0, [1.0; 3]).unwrap();
    let mut cfg = quick(5);
    cfg.grid_level = 8; // 16.7 M voxels; degree-3 SH need 3.0 GB in one buffer
    let need = (1u64 << 24) * 15 * 12;
    let limit = ctx.info().max_memory_allocation_size;
    if limit >= need {
        println!("skipped: this device allocates {limit} bytes at once (≥ {need})");
    } else {
        let t0 = std::time::Instant::now();
        let e = Trainer::new(&ctx, cfg, &train, None)
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("grid_level=7") && e.contains("allocation limit"),
            "{e}"
        );
        assert!(
            t0.elapsed().as_secs() < 5,
            "refused only after building the grid"
        );
    }
    finish(&ctx);
}

/// Training views packed into several device buffers land whole and in order: every
/// view read back at its (buffer, offset) is its frame in planar RGB, chunks hold at
/// most the requested bytes (a view larger than that gets a chunk of its own), and the
/// address is the buffer's plus the offset.
#[test]
fn training_views_pack_into_chunks() {
    use svraster::data::{Dataset, Frame};
    use svraster::train::views::TrainViews;
    let ctx = context();
    // Views of different sizes (a capture with several cameras): 35, 48, 45, 42 and 40
    // pixels, 12 bytes each.
    let sizes = [(7u32, 5u32), (8, 6), (9, 5), (7, 6), (8, 5)];
    let mut rng = common::Rng(11);
    let frames: Vec<Frame> = sizes
        .iter()
        .enumerate()
        .map(|(k, &(w, h))| Frame {
            name: format!("v{k}"),
            camera: svraster::data::Camera::look_at(
                [0.0, -4.0, 0.0],
                [0.0; 3],
                [0.0, 0.0, 1.0],
                0.7,
                w,
                h,
            ),
            rgb: (0..w * h)
                .map(|_| std::array::from_fn(|_| rng.unit() as f32))
                .collect(),
        })
        .collect();
    let data = Dataset {
        frames,
        width: 8,
        height: 6,
        background: [1.0; 3],
        alpha: true,
        split: "train".into(),
        points: Vec::new(),
        sphere: None,
    };
    // 1000 bytes: [420 + 576], [540] (+ 504 would be 1044), [504 + 480].
    for (chunk_bytes, want_chunks) in [(1000, 3), (200, 5), (1 << 30, 1)] {
        let views = TrainViews::upload(&ctx, &data, chunk_bytes).unwrap();
        assert_eq!(views.len(), 5);
        assert_eq!(views.chunks(), want_chunks, "chunk limit {chunk_bytes}");
        for (k, f) in data.frames.iter().enumerate() {
            let np = f.rgb.len();
            let view_bytes = (3 * np * 4) as u64;
            let (buf, offset) = views.locate(k);
            assert!(offset + view_bytes <= buf.size());
            assert!(want_chunks == 5 || buf.size() <= chunk_bytes);
            assert_eq!(views.address(k), buf.address() + offset);
            let got: Vec<f32> = ctx.download(buf, offset, 3 * np).unwrap();
            for p in 0..np {
                for c in 0..3 {
                    assert_eq!(
                        got[c * np + p],
                        f.rgb[p][c],
                        "view {k} pixel {p} channel {c}"
                    );
                }
            }
        }
    }
    // A frame of the wrong size is named.
    let mut bad = data.clone();
    bad.frames[3].rgb.pop();
    let e = TrainViews::upload(&ctx, &bad, 1 << 20).err().unwrap();
    assert!(e.to_string().contains("v3"), "{e}");
    finish(&ctx);
}
