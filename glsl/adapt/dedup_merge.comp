#version 460
// Grid-point dedup, step 2 (src/train/topology.rs), thread per sorted candidate i:
//   uid = scan[i] + heads[i] - 1      (scan = exclusive prefix sum of heads)
//   corners[vals[i]] = uid            (vals = candidate index = 8·voxel + corner)
// and the head of each run (at most 8 candidates, checked by dedup_heads; the loop is
// bounded by 8 regardless) writes the unique grid point: its full 51-bit key and the
// mean of the run's candidate values per plane (geo, then the geo Adam moments when
// planes == 3). The mean is taken as v0 + Σ(vj − v0)/count, so a run of equal values
// averages to exactly that value (a point untouched by the change keeps its density
// bit for bit). The sort is stable: a run lists its candidates by index, so the
// summation order is deterministic.
#include "common.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    U64s keys;      // [n] sorted compact keys
    U32s vals;      // [n] candidate index of each sorted key
    U32s heads;     // [n]
    U32s scan;      // [n] exclusive scan of heads
    F32s cand;      // [n][planes] candidate values by candidate index
    U32s corners;   // [n] out: grid-point index of each candidate
    U64s out_keys;  // [U] out: unique 51-bit grid keys, ascending
    F32s out_vals;  // [planes][n] out: plane p of unique point u at p * n + u
    uint count;     // n
    uint shift;     // compact → fine coordinates
    uint bits;      // bits per axis of the compact key
    uint planes;
} pc;

void main() {
    uint i = linear_group_id() * 256u + gl_LocalInvocationID.x;
    uint n = pc.count;
    if (i >= n) return;
    uint h = pc.heads.v[i];
    uint uid = pc.scan.v[i] + h - 1u;
    pc.corners.v[pc.vals.v[i]] = uid;
    if (h == 0u) return;
    uint64_t k = pc.keys.v[i];
    // Candidates of the run after the head (at most 7).
    uint idx[7];
    uint extra = 0u;
    for (uint j = 1u; j < 8u; ++j) {
        if (i + j >= n || pc.keys.v[i + j] != k) break;
        idx[j - 1u] = pc.vals.v[i + j];
        extra = j;
    }
    uint c0 = pc.vals.v[i];
    float cnt = float(extra + 1u);
    for (uint p = 0u; p < pc.planes; ++p) {
        float v0 = pc.cand.v[c0 * pc.planes + p];
        float dev = 0.0;
        for (uint j = 0u; j < 7u; ++j) {
            if (j < extra) dev += pc.cand.v[idx[j] * pc.planes + p] - v0;
        }
        pc.out_vals.v[p * n + uid] = extra == 0u ? v0 : v0 + dev / cnt;
    }
    uint64_t m = (1ul << pc.bits) - 1ul;
    uint64_t x = ((k >> (2u * pc.bits)) & m) << pc.shift;
    uint64_t y = ((k >> pc.bits) & m) << pc.shift;
    uint64_t z = (k & m) << pc.shift;
    pc.out_keys.v[uid] = (x << 34u) | (y << 17u) | z;
}
