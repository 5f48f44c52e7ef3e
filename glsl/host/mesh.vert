#version 460
// The viewer host engine's geometry pass (src/viewer/, tests/host/): vertices
// pulled from a buffer device address, 6 floats each (position xyz, colour rgb),
// transformed by the host's view-projection (Vulkan clip space).
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require

layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer Vertices {
    float v[];
};

layout(push_constant) uniform Push {
    mat4 view_projection;
    Vertices vertices;
} pc;

layout(location = 0) out vec3 v_colour;

void main() {
    uint b = 6u * uint(gl_VertexIndex);
    vec3 pos = vec3(pc.vertices.v[b], pc.vertices.v[b + 1u], pc.vertices.v[b + 2u]);
    v_colour = vec3(pc.vertices.v[b + 3u], pc.vertices.v[b + 4u], pc.vertices.v[b + 5u]);
    gl_Position = pc.view_projection * vec4(pos, 1.0);
}
