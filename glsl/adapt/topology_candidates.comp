#version 460
// Grid-point candidates of a topology change (src/train/topology.rs), thread per voxel
// of the NEW scene (2-D grid): for each of its 8 corners (order x<<2|y<<1|z) one
// candidate at index 8·voxel + corner with
//   key   the corner's integer coordinates at the scene's finest level in use, packed
//         as x<<2b | y<<b | z with b = bits per axis (order-preserving compaction of
//         the 51-bit grid key x<<34|y<<17|z; b = 17 and shift = 0 give that key),
//   value its candidate index (the sort carries it),
//   geo   (and the geo Adam moments when present): for a voxel kept as is, the value
//         of its own grid point; for a child of a split voxel, the parent's trilinear
//         interpolation at the corner. The local coordinates are 0, ½ or 1 and weights
//         0, ½, 1 multiply exactly, so at the parent's own corners the result is
//         exactly the parent's value.
// info[v] = level | split << 8 | child << 9 (child 0..7, order x<<2|y<<1|z).
// src[v] = the old voxel it comes from (itself, or the parent of a child): corner c's
// old grid point is old_corners[8·src + c]. Everything is read from the old scene's
// device buffers (no host round trip of densities or moments).
#include "common.glsl"
#include "morton.glsl"
#include "trilinear.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    U64s path;      // [V] octpath of each new voxel
    U32s info;      // [V]
    U32s src;       // [V] source voxel in the old scene
    U32s old_corners;  // [old V * 8] old grid-point index of each old voxel corner
    F32s old_geo;   // [G] old densities
    F32s old_m;     // [G] old geo Adam m (planes == 3)
    F32s old_v;     // [G] old geo Adam v (planes == 3)
    U64s keys;      // [8V] out: compact corner keys
    U32s vals;      // [8V] out: candidate index
    F32s cand;      // [8V][planes] out: candidate geo (and m, v)
    uint voxels;
    uint shift;      // 16 - finest level in use
    uint bits;       // b = finest level in use + 1
    uint planes;     // 1 (geo) or 3 (geo, m, v)
} pc;

void main() {
    uint v = linear_group_id() * 256u + gl_LocalInvocationID.x;
    if (v >= pc.voxels) return;
    uint info = pc.info.v[v];
    uint level = info & 0xffu;
    bool split = ((info >> 8u) & 1u) != 0u;
    uint child = (info >> 9u) & 7u;
    uvec3 o = octpath_ijk(pc.path.v[v], level) << (MAX_LEVEL - level);
    uint size = 1u << (MAX_LEVEL - level);
    // Child offset inside the parent, in half-parent units (0 or 1 per axis).
    uvec3 ch = uvec3((child >> 2u) & 1u, (child >> 1u) & 1u, child & 1u);
    uint s = pc.src.v[v];
    uint pts[8];
    for (uint c = 0u; c < 8u; ++c) pts[c] = pc.old_corners.v[8u * s + c];
    for (uint p = 0u; p < pc.planes; ++p) {
        F32s plane = p == 0u ? pc.old_geo : (p == 1u ? pc.old_m : pc.old_v);
        float g[8];
        for (uint c = 0u; c < 8u; ++c) g[c] = plane.v[pts[c]];
        for (uint c = 0u; c < 8u; ++c) {
            uvec3 cb = uvec3((c >> 2u) & 1u, (c >> 1u) & 1u, c & 1u);
            float val;
            if (split) {
                vec3 q = vec3(ch + cb) * 0.5;
                val = trilinear(g, q);
            } else {
                val = g[c];
            }
            pc.cand.v[(8u * v + c) * pc.planes + p] = val;
        }
    }
    for (uint c = 0u; c < 8u; ++c) {
        uvec3 cb = uvec3((c >> 2u) & 1u, (c >> 1u) & 1u, c & 1u);
        uvec3 k = (o + size * cb) >> pc.shift;
        uint64_t key = (uint64_t(k.x) << (2u * pc.bits)) | (uint64_t(k.y) << pc.bits) | uint64_t(k.z);
        pc.keys.v[8u * v + c] = key;
        pc.vals.v[8u * v + c] = 8u * v + c;
    }
}
