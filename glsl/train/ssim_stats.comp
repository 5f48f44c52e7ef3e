#version 460
// SSIM pass 2 of 4: the vertical 11-tap blur of pass 1's maps gives, per channel and
// pixel, mu_x, mu_y, E[x²], E[y²], E[xy]; from them the SSIM map value S and its
// partial derivatives A = ∂S/∂mu_x, B = ∂S/∂E[x²], Cm = ∂S/∂E[xy] (written to planes
// dst[c*3 + {0,1,2}]), and one partial sum of S per workgroup (partials[group], from
// subgroup sums added by one invocation, no float atomics; the host adds the partials
// up in f64). Thread per (channel, pixel). With margin > 0, only the window centres at
// least `margin` pixels from every border count ("valid" SSIM, SVRaster's
// fused_ssim(..., padding="valid")): the others add nothing to the sum and have A = B =
// Cm = 0, so no gradient flows from them.
#include "common.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    F32s src;       // 15 planes from ssim_hblur_in
    F32s dst;       // 9 planes: A, B, Cm per channel
    F32s partials;  // one float per workgroup
    uint width;
    uint height;
    uint margin;
    uint pad;
    float gauss[12];
} pc;

const float C1 = 0.01 * 0.01;
const float C2 = 0.03 * 0.03;

shared float red[256];

void main() {
    uint W = pc.width, H = pc.height;
    uint npix = W * H;
    uint lid = gl_LocalInvocationID.x;
    // Padding groups of a 2-D grid leave as a whole (uniformly: no barrier is reached
    // by only part of a workgroup) and must not write a partial sum.
    if (linear_group_id() >= (3u * npix + 255u) / 256u) return;
    uint i = linear_group_id() * 256u + lid;
    float s_val = 0.0;
    // No other early return: every invocation of the group reaches the barrier below.
    if (i < 3u * npix) {
        uint c = i / npix, p = i - c * npix;
        uint row = p / W, col = p - row * W;
        uint base = 5u * c * npix + col;
        float m[5] = float[5](0.0, 0.0, 0.0, 0.0, 0.0);
        for (int t = 0; t < 11; ++t) {
            int r = int(row) + t - 5;
            if (r < 0 || r >= int(H)) continue;
            float g = pc.gauss[t];
            uint q = base + uint(r) * W;
            for (uint k = 0u; k < 5u; ++k) m[k] += g * pc.src.v[q + k * npix];
        }
        float mx = m[0], my = m[1];
        float sxx = m[2] - mx * mx;
        float syy = m[3] - my * my;
        float sxy = m[4] - mx * my;
        float L = 2.0 * mx * my + C1;
        float Cs = 2.0 * sxy + C2;
        float D1 = mx * mx + my * my + C1;
        float D2 = sxx + syy + C2;
        float inv = 1.0 / (D1 * D2);
        float S = L * Cs * inv;
        float A = 2.0 * my * (Cs - L) * inv + 2.0 * mx * S * (1.0 / D2 - 1.0 / D1);
        float B = -S / D2;
        float Cm = 2.0 * L * inv;
        uint mg = pc.margin;
        if (row < mg || row + mg >= H || col < mg || col + mg >= W) {
            S = 0.0;
            A = 0.0;
            B = 0.0;
            Cm = 0.0;
        }
        uint o = 3u * c * npix + p;
        pc.dst.v[o] = A;
        pc.dst.v[o + npix] = B;
        pc.dst.v[o + 2u * npix] = Cm;
        s_val = S;
    }
    // Workgroup sum of S: subgroup sums, then one invocation adds them (any subgroup
    // size; one barrier, in uniform control flow).
    float sub = subgroupAdd(s_val);
    if (subgroupElect()) red[gl_SubgroupID] = sub;
    barrier();
    if (lid == 0u) {
        float total = 0.0;
        for (uint k = 0u; k < gl_NumSubgroups; ++k) total += red[k];
        pc.partials.v[linear_group_id()] = total;
    }
}
