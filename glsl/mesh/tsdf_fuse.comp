#version 460
// TSDF fusion of one view into the grid points (paper §3.2.4; KinectFusion-style as the
// reference's Fuser), one invocation per grid point, one dispatch per view:
//   q = w2c · p;  skip if q.z ≤ near or the pixel (fx·q.x/q.z + cx, fy·q.y/q.z + cy) lies
//   outside the image shrunk by `crop` (fraction of the half-size, as NDC |uv| ≤ 1 − crop);
//   bilinear taps of the view's (depth, alpha) at the pixel (centres at +0.5, edge
//   clamped); skip unless all four taps with weight are valid (alpha ≥ alpha_min and
//   depth > 0); sdf = (depth − q.z) / band, skip if sdf < −1, clamp to ≤ 1;
//   w = bilinear alpha;  sd[p] += w·sdf,  wt[p] += w.
// Positive values lie in front of the surface (free space), negative ones behind it.
#include "common.glsl"
layout(local_size_x = 128) in;

layout(push_constant) uniform Push {
    F32s points;   // xyz per grid point (model frame)
    F32s views;    // per pixel of every view: depth, alpha (interleaved)
    F32s cams;     // per view: w2c rows (12), fx, fy, cx, cy, width, height, near, offset
    F32s sd;       // Σ w·sdf per grid point
    F32s wt;       // Σ w per grid point
    uint count;    // grid points
    uint view;
    float band;
    float alpha_min;
    float crop;
    uint pad;
} pc;

const uint CAM_FLOATS = 20u;

void main() {
    uint i = linear_group_id() * 128u + gl_LocalInvocationID.x;
    if (i >= pc.count) return;
    vec3 p = vec3(pc.points.v[3u * i], pc.points.v[3u * i + 1u], pc.points.v[3u * i + 2u]);
    uint c = pc.view * CAM_FLOATS;
    vec3 q;
    for (int r = 0; r < 3; r++) {
        uint o = c + 4u * uint(r);
        q[r] = pc.cams.v[o] * p.x + pc.cams.v[o + 1u] * p.y + pc.cams.v[o + 2u] * p.z
             + pc.cams.v[o + 3u];
    }
    float fx = pc.cams.v[c + 12u], fy = pc.cams.v[c + 13u];
    float cx = pc.cams.v[c + 14u], cy = pc.cams.v[c + 15u];
    uint w = floatBitsToUint(pc.cams.v[c + 16u]);
    uint h = floatBitsToUint(pc.cams.v[c + 17u]);
    float near = pc.cams.v[c + 18u];
    uint base = floatBitsToUint(pc.cams.v[c + 19u]);
    if (!(q.z > near)) return;
    float u = fx * q.x / q.z + cx;
    float v = fy * q.y / q.z + cy;
    float nu = 2.0 * u / float(w) - 1.0, nv = 2.0 * v / float(h) - 1.0;
    if (!(abs(nu) <= 1.0 - pc.crop && abs(nv) <= 1.0 - pc.crop)) return;
    // Bilinear taps around (u − 0.5, v − 0.5), clamped to the image.
    float x = u - 0.5, y = v - 0.5;
    float x0f = floor(x), y0f = floor(y);
    float fxr = x - x0f, fyr = y - y0f;
    int x0 = int(x0f), y0 = int(y0f);
    float depth = 0.0, alpha = 0.0;
    for (int t = 0; t < 4; t++) {
        int dx = t & 1, dy = t >> 1;
        float wgt = (dx == 1 ? fxr : 1.0 - fxr) * (dy == 1 ? fyr : 1.0 - fyr);
        if (wgt == 0.0) continue;
        uint px = uint(clamp(x0 + dx, 0, int(w) - 1));
        uint py = uint(clamp(y0 + dy, 0, int(h) - 1));
        uint o = base + 2u * (py * w + px);
        float d = pc.views.v[o], a = pc.views.v[o + 1u];
        if (!(d > 0.0 && a >= pc.alpha_min)) return;
        depth += wgt * d;
        alpha += wgt * a;
    }
    float sdf = (depth - q.z) / pc.band;
    if (sdf < -1.0) return;
    sdf = min(sdf, 1.0);
    pc.sd.v[i] += alpha * sdf;
    pc.wt.v[i] += alpha;
}
