// Decoupled look-back status words (64-bit, one atomic word per tile and digit):
//   bits 34..63  tag: the run's epoch + pass (30 bits). A word from an earlier run never
//                matches, so the status array is never cleared.
//   bits 32..33  flag: 0 = nothing published, 1 = aggregate (this tile only),
//                2 = inclusive prefix (this tile and every tile before it)
//   bits  0..31  value
// The value travels in the same atomic word as its flag, so readers need no
// acquire/release ordering: relaxed atomics are enough on any conforming driver.
#ifndef LOOKBACK_GLSL
#define LOOKBACK_GLSL
#extension GL_KHR_memory_scope_semantics : require
#define LB_AGGREGATE 1u
#define LB_INCLUSIVE 2u

uint64_t lb_pack(uint tag, uint flag, uint value) {
    return (uint64_t(tag & 0x3fffffffu) << 34) | (uint64_t(flag) << 32) | uint64_t(value);
}
// Flag of `w` if it belongs to run `tag`, else 0 (not yet published in this run).
uint lb_flag(uint64_t w, uint tag) {
    return (uint(w >> 34) == (tag & 0x3fffffffu)) ? uint(w >> 32) & 3u : 0u;
}
uint lb_value(uint64_t w) { return uint(w); }

// Relaxed atomic store and load of status word `i` (device scope). Formerly an atomic
// exchange and an add of zero: read-modify-write atomics, which llvmpipe runs lane by
// lane with a locked instruction and a full fence each (perf: ~7 % of a onesweep pass
// on those fences); relaxed loads and stores are all the protocol needs.
void lb_store(U64s s, uint i, uint64_t w) {
    atomicStore(s.v[i], w, gl_ScopeDevice, gl_StorageSemanticsBuffer, gl_SemanticsRelaxed);
}
uint64_t lb_load(U64s s, uint i) {
    return atomicLoad(s.v[i], gl_ScopeDevice, gl_StorageSemanticsBuffer, gl_SemanticsRelaxed);
}

// Workgroup-wide OR of `x`. Must be called in workgroup-uniform control flow. Its shared
// word is `lb_vote` unless the kernel defines LB_VOTE as a word of its own that is idle
// while it calls this (onesweep_coalesced.glsl, to fit 32 KiB).
#ifndef LB_VOTE
shared uint lb_vote;
#define LB_VOTE lb_vote
#endif
uint lb_workgroup_or(uint x) {
    barrier();
    if (gl_LocalInvocationIndex == 0) LB_VOTE = 0;
    barrier();
    uint sx = subgroupOr(x);
    if (subgroupElect() && sx != 0) atomicOr(LB_VOTE, sx);
    barrier();
    return LB_VOTE;
}
#endif
