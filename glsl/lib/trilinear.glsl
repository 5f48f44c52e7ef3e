// Trilinear interpolation of a voxel's 8 corner values (corner index x<<2|y<<1|z) at
// local coordinate q in [0,1]^3 (paper Eq. 13), and the analytic density gradient at
// the voxel centre (paper Eq. 16, without the constant 0.25 which normalisation drops).
#ifndef TRILINEAR_GLSL
#define TRILINEAR_GLSL
// precise: the forward and the backward must compute bit-identical α from it.
float trilinear(float g[8], vec3 q) {
    precise vec3 w0 = 1.0 - q;
    precise float r =
        w0.x * (w0.y * (w0.z * g[0] + q.z * g[1]) + q.y * (w0.z * g[2] + q.z * g[3])) +
        q.x * (w0.y * (w0.z * g[4] + q.z * g[5]) + q.y * (w0.z * g[6] + q.z * g[7]));
    return r;
}

vec3 centre_gradient(float g[8]) {
    return vec3((g[4] + g[5] + g[6] + g[7]) - (g[0] + g[1] + g[2] + g[3]),
                (g[2] + g[3] + g[6] + g[7]) - (g[0] + g[1] + g[4] + g[5]),
                (g[1] + g[3] + g[5] + g[7]) - (g[0] + g[2] + g[4] + g[6]));
}
#endif
