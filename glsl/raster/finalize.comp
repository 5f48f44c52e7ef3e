#version 460
// Resolves the composited state per pixel (render resolution): background behind
// the remaining transmittance (the constant `bg`, or the frame's mean colour summed
// before by frame_mean.comp), alpha = 1 - T, mean depth and the reference's median
// depth (the last voxel entered with T > 0.5, refined with 16 samples) as camera z.
#include "raster_params.glsl"
#include "explin.glsl"
#include "ray_aabb.glsl"
#include "trilinear.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams frame;
} pc;

void main() {
    FrameParams P = pc.frame;
    uint p = linear_group_id() * 256u + gl_LocalInvocationID.x;
    uint W = P.render_size.x, H = P.render_size.y;
    uint npix = W * H;
    if (p >= npix) return;
    uvec2 pix = uvec2(p % W, p / W);
    vec3 rd;
    float rd_norm;
    pixel_ray(P, pix, rd, rd_norm);

    float T = P.img.v[CH_T * npix + p];
    P.aux.v[AUX_T * npix + p] = T;
    vec3 bg = frame_background(P);
    for (uint c = 0u; c < 3u; ++c) P.img.v[c * npix + p] += T * bg[c];
    P.img.v[CH_T * npix + p] = 1.0 - T;
    P.img.v[CH_DEPTH * npix + p] /= rd_norm;

    float dmed = 0.0;
    uint v = P.med_id.v[p];
    if (v != 0xffffffffu) {
        const int n_samp = 16;
        float med_t = P.med_t.v[p];
        vec4 cs = vec4(P.cs.v[4u * v], P.cs.v[4u * v + 1u], P.cs.v[4u * v + 2u], P.cs.v[4u * v + 3u]);
        float g[8];
        for (uint c = 0u; c < 8u; ++c) g[c] = P.geo8.v[8u * v + c];
        float h = 0.5 * cs.w;
        vec2 ab = ray_aabb(cs.xyz - h, cs.xyz + h, rd, 1.0 / rd);
        float a = max(ab.x, P.near * rd_norm), b = min(ab.y, host_t_far(P, pix, rd_norm));
        float step_sz = (b - a) * (1.0 / float(n_samp));
        vec3 vmin = cs.xyz - h;
        dmed = a - 0.5 * step_sz;
        for (int k = 0; k < n_samp; ++k) {
            if (med_t <= 0.5) break;
            dmed += step_sz;
            vec3 q = ((a + (float(k) + 0.5) * step_sz) * rd - vmin) / cs.w;
            med_t *= exp(-STEP_SZ_SCALE * step_sz * explin(trilinear(g, q)));
        }
    }
    P.img.v[CH_DMED * npix + p] = dmed / rd_norm;
}
