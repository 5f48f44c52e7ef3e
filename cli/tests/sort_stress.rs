//! Look-back correctness under real concurrency: lavapipe runs workgroups on
//! LP_NUM_THREADS worker threads (1 thread hides races; more threads than cores means
//! a tile's predecessor can be descheduled mid-tile, so the recount fallback runs). The
//! same 2^20 sort (hundreds of workgroups, far more than run at once) is run 20 times by
//! the CLI bench, which verifies every run, under validation — with the direct pass
//! and with the coalesced pass GPUs take (`c128`: the body of `c256` at 128
//! invocations, which 8-lane subgroups support), and once with the reduce-then-scan
//! pass (`s128`), whose workgroups never wait on each other.

use std::process::Command;

fn run(threads: &str, pass: &str) -> serde_json::Value {
    run_with(threads, pass, &[])
}

fn run_with(threads: &str, pass: &str, extra: &[&str]) -> serde_json::Value {
    let out = Command::new(env!("CARGO_BIN_EXE_svraster"))
        .args([
            "--validation",
            "bench",
            "sort",
            "--n",
            "1048576",
            "--runs",
            "20",
            "--warmup",
            "0",
            "--json",
            "--pass",
            pass,
        ])
        .args(extra)
        .env("LP_NUM_THREADS", threads)
        .output()
        .expect("run svraster");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "LP_NUM_THREADS={threads} pass {pass}: svraster failed\n{stderr}\n{stdout}"
    );
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("bench JSON");
    assert_eq!(
        v["failed_runs"], 0,
        "LP_NUM_THREADS={threads} pass {pass}: {stdout}"
    );
    if pass != "auto" {
        assert_eq!(v["pass_kernel"], pass);
    }
    assert_eq!(v["verified"], true);
    assert_eq!(v["runs"], 20);
    v
}

#[test]
fn repeated_sort_two_threads() {
    run("2", "direct");
    run("2", "c128");
    // The device's own choice (c256 on GPUs with ≥ 16-lane subgroups).
    run("2", "auto");
}

#[test]
fn repeated_sort_four_threads() {
    run("4", "direct");
    run("4", "c128");
    // `--spin 0`: every predecessor not yet published is recounted at once, so the
    // fallback runs in every pass that meets one — and the result is still verified.
    let v = run_with("4", "c128", &["--spin", "0"]);
    assert_eq!(v["spin_limit"], 0, "{v}");
    assert!(
        v["lookback"]["fallbacks_per_run"].as_f64().unwrap() > 0.0,
        "no fallback with --spin 0: {v}"
    );
    // Seven histogram workgroups for 256 blocks of keys: each counts ~37 blocks while
    // the others add to the same global counts.
    let v = run_with("4", "direct", &["--hist-groups", "7"]);
    assert_eq!(v["hist_groups"], 7, "{v}");
    // Reduce-then-scan: no look-back at all, its count and scan timed apart.
    let v = run("4", "s128");
    assert_eq!(v["lookback"]["steps_per_digit_tile"], 0.0, "{v}");
    assert!(v["stages_median_ms"]["sort.count0"].is_number(), "{v}");
}

#[test]
fn repeated_sort_eight_threads() {
    run("8", "direct");
    run("8", "c128");
    // The coalesced pass reading 8 look-back words at once: walks of several words
    // (steps > 1 per digit and tile) taken from one window; busy rounds between polls.
    let v = run_with("8", "c128", &["--window", "8", "--backoff", "16"]);
    assert_eq!(v["lookback_window"], 8, "{v}");
    assert_eq!(v["lookback_backoff"], 16, "{v}");
    assert!(
        v["lookback"]["steps_per_digit_tile"].as_f64().unwrap() > 1.0,
        "{v}"
    );
}
