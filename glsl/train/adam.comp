#version 460
// One Adam step over one parameter group, thread per element (2-D grid):
//   m = b1·m + (1−b1)·g;  v = b2·v + (1−b2)·g²;
//   p −= lr/bc1 · m / (sqrt(v)/sqrt(bc2) + eps)
// with the bias corrections bc1 = 1 − b1^t, bc2 = 1 − b2^t folded into `step` and
// `rsqrt_bc2` on the host (in f64). Overflow-safe for |g| up to ~1e20: g² is formed as
// ((1−b2)·g)·g, v/bc2 is never formed (sqrt(v)·rsqrt_bc2 instead), and v saturates at
// the largest finite float instead of becoming +inf (which would freeze p for good).
// m = 0 gives an update of exactly 0 (never 0/0, whatever eps). A non-finite g sets
// bit 0 (value 1) of flags[0] and leaves that element's p, m, v untouched; a non-finite
// new p is written and sets the same bit. With skip_zero (selective Adam) an element
// whose gradient is exactly zero keeps p, m and v (only the gradient is read).
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

void main() {
    uint i = linear_group_id() * 256u + gl_LocalInvocationID.x;
    if (i >= pc.count) return;
    float g = pc.grad.v[i];
    if (isinf(g) || isnan(g)) {
        atomicOr(pc.flags.v[0], 1u);
        return;
    }
    if (pc.skip_zero != 0u && g == 0.0) return;
    float m = pc.b1 * pc.m.v[i] + pc.omb1 * g;
    float v = min(pc.b2 * pc.v.v[i] + (pc.omb2 * g) * g, FLT_MAX);
    pc.m.v[i] = m;
    pc.v.v[i] = v;
    float denom = sqrt(v) * pc.rsqrt_bc2 + pc.eps;
    if (m != 0.0 && denom > 0.0) {
        float p = pc.param.v[i] - pc.step * (m / denom);
        pc.param.v[i] = p;
        if (isinf(p) || isnan(p)) atomicOr(pc.flags.v[0], 1u);
    }
}
