// Layout of the small state buffer shared by the sort and the scan (u32 words).
// Written by sort/setup.comp at the start of every sort/scan; see src/sort/mod.rs.
#ifndef PASS_STATE_GLSL
#define PASS_STATE_GLSL
#define ST_N 0            // element count for this run (clamped to capacity)
#define ST_REQUESTED 1    // element count asked for (before clamping)
#define ST_EPOCH 2        // tag base of look-back status words; +8 per run
#define ST_ERRORS 3       // sticky error bits (ERR_*), cleared by the host
#define ST_TOTAL 4        // scan: total sum
// Look-back counters of the sort's passes in this run (zeroed by setup; bench sort):
#define ST_LB_STEPS 5     // status words read that carried a flag (one per digit per tile walked)
#define ST_LB_WAITS 6     // extra polls of words not yet published
#define ST_LB_FALLBACKS 7 // fallback rounds (a workgroup recounted a stalled tile's keys)
#define ST_TILE_CTR 8     // 8 tile-claim counters (one per sort pass)
#define ST_ARGS_TILES 16  // VkDispatchIndirectCommand for tile kernels (x, y, z)
#define ST_ARGS_CHUNKS 20 // VkDispatchIndirectCommand for the histogram kernel
#define ST_HIST_MULT 23   // histogram: blocks of HIST_WG x HIST_KPT keys per workgroup (>= 1)
#define ST_HIST 32        // 8 passes x 256 digit counts, then exclusive offsets
// Written by sort/hist_scan.comp: a pass whose digit is the same for every key is
// skipped (its dispatch has 0 workgroups) and swaps the direction of the later ones.
#define ST_PASS_ARGS 2080 // 8 x VkDispatchIndirectCommand: the tile grid, or 0 groups
#define ST_FLIP 2104      // 8 words: 1 if pass p reads the buffers it would write
#define ST_ARGS_COPY 2112 // VkDispatchIndirectCommand of the final copy (0 groups: none)
#define ST_SKIPPED 2115   // bit p set: pass p was skipped
#define ST_WORDS 2116

#define ERR_OVERFLOW 1u   // count exceeded capacity: clamped
#define ERR_LOOKBACK 2u   // look-back ran past tile 0 (cannot happen unless the state was corrupted)
#endif
