#version 460
// Grid-point dedup, step 1 (src/train/topology.rs), thread per sorted candidate:
// heads[i] = 1 where a run of equal keys starts (i == 0 or key[i] != key[i-1]), else 0.
// Voxels around a point are disjoint, so at most 8 candidates share a key: a longer
// run (key[i-8] == key[i]) sets bit 0 of flags[0] (overlapping input voxels).
#include "common.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    U64s keys;   // [n] sorted keys
    U32s heads;  // [n] out
    U32s flags;  // [1] sticky error bits
    uint count;
    uint pad;
} pc;

void main() {
    uint i = linear_group_id() * 256u + gl_LocalInvocationID.x;
    if (i >= pc.count) return;
    uint64_t k = pc.keys.v[i];
    pc.heads.v[i] = (i == 0u || pc.keys.v[i - 1u] != k) ? 1u : 0u;
    if (i >= 8u && pc.keys.v[i - 8u] == k) atomicOr(pc.flags.v[0], 1u);
}
