// Forward compositing of one 16x16 tile per workgroup (paper Eq. 1, supp. A.2-A.4).
// Variants (glsl/variants.rs): N_SAMP samples per voxel segment; TRACK_MAXW
// folds per-voxel max blend weights (the adaptive statistics pass only); COUNTERS counts
// the walk's work into P.counters (bench only).
//
// Without segments (mode SEG_OFF) each dispatch handles one chunk of at most CHUNK
// entries of every tile's sorted list and carries the per-pixel state (C, T, D, N,
// median) in the image buffers, so no invocation's loops exceed llvmpipe's 65 535-
// iteration limit however long a tile's list is; the host records enough chunks (stats
// report the longest list and flag a shortfall). With segments (SEG_TRANSMIT, SEG_EXACT;
// "Segments" in raster_params.glsl) each workgroup walks one segment of one tile, named
// by its slot. Each invocation composites two pixels (tile_walk.glsl's walk_pixel).
// Entries are staged through shared memory 128 at a time; each subgroup visits only the
// staged entries whose pixel rectangle meets its block and whose sign octant one of its
// live pixels has (tile_walk.glsl); a pixel then skips entries of another octant or
// whose rectangle excludes it.
#include "raster_params.glsl"
#include "explin.glsl"
#include "morton.glsl"
#include "ray_aabb.glsl"
#include "trilinear.glsl"
#include "entry_stage.glsl"
#include "tile_walk.glsl"
layout(local_size_x = 128) in;  // WALK_WG

layout(push_constant) uniform Push {
    FrameParams frame;
    uint chunk;
    uint mode;  // SEG_OFF, SEG_TRANSMIT or SEG_EXACT
} pc;

shared uint s_live[2];  // per batch parity: subgroups with a pixel still compositing

// One pixel's compositing state (carried between chunk dispatches in the image buffers).
struct Px {
    uvec2 pix;
    uint p;  // index in the render
    bool inside;
    vec3 rd, inv_rd;
    uint sign;
    float t_near, t_far;
    vec3 C, N;
    float T, D, med_t;
    uint med_id;
    // Distortion (mip-NeRF 360) sums over contributors in order: Σ w·m and the loss
    // value Σ 2 w_k (m_k W_k - M_k) + w_k² δ_k / 3 with W_k = 1 - T_k, M_k = Σ_{j<k} w_j m_j.
    float dist_m, dist_l;
    float t_last;  // transmittance in front of the last contributor
    uint last;
    bool done;
    float Q;  // segments (SEG_EXACT): Σ w·|c|², for the backward's boundary state
};

// Pixel lp of the tile at `org`; `slot`: the segment's slot (SEG_EXACT starts from the
// transmittance and Σ w·m in front of the segment).
Px px_init(FrameParams P, uvec2 lp, uvec2 org, uint slot) {
    Px s;
    s.pix = org + lp;
    uint W = P.render_size.x, H = P.render_size.y;
    uint npix = W * H;
    s.inside = s.pix.x < W && s.pix.y < H;
    s.p = s.pix.y * W + s.pix.x;
    float rd_norm;
    pixel_ray(P, s.pix, s.rd, rd_norm);
    s.inv_rd = 1.0 / s.rd;
    s.sign = ray_sign_bits(s.rd);
    s.t_near = P.near * rd_norm;
    // The host's surface ends the ray (raster/host/); infinity without host depth.
    s.t_far = s.inside ? host_t_far(P, s.pix, rd_norm) : 0.0;
    s.C = vec3(0.0);
    s.N = vec3(0.0);
    s.T = 1.0;
    s.D = 0.0;
    s.med_t = 0.0;
    s.med_id = 0xffffffffu;
    s.dist_m = 0.0;
    s.dist_l = 0.0;
    s.t_last = 1.0;
    s.last = 0u;
    s.Q = 0.0;
    uint p = s.p;
    if (pc.chunk > 0u && s.inside) {
        s.dist_m = P.aux.v[AUX_M * npix + p];
        s.dist_l = P.aux.v[AUX_DIST * npix + p];
        s.t_last = P.aux.v[AUX_TLAST * npix + p];
        s.last = P.last.v[p];
        s.C = vec3(P.img.v[CH_R * npix + p], P.img.v[CH_G * npix + p], P.img.v[CH_B * npix + p]);
        s.T = P.img.v[CH_T * npix + p];
        s.D = P.img.v[CH_DEPTH * npix + p];
        s.N = vec3(P.img.v[CH_NX * npix + p], P.img.v[CH_NY * npix + p], P.img.v[CH_NZ * npix + p]);
        s.med_id = P.med_id.v[p];
        s.med_t = P.med_t.v[p];
    }
    if (pc.mode == SEG_EXACT && s.inside) {
        uint q = lp.y * 16u + lp.x;
        s.T = P.seg_state.v[seg_word(P, SEG_T, slot, q)];
        s.dist_m = P.seg_state.v[seg_word(P, SEG_M, slot, q)];
    }
    s.done = !s.inside || s.T < EARLY_STOP_T;
    return s;
}

// A segment's results: its transmittance product and Σ w·m (SEG_TRANSMIT), or its
// partial sums and decisions (SEG_EXACT), at pixel lp of slot `slot`.
void px_store_segment(FrameParams P, Px s, uvec2 lp, uint slot) {
    if (!s.inside) return;
    uint q = lp.y * 16u + lp.x;
    if (pc.mode == SEG_TRANSMIT) {
        P.seg_state.v[seg_word(P, SEG_T, slot, q)] = s.T;
        P.seg_state.v[seg_word(P, SEG_M, slot, q)] = s.dist_m;
        return;
    }
    P.seg_state.v[seg_word(P, SEG_R, slot, q)] = s.C.x;
    P.seg_state.v[seg_word(P, SEG_G, slot, q)] = s.C.y;
    P.seg_state.v[seg_word(P, SEG_B, slot, q)] = s.C.z;
    P.seg_state.v[seg_word(P, SEG_D, slot, q)] = s.D;
    P.seg_state.v[seg_word(P, SEG_NX, slot, q)] = s.N.x;
    P.seg_state.v[seg_word(P, SEG_NY, slot, q)] = s.N.y;
    P.seg_state.v[seg_word(P, SEG_NZ, slot, q)] = s.N.z;
    P.seg_state.v[seg_word(P, SEG_DIST, slot, q)] = s.dist_l;
    P.seg_state.v[seg_word(P, SEG_MEND, slot, q)] = s.dist_m;
    P.seg_state.v[seg_word(P, SEG_TEND, slot, q)] = s.T;
    P.seg_state.v[seg_word(P, SEG_LAST, slot, q)] = uintBitsToFloat(s.last);
    P.seg_state.v[seg_word(P, SEG_TLAST, slot, q)] = s.t_last;
    P.seg_state.v[seg_word(P, SEG_MEDID, slot, q)] = uintBitsToFloat(s.med_id);
    P.seg_state.v[seg_word(P, SEG_MEDT, slot, q)] = s.med_t;
    P.seg_state.v[seg_word(P, SEG_Q, slot, q)] = s.Q;
}

void px_store(FrameParams P, Px s) {
    if (!s.inside) return;
    uint npix = P.render_size.x * P.render_size.y;
    uint p = s.p;
    P.img.v[CH_R * npix + p] = s.C.x;
    P.img.v[CH_G * npix + p] = s.C.y;
    P.img.v[CH_B * npix + p] = s.C.z;
    P.img.v[CH_T * npix + p] = s.T;
    P.img.v[CH_DEPTH * npix + p] = s.D;
    P.img.v[CH_NX * npix + p] = s.N.x;
    P.img.v[CH_NY * npix + p] = s.N.y;
    P.img.v[CH_NZ * npix + p] = s.N.z;
    P.med_id.v[p] = s.med_id;
    P.med_t.v[p] = s.med_t;
    P.aux.v[AUX_M * npix + p] = s.dist_m;
    P.aux.v[AUX_DIST * npix + p] = s.dist_l;
    P.aux.v[AUX_TLAST * npix + p] = s.t_last;
    P.last.v[p] = s.last;
}

// Composites entry `e` (sorted index idx) into pixel state `s` when `need` (the entry
// is of the pixel's octant and its rectangle holds the pixel; uniform control flow).
// Returns 1 for a ray–voxel crossing, 2 for a contribution too (work counters).
uint px_step(FrameParams P, inout Px s, Entry e, uint idx, bool need, bool track_maxw) {
    uint work = 0u;
    vec4 cs = e.cs;
    float h = 0.5 * cs.w;
    vec2 ab = ray_aabb(cs.xyz - h, cs.xyz + h, s.rd, s.inv_rd);
    float a = max(ab.x, s.t_near), b = min(ab.y, s.t_far);
    // A voxel the ray enters at or behind the host's surface: so do all later ones of
    // this octant (exact depth order), the pixel is done.
    if (need && a >= s.t_far && ab.x <= ab.y) s.done = true;
    need = need && a <= b;
    if (need) {
        work = 1u;
        precise float step_sz = (b - a) * (1.0 / float(N_SAMP));
        vec3 vmin = cs.xyz - h;
        float inv_size = 1.0 / cs.w;
        // precise: α is recomputed by the backward, compiled separately; both must
        // round identically (no contraction into FMAs one kernel does and one not).
        precise float vol = 0.0;
        float la[N_SAMP];
        for (int k = 0; k < N_SAMP; ++k) {
            precise float t = a + (float(k) + 0.5) * step_sz;
            precise vec3 q = (t * s.rd - vmin) * inv_size;
            float local_vol = STEP_SZ_SCALE * step_sz * explin(trilinear(e.g, q));
            vol += local_vol;
            la[k] = min(MAX_ALPHA, alpha_of_depth(local_vol));
        }
        precise float alpha = min(MAX_ALPHA, alpha_of_depth(vol));
        if (alpha >= MIN_ALPHA) {
            work = 2u;
            float T = s.T;
            float wt = T * alpha;
#ifdef TRACK_MAXW
            if (track_maxw) {
                // wt >= 0: its bits order as the floats do. Read first, so most
                // entries skip the atomic.
                uint vid = e.val & 0x1fffffffu;
                uint wb = floatBitsToUint(wt);
                if (P.maxw.v[vid] < wb) atomicMax(P.maxw.v[vid], wb);
            }
#endif
            // Only what the frame's consumers read (FrameParams.flags; uniform).
            if (frame_distortion(P)) {
                float da = dist_axis(P, a), db = dist_axis(P, b);
                float mid = 0.5 * (da + db);
                s.dist_l += wt * (2.0 * (mid * (1.0 - T) - s.dist_m) + wt * (db - da) * (1.0 / 3.0));
                s.dist_m += wt * mid;
            }
            s.last = idx + 1u;
            s.t_last = T;
            s.C += wt * e.rgb;
            if (pc.mode == SEG_EXACT) s.Q += wt * dot(e.rgb, e.rgb);
            if (frame_normals(P)) s.N += wt * e.nrm;
            // Voxel depth (supp. A.4, Eqs. 19-21); K = 1 uses the segment midpoint.
            float dval;
#if N_SAMP == 1
            dval = alpha * 0.5 * (a + b);
#else
            dval = 0.0;
            float tr = 1.0;
            for (int k = 0; k < N_SAMP; ++k) {
                dval += tr * la[k] * (a + (float(k) + 0.5) * step_sz);
                tr *= 1.0 - la[k];
            }
#endif
            s.D += T * dval;
            if (T > 0.5) {
                s.med_id = e.val & 0x1fffffffu;
                s.med_t = T;
            }
            s.T = T * (1.0 - alpha);
            s.done = s.T < EARLY_STOP_T;
        }
    }
    return work;
}

void main() {
    FrameParams P = pc.frame;
    uint l = gl_LocalInvocationID.x;
    uint tiles_x = P.tiles.x;
    // The tile and the part of its list this workgroup walks: chunk `pc.chunk` of the
    // tile of this workgroup, or the segment of this workgroup's slot.
    uint tile, slot = 0u, start, end;
    uint r0, r1;
    if (pc.mode == SEG_OFF) {
        tile = gl_WorkGroupID.y * tiles_x + gl_WorkGroupID.x;
        r0 = P.ranges.v[2u * tile];
        r1 = P.ranges.v[2u * tile + 1u];
        start = r0 + min(r1 - r0, pc.chunk * P.chunk_size);
        end = min(r1, start + P.chunk_size);
        if (l == 0u) {
            if (pc.chunk == 0u) atomicMax(P.stats.v[STAT_MAX_TILE], r1 - r0);
            if (pc.chunk + 1u == P.chunks && end < r1)
                atomicOr(P.stats.v[STAT_FLAGS], FLAG_NEED_CHUNKS);
        }
    } else {
        // Uniform exits: no slot here, or (SEG_TRANSMIT) the tile's last segment, whose
        // product nothing behind it needs.
        slot = linear_group_id();
        if (slot >= P.slot_cap) return;
        tile = P.seg_tile.v[slot];
        if (tile == 0xffffffffu) return;
        r0 = P.ranges.v[2u * tile];
        r1 = P.ranges.v[2u * tile + 1u];
        start = r0 + (slot - seg_first_slot(P, tile, r0)) * P.seg_size;
        end = min(r1, start + P.seg_size);
        if (pc.mode == SEG_TRANSMIT && end == r1) return;
    }
    // Without segments the origin is the workgroup id's, which the compiler recomputes
    // where used instead of carrying it across the walk's barriers (llvmpipe saves live
    // values at each: carrying an origin computed from the tile cost the composite 7 %).
    uvec2 org = pc.mode == SEG_OFF ? gl_WorkGroupID.xy * 16u
                                   : uvec2(tile % tiles_x, tile / tiles_x) * 16u;
    uvec2 lp0 = walk_pixel(0u), lp1 = walk_pixel(1u);
    Px s0 = px_init(P, lp0, org, slot);
    Px s1 = px_init(P, lp1, org, slot);
    // Max-weight statistics: only when a target is set, and never from a frame whose
    // entries overflowed the key buffers (its tile lists miss voxels, which would
    // inflate the transmittance of those behind). A frame short of chunks composites
    // an exact prefix of every list, so its weights are the complete frame's.
    bool track_maxw = false;
#ifdef TRACK_MAXW
    // A segment's own transmittance (SEG_TRANSMIT) is not the frame's: no weights.
    track_maxw = pc.mode != SEG_TRANSMIT &&
                 U64s(uint64_t(P.stats)).v[STAT_TOTAL / 2u] <= uint64_t(P.entry_capacity);
#endif
#ifdef COUNTERS
    // Per invocation (a dispatch stays far below 2^32 of each).
    uint c_trips = 0u, c_useful = 0u, c_dense = 0u, c_pairs = 0u, c_cross = 0u, c_contrib = 0u,
         c_build = 0u, c_body = 0u, c_lane_max = 0u;
#endif
    uint sg = gl_SubgroupID;
    if (l < 2u) s_live[l] = 0u;
    walk_setup(l, lp0, lp1, s0.sign, s1.sign, s0.inside, s1.inside);
    uint n = end - start;

    for (uint base = 0u, batch = 0u; base < n; base += STAGE_SLOTS, ++batch) {
        // Subgroups with a pixel still compositing; stop when none is (uniform). Two
        // words by batch parity: the other one, last read before the previous batch's
        // second barrier, is cleared here for the next batch, so one barrier serves.
        // It also ends the previous batch's walk before staging overwrites its slots.
        bool sg_live = subgroupAny(!(s0.done && s1.done));
        if (sg_live && subgroupElect()) atomicOr(s_live[batch & 1u], 1u << sg);
        if (l == 0u) s_live[(batch + 1u) & 1u] = 0u;
        barrier();
        uint live = s_live[batch & 1u];
        if (live == 0u) break;

        uint cnt = min(STAGE_SLOTS, n - base);
        stage_slot(P, walk_slot(), cnt, start + base, org, live);
        barrier();
        uint word = visit_word(P, start + base, start + base + STAGE_SLOTS);
#ifdef COUNTERS
        // What a full walk with one pixel per lane did: every such subgroup (two per
        // subgroup here), every staged entry, while any pixel of the tile was live.
        c_dense += WALK_PPL * cnt;
        if (sg_live) c_build += 1u;
        uint c_lane_batch = 0u; // this lane's crossings (both pixels) in this batch
#endif

        for (uint w = 0u; w < WALK_WORDS; ++w) {
            uint bits = subgroupShuffle(word, w);
            while (bits != 0u) {
                uint j = 32u * w + uint(findLSB(bits));
                bits &= bits - 1u;
                // j is the same on every lane (uniform control flow).
                Entry e = load_entry(j);
                uint idx = start + base + j;
                bool need0 = !s0.done && covers(e.val, e.box, s0.sign, s0.pix);
                bool need1 = !s1.done && covers(e.val, e.box, s1.sign, s1.pix);
                uint w0 = px_step(P, s0, e, idx, need0, track_maxw);
                uint w1 = px_step(P, s1, e, idx, need1, track_maxw);
#ifdef COUNTERS
                c_trips += 1u;
                if (subgroupAny(need0 || need1)) c_useful += 1u;
                c_pairs += uint(need0) + uint(need1);
                c_cross += uint(w0 >= 1u) + uint(w1 >= 1u);
                c_contrib += uint(w0 == 2u) + uint(w1 == 2u);
                c_body += uint(subgroupAny(w0 >= 1u)) + uint(subgroupAny(w1 >= 1u));
                c_lane_batch += uint(w0 >= 1u) + uint(w1 >= 1u);
#endif
            }
            // A subgroup whose pixels are all done stops walking (uniform).
            if (subgroupAll(s0.done && s1.done)) break;
        }
#ifdef COUNTERS
        c_lane_max += subgroupMax(c_lane_batch);
#endif
    }
#ifdef COUNTERS
    U64s ctr = P.counters;  // a writable copy of the address (the block is readonly)
    flush_counters(ctr, CTR_FWD, c_trips, c_useful, c_dense, c_pairs, c_cross, c_contrib,
                   c_build, c_body, c_lane_max);
#endif
    if (pc.mode == SEG_OFF) {
        px_store(P, s0);
        px_store(P, s1);
    } else {
        px_store_segment(P, s0, lp0, linear_group_id());
        px_store_segment(P, s1, lp1, linear_group_id());
    }
}
