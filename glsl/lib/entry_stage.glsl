// Staging of sorted (tile, sign) entries in shared memory, shared by the forward
// composite and the training backward: per slot ENTRY_WORDS words holding the entry
// value (sign << 29 | voxel), the voxel's pixel rectangle, camera-relative centre and
// size, 8 corner densities, colour and normal, as preprocess left them.
//
// A subgroup reads a slot with the same index on every lane (tile_walk.glsl), so
// load_entry reads it lane-parallel (one vec4 load, lane i < 6 reading words 4i..4i+3)
// and broadcasts the six vec4s: llvmpipe turns every shared load into a loop over the
// lanes even when the address is uniform, so 21 uniform loads cost 21 such loops, one
// lane-parallel load plus six broadcasts a fraction of that (forward 133 → 53 ms on lego
// 100², docs/PERFORMANCE.md). Needs a subgroup size of at least 8.
#ifndef ENTRY_STAGE_GLSL
#define ENTRY_STAGE_GLSL
#extension GL_EXT_control_flow_attributes : require
#include "raster_params.glsl"

const uint ENTRY_WORDS = 24u;  // 21 used: val, box (2), cs (4), geo (8), rgb (3), nrm (3)
// Entries staged per batch: one per invocation of the tile's workgroup (tile_walk.glsl).
const uint STAGE_SLOTS = 128u;
const uint EW_VAL = 0u, EW_BOX = 1u, EW_CS = 3u, EW_GEO = 7u, EW_RGB = 15u, EW_NRM = 18u;

shared vec4 s_ent[STAGE_SLOTS * ENTRY_WORDS / 4u];

struct Entry {
    uint val;
    uvec2 box;
    vec4 cs;
    float g[8];
    vec3 rgb;
    vec3 nrm;
};

// Copies sorted entry `index` into slot `slot`; returns its value and rectangle.
void stage_entry(FrameParams P, uint slot, uint index, out uint val, out uvec2 box) {
    val = P.svals.v[index];
    uint v = val & 0x1fffffffu;
    box = uvec2(P.bbox.v[2u * v], P.bbox.v[2u * v + 1u]);
    float w[24];
    w[EW_VAL] = uintBitsToFloat(val);
    w[EW_BOX] = uintBitsToFloat(box.x);
    w[EW_BOX + 1u] = uintBitsToFloat(box.y);
    for (uint c = 0u; c < 4u; ++c) w[EW_CS + c] = P.cs.v[4u * v + c];
    for (uint c = 0u; c < 8u; ++c) w[EW_GEO + c] = P.geo8.v[8u * v + c];
    for (uint c = 0u; c < 3u; ++c) {
        w[EW_RGB + c] = P.rgb.v[3u * v + c];
        w[EW_NRM + c] = P.nrm.v[3u * v + c];
    }
    w[21] = 0.0;
    w[22] = 0.0;
    w[23] = 0.0;
    uint o = (ENTRY_WORDS / 4u) * slot;
    [[unroll]] for (uint q = 0u; q < 6u; ++q)
        s_ent[o + q] = vec4(w[4u * q], w[4u * q + 1u], w[4u * q + 2u], w[4u * q + 3u]);
}

// The entry in slot `j`, which must be the same on every lane (uniform control flow).
Entry load_entry(uint j) {
    vec4 x = s_ent[(ENTRY_WORDS / 4u) * j + min(gl_SubgroupInvocationID, 5u)];
    float w[24];
    [[unroll]] for (uint q = 0u; q < 6u; ++q) {
        vec4 b = subgroupBroadcast(x, q);
        w[4u * q] = b.x;
        w[4u * q + 1u] = b.y;
        w[4u * q + 2u] = b.z;
        w[4u * q + 3u] = b.w;
    }
    Entry e;
    e.val = floatBitsToUint(w[EW_VAL]);
    e.box = uvec2(floatBitsToUint(w[EW_BOX]), floatBitsToUint(w[EW_BOX + 1u]));
    e.cs = vec4(w[EW_CS], w[EW_CS + 1u], w[EW_CS + 2u], w[EW_CS + 3u]);
    [[unroll]] for (uint c = 0u; c < 8u; ++c) e.g[c] = w[EW_GEO + c];
    e.rgb = vec3(w[EW_RGB], w[EW_RGB + 1u], w[EW_RGB + 2u]);
    e.nrm = vec3(w[EW_NRM], w[EW_NRM + 1u], w[EW_NRM + 2u]);
    return e;
}

// Whether an entry (value `val`, pixel rectangle `box`) is of this ray's sign octant
// and its rectangle holds pix.
bool covers(uint val, uvec2 box, uint sign, uvec2 pix) {
    return (val >> 29u) == sign && pix.x >= (box.x & 0xffffu) && pix.x <= (box.y & 0xffffu) &&
           pix.y >= (box.x >> 16u) && pix.y <= (box.y >> 16u);
}
#endif
