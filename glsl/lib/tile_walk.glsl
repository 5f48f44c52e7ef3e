// Per-subgroup walk of a tile's staged entries (shared by the forward composite and the
// training backward): a subgroup visits only the entries that can matter to one of its
// pixels, instead of every lane testing every entry of the tile.
//
// A tile of 16×16 pixels is one workgroup of WALK_WG = 128 invocations, each compositing
// WALK_PPL = 2 pixels (walk_pixel). The pixels of a subgroup of S lanes are 2S
// consecutive ones in the tile's Morton order (tile_pixel): a 4×4 block for 8 lanes, 8×8
// for 32, 16×8 for 64; lane i holds the block's pixels i and S + i. Two pixels per lane
// halve the trips of a walk for every entry that meets both halves of a block, so the
// per-trip work (loading the entry, the loop, the backward's gradient reduction and
// atomic adds) is shared by up to 2S pixels; measured on lavapipe (8 lanes) against one
// pixel per lane: docs/ARCHITECTURE.md §3.1.
//
// For every staged entry the thread that staged it computes the set of subgroups that
// must visit it, as a bit mask (subgroup count = 128 / subgroup size ≤ 16):
//     groups(entry) = cols[x0][x1] & rows[y0][y1] & signs[sign] & live
// cols[x0][x1] holds the subgroups whose block meets pixel columns x0..x1 (tile-local),
// rows[y0][y1] likewise for rows: blocks are axis-aligned rectangles of a grid, so a
// block meets the entry's pixel rectangle iff it meets both its column and row ranges.
// signs[s] holds the subgroups with a pixel whose ray sign octant is s (an entry is only
// ever composited by rays of its own octant); live the subgroups with a pixel still
// compositing. The masks are then transposed into one 128-bit visit set per subgroup
// (WALK_WORDS = 4 words; bit j: visit slot j; lane w of the subgroup holds word w), which
// the walk enumerates with findLSB (front to back) or findMSB (back to front): depth
// order is the slot order, as before.
//
// Assumes full subgroups of a power-of-two size ≥ 8 (at most 16 subgroups per
// workgroup): the pipeline requires full subgroups where the device offers
// computeFullSubgroups, and a 128-invocation workgroup splits into full subgroups of any
// power-of-two size up to 128 on every driver we know.
//
// Cost per batch of 128 entries: staging, a register transpose (8-lane subgroups; else
// 32 mask reads per visit word), 4 shared reads per visit word, two barriers (the
// composite's live vote shares the first), then one loop trip per entry a subgroup
// visits. Lanes still test the exact rectangle and sign per pixel (covers), so the
// images are bit-identical to a full walk.
#ifndef TILE_WALK_GLSL
#define TILE_WALK_GLSL
#include "entry_stage.glsl"
#extension GL_KHR_shader_subgroup_shuffle : require

const uint WALK_WG = STAGE_SLOTS;        // invocations per tile workgroup
const uint WALK_PPL = 2u;                // pixels per invocation
const uint WALK_WORDS = STAGE_SLOTS / 32u;  // visit words per batch

shared uint s_sgbox[16];       // per subgroup: x0 | x1 << 8 | y0 << 16 | y1 << 24
shared uint s_colmask[256];    // [x0 * 16 + x1], x0 <= x1
shared uint s_rowmask[256];    // [y0 * 16 + y1]
shared uint s_signmask[8];
shared uint s_emask[STAGE_SLOTS];  // per staged slot: subgroups that visit it (sizes ≠ 8)

// Tile-local pixel k (0 or 1) of this invocation: pixels 2S·s + i and 2S·s + S + i of
// the tile's Morton order for lane i of subgroup s (S lanes).
uvec2 walk_pixel(uint k) {
    return tile_pixel(2u * gl_SubgroupSize * gl_SubgroupID + gl_SubgroupInvocationID +
                      k * gl_SubgroupSize);
}

// Once per dispatch, in uniform control flow: the subgroups' blocks, the column/row
// tables and the sign masks. lp0, lp1 are this invocation's tile-local pixels, sign0,
// sign1 their rays' sign octants, inside0, inside1 whether they are in the image.
void walk_setup(uint l, uvec2 lp0, uvec2 lp1, uint sign0, uint sign1, bool inside0,
                bool inside1) {
    uint sg = gl_SubgroupID;
    uint bx0 = subgroupMin(min(lp0.x, lp1.x)), bx1 = subgroupMax(max(lp0.x, lp1.x));
    uint by0 = subgroupMin(min(lp0.y, lp1.y)), by1 = subgroupMax(max(lp0.y, lp1.y));
    if (subgroupElect()) s_sgbox[sg] = bx0 | (bx1 << 8u) | (by0 << 16u) | (by1 << 24u);
    if (l < 8u) s_signmask[l] = 0u;
    barrier();
    if (inside0) atomicOr(s_signmask[sign0], 1u << sg);
    if (inside1) atomicOr(s_signmask[sign1], 1u << sg);
    for (uint t = l; t < 256u; t += WALK_WG) {
        uint a = t >> 4u, b = t & 15u;
        uint cm = 0u, rm = 0u;
        for (uint s = 0u; s < gl_NumSubgroups; ++s) {
            uint q = s_sgbox[s];
            if (a <= ((q >> 8u) & 0xffu) && b >= (q & 0xffu)) cm |= 1u << s;
            if (a <= (q >> 24u) && b >= ((q >> 16u) & 0xffu)) rm |= 1u << s;
        }
        s_colmask[t] = cm;
        s_rowmask[t] = rm;
    }
    barrier();
}

// Subgroups of `live` that must visit an entry (value `val`, pixel rectangle `box`) of
// the tile with origin `org`.
uint entry_groups(uint val, uvec2 box, uvec2 org, uint live) {
    ivec2 lo = ivec2(box.x & 0xffffu, box.x >> 16u) - ivec2(org);
    ivec2 hi = ivec2(box.y & 0xffffu, box.y >> 16u) - ivec2(org);
    if (hi.x < 0 || hi.y < 0 || lo.x > 15 || lo.y > 15) return 0u;
    lo = max(lo, ivec2(0));
    hi = min(hi, ivec2(15));
    return live & s_colmask[lo.x * 16 + hi.x] & s_rowmask[lo.y * 16 + hi.y] &
           s_signmask[val >> 29u];
}

// The staging slot of this invocation: slots follow the subgroups (slot S·s + lane),
// which the 8-lane transpose (stage_slot, visit_word) relies on.
uint walk_slot() {
    return gl_SubgroupID * gl_SubgroupSize + gl_SubgroupInvocationID;
}

shared uint s_vt[STAGE_SLOTS];  // 8-lane subgroups: per slot, a row of the transposed masks

// Stages sorted entry `first + slot` in `slot` (this invocation's walk_slot(), when
// slot < cnt) and publishes the set of subgroups of `live` that must visit it (none
// for the slots past cnt) for visit_word, which reads it after a barrier. Uniform
// control flow.
//
// 8-lane subgroups (lavapipe): the subgroup's 8 slots form an 8 × 16 bit matrix (row r:
// lane r's set, column s: subgroup s). Three xor-shuffle butterflies transpose its two
// 8 × 8 blocks in registers, after which lane L's byte c holds the 8 slots' bits for
// subgroup 8c + L (s_vt). A visit word of 32 slots is then 4 such bytes: 4 shared reads
// where reading the 32 sets would take 32 (llvmpipe turns every shared access into a
// loop over the lanes, and a shuffle into one permute). Other sizes publish the sets
// (s_emask) and visit_word reads 32 of them.
// Whether the 8-lane transpose serves (else the path for any size; FRAME_GENERIC_WALK forces
// it for tests).
bool lanes8(FrameParams P) {
    return gl_SubgroupSize == 8u && (P.flags & FRAME_GENERIC_WALK) == 0u;
}

void stage_slot(FrameParams P, uint slot, uint cnt, uint first, uvec2 org, uint live) {
    uint em = 0u;
    if (slot < cnt) {
        uint val;
        uvec2 box;
        stage_entry(P, slot, first + slot, val, box);
        em = entry_groups(val, box, org, live);
    }
    if (lanes8(P)) {
        uint lane = gl_SubgroupInvocationID;
        [[unroll]] for (uint d = 1u; d < 8u; d <<= 1u) {
            uint m = d == 1u ? 0xaaaaaaaau : (d == 2u ? 0xccccccccu : 0xf0f0f0f0u);
            uint y = subgroupShuffleXor(em, d);
            em = (lane & d) == 0u ? ((em & ~m) | ((y & ~m) << d)) : ((em & m) | ((y & m) >> d));
        }
        s_vt[slot] = em;
    } else {
        s_emask[slot] = em;
    }
}

// This subgroup's visit word `w = lane` (lanes 0..WALK_WORDS-1; bit i: visit slot
// 32w + i; 0 on other lanes), keeping only the slots before `cut` (slot 0 is sorted
// entry `first`; pass cut = first + STAGE_SLOTS or more to keep all). Call after the
// barrier that follows stage_slot; the walk takes word w with subgroupShuffle(word, w).
uint visit_word(FrameParams P, uint first, uint cut) {
    uint sg = gl_SubgroupID, w = gl_SubgroupInvocationID;
    if (w >= WALK_WORDS) return 0u;
    uint bits = 0u;
    if (lanes8(P)) {
        uint sh = 8u * (sg >> 3u);
        [[unroll]] for (uint k = 0u; k < 4u; ++k)
            bits |= ((s_vt[8u * (4u * w + k) + (sg & 7u)] >> sh) & 0xffu) << (8u * k);
    } else {
        [[unroll]] for (uint i = 0u; i < 32u; ++i) bits |= ((s_emask[32u * w + i] >> sg) & 1u) << i;
    }
    int keep = clamp(int(cut) - int(first) - int(32u * w), 0, 32);
    return keep == 32 ? bits : bits & ((1u << uint(keep)) - 1u);
}

#ifdef COUNTERS
// Adds one subgroup's work counters to the walk's words at `base` (CTR_FWD or CTR_BWD),
// in uniform control flow. Trips, useful trips, full-walk trips, builds, body runs and
// lane maxima are uniform (added once); pairs, crossings and contributions are per lane
// (summed).
void flush_counters(U64s ctr, uint base, uint trips, uint useful, uint dense, uint pairs,
                    uint cross, uint contrib, uint build, uint body, uint lane_max) {
    pairs = subgroupAdd(pairs);
    cross = subgroupAdd(cross);
    contrib = subgroupAdd(contrib);
    if (subgroupElect()) {
        atomicAdd(ctr.v[base + CTR_TRIPS], uint64_t(trips));
        atomicAdd(ctr.v[base + CTR_USEFUL], uint64_t(useful));
        atomicAdd(ctr.v[base + CTR_DENSE], uint64_t(dense));
        atomicAdd(ctr.v[base + CTR_PAIRS], uint64_t(pairs));
        atomicAdd(ctr.v[base + CTR_CROSS], uint64_t(cross));
        atomicAdd(ctr.v[base + CTR_CONTRIB], uint64_t(contrib));
        atomicAdd(ctr.v[base + CTR_BUILD], uint64_t(build));
        atomicAdd(ctr.v[base + CTR_SUBGROUPS], 1ul);
        atomicAdd(ctr.v[base + CTR_BODY], uint64_t(body));
        atomicAdd(ctr.v[base + CTR_LANE_MAX], uint64_t(lane_max));
    }
}
#endif

#endif
