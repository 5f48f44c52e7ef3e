// Real spherical harmonics up to degree 3 with the 3DGS basis, constants and signs;
// colour = max(0, 0.5 + sum_k c_k * Y_k(dir)) as in the reference implementation.
#ifndef SH_GLSL
#define SH_GLSL
const float SH_C0 = 0.28209479177387814;
const float SH_C1 = 0.4886025119029199;
const float SH_C2[5] = float[5](1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
                                -1.0925484305920792, 0.5462742152960396);
const float SH_C3[7] = float[7](-0.5900435899266435, 2.890611442640554, -0.4570457994644658,
                                0.3731763325901154, -0.4570457994644658, 1.445305721320277,
                                -0.5900435899266435);

// Basis values Y_0..Y_15 for a unit direction (entries above the degree are unused).
void sh_basis(vec3 d, uint degree, out float y[16]) {
    for (int i = 0; i < 16; ++i) y[i] = 0.0;
    float x = d.x, yy = d.y, z = d.z;
    y[0] = SH_C0;
    if (degree >= 1u) {
        y[1] = -SH_C1 * yy;
        y[2] = SH_C1 * z;
        y[3] = -SH_C1 * x;
    }
    if (degree >= 2u) {
        float xx = x * x, y2 = yy * yy, zz = z * z;
        y[4] = SH_C2[0] * x * yy;
        y[5] = SH_C2[1] * yy * z;
        y[6] = SH_C2[2] * (2.0 * zz - xx - y2);
        y[7] = SH_C2[3] * x * z;
        y[8] = SH_C2[4] * (xx - y2);
        if (degree >= 3u) {
            y[9] = SH_C3[0] * yy * (3.0 * xx - y2);
            y[10] = SH_C3[1] * x * yy * z;
            y[11] = SH_C3[2] * yy * (4.0 * zz - xx - y2);
            y[12] = SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * y2);
            y[13] = SH_C3[4] * x * (4.0 * zz - xx - y2);
            y[14] = SH_C3[5] * z * (xx - y2);
            y[15] = SH_C3[6] * x * (xx - 3.0 * y2);
        }
    }
}
#endif
