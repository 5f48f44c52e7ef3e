// One pass over the keys builds the 256-bin histogram of every digit of the sort.
#include "common.glsl"
#include "pass_state.glsl"
#include "sort_key.glsl"
#define HIST_WG 256
#define HIST_KPT 16
layout(local_size_x = HIST_WG) in;

layout(push_constant) uniform Push {
    KeyBuf keys;
    U32s state;
    uint lo;      // first bit sorted
    uint hi;      // one past the last bit sorted
    uint passes;  // ceil((hi - lo) / 8)
    uint aggregate; // 1: a subgroup whose keys share a digit adds it once (GPUs)
} pc;

shared uint s_hist[8 * 256];

// Digit of pass p of `key`.
uint digit(KeyT key, uint p) {
    uint shift = pc.lo + 8u * p;
    uint bits = min(8u, pc.hi - shift);
    return uint(key >> shift) & ((1u << bits) - 1u);
}

void main() {
    uint t = gl_LocalInvocationID.x;
    uint n = pc.state.v[ST_N];
    // Blocks of HIST_WG x HIST_KPT keys; a workgroup takes `mult` consecutive ones
    // (sort/setup.comp: the grid is capped, so few workgroups add to the global counts).
    uint mult = pc.state.v[ST_HIST_MULT];
    uint base = linear_group_id() * (HIST_WG * HIST_KPT) * mult;
    if (base >= n) return; // uniform across the workgroup
    for (uint i = t; i < 8u * 256u; i += HIST_WG) s_hist[i] = 0u;
    barrier();
    // Two copies of the loop, so the device without aggregation (lavapipe, where a
    // branch around a vote inside the loop cost 14 % of this kernel) runs the plain one.
    if (pc.aggregate != 0u) {
        for (uint m = 0u; m < mult; m++)
        for (uint r = 0u; r < HIST_KPT; r++) {
            uint idx = base + (m * HIST_KPT + r) * HIST_WG + t;
            if (idx < n) {
                KeyT key = pc.keys.v[idx];
                for (uint p = 0u; p < pc.passes; p++) {
                    uint d = digit(key, p);
                    // A digit the whole subgroup shares (constant or sorted keys) would
                    // serialize its lanes' adds on one shared word: one add of the
                    // count instead.
                    if (subgroupAllEqual(d)) {
                        uint c = subgroupBallotBitCount(subgroupBallot(true));
                        if (subgroupElect()) atomicAdd(s_hist[p * 256u + d], c);
                    } else {
                        atomicAdd(s_hist[p * 256u + d], 1u);
                    }
                }
            }
        }
    } else {
        for (uint m = 0u; m < mult; m++)
        for (uint r = 0u; r < HIST_KPT; r++) {
            uint idx = base + (m * HIST_KPT + r) * HIST_WG + t;
            if (idx < n) {
                KeyT key = pc.keys.v[idx];
                for (uint p = 0u; p < pc.passes; p++)
                    atomicAdd(s_hist[p * 256u + digit(key, p)], 1u);
            }
        }
    }
    barrier();
    for (uint p = 0u; p < pc.passes; p++) {
        uint c = s_hist[p * 256u + t];
        if (c != 0u) atomicAdd(pc.state.v[ST_HIST + p * 256u + t], c);
    }
}
