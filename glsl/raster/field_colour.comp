#version 460
// Replaces the colours the preprocess computed with three channels of a per-voxel
// field (`Renderer::set_voxel_colours`): rgb[v] = field[v·channels + first + c] for
// c < 3 (0 past the last channel), unclamped, so the composite accumulates
// Σ_k T_k α_k f_k of any real values (features, class probabilities) exactly as it
// accumulates colour. Recorded between the preprocess and the composite.
#include "raster_params.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams frame;
    F32s field;     // [voxels][channels]
    uint channels;
    uint first;
} pc;

void main() {
    FrameParams P = pc.frame;
    uint v = linear_group_id() * 256u + gl_LocalInvocationID.x;
    if (v >= P.voxels) return;
    for (uint c = 0u; c < 3u; ++c) {
        uint ch = pc.first + c;
        P.rgb.v[3u * v + c] = ch < pc.channels ? pc.field.v[v * pc.channels + ch] : 0.0;
    }
}
