//! The trainer end to end on the procedural demo scene (the CI training smoke test),
//! its schedule, reproducibility and failure handling.

use crate::common;

use common::{context, finish, mean_psnr};
use svraster::data::{self, demo};
use svraster::scene::Scene;
use svraster::train::config::TrainConfig;
use svraster::train::trainer::{uniform_grid, StageTimes, Trainer};
use tempfile::TempDir;

/// The demo dataset in a fresh directory named `svraster-train-<name>-…`, removed when
/// dropped.
fn demo_data(name: &str, size: u32) -> TempDir {
    let dir = tempfile::Builder::new()
        .prefix(&format!("svraster-train-{name}-"))
        .tempdir()
        .unwrap();
    demo::write_dataset(
        dir.path(),
        &demo::DemoOptions {
            width: size,
            height: size,
            train: 40,
            val: 6,
            test: 1,
            seed: 3,
        },
    )
    .unwrap();
    dir
}

fn quick(iters: u32) -> TrainConfig {
    let mut cfg = TrainConfig::preset("quick").unwrap();
    cfg.iters = iters;
    cfg.grid_level = 5;
    cfg
}

/// A training iteration is one submission and one fence wait where the device has
/// conditional rendering (lavapipe has it): the frame, its checks and the update in one
/// command buffer, the update skipped on the GPU when the frame comes out incomplete and
/// the iteration run again with grown buffers. Tiny dispatch chunks make the first
/// frames incomplete; the model is then bit for bit the one of the two-submission path
/// (the frame checked on the host before the update is recorded), under the ordered
/// reduction. Fails if an incomplete frame's update is not skipped (the models differ),
/// or if an iteration submits or waits more than once.
#[test]
fn one_submission_per_iteration_same_model_as_two() {
    let ctx = context();
    if !ctx.info().conditional_rendering {
        eprintln!(
            "skipped: {} has no conditional rendering (iterations take two submissions)",
            ctx.info().name
        );
        return;
    }
    let dir = demo_data("single", 32);
    let train = data::load_split(dir.path(), "train", 1.0, [1.0; 3]).unwrap();
    // (single submission, queued behind the next, stage timestamps) → model, redone
    // frames, per iteration without a redo: (submissions, fence waits, throttle waits),
    // and the stage times of every settled iteration.
    type Run = (Scene, u64, Vec<(u64, u64, u64)>, Vec<StageTimes>);
    let run = |single: bool, queued: bool, timing: bool| -> Run {
        let mut cfg = quick(12);
        cfg.grid_level = 4;
        cfg.ss = 3.0;
        cfg.ss_from = 0.0;
        cfg.deterministic = true;
        let mut t = Trainer::new(&ctx, cfg.clone(), &train, None).unwrap();
        t.set_single_submission(single).unwrap();
        t.set_pipelined(queued).unwrap();
        t.set_chunk_size(16);
        // Chunks split the unsegmented walks; a GPU's default segments never run short.
        t.set_segment_entries(0).unwrap();
        if timing {
            t.enable_timing().unwrap();
        }
        let mut per_iter = Vec::new();
        let mut times = Vec::new();
        for i in 0..cfg.iters {
            let c0 = ctx.queue_counters();
            let redone = t.frames_redone();
            // A logged iteration in the middle waits for the queue (and is not steady).
            let measure = i == 6;
            t.step(measure).unwrap();
            let c = ctx.queue_counters() - c0;
            if t.frames_redone() == redone && !measure {
                per_iter.push((c.submits, c.fence_waits, c.throttle_waits));
            }
            times.extend(t.take_stage_times());
        }
        t.check_finite().unwrap();
        times.extend(t.take_stage_times());
        (t.scene().unwrap(), t.frames_redone(), per_iter, times)
    };
    let (queued, redone_queued, costs_queued, _) = run(true, true, false);
    let (one, redone_one, costs_one, _) = run(true, false, false);
    let (two, redone_two, costs_two, _) = run(false, false, false);
    // Stage timestamps keep the iterations queued, and time each one once.
    let (timed, redone_timed, costs_timed, times) = run(true, true, true);
    println!(
        "redone: {redone_queued} (queued), {redone_one} (one submission), {redone_two} (two); \
         steady iterations (submits, waits, throttles): {costs_queued:?} vs {costs_one:?} \
         vs {costs_two:?}"
    );
    assert!(
        redone_one > 0,
        "the small chunks must make some frames incomplete"
    );
    assert_eq!(redone_one, redone_two);
    // Frames grow while an iteration is queued behind the incomplete one: its update
    // must be skipped with it (the go words chain), or the models below differ.
    assert!(redone_queued > 0);
    assert!(costs_queued.len() >= 3, "{costs_queued:?}");
    // The first iteration has nothing before it to wait for; every later steady one
    // waits only for the iteration before it, while its own runs.
    assert!(
        costs_queued
            .iter()
            .all(|&c| c == (1, 0, 1) || c == (1, 0, 0)),
        "a queued iteration is one submission and no drain: {costs_queued:?}"
    );
    assert!(!costs_one.is_empty());
    assert!(
        costs_one.iter().all(|&c| c == (1, 1, 0)),
        "an iteration without growth is one submission and one wait: {costs_one:?}"
    );
    assert!(costs_two.iter().all(|&c| c == (2, 2, 0)), "{costs_two:?}");
    assert_eq!(redone_timed, redone_queued);
    assert!(
        costs_timed.len() == costs_queued.len()
            && costs_timed
                .iter()
                .all(|&c| c == (1, 0, 1) || c == (1, 0, 0)),
        "timestamps changed the queue traffic: {costs_timed:?} vs {costs_queued:?}"
    );
    assert_eq!(
        times.len(),
        12,
        "one set of stage times per iteration (redone ones included)"
    );
    for (i, st) in times.iter().enumerate() {
        let names: Vec<&str> = st.iter().map(|(n, _)| n.as_str()).collect();
        for stage in ["sort", "composite", "backward.walk", "optimizer.geo"] {
            assert!(
                names.contains(&stage),
                "settled iteration {i}: no {stage} in {names:?}"
            );
        }
        assert!(
            st.iter().all(|(_, ms)| ms.is_finite() && *ms >= 0.0),
            "settled iteration {i}: {st:?}"
        );
    }
    let same = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
    for (name, m) in [
        ("queued", &queued),
        ("two submissions", &two),
        ("queued with timestamps", &timed),
    ] {
        assert!(same(&one.geo, &m.geo), "densities differ ({name})");
        assert!(
            same(one.sh0.as_flattened(), m.sh0.as_flattened()),
            "base colours differ ({name})"
        );
        assert!(same(&one.shs, &m.shs), "SH coefficients differ ({name})");
    }
    finish(&ctx);
}

/// The budget rule for `bytes` of memory on `info` (degree-0 SH): half of it, capped by
/// one allocation (8 candidate keys per voxel) and the voxel ids.
fn expect_budget(info: &svraster::gpu::DeviceInfo, bytes: u64) -> u64 {
    let mut b = bytes / 2 / svraster::train::trainer::bytes_per_voxel(0);
    if info.max_memory_allocation_size > 0 {
        b = b.min(info.max_memory_allocation_size / 64);
    }
    b.min(svraster::scene::MAX_VOXELS as u64)
}

mod training;
mod unbounded;
