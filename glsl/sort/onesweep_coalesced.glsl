// One digit pass of the onesweep radix sort built for GPUs (32- and 64-lane subgroups):
// the keys of a tile are ranked with warp-level multisplit, staged in shared memory in
// their sorted order, and written out in runs, so that consecutive invocations write
// consecutive addresses of one digit's bucket (coalesced) instead of one scattered
// 12-byte write per key. Same result, state and look-back words as onesweep.glsl (the
// lavapipe pass), between which src/sort chooses from the device's subgroup size and
// shared memory.
//
// Where the choices come from:
// - Adinets & Merrill, "Onesweep" (2022) and CUB's DeviceRadixSort onesweep: one pass per
//   8-bit digit after one histogram of every digit, tiles claimed in the order workgroups
//   start (an atomic counter), decoupled look-back over (flag, value) words.
// - b0nes164/GPUSorting (OneSweep.cu, DigitBinningPassPairs): warp-level multisplit (one
//   ballot per digit bit, the lowest matching lane adds the run's count to its
//   subgroup's histogram row and shuffles the old value to the others), per-subgroup
//   histogram rows scanned down the columns, keys staged in shared memory at their
//   tile-local sorted position before the look-back (so its latency overlaps that work),
//   then written out as runs; 15 keys per invocation.
// - Ours: 64-bit keys staged as two words and values staged in a second round (one
//   32 KiB-class array instead of 45 KiB); the look-back has the bounded spin and the
//   recount fallback of onesweep.glsl (no invocation waits on another workgroup, so it
//   needs no forward-progress guarantee), but every digit walks back on its own and the
//   workgroup votes only once per round of stalls instead of once per predecessor tile.
//
// With SCAN_PREFIX (the reduce-then-scan passes, src/sort SortPass::Scan*) there is no
// look-back: sort/tile_count.glsl and sort/tile_scan.comp have already written, per digit
// and tile, the count of that digit in every earlier tile (CUB's and GPUSorting's older
// DeviceRadixSort: upsweep, scan, downsweep), and tiles are workgroup ids.
//
// With PROBE (src/sort SortPass probes, `bench sort --probe`: timing instruments, not
// sorts) the pass does only a part of its work, so that a device's pass time can be
// taken apart: PROBE 1 ("copy") loads each tile and writes it back through shared memory
// at the same positions (no ranking, no look-back: the output is the input); PROBE 2
// ("tile") ranks and stages as the pass does, with no look-back, and writes each tile's
// keys back into the tile's own slots in their tile-local sorted order (a pass of an
// LSD sort within every tile: the output is each tile sorted by the bits passed).
// Tiles are workgroup ids, as with SCAN_PREFIX.
//
// Defines (build.rs variants): WG invocations, KPT keys per invocation, MIN_SG the
// smallest subgroup size the variant supports (its shared histogram rows: WG / MIN_SG).
#include "common.glsl"
#ifndef PROBE
#define PROBE 0 // the pass itself
#endif
#if defined(SCAN_PREFIX) || PROBE != 0
#define NO_LOOKBACK // offsets from a scan over the tiles, or none (probes)
#endif
#extension GL_KHR_shader_subgroup_shuffle : require
#extension GL_EXT_control_flow_attributes : require
#include "pass_state.glsl"

#define TILE (WG * KPT)
#define RADIX 256
#define DPT (RADIX / WG)      // digits per invocation (WG <= 256)
#define MAX_SG (WG / MIN_SG)  // subgroups per workgroup at most
#define ROWS_WORDS (MAX_SG * RADIX)
#define STAGE_WORDS (2 * TILE) // u64 keys as two words, or u32 keys then values
#define LB_WINDOW 8           // most look-back words a digit reads at once

// Shared memory: 32 768 bytes for 256 invocations, so that the pass fits a 32 KiB
// device (lavapipe, where its 16-lane subgroups then run it in tests). The scalars live
// in words that are idle while they are used (build.rs reflects the total; a test in
// src/sort/pass.rs holds it to 32 KiB):
// - the tile index in s_base[0]: read once after the first barrier; s_base is written
//   first after step 2's barrier;
// - s_part (step 3) past the subgroup rows in s_mem, where the tile is staged only in
//   step 4, when there is room there (256 invocations; 128 have no spare words);
// - the look-back's vote, stalled-tile and counter words in s_local, which every
//   invocation has read into registers before the look-back starts (step 4).
#if STAGE_WORDS >= ROWS_WORDS + MAX_SG
#define MEM_WORDS STAGE_WORDS
#define S_PART(s) s_mem[ROWS_WORDS + (s)]
#else
#define MEM_WORDS (ROWS_WORDS > STAGE_WORDS ? ROWS_WORDS : STAGE_WORDS)
shared uint s_part[MAX_SG];   // subgroup sums of the digit scan
#define S_PART(s) s_part[s]
#endif
shared uint s_mem[MEM_WORDS];  // subgroup histogram rows, then the staged tile
shared uint s_local[RADIX];    // tile-local start of each digit (until step 4)
shared uint s_base[RADIX];     // fallback counts during look-back; then global base - local start
#define S_TILE s_base[0]
#define LB_VOTE s_local[0]
#define S_JMAX s_local[1]      // look-back: the nearest tile a digit stalled on
#define S_LB(i) s_local[2 + (i)] // look-back steps and extra polls of the workgroup

#include "lookback.glsl"
#include "sort_key.glsl"
#include "sort_rank.glsl"
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
    uint lb_window;   // look-back: predecessors' words read at once per digit (1..LB_WINDOW)
    uint lb_backoff;  // look-back: ALU rounds between two polls of an unpublished word
    uint pad0;        // the block's size a multiple of 8 (the Rust mirror has no padding)
} pc;

void main() {
    uint t = gl_LocalInvocationID.x;
#ifndef NO_LOOKBACK
    if (t == 0u) S_TILE = atomicAdd(pc.state.v[ST_TILE_CTR + pc.pass_index], 1u);
#endif
#if PROBE != 1 // the copy probe uses no histogram rows
    for (uint i = t; i < ROWS_WORDS; i += WG) s_mem[i] = 0u;
#endif
    barrier();
#ifdef NO_LOOKBACK
    uint tile = linear_group_id(); // no look-back: tiles need not start in order
#else
    uint tile = S_TILE;
#endif
    uint n = pc.state.v[ST_N];
    uint ntiles = (n + TILE - 1u) / TILE;
    if (tile >= ntiles) return; // uniform: every invocation read the same tile index
    uint tile_n = min(TILE, n - tile * TILE);
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

    // 1. Load (coalesced: each subgroup owns a contiguous chunk, round-major), then rank
    // within the subgroup: loc = keys of the same digit earlier in the subgroup's chunk.
    KeyT k[KPT];
    uint v[KPT];
    uint loc[KPT];
    [[unroll]] for (uint r = 0u; r < KPT; r++) {
        uint idx = chunk + r * sgsize + lane;
        bool valid = idx < n;
        k[r] = valid ? keys_in.v[idx] : KeyT(0);
        v[r] = valid ? vals_in.v[idx] : 0u;
    }
    // Unrolled: k[], v[] and loc[] must stay in registers (an array indexed by a loop
    // counter the compiler does not unroll goes to local memory on GPUs).
#if PROBE == 1
    // The copy probe: each key's slot is its load position within the tile.
    [[unroll]] for (uint r = 0u; r < KPT; r++)
        loc[r] = chunk - tile * TILE + r * sgsize + lane;
#else
    [[unroll]] for (uint r = 0u; r < KPT; r++) {
        bool valid = chunk + r * sgsize + lane < n;
        uint d = uint(k[r] >> pc.shift) & digit_mask;
        uvec3 rank = rank_in_subgroup(valid, d, pc.bits, pc.generic_rank == 0u);
        uint below = rank.x, cnt = rank.y, leader = rank.z;
        // The lowest lane of each digit's run adds the run to the subgroup's row; the
        // others get the old value from it. The next round's adds follow this round's:
        // its shuffle waits for them.
        uint pre = 0u;
        if (valid && below == 0u) pre = atomicAdd(s_mem[sg * RADIX + d], cnt);
        pre = subgroupShuffle(pre, leader);
        loc[r] = pre + below;
    }
#endif
    barrier();

#if PROBE != 1
    // 2. Down each digit's column: subgroup counts -> subgroup offsets; tile counts.
    uint nsg = gl_NumSubgroups;
    uint count[DPT];
    [[unroll]] for (uint q = 0u; q < DPT; q++) {
        uint d = t + q * WG;
        uint run = 0u;
        for (uint s = 0u; s < nsg; s++) {
            uint c = s_mem[s * RADIX + d];
            s_mem[s * RADIX + d] = run;
            run += c;
        }
        count[q] = run;
        s_local[d] = run;
    }
#ifndef NO_LOOKBACK
    // Publish the tile's counts at once: successors' look-back may stop here.
    uint tag = pc.state.v[ST_EPOCH] + pc.pass_index;
    uint status_base = tile * RADIX;
    [[unroll]] for (uint q = 0u; q < DPT; q++) {
        lb_store(pc.status, status_base + t + q * WG,
                 lb_pack(tag, tile == 0u ? LB_INCLUSIVE : LB_AGGREGATE, count[q]));
    }
#endif
    barrier();

    // 3. Exclusive scan of the tile's counts over the digits: each invocation takes DPT
    // consecutive digits, subgroups scan, s_part carries the subgroup sums.
    uint mine[DPT];
    uint sum = 0u;
    [[unroll]] for (uint q = 0u; q < DPT; q++) {
        mine[q] = s_local[t * DPT + q];
        sum += mine[q];
    }
    uint excl = subgroupExclusiveAdd(sum);
    if (lane == sgsize - 1u) S_PART(sg) = excl + sum;
    barrier();
    for (uint s = 0u; s < sg; s++) excl += S_PART(s);
    [[unroll]] for (uint q = 0u; q < DPT; q++) {
        s_local[t * DPT + q] = excl;
        excl += mine[q];
    }
    barrier();

    // 4. Tile-local sorted position of each key; stage the keys there (two words per
    // u64 key; u32 keys and their values in one round).
    [[unroll]] for (uint r = 0u; r < KPT; r++) {
        uint d = uint(k[r] >> pc.shift) & digit_mask;
        loc[r] += s_mem[sg * RADIX + d] + s_local[d];
    }
    uint local_start[DPT]; // s_local's words take the look-back's scalars from here on
    [[unroll]] for (uint q = 0u; q < DPT; q++) local_start[q] = s_local[t + q * WG];
    barrier();
#endif // PROBE != 1
#ifndef NO_LOOKBACK
    if (t == 0u) {
        S_LB(0) = 0u;
        S_LB(1) = 0u;
    }
#endif
    [[unroll]] for (uint r = 0u; r < KPT; r++) {
        if (chunk + r * sgsize + lane < n) {
#ifdef KEY32
            s_mem[loc[r]] = k[r];
            s_mem[TILE + loc[r]] = v[r];
#else
            s_mem[2u * loc[r]] = uint(k[r]);
            s_mem[2u * loc[r] + 1u] = uint(k[r] >> 32);
#endif
        }
    }

#if PROBE != 0
    // 5. (probes) No offsets: every key goes back into its own tile's slots.
    [[unroll]] for (uint q = 0u; q < DPT; q++) s_base[t + q * WG] = tile * TILE;
#else
    uint before[DPT];
#ifdef SCAN_PREFIX
    // 5. The keys of this digit in every earlier tile: sort/tile_count.glsl counted
    // them and sort/tile_scan.comp summed them over the tiles (digit-major words in the
    // status buffer), so no workgroup waits on another.
    U32s prefix = U32s(uint64_t(pc.status));
    [[unroll]] for (uint q = 0u; q < DPT; q++)
        before[q] = prefix.v[(t + q * WG) * ntiles + tile];
#else
    // 5. Look-back: every digit walks back on its own. A predecessor that has not
    // published after `spin_limit` polls stalls its digit; then the workgroup recounts
    // the nearest stalled tile from its keys (the fallback: tile j < tile is full) and
    // the digits stalled there go on. One workgroup vote per round of stalls.
    uint jj[DPT];
    bool done[DPT];
    bool published[DPT]; // this digit's inclusive prefix is out (as soon as it is known)
    [[unroll]] for (uint q = 0u; q < DPT; q++) {
        before[q] = 0u;
        jj[q] = tile - 1u;
        done[q] = tile == 0u;
        published[q] = tile == 0u;
    }
    if (tile > 0u) {
        uint lb_steps = 0u, lb_waits = 0u;
        for (;;) { // workgroup-uniform: exits depend on lb_workgroup_or results only
            bool stalled = false;
            [[unroll]] for (uint q = 0u; q < DPT; q++) {
                uint d = t + q * WG;
                while (!done[q]) {
                    // Windowed: the words of up to lb_window predecessors are loaded
                    // at once (independent loads: one memory latency, not one per
                    // tile walked), then taken nearest first up to the first
                    // inclusive prefix or the first word not yet published.
                    uint64_t ws[LB_WINDOW];
                    [[unroll]] for (uint i = 0u; i < LB_WINDOW; i++) {
                        ws[i] = (i < pc.lb_window && i <= jj[q])
                              ? lb_load(pc.status, (jj[q] - i) * RADIX + d) : uint64_t(0);
                    }
                    uint jj0 = jj[q];
                    bool open = true; // still taking words of this window
                    uint taken = 0u;
                    [[unroll]] for (uint i = 0u; i < LB_WINDOW; i++) {
                        if (open && i < pc.lb_window && i <= jj0) {
                            uint fi = lb_flag(ws[i], tag);
                            if (fi == 0u) {
                                open = false;
                            } else {
                                lb_steps++;
                                taken++;
                                before[q] += lb_value(ws[i]);
                                if (fi == LB_INCLUSIVE) {
                                    done[q] = true;
                                    open = false;
                                } else if (jj[q] == 0u) {
                                    // Tile 0 publishes only inclusive words: a
                                    // corrupted state.
                                    atomicOr(pc.state.v[ST_ERRORS], ERR_LOOKBACK);
                                    done[q] = true;
                                    open = false;
                                } else {
                                    jj[q]--;
                                }
                            }
                        }
                    }
                    if (done[q] || taken > 0u) continue; // next window from jj[q]
                    // The nearest word is not published yet: poll it.
                    uint idx = jj[q] * RADIX + d;
                    uint f = 0u;
                    uint s = 0u;
                    uint idle = 0u;
                    for (; f == 0u && s < pc.spin_limit; s++) {
                        f = lb_flag(lb_load(pc.status, idx), tag);
                        // Back-off: CUB's look-back sleeps between polls (__nanosleep)
                        // so that waiting workgroups do not flood the memory system
                        // the working ones need. SPIR-V has no sleep: ALU rounds that
                        // no memory access waits on (0 by default).
                        for (uint i = 0u; f == 0u && i < pc.lb_backoff; i++)
                            idle = idle * 1664525u + 1013904223u;
                    }
                    // Keeps the back-off's rounds from being optimised away (an OR
                    // of 0: no effect whatever `idle` is).
                    if (idle == 0x9e3779b9u) atomicOr(pc.state.v[ST_ERRORS], 0u);
                    lb_waits += s;
                    if (f == 0u) {
                        stalled = true;
                        break;
                    }
                    // Published now: the next window starts with it.
                }
                // Publish the digit's inclusive prefix at once, not after the
                // workgroup's slowest digit: successors' walks stop here sooner.
                if (done[q] && !published[q]) {
                    lb_store(pc.status, status_base + d,
                             lb_pack(tag, LB_INCLUSIVE, before[q] + count[q]));
                    published[q] = true;
                }
            }
            if (t == 0u) S_JMAX = 0u;
            if (lb_workgroup_or(stalled ? 1u : 0u) == 0u) break;
            [[unroll]] for (uint q = 0u; q < DPT; q++)
                if (!done[q]) atomicMax(S_JMAX, jj[q] + 1u);
            for (uint i = t; i < RADIX; i += WG) s_base[i] = 0u;
            if (t == 0u) atomicAdd(pc.state.v[ST_LB_FALLBACKS], 1u);
            barrier();
            uint j = S_JMAX - 1u;
            for (uint r = 0u; r < KPT; r++) {
                KeyT key = keys_in.v[j * TILE + r * WG + t];
                atomicAdd(s_base[uint(key >> pc.shift) & digit_mask], 1u);
            }
            barrier();
            [[unroll]] for (uint q = 0u; q < DPT; q++) {
                if (!done[q] && jj[q] == j) {
                    before[q] += s_base[t + q * WG];
                    if (j == 0u) done[q] = true; // tile 0's count is its inclusive prefix
                    else jj[q] = j - 1u;
                }
            }
            barrier(); // s_base and S_JMAX are reused by the next round
        }
        // Counters (bench sort): one shared add per subgroup, one global add per tile.
        uint sst = subgroupAdd(lb_steps), swt = subgroupAdd(lb_waits);
        if (subgroupElect()) {
            atomicAdd(S_LB(0), sst);
            atomicAdd(S_LB(1), swt);
        }
        barrier();
        if (t == 0u) {
            atomicAdd(pc.state.v[ST_LB_STEPS], S_LB(0));
            atomicAdd(pc.state.v[ST_LB_WAITS], S_LB(1));
        }
    }
#endif
    uint hist_base = ST_HIST + pc.pass_index * RADIX;
    [[unroll]] for (uint q = 0u; q < DPT; q++) {
        uint d = t + q * WG;
        s_base[d] = pc.state.v[hist_base + d] + before[q] - local_start[q];
    }
#endif // PROBE
    barrier();

    // 6. Write out in sorted order: slot i of the tile goes to base[digit] + i, so the
    // invocations of a subgroup write runs of consecutive addresses.
#ifdef KEY32
    for (uint i = t; i < tile_n; i += WG) {
        uint key = s_mem[i];
        uint dst = s_base[(key >> pc.shift) & digit_mask] + i;
        keys_out.v[dst] = key;
        vals_out.v[dst] = s_mem[TILE + i];
    }
#else
    uint dst[KPT];
    [[unroll]] for (uint m = 0u; m < KPT; m++) {
        uint i = t + m * WG;
        if (i < tile_n) {
            uint64_t key = uint64_t(s_mem[2u * i]) | (uint64_t(s_mem[2u * i + 1u]) << 32);
            dst[m] = s_base[uint(key >> pc.shift) & digit_mask] + i;
            keys_out.v[dst[m]] = key;
        }
    }
    barrier();
    [[unroll]] for (uint r = 0u; r < KPT; r++)
        if (chunk + r * sgsize + lane < n) s_mem[loc[r]] = v[r];
    barrier();
    [[unroll]] for (uint m = 0u; m < KPT; m++) {
        uint i = t + m * WG;
        if (i < tile_n) vals_out.v[dst[m]] = s_mem[i];
    }
#endif
}
