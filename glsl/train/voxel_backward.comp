#version 460
// Per-voxel training backward with native float atomics (see lib/voxel_backward.glsl).
#define FLOAT_ATOMICS
#include "voxel_backward.glsl"
