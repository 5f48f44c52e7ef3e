// Total variation of the grid-point densities (body of the kernels train/tv, with native
// float atomic adds, and train/tv_cas, with compare-and-swap adds: build.rs's table). Thread per voxel v with corners corners[8v + c] (c = x<<2|y<<1|z):
//   L_v = Σ over the 12 cube edges (a, b) of (geo[a] − geo[b])²
//   grad[corner c] += weight · ∂L_v/∂geo[c] = weight · 2 Σ_{k<3} (geo[c] − geo[c ^ 1<<k])
// FORM 1 (SVRaster's, cuda/src/tv_compute.cu with no_tv_s): L1 on the same edges,
//   L_v = Σ |geo[a] − geo[b]|,  grad[corner c] += weight · Σ_{k<3} s(geo[c], geo[c ^ 1<<k])
//   with s(a, b) = +1 if a > b else −1: equal ends give −1 to *both* (SVRaster's
//   tie rule, so a flat region is pushed up; not the subgradient 0).
// The adds go through atomic_add_f32 (grid points are shared between voxels). The sum
// of L_v over each workgroup (weight not applied) goes to partials[group] by a
// shared-memory tree reduction; the host adds the partials in f64.
// DETERMINISTIC (train/tv_det): `grad` is the per-voxel corner array (8 floats per voxel,
// voxel_backward's B.vcorner) and the adds are plain, one invocation per voxel;
// point_gather.comp then sums per grid point in a fixed order.
#include "atomic_f32.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    U32s corners;
    F32s geo;
    F32s grad;
    F32s partials;
    U32s lost;
    uint voxels;
    float weight;
    uint form; // 0: L2 (ours), 1: L1 with SVRaster's tie rule
    uint pad_;
} pc;

shared float red[256];

void main() {
    uint lid = gl_LocalInvocationID.x;
    uint group = linear_group_id();
    uint vox = group * 256u + lid;
    float L = 0.0;
    if (vox < pc.voxels) {
        uint idx[8];
        float g[8];
        for (uint c = 0u; c < 8u; ++c) {
            idx[c] = pc.corners.v[8u * vox + c];
            g[c] = pc.geo.v[idx[c]];
        }
        // d[c] = Σ_k (g[c] − g[c ^ 1<<k]) (L2) or Σ_k s(g[c], g[c ^ 1<<k]) (L1); each
        // edge counted from both of its ends, so Σ_c over the bit-clear ends gives L.
        bool l1 = pc.form == 1u;
        float d[8];
        for (uint c = 0u; c < 8u; ++c) {
            float e0 = g[c] - g[c ^ 4u];
            float e1 = g[c] - g[c ^ 2u];
            float e2 = g[c] - g[c ^ 1u];
            if (l1) {
                // Integer counts: exact, whatever the evaluation order.
                int n = (g[c] > g[c ^ 4u] ? 1 : -1) + (g[c] > g[c ^ 2u] ? 1 : -1)
                    + (g[c] > g[c ^ 1u] ? 1 : -1);
                d[c] = float(n);
                // Count each edge once: from its end with the bit clear.
                if ((c & 4u) == 0u) L += abs(e0);
                if ((c & 2u) == 0u) L += abs(e1);
                if ((c & 1u) == 0u) L += abs(e2);
            } else {
                d[c] = (e0 + e1) + e2;
                if ((c & 4u) == 0u) L += e0 * e0;
                if ((c & 2u) == 0u) L += e1 * e1;
                if ((c & 1u) == 0u) L += e2 * e2;
            }
        }
        float s = l1 ? pc.weight : 2.0 * pc.weight;
#ifdef DETERMINISTIC
        for (uint c = 0u; c < 8u; ++c) pc.grad.v[8u * vox + c] += s * d[c];
#else
        for (uint c = 0u; c < 8u; ++c) atomic_add_f32(pc.grad, idx[c], s * d[c], pc.lost);
#endif
    }
    red[lid] = L;
    barrier();
    for (uint w = 128u; w > 0u; w >>= 1u) {
        if (lid < w) red[lid] += red[lid + w];
        barrier();
    }
    if (lid == 0u) pc.partials.v[group] = red[0];
}
