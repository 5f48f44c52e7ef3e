// Float addition into a global buffer: the native VK_EXT_shader_atomic_float add where
// the device has it (the kernel variant defines FLOAT_ATOMICS), otherwise a
// compare-and-swap loop on the bits (any Vulkan device). Include this FIRST in a
// kernel (it may enable an extension, which must precede any code).
//
// The CAS loop is bounded (llvmpipe's loop limit, DESIGN §LAVAPIPE) at 64 tries: the
// lanes of a subgroup add to distinct words (one gradient component each), so a retry
// means another subgroup wrote the same word between our read and swap; 64 consecutive
// losses do not happen in practice, and a give-up is counted in `lost` (word 0 of the
// buffer passed) so it cannot go unseen.
#ifndef ATOMIC_F32_GLSL
#define ATOMIC_F32_GLSL
#ifdef FLOAT_ATOMICS
#extension GL_EXT_shader_atomic_float : require
#endif
#include "common.glsl"

void atomic_add_f32(F32s b, uint i, float x, U32s lost) {
    if (x == 0.0) return;
#ifdef FLOAT_ATOMICS
    atomicAdd(b.v[i], x);
#else
    U32s u = U32s(uint64_t(b));
    uint old = u.v[i];
    for (int k = 0; k < 64; ++k) {
        uint prev = atomicCompSwap(u.v[i], old, floatBitsToUint(uintBitsToFloat(old) + x));
        if (prev == old) return;
        old = prev;
    }
    atomicAdd(lost.v[0], 1u);
#endif
}
#endif
