#version 460
// Minimum sampling interval per voxel over views (paper §3.2.2, Eq. 7b), one invocation
// per voxel, recorded after a completed frame whose FrameParams block it reads:
//   minint[v] = min(minint[v], max(z, near) / fx)
// for every voxel the frame's preprocess gave at least one entry (counts[v] > 0), with
// z the camera depth of the voxel centre ((centre - origin) · forward, i.e. the lookat
// row of w2c applied to the camera-relative centre `cs.xyz`) and fx the focal length in
// pixels at render resolution: z / fx = z·tan(fov_x/2)/(W/2). Voxels the frame does not
// show are left unchanged (+inf until a view shows them).
#include "raster_params.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams frame;
    F32s minint;  // one float per voxel
    uint count;   // voxels of the accumulator (the frame's cfg.x must not exceed it)
    uint pad;
} pc;

void main() {
    FrameParams P = pc.frame;
    uint v = linear_group_id() * 256u + gl_LocalInvocationID.x;
    if (v >= min(pc.count, P.voxels)) return;
    if (P.counts.v[v] == 0u) return;  // cs is only written for visible voxels
    vec3 c = vec3(P.cs.v[4u * v], P.cs.v[4u * v + 1u], P.cs.v[4u * v + 2u]);
    float z = dot(P.w2c[2].xyz, c);
    float interval = max(z, P.near) / P.intr.x;
    if (interval < pc.minint.v[v]) pc.minint.v[v] = interval;
}
