#version 460
// Between preprocess/scan and key emission, one invocation: clamps the entry count to
// the key buffers' capacity (flagging overflow, so the host grows and re-renders
// instead of silently truncating) and writes the indirect dispatch arguments of the
// entry-parallel kernels and, for segmented frames, of the per-slot composite.
#include "raster_params.glsl"
layout(local_size_x = 1) in;

layout(push_constant) uniform Push {
    FrameParams frame;
    uint max_groups_x;
    uint pad;
} pc;

void main() {
    FrameParams P = pc.frame;
    uint64_t total = U64s(uint64_t(P.stats)).v[STAT_TOTAL / 2u];
    uint cap = P.entry_capacity;
    uint used = uint(min(total, uint64_t(cap)));
    if (total > uint64_t(cap)) P.stats.v[STAT_FLAGS] |= FLAG_ENTRY_OVERFLOW;
    P.stats.v[STAT_USED] = used;
    uint groups = (used + 255u) / 256u;
    uvec3 g = groups <= pc.max_groups_x
                  ? uvec3(groups, 1u, 1u)
                  : uvec3(pc.max_groups_x, (groups + pc.max_groups_x - 1u) / pc.max_groups_x, 1u);
    P.stats.v[STAT_ARGS] = g.x;
    P.stats.v[STAT_ARGS + 1u] = g.y;
    P.stats.v[STAT_ARGS + 2u] = g.z;
    if (P.seg_size > 0u) {
        // Segmented composite: one workgroup per slot that may hold a segment (every
        // slot is below tiles + used / S; slots without one exit at once).
        uint slots = min(P.tiles.x * P.tiles.y + used / P.seg_size, P.slot_cap);
        uvec3 s = slots <= pc.max_groups_x
                      ? uvec3(slots, 1u, 1u)
                      : uvec3(pc.max_groups_x, (slots + pc.max_groups_x - 1u) / pc.max_groups_x, 1u);
        P.stats.v[STAT_SEG_ARGS] = s.x;
        P.stats.v[STAT_SEG_ARGS + 1u] = s.y;
        P.stats.v[STAT_SEG_ARGS + 2u] = s.z;
    }
}
