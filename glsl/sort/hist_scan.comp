#version 460
// Turns each pass's digit histogram into exclusive global offsets (in place).
// One workgroup of 256 invocations: one digit each.
#include "common.glsl"
#include "pass_state.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    U32s state;
    uint passes;
    uint pad;
} pc;

shared uint s_part[256];

void main() {
    uint t = gl_LocalInvocationID.x;
    for (uint p = 0u; p < pc.passes; p++) {
        uint c = pc.state.v[ST_HIST + p * 256u + t];
        uint incl = subgroupInclusiveAdd(c);
        if (gl_SubgroupInvocationID == gl_SubgroupSize - 1u) s_part[gl_SubgroupID] = incl;
        barrier();
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
        barrier();
    }
}
