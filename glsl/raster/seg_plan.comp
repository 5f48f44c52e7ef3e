#version 460
// Segmented frames ("Segments" in raster_params.glsl), one invocation per tile, after
// tile_ranges: names the tile in each of its segments' slots (the buffer was filled
// with ~0) and records the longest list (STAT_MAX_TILE). The forward and the training
// backward walk segments, not chunks: no list is ever too long for the frame.
#include "raster_params.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams frame;
} pc;

void main() {
    FrameParams P = pc.frame;
    uint tile = linear_group_id() * 256u + gl_LocalInvocationID.x;
    if (tile >= P.tiles.x * P.tiles.y) return;
    uint r0 = P.ranges.v[2u * tile], r1 = P.ranges.v[2u * tile + 1u];
    if (r1 <= r0) return;
    atomicMax(P.stats.v[STAT_MAX_TILE], r1 - r0);
    uint first = seg_first_slot(P, tile, r0);
    uint n = seg_count(P, r0, r1);
    // Below slot_cap by construction (the host sizes it from the entry capacity).
    for (uint z = 0u; z < n; ++z) P.seg_tile.v[first + z] = tile;
    atomicMax(P.stats.v[STAT_SLOTS], first + n);
}
