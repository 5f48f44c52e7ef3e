#version 460
// Host output (raster/host.rs): the frame's final image at output resolution as
// premultiplied linear light (the model's colours are sRGB-encoded display values, as
// the photos it was trained on: α·decode(C/α)), packed for the host's colour target
// (sRGB targets store encode(α·linear)), and optionally the depth in
// the host's convention. The field writes a depth where its alpha reaches 0.5 in front
// of the host's surface (median or mean depth, as chosen); elsewhere the host's own
// depth passes through (or, without host depth, the clear value).
#include "raster_params.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams P;
    U32s color;        // packed pixels, row-major: 1 word (8-bit), 2 (16F) or 4 (32F)
    F32s depth;        // 0: no depth output
    uint format;       // HOST_*
    uint depth_mode;   // HOST_DEPTH_*
    float depth_clear; // the host's "nothing here" depth (1 standard, 0 reverse-Z)
    uint pad;
} pc;

float srgb_encode(float x) {
    return x <= 0.0031308 ? 12.92 * x : 1.055 * pow(x, 1.0 / 2.4) - 0.055;
}

float srgb_decode(float x) {
    return x <= 0.04045 ? x / 12.92 : pow((x + 0.055) / 1.055, 2.4);
}

void main() {
    FrameParams P = pc.P;
    uint p = linear_group_id() * 256u + gl_LocalInvocationID.x;
    uint W = P.out_size.x, H = P.out_size.y;
    uint npix = W * H;
    if (p >= npix) return;
    F32s img = P.supersampled != 0u ? P.out_img : P.img;
    vec4 c = vec4(img.v[CH_R * npix + p], img.v[CH_G * npix + p], img.v[CH_B * npix + p],
                  img.v[CH_T * npix + p]);
    vec3 d = c.a > 0.0 ? max(c.rgb / c.a, 0.0) : vec3(0.0);
    c.rgb = c.a * vec3(srgb_decode(d.r), srgb_decode(d.g), srgb_decode(d.b));
    if (pc.format == HOST_RGBA32F) {
        for (uint k = 0u; k < 4u; ++k) pc.color.v[4u * p + k] = floatBitsToUint(c[k]);
    } else if (pc.format == HOST_RGBA16F) {
        pc.color.v[2u * p] = packHalf2x16(c.rg);
        pc.color.v[2u * p + 1u] = packHalf2x16(c.ba);
    } else {
        vec4 u = clamp(c, 0.0, 1.0);
        if (pc.format == HOST_RGBA8_SRGB) {
            u.rgb = vec3(srgb_encode(u.r), srgb_encode(u.g), srgb_encode(u.b));
        }
        pc.color.v[p] = packUnorm4x8(u);
    }

    if (uint64_t(pc.depth) != 0ul) {
        float z = uint64_t(P.host_depth) != 0ul ? P.host_depth.v[p] : pc.depth_clear;
        if (c.a >= 0.5) {
            float d = pc.depth_mode == HOST_DEPTH_MEAN ? img.v[CH_DEPTH * npix + p] / c.a
                                                       : img.v[CH_DMED * npix + p];
            uvec2 o = uvec2(p % W, p / W);
            vec2 xy = ((vec2(o) + 0.5) * P.ss_scale - P.intr.zw) / P.intr.xy;
            if (d > 0.0) {
                z = clamp(dot(P.depth_map.xyz, vec3(xy, 1.0)) + P.depth_map.w / d, 0.0, 1.0);
            }
        }
        pc.depth.v[p] = z;
    }
}
