// Octree Morton codes (paper Listing 1) and direction-dependent Morton order
// (paper supp. B.2, Listing 3: table[s][c] = c ^ s, applied to every level by one XOR).
#ifndef MORTON_GLSL
#define MORTON_GLSL
const uint MAX_LEVEL = 16u;

// Voxel index (i, j, k) at `level` of an octpath.
uvec3 octpath_ijk(uint64_t path, uint level) {
    uint64_t p = path >> (3u * (MAX_LEVEL - level));
    uvec3 ijk = uvec3(0u);
    for (uint n = 0u; n < MAX_LEVEL; ++n) {
        if (n < level) {
            uint bits = uint(p & 7ul);
            ijk |= uvec3((bits >> 2u) & 1u, (bits >> 1u) & 1u, bits & 1u) << n;
            p >>= 3u;
        }
    }
    return ijk;
}

// Sorting order of a voxel for rays with sign bits `sign` (x<<2|y<<1|z, bit set when
// the component is negative).
uint64_t dir_morton_order(uint64_t path, uint sign) {
    return path ^ (uint64_t(sign) * 0x249249249249ul);
}

// Octant bits of a ray direction; -0.0 counts as positive, as in the reference.
uint ray_sign_bits(vec3 rd) {
    return (rd.x < 0.0 ? 4u : 0u) | (rd.y < 0.0 ? 2u : 0u) | (rd.z < 0.0 ? 1u : 0u);
}
#endif
