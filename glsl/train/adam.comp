#version 460
// One Adam step over one parameter group, thread per 4 consecutive elements (2-D grid):
//   m = b1·m + (1−b1)·g;  v = b2·v + (1−b2)·g²;
//   p −= lr/bc1 · m / (sqrt(v)/sqrt(bc2) + eps)
// with the bias corrections bc1 = 1 − b1^t, bc2 = 1 − b2^t folded into `step` and
// `rsqrt_bc2` on the host (in f64). Overflow-safe for |g| up to ~1e20: g² is formed as
// ((1−b2)·g)·g, in that order on every device (`precise`), v/bc2 is never formed
// (sqrt(v)·rsqrt_bc2 instead), and v saturates at the largest finite float instead of
// becoming +inf (which would freeze p for good).
// m = 0 gives an update of exactly 0 (never 0/0, whatever eps). A non-finite g sets
// bit 0 (value 1) of flags[0] and leaves that element's p, m, v untouched; a non-finite
// new p is written and sets the same bit. With skip_zero (selective Adam) an element
// whose gradient is exactly zero keeps p, m and v (only the gradient is read).
// Four elements per thread: on lavapipe a buffer access is a per-lane gather, so one
// 16-byte access per lane moves four times the data of a scalar one (the parameter
// buffers are 16-byte aligned; the last thread does the remainder one by one). Each
// element's arithmetic is the scalar one, element by element.
#include "common.glsl"
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    F32s param;
    F32s grad;
    F32s m;
    F32s v;
    U32s flags;
    uint count;
    float b1;
    float omb1;      // 1 − b1
    float b2;
    float omb2;      // 1 − b2
    float step;      // lr / bc1
    float rsqrt_bc2; // 1 / sqrt(bc2)
    float eps;
    uint skip_zero;  // 1: selective Adam, an element with g == 0 is left untouched
    uint pad;
} pc;

const float FLT_MAX = 3.402823466e38;

// One element: the new (p, m, v) from the old ones and g; `bad` when g or the new p
// is not finite; `write` false when nothing changes (non-finite or skipped g).
void step1(float g, inout float p, inout float m, inout float v, inout bool bad, out bool write) {
    write = false;
    if (isinf(g) || isnan(g)) {
        bad = true;
        return;
    }
    if (pc.skip_zero != 0u && g == 0.0) return;
    write = true;
    // `precise` (SPIR-V NoContraction): the order written is the order evaluated. A
    // compiler free to reassociate may form g·g first, which overflows for |g| ≳ 1.8e19
    // (NVIDIA's did: v saturated at g = 1e20 and the step shrank to 0.54 lr); llvmpipe
    // happened to keep the written order, so nothing else here may rely on it.
    precise float sg = pc.omb2 * g;
    precise float v2 = pc.b2 * v + sg * g;
    precise float m2 = pc.b1 * m + pc.omb1 * g;
    m = m2;
    v = min(v2, FLT_MAX);
    precise float denom = sqrt(v) * pc.rsqrt_bc2 + pc.eps;
    if (m != 0.0 && denom > 0.0) {
        precise float p2 = p - pc.step * (m / denom);
        p = p2;
        if (isinf(p) || isnan(p)) bad = true;
    }
}

// Four consecutive floats as two 64-bit words: llvmpipe splits a vec4 access into four
// 32-bit gathers (scatters) across the lanes, a pair of 64-bit words into two.
vec4 load4(F32s b, uint q) {
    U64s u = U64s(uint64_t(b));
    return vec4(uintBitsToFloat(unpackUint2x32(u.v[2u * q])), uintBitsToFloat(unpackUint2x32(u.v[2u * q + 1u])));
}
void store4(F32s b, uint q, vec4 x) {
    U64s u = U64s(uint64_t(b));
    u.v[2u * q] = packUint2x32(floatBitsToUint(x.xy));
    u.v[2u * q + 1u] = packUint2x32(floatBitsToUint(x.zw));
}

void main() {
    uint q = linear_group_id() * 256u + gl_LocalInvocationID.x;
    uint first = 4u * q;
    if (first >= pc.count) return;
    bool bad = false;
    if (first + 4u <= pc.count) {
        vec4 g = load4(pc.grad, q);
        vec4 p = load4(pc.param, q);
        vec4 m = load4(pc.m, q);
        vec4 v = load4(pc.v, q);
        bool any_write = false;
        for (int c = 0; c < 4; ++c) {
            float pc_ = p[c], mc = m[c], vc = v[c];
            bool w;
            step1(g[c], pc_, mc, vc, bad, w);
            if (w) {
                p[c] = pc_;
                m[c] = mc;
                v[c] = vc;
            }
            any_write = any_write || w;
        }
        if (any_write) {
            store4(pc.param, q, p);
            store4(pc.m, q, m);
            store4(pc.v, q, v);
        }
    } else {
        for (uint i = first; i < pc.count; ++i) {
            float p = pc.param.v[i], m = pc.m.v[i], v = pc.v.v[i];
            bool w;
            step1(pc.grad.v[i], p, m, v, bad, w);
            if (w) {
                pc.param.v[i] = p;
                pc.m.v[i] = m;
                pc.v.v[i] = v;
            }
        }
    }
    if (bad) atomicOr(pc.flags.v[0], 1u);
}
