// Device layout of the higher-order SH coefficients, their gradients and Adam moments
// (src/scene/mod.rs SHS_BLOCK): blocks of 8 voxels interleave their values, value e of
// voxel v (w values per voxel) at (v / 8)·8w + 8e + v % 8, so a subgroup's threads (one
// voxel each) touch whole cache lines instead of one line per lane.
#ifndef SH_LAYOUT_GLSL
#define SH_LAYOUT_GLSL
uint shs_index(uint v, uint e, uint w) {
    return (v >> 3u) * (8u * w) + 8u * e + (v & 7u);
}
#endif
