#version 460
// The example host's composite pass: the radiance field's premultiplied RGBA16F pixels
// (a buffer written by HostRenderer, read through its device address) blended over the
// host's colour attachment with (ONE, ONE_MINUS_SRC_ALPHA).
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require

layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer Pixels {
    uint v[];
};

layout(push_constant) uniform Push {
    Pixels pixels;
    uint width;
} pc;

layout(location = 0) out vec4 colour;

void main() {
    uvec2 p = uvec2(gl_FragCoord.xy);
    uint i = p.y * pc.width + p.x;
    colour = vec4(unpackHalf2x16(pc.pixels.v[2u * i]), unpackHalf2x16(pc.pixels.v[2u * i + 1u]));
}
