// Warp-level multisplit: which lanes of the subgroup hold a key with the same digit.
// Shared by the radix sort's two pass kernels (glsl/sort/onesweep*.glsl).
#ifndef SORT_RANK_GLSL
#define SORT_RANK_GLSL
#extension GL_KHR_shader_subgroup_shuffle : require
#extension GL_EXT_control_flow_attributes : require

uint popcount4(uvec4 m) {
    return bitCount(m.x) + bitCount(m.y) + bitCount(m.z) + bitCount(m.w);
}
uint lsb4(uvec4 m) {
    return m.x != 0u ? findLSB(m.x)
         : m.y != 0u ? 32u + findLSB(m.y)
         : m.z != 0u ? 64u + findLSB(m.z)
                     : 96u + findLSB(m.w);
}

// For this lane's key with digit `d` (`bits` wide; `valid` false past the end): the
// valid lanes below it with the same digit, their count including it, and the lowest
// such lane (this lane if invalid). Call in subgroup-uniform control flow.
// `shuffle8`: 8-lane subgroups compare digits through 8 shuffles (one permute each on
// lavapipe, where a ballot is a loop over the lanes); otherwise AND one ballot per digit
// bit — subgroups of up to 32 lanes (NVIDIA, Intel, lavapipe) need only the first mask
// word. An invalid lane carries a digit no valid lane has.
uvec3 rank_in_subgroup(bool valid, uint d, uint bits, bool shuffle8) {
    uint lane = gl_SubgroupInvocationID;
    uvec4 lt = gl_SubgroupLtMask;
    if (gl_SubgroupSize == 8u && shuffle8) {
        uint dd = valid ? d : 0xffffffffu;
        uint match = 0u;
        [[unroll]] for (uint i = 0u; i < 8u; i++)
            match |= subgroupShuffle(dd, i) == dd ? (1u << i) : 0u;
        return uvec3(bitCount(match & lt.x), bitCount(match), findLSB(match));
    } else if (gl_SubgroupSize <= 32u) {
        uint match = subgroupBallot(valid).x;
        for (uint b = 0u; b < bits; b++) {
            bool set = ((d >> b) & 1u) != 0u;
            uint bal = subgroupBallot(set).x;
            match &= set ? bal : ~bal;
        }
        return uvec3(bitCount(match & lt.x), bitCount(match), valid ? findLSB(match) : lane);
    } else {
        uvec4 match = subgroupBallot(valid);
        for (uint b = 0u; b < bits; b++) {
            bool set = ((d >> b) & 1u) != 0u;
            uvec4 bal = subgroupBallot(set);
            match &= set ? bal : ~bal;
        }
        return uvec3(popcount4(match & lt), popcount4(match), valid ? lsb4(match) : lane);
    }
}
#endif
