#version 460
// Training backward with K = 1 sample(s) per voxel segment, native float atomics (see lib/backward.glsl).
#define FLOAT_ATOMICS
#define N_SAMP 1
#include "backward.glsl"
