#version 460
// Segmented frames ("Segments" in raster_params.glsl): one workgroup per tile, one
// invocation per pixel, over the tile's segments in depth order.
//   SEG_PREFIX: each segment's (own transmittance, own Σ w·m) → (transmittance, Σ w·m)
//     in front of it: T_z = Π_{j<z} τ_j, M_z = Σ_{j<z} T_j · m_j (m_j with the segment's
//     own weights; the frame's weights are T_j times them).
//   SEG_MERGE: the partials of the exact pass summed in order (colour, depth, normal and
//     distortion sums carry the frame's weights already) and what the sequential walk
//     stores after its last entry: the transmittance and Σ w·m after the last segment
//     that composited (one whose front transmittance was above the early stop), the
//     last contributor and the median of the last segment that has one.
#include "raster_params.glsl"
#include "explin.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams frame;
    uint mode;  // SEG_PREFIX or SEG_MERGE
    uint pad;
} pc;

void main() {
    FrameParams P = pc.frame;
    uint tile = gl_WorkGroupID.y * P.tiles.x + gl_WorkGroupID.x;
    uint q = gl_LocalInvocationID.x;
    uvec2 pix = gl_WorkGroupID.xy * 16u + uvec2(q % 16u, q / 16u);
    uint W = P.render_size.x, H = P.render_size.y;
    if (pix.x >= W || pix.y >= H) return;
    uint r0 = P.ranges.v[2u * tile], r1 = P.ranges.v[2u * tile + 1u];
    uint n = r1 > r0 ? seg_count(P, r0, r1) : 0u;
    uint first = n > 0u ? seg_first_slot(P, tile, r0) : 0u;
    if (pc.mode == SEG_PREFIX) {
        float T = 1.0, M = 0.0;
        for (uint z = 0u; z < n; ++z) {
            uint slot = first + z;
            uint it = seg_word(P, SEG_T, slot, q), im = seg_word(P, SEG_M, slot, q);
            // The last segment's own product was not computed (nothing needs it).
            float tau = z + 1u < n ? P.seg_state.v[it] : 1.0;
            float m = z + 1u < n ? P.seg_state.v[im] : 0.0;
            P.seg_state.v[it] = T;
            P.seg_state.v[im] = M;
            M += T * m;
            T *= tau;
        }
        return;
    }
    vec3 C = vec3(0.0), N = vec3(0.0);
    float T = 1.0, D = 0.0, dist_m = 0.0, dist_l = 0.0, t_last = 1.0, med_t = 0.0;
    uint last = 0u, med_id = 0xffffffffu;
    for (uint z = 0u; z < n; ++z) {
        uint slot = first + z;
        // A segment behind the early stop composited nothing and stored its start.
        if (P.seg_state.v[seg_word(P, SEG_T, slot, q)] < EARLY_STOP_T) break;
        C += vec3(P.seg_state.v[seg_word(P, SEG_R, slot, q)],
                  P.seg_state.v[seg_word(P, SEG_G, slot, q)],
                  P.seg_state.v[seg_word(P, SEG_B, slot, q)]);
        N += vec3(P.seg_state.v[seg_word(P, SEG_NX, slot, q)],
                  P.seg_state.v[seg_word(P, SEG_NY, slot, q)],
                  P.seg_state.v[seg_word(P, SEG_NZ, slot, q)]);
        D += P.seg_state.v[seg_word(P, SEG_D, slot, q)];
        dist_l += P.seg_state.v[seg_word(P, SEG_DIST, slot, q)];
        dist_m = P.seg_state.v[seg_word(P, SEG_MEND, slot, q)];
        T = P.seg_state.v[seg_word(P, SEG_TEND, slot, q)];
        uint zl = floatBitsToUint(P.seg_state.v[seg_word(P, SEG_LAST, slot, q)]);
        if (zl != 0u) {
            last = zl;
            t_last = P.seg_state.v[seg_word(P, SEG_TLAST, slot, q)];
        }
        uint zm = floatBitsToUint(P.seg_state.v[seg_word(P, SEG_MEDID, slot, q)]);
        if (zm != 0xffffffffu) {
            med_id = zm;
            med_t = P.seg_state.v[seg_word(P, SEG_MEDT, slot, q)];
        }
    }
    // What composite.glsl's px_store writes.
    uint npix = W * H;
    uint p = pix.y * W + pix.x;
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
