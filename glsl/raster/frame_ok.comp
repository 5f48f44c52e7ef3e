#version 460
// A frame's go/no-go word for the work recorded after it in the same command buffer
// (the training step's conditional region, recorder::begin_conditional): 1 when the
// frame is complete (no entry overflow, no tile list longer than the chunks recorded)
// and its scan and sort raised no error bit, else 0. The host learns why from the
// words copied beside it (Renderer::record_checks) once the submission completed.
// With `after` set, an earlier frame's go word gates this one too: an iteration queued
// behind one whose update was skipped is skipped with it (the host redoes both, in
// order), so no update ever runs on parameters a skipped one should have changed.
#include "raster_params.glsl"
#include "pass_state.glsl"
layout(local_size_x = 1) in;

layout(push_constant) uniform Push {
    U32s stats;       // the frame's stats words
    U32s sort_state;  // the sort's and the scan's run state (ST_ERRORS)
    U32s scan_state;
    U32s ok;          // ok.v[0] = 1 (go) or 0
    U32s after;       // an earlier frame's go word, or null (no chain)
} pc;

void main() {
    bool go = pc.stats.v[STAT_FLAGS] == 0u && pc.sort_state.v[ST_ERRORS] == 0u &&
              pc.scan_state.v[ST_ERRORS] == 0u;
    if (uint64_t(pc.after) != 0ul) {
        go = go && pc.after.v[0] != 0u;
    }
    pc.ok.v[0] = go ? 1u : 0u;
}
