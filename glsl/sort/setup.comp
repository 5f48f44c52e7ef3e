#version 460
// Starts a sort or scan run entirely on the GPU: reads the element count (from a
// buffer, or the push constant), clamps it to the capacity (setting ERR_OVERFLOW),
// writes the indirect dispatch arguments, zeroes the tile counters and histograms,
// and advances the look-back epoch. One workgroup.
#include "common.glsl"
#include "pass_state.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    U32s count;        // if non-null: element count at count.v[0]
    U32s state;
    uint n;            // element count when `count` is null
    uint capacity;
    uint tile_size;    // elements per tile of the tile kernel
    uint chunk_size;   // elements per workgroup of the histogram kernel (0: none)
    uint max_groups_x; // maxComputeWorkGroupCount[0]
    uint hist_words;   // histogram words to zero (passes * 256)
    uint max_chunk_groups; // histogram workgroups at most (0: one per chunk_size keys)
    uint pad;
} pc;

uvec3 grid(uint groups) {
    if (groups <= pc.max_groups_x) return uvec3(groups, 1u, 1u);
    return uvec3(pc.max_groups_x, (groups + pc.max_groups_x - 1u) / pc.max_groups_x, 1u);
}

void main() {
    uint t = gl_LocalInvocationID.x;
    for (uint i = t; i < pc.hist_words; i += 256u) pc.state.v[ST_HIST + i] = 0u;
    if (t < 8u) pc.state.v[ST_TILE_CTR + t] = 0u;
    if (t == 0u) {
        uint requested = uint64_t(pc.count) != 0ul ? pc.count.v[0] : pc.n;
        uint n = min(requested, pc.capacity);
        if (requested > pc.capacity) pc.state.v[ST_ERRORS] |= ERR_OVERFLOW;
        pc.state.v[ST_N] = n;
        pc.state.v[ST_REQUESTED] = requested;
        pc.state.v[ST_TOTAL] = 0u;
        pc.state.v[ST_LB_STEPS] = 0u;
        pc.state.v[ST_LB_WAITS] = 0u;
        pc.state.v[ST_LB_FALLBACKS] = 0u;
        uint e = pc.state.v[ST_EPOCH] + 8u;
        // Epoch 0 is what a fresh (zeroed) status array holds: never use it.
        if ((e & 0x3ffffff8u) == 0u) e = 8u;
        pc.state.v[ST_EPOCH] = e;
        uvec3 a = grid((n + pc.tile_size - 1u) / pc.tile_size);
        pc.state.v[ST_ARGS_TILES + 0] = a.x;
        pc.state.v[ST_ARGS_TILES + 1] = a.y;
        pc.state.v[ST_ARGS_TILES + 2] = a.z;
        // Each histogram workgroup ends with one global add per digit and pass, so
        // beyond max_chunk_groups workgroups each takes several chunks instead.
        uint chunks = pc.chunk_size > 0u ? (n + pc.chunk_size - 1u) / pc.chunk_size : 0u;
        uint mult = 1u;
        if (pc.max_chunk_groups > 0u && chunks > pc.max_chunk_groups)
            mult = (chunks + pc.max_chunk_groups - 1u) / pc.max_chunk_groups;
        pc.state.v[ST_HIST_MULT] = mult;
        uvec3 b = pc.chunk_size > 0u ? grid((chunks + mult - 1u) / mult) : uvec3(0u, 1u, 1u);
        pc.state.v[ST_ARGS_CHUNKS + 0] = b.x;
        pc.state.v[ST_ARGS_CHUNKS + 1] = b.y;
        pc.state.v[ST_ARGS_CHUNKS + 2] = b.z;
    }
}
