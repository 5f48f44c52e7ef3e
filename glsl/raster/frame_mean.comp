#version 460
// SVRaster's background for scenes that are neither white nor black (renderer.py:
// `color + T · color.mean((1, 2))`): behind each pixel's remaining transmittance T, the
// frame's own mean composited colour m = (1/N) Σ_p C_p (C = Σ w c, premultiplied,
// at render resolution, N pixels), recomputed every frame and differentiated through.
// out_p = C_p + T_p·m, so ∂L/∂C_p = g_p + (1/N) Σ_q T_q g_q and ∂L/∂T_p = m·g_p
// (g = ∂L/∂out at render resolution; grad_prepare.comp takes the T part).
//
// Sums in a fixed order (per workgroup a tree over FM_PIXELS pixels, then one
// workgroup over the partials), so a frame sums alike on every run and device.
// Buffer `P.bgsum`: FM_SLOT_MEAN (m, rgb), FM_SLOT_GRAD ((1/N) Σ T g, rgb), then the
// partials (4 floats each) from FM_PARTIALS.
//   FM_SUM_COLOUR (before finalize): partial of workgroup g = Σ C over its pixels.
//   FM_SUM_TGRAD (after grad_prepare): partial = Σ T·∂L/∂C (aux T, dimg r, g, b).
//   FM_TOTAL (one workgroup): slot `dst` = Σ partials / N.
//   FM_APPLY (per pixel): dimg r, g, b += slot FM_SLOT_GRAD.
#include "raster_params.glsl"
#include "backward_params.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams frame;
    BackParams back;  // 0 in the forward's modes
    uint mode;
    uint dst;         // FM_TOTAL: the slot written
} pc;

shared float red[3][256];

// Tree sum of red[*][0..256) into red[*][0] (every invocation calls it).
void tree_sum() {
    uint i = gl_LocalInvocationID.x;
    for (uint s = 128u; s > 0u; s >>= 1) {
        barrier();
        if (i < s) {
            for (uint c = 0u; c < 3u; ++c) red[c][i] += red[c][i + s];
        }
    }
    barrier();
}

void main() {
    FrameParams P = pc.frame;
    uint npix = P.render_size.x * P.render_size.y;
    uint groups = (npix + FM_PIXELS - 1u) / FM_PIXELS;
    uint i = gl_LocalInvocationID.x;
    F32s S = P.bgsum;
    if (pc.mode == FM_APPLY) {
        uint p = linear_group_id() * 256u + i;
        if (p >= npix) return;
        for (uint c = 0u; c < 3u; ++c) pc.back.dimg.v[(DI_R + c) * npix + p] += S.v[FM_SLOT_GRAD + c];
        return;
    }
    vec3 acc = vec3(0.0);
    if (pc.mode == FM_TOTAL) {
        for (uint g = i; g < groups; g += 256u) {
            acc += vec3(S.v[FM_PARTIALS + 4u * g], S.v[FM_PARTIALS + 4u * g + 1u],
                        S.v[FM_PARTIALS + 4u * g + 2u]);
        }
    } else {
        uint g = linear_group_id();
        if (g >= groups) return;  // the whole workgroup: the grid's spare groups
        uint first = g * FM_PIXELS;
        uint end = min(first + FM_PIXELS, npix);
        for (uint p = first + i; p < end; p += 256u) {
            if (pc.mode == FM_SUM_COLOUR) {
                acc += vec3(P.img.v[p], P.img.v[npix + p], P.img.v[2u * npix + p]);
            } else {
                float T = P.aux.v[AUX_T * npix + p];
                F32s D = pc.back.dimg;
                acc += T * vec3(D.v[DI_R * npix + p], D.v[DI_G * npix + p], D.v[DI_B * npix + p]);
            }
        }
    }
    red[0][i] = acc.x;
    red[1][i] = acc.y;
    red[2][i] = acc.z;
    tree_sum();
    if (i == 0u) {
        if (pc.mode == FM_TOTAL) {
            float inv = 1.0 / float(npix);
            for (uint c = 0u; c < 3u; ++c) S.v[pc.dst + c] = red[c][0] * inv;
        } else {
            uint g = linear_group_id();
            for (uint c = 0u; c < 3u; ++c) S.v[FM_PARTIALS + 4u * g + c] = red[c][0];
        }
    }
}
