#version 460
// Loss gradients from output to render resolution (training backward, step 1).
// Per render pixel: the transpose of the frame's anti-aliasing downsample (tent filter
// normalised per output pixel, exactly raster/downsample.comp) applied to the output
// gradients, then the transpose of finalize: rgb = C + T·bg and alpha = 1 - T give
// ∂L/∂C = ∂L/∂rgb and ∂L/∂T = bg·∂L/∂rgb - ∂L/∂alpha, plus the transmittance losses
// taken at render resolution (SVRaster's raw_T: back.lambda_t, back.lambda_t_inside) on
// the frame's exact final T. The ground truth for the per-point RGB loss is the output
// pixel containing the render pixel's centre, or with back.r_bilinear the photo's
// bilinear interpolation there (torch's interpolate, align_corners=False, as
// SVRaster's resize_rendering; identical to its antialiased form when enlarging).
#include "raster_params.glsl"
#include "backward_params.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams frame;
    BackParams back;
} pc;

// Sum of the tent weights of output pixel o along one axis (render size n).
float tent_sum(float o, float scale, float rad, uint n) {
    float centre = (o + 0.5) * scale;
    int lo = max(int(floor(centre - rad)), 0);
    int hi = min(int(ceil(centre + rad)), int(n) - 1);
    float s = 0.0;
    for (int i = lo; i <= hi; ++i) s += max(0.0, 1.0 - abs(float(i) + 0.5 - centre) / rad);
    return s;
}

void main() {
    FrameParams P = pc.frame;
    BackParams B = pc.back;
    uint p = linear_group_id() * 256u + gl_LocalInvocationID.x;
    uint W = P.render_size.x, H = P.render_size.y;
    if (p >= W * H) return;
    uint npix = W * H;
    uint OW = B.out_size.x, OH = B.out_size.y;
    uint nout = OW * OH;
    uvec2 pix = uvec2(p % W, p / W);

    float acc[8];
    for (uint c = 0u; c < 8u; ++c) acc[c] = 0.0;
    uint qgt;
    if (P.supersampled == 0u) {
        for (uint c = 0u; c < 8u; ++c) acc[c] = B.dout.v[c * nout + p];
        qgt = p;
    } else {
        vec2 scale = P.ss_scale, rad = P.filter_radius;
        vec2 x = vec2(pix) + 0.5;
        // Output pixels whose footprint |x - (o + 0.5)·scale| < rad contains this pixel.
        ivec2 olo = max(ivec2(floor((x - rad) / scale - 0.5)), ivec2(0));
        ivec2 ohi = min(ivec2(ceil((x + rad) / scale - 0.5)), ivec2(OW, OH) - 1);
        for (int oy = olo.y; oy <= ohi.y; ++oy) {
            float wy = max(0.0, 1.0 - abs(x.y - (float(oy) + 0.5) * scale.y) / rad.y);
            if (wy == 0.0) continue;
            float sy = tent_sum(float(oy), scale.y, rad.y, H);
            for (int ox = olo.x; ox <= ohi.x; ++ox) {
                float wx = max(0.0, 1.0 - abs(x.x - (float(ox) + 0.5) * scale.x) / rad.x);
                if (wx == 0.0) continue;
                float w = wx * wy / (tent_sum(float(ox), scale.x, rad.x, W) * sy);
                uint q = uint(oy) * OW + uint(ox);
                for (uint c = 0u; c < 8u; ++c) acc[c] += w * B.dout.v[c * nout + q];
            }
        }
        uvec2 o = min(uvec2(x / scale), uvec2(OW, OH) - 1u);
        qgt = o.y * OW + o.x;
    }
    vec3 drgb = vec3(acc[DO_R], acc[DO_G], acc[DO_B]);
    B.dimg.v[DI_R * npix + p] = drgb.x;
    B.dimg.v[DI_G * npix + p] = drgb.y;
    B.dimg.v[DI_B * npix + p] = drgb.z;
    // With the frame-mean background (P.bgsum), bg is that frame's mean m; the part of
    // the gradient that flows through m into every pixel's C is added afterwards
    // (frame_mean.comp, FM_SUM_TGRAD → FM_TOTAL → FM_APPLY).
    vec3 bg = frame_background(P);
    float dT = dot(bg, drgb) - acc[DO_ALPHA];
    if (B.lambda_t != 0.0 || B.lambda_t_inside != 0.0) {
        float T = P.aux.v[AUX_T * npix + p];
        dT += B.lambda_t * 2.0 * T * (1.0 - T) * (1.0 - 2.0 * T) + B.lambda_t_inside * 2.0 * T;
    }
    B.dimg.v[DI_T * npix + p] = dT;
    B.dimg.v[DI_DEPTH * npix + p] = acc[DO_DEPTH];
    B.dimg.v[DI_NX * npix + p] = acc[DO_NX];
    B.dimg.v[DI_NY * npix + p] = acc[DO_NY];
    B.dimg.v[DI_NZ * npix + p] = acc[DO_NZ];
    if (B.r_bilinear != 0u && P.supersampled != 0u) {
        // Source position in output pixels, clamped at the first pixel's centre; the
        // upper neighbour clamped to the last pixel.
        vec2 src = max((vec2(pix) + 0.5) / P.ss_scale - 0.5, vec2(0.0));
        uvec2 i0 = min(uvec2(src), uvec2(OW, OH) - 1u);
        uvec2 i1 = min(i0 + 1u, uvec2(OW, OH) - 1u);
        vec2 f = src - vec2(i0);
        for (uint c = 0u; c < 3u; ++c) {
            uint base = (DO_GTR + c) * nout;
            float top = mix(B.dout.v[base + i0.y * OW + i0.x], B.dout.v[base + i0.y * OW + i1.x], f.x);
            float bot = mix(B.dout.v[base + i1.y * OW + i0.x], B.dout.v[base + i1.y * OW + i1.x], f.x);
            B.dimg.v[(DI_GTR + c) * npix + p] = mix(top, bot, f.y);
        }
    } else {
        for (uint c = 0u; c < 3u; ++c) B.dimg.v[(DI_GTR + c) * npix + p] = B.dout.v[(DO_GTR + c) * nout + qgt];
    }
}
