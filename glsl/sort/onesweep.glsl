// One digit pass of the onesweep radix sort (u64 or u32 keys, u32 values, stable).
//
// Each workgroup claims a tile of TILE keys with an atomic counter (never by
// gl_WorkGroupID: drivers give no forward-progress guarantee in that order), then
//  1. ranks its keys locally: every subgroup owns a contiguous chunk of the tile and walks
//     it in rounds of gl_SubgroupSize keys; lanes with equal digits find each other with
//     8 ballots (one per digit bit) and a per-subgroup digit counter row in shared memory
//     gives each key its stable rank inside the chunk;
//  2. turns the per-subgroup counts into per-subgroup offsets (column scan) and tile totals;
//  3. publishes the tile totals and finds the count of each digit in all earlier tiles by
//     decoupled look-back over 64-bit status words (lookback.glsl). A predecessor that has
//     not published after `spin_limit` polls is not waited for: the whole workgroup
//     recomputes that tile's digit counts from its keys (the fallback) and goes on, so no
//     invocation ever waits on another workgroup — correct without any forward-progress
//     guarantee, and on lavapipe, whose loops stop silently after 65 535 iterations;
//  4. scatters every key to global_offset[digit] + earlier_tiles[digit] + rank.
//
// Loop bounds per invocation (lavapipe's limit is 65 535 in total): KPT rounds, RADIX/WG
// column scans of <= WG/8 steps, and one look-back step per predecessor tile that has not
// published its inclusive prefix yet; such a tile is still running, so the number of steps
// is at most the number of workgroups running concurrently (the worker threads, on
// lavapipe), each costing <= 2 * spin_limit + KPT iterations.
#include "common.glsl"
#extension GL_KHR_shader_subgroup_shuffle : require
#extension GL_EXT_control_flow_attributes : require
#include "pass_state.glsl"
#include "lookback.glsl"
#include "sort_key.glsl"
#include "sort_rank.glsl"

#define WG 128
#define KPT 16
#define TILE (WG * KPT)
#define RADIX 256
#define DPT (RADIX / WG)   // digits per invocation
#define MAX_SG (WG / 8)    // subgroups per workgroup at the smallest supported size (8)
layout(local_size_x = WG) in;

layout(push_constant) uniform Push {
    KeyBuf keys_in;
    U32s vals_in;
    KeyBuf keys_out;
    U32s vals_out;
    U32s state;
    U64s status;      // [tiles][RADIX] look-back words
    uint shift;       // first bit of this pass's digit
    uint bits;        // digit width (1..8)
    uint pass_index;  // 0..7
    uint spin_limit;  // polls of a predecessor before the fallback
    uint generic_rank; // 1: rank with ballots on any subgroup size (tests)
    uint lb_window;   // the coalesced passes' look-back window (unused here: one word at a time)
    uint lb_backoff;  // the coalesced passes' back-off between polls (unused here)
    uint pad0;        // the block's size a multiple of 8 (the Rust mirror has no padding)
} pc;

shared uint s_tile;
shared uint s_rows[MAX_SG * RADIX]; // per-subgroup digit counters, then offsets
shared uint s_base[RADIX];          // destination of the tile's first key of each digit
shared uint s_fallback[RADIX];      // digit counts of a stalled predecessor tile


void main() {
    uint t = gl_LocalInvocationID.x;
    if (t == 0u) s_tile = atomicAdd(pc.state.v[ST_TILE_CTR + pc.pass_index], 1u);
    for (uint i = t; i < MAX_SG * RADIX; i += WG) s_rows[i] = 0u;
    barrier();
    uint tile = s_tile;
    uint n = pc.state.v[ST_N];
    uint ntiles = (n + TILE - 1u) / TILE;
    if (tile >= ntiles) return; // uniform: every invocation read the same s_tile
    // A skipped pass before this one (constant digit, sort/hist_scan.comp) swaps the
    // ping-pong direction of every later pass.
    bool flip = pc.state.v[ST_FLIP + pc.pass_index] != 0u;
    KeyBuf keys_in = flip ? pc.keys_out : pc.keys_in;
    U32s vals_in = flip ? pc.vals_out : pc.vals_in;
    KeyBuf keys_out = flip ? pc.keys_in : pc.keys_out;
    U32s vals_out = flip ? pc.vals_in : pc.vals_out;

    uint digit_mask = (1u << pc.bits) - 1u;
    uint sg = gl_SubgroupID;
    uint lane = gl_SubgroupInvocationID;
    uint sgsize = gl_SubgroupSize;
    uint chunk = tile * TILE + sg * (sgsize * KPT);

    // 1. Local ranking (uniform loop: every lane runs all KPT rounds).
    KeyT k[KPT];
    uint v[KPT];
    uint rk[KPT]; // digit << 16 | rank within the subgroup's chunk
    // All loads first: independent, so their memory latencies overlap (on lavapipe a
    // load is a gather, and one per round of the ranking left the core waiting on it).
    for (uint r = 0u; r < KPT; r++) {
        uint idx = chunk + r * sgsize + lane;
        bool valid = idx < n;
        k[r] = valid ? keys_in.v[idx] : KeyT(0);
        v[r] = valid ? vals_in.v[idx] : 0u;
    }
    for (uint r = 0u; r < KPT; r++) {
        uint idx = chunk + r * sgsize + lane;
        bool valid = idx < n;
        KeyT key = k[r];
        uint d = uint(key >> pc.shift) & digit_mask;
        uvec3 rank = rank_in_subgroup(valid, d, pc.bits, pc.generic_rank == 0u);
        uint below = rank.x, cnt = rank.y;
        uint prev = valid ? s_rows[sg * RADIX + d] : 0u;
        subgroupMemoryBarrierShared();
        subgroupBarrier();
        if (valid && below == 0u) s_rows[sg * RADIX + d] = prev + cnt;
        subgroupMemoryBarrierShared();
        subgroupBarrier();
        rk[r] = (d << 16) | (prev + below);
    }
    barrier();

    // 2. Column scan: per digit, subgroup counts -> subgroup offsets; tile total.
    uint nsg = gl_NumSubgroups;
    uint count[DPT];
    for (uint q = 0u; q < DPT; q++) {
        uint d = t + q * WG;
        uint run = 0u;
        for (uint s = 0u; s < nsg; s++) {
            uint c = s_rows[s * RADIX + d];
            s_rows[s * RADIX + d] = run;
            run += c;
        }
        count[q] = run;
    }

    // 3. Publish this tile's counts, then look back.
    uint tag = pc.state.v[ST_EPOCH] + pc.pass_index;
    uint status_base = tile * RADIX;
    for (uint q = 0u; q < DPT; q++) {
        uint d = t + q * WG;
        lb_store(pc.status, status_base + d,
                 lb_pack(tag, tile == 0u ? LB_INCLUSIVE : LB_AGGREGATE, count[q]));
    }
    uint before[DPT];
    bool done[DPT];
    for (uint q = 0u; q < DPT; q++) {
        before[q] = 0u;
        done[q] = tile == 0u;
    }
    if (tile > 0u) {
        uint j = tile - 1u;
        uint lb_steps = 0u, lb_waits = 0u;
        for (;;) { // workgroup-uniform: every exit depends on lb_workgroup_or results only
            bool pending[DPT];
            bool any_pending = false;
            for (uint q = 0u; q < DPT; q++) {
                pending[q] = false;
                if (!done[q]) {
                    uint idx = j * RADIX + t + q * WG;
                    uint64_t w = lb_load(pc.status, idx);
                    uint f = lb_flag(w, tag);
                    uint s = 0u;
                    for (; f == 0u && s < pc.spin_limit; s++) {
                        w = lb_load(pc.status, idx);
                        f = lb_flag(w, tag);
                    }
                    lb_waits += s;
                    if (f == 0u) {
                        pending[q] = true;
                        any_pending = true;
                    } else {
                        lb_steps++;
                        before[q] += lb_value(w);
                        done[q] = f == LB_INCLUSIVE;
                    }
                }
            }
            if (lb_workgroup_or(any_pending ? 1u : 0u) != 0u) {
                // Fallback: count tile j's digits from its keys (tile j < tile is full).
                for (uint i = t; i < RADIX; i += WG) s_fallback[i] = 0u;
                if (t == 0u) atomicAdd(pc.state.v[ST_LB_FALLBACKS], 1u);
                barrier();
                for (uint r = 0u; r < KPT; r++) {
                    KeyT key = keys_in.v[j * TILE + r * WG + t];
                    atomicAdd(s_fallback[uint(key >> pc.shift) & digit_mask], 1u);
                }
                barrier();
                for (uint q = 0u; q < DPT; q++) {
                    if (pending[q]) {
                        before[q] += s_fallback[t + q * WG];
                        done[q] = j == 0u; // tile 0's aggregate is its inclusive prefix
                    }
                }
            }
            bool all_done = true;
            for (uint q = 0u; q < DPT; q++) all_done = all_done && done[q];
            uint not_done = lb_workgroup_or(all_done ? 0u : 1u);
            if (not_done == 0u) break;
            if (j == 0u) {
                if (t == 0u) atomicOr(pc.state.v[ST_ERRORS], ERR_LOOKBACK);
                break;
            }
            j--;
        }
        for (uint q = 0u; q < DPT; q++) {
            uint d = t + q * WG;
            lb_store(pc.status, status_base + d, lb_pack(tag, LB_INCLUSIVE, before[q] + count[q]));
        }
        // Counters (bench sort): one global add per subgroup.
        uint sst = subgroupAdd(lb_steps), swt = subgroupAdd(lb_waits);
        if (subgroupElect()) {
            atomicAdd(pc.state.v[ST_LB_STEPS], sst);
            atomicAdd(pc.state.v[ST_LB_WAITS], swt);
        }
    }
    uint hist_base = ST_HIST + pc.pass_index * RADIX;
    for (uint q = 0u; q < DPT; q++) {
        uint d = t + q * WG;
        s_base[d] = pc.state.v[hist_base + d] + before[q];
    }
    barrier();

    // 4. Scatter.
    for (uint r = 0u; r < KPT; r++) {
        uint idx = chunk + r * sgsize + lane;
        if (idx < n) {
            uint d = rk[r] >> 16;
            uint dst = s_base[d] + s_rows[sg * RADIX + d] + (rk[r] & 0xffffu);
            keys_out.v[dst] = k[r];
            vals_out.v[dst] = v[r];
        }
    }
}
