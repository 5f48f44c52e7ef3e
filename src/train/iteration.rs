//! One training iteration as the queue holds it: its draws and switches ([`IterPlan`],
//! what recording it again needs), its loss weights, and an iteration submitted and not
//! yet checked ([`Queued`]). The recording and settling are in queue.rs.

use crate::gpu::{Ticket, Timestamps};
use crate::raster::{FrameCheck, FrameOutputs, RenderOptions};

/// The loss weights and learning-rate scale of one iteration (the schedule's switches
/// applied).
#[derive(Clone, Copy)]
pub(super) struct IterWeights {
    pub(super) dist: f32,
    pub(super) nmed: f32,
    pub(super) nmean: f32,
    pub(super) tv: f32,
    pub(super) lr_scale: f32,
}

/// One iteration's draws and switches: what recording it (again) needs.
#[derive(Clone)]
pub(super) struct IterPlan {
    /// Adam step number (the 1-based iteration).
    pub(super) step: u32,
    pub(super) view: usize,
    pub(super) ss: f32,
    pub(super) degree: u32,
    pub(super) opts: RenderOptions,
    pub(super) outputs: FrameOutputs,
    pub(super) w: IterWeights,
}

/// An iteration submitted and not yet checked.
pub(super) struct Queued {
    pub(super) plan: IterPlan,
    pub(super) ticket: Ticket,
    pub(super) check: FrameCheck,
    /// Byte offset of its go word in `Trainer::go`.
    pub(super) go_offset: u64,
    /// Its stage timestamps (frame, update), when timing is on: read once it is
    /// settled, while the iteration behind it runs.
    pub(super) timing: Option<(Timestamps, Timestamps)>,
}

/// Go words in `Trainer::go`, used in turn.
pub(super) const GO_WORDS: u64 = 2;
