#version 460
// Row gather of a topology change (src/adapt/topology.rs), thread per output element
// (2-D grid): dst[j·width + k] = src[index[j]·width + k] for j < rows, k < width. Copies
// the per-voxel SH coefficients and their Adam moments from each new voxel's source
// voxel (itself, or the parent of a child) without leaving the device. With `blocked`
// both sides are in the blocked SH layout (sh_layout.glsl).
#include "common.glsl"
#include "sh_layout.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    U32s index;  // [rows] source row of each output row
    F32s src;    // [*][width]
    F32s dst;    // [rows][width] out
    uint rows;
    uint width;
    uint blocked;
    uint pad;
} pc;

void main() {
    uint i = linear_group_id() * 256u + gl_LocalInvocationID.x;
    if (i >= pc.rows * pc.width) return;
    uint j = i / pc.width, k = i - j * pc.width;
    if (pc.blocked != 0u)
        pc.dst.v[shs_index(j, k, pc.width)] = pc.src.v[shs_index(pc.index.v[j], k, pc.width)];
    else
        pc.dst.v[i] = pc.src.v[pc.index.v[j] * pc.width + k];
}
