#version 460
// Forward compositing with K = 3 sample(s) per voxel segment (see lib/composite.glsl).
#define N_SAMP 3
#include "composite.glsl"
