#version 460
// Ordered reduction (`--deterministic`), last step of the backward: each grid point's
// density gradient is the sum of its voxel corners' gradients (voxel_backward and TV,
// DETERMINISTIC, per voxel corner in B.vcorner) over its list point_list[point_off[g] ..
// point_off[g + 1]) in ascending voxel · 8 + corner order — a fixed order, where the
// default backward adds them with float atomics in whatever order the voxels finish.
// Overwrites grad_geo (a grid point belongs to at most 8 voxel corners).
#include "raster_params.glsl"
#include "backward_params.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams frame;
    BackParams back;
    uint points;
    uint pad;
} pc;

void main() {
    BackParams B = pc.back;
    uint g = linear_group_id() * 256u + gl_LocalInvocationID.x;
    if (g >= pc.points) return;
    uint lo = B.point_off.v[g], hi = B.point_off.v[g + 1u];
    float s = 0.0;
    for (uint i = lo; i < hi; ++i) s += B.vcorner.v[B.point_list.v[i]];
    B.grad_geo.v[g] = s;
}
