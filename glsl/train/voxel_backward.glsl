// Training backward, per voxel (kernels train/voxel_backward[_cas], from build.rs's table): the voxel's
// accumulated ∂L/∂rgb through max(0, 0.5 + SH) (the clamp read from the colour preprocess
// stored, not recomputed from the 48 coefficients) to its SH coefficients (written, so
// voxels off screen get zeros), ∂L/∂normal through n = ∇/|∇| and the centre gradient to
// its 8 corner densities, and those through the corner indices into the grid points'
// gradients (float atomics: neighbours share grid points). Adds the entry priorities.
// DETERMINISTIC: the 8 corner gradients are written to B.vcorner (per voxel) instead, and
// point_gather.comp sums them per grid point in a fixed order.
#include "atomic_f32.glsl"
#include "raster_params.glsl"
#include "sh.glsl"
#include "sh_layout.glsl"
#include "trilinear.glsl"
#include "backward_params.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams frame;
    BackParams back;
} pc;

void main() {
    FrameParams P = pc.frame;
    BackParams B = pc.back;
    uint v = linear_group_id() * 256u + gl_LocalInvocationID.x;
    if (v >= P.voxels) return;
    uint stride = P.shs_stride;
    uint degree = P.sh_degree;
    uint nc = (degree + 1u) * (degree + 1u) - 1u;
    if (P.counts.v[v] == 0u) {
        for (uint c = 0u; c < 3u; ++c) B.grad_sh0.v[3u * v + c] = 0.0;
        for (uint e = 0u; e < 3u * stride; ++e) B.grad_shs.v[shs_index(v, e, 3u * stride)] = 0.0;
#ifdef DETERMINISTIC
        for (uint c = 0u; c < 8u; ++c) B.vcorner.v[8u * v + c] = 0.0;
#endif
        return;
    }
    uint rec = VG_STRIDE * v;
    vec3 drgb = vec3(B.vgrad.v[rec + VG_RGB], B.vgrad.v[rec + VG_RGB + 1u], B.vgrad.v[rec + VG_RGB + 2u]);
    vec3 dn = vec3(B.vgrad.v[rec + VG_NRM], B.vgrad.v[rec + VG_NRM + 1u], B.vgrad.v[rec + VG_NRM + 2u]);

    // SH: the forward's clamp max(0, 0.5 + SH) passes the gradient where its colour
    // (stored by preprocess) is positive, or everywhere with colour_straight
    // (SVRaster's backward, its mask commented out).
    vec3 centre = vec3(P.cs.v[4u * v], P.cs.v[4u * v + 1u], P.cs.v[4u * v + 2u]);
    float y[16];
    sh_basis(normalize(centre), degree, y);
    vec3 rgb = vec3(P.rgb.v[3u * v], P.rgb.v[3u * v + 1u], P.rgb.v[3u * v + 2u]);
    if (B.colour_straight == 0u) drgb = mix(vec3(0.0), drgb, greaterThan(rgb, vec3(0.0)));
    for (uint c = 0u; c < 3u; ++c) B.grad_sh0.v[3u * v + c] = y[0] * drgb[c];
    for (uint k = 1u; k <= stride; ++k) {
        vec3 gk = k <= nc ? y[k] * drgb : vec3(0.0);
        for (uint c = 0u; c < 3u; ++c)
            B.grad_shs.v[shs_index(v, 3u * (k - 1u) + c, 3u * stride)] = gk[c];
    }

    // Normal n = ∇/|∇| of the centre gradient ∇ (zero gradient where |∇|² ≤ 1e-30).
    float g[8], dg[8];
    for (uint c = 0u; c < 8u; ++c) {
        g[c] = P.geo8.v[8u * v + c];
        dg[c] = B.vgrad.v[rec + VG_GEO + c];
    }
    vec3 grad = centre_gradient(g);
    float l2 = dot(grad, grad);
    if (l2 > 1e-30) {
        float inv = inversesqrt(l2);
        vec3 n = grad * inv;
        vec3 dgrad = (dn - n * dot(n, dn)) * inv;
        for (uint c = 0u; c < 8u; ++c) {
            dg[c] += ((c & 4u) != 0u ? dgrad.x : -dgrad.x) + ((c & 2u) != 0u ? dgrad.y : -dgrad.y) +
                     ((c & 1u) != 0u ? dgrad.z : -dgrad.z);
        }
    }
#ifdef DETERMINISTIC
    for (uint c = 0u; c < 8u; ++c) B.vcorner.v[8u * v + c] = dg[c];
#else
    for (uint c = 0u; c < 8u; ++c) atomic_add_f32(B.grad_geo, P.corners.v[8u * v + c], dg[c], B.lost);
#endif
    B.priority.v[v] += B.vgrad.v[rec + VG_PRIO];
}
