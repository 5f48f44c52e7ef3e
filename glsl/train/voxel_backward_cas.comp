#version 460
// Per-voxel training backward with CAS float adds (see lib/voxel_backward.glsl).
#include "voxel_backward.glsl"
