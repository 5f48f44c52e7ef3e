#version 460
// Training backward with K = 1 sample(s) per voxel segment, CAS float adds (devices without float atomics) (see lib/backward.glsl).
#define N_SAMP 1
#include "backward.glsl"
