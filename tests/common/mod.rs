//! Shared test helpers: a validated context, deterministic random data, and the f64/
//! plain-Rust references the GPU results are checked against.
#![allow(dead_code)]

use svraster::gpu::{Context, ContextOptions};

/// A context on the default device (lavapipe in CI) with the Khronos validation layer.
/// Tests call [`finish`] at the end: any validation message fails the test.
pub fn context() -> Context {
    Context::new(&ContextOptions {
        device: None,
        validation: true,
    })
    .expect("cannot create a Vulkan context with validation (see README: Requirements)")
}

/// Asserts that validation reported nothing.
pub fn finish(ctx: &Context) {
    let n = ctx.validation_messages();
    assert_eq!(
        n,
        0,
        "validation messages:\n{}",
        ctx.validation_log().join("\n")
    );
}

/// SplitMix64: small, seedable, good enough for test data.
pub struct Rng(pub u64);
impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n
    }
}

/// The reference for a stable sort by bits `lo..hi`: Rust's stable `sort_by_key` on
/// the extracted bits, carrying the values.
pub fn reference_sort(keys: &[u64], values: &[u32], lo: u32, hi: u32) -> (Vec<u64>, Vec<u32>) {
    let mask = if hi - lo == 64 {
        u64::MAX
    } else {
        (1u64 << (hi - lo)) - 1
    };
    let mut pairs: Vec<(u64, u32)> = keys.iter().copied().zip(values.iter().copied()).collect();
    pairs.sort_by_key(|&(k, _)| (k >> lo) & mask);
    pairs.into_iter().unzip()
}

/// The reference exclusive scan (wrapping u32) and its total.
pub fn reference_scan(data: &[u32]) -> (Vec<u32>, u32) {
    let mut run = 0u32;
    let out = data
        .iter()
        .map(|&x| {
            let r = run;
            run = run.wrapping_add(x);
            r
        })
        .collect();
    (out, run)
}
