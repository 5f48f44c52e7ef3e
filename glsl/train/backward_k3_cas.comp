#version 460
// Training backward with K = 3 sample(s) per voxel segment, CAS float adds (devices without float atomics) (see lib/backward.glsl).
#define N_SAMP 3
#include "backward.glsl"
