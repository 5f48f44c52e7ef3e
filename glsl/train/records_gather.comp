#version 460
// Ordered reduction (`--deterministic`), step 2 of the backward: per voxel, the sum of
// its entries' gradient records (backward.glsl, DETERMINISTIC) in emission order, added
// to its vgrad record (zeroed before the walk). A voxel's entries are emit_keys.comp's
// offsets[v] .. offsets[v] + counts[v]; pass `chunk` sums the span
// [chunk · gather_span, (chunk + 1) · gather_span) of them, so one invocation's loop
// stays under llvmpipe's loop limit however many tiles a voxel covers, and the passes
// run in order (a fixed summation order).
#extension GL_EXT_control_flow_attributes : require
#include "raster_params.glsl"
#include "backward_params.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams frame;
    BackParams back;
    uint chunk;
    uint mode; // unused: the walk mode of the shared ChunkPush mirror (0 here)
} pc;

void main() {
    FrameParams P = pc.frame;
    BackParams B = pc.back;
    uint v = linear_group_id() * 256u + gl_LocalInvocationID.x;
    if (v >= P.voxels) return;
    uint n = P.counts.v[v];
    uint span = B.gather_span;
    uint lo = pc.chunk * span;
    if (lo >= n) return;
    uint hi = min(n, lo + span);
    uint first = P.offsets.v[v];
    float s[VG_STRIDE];
    [[unroll]] for (uint c = 0u; c < VG_STRIDE; ++c) s[c] = 0.0;
    for (uint i = lo; i < hi; ++i) {
        uint r = VG_STRIDE * (first + i);
        [[unroll]] for (uint c = 0u; c < VG_STRIDE; ++c) s[c] += B.records.v[r + c];
    }
    uint o = VG_STRIDE * v;
    [[unroll]] for (uint c = 0u; c < VG_STRIDE; ++c) B.vgrad.v[o + c] += s[c];
}
