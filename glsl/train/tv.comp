#version 460
// TV on the grid-point densities with native float atomic adds (VK_EXT_shader_atomic_float).
#define FLOAT_ATOMICS
#include "atomic_f32.glsl"
#include "tv.glsl"
