//! Look-back correctness under real concurrency: lavapipe runs workgroups on
//! LP_NUM_THREADS worker threads (1 thread hides races). The same 2^20 sort is run 20
//! times by the CLI bench, which verifies every run, under validation.

use std::process::Command;

fn run(threads: &str) {
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
        ])
        .env("LP_NUM_THREADS", threads)
        .output()
        .expect("run svraster");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "LP_NUM_THREADS={threads}: svraster failed\n{stderr}\n{stdout}"
    );
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("bench JSON");
    assert_eq!(v["failed_runs"], 0, "LP_NUM_THREADS={threads}: {stdout}");
    assert_eq!(v["verified"], true);
    assert_eq!(v["runs"], 20);
}

#[test]
fn repeated_sort_two_threads() {
    run("2");
}

#[test]
fn repeated_sort_four_threads() {
    run("4");
}
