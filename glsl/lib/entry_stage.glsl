// Staging of sorted (tile, sign) entries in shared memory, shared by the forward
// composite and the training backward: per slot the entry value (sign << 29 | voxel),
// the voxel's pixel rectangle, camera-relative centre and size, 8 corner densities,
// colour and normal, as preprocess left them.
#ifndef ENTRY_STAGE_GLSL
#define ENTRY_STAGE_GLSL
#include "raster_params.glsl"

shared uint s_val[256];
shared uvec2 s_box[256];
shared vec4 s_cs[256];
shared float s_geo[256 * 8];
shared float s_rgb[256 * 3];
shared float s_nrm[256 * 3];

// Copies sorted entry `index` into slot `slot`.
void stage_entry(FrameParams P, uint slot, uint index) {
    uint val = P.svals.v[index];
    uint v = val & 0x1fffffffu;
    s_val[slot] = val;
    s_box[slot] = uvec2(P.bbox.v[2u * v], P.bbox.v[2u * v + 1u]);
    s_cs[slot] = vec4(P.cs.v[4u * v], P.cs.v[4u * v + 1u], P.cs.v[4u * v + 2u], P.cs.v[4u * v + 3u]);
    for (uint c = 0u; c < 8u; ++c) s_geo[8u * slot + c] = P.geo8.v[8u * v + c];
    for (uint c = 0u; c < 3u; ++c) {
        s_rgb[3u * slot + c] = P.rgb.v[3u * v + c];
        s_nrm[3u * slot + c] = P.nrm.v[3u * v + c];
    }
}

// Whether the entry in slot `j` is of this ray's sign octant and its rectangle holds pix.
bool entry_covers(uint j, uint sign, uvec2 pix) {
    uvec2 box = s_box[j];
    return (s_val[j] >> 29u) == sign && pix.x >= (box.x & 0xffffu) && pix.x <= (box.y & 0xffffu) &&
           pix.y >= (box.x >> 16u) && pix.y <= (box.y >> 16u);
}
#endif
