// Layout of the small state buffer shared by the sort and the scan (u32 words).
// Written by sort/setup.comp at the start of every sort/scan; see src/sort/mod.rs.
#ifndef PASS_STATE_GLSL
#define PASS_STATE_GLSL
#define ST_N 0            // element count for this run (clamped to capacity)
#define ST_REQUESTED 1    // element count asked for (before clamping)
#define ST_EPOCH 2        // tag base of look-back status words; +8 per run
#define ST_ERRORS 3       // sticky error bits (ERR_*), cleared by the host
#define ST_TOTAL 4        // scan: total sum
#define ST_TILE_CTR 8     // 8 tile-claim counters (one per sort pass)
#define ST_ARGS_TILES 16  // VkDispatchIndirectCommand for tile kernels (x, y, z)
#define ST_ARGS_CHUNKS 20 // VkDispatchIndirectCommand for the histogram kernel
#define ST_HIST 32        // 8 passes x 256 digit counts, then exclusive offsets
#define ST_WORDS (ST_HIST + 8 * 256)

#define ERR_OVERFLOW 1u   // count exceeded capacity: clamped
#define ERR_LOOKBACK 2u   // look-back ran past tile 0 (cannot happen unless the state was corrupted)
#endif
