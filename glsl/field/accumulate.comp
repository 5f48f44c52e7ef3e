#version 460
// Field fusion (src/field): adds one backward's colour gradients to the fused sums.
// The backward of a frame whose output gradient is a per-pixel value image g gives
// each voxel Σ_pixels T_k α_k g (its blending weight in every ray times the value: the
// adjoint of compositing), so with three value planes as the gradient's r, g, b
// channels, vgrad's rgb are three channels' Σ w·value:
//   acc[(first + c)·voxels + v] += vgrad[v].rgb[c]   for c < 3, first + c < channels.
#include "common.glsl"
#include "backward_params.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    F32s vgrad;     // per voxel, VG_STRIDE floats (the backward's)
    F32s acc;       // planar [channels][voxels]
    uint voxels;
    uint channels;
    uint first;
    uint pad;
} pc;

void main() {
    uint v = linear_group_id() * 256u + gl_LocalInvocationID.x;
    if (v >= pc.voxels) return;
    for (uint c = 0u; c < 3u; ++c) {
        uint ch = pc.first + c;
        if (ch < pc.channels) {
            uint o = ch * pc.voxels + v;  // < 2^32: checked by the host
            pc.acc.v[o] += pc.vgrad.v[VG_STRIDE * v + VG_RGB + c];
        }
    }
}
