#version 460
// Forward compositing with K = 2 sample(s) per voxel segment (see lib/composite.glsl).
#define N_SAMP 2
#include "composite.glsl"
