#version 460
// Segmented frames ("Segments" in raster_params.glsl), training backward, after
// grad_prepare: per pixel, the state the backward walk carries (transmittance T, the
// per-unit-transmittance suffix A, Σ w and Σ w·m behind) at the back of each of the
// tile's segments, so every segment is walked back to front by its own workgroup.
//
// With G = Σ_k T_k φ_k + T_final g_T (backward.glsl), the suffix behind a boundary with
// transmittance T_b is A_b = (Σ_{k behind} T_k φ_k + T_final g_T) / T_b, and a segment's
// Φ = Σ_{k in it} T_k φ_k follows from the forward's partial sums (weights w = T·α):
//   Φ = dC·ΣwC + dN·ΣwN + dD·ΣT·dval + (λ_R/3)(Σw|c|² − 2 gt·ΣwC + |gt|² W)
//       + 2 λ_dist (L + (MA + M_s) W − (1 − T_s + WA) M)
// with W = Σw = T_s − T_end, M = Σw·m = M_end − M_s, L the segment's distortion sum,
// (T_s, M_s) the state in front of it and (WA, MA) the Σ w, Σ w·m behind it (checked
// against the sequential recursion in f64 and through the f64 reference gradients:
// tests/train_grad/ segmented_*).
#include "raster_params.glsl"
#include "explin.glsl"
#include "backward_params.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    FrameParams frame;
    BackParams back;
} pc;

float st(uint ch, uint slot, uint q) {
    return pc.frame.seg_state.v[seg_word(pc.frame, ch, slot, q)];
}

void main() {
    FrameParams P = pc.frame;
    BackParams B = pc.back;
    uint tile = gl_WorkGroupID.y * P.tiles.x + gl_WorkGroupID.x;
    uint q = gl_LocalInvocationID.x;
    uvec2 pix = gl_WorkGroupID.xy * 16u + uvec2(q % 16u, q / 16u);
    uint W = P.render_size.x, H = P.render_size.y;
    if (pix.x >= W || pix.y >= H) return;
    uint r0 = P.ranges.v[2u * tile], r1 = P.ranges.v[2u * tile + 1u];
    if (r1 <= r0) return;
    uint n = seg_count(P, r0, r1);
    uint first = seg_first_slot(P, tile, r0);
    uint npix = W * H;
    uint p = pix.y * W + pix.x;
    vec3 rd;
    float rd_norm;
    pixel_ray(P, pix, rd, rd_norm);
    vec3 dC = vec3(B.dimg.v[DI_R * npix + p], B.dimg.v[DI_G * npix + p], B.dimg.v[DI_B * npix + p]);
    vec3 dN = vec3(B.dimg.v[DI_NX * npix + p], B.dimg.v[DI_NY * npix + p], B.dimg.v[DI_NZ * npix + p]);
    vec3 gt = vec3(B.dimg.v[DI_GTR * npix + p], B.dimg.v[DI_GTG * npix + p], B.dimg.v[DI_GTB * npix + p]);
    float dD = B.dimg.v[DI_DEPTH * npix + p] / rd_norm;  // as backward.glsl's bpx_init
    bool normals = frame_normals(P);
    bool distortion = B.lambda_dist != 0.0;
    // Σ_{k behind} T_k φ_k + T_final g_T, and Σ w, Σ w·m behind.
    float gT = B.dimg.v[DI_T * npix + p];
    float S = P.aux.v[AUX_T * npix + p] * gT;
    float WA = 0.0, MA = 0.0;
    bool behind = false;  // a live segment behind this one
    for (uint zz = n; zz > 0u; --zz) {
        uint slot = first + zz - 1u;
        float Ts = st(SEG_T, slot, q);
        if (Ts < EARLY_STOP_T) {
            // Behind the early stop: nothing to walk (all past the last contributor).
            P.seg_state.v[seg_word(P, SEG_BT, slot, q)] = 1.0;
            P.seg_state.v[seg_word(P, SEG_BA, slot, q)] = 0.0;
            P.seg_state.v[seg_word(P, SEG_BWA, slot, q)] = 0.0;
            P.seg_state.v[seg_word(P, SEG_BMA, slot, q)] = 0.0;
            continue;
        }
        float Te = st(SEG_TEND, slot, q);
        P.seg_state.v[seg_word(P, SEG_BT, slot, q)] = Te;
        // The last live segment starts exactly where the unsegmented walk starts
        // (T_final, g_T): a tile with one segment trains bit for bit as without.
        P.seg_state.v[seg_word(P, SEG_BA, slot, q)] = !behind ? gT : (Te > 0.0 ? S / Te : 0.0);
        behind = true;
        P.seg_state.v[seg_word(P, SEG_BWA, slot, q)] = WA;
        P.seg_state.v[seg_word(P, SEG_BMA, slot, q)] = MA;
        vec3 C = vec3(st(SEG_R, slot, q), st(SEG_G, slot, q), st(SEG_B, slot, q));
        float Wz = Ts - Te;
        float phi = dot(dC, C) + dD * st(SEG_D, slot, q);
        if (normals) phi += dot(dN, vec3(st(SEG_NX, slot, q), st(SEG_NY, slot, q), st(SEG_NZ, slot, q)));
        if (B.lambda_r != 0.0)
            phi += B.lambda_r * (1.0 / 3.0) * (st(SEG_Q, slot, q) - 2.0 * dot(gt, C) + dot(gt, gt) * Wz);
        float Mz = 0.0;
        if (distortion) {
            float Ms = st(SEG_M, slot, q);
            Mz = st(SEG_MEND, slot, q) - Ms;
            phi += 2.0 * B.lambda_dist *
                   (st(SEG_DIST, slot, q) + (MA + Ms) * Wz - (1.0 - Ts + WA) * Mz);
        }
        S += phi;
        WA += Wz;
        MA += Mz;
    }
}
