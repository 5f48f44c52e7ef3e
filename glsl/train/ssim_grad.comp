#version 460
// SSIM pass 4 of 4: the vertical 11-tap blur of pass 3's maps completes G*A, G*B, G*Cm
// (the zero-padded Gaussian convolution is its own transpose), and
//   grad[c][q] += scale * ((G*A)_q + 2 x_q (G*B)_q + y_q (G*Cm)_q),
// scale = weight / (3 H W). Thread per (channel, pixel).
#include "common.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    F32s src;   // 9 planes from ssim_hblur_back
    F32s x;
    F32s y;
    F32s grad;
    uint width;
    uint height;
    float scale;
    uint pad;
    float gauss[12];
    F32s pass_if; // 0, or an image (layout of x) whose values outside [0, 1] stop the
                  // gradient: x is that image clamped (the clamp's derivative)
} pc;

void main() {
    uint W = pc.width, H = pc.height;
    uint npix = W * H;
    uint i = linear_group_id() * 256u + gl_LocalInvocationID.x;
    if (i >= 3u * npix) return;
    uint c = i / npix, p = i - c * npix;
    uint row = p / W, col = p - row * W;
    uint base = 3u * c * npix + col;
    float acc[3] = float[3](0.0, 0.0, 0.0);
    for (int t = 0; t < 11; ++t) {
        int r = int(row) + t - 5;
        if (r < 0 || r >= int(H)) continue;
        float g = pc.gauss[t];
        uint q = base + uint(r) * W;
        for (uint k = 0u; k < 3u; ++k) acc[k] += g * pc.src.v[q + k * npix];
    }
    float d = acc[0] + 2.0 * pc.x.v[i] * acc[1] + pc.y.v[i] * acc[2];
    if (uint64_t(pc.pass_if) != 0ul) {
        float o = pc.pass_if.v[i];
        if (!(o >= 0.0 && o <= 1.0)) d = 0.0;
    }
    pc.grad.v[i] += pc.scale * d;
}
