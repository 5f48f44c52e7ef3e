//! Reports shared by `bench render` and `bench train`: queue traffic per iteration or
//! frame, tile-list balance, walk workgroups and the walks' work counters.

use svraster::eval::median;
use svraster::raster::{WalkCounters, WorkCounters};

/// What the host spends per timed iteration or frame besides the kernels: queue
/// submissions, blocking fence waits (the queue drained), throttle waits (for an older
/// submission while a newer one runs) and the milliseconds it was busy outside both
/// (recording, submitting, reading mapped results; on a CPU device the waits hold the
/// kernels' own time, so there `host_ms` is what the host adds on top).
#[derive(Default)]
pub(super) struct QueueCost {
    submits: Vec<f64>,
    waits: Vec<f64>,
    wait_ms: Vec<f64>,
    throttles: Vec<f64>,
    throttle_ms: Vec<f64>,
    host_ms: Vec<f64>,
}

impl QueueCost {
    pub(super) fn push(&mut self, c: svraster::gpu::QueueCounters, wall_ms: f64) {
        self.submits.push(c.submits as f64);
        self.waits.push(c.fence_waits as f64);
        self.wait_ms.push(c.wait_ms);
        self.throttles.push(c.throttle_waits as f64);
        self.throttle_ms.push(c.throttle_ms);
        self.host_ms
            .push((wall_ms - c.wait_ms - c.throttle_ms).max(0.0));
    }
    pub(super) fn json(&self) -> serde_json::Value {
        let max = |v: &[f64]| v.iter().cloned().fold(0.0, f64::max);
        serde_json::json!({
            "submits_median": median(&self.submits),
            "submits_max": max(&self.submits),
            "fence_waits_median": median(&self.waits),
            "fence_waits_max": max(&self.waits),
            "wait_ms_median": median(&self.wait_ms),
            "throttle_waits_median": median(&self.throttles),
            "throttle_waits_max": max(&self.throttles),
            "throttle_ms_median": median(&self.throttle_ms),
            "host_ms_median": median(&self.host_ms),
        })
    }
    pub(super) fn text(&self) -> String {
        format!(
            "{:.0} submissions, {:.0} fence waits ({:.2} ms blocked), {:.0} throttle waits \
             ({:.2} ms), host {:.2} ms outside waits (medians)",
            median(&self.submits),
            median(&self.waits),
            median(&self.wait_ms),
            median(&self.throttles),
            median(&self.throttle_ms),
            median(&self.host_ms)
        )
    }
}

/// Workgroups of the frame's walk dispatch: one per tile, or with segments one per slot.
pub(super) fn walk_workgroups(st: &svraster::raster::FrameStats) -> f64 {
    f64::from(if st.slots > 0 { st.slots } else { st.tiles })
}

/// Longest tile list over the mean list of the frame's tiles (1: perfectly even; the
/// walk's one workgroup per tile waits for the longest).
pub(super) fn tile_balance(st: &svraster::raster::FrameStats) -> f64 {
    let mean = st.entries_used as f64 / f64::from(st.tiles.max(1));
    if mean > 0.0 {
        f64::from(st.max_tile_entries) / mean
    } else {
        0.0
    }
}

/// Mean of the per-iteration (or per-frame) counters.
pub(super) fn mean_counters(c: &[WorkCounters]) -> WorkCounters {
    fn mean(v: impl Iterator<Item = u64>, n: usize) -> u64 {
        (v.sum::<u64>() as f64 / n.max(1) as f64).round() as u64
    }
    let n = c.len();
    let walk = |f: fn(&WorkCounters) -> &WalkCounters| WalkCounters {
        trips: mean(c.iter().map(|x| f(x).trips), n),
        useful_trips: mean(c.iter().map(|x| f(x).useful_trips), n),
        full_walk_trips: mean(c.iter().map(|x| f(x).full_walk_trips), n),
        pairs: mean(c.iter().map(|x| f(x).pairs), n),
        crossings: mean(c.iter().map(|x| f(x).crossings), n),
        contributions: mean(c.iter().map(|x| f(x).contributions), n),
        builds: mean(c.iter().map(|x| f(x).builds), n),
        subgroups: mean(c.iter().map(|x| f(x).subgroups), n),
        body_runs: mean(c.iter().map(|x| f(x).body_runs), n),
        lane_max_crossings: mean(c.iter().map(|x| f(x).lane_max_crossings), n),
    };
    WorkCounters {
        forward: walk(|x| &x.forward),
        backward: walk(|x| &x.backward),
    }
}

pub(super) fn walk_json(w: &WalkCounters) -> serde_json::Value {
    serde_json::json!({
        "subgroup_trips": w.trips,
        "useful_trips": w.useful_trips,
        "full_walk_trips": w.full_walk_trips,
        "pairs_past_rectangle": w.pairs,
        "ray_voxel_crossings": w.crossings,
        "contributions": w.contributions,
        "visit_set_builds": w.builds,
        "body_runs": w.body_runs,
        "lane_max_crossings": w.lane_max_crossings,
        "trips_per_useful_trip": w.trips_per_useful(),
        "full_walk_trips_per_useful_trip": if w.useful_trips == 0 { 0.0 } else {
            w.full_walk_trips as f64 / w.useful_trips as f64 },
    })
}

pub(super) fn work_json(w: &WorkCounters) -> serde_json::Value {
    serde_json::json!({ "forward": walk_json(&w.forward), "backward": walk_json(&w.backward) })
}

/// Prints the walks' work `per` frame or iteration.
pub(super) fn print_work(w: &WorkCounters, subgroup: u32, per: &str) {
    println!("  work per {per} ({subgroup}-lane subgroups; trips = a subgroup visiting an entry):");
    for (name, c) in [("forward", &w.forward), ("backward", &w.backward)] {
        if c.subgroups == 0 {
            continue;
        }
        println!(
            "    {name:<8} trips {} ({:.2} per useful trip; the full walk: {} = {:.1}×), pairs {}, crossings {}, contributions {}",
            c.trips,
            c.trips_per_useful(),
            c.full_walk_trips,
            c.full_walk_trips as f64 / c.useful_trips.max(1) as f64,
            c.pairs,
            c.crossings,
            c.contributions
        );
        if c.body_runs > 0 {
            println!(
                "    {:<8} compositing body runs {} (a lane's crossing ran it for the subgroup); \
                 over per-lane lists of crossings: {} ({:.2}×)",
                "",
                c.body_runs,
                c.lane_max_crossings,
                c.lane_max_crossings as f64 / c.body_runs as f64
            );
        }
    }
}
