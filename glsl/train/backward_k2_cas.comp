#version 460
// Training backward with K = 2 sample(s) per voxel segment, CAS float adds (devices without float atomics) (see lib/backward.glsl).
#define N_SAMP 2
#include "backward.glsl"
