#version 460
// SSIM pass 1 of 4: the horizontal 11-tap Gaussian blur (zero padding) of the five
// per-channel statistics maps x, y, x², y², xy, computed on the fly from the planar
// [3][H][W] images. Thread per (channel, pixel); writes planes dst[c*5 + k][H][W].
#include "common.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    F32s x;
    F32s y;
    F32s dst;
    uint width;
    uint height;
    float gauss[12];  // 11 normalised taps (index 5 = centre), [11] unused
} pc;

void main() {
    uint W = pc.width, H = pc.height;
    uint npix = W * H;
    uint i = linear_group_id() * 256u + gl_LocalInvocationID.x;
    if (i >= 3u * npix) return;
    uint c = i / npix, p = i - c * npix;
    uint row = p / W, col = p - row * W;
    uint base = c * npix + row * W;
    float sx = 0.0, sy = 0.0, sxx = 0.0, syy = 0.0, sxy = 0.0;
    for (int t = 0; t < 11; ++t) {
        int j = int(col) + t - 5;
        if (j < 0 || j >= int(W)) continue;
        float g = pc.gauss[t];
        float a = pc.x.v[base + uint(j)];
        float b = pc.y.v[base + uint(j)];
        sx += g * a;
        sy += g * b;
        sxx += g * (a * a);
        syy += g * (b * b);
        sxy += g * (a * b);
    }
    uint o = 5u * c * npix + p;
    pc.dst.v[o] = sx;
    pc.dst.v[o + npix] = sy;
    pc.dst.v[o + 2u * npix] = sxx;
    pc.dst.v[o + 3u * npix] = syy;
    pc.dst.v[o + 4u * npix] = sxy;
}
