// Per-frame parameters of the rasterizer, written into the command buffer with
// vkCmdUpdateBuffer (so a recorded frame is self-contained) and read through a device
// address. Mirrored by `raster::FrameParams` in Rust; build.rs reflects this block from the
// SPIR-V and `gpu_layout!` fails the build when a member name or offset differs.
// All geometry is camera-relative: the camera sits at the origin of world axes.
// Voxel corners relative to the camera are computed from integer grid coordinates
// minus the camera's integer grid position (exact), minus its fractional part, times the
// grid unit: level-16 voxels keep full f32 precision relative to the camera however far
// the scene is from the world origin.
#ifndef RASTER_PARAMS_GLSL
#define RASTER_PARAMS_GLSL
#include "common.glsl"

layout(buffer_reference, std430, buffer_reference_align = 16) readonly buffer FrameParams {
    vec4 w2c[3];        // rows of the world-to-camera rotation (xyz)
    vec4 c2w[3];        // rows of the camera-to-world rotation (xyz)
    vec4 intr;          // fx, fy, cx, cy (render resolution)
    vec3 cam_frac;      // camera position in finest-grid units: fractional part
    float unit;         // finest-grid unit length (world units)
    vec3 bg;            // background rgb
    float near;         // near plane (camera depth)
    uvec2 render_size;  // width, height of the rendered (possibly supersampled) image
    uvec2 tiles;        // tiles along x, y
    uint voxels;
    uint sh_degree;
    uint max_level;
    uint entry_capacity;  // entries the key buffers hold
    uint chunks;          // chunks recorded
    uint chunk_size;      // entries per chunk
    uint key_shift;       // 3 * max_level: bits of the Morton part of a sort key
    uint supersampled;    // 0/1: render_size differs from out_size (downsample pass)
    uvec2 out_size;       // width, height of the output image
    uint shs_stride;      // SH coefficients stored per voxel (rgb triples)
    uint key32;           // 0/1: the sort keys are u32 (the sort's bits fit in 32)
    vec2 ss_scale;        // render / out size, x and y
    vec2 filter_radius;   // downsample filter radius, x and y (output pixels)
    ivec3 cam_int;        // camera position in finest-grid units: integer part
    uint flags;           // FRAME_* bits
    // Host depth convention (raster/host/): a host depth value z at camera-space
    // direction (x', y', 1) and camera depth d satisfies z = dot(xyz, (x', y', 1)) + w / d.
    vec4 depth_map;
    // scene
    U64s octpath; U32s level; U32s corners; F32s geo; F32s sh0; F32s shs;
    // per voxel (frame)
    U32s bbox; U32s signs; U32s counts; U32s offsets; F32s geo8; F32s rgb; F32s nrm; F32s cs;
    // entries: emitted, and sorted
    U64s keys; U32s vals; U64s skeys; U32s svals;
    // per tile / pixel
    U32s ranges; F32s img; U32s med_id; F32s med_t; F32s out_img;
    U32s stats;
    // per pixel, for training: 1 + index of the last contributing sorted entry (0: none),
    // and AUX_CHANNELS planar floats (distortion sums, exact final transmittance)
    U32s last; F32s aux;
    // optional (0: off): per voxel, the largest blending weight T·α seen on any pixel
    // of the frames recorded with it set, as float bits folded in with atomicMax (the
    // adaptive pass's statistics, paper §3.2.2)
    U32s maxw;
    // optional (0: off; read only by the COUNTERS kernel variants): work counters, u64
    // words CTR_FWD + CTR_* (forward composite) and CTR_BWD + CTR_* (backward)
    U64s counters;
    // optional (0: off): the host's depth values at output resolution (row-major,
    // out_size), converted with depth_map: each ray ends at the host's surface
    F32s host_depth;
    // Segmented compositing (seg_size > 0; see "Segments" below): the tile of each
    // slot (~0: none), and SEG_CHANNELS planar per-pixel floats per slot
    U32s seg_tile; F32s seg_state;
    uint seg_size;   // entries per segment (0: segments off, chunks as before)
    uint slot_cap;   // slots the two buffers above hold
    // optional (0: the constant background `bg`): the frame-mean background's sums
    // (raster/frame_mean.comp), whose FM_SLOT_MEAN finalize composites behind T
    F32s bgsum;
};

// Work counters (bench): per walk, subgroup loop trips over entries; trips where at least
// one lane's pixel needs the entry (rectangle and sign); trips the full walk (every
// subgroup × every staged entry) would have made; (pixel, entry) pairs past the
// rectangle and sign test; ray–voxel crossings; contributions (α ≥ MIN_ALPHA);
// visit-set builds (one per subgroup and staged batch); subgroups dispatched; (forward
// only) pixel steps whose crossing branch ran for the subgroup (a lane's pixel crossed
// the entry's voxel: `px_step`'s body) and, per staged batch, the subgroup's largest
// crossing count of one lane (what a walk over each lane's own list of crossings would
// run instead: docs/NVIDIA.md, "Where a GPU frame goes next").
const uint CTR_TRIPS = 0u, CTR_USEFUL = 1u, CTR_DENSE = 2u, CTR_PAIRS = 3u, CTR_CROSS = 4u,
           CTR_CONTRIB = 5u, CTR_BUILD = 6u, CTR_SUBGROUPS = 7u, CTR_BODY = 8u,
           CTR_LANE_MAX = 9u, CTR_WALK_WORDS = 10u, CTR_FWD = 0u, CTR_BWD = 10u,
           CTR_WORDS = 20u;

// Words of the stats buffer.
const uint STAT_TOTAL = 0u;      // u64: entries requested by preprocess
const uint STAT_USED = 2u;       // entries emitted and sorted (clamped to capacity)
const uint STAT_FLAGS = 3u;      // FLAG_* bits
const uint STAT_MAX_TILE = 4u;   // longest tile list
const uint STAT_VISIBLE = 5u;    // voxels with at least one entry
const uint STAT_SLOTS = 6u;      // segmented frames: slots the frame's lists need
const uint STAT_ARGS = 8u;       // dispatch args of the entry-parallel kernels
const uint STAT_SEG_ARGS = 11u;  // dispatch args over the slots (segmented frames)
const uint STATS_WORDS = 16u;

const uint FLAG_ENTRY_OVERFLOW = 1u;  // more entries than the key buffers hold
const uint FLAG_NEED_CHUNKS = 2u;     // a tile list is longer than the chunks recorded

// Host output formats and depth modes (raster/host_output.comp).
const uint HOST_RGBA8_UNORM = 0u, HOST_RGBA8_SRGB = 1u, HOST_RGBA16F = 2u, HOST_RGBA32F = 3u;
const uint HOST_DEPTH_MEDIAN = 0u, HOST_DEPTH_MEAN = 1u;
const uint HOST_IMAGE_COLOUR = 0u, HOST_IMAGE_DEPTH = 1u, HOST_IMAGE_NORMAL = 2u;

// Channels of the planar image buffers.
const uint CH_R = 0u, CH_G = 1u, CH_B = 2u, CH_T = 3u, CH_DEPTH = 4u, CH_DMED = 5u,
           CH_NX = 6u, CH_NY = 7u, CH_NZ = 8u, IMG_CHANNELS = 9u;
// Channels of the per-pixel training aux buffer (render resolution): Σ w·m (weighted
// segment midpoints), the distortion loss value, the final transmittance (kept
// exact: finalize turns CH_T into alpha = 1 - T, which loses a small T), and the
// transmittance in front of the last contributor (the backward starts there instead
// of dividing by 1 - α, which reaches 1e-5 for a near-opaque last voxel).
const uint AUX_M = 0u, AUX_DIST = 1u, AUX_T = 2u, AUX_TLAST = 3u, AUX_CHANNELS = 4u;
// The frame-mean background (raster/frame_mean.comp): the buffer's slots (floats), the
// pixels one workgroup sums, and the kernel's modes.
const uint FM_SLOT_MEAN = 0u, FM_SLOT_GRAD = 4u, FM_PARTIALS = 8u, FM_PIXELS = 4096u;
const uint FM_SUM_COLOUR = 0u, FM_SUM_TGRAD = 1u, FM_TOTAL = 2u, FM_APPLY = 3u;

// Segments. With seg_size = S > 0 a tile's sorted list [r0, r1) is cut into segments of
// S entries, each composited by its own workgroup (every SM busy however few tiles the
// image has), in three dispatches over the slots plus two per tile:
//   1. SEG_TRANSMIT: every segment but a tile's last, from T = 1, records its own
//      transmittance product and Σ w·m (local weights) per pixel (SEG_T, SEG_M);
//   2. seg_compose (SEG_PREFIX): per pixel, in depth order over the tile's segments,
//      the transmittance and Σ w·m in front of each segment (SEG_T, SEG_M replaced);
//   3. SEG_EXACT: every segment walks again from that state — the sequential walk's
//      own step, so every decision (early stop, median, last contributor, max weight)
//      is taken on the frame's transmittance — and stores its partial sums;
//   4. seg_compose (SEG_MERGE): per pixel, sums the partials in order and stores what
//      a sequential walk stores.
// The training backward walks the same segments, each from the state behind it
// (train/seg_bmerge.comp computes it from the partial sums and the loss gradients).
// Segment z of tile t (n_t = ceil((r1 - r0) / S) of them) has slot t + r0 / S + z: no
// two tiles share a slot (the last slot of t is at most t + r1 / S), and every slot is
// below tiles + used / S. A tile whose list fits one segment composites exactly as
// without segments (from T = 1 and zero sums), bit for bit.
const uint SEG_OFF = 0u, SEG_TRANSMIT = 1u, SEG_EXACT = 2u;  // composite modes
const uint SEG_PREFIX = 0u, SEG_MERGE = 1u;                  // seg_compose modes
const uint SEG_T = 0u, SEG_M = 1u, SEG_R = 2u, SEG_G = 3u, SEG_B = 4u, SEG_D = 5u,
           SEG_NX = 6u, SEG_NY = 7u, SEG_NZ = 8u, SEG_DIST = 9u, SEG_MEND = 10u,
           SEG_TEND = 11u, SEG_LAST = 12u, SEG_TLAST = 13u, SEG_MEDID = 14u, SEG_MEDT = 15u,
           SEG_Q = 16u, SEG_BT = 17u, SEG_BA = 18u, SEG_BWA = 19u, SEG_BMA = 20u,
           SEG_CHANNELS = 21u;
// SEG_Q: Σ w·|c|² (the per-point RGB loss's part of the backward's boundary state).
// SEG_BT..SEG_BMA: the backward's state at the back of each segment (train/seg_bmerge):
// the transmittance there, the suffix A, Σ w and Σ w·m behind the segment — what the
// chunked backward carries between chunks, so each segment walks back to front alone.

uint seg_first_slot(FrameParams P, uint tile, uint r0) {
    return tile + r0 / P.seg_size;
}
uint seg_count(FrameParams P, uint r0, uint r1) {
    return (r1 - r0 + P.seg_size - 1u) / P.seg_size;
}
// Word of channel `ch` of pixel q (y * 16 + x in the tile) of slot `slot`.
uint seg_word(FrameParams P, uint ch, uint slot, uint q) {
    return (ch * P.slot_cap + slot) * 256u + q;
}

// Direction of pixel (px, py) (pixel centres at +0.5): unit world direction with
// near-zero components flushed to exactly zero, and |camera-space direction| (whose
// z is 1), which converts ray distance to camera depth.
void pixel_ray(FrameParams P, uvec2 pix, out vec3 rd, out float rd_norm) {
    vec3 cam = vec3((float(pix.x) + 0.5 - P.intr.z) / P.intr.x,
                    (float(pix.y) + 0.5 - P.intr.w) / P.intr.y, 1.0);
    rd_norm = length(cam);
    vec3 w = vec3(dot(P.c2w[0].xyz, cam), dot(P.c2w[1].xyz, cam), dot(P.c2w[2].xyz, cam));
    rd = w / rd_norm;
    rd = mix(rd, vec3(0.0), lessThan(abs(rd), vec3(1e-20)));
}

// Ray distance at which pixel (px, py) of the render meets the host's depth (infinity
// without host depth, or where the host value maps to no positive camera depth).
float host_t_far(FrameParams P, uvec2 pix, float rd_norm) {
    float inf = uintBitsToFloat(0x7f800000u);
    if (uint64_t(P.host_depth) == 0ul) return inf;
    uvec2 op = min(uvec2((vec2(pix) + 0.5) / P.ss_scale), P.out_size - 1u);
    float z = P.host_depth.v[op.y * P.out_size.x + op.x];
    vec2 xy = (vec2(pix) + 0.5 - P.intr.zw) / P.intr.xy;
    float a = dot(P.depth_map.xyz, vec3(xy, 1.0));
    float d = P.depth_map.w / (z - a);
    // NaN, negative (beyond infinity) and infinite depths: no cut.
    return d > 0.0 && d < inf ? d * rd_norm : inf;
}

// FrameParams.flags. GENERIC_WALK: the tile walk builds its visit sets by the path for
// any subgroup size (tests). NORMALS: the composite accumulates the normal image (else
// it stays 0) and the backward propagates its gradient. DISTORTION: the composite
// accumulates the distortion sums (AUX_M, AUX_DIST; else 0), which the distortion loss
// and its gradient need. DIST_CONTRACT: those sums are taken on SVRaster's contracted
// axis (dist_axis below) instead of the ray parameter t.
const uint FRAME_GENERIC_WALK = 1u, FRAME_NORMALS = 2u, FRAME_DISTORTION = 4u,
           FRAME_DIST_CONTRACT = 8u;

// The background behind the frame's remaining transmittance: the constant `bg`, or with
// `bgsum` the frame's mean composited colour (raster/frame_mean.comp, FM_SLOT_MEAN).
vec3 frame_background(FrameParams P) {
    if (uint64_t(P.bgsum) == 0ul) return P.bg;
    return vec3(P.bgsum.v[FM_SLOT_MEAN], P.bgsum.v[FM_SLOT_MEAN + 1u], P.bgsum.v[FM_SLOT_MEAN + 2u]);
}

// Whether the frame accumulates normals / distortion sums (uniform branches). The
// NO_NORMALS kernel variants (build.rs), which the host picks for frames without
// normals, know it at compile time: the compiler then drops the normal state and work
// from the walk (measured: a uniform branch alone left most of that cost).
bool frame_normals(FrameParams P) {
#ifdef NO_NORMALS
    return false;
#else
    return (P.flags & FRAME_NORMALS) != 0u;
#endif
}
bool frame_distortion(FrameParams P) {
    return (P.flags & FRAME_DISTORTION) != 0u;
}

// The distortion loss's axis at ray distance t (pixel_ray's rd is a unit vector; uniform
// branch): t itself, or with FRAME_DIST_CONTRACT SVRaster's `depth_contracted`
// (cuda/src/auxiliary.h): t < 1 ? t : 2 − 1/t, so everything beyond distance 1 lies in
// [1, 2).
float dist_axis(FrameParams P, float t) {
    if ((P.flags & FRAME_DIST_CONTRACT) == 0u) return t;
    return t < 1.0 ? t : 2.0 - 1.0 / t;
}

// Pixel `l` (0..255) of a 16x16 tile in Morton order: 2^n consecutive ones form a
// rectangle (16: 4x4, 64: 8x8), which tile_walk.glsl's walk_pixel gives a subgroup
// (coherent rays, fewer idle lanes).
uvec2 tile_pixel(uint l) {
    uint x = (l & 1u) | ((l >> 1u) & 2u) | ((l >> 2u) & 4u) | ((l >> 3u) & 8u);
    uint y = ((l >> 1u) & 1u) | ((l >> 2u) & 2u) | ((l >> 3u) & 4u) | ((l >> 4u) & 8u);
    return uvec2(x, y);
}

// Camera-relative world position of integer finest-grid coordinates.
vec3 grid_to_camera(FrameParams P, uvec3 fine) {
    return (vec3(ivec3(fine) - P.cam_int) - P.cam_frac) * P.unit;
}
#endif
