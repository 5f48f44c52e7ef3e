#version 460
// Pixel losses of a training frame and their gradients w.r.t. the frame's outputs
// (docs/ARCHITECTURE.md §4). Per output pixel q: MSE over rgb (mean over 3·npix), the transmittance
// concentration T²(1-T)² with T = 1 - alpha (mean over npix), the inside term T² (the
// reference's lambda_T_inside: every ray ends inside the model, mean over npix); writes
// EVERY channel of
// `dout` (rgb and alpha gradients, zero depth/normal gradients, the ground truth) —
// SSIM then adds its gradient to the rgb channels. With `clamp_rgb` the rgb losses see
// clamp(rgb, 0, 1) (SVRaster's training and our eval), their gradient passes only where
// rgb is in [0, 1], and the clamped image goes to `clamped` for SSIM. Per-workgroup partial sums of the
// squared error, the concentration term, the render-resolution distortion values and
// the inside term go to `partials` (4 floats per workgroup; the host adds them when it
// logs).
#include "raster_params.glsl"
#include "backward_params.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams frame;
    F32s out_img;   // planar IMG_CHANNELS at output resolution
    F32s gt;        // planar rgb at output resolution
    F32s dout;      // planar DO_CHANNELS
    F32s partials;  // 4 per workgroup
    float w_mse;    // λ_mse / (3·npix)
    float w_t;      // λ_T / npix
    uint nout;
    uint nrender;
    float w_tin;    // λ_T_inside / npix
    uint clamp_rgb; // 1: the rgb losses on clamp(rgb, 0, 1), as SVRaster (renderer.py:176)
    F32s clamped;   // clamp_rgb: planar clamped rgb at output resolution (SSIM's input)
} pc;

shared float s_red[4][256];

void main() {
    FrameParams P = pc.frame;
    uint l = gl_LocalInvocationID.x;
    uint g = linear_group_id();
    uint q = g * 256u + l;
    uint nout = pc.nout;
    float se = 0.0, tc = 0.0, dist = 0.0, tin = 0.0;
    if (q < nout) {
        float a = pc.out_img.v[CH_T * nout + q];  // alpha after finalize
        for (uint c = 0u; c < 3u; ++c) {
            float y = pc.gt.v[c * nout + q];
            float x = pc.out_img.v[c * nout + q];
            // The clamp's derivative (torch's): 1 on [0, 1] inclusive, 0 outside.
            float pass = 1.0;
            if (pc.clamp_rgb != 0u) {
                pass = x >= 0.0 && x <= 1.0 ? 1.0 : 0.0;
                x = clamp(x, 0.0, 1.0);
                pc.clamped.v[c * nout + q] = x;
            }
            float d = x - y;
            se += d * d;
            pc.dout.v[c * nout + q] = 2.0 * pc.w_mse * d * pass;
            pc.dout.v[(DO_GTR + c) * nout + q] = y;
        }
        float T = 1.0 - a;
        tc = T * T * (1.0 - T) * (1.0 - T);
        tin = T * T;
        // dL/dalpha = -dL/dT
        pc.dout.v[DO_ALPHA * nout + q] =
            -(pc.w_t * 2.0 * T * (1.0 - T) * (1.0 - 2.0 * T) + pc.w_tin * 2.0 * T);
        for (uint c = DO_DEPTH; c <= DO_NZ; ++c) pc.dout.v[c * nout + q] = 0.0;
    }
    if (q < pc.nrender) dist = P.aux.v[AUX_DIST * pc.nrender + q];
    s_red[0][l] = se;
    s_red[1][l] = tc;
    s_red[2][l] = dist;
    s_red[3][l] = tin;
    barrier();
    for (uint s = 128u; s > 0u; s >>= 1u) {
        if (l < s) {
            for (uint k = 0u; k < 4u; ++k) s_red[k][l] += s_red[k][l + s];
        }
        barrier();
    }
    if (l == 0u) {
        for (uint k = 0u; k < 4u; ++k) pc.partials.v[4u * g + k] = s_red[k][0];
    }
}
