#version 460
// Minimum sampling interval per voxel over views (paper §3.2.2, Eq. 7b), one invocation
// per voxel, recorded after a completed frame whose FrameParams block it reads:
//   minint[v] = min(minint[v], max(z, near) / fx)
// (with skip_near, the initial layout's rule, SVRaster's mark_max_samp_rate: a view whose
// near plane holds the voxel's centre, z <= near, does not show it at all)
// with z the camera depth of the voxel centre ((centre - origin) · forward, i.e. the
// lookat row of w2c applied to the camera-relative centre `cs.xyz`) and fx the focal
// length in pixels of the view at its output size: the frame's render-resolution fx
// times `fx_scale` (output / render width: 1 unless supersampled), so
// z / fx = z·tan(fov_x/2)/(W/2) at the view's own resolution.
// Which voxels a view shows (the others are left unchanged: +inf until a view shows
// them):
// - view_w == 0: every voxel the frame's preprocess gave at least one entry
//   (counts[v] > 0; ours);
// - else every voxel with a non-zero blending weight in this frame (view_w: the frame's
//   own max-weight target, f32 bits per voxel, zeroed before it), which is also folded
//   into maxw (SVRaster's `compute_training_stat`: `max_w_i > 0`).
#include "raster_params.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams frame;
    F32s minint;  // one float per voxel
    U32s view_w;  // this frame's max weights (f32 bits), or 0
    U32s maxw;    // the accumulated max weights (f32 bits; with view_w)
    uint count;   // voxels of the accumulator (the frame's cfg.x must not exceed it)
    float fx_scale;
    uint skip_near;
    uint pad;
} pc;

void main() {
    FrameParams P = pc.frame;
    uint v = linear_group_id() * 256u + gl_LocalInvocationID.x;
    if (v >= min(pc.count, P.voxels)) return;
    if (P.counts.v[v] == 0u) return;  // cs is only written for visible voxels
    if (uint64_t(pc.view_w) != 0ul) {
        // Non-negative f32 bits order as the floats do.
        uint w = pc.view_w.v[v];
        if (w == 0u) return;
        if (w > pc.maxw.v[v]) pc.maxw.v[v] = w;
    }
    vec3 c = vec3(P.cs.v[4u * v], P.cs.v[4u * v + 1u], P.cs.v[4u * v + 2u]);
    float z = dot(P.w2c[2].xyz, c);
    if (pc.skip_near != 0u && z <= P.near) return;
    float interval = max(z, P.near) / (P.intr.x * pc.fx_scale);
    if (interval < pc.minint.v[v]) pc.minint.v[v] = interval;
}
