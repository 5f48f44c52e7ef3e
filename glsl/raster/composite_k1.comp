#version 460
// Forward compositing with K = 1 sample(s) per voxel segment (see lib/composite.glsl).
#define N_SAMP 1
#include "composite.glsl"
