// Ray / axis-aligned box intersection for a ray from the origin (all raster geometry
// is camera-relative, which keeps level-16 voxels far from the world origin precise).
// A zero direction component (either sign) is handled explicitly instead of producing
// 0 * inf = NaN: the ray then lies in the slab iff lo <= 0 < hi (half-open, so a ray
// running exactly along a shared face belongs to one voxel only).
#ifndef RAY_AABB_GLSL
#define RAY_AABB_GLSL
#define RAY_INF uintBitsToFloat(0x7f800000u)
const float RAY_BIG = 3.0e38;

vec2 slab(float lo, float hi, float d, float inv_d) {
    if (d == 0.0) {
        return (lo <= 0.0 && 0.0 < hi) ? vec2(-RAY_INF, RAY_INF) : vec2(RAY_INF, -RAY_INF);
    }
    float t0 = lo * inv_d;
    float t1 = hi * inv_d;
    return vec2(min(t0, t1), max(t0, t1));
}

// Entry and exit distance (a, b) of the ray t * rd, t real; no hit when a > b.
vec2 ray_aabb(vec3 lo, vec3 hi, vec3 rd, vec3 inv_rd) {
    vec2 sx = slab(lo.x, hi.x, rd.x, inv_rd.x);
    vec2 sy = slab(lo.y, hi.y, rd.y, inv_rd.y);
    vec2 sz = slab(lo.z, hi.z, rd.z, inv_rd.z);
    return vec2(max(max(sx.x, sy.x), sz.x), min(min(sx.y, sy.y), sz.y));
}
#endif
