// Forward compositing of one 16x16 tile per workgroup (paper Eq. 1, supp. A.2-A.4).
// Variants (build.rs permutation table): N_SAMP samples per voxel segment; TRACK_MAXW
// folds per-voxel max blend weights (the adaptive statistics pass only); COUNTERS counts
// the walk's work into P.counters (bench only).
//
// Each dispatch handles one chunk of at most CHUNK entries of every tile's sorted list
// and carries the per-pixel state (C, T, D, N, median) in the image buffers, so no
// invocation's loops exceed llvmpipe's 65 535-iteration limit however long a tile's
// list is; the host records enough chunks (stats report the longest list and flag a
// shortfall). Entries are staged through shared memory 256 at a time; each subgroup
// visits only the staged entries whose pixel rectangle meets its block and whose sign
// octant one of its live pixels has (tile_walk.glsl); a pixel then skips entries of
// another octant or whose rectangle excludes it.
#include "raster_params.glsl"
#include "explin.glsl"
#include "morton.glsl"
#include "ray_aabb.glsl"
#include "trilinear.glsl"
#include "entry_stage.glsl"
#include "tile_walk.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams P;
    uint chunk;
    uint pad;
} pc;

shared uint s_live[2];  // per batch parity: subgroups with a pixel still compositing

void main() {
    FrameParams P = pc.P;
    uint l = gl_LocalInvocationID.x;
    uint tiles_x = P.tiles.x;
    uint tile = gl_WorkGroupID.y * tiles_x + gl_WorkGroupID.x;
    uvec2 pix = gl_WorkGroupID.xy * 16u + tile_pixel(l);
    uint W = P.render_size.x, H = P.render_size.y;
    bool inside = pix.x < W && pix.y < H;
    uint npix = W * H;
    uint p = pix.y * W + pix.x;

    vec3 rd;
    float rd_norm;
    pixel_ray(P, pix, rd, rd_norm);
    vec3 inv_rd = 1.0 / rd;
    uint sign = ray_sign_bits(rd);
    float t_near = P.near * rd_norm;
    // The host's surface ends the ray (raster/host/); infinity without host depth.
    float t_far = inside ? host_t_far(P, pix, rd_norm) : 0.0;

    vec3 C = vec3(0.0), N = vec3(0.0);
    float T = 1.0, D = 0.0, med_t = 0.0;
    uint med_id = 0xffffffffu;
    // Distortion (mip-NeRF 360) sums over contributors in order: Σ w·m and the loss value
    // Σ 2 w_k (m_k W_k - M_k) + w_k² δ_k / 3 with W_k = 1 - T_k, M_k = Σ_{j<k} w_j m_j.
    float dist_m = 0.0, dist_l = 0.0;
    float t_last = 1.0;  // transmittance in front of the last contributor
    uint last = 0u;
    if (pc.chunk > 0u && inside) {
        dist_m = P.aux.v[AUX_M * npix + p];
        dist_l = P.aux.v[AUX_DIST * npix + p];
        t_last = P.aux.v[AUX_TLAST * npix + p];
        last = P.last.v[p];
        C = vec3(P.img.v[CH_R * npix + p], P.img.v[CH_G * npix + p], P.img.v[CH_B * npix + p]);
        T = P.img.v[CH_T * npix + p];
        D = P.img.v[CH_DEPTH * npix + p];
        N = vec3(P.img.v[CH_NX * npix + p], P.img.v[CH_NY * npix + p], P.img.v[CH_NZ * npix + p]);
        med_id = P.med_id.v[p];
        med_t = P.med_t.v[p];
    }
    bool done = !inside || T < EARLY_STOP_T;
    // Max-weight statistics: only when a target is set, and never from a frame whose
    // entries overflowed the key buffers (its tile lists miss voxels, which would
    // inflate the transmittance of those behind). A frame short of chunks composites
    // an exact prefix of every list, so its weights are the complete frame's.
#ifdef TRACK_MAXW
    bool track_maxw = U64s(uint64_t(P.stats)).v[STAT_TOTAL / 2u] <= uint64_t(P.entry_capacity);
#endif
#ifdef COUNTERS
    // Per invocation (a dispatch stays far below 2^32 of each).
    uint c_trips = 0u, c_useful = 0u, c_dense = 0u, c_pairs = 0u, c_cross = 0u, c_contrib = 0u,
         c_build = 0u;
#endif
    uint sg = gl_SubgroupID;
    uvec2 org = gl_WorkGroupID.xy * 16u;
    if (l < 2u) s_live[l] = 0u;
    walk_setup(l, tile_pixel(l), sign, inside);

    uint chunk_size = P.chunk_size;
    uint r0 = P.ranges.v[2u * tile], r1 = P.ranges.v[2u * tile + 1u];
    uint start = r0 + min(r1 - r0, pc.chunk * chunk_size);
    uint end = min(r1, start + chunk_size);
    if (l == 0u) {
        if (pc.chunk == 0u) atomicMax(P.stats.v[STAT_MAX_TILE], r1 - r0);
        if (pc.chunk + 1u == P.chunks && end < r1) atomicOr(P.stats.v[STAT_FLAGS], FLAG_NEED_CHUNKS);
    }
    uint n = end - start;

    for (uint base = 0u, batch = 0u; base < n; base += 256u, ++batch) {
        // Subgroups with a pixel still compositing; stop when none is (uniform). Two
        // words by batch parity: the other one, last read before the previous batch's
        // second barrier, is cleared here for the next batch, so one barrier serves.
        // It also ends the previous batch's walk before staging overwrites its slots.
        bool sg_live = subgroupAny(!done);
        if (sg_live && subgroupElect()) atomicOr(s_live[batch & 1u], 1u << sg);
        if (l == 0u) s_live[(batch + 1u) & 1u] = 0u;
        barrier();
        uint live = s_live[batch & 1u];
        if (live == 0u) break;

        uint cnt = min(256u, n - base);
        stage_slot(P, walk_slot(), cnt, start + base, org, live);
        barrier();
        uint word = visit_word(P, start + base, start + base + 256u);
#ifdef COUNTERS
        // What the full walk did: every subgroup, every staged entry, while any pixel
        // of the tile was live.
        c_dense += cnt;
        if (sg_live) c_build += 1u;
#endif

        for (uint w = 0u; w < 8u; ++w) {
            uint bits = subgroupShuffle(word, w);
            while (bits != 0u) {
            uint j = 32u * w + uint(findLSB(bits));
            bits &= bits - 1u;
            // j is the same on every lane (uniform control flow).
            Entry e = load_entry(j);
            bool need = !done && covers(e.val, e.box, sign, pix);
#ifdef COUNTERS
            c_trips += 1u;
            if (subgroupAny(need)) c_useful += 1u;
            if (need) c_pairs += 1u;
#endif
            vec4 cs = e.cs;
            float h = 0.5 * cs.w;
            vec2 ab = ray_aabb(cs.xyz - h, cs.xyz + h, rd, inv_rd);
            float a = max(ab.x, t_near), b = min(ab.y, t_far);
            // A voxel the ray enters at or behind the host's surface: so do all later
            // ones of this octant (exact depth order), the pixel is done.
            if (need && a >= t_far && ab.x <= ab.y) done = true;
            need = need && a <= b;
#ifdef COUNTERS
            if (need) c_cross += 1u;
#endif
            if (need) {
            precise float step_sz = (b - a) * (1.0 / float(N_SAMP));
            vec3 vmin = cs.xyz - h;
            float inv_size = 1.0 / cs.w;
            // precise: α is recomputed by the backward, compiled separately; both must
            // round identically (no contraction into FMAs one kernel does and one not).
            precise float vol = 0.0;
            float la[N_SAMP];
            for (int k = 0; k < N_SAMP; ++k) {
                precise float t = a + (float(k) + 0.5) * step_sz;
                precise vec3 q = (t * rd - vmin) * inv_size;
                float local_vol = STEP_SZ_SCALE * step_sz * explin(trilinear(e.g, q));
                vol += local_vol;
                la[k] = min(MAX_ALPHA, alpha_of_depth(local_vol));
            }
            precise float alpha = min(MAX_ALPHA, alpha_of_depth(vol));
            if (alpha >= MIN_ALPHA) {
#ifdef COUNTERS
            c_contrib += 1u;
#endif
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
            float mid = 0.5 * (a + b);
            dist_l += wt * (2.0 * (mid * (1.0 - T) - dist_m) + wt * (b - a) * (1.0 / 3.0));
            dist_m += wt * mid;
            last = start + base + j + 1u;
            t_last = T;
            C += wt * e.rgb;
            N += wt * e.nrm;
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
            D += T * dval;
            if (T > 0.5) {
                med_id = e.val & 0x1fffffffu;
                med_t = T;
            }
            T *= 1.0 - alpha;
            done = T < EARLY_STOP_T;
            }
            }
            }
            // A subgroup whose pixels are all done stops walking (uniform).
            if (subgroupAll(done)) break;
        }
    }
#ifdef COUNTERS
    U64s ctr = P.counters;  // a writable copy of the address (the block is readonly)
    flush_counters(ctr, CTR_FWD, c_trips, c_useful, c_dense, c_pairs, c_cross, c_contrib,
                   c_build);
#endif

    if (inside) {
        P.img.v[CH_R * npix + p] = C.x;
        P.img.v[CH_G * npix + p] = C.y;
        P.img.v[CH_B * npix + p] = C.z;
        P.img.v[CH_T * npix + p] = T;
        P.img.v[CH_DEPTH * npix + p] = D;
        P.img.v[CH_NX * npix + p] = N.x;
        P.img.v[CH_NY * npix + p] = N.y;
        P.img.v[CH_NZ * npix + p] = N.z;
        P.med_id.v[p] = med_id;
        P.med_t.v[p] = med_t;
        P.aux.v[AUX_M * npix + p] = dist_m;
        P.aux.v[AUX_DIST * npix + p] = dist_l;
        P.aux.v[AUX_TLAST * npix + p] = t_last;
        P.last.v[p] = last;
    }
}
