// Parameters of the training backward (not readonly: its references are passed to
// atomic_add_f32), mirrored by `train::backward::BackParams` in Rust,
// checked member by member at build time (`gpu_layout!`).
#ifndef BACKWARD_PARAMS_GLSL
#define BACKWARD_PARAMS_GLSL
#include "common.glsl"

layout(buffer_reference, std430, buffer_reference_align = 16) buffer BackParams {
    float lambda_dist;  // distortion-loss weight, per pixel (divided by the pixel count)
    float lambda_r;     // per-pixel weight of the second loss term (divided likewise)
    uint chunks;        // chunks recorded
    uint chunk_size;    // entries per chunk
    uint voxels;
    float lambda_r_colour; // SVRaster's per-point RGB term: colour gradient 2λ·w·(c − gt) only
    uvec2 out_size;     // width, height of the output image
    uvec2 render_size;  // width, height of the rendered image
    F32s dimg;    // per render pixel, planar DI_CHANNELS: loss gradients and ground truth
    F32s dout;    // per output pixel, planar DO_CHANNELS: gradients w.r.t. the outputs + gt
    F32s bstate;  // per render pixel, planar BS_CHANNELS: backward state between chunks
    F32s vgrad;   // per voxel, VG_STRIDE floats
    F32s grad_geo;  // per grid point
    F32s grad_sh0;  // per voxel, 3
    F32s grad_shs;  // per voxel, 3 * stored coefficients (blocked: sh_layout.glsl)
    F32s priority;  // per voxel, accumulated Σ|α ∂L/∂α|
    U32s lost;      // CAS give-ups (atomic_f32.glsl)
    // Ordered reduction only (DETERMINISTIC variants; 0 otherwise):
    F32s records;   // per emitted entry, VG_STRIDE floats (backward.glsl)
    F32s vcorner;   // per voxel, 8 corner-density gradients before the grid-point sums
    U32s point_off;   // per grid point + 1: start of its (voxel · 8 + corner) list
    U32s point_list;  // per voxel corner, grouped by grid point, ascending
    uint gather_span; // records a voxel sums per records_gather pass
    uint colour_straight; // 1: ∂L/∂rgb passes max(0, ·) straight through (SVRaster's)
    uint alpha_straight;  // 1: ∂L/∂α passes min(MAX_ALPHA, ·) straight through (SVRaster's)
    // Transmittance losses on the render-resolution T (SVRaster's raw_T), per render
    // pixel: concentration T²(1−T)² and inside T² weights (0: none here; loss.comp has
    // the output-resolution forms)
    float lambda_t;
    float lambda_t_inside;
    uint r_bilinear;  // 1: the per-point RGB target is the photo bilinearly resized to
                      // render resolution (SVRaster's resize_rendering), else the output
                      // pixel containing the render pixel's centre
    uint pad4;
    uint pad5;
};

// dout: gradients w.r.t. the frame's outputs at output resolution (rgb with background,
// alpha, depth as camera z, normal) and the ground-truth rgb.
const uint DO_R = 0u, DO_G = 1u, DO_B = 2u, DO_ALPHA = 3u, DO_DEPTH = 4u, DO_NX = 5u,
           DO_NY = 6u, DO_NZ = 7u, DO_GTR = 8u, DO_GTG = 9u, DO_GTB = 10u, DO_CHANNELS = 11u;
// dimg: the same at render resolution, w.r.t. the raw composited sums (C = Σ w c
// without background, final transmittance T, depth as camera z, N = Σ w n).
const uint DI_R = 0u, DI_G = 1u, DI_B = 2u, DI_T = 3u, DI_DEPTH = 4u, DI_NX = 5u,
           DI_NY = 6u, DI_NZ = 7u, DI_GTR = 8u, DI_GTG = 9u, DI_GTB = 10u, DI_CHANNELS = 11u;
const uint BS_T = 0u, BS_A = 1u, BS_WA = 2u, BS_MA = 3u, BS_CHANNELS = 4u;
// Voxel gradient record: ∂L/∂(8 corner densities), ∂L/∂rgb, ∂L/∂normal, priority.
const uint VG_GEO = 0u, VG_RGB = 8u, VG_NRM = 11u, VG_PRIO = 14u, VG_USED = 15u,
           VG_STRIDE = 16u;
#endif
