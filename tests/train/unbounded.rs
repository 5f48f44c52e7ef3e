use super::*;

/// A capture trains the same whatever its world's scale and offset (COLMAP's are
/// arbitrary): the demo scene's cameras moved 10⁴ units away and the scene shrunk to a
/// thousandth give the same main region in the model frame, the same layout and the same
/// held-out PSNR, with the unbounded preset (main region from the cameras, background
/// shells) at a small size.
#[test]
fn unbounded_training_is_invariant_to_the_world_frame() {
    let ctx = context();
    let dir = demo_data("world", 32);
    let train = data::load_split(dir.path(), "train", 1.0, [0.0; 3]).unwrap();
    let val = data::load_split(dir.path(), "val", 1.0, [0.0; 3]).unwrap();
    let moved = |ds: &data::Dataset, offset: f64, scale: f64| {
        let mut ds = ds.clone();
        for f in &mut ds.frames {
            for row in &mut f.camera.c2w {
                row[3] = row[3] * scale + offset;
            }
            f.camera.near *= scale;
        }
        ds
    };
    // The real preset's background from the photos needs opaque photos: the demo's
    // carry alpha (composited over black) and are refused; a colour given turns it off.
    let mut cfg = TrainConfig::preset("real").unwrap();
    let e = svraster::train::bounds::resolve_run(&mut cfg, &mut train.clone())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("carry alpha") && e.contains("background=[r,g,b]"),
        "{e}"
    );
    cfg.set("background=[0.1,0.2,0.3]").unwrap();
    assert!(!cfg.background_from_photos);
    svraster::train::bounds::resolve_run(&mut cfg, &mut train.clone()).unwrap();
    assert_eq!(cfg.background, [0.1, 0.2, 0.3]);
    let mut results = Vec::new();
    for (offset, scale) in [(0.0, 1.0), (1.0e4, 1.0e-3)] {
        let mut t = moved(&train, offset, scale);
        let mut v = moved(&val, offset, scale);
        let mut cfg = TrainConfig::preset("real").unwrap();
        cfg.iters = 150;
        cfg.grid_level = 4;
        cfg.outside_level = 2;
        cfg.ss = 1.0;
        // The demo's RGBA photos are composited over black: the model's background.
        cfg.set("background=[0,0,0]").unwrap();
        let region = svraster::train::bounds::resolve_run(&mut cfg, &mut t)
            .unwrap()
            .unwrap();
        assert_eq!(region.mode, "camera_median");
        let mut tr = Trainer::new(&ctx, cfg.clone(), &t, None).unwrap();
        for i in 0..cfg.iters {
            tr.step(i + 1 == cfg.iters).unwrap();
        }
        let scene = tr.scene().unwrap();
        v.to_model(&scene.world);
        let psnr = mean_psnr(&ctx, &scene, &v);
        println!(
            "offset {offset:e}, scale {scale:e}: region radius {:.6e}, {} voxels, val PSNR {psnr:.3} dB",
            region.radius,
            scene.num_voxels()
        );
        results.push((region.radius / scale, scene.num_voxels(), psnr));
    }
    let (a, b) = (results[0], results[1]);
    assert!((a.0 - b.0).abs() < 1e-6 * a.0, "{a:?} vs {b:?}");
    // Pruning thresholds see float atomics' summation order: a few voxels may differ.
    assert!(
        a.1.abs_diff(b.1) * 100 <= a.1,
        "layouts differ: {a:?} vs {b:?}"
    );
    assert!((a.2 - b.2).abs() < 0.05, "{a:?} vs {b:?}");
    assert!(a.2 > 14.0, "{a:?}");
    finish(&ctx);
}

/// The mesh preset's depth–normal losses (paper §3.2.3) do what they are for: with them
/// the rendered normals agree better with the normals of the rendered depth, at a small
/// colour cost. Both runs measure the terms (the reference run with a weight too small
/// to act).
#[test]
fn depth_normal_losses_make_normals_agree_with_depth() {
    let ctx = context();
    let dir = demo_data("normals", 48);
    let train = data::load_split(dir.path(), "train", 1.0, [1.0; 3]).unwrap();
    let val = data::load_split(dir.path(), "val", 1.0, [1.0; 3]).unwrap();
    let run = |lambda: f32| {
        let mut cfg = quick(300);
        cfg.lambda_normal_dmed = lambda;
        cfg.lambda_normal_dmean = lambda;
        cfg.normal_dmed_from = 0.0;
        cfg.normal_dmean_from = 0.0;
        let init = uniform_grid(&cfg).unwrap();
        let mut t = Trainer::new(&ctx, cfg.clone(), &train, Some(init)).unwrap();
        let (mut med, mut mean, mut n) = (0.0, 0.0, 0);
        for i in 0..cfg.iters {
            let info = t.step(i + 60 >= cfg.iters && i % 4 == 0).unwrap();
            if let Some(l) = info.losses {
                assert!(l.loss.is_finite() && l.normal_dmed > 0.0);
                med += l.normal_dmed;
                mean += l.normal_dmean;
                n += 1;
            }
        }
        t.check_finite().unwrap();
        let psnr = mean_psnr(&ctx, &t.scene().unwrap(), &val);
        (med / n as f64, mean / n as f64, psnr)
    };
    let (med0, mean0, p0) = run(1e-7);
    let (med1, mean1, p1) = run(0.01);
    println!(
        "without: 1−N·n_med {med0:.4}, α²−αN·n_mean {mean0:.4}, val {p0:.2} dB; \
         with: {med1:.4}, {mean1:.4}, {p1:.2} dB"
    );
    assert!(med1 < 0.7 * med0, "median-depth term {med0:.4} → {med1:.4}");
    assert!(
        mean1 < 0.7 * mean0,
        "mean-depth term {mean0:.4} → {mean1:.4}"
    );
    assert!(p1 > p0 - 1.5, "val PSNR {p0:.2} → {p1:.2}");
    finish(&ctx);
}

/// The default voxel budget follows what the device's memory budget
/// (VK_EXT_memory_budget) leaves this process when the run starts — half of it, capped
/// by one allocation and the voxel ids; the heap without the extension — and an
/// explicit max_voxels wins. (Checked on one reading: the live budget moves with every
/// process's allocations.)
#[test]
fn voxel_budget_follows_the_device_memory_budget() {
    use svraster::gpu::{DeviceInfo, MemoryBudget};
    use svraster::train::trainer::{voxel_budget, voxel_budget_with};
    let ctx = context();
    let info = ctx.info();
    let Some(reading) = ctx.memory_budget() else {
        eprintln!(
            "skipped: {} does not offer VK_EXT_memory_budget (the heap size is used)",
            info.name
        );
        return;
    };
    assert_eq!(reading.heap_bytes, info.device_local_heap_bytes);
    let mut cfg = TrainConfig::preset("quick").unwrap();
    cfg.sh_degree = 0; // per-voxel buffers small enough that memory, not one allocation, limits
                       // The rules on this device's limits, and on an H200's (143 GB heap, 4 GiB per
                       // allocation: there the allocation cap binds until little memory is left).
    let h200 = DeviceInfo {
        device_local_heap_bytes: 143_000_000_000,
        max_memory_allocation_size: 4 << 30,
        ..info.clone()
    };
    let h200_reading = MemoryBudget {
        heap_bytes: h200.device_local_heap_bytes,
        budget_bytes: 140_000_000_000,
        usage_bytes: 600 << 20,
    };
    for (info, reading) in [(info, reading), (&h200, h200_reading)] {
        let expect = |bytes: u64| expect_budget(info, bytes);
        let b0 = voxel_budget_with(info, Some(reading), &cfg);
        assert_eq!(b0, expect(reading.available_bytes()));
        // Far more in use (another process, or this one): 256 MiB left, where the memory
        // and not the allocation cap binds on any device (with "4 GiB more in use" the
        // cap still bound on an H200, and the budget did not shrink).
        let busier = MemoryBudget {
            usage_bytes: reading.budget_bytes.saturating_sub(256 << 20),
            ..reading
        };
        assert!(busier.available_bytes() < reading.available_bytes());
        let b1 = voxel_budget_with(info, Some(busier), &cfg);
        assert_eq!(b1, expect(busier.available_bytes()));
        assert!(b1 < b0, "{}: {b1} !< {b0}", info.device_local_heap_bytes);
        // Without the extension: the heap.
        assert_eq!(
            voxel_budget_with(info, None, &cfg),
            expect(info.device_local_heap_bytes)
        );
    }
    let live = voxel_budget(&ctx, &cfg);
    assert!(
        live > 0 && live <= expect_budget(info, reading.budget_bytes),
        "{live}"
    );
    cfg.max_voxels = 1234;
    assert_eq!(voxel_budget(&ctx, &cfg), 1234);
    finish(&ctx);
}

/// Training with the frame-mean background (`background_frame_mean`, SVRaster's for
/// captures neither white nor black): the real preset's small run trains (val PSNR of
/// the demo, whose photos are composited over black, above 14 dB), the model and its
/// checkpoint keep the setting, and giving a colour turns it off.
#[test]
fn frame_mean_background_trains_and_is_kept() {
    let ctx = context();
    let dir = demo_data("frame-mean", 32);
    let mut train = data::load_split(dir.path(), "train", 1.0, [0.0; 3]).unwrap();
    let mut val = data::load_split(dir.path(), "val", 1.0, [0.0; 3]).unwrap();
    let mut cfg = TrainConfig::preset("real").unwrap();
    cfg.set("background_frame_mean=true").unwrap();
    cfg.set("background=[0,0,0]").unwrap();
    assert!(!cfg.background_frame_mean, "a colour given turns it off");
    cfg.set("background_frame_mean=true").unwrap();
    cfg.iters = 150;
    cfg.grid_level = 4;
    cfg.outside_level = 2;
    cfg.ss = 1.0;
    svraster::train::bounds::resolve_run(&mut cfg, &mut train).unwrap();
    let mut tr = Trainer::new(&ctx, cfg.clone(), &train, None).unwrap();
    for i in 0..cfg.iters {
        tr.step(i + 1 == cfg.iters).unwrap();
    }
    let scene = tr.scene().unwrap();
    assert!(scene.background_frame_mean);
    val.to_model(&scene.world);
    let psnr = mean_psnr(&ctx, &scene, &val);
    println!(
        "frame-mean background: val PSNR {psnr:.2} dB, {} voxels",
        scene.num_voxels()
    );
    assert!(psnr > 14.0, "{psnr}");
    let file = dir.path().join("fm.safetensors");
    svraster::scene::checkpoint::save(&scene, &file).unwrap();
    assert!(
        svraster::scene::checkpoint::load(&file)
            .unwrap()
            .background_frame_mean
    );
    finish(&ctx);
}
