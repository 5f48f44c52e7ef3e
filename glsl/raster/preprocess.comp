#version 460
// Preprocess, one invocation per voxel (paper §3.1.2; docs/ARCHITECTURE.md §3): voxel geometry
// relative to the camera, near-plane clipping and projection to a pixel rectangle,
// the ray-sign octants that can hit the voxel, the number of (tile, sign) entries,
// gathered corner densities, SH colour and normal.
#include "raster_params.glsl"
#include "morton.glsl"
#include "sh.glsl"
#include "sh_layout.glsl"
#include "trilinear.glsl"
#include "ray_aabb.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams frame;
} pc;

void project(FrameParams P, vec3 c, inout vec2 lo, inout vec2 hi) {
    vec2 uv = vec2(P.intr.x * c.x / c.z + P.intr.z, P.intr.y * c.y / c.z + P.intr.w);
    lo = min(lo, uv);
    hi = max(hi, uv);
}

void main() {
    FrameParams P = pc.frame;
    uint v = linear_group_id() * 256u + gl_LocalInvocationID.x;
    uint n = P.voxels;
    if (v >= n) return;

    uint level = P.level.v[v];
    uvec3 ijk = octpath_ijk(P.octpath.v[v], level);
    uint shift = MAX_LEVEL - level;
    float size = P.unit * float(1u << shift);
    vec3 vmin = grid_to_camera(P, ijk << shift);  // camera-relative
    vec3 vmax = vmin + size;
    vec3 centre = vmin + 0.5 * size;
    float near = P.near;

    // Camera-space corners.
    vec3 cc[8];
    bool any_front = false;
    bool all_front = true;
    for (uint c = 0u; c < 8u; ++c) {
        vec3 p = vec3((c & 4u) != 0u ? vmax.x : vmin.x, (c & 2u) != 0u ? vmax.y : vmin.y,
                      (c & 1u) != 0u ? vmax.z : vmin.z);
        cc[c] = vec3(dot(P.w2c[0].xyz, p), dot(P.w2c[1].xyz, p), dot(P.w2c[2].xyz, p));
        bool front = cc[c].z >= near;
        any_front = any_front || front;
        all_front = all_front && front;
    }

    uint count = 0u;
    uint signs = 0u;
    uvec2 box = uvec2(0u);
    if (any_front) {
        // Screen bounds of the part in front of the near plane: front corners plus
        // the points where box edges cross the plane (exact for the clipped box).
        vec2 lo = vec2(RAY_BIG), hi = vec2(-RAY_BIG);
        for (uint c = 0u; c < 8u; ++c) {
            if (cc[c].z >= near) project(P, cc[c], lo, hi);
        }
        if (!all_front) {
            for (uint c = 0u; c < 8u; ++c) {
                for (uint b = 1u; b <= 4u; b <<= 1u) {
                    if ((c & b) != 0u) continue;
                    vec3 p0 = cc[c], p1 = cc[c | b];
                    if ((p0.z >= near) != (p1.z >= near)) {
                        float t = (near - p0.z) / (p1.z - p0.z);
                        vec3 p = mix(p0, p1, t);
                        p.z = near;
                        project(P, p, lo, hi);
                    }
                }
            }
        }
        // Pixel i is hit through u = i + 0.5: i in [ceil(lo - 0.5), floor(hi - 0.5)],
        // widened by a small epsilon against rounding (exact tests happen per pixel).
        float W = float(P.render_size.x), H = float(P.render_size.y);
        vec2 flo = clamp(ceil(lo - 0.5 - 0.01), vec2(0.0), vec2(W, H));
        vec2 fhi = clamp(floor(hi - 0.5 + 0.01), vec2(-1.0), vec2(W - 1.0, H - 1.0));
        if (flo.x <= fhi.x && flo.y <= fhi.y) {
            uvec2 plo = uvec2(flo), phi = uvec2(fhi);
            box = uvec2(plo.x | (plo.y << 16u), phi.x | (phi.y << 16u));
            uvec2 tlo = plo / 16u, thi = phi / 16u;
            // Octants of directions from the camera to points of the voxel; a ray
            // component's sign bit is set when it is negative, and a zero component
            // counts as positive (it can only meet voxels with lo <= 0 < hi).
            bvec3 neg = lessThan(vmin, vec3(0.0));
            bvec3 pos = greaterThanEqual(vmax, vec3(0.0));
            for (uint s = 0u; s < 8u; ++s) {
                bool ok = ((s & 4u) != 0u ? neg.x : pos.x) && ((s & 2u) != 0u ? neg.y : pos.y) &&
                          ((s & 1u) != 0u ? neg.z : pos.z);
                if (ok) signs |= 1u << s;
            }
            count = bitCount(signs) * (thi.x - tlo.x + 1u) * (thi.y - tlo.y + 1u);
        }
    }
    P.bbox.v[2u * v] = box.x;
    P.bbox.v[2u * v + 1u] = box.y;
    P.signs.v[v] = signs;
    P.counts.v[v] = count;

    // Totals: one 64-bit atomic per subgroup (the frame total can exceed 32 bits). A
    // voxel's count (8 signs x its tiles) fits 32 bits, a subgroup's sum may not (64
    // lanes of voxels over 8.4 M tiles each): summed in 16-bit halves, exact.
    uint sub_hi = subgroupAdd(count >> 16u);     // <= 64 * 2^16
    uint sub_lo = subgroupAdd(count & 0xffffu);  // <= 64 * 2^16
    uint64_t sub_total = (uint64_t(sub_hi) << 16) + uint64_t(sub_lo);
    uint sub_visible = subgroupAdd(count > 0u ? 1u : 0u);
    if (subgroupElect()) {
        atomicAdd(U64s(uint64_t(P.stats)).v[STAT_TOTAL / 2u], sub_total);
        atomicAdd(P.stats.v[STAT_VISIBLE], sub_visible);
    }
    if (count == 0u) return;

    float g[8];
    for (uint c = 0u; c < 8u; ++c) {
        g[c] = P.geo.v[P.corners.v[8u * v + c]];
        P.geo8.v[8u * v + c] = g[c];
    }
    vec3 grad = centre_gradient(g);
    vec3 nrm = grad * inversesqrt(max(dot(grad, grad), 1e-30));

    // Colour from the direction camera -> voxel centre.
    uint degree = P.sh_degree;
    float y[16];
    sh_basis(normalize(centre), degree, y);
    vec3 rgb = y[0] * vec3(P.sh0.v[3u * v], P.sh0.v[3u * v + 1u], P.sh0.v[3u * v + 2u]);
    uint nc = (degree + 1u) * (degree + 1u) - 1u;  // active (degree may be raised during training)
    uint w = 3u * P.shs_stride;                        // values stored per voxel
    for (uint k = 1u; k <= nc; ++k) {
        uint e = 3u * (k - 1u);
        rgb += y[k] * vec3(P.shs.v[shs_index(v, e, w)], P.shs.v[shs_index(v, e + 1u, w)],
                           P.shs.v[shs_index(v, e + 2u, w)]);
    }
    rgb = max(rgb + 0.5, vec3(0.0));

    for (uint c = 0u; c < 3u; ++c) {
        P.rgb.v[3u * v + c] = rgb[c];
        P.nrm.v[3u * v + c] = nrm[c];
        P.cs.v[4u * v + c] = centre[c];
    }
    P.cs.v[4u * v + 3u] = size;
}
