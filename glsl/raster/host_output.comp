#version 460
// Host output (raster/host/): the frame's final image at output resolution as
// premultiplied linear light (the model's colours are sRGB-encoded display values, as
// the photos it was trained on: α·decode(C/α)), packed for the host's colour target
// (sRGB targets store encode(α·linear)), and optionally the depth in
// the host's convention: where the field's alpha reaches 0.5 its median or mean depth,
// or the host's own where that is nearer; elsewhere the host's depth passes through.
// Instead of the colour the target can show the depth (grey, near = bright, opaque where
// the alpha reaches 0.5: the nearest median depth over the output pixel's render
// pixels) or the normal (outward unit normal -n/|n| as n*0.5 + 0.5, times alpha), both
// display values like the colour, written the same way.
#include "raster_params.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams frame;
    U32s color;        // packed pixels, row-major: 1 word (8-bit), 2 (16F) or 4 (32F)
    F32s depth;        // 0: no depth output
    F32s host_depth;   // the host's depth values (0: none)
    uint format;       // HOST_*
    uint depth_mode;   // HOST_DEPTH_*
    float depth_clear; // the host's "nothing here" depth (1 standard, 0 reverse-Z)
    uint reverse;      // 1: reverse-Z (nearer = larger)
    uint image;        // HOST_IMAGE_*: what the colour target shows
    float near_depth;  // HOST_IMAGE_DEPTH: camera depths mapped to grey 1.0 ...
    float far_depth;   // ... 0.2 (the CLI's depth PNG); no surface: transparent
    uint pad_;
} pc;

float srgb_encode(float x) {
    return x <= 0.0031308 ? 12.92 * x : 1.055 * pow(x, 1.0 / 2.4) - 0.055;
}

float srgb_decode(float x) {
    return x <= 0.04045 ? x / 12.92 : pow((x + 0.055) / 1.055, 2.4);
}

// The field's surface depth (camera z) at output pixel p: the nearest over the render
// pixels inside it whose alpha reaches 0.5 (one pixel without supersampling; a filtered
// median would mix in pixels without a surface); 0 where there is none.
float surface_depth(FrameParams P, uint p, uint mode) {
    uint W = P.out_size.x;
    uvec2 o = uvec2(p % W, p / W);
    uvec2 lo = uvec2(floor(vec2(o) * P.ss_scale));
    uvec2 hi = min(uvec2(ceil(vec2(o + 1u) * P.ss_scale)), P.render_size);
    hi = max(hi, lo + 1u);
    uint RW = P.render_size.x, rpix = RW * P.render_size.y;
    float dmin = uintBitsToFloat(0x7f800000u);
    for (uint y = lo.y; y < hi.y; ++y) {
        for (uint x = lo.x; x < hi.x; ++x) {
            uint q = y * RW + x;
            float a = P.img.v[CH_T * rpix + q];
            if (a < 0.5) continue;
            float dq = mode == HOST_DEPTH_MEAN ? P.img.v[CH_DEPTH * rpix + q] / a
                                               : P.img.v[CH_DMED * rpix + q];
            if (dq > 0.0) dmin = min(dmin, dq);
        }
    }
    return dmin < uintBitsToFloat(0x7f800000u) ? dmin : 0.0;
}

void main() {
    FrameParams P = pc.frame;
    uint p = linear_group_id() * 256u + gl_LocalInvocationID.x;
    uint W = P.out_size.x, H = P.out_size.y;
    uint npix = W * H;
    if (p >= npix) return;
    F32s img = P.supersampled != 0u ? P.out_img : P.img;
    vec4 c = vec4(img.v[CH_R * npix + p], img.v[CH_G * npix + p], img.v[CH_B * npix + p],
                  img.v[CH_T * npix + p]);
    if (pc.image == HOST_IMAGE_NORMAL) {
        vec3 n = vec3(img.v[CH_NX * npix + p], img.v[CH_NY * npix + p], img.v[CH_NZ * npix + p]);
        float l = length(n);
        float a = clamp(c.a, 0.0, 1.0);
        c = l < 1e-6 ? vec4(0.0, 0.0, 0.0, a) : vec4((-n / l * 0.5 + 0.5) * a, a);
    } else if (pc.image == HOST_IMAGE_DEPTH) {
        float dsurf = surface_depth(P, p, HOST_DEPTH_MEDIAN);
        float span = max(pc.far_depth - pc.near_depth, 1e-6);
        float g = 1.0 - 0.8 * clamp((dsurf - pc.near_depth) / span, 0.0, 1.0);
        c = dsurf > 0.0 ? vec4(vec3(g), 1.0) : vec4(0.0);
    }
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
        bool has_host = uint64_t(pc.host_depth) != 0ul;
        float z = has_host ? pc.host_depth.v[p] : pc.depth_clear;
        float dmin = surface_depth(P, p, pc.depth_mode);
        uvec2 o = uvec2(p % W, p / W);
        if (dmin > 0.0) {
            vec2 xy = ((vec2(o) + 0.5) * P.ss_scale - P.intr.zw) / P.intr.xy;
            float zf = clamp(dot(P.depth_map.xyz, vec3(xy, 1.0)) + P.depth_map.w / dmin, 0.0, 1.0);
            // The nearer of the field and the host (rays cut at the host's depth are
            // always in front of it; without the cut the host may be nearer).
            z = !has_host ? zf : (pc.reverse != 0u ? max(zf, z) : min(zf, z));
        }
        pc.depth.v[p] = z;
    }
}
