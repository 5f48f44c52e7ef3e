#version 460
// TV on the grid-point densities with compare-and-swap float adds (any device).
#include "atomic_f32.glsl"
#include "tv.glsl"
