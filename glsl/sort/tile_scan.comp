#version 460
// The reduce-then-scan sort passes (src/sort SortPass::Scan*), step 2 of 3 per digit
// pass: for the digit of its workgroup (256 workgroups), the exclusive prefix over the
// tiles of sort/tile_count.glsl's counts, in place: word d * tiles + j becomes the number
// of keys with digit d in tiles 0..j-1. A skipped pass (its pass dispatch has 0
// workgroups, sort/hist_scan.comp) leaves the words alone.
#include "common.glsl"
#include "pass_state.glsl"
#extension GL_EXT_control_flow_attributes : require
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    U32s state;
    U32s counts;     // [256][tiles]
    uint pass_index;
    uint tile_size;  // keys per tile of the pass
} pc;

#define PER 8       // tiles per invocation and round: 2 048 per round, loads overlapped
shared uint s_part[256]; // subgroup sums of one round

void main() {
    if (pc.state.v[ST_PASS_ARGS + 3u * pc.pass_index] == 0u) return; // uniform
    uint t = gl_LocalInvocationID.x;
    uint n = pc.state.v[ST_N];
    uint ntiles = (n + pc.tile_size - 1u) / pc.tile_size;
    uint base = gl_WorkGroupID.x * ntiles;
    uint carry = 0u; // sum of the rounds before
    for (uint i0 = 0u; i0 < ntiles; i0 += 256u * PER) {
        uint first = i0 + t * PER; // this invocation's PER consecutive tiles
        uint c[PER];
        uint sum = 0u;
        [[unroll]] for (uint j = 0u; j < PER; j++) {
            c[j] = first + j < ntiles ? pc.counts.v[base + first + j] : 0u;
            sum += c[j];
        }
        uint incl = subgroupInclusiveAdd(sum);
        if (gl_SubgroupInvocationID == gl_SubgroupSize - 1u) s_part[gl_SubgroupID] = incl;
        barrier();
        uint run = carry + incl - sum, total = 0u;
        for (uint s = 0u; s < gl_NumSubgroups; s++) {
            uint p = s_part[s];
            if (s < gl_SubgroupID) run += p;
            total += p;
        }
        [[unroll]] for (uint j = 0u; j < PER; j++) {
            if (first + j < ntiles) pc.counts.v[base + first + j] = run;
            run += c[j];
        }
        carry += total;
        barrier(); // s_part is rewritten by the next round
    }
}
