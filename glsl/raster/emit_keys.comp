#version 460
// Emits one (key, value) pair per entry, one invocation per entry (so a voxel covering
// the whole screen costs no long loop): the owning voxel is found by binary search in
// the exclusive scan of the per-voxel counts.
//   key   = tile_id << (3 * max_level) | direction-dependent Morton order (top 3*max_level
//           bits of the 48-bit path; lower levels are unused by every voxel)
//   value = sign << 29 | voxel id
// Stored as u32 when P.key32 (tile and Morton bits fit in 32: the sort moves less).
#include "raster_params.glsl"
#include "morton.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams frame;
} pc;

shared uint s_range[2];

// Last voxel whose offset is <= i (it has a non-zero count), given
// offsets[lo] <= i < offsets[hi] (hi = voxels: infinity).
uint find_voxel(FrameParams P, uint i, uint lo, uint hi) {
    while (hi - lo > 1u) {
        uint mid = (lo + hi) >> 1u;
        if (P.offsets.v[mid] <= i) lo = mid; else hi = mid;
    }
    return lo;
}

void main() {
    FrameParams P = pc.frame;
    uint used = P.stats.v[STAT_USED];
    uint i0 = linear_group_id() * 256u;
    if (i0 >= used) return;  // the whole workgroup
    // Two invocations find the voxels of the group's first and last entries; every
    // invocation then searches only between them (at most 256 voxels: every voxel owns
    // at least one entry), instead of each walking a chain of log2(voxels) dependent
    // loads from the whole offset array.
    uint l = gl_LocalInvocationID.x;
    if (l < 2u) s_range[l] = find_voxel(P, l == 0u ? i0 : min(i0 + 255u, used - 1u), 0u, P.voxels);
    barrier();
    uint i = i0 + l;
    if (i >= used) return;
    uint v = find_voxel(P, i, s_range[0], min(s_range[1] + 1u, P.voxels));
    uint r = i - P.offsets.v[v];

    uvec2 box = uvec2(P.bbox.v[2u * v], P.bbox.v[2u * v + 1u]);
    uvec2 tlo = uvec2(box.x & 0xffffu, box.x >> 16u) / 16u;
    uvec2 thi = uvec2(box.y & 0xffffu, box.y >> 16u) / 16u;
    uint tw = thi.x - tlo.x + 1u;
    uint ntiles = tw * (thi.y - tlo.y + 1u);
    uint si = r / ntiles, tr = r % ntiles;

    // si-th set bit of the sign octants.
    uint signs = P.signs.v[v];
    for (uint k = 0u; k < si; ++k) signs &= signs - 1u;
    uint sign = uint(findLSB(signs));

    uint tile = (tlo.y + tr / tw) * P.tiles.x + tlo.x + tr % tw;
    uint shift = P.key_shift;
    uint64_t order = dir_morton_order(P.octpath.v[v], sign) >> (48u - shift);
    uint64_t key = (uint64_t(tile) << shift) | order;
    if (P.key32 != 0u) {
        U32s(uint64_t(P.keys)).v[i] = uint(key);  // the key's bits fit in 32
    } else {
        P.keys.v[i] = key;
    }
    P.vals.v[i] = (sign << 29u) | v;
}
