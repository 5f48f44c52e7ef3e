#version 460
// Depth–normal self-consistency of a training frame (paper §3.2.3, the reference's
// NormalMedianConsistencyLoss and NormalDepthConsistencyLoss; 2DGS-style), at output
// resolution, one invocation per pixel. ADDS its gradients to `dout` (after loss.comp
// wrote every channel).
//
// Normals from a depth map D (camera z) with the reference's 3-pixel stencil: at an
// interior pixel k = (x, y), with P(j) = D(j)·ray(j) and ray(j) = ((x_j + ½ − cx)/fx,
// (y_j + ½ − cy)/fy, 1) in camera space,
//   dx = P(x+1, y) − P(x−1, y),  dy = P(x, y+1) − P(x, y−1),  n = (dx × dy)/|dx × dy|
// (x right, y down: n points away from the camera, into the surface, like the rendered
// normal N = Σ Tα ∇density/|∇density|). Defined only where the four depths are > 0 and
// the cross product is not zero (the reference's mask).
//   median term: λ_med · mean_k (1 − N_k·n_med,k); n_med from the median depth, not
//                differentiated (the median has no gradient): gradient w.r.t. N only.
//   mean term:   λ_mean · mean_k (α_k² − α_k N_k·n_mean,k); n_mean from the mean depth
//                channel (Σ Tα d, not divided by α, as the reference), α held constant:
//                gradients w.r.t. N and, through n_mean, w.r.t. the depth of the four
//                stencil pixels. Pixel k gathers the depth gradient of the four terms
//                whose stencil it is in (no atomics):
//                  g = −λ α_q N_q,  h = (g − (g·n) n)/|u|,  ∂/∂D_right = (dy × h)·ray,
//                  ∂/∂D_left = −(dy × h)·ray,  ∂/∂D_down = (h × dx)·ray,
//                  ∂/∂D_up = −(h × dx)·ray.
// N is world space in the image; `rot` (w2c rotation rows) takes it to camera space and
// back. Per-workgroup partial sums of the two unweighted terms go to `partials`.
#include "raster_params.glsl"
#include "backward_params.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    vec4 r0;        // w2c rotation row 0 (xyz), fx (w)
    vec4 r1;        // row 1, fy
    vec4 r2;        // row 2, cx
    F32s out_img;   // planar IMG_CHANNELS at output resolution
    F32s dout;      // planar DO_CHANNELS
    F32s partials;  // 2 per workgroup
    float cy;
    float w_med;    // λ_med / npix
    float w_mean;   // λ_mean / npix
    uint width;
    uint height;
    uint pad;
} pc;

shared float s_red[2][256];

vec3 ray(int x, int y) {
    return vec3((float(x) + 0.5 - pc.r2.w) / pc.r0.w, (float(y) + 0.5 - pc.cy) / pc.r1.w, 1.0);
}

float depth_at(uint ch, int x, int y) {
    uint n = pc.width * pc.height;
    return pc.out_img.v[ch * n + uint(y) * pc.width + uint(x)];
}

// Normal from depth channel `ch` at (x, y): n, dx, dy, |dx × dy|; false where undefined.
bool dnormal(uint ch, int x, int y, out vec3 n, out vec3 dx, out vec3 dy, out float len) {
    n = vec3(0.0);
    dx = vec3(0.0);
    dy = vec3(0.0);
    len = 0.0;
    if (x < 1 || y < 1 || x > int(pc.width) - 2 || y > int(pc.height) - 2) return false;
    float dr = depth_at(ch, x + 1, y), dl = depth_at(ch, x - 1, y);
    float dd = depth_at(ch, x, y + 1), du = depth_at(ch, x, y - 1);
    if (!(dr > 0.0 && dl > 0.0 && dd > 0.0 && du > 0.0)) return false;
    dx = dr * ray(x + 1, y) - dl * ray(x - 1, y);
    dy = dd * ray(x, y + 1) - du * ray(x, y - 1);
    vec3 u = cross(dx, dy);
    len = length(u);
    if (!(len > 0.0)) return false;
    n = u / len;
    return true;
}

// The camera-space rendered normal of pixel (x, y).
vec3 normal_cam(int x, int y) {
    uint n = pc.width * pc.height;
    uint q = uint(y) * pc.width + uint(x);
    vec3 N = vec3(pc.out_img.v[CH_NX * n + q], pc.out_img.v[CH_NY * n + q],
                  pc.out_img.v[CH_NZ * n + q]);
    return vec3(dot(pc.r0.xyz, N), dot(pc.r1.xyz, N), dot(pc.r2.xyz, N));
}

float alpha_at(int x, int y) {
    uint n = pc.width * pc.height;
    return pc.out_img.v[CH_T * n + uint(y) * pc.width + uint(x)];
}

void main() {
    uint l = gl_LocalInvocationID.x;
    uint k = linear_group_id() * 256u + l;
    uint npix = pc.width * pc.height;
    float lmed = 0.0, lmean = 0.0;
    if (k < npix) {
        int x = int(k % pc.width), y = int(k / pc.width);
        vec3 Nc = normal_cam(x, y);
        vec3 dN = vec3(0.0);
        vec3 n, dx, dy;
        float len;
        if (pc.w_med != 0.0 && dnormal(CH_DMED, x, y, n, dx, dy, len)) {
            lmed = 1.0 - dot(Nc, n);
            dN -= pc.w_med * n;
        }
        float dD = 0.0;
        if (pc.w_mean != 0.0) {
            float a = alpha_at(x, y);
            if (dnormal(CH_DEPTH, x, y, n, dx, dy, len)) {
                lmean = a * a - a * dot(Nc, n);
                dN -= pc.w_mean * a * n;
            }
            // Depth gradient gathered from the stencils pixel k belongs to: it is the
            // right neighbour of (x−1, y), the left of (x+1, y), the lower of (x, y−1)
            // and the upper of (x, y+1).
            vec3 rk = ray(x, y);
            for (int s = 0; s < 4; ++s) {
                int qx = x + (s == 0 ? -1 : (s == 1 ? 1 : 0));
                int qy = y + (s == 2 ? -1 : (s == 3 ? 1 : 0));
                if (!dnormal(CH_DEPTH, qx, qy, n, dx, dy, len)) continue;
                vec3 g = -pc.w_mean * alpha_at(qx, qy) * normal_cam(qx, qy);
                vec3 h = (g - dot(g, n) * n) / len;
                if (s == 0) dD += dot(cross(dy, h), rk);
                else if (s == 1) dD -= dot(cross(dy, h), rk);
                else if (s == 2) dD += dot(cross(h, dx), rk);
                else dD -= dot(cross(h, dx), rk);
            }
        }
        // Nc = R·N (R: the w2c rotation, rows r0..r2), so ∂L/∂N = Rᵀ·∂L/∂Nc.
        vec3 dNw = pc.r0.xyz * dN.x + pc.r1.xyz * dN.y + pc.r2.xyz * dN.z;
        pc.dout.v[DO_NX * npix + k] += dNw.x;
        pc.dout.v[DO_NY * npix + k] += dNw.y;
        pc.dout.v[DO_NZ * npix + k] += dNw.z;
        pc.dout.v[DO_DEPTH * npix + k] += dD;
    }
    s_red[0][l] = lmed;
    s_red[1][l] = lmean;
    barrier();
    for (uint s = 128u; s > 0u; s >>= 1u) {
        if (l < s) {
            s_red[0][l] += s_red[0][l + s];
            s_red[1][l] += s_red[1][l + s];
        }
        barrier();
    }
    if (l == 0u) {
        uint g = linear_group_id();
        pc.partials.v[2u * g] = s_red[0][0];
        pc.partials.v[2u * g + 1u] = s_red[1][0];
    }
}
