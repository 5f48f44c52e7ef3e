// The radix sort's key type, shared by its histogram and onesweep passes.
#ifndef SORT_KEY_GLSL
#define SORT_KEY_GLSL
#include "common.glsl"
// Key width (build.rs variants): u64 keys, or u32 keys with KEY32 (a sort whose bits
// all lie below 32 moves 8 instead of 12 bytes per pair and pass).
#ifdef KEY32
#define KeyT uint
#define KeyBuf U32s
#else
#define KeyT uint64_t
#define KeyBuf U64s
#endif
#endif
