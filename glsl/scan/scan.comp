#version 460
// Single-pass exclusive prefix sum of u32 (wrapping), with decoupled look-back.
// Tiles are claimed with an atomic counter; a predecessor that has not published after
// `spin_limit` polls has its tile sum recomputed from its input by the whole workgroup
// (fallback), so no invocation ever waits on another workgroup. The output must not
// alias the input (the fallback rereads predecessors' input). Writes the total to
// state[ST_TOTAL] and, if non-null, to total[0].
#include "common.glsl"
#include "pass_state.glsl"
#include "lookback.glsl"

#define WG 256
#define IPT 8
#define TILE (WG * IPT)
layout(local_size_x = WG) in;

layout(push_constant) uniform Push {
    U32s src;
    U32s dst;
    U32s state;
    U64s status;   // [tiles] look-back words
    U32s total;    // optional
    uint spin_limit;
    uint pad;
} pc;

shared uint s_tile;
shared uint s_sg[WG / 8];
shared uint s_agg;
shared uint s_fallback;
shared uint s_before;

void main() {
    uint t = gl_LocalInvocationID.x;
    if (t == 0u) s_tile = atomicAdd(pc.state.v[ST_TILE_CTR], 1u);
    barrier();
    uint tile = s_tile;
    uint n = pc.state.v[ST_N];
    uint ntiles = (n + TILE - 1u) / TILE;
    if (tile >= ntiles) return; // uniform

    uint base = tile * TILE + t * IPT;
    uint x[IPT];
    uint sum = 0u;
    for (uint i = 0u; i < IPT; i++) {
        uint idx = base + i;
        x[i] = idx < n ? pc.src.v[idx] : 0u;
        sum += x[i];
    }
    uint in_sg = subgroupExclusiveAdd(sum);
    uint sg_total = subgroupAdd(sum);
    if (subgroupElect()) s_sg[gl_SubgroupID] = sg_total;
    barrier();
    if (t == 0u) {
        uint run = 0u;
        for (uint s = 0u; s < gl_NumSubgroups; s++) {
            uint c = s_sg[s];
            s_sg[s] = run;
            run += c;
        }
        s_agg = run;
    }
    barrier();
    uint agg = s_agg;
    uint tag = pc.state.v[ST_EPOCH];
    if (t == 0u) {
        atomicExchange(pc.status.v[tile], lb_pack(tag, tile == 0u ? LB_INCLUSIVE : LB_AGGREGATE, agg));
    }
    uint before = 0u;
    if (tile > 0u) {
        bool done = false;
        uint j = tile - 1u;
        for (;;) { // workgroup-uniform
            bool pending = false;
            if (t == 0u) {
                uint64_t w = atomicAdd(pc.status.v[j], 0ul);
                uint f = lb_flag(w, tag);
                for (uint s = 0u; f == 0u && s < pc.spin_limit; s++) {
                    w = atomicAdd(pc.status.v[j], 0ul);
                    f = lb_flag(w, tag);
                }
                if (f == 0u) {
                    pending = true;
                } else {
                    before += lb_value(w);
                    done = f == LB_INCLUSIVE;
                }
            }
            if (lb_workgroup_or(pending ? 1u : 0u) != 0u) {
                if (t == 0u) s_fallback = 0u;
                barrier();
                uint part = 0u;
                for (uint i = 0u; i < IPT; i++) part += pc.src.v[j * TILE + t * IPT + i];
                part = subgroupAdd(part);
                if (subgroupElect()) atomicAdd(s_fallback, part);
                barrier();
                if (t == 0u) {
                    before += s_fallback;
                    done = j == 0u;
                }
            }
            if (lb_workgroup_or((t == 0u && !done) ? 1u : 0u) == 0u) break;
            if (j == 0u) {
                if (t == 0u) atomicOr(pc.state.v[ST_ERRORS], ERR_LOOKBACK);
                break;
            }
            j--;
        }
        if (t == 0u) {
            atomicExchange(pc.status.v[tile], lb_pack(tag, LB_INCLUSIVE, before + agg));
            s_before = before;
        }
        barrier();
        before = s_before;
    }
    uint run = before + s_sg[gl_SubgroupID] + in_sg;
    for (uint i = 0u; i < IPT; i++) {
        uint idx = base + i;
        if (idx < n) pc.dst.v[idx] = run;
        run += x[i];
    }
    if (tile == ntiles - 1u && t == 0u) {
        pc.state.v[ST_TOTAL] = before + agg;
        if (uint64_t(pc.total) != 0ul) pc.total.v[0] = before + agg;
    }
}
