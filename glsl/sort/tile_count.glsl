// The reduce-then-scan sort passes (src/sort SortPass::Scan*), step 1 of 3 per digit
// pass: how many keys of each digit every tile holds, written digit-major into the
// status buffer (word d * tiles + tile) for sort/tile_scan.comp, which turns them into
// prefixes over the tiles for the pass (onesweep_coalesced.glsl with SCAN_PREFIX). The
// tiles are the pass's (WG × KPT keys, in input order); no workgroup waits on another.
//
// Defines (build.rs variants): WG invocations, KPT keys per invocation, KEY32.
#include "common.glsl"
#extension GL_KHR_shader_subgroup_shuffle : require
#extension GL_EXT_control_flow_attributes : require
#include "pass_state.glsl"
#include "sort_key.glsl"
#include "sort_rank.glsl"

#define TILE (WG * KPT)
#define RADIX 256
layout(local_size_x = WG) in;

layout(push_constant) uniform Push {
    KeyBuf keys_in;
    KeyBuf keys_out;   // the pass's other key buffer: a skipped pass before swaps them
    U32s state;
    U32s counts;       // [RADIX][tiles]
    uint shift;        // first bit of this pass's digit
    uint bits;         // digit width (1..8)
    uint pass_index;   // 0..7
    uint generic_rank; // 1: rank with ballots on any subgroup size (tests)
} pc;

shared uint s_count[RADIX];

void main() {
    uint t = gl_LocalInvocationID.x;
    for (uint i = t; i < RADIX; i += WG) s_count[i] = 0u;
    barrier();
    uint tile = linear_group_id();
    uint n = pc.state.v[ST_N];
    uint ntiles = (n + TILE - 1u) / TILE;
    if (tile >= ntiles) return; // uniform across the workgroup
    bool flip = pc.state.v[ST_FLIP + pc.pass_index] != 0u;
    KeyBuf keys = flip ? pc.keys_out : pc.keys_in;
    uint digit_mask = (1u << pc.bits) - 1u;
    // Every load first (their latencies overlap), then one shared add per digit run of
    // each subgroup round (a digit many keys share adds once, not once per key).
    KeyT k[KPT];
    [[unroll]] for (uint r = 0u; r < KPT; r++) {
        uint idx = tile * TILE + r * WG + t;
        k[r] = idx < n ? keys.v[idx] : KeyT(0);
    }
    [[unroll]] for (uint r = 0u; r < KPT; r++) {
        bool valid = tile * TILE + r * WG + t < n;
        uint d = uint(k[r] >> pc.shift) & digit_mask;
        uvec3 rank = rank_in_subgroup(valid, d, pc.bits, pc.generic_rank == 0u);
        if (valid && rank.x == 0u) atomicAdd(s_count[d], rank.y);
    }
    barrier();
    for (uint d = t; d < RADIX; d += WG) pc.counts.v[d * ntiles + tile] = s_count[d];
}
