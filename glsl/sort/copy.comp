#version 460
// The radix sort's final copy when an odd number of passes was skipped
// (sort/hist_scan.comp): moves the sorted pairs into the buffer pair the recorded passes
// end in. Dispatched indirectly on the tile grid (0 workgroups when no copy is needed);
// each workgroup copies `tile_size` pairs.
#include "common.glsl"
#include "pass_state.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    U32s keys_src; // key words: key_words per pair
    U32s vals_src;
    U32s keys_dst;
    U32s vals_dst;
    U32s state;
    uint key_words; // 1 (u32 keys) or 2 (u64 keys)
    uint tile_size;
} pc;

void main() {
    uint n = pc.state.v[ST_N];
    uint base = linear_group_id() * pc.tile_size;
    for (uint i = gl_LocalInvocationID.x; i < pc.tile_size; i += 256u) {
        uint e = base + i;
        if (e >= n) break;
        pc.vals_dst.v[e] = pc.vals_src.v[e];
        for (uint w = 0u; w < pc.key_words; w++)
            pc.keys_dst.v[e * pc.key_words + w] = pc.keys_src.v[e * pc.key_words + w];
    }
}
