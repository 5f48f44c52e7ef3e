#version 460
// The viewer's composite pass (src/viewer/): premultiplied RGBA16F pixels (the radiance
// field written by HostRenderer, or the text overlay; a buffer read through its device
// address) blended over the host's colour attachment with (ONE, ONE_MINUS_SRC_ALPHA).
// `display` = 1: the attachment holds display (sRGB-encoded) values and the blend
// happens in them, as `svraster render` composites over the background: the field's
// premultiplied linear light α·decode(C/α) is turned back into α·(C/α) = C.
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_shader_explicit_arithmetic_types_int64 : require

layout(buffer_reference, std430, buffer_reference_align = 4) readonly buffer Pixels {
    uint v[];
};

layout(push_constant) uniform Push {
    Pixels pixels;
    uint width;
    uint display;
} pc;

layout(location = 0) out vec4 colour;

float srgb_encode(float x) {
    return x <= 0.0031308 ? 12.92 * x : 1.055 * pow(x, 1.0 / 2.4) - 0.055;
}

void main() {
    uvec2 p = uvec2(gl_FragCoord.xy);
    uint i = p.y * pc.width + p.x;
    vec4 c = vec4(unpackHalf2x16(pc.pixels.v[2u * i]), unpackHalf2x16(pc.pixels.v[2u * i + 1u]));
    if (pc.display != 0u && c.a > 0.0) {
        vec3 l = max(c.rgb / c.a, 0.0);
        c.rgb = c.a * vec3(srgb_encode(l.r), srgb_encode(l.g), srgb_encode(l.b));
    }
    colour = c;
}
