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
#endif
