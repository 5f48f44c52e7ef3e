// Exponential-linear activation of raw density (paper Eq. 3) and the reference's
// alpha constants (paper supp. C / reference config).
#ifndef EXPLIN_GLSL
#define EXPLIN_GLSL
const float STEP_SZ_SCALE = 100.0;  // density scale of the reference implementation
const float MAX_ALPHA = 0.99999;
const float MIN_ALPHA = 0.00001;
const float EARLY_STOP_T = 0.0001;

// explin(x) = x if x > 1.1 else exp(x / 1.1 - 1 + ln 1.1)
float explin(float x) {
    precise float r = x > 1.1 ? x : exp(x * 0.909090909091 - 0.904689820196);  // see trilinear
    return r;
}

// Opacity of optical depth v ≥ 0: 1 − e^(−v). Formed as 1.0 − exp(−v) it cancels: the
// f32 result carries an absolute error of ~6e-8 plus exp's own (Vulkan allows 3 + 2|x|
// ulp), i.e. a relative one of ~1e-7 / v (1 % at the skip threshold 1e-5, 0.1 % at the
// 1e-4 of a freshly initialised voxel), and every gradient through α inherits it. Below
// v = 1/16 the Taylor polynomial v − v²/2 + v³/6 − v⁴/24 is used instead (truncation
// ≤ v⁴/120 ≈ 1.3e-7 relative there); above, the cancellation costs at most ~2e-6. The
// composite and the backward both call this (`precise`), so their α stay bit-identical.
float alpha_of_depth(float v) {
    precise float series = v * (1.0 - v * (0.5 - v * (0.16666666667 - v * 0.041666666667)));
    precise float direct = 1.0 - exp(-v);
    precise float r = v < 0.0625 ? series : direct;
    return r;
}
#endif
