// Common extensions and buffer-reference types. Every kernel takes its data as device
// addresses in its push-constant block, so no array is limited by maxStorageBufferRange.
#ifndef COMMON_GLSL
#define COMMON_GLSL
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require
#extension GL_EXT_shader_atomic_int64 : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_ballot : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_KHR_shader_subgroup_vote : require

layout(buffer_reference, std430, buffer_reference_align = 4) buffer U32s { uint v[]; };
layout(buffer_reference, std430, buffer_reference_align = 8) buffer U64s { uint64_t v[]; };
layout(buffer_reference, std430, buffer_reference_align = 4) buffer F32s { float v[]; };
// A vector view of the same buffers (every buffer starts 16-byte aligned, src/gpu/buffer.rs):
// for kernels that stream 4 consecutive elements per invocation (train/adam.comp). Measured
// on lavapipe, vec4 records in preprocess, voxel_backward and the entry staging gained
// nothing (their time is not in these accesses); Adam's time halved.
layout(buffer_reference, std430, buffer_reference_align = 16) buffer V4s { vec4 v[]; };

// Linear workgroup index of a (possibly 2-D) dispatch grid.
uint linear_group_id() {
    return gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
}
#endif
