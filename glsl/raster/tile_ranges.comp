#version 460
// Start/end of every tile's run in the sorted keys, one invocation per entry. Ranges
// are zeroed before, so tiles without entries read as empty.
#include "raster_params.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams frame;
} pc;

void main() {
    FrameParams P = pc.frame;
    uint i = linear_group_id() * 256u + gl_LocalInvocationID.x;
    uint n = P.stats.v[STAT_USED];
    if (i >= n) return;
    uint shift = P.key_shift;
    U32s k32 = U32s(uint64_t(P.skeys));  // u32 keys (P.key32)
    uint tile = P.key32 != 0u ? k32.v[i] >> shift : uint(P.skeys.v[i] >> shift);
    if (i == 0u) {
        P.ranges.v[2u * tile] = i;
    } else {
        uint prev = P.key32 != 0u ? k32.v[i - 1u] >> shift : uint(P.skeys.v[i - 1u] >> shift);
        if (prev != tile) P.ranges.v[2u * tile] = i;
    }
    if (i + 1u == n) {
        P.ranges.v[2u * tile + 1u] = i + 1u;
    } else {
        uint next = P.key32 != 0u ? k32.v[i + 1u] >> shift : uint(P.skeys.v[i + 1u] >> shift);
        if (next != tile) P.ranges.v[2u * tile + 1u] = i + 1u;
    }
}
