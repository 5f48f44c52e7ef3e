#version 460
// Training backward with K = 2 sample(s) per voxel segment, native float atomics (see lib/backward.glsl).
#define FLOAT_ATOMICS
#define N_SAMP 2
#include "backward.glsl"
