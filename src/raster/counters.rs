//! Work counters of the tile walks (`_counters` kernel variants; `CTR_*` in
//! glsl/lib/raster_params.glsl): what the forward composite and the training backward
//! did, independent of machine speed. Read with [`Renderer::counters`](super::Renderer::counters).

/// u64 words of the work-counter buffer (`CTR_WORDS` in raster_params.glsl).
pub(crate) const COUNTER_WORDS: usize = crate::gpu::glsl::CTR_WORDS as usize;

/// Work done by the tile walks of the frames (and backwards) recorded with counters on
/// ([`Renderer::set_counters`](super::Renderer::set_counters)): one walk's totals over all tiles and chunks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct WalkCounters {
    /// Subgroup loop trips over entries (a subgroup visiting one entry).
    pub trips: u64,
    /// Trips in which at least one lane's pixel needed the entry (rectangle and sign).
    pub useful_trips: u64,
    /// Trips a full walk with one pixel per lane (every such subgroup visits every
    /// entry of its tile) would make: the baseline the tile walk is measured against.
    pub full_walk_trips: u64,
    /// (pixel, entry) pairs past the rectangle and sign test.
    pub pairs: u64,
    /// Ray–voxel crossings (a non-empty ray segment).
    pub crossings: u64,
    /// Contributions (α ≥ 1e-5).
    pub contributions: u64,
    /// Visit-set builds (one per subgroup and staged batch of 128 entries).
    pub builds: u64,
    /// Subgroups dispatched (all chunks).
    pub subgroups: u64,
    /// (Forward only; 0 in the backward.) Pixel steps whose crossing branch ran for the
    /// whole subgroup because at least one lane's pixel crossed the entry's voxel: with
    /// two pixels per lane, up to two per trip. What the compositing body costs.
    pub body_runs: u64,
    /// (Forward only.) Per staged batch, the largest number of crossings one lane made
    /// (both its pixels), summed: the body runs a walk would need that first lists each
    /// lane's crossings and then composites them lane by lane (SVRaster's forward). At
    /// most `body_runs`; at least `crossings` / lanes.
    pub lane_max_crossings: u64,
}

impl WalkCounters {
    pub(crate) fn from_words(w: &[u64]) -> WalkCounters {
        WalkCounters {
            trips: w[0],
            useful_trips: w[1],
            full_walk_trips: w[2],
            pairs: w[3],
            crossings: w[4],
            contributions: w[5],
            builds: w[6],
            subgroups: w[7],
            body_runs: w[8],
            lane_max_crossings: w[9],
        }
    }

    /// Trips per useful trip (1 is the floor; 0 when nothing was useful).
    pub fn trips_per_useful(&self) -> f64 {
        if self.useful_trips == 0 {
            0.0
        } else {
            self.trips as f64 / self.useful_trips as f64
        }
    }
}

/// Counters of the forward composite and the training backward.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct WorkCounters {
    pub forward: WalkCounters,
    pub backward: WalkCounters,
}
