//! 8-bit quantization of a model's parameters for smaller checkpoints (as SVRaster's
//! `--save_quantized`): every channel — the grid points' densities, each of the 3 DC
//! colour channels, each of the `3·((D+1)²−1)` higher SH channels — gets its own
//! codebook of 256 values, and each value is stored as the index of its nearest entry.
//!
//! The codebook of a channel is a 1-D k-means (Lloyd's algorithm) of its values, run
//! to convergence from two starts — the means of 256 equal-count slices of the sorted
//! values (the reference's start, which it refines by moving single values between
//! neighbours) and 256 uniform levels over the range — keeping the one with the lower
//! squared error: on a compact distribution the equal-count start converges to a worse
//! local optimum than uniform levels (measured in `tests/checkpoint/`). On sorted
//! values Lloyd's steps are exact and cheap: the cells are the intervals between the
//! midpoints of adjacent centroids, found by binary search, and their means come from
//! prefix sums.

/// Entries per codebook.
pub const CODES: usize = 256;

/// One channel's codebook (ascending) and the code of each value.
#[derive(Clone, Debug, PartialEq)]
pub struct Quantized {
    pub codebook: [f32; CODES],
    pub codes: Vec<u8>,
}

/// Quantizes one channel.
pub fn kmeans8(values: &[f32]) -> Quantized {
    let mut sorted: Vec<f64> = values.iter().map(|&v| v as f64).collect();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    let codebook: [f32; CODES] = if n == 0 {
        [0.0; CODES]
    } else {
        // Prefix sums of x and x² (f64): cell means and squared errors in O(1).
        let mut s1 = Vec::with_capacity(n + 1);
        let mut s2 = Vec::with_capacity(n + 1);
        s1.push(0f64);
        s2.push(0f64);
        for &v in &sorted {
            s1.push(s1.last().unwrap() + v);
            s2.push(s2.last().unwrap() + v * v);
        }
        let (lo, hi) = (sorted[0], sorted[n - 1]);
        // Two starts — 256 equal-count slices (dense where the values are) and 256
        // uniform levels (even over the range) — refined to convergence; the lower
        // squared error wins.
        let slices: [f64; CODES] = std::array::from_fn(|k| {
            let (a, b) = (k * n / CODES, ((k + 1) * n / CODES).max(k * n / CODES + 1));
            (s1[b.min(n)] - s1[a.min(n - 1)]) / (b.min(n) - a.min(n - 1)) as f64
        });
        let uniform: [f64; CODES] =
            std::array::from_fn(|k| lo + (hi - lo) * (k as f64 + 0.5) / CODES as f64);
        let a = lloyd(&sorted, &s1, &s2, slices);
        let b = lloyd(&sorted, &s1, &s2, uniform);
        let best = if a.1 <= b.1 { a.0 } else { b.0 };
        std::array::from_fn(|k| best[k] as f32)
    };
    let codes = values.iter().map(|&v| nearest(&codebook, v)).collect();
    Quantized { codebook, codes }
}

/// Lloyd's algorithm on sorted values from `centres` (ascending): cells between the
/// midpoints of adjacent centres, centres to the cells' means, until no cell boundary
/// moves (at most 2 000 rounds, each O(256 log n)). Returns the centres and the sum
/// of squared errors.
fn lloyd(sorted: &[f64], s1: &[f64], s2: &[f64], mut centres: [f64; CODES]) -> ([f64; CODES], f64) {
    let n = sorted.len();
    let mut bounds = vec![usize::MAX; CODES + 1];
    for _ in 0..2000 {
        let mut next = vec![0usize; CODES + 1];
        next[CODES] = n;
        for k in 1..CODES {
            let mid = 0.5 * (centres[k - 1] + centres[k]);
            next[k] = sorted.partition_point(|&v| v <= mid).max(next[k - 1]);
        }
        if next == bounds {
            break;
        }
        bounds = next;
        let mut last = sorted[0];
        for k in 0..CODES {
            let (a, b) = (bounds[k], bounds[k + 1]);
            if b > a {
                last = (s1[b] - s1[a]) / (b - a) as f64;
            }
            // An empty cell keeps the centre of the cell before it (a duplicate entry,
            // never chosen over its twin), so the centres stay ascending.
            centres[k] = if b > a { last } else { centres[k].max(last) };
        }
        for k in 1..CODES {
            centres[k] = centres[k].max(centres[k - 1]);
        }
    }
    let sse = (0..CODES)
        .map(|k| {
            let (a, b) = (bounds[k], bounds[k + 1]);
            let c = centres[k];
            (s2[b] - s2[a]) - 2.0 * c * (s1[b] - s1[a]) + (b - a) as f64 * c * c
        })
        .sum::<f64>();
    (centres, sse)
}

/// Index of the codebook entry nearest to `v` (the lower one on a tie).
pub fn nearest(codebook: &[f32; CODES], v: f32) -> u8 {
    let i = codebook.partition_point(|&c| c < v);
    if i == 0 {
        return 0;
    }
    if i == CODES {
        return (CODES - 1) as u8;
    }
    let (lo, hi) = (codebook[i - 1], codebook[i]);
    if (v - lo) <= (hi - v) {
        (i - 1) as u8
    } else {
        i as u8
    }
}

/// Quantizes interleaved channels: `values[i·channels + c]` belongs to channel `c`.
/// Returns one codebook per channel and the codes in the same interleaved order.
pub fn quantize_channels(values: &[f32], channels: usize) -> (Vec<[f32; CODES]>, Vec<u8>) {
    let mut books = Vec::with_capacity(channels);
    let mut codes = vec![0u8; values.len()];
    for c in 0..channels {
        let column: Vec<f32> = values.iter().skip(c).step_by(channels).copied().collect();
        let q = kmeans8(&column);
        for (i, code) in q.codes.into_iter().enumerate() {
            codes[i * channels + c] = code;
        }
        books.push(q.codebook);
    }
    (books, codes)
}

/// The values of interleaved codes (inverse of [`quantize_channels`] up to rounding).
pub fn dequantize_channels(books: &[[f32; CODES]], codes: &[u8]) -> Vec<f32> {
    let channels = books.len().max(1);
    codes
        .iter()
        .enumerate()
        .map(|(i, &q)| books[i % channels][q as usize])
        .collect()
}
