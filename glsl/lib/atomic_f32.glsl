// Float addition into a global buffer: the native VK_EXT_shader_atomic_float add where
// the device has it (the kernel variant defines FLOAT_ATOMICS), otherwise a
// compare-and-swap loop on the bits (any Vulkan device). Include this FIRST in a
// kernel (it may enable an extension, which must precede any code).
//
// The CAS loop retries until its swap lands: each failed try means another invocation's
// swap on the same word landed, so the device as a whole always progresses. The bound
// (2^20 tries) only guards against a broken device; a give-up is counted in `lost`
// (word 0 of the buffer passed) so it cannot go unseen. It used to be 64: enough on
// lavapipe (2 threads, a handful of contenders per word), too few on a GPU, where
// thousands of resident invocations add to the same few words (the TV test's 16- and
// 2000-point pools) and a lane can lose its swap hundreds of times in a row (the H200
// run of tests/optim lost adds at a different point each run). Retries
// count towards llvmpipe's loop limit (LAVAPIPE.md) only when they happen; there they
// are rare.
#ifndef ATOMIC_F32_GLSL
#define ATOMIC_F32_GLSL
#ifdef FLOAT_ATOMICS
#extension GL_EXT_shader_atomic_float : require
#endif
#include "common.glsl"

#ifndef CAS_TRIES
#define CAS_TRIES (1u << 20)
#endif

void atomic_add_f32(F32s b, uint i, float x, U32s lost) {
    if (x == 0.0) return;
#ifdef FLOAT_ATOMICS
    atomicAdd(b.v[i], x);
#else
    U32s u = U32s(uint64_t(b));
    uint old = u.v[i];
    for (uint k = 0u; k < CAS_TRIES; ++k) {
        uint prev = atomicCompSwap(u.v[i], old, floatBitsToUint(uintBitsToFloat(old) + x));
        if (prev == old) return;
        old = prev;
    }
    atomicAdd(lost.v[0], 1u);
#endif
}
#endif
