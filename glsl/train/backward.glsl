// Backward of the compositing (paper §3.2; docs/ARCHITECTURE.md §4). Variants
// (glsl/variants.rs): N_SAMP samples per voxel segment; FLOAT_ATOMICS (else CAS float adds);
// COUNTERS counts the walk's work into P.counters (bench only).
//
// One workgroup per 16x16 tile walks the tile's sorted list BACK TO FRONT, starting at
// each pixel's last contributor with the exact final transmittance the forward kept.
// With G the loss's linear functional of the composited outputs,
//     G = Σ_k T_k φ_k + T_final g_T,   φ_k = α_k (dC·c_k + dN·n_k + r_k + u_k) + dD·dval_k,
// the per-unit-transmittance suffix A_k = φ_k + (1 - α_k) A_{k+1} (A_{N+1} = g_T) gives
//     ∂L/∂α_k = T_k (∂φ_k/∂α_k - A_{k+1})
// without dividing a suffix sum by (1 - α_k); T_k = T_{k+1} / (1 - α_k) is exact enough
// because α ≤ 0.99999 and the forward stopped at T < 1e-4. r_k is the per-point RGB loss
// λ_R·|c_k - gt|²/3; u_k = ∂L_dist/∂w_k uses W_k = 1 - T_k and the forward's Σ w·m.
// SVRaster's form of the per-point RGB loss (λ_Rc·Σ w_k |c_k - gt|² with w_k held
// constant) adds 2 λ_Rc w_k (c_k - gt) to the colour gradient and nothing to φ.
//
// Each invocation handles two pixels (tile_walk.glsl's walk_pixel); each subgroup visits
// only the staged entries that can matter to its pixels (rectangle, sign octant, before
// its last contributor: tile_walk.glsl), back to front. Per visited entry the lanes add
// their two pixels' gradients, then reduce the voxel's 15 gradient components with a transposed
// (reduce-scatter) butterfly of subgroup shuffles, after which every lane owns the
// complete sum of one or two components and adds them with a single global float
// atomic instruction across the subgroup (a CAS loop where the device lacks them)
// instead of 15 reductions and 15 single-lane atomics. Chunks of the list are separate
// dispatches (last chunk first), carrying per-pixel state (T, A, Σ_after w, Σ_after w·m)
// in `bstate`, which keeps each invocation under llvmpipe's loop limit. A segmented
// frame ("Segments" in raster_params.glsl) is walked per segment instead, every
// segment by its own workgroup in one dispatch, from that same state at its back
// (computed in closed form by train/seg_bmerge.comp).
//
// DETERMINISTIC (the ordered reduction, `--deterministic`): no float atomics. Each sorted
// entry (one tile, one voxel, one sign octant) owns a VG_STRIDE record in B.records at
// its emission index (emit_keys.comp's i: offsets[v] + sign rank · tiles + tile rank);
// the subgroups of the tile's workgroup take turns over each batch (barriers between
// turns), so the partial sums reach a record in subgroup order, and records_gather.comp
// then sums a voxel's records in emission order. The walk itself is unchanged.
#include "atomic_f32.glsl"
#extension GL_KHR_shader_subgroup_shuffle : require
#include "raster_params.glsl"
#include "explin.glsl"
#include "morton.glsl"
#include "ray_aabb.glsl"
#include "trilinear.glsl"
#include "entry_stage.glsl"
#include "tile_walk.glsl"
#include "backward_params.glsl"
layout(local_size_x = 128) in;  // WALK_WG

layout(push_constant) uniform Push {
    FrameParams frame;
    BackParams back;
    uint chunk;  // chunk index (dispatched from the last down to 0)
    uint mode;   // SEG_OFF (per tile, in chunks) or SEG_EXACT (per segment's slot)
} pc;

shared uint s_last;
shared uint s_live;

void add_component(uint i, float x) {
#ifdef DETERMINISTIC
    if (x != 0.0) pc.back.records.v[i] += x;
#else
    atomic_add_f32(pc.back.vgrad, i, x, pc.back.lost);
#endif
}

float explin_grad(float x) {
    return x > 1.1 ? 1.0 : explin(x) * 0.909090909091;
}

// Adds the subgroup's sum of r[0..15) (r[15] must be 0) to out[base + c]: the voxel's
// vgrad record with float atomics, the entry's record with plain adds (DETERMINISTIC:
// this subgroup is the only one adding to it during its turn).
// Reduce-scatter: each xor step halves the components a lane holds and sums them with
// its partner's; after the steps over lane bits 0, 1, 2 lane L holds components
// c0, c0 + 1 with c0 = 8·L₀ + 4·L₁ + 2·L₂, summed over its 8-lane group; with ≥ 16
// lanes a fourth step leaves one component c0 + L₃, and plain butterflies sum the
// 16-lane groups. Every step is uniform (called in uniform control flow).
void reduce_add(float r[16], uint base) {
    BackParams B = pc.back;
    uint lane = gl_SubgroupInvocationID;
    bool hi = (lane & 1u) != 0u;
    [[unroll]] for (uint i = 0u; i < 8u; ++i) {
        float keep = hi ? r[i + 8u] : r[i];
        float send = hi ? r[i] : r[i + 8u];
        r[i] = keep + subgroupShuffleXor(send, 1u);
    }
    hi = (lane & 2u) != 0u;
    [[unroll]] for (uint i = 0u; i < 4u; ++i) {
        float keep = hi ? r[i + 4u] : r[i];
        float send = hi ? r[i] : r[i + 4u];
        r[i] = keep + subgroupShuffleXor(send, 2u);
    }
    hi = (lane & 4u) != 0u;
    [[unroll]] for (uint i = 0u; i < 2u; ++i) {
        float keep = hi ? r[i + 2u] : r[i];
        float send = hi ? r[i] : r[i + 2u];
        r[i] = keep + subgroupShuffleXor(send, 4u);
    }
    uint c0 = ((lane & 1u) << 3u) | ((lane & 2u) << 1u) | ((lane & 4u) >> 1u);
    if (gl_SubgroupSize == 8u) {
        add_component(base + c0, r[0]);
        add_component(base + c0 + 1u, r[1]);
    } else {
        hi = (lane & 8u) != 0u;
        float keep = hi ? r[1] : r[0];
        float send = hi ? r[0] : r[1];
        float x = keep + subgroupShuffleXor(send, 8u);
        for (uint o = 16u; o < gl_SubgroupSize; o <<= 1u) x += subgroupShuffleXor(x, o);
        if (lane < 16u) add_component(base + c0 + (hi ? 1u : 0u), x);
    }
}

#ifdef DETERMINISTIC
// Record of the staged entry `e` of the tile at tile coordinates `tile_xy`: its index in
// emit_keys.comp's emission order (the sort keeps no index, but the emission is a pure
// function of the voxel's rectangle and sign octants).
uint record_index(Entry e, uvec2 tile_xy) {
    FrameParams P = pc.frame;
    uint v = e.val & 0x1fffffffu, sign = e.val >> 29u;
    uvec2 tlo = uvec2(e.box.x & 0xffffu, e.box.x >> 16u) / 16u;
    uvec2 thi = uvec2(e.box.y & 0xffffu, e.box.y >> 16u) / 16u;
    uint tw = thi.x - tlo.x + 1u;
    uint ntiles = tw * (thi.y - tlo.y + 1u);
    uint si = bitCount(P.signs.v[v] & ((1u << sign) - 1u));
    uvec2 t = tile_xy - tlo;
    return P.offsets.v[v] + si * ntiles + t.y * tw + t.x;
}
#endif

// One pixel's backward state (carried between chunk dispatches in `bstate`).
struct BPx {
    uvec2 pix;
    uint p;
    bool inside;
    vec3 rd, inv_rd;
    uint sign;
    float t_near;
    vec3 dC, dN, gt;  // loss gradients of the pixel (render resolution), target colour
    float dD, mtot;
    uint last;
    float t_last;
    float T, A, wa, ma;
};

// Pixel lp of the tile at `org`; `slot`: the segment walked (per-slot mode), which
// starts from the state behind it (SEG_BT..SEG_BMA, train/seg_bmerge.comp).
BPx bpx_init(FrameParams P, BackParams B, uvec2 lp, uvec2 org, uint slot) {
    BPx s;
    s.pix = org + lp;
    uint W = P.render_size.x, H = P.render_size.y;
    s.inside = s.pix.x < W && s.pix.y < H;
    uint npix = W * H;
    uint p = s.inside ? s.pix.y * W + s.pix.x : 0u;
    s.p = p;
    float rd_norm;
    pixel_ray(P, s.pix, s.rd, rd_norm);
    s.inv_rd = 1.0 / s.rd;
    s.sign = ray_sign_bits(s.rd);
    s.t_near = P.near * rd_norm;
    s.dC = vec3(0.0);
    s.dN = vec3(0.0);
    s.gt = vec3(0.0);
    s.dD = 0.0;
    s.mtot = 0.0;
    s.last = 0u;
    s.t_last = 1.0;
    s.T = 1.0;
    s.A = 0.0;
    s.wa = 0.0;
    s.ma = 0.0;
    if (s.inside) {
        s.dC = vec3(B.dimg.v[DI_R * npix + p], B.dimg.v[DI_G * npix + p], B.dimg.v[DI_B * npix + p]);
        s.dD = B.dimg.v[DI_DEPTH * npix + p] / rd_norm;  // out depth = ray distance / rd_norm
        s.dN = vec3(B.dimg.v[DI_NX * npix + p], B.dimg.v[DI_NY * npix + p], B.dimg.v[DI_NZ * npix + p]);
        s.gt = vec3(B.dimg.v[DI_GTR * npix + p], B.dimg.v[DI_GTG * npix + p], B.dimg.v[DI_GTB * npix + p]);
        s.mtot = P.aux.v[AUX_M * npix + p];
        s.last = P.last.v[p];
        s.t_last = P.aux.v[AUX_TLAST * npix + p];
        if (pc.mode != SEG_OFF) {
            uint q = lp.y * 16u + lp.x;
            s.T = P.seg_state.v[seg_word(P, SEG_BT, slot, q)];
            s.A = P.seg_state.v[seg_word(P, SEG_BA, slot, q)];
            s.wa = P.seg_state.v[seg_word(P, SEG_BWA, slot, q)];
            s.ma = P.seg_state.v[seg_word(P, SEG_BMA, slot, q)];
        } else if (pc.chunk + 1u == B.chunks) {
            s.T = P.aux.v[AUX_T * npix + p];
            s.A = B.dimg.v[DI_T * npix + p];
        } else {
            s.T = B.bstate.v[BS_T * npix + p];
            s.A = B.bstate.v[BS_A * npix + p];
            s.wa = B.bstate.v[BS_WA * npix + p];
            s.ma = B.bstate.v[BS_MA * npix + p];
        }
    }
    return s;
}

void bpx_store(FrameParams P, BackParams B, BPx s) {
    if (!s.inside) return;
    uint npix = P.render_size.x * P.render_size.y;
    uint p = s.p;
    B.bstate.v[BS_T * npix + p] = s.T;
    B.bstate.v[BS_A * npix + p] = s.A;
    B.bstate.v[BS_WA * npix + p] = s.wa;
    B.bstate.v[BS_MA * npix + p] = s.ma;
}

// Backward of entry `e` (sorted index idx) for pixel state `s` when `need` (the entry
// is of the pixel's octant, its rectangle holds the pixel and it is before the pixel's
// last contributor): adds the pixel's gradient components to red (VG_* layout) and
// steps the state to the front of the entry. Uniform control flow. Returns 1 for a
// ray–voxel crossing, 2 for a contribution too (work counters).
uint bpx_step(inout BPx s, Entry e, uint idx, bool need, inout float red[16]) {
    uint work = 0u;
    // What the loss uses (uniform): the normal image (FRAME_NORMALS; never in the
    // NO_NORMALS variant) and the distortion loss (λ_dist ≠ 0, whose sums the forward
    // kept: FRAME_DISTORTION, checked on the host). Skipping a term whose gradient input
    // is zero changes no value.
    bool normals = frame_normals(pc.frame);
    bool distortion = pc.back.lambda_dist != 0.0;
    float lam_dist = pc.back.lambda_dist, lam_r = pc.back.lambda_r;
    // Recompute the forward quantities of this entry (identically to composite).
    vec4 cs = e.cs;
    float h = 0.5 * cs.w;
    vec2 ab = ray_aabb(cs.xyz - h, cs.xyz + h, s.rd, s.inv_rd);
    float a = max(ab.x, s.t_near), b = ab.y;
    need = need && a <= b;
    if (!need) return 0u;
    work = 1u;
    precise float step_sz = (b - a) * (1.0 / float(N_SAMP));
    vec3 vmin = cs.xyz - h;
    float inv_size = 1.0 / cs.w;
    precise float vol = 0.0;  // as in the composite (bit-identical α)
    float la[N_SAMP], lv[N_SAMP], rho[N_SAMP];
    vec3 qs[N_SAMP];
    for (int k = 0; k < N_SAMP; ++k) {
        precise float t = a + (float(k) + 0.5) * step_sz;
        precise vec3 qk = (t * s.rd - vmin) * inv_size;
        qs[k] = qk;
        rho[k] = trilinear(e.g, qs[k]);
        lv[k] = STEP_SZ_SCALE * step_sz * explin(rho[k]);
        vol += lv[k];
        la[k] = min(MAX_ALPHA, alpha_of_depth(lv[k]));
    }
    precise float raw_alpha = alpha_of_depth(vol);
    float alpha = min(MAX_ALPHA, raw_alpha);
    if (alpha < MIN_ALPHA) return work;
    work = 2u;
    vec3 col = e.rgb;
    vec3 nrm = e.nrm;
    // The last contributor's T_k is stored by the forward: T / (1 - α) would amplify any
    // difference in α by up to 1 / (1 - α) = 1e5. Before it, T_{k+1} ≥ 1e-4 (no early
    // stop yet) bounds 1 / (1 - α_k) by 1e4·T_k.
    float Tk = idx + 1u == s.last ? s.t_last : s.T / (1.0 - alpha);
    float w = Tk * alpha;
    float mid = 0.5 * (a + b);
    float u = 0.0, dmid = 0.0;
    if (distortion) {
        // ∂L_dist/∂w_k (segments are constants), on the composite's distortion axis.
        float da = dist_axis(pc.frame, a), db = dist_axis(pc.frame, b);
        dmid = 0.5 * (da + db);
        float Wk = 1.0 - Tk;
        float Mk = s.mtot - s.ma - w * dmid;
        u = lam_dist * (2.0 * (dmid * Wk - Mk) + 2.0 * (s.ma - dmid * s.wa) + (2.0 / 3.0) * w * (db - da));
    }
    vec3 diff = col - s.gt;
    float r = lam_r * dot(diff, diff) * (1.0 / 3.0);
    float lin = dot(s.dC, col) + (normals ? dot(s.dN, nrm) : 0.0) + r + u;
    float dval, dphi;
#if N_SAMP == 1
    dval = alpha * mid;
    dphi = lin + s.dD * mid;
#else
    dval = 0.0;
    float tr = 1.0;
    float trs[N_SAMP];
    for (int k = 0; k < N_SAMP; ++k) {
        trs[k] = tr;
        dval += tr * la[k] * (a + (float(k) + 0.5) * step_sz);
        tr *= 1.0 - la[k];
    }
    dphi = lin;
#endif
    float phi = alpha * lin + s.dD * dval;
    float g_alpha = Tk * (dphi - s.A);
    red[VG_PRIO] += abs(alpha * g_alpha);
    // Past the clamp α = min(MAX_ALPHA, ·): its derivative (0), or straight through
    // with alpha_straight (SVRaster's backward.cu uses exp(−vol) either way).
    bool a_straight = pc.back.alpha_straight != 0u;
    float g_vol = raw_alpha > MAX_ALPHA && !a_straight ? 0.0 : g_alpha * exp(-vol);
    float d_lv[N_SAMP];
    for (int k = 0; k < N_SAMP; ++k) d_lv[k] = g_vol;
#if N_SAMP > 1
    // Depth of a K-sample segment: dval = Σ_s tr_s la_s t_s.
    float S = 0.0;
    for (int k = N_SAMP - 1; k >= 0; --k) {
        float t = a + (float(k) + 0.5) * step_sz;
        float dla = trs[k] * (t - S);
        float lraw = alpha_of_depth(lv[k]);
        if (lraw <= MAX_ALPHA || a_straight) d_lv[k] += Tk * s.dD * dla * exp(-lv[k]);
        S = la[k] * t + (1.0 - la[k]) * S;
    }
#endif
    for (int k = 0; k < N_SAMP; ++k) {
        float coef = d_lv[k] * STEP_SZ_SCALE * step_sz * explin_grad(rho[k]);
        vec3 q = qs[k], q0 = 1.0 - q;
        for (uint c = 0u; c < 8u; ++c) {
            float wt = ((c & 4u) != 0u ? q.x : q0.x) * ((c & 2u) != 0u ? q.y : q0.y) *
                       ((c & 1u) != 0u ? q.z : q0.z);
            red[VG_GEO + c] += coef * wt;
        }
    }
    vec3 d_rgb = w * s.dC + (w * (lam_r * (2.0 / 3.0) + 2.0 * pc.back.lambda_r_colour)) * diff;
    for (uint c = 0u; c < 3u; ++c) red[VG_RGB + c] += d_rgb[c];
    if (normals) {
        vec3 d_nrm = w * s.dN;
        for (uint c = 0u; c < 3u; ++c) red[VG_NRM + c] += d_nrm[c];
    }
    s.A = phi + (1.0 - alpha) * s.A;
    if (distortion) {
        s.wa += w;
        s.ma += w * dmid;
    }
    s.T = Tk;
    return work;
}

void main() {
    FrameParams P = pc.frame;
    BackParams B = pc.back;
    uint l = gl_LocalInvocationID.x;
    uint tiles_x = P.tiles.x;
    // The tile and the part of its list this workgroup walks: chunk `pc.chunk` of the
    // tile of this workgroup, or the segment of this workgroup's slot (the forward's).
    uint tile, slot = 0u, start, end;
    if (pc.mode == SEG_OFF) {
        tile = gl_WorkGroupID.y * tiles_x + gl_WorkGroupID.x;
        uint r0 = P.ranges.v[2u * tile], r1 = P.ranges.v[2u * tile + 1u];
        start = r0 + min(r1 - r0, pc.chunk * B.chunk_size);
        end = min(r1, start + B.chunk_size);
    } else {
        // Uniform exits: no segment in this slot.
        slot = linear_group_id();
        if (slot >= P.slot_cap) return;
        tile = P.seg_tile.v[slot];
        if (tile == 0xffffffffu) return;
        uint r0 = P.ranges.v[2u * tile], r1 = P.ranges.v[2u * tile + 1u];
        start = r0 + (slot - seg_first_slot(P, tile, r0)) * P.seg_size;
        end = min(r1, start + P.seg_size);
    }
    // Without segments the origin is the workgroup id's, which the compiler recomputes
    // where used instead of carrying it across the walk's barriers (llvmpipe saves live
    // values at each).
    uvec2 org = pc.mode == SEG_OFF ? gl_WorkGroupID.xy * 16u
                                   : uvec2(tile % tiles_x, tile / tiles_x) * 16u;
    uvec2 lp0 = walk_pixel(0u), lp1 = walk_pixel(1u);
    BPx s0 = bpx_init(P, B, lp0, org, slot);
    BPx s1 = bpx_init(P, B, lp1, org, slot);
    // Nothing after the tile's last contributor matters.
    if (l == 0u) s_last = 0u;
    barrier();
    atomicMax(s_last, max(s0.last, s1.last));
    barrier();
    end = min(end, max(s_last, start));
    uint n = end - start;

#ifdef COUNTERS
    // Per invocation (a dispatch stays far below 2^32 of each).
    uint c_trips = 0u, c_useful = 0u, c_dense = 0u, c_pairs = 0u, c_cross = 0u, c_contrib = 0u,
         c_build = 0u;
#endif
    uint sg = gl_SubgroupID;
    walk_setup(l, lp0, lp1, s0.sign, s1.sign, s0.inside, s1.inside);
    uint sg_last = subgroupMax(max(s0.inside ? s0.last : 0u, s1.inside ? s1.last : 0u));
    // Subgroups with a contributor in this chunk.
    if (l == 0u) s_live = 0u;
    barrier();
    if (sg_last > start && subgroupElect()) atomicOr(s_live, 1u << sg);
    barrier();
    uint live = s_live;

    for (uint top = n; top > 0u;) {
        uint cnt = min(STAGE_SLOTS, top);
        uint base = top - cnt;  // batch [base, top) of the chunk
        top = base;
        barrier();
        stage_slot(P, walk_slot(), cnt, start + base, org, live);
        barrier();
        // Nothing at or after the subgroup's last contributor.
        uint word = visit_word(P, start + base, sg_last);
#ifdef COUNTERS
        c_dense += WALK_PPL * cnt;
        if ((live & (1u << sg)) != 0u) c_build += 1u;
#endif

#ifdef DETERMINISTIC
        // One subgroup at a time (uniform loop; the barrier makes its record adds
        // visible to the next turn).
        for (uint turn = 0u; turn < gl_NumSubgroups; ++turn) {
        if (turn == sg) {
#endif
        for (uint ww = WALK_WORDS; ww > 0u; --ww) {
            uint bits = subgroupShuffle(word, ww - 1u);
            while (bits != 0u) {
                uint b32 = uint(findMSB(bits));
                bits &= ~(1u << b32);
                uint j = 32u * (ww - 1u) + b32;
                uint idx = start + base + j;
                Entry e = load_entry(j);  // j is the same on every lane
                bool need0 = s0.inside && idx < s0.last && covers(e.val, e.box, s0.sign, s0.pix);
                bool need1 = s1.inside && idx < s1.last && covers(e.val, e.box, s1.sign, s1.pix);
                // No vote here: the visit set holds only entries some lane needs (1.00
                // trips per useful trip), and a vote is a loop over the lanes on llvmpipe.
                float red[16];
                for (uint c = 0u; c < 16u; ++c) red[c] = 0.0;
                uint w0 = bpx_step(s0, e, idx, need0, red);
                uint w1 = bpx_step(s1, e, idx, need1, red);
#ifdef COUNTERS
                c_trips += 1u;
                if (subgroupAny(need0 || need1)) c_useful += 1u;
                c_pairs += uint(need0) + uint(need1);
                c_cross += uint(w0 >= 1u) + uint(w1 >= 1u);
                c_contrib += uint(w0 == 2u) + uint(w1 == 2u);
#endif
                // One voxel per entry: reduce over the subgroup, every lane adds a component.
#ifdef DETERMINISTIC
                reduce_add(red, VG_STRIDE * record_index(e, org / 16u));
#else
                reduce_add(red, VG_STRIDE * (e.val & 0x1fffffffu));
#endif
            }
        }
#ifdef DETERMINISTIC
        }
        memoryBarrierBuffer();
        barrier();
        }
#endif
    }
#ifdef COUNTERS
    U64s ctr = P.counters;  // a writable copy of the address (the block is readonly)
    flush_counters(ctr, CTR_BWD, c_trips, c_useful, c_dense, c_pairs, c_cross, c_contrib,
                   c_build, 0u, 0u); // body runs and lane maxima: the forward's only
#endif
    if (pc.mode == SEG_OFF) {
        bpx_store(P, B, s0);
        bpx_store(P, B, s1);
    }
}
