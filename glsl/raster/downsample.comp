#version 460
// Anti-aliased downsampling of every image channel from the supersampled render
// resolution to the output resolution: a separable triangle (tent) filter whose
// radius is the scale factor, i.e. PyTorch's `interpolate(bilinear, antialias=True)`
// that the reference uses.
#include "raster_params.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams frame;
} pc;

void main() {
    FrameParams P = pc.frame;
    uint q = linear_group_id() * 256u + gl_LocalInvocationID.x;
    uint OW = P.out_size.x, OH = P.out_size.y;
    if (q >= OW * OH) return;
    uint W = P.render_size.x, H = P.render_size.y;
    uint npix = W * H, nout = OW * OH;
    vec2 o = vec2(q % OW, q / OW);
    vec2 scale = P.ss_scale;   // render pixels per output pixel
    vec2 rad = P.filter_radius;     // filter radius in render pixels (max(scale, 1))
    vec2 centre = (o + 0.5) * scale;  // in render-pixel coordinates
    ivec2 lo = max(ivec2(floor(centre - rad)), ivec2(0));
    ivec2 hi = min(ivec2(ceil(centre + rad)), ivec2(W, H) - 1);

    float acc[IMG_CHANNELS];
    for (uint c = 0u; c < IMG_CHANNELS; ++c) acc[c] = 0.0;
    float wsum = 0.0;
    for (int y = lo.y; y <= hi.y; ++y) {
        float wy = max(0.0, 1.0 - abs(float(y) + 0.5 - centre.y) / rad.y);
        if (wy == 0.0) continue;
        for (int x = lo.x; x <= hi.x; ++x) {
            float wx = max(0.0, 1.0 - abs(float(x) + 0.5 - centre.x) / rad.x);
            float w = wx * wy;
            if (w == 0.0) continue;
            uint p = uint(y) * W + uint(x);
            for (uint c = 0u; c < IMG_CHANNELS; ++c) acc[c] += w * P.img.v[c * npix + p];
            wsum += w;
        }
    }
    float inv = wsum > 0.0 ? 1.0 / wsum : 0.0;
    for (uint c = 0u; c < IMG_CHANNELS; ++c) P.out_img.v[c * nout + q] = acc[c] * inv;
}
