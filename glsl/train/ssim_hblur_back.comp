#version 460
// SSIM pass 3 of 4: the horizontal 11-tap blur (zero padding) of the three derivative
// maps A, B, Cm of every channel (planes [c*3 + k][H][W]). Thread per (channel, pixel).
#include "common.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    F32s src;  // 9 planes from ssim_stats
    F32s dst;  // 9 planes
    uint width;
    uint height;
    float gauss[12];
} pc;

void main() {
    uint W = pc.width, H = pc.height;
    uint npix = W * H;
    uint i = linear_group_id() * 256u + gl_LocalInvocationID.x;
    if (i >= 3u * npix) return;
    uint c = i / npix, p = i - c * npix;
    uint row = p / W, col = p - row * W;
    uint base = 3u * c * npix + row * W;
    float acc[3] = float[3](0.0, 0.0, 0.0);
    for (int t = 0; t < 11; ++t) {
        int j = int(col) + t - 5;
        if (j < 0 || j >= int(W)) continue;
        float g = pc.gauss[t];
        uint q = base + uint(j);
        for (uint k = 0u; k < 3u; ++k) acc[k] += g * pc.src.v[q + k * npix];
    }
    uint o = 3u * c * npix + p;
    for (uint k = 0u; k < 3u; ++k) pc.dst.v[o + k * npix] = acc[k];
}
