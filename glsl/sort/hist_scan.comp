#version 460
// Turns each pass's digit histogram into exclusive global offsets (in place), and skips
// the passes whose digit is the same for every key (one bin holds all n keys: the pass
// would be the identity permutation). A skipped pass gets a dispatch of 0 workgroups;
// every later pass swaps its ping-pong direction (ST_FLIP), and if an odd number was
// skipped the result ends in the other buffer pair than the recorded passes say, so a
// final copy (ST_ARGS_COPY) moves it there. One workgroup of 256 invocations: one digit
// each.
#include "common.glsl"
#include "pass_state.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    U32s state;
    uint passes;
    uint skip_constant; // 0: run every pass (tests, benchmarks of the full cost)
} pc;

shared uint s_part[256];
shared uint s_const;

void main() {
    uint t = gl_LocalInvocationID.x;
    uint n = pc.state.v[ST_N];
    uint skipped = 0u;
    uint mask = 0u; // bit p: pass p skipped
    for (uint p = 0u; p < pc.passes; p++) {
        if (t == 0u) s_const = 0u;
        uint c = pc.state.v[ST_HIST + p * 256u + t];
        uint incl = subgroupInclusiveAdd(c);
        if (gl_SubgroupInvocationID == gl_SubgroupSize - 1u) s_part[gl_SubgroupID] = incl;
        barrier();
        if (c == n) s_const = 1u; // n > 0: at most one bin can hold them all
        if (t == 0u) {
            uint run = 0u;
            for (uint s = 0u; s < gl_NumSubgroups; s++) {
                uint x = s_part[s];
                s_part[s] = run;
                run += x;
            }
        }
        barrier();
        pc.state.v[ST_HIST + p * 256u + t] = s_part[gl_SubgroupID] + incl - c;
        bool skip = pc.skip_constant != 0u && (n == 0u || s_const != 0u);
        if (t < 3u) {
            uint grid = pc.state.v[ST_ARGS_TILES + t];
            pc.state.v[ST_PASS_ARGS + 3u * p + t] = skip && t == 0u ? 0u : grid;
        }
        if (t == 0u) pc.state.v[ST_FLIP + p] = skipped & 1u;
        if (skip) {
            skipped++;
            mask |= 1u << p;
        }
        barrier();
    }
    if (t < 3u) {
        uint grid = pc.state.v[ST_ARGS_TILES + t];
        pc.state.v[ST_ARGS_COPY + t] = (skipped & 1u) == 0u && t == 0u ? 0u : grid;
    }
    if (t == 0u) pc.state.v[ST_SKIPPED] = mask;
}
