/* A generated terrain: a heightmap of fractal value noise with overhangs (3-D noise moving the
 * surface up and down by at most `overhang`) and caves (tunnels where 3-D noise crosses a level,
 * no deeper than `cave_depth` below the surface), coloured grass, dirt and stone (RGB332).
 *
 * Every voxel is a pure function of its world position and the seed, so any box of the world,
 * a tile and its halo included, is generated alone and agrees with its neighbours. The host
 * relies on the bounds: the surface height lies in [base - amplitude, base + amplitude]; above
 * height + overhang every voxel is air; below height - overhang - max(cave_depth, DIRT_DEPTH)
 * every voxel is stone (sdfserver/sparse/terrain.py).
 */
#include "sdf_common.h"

#define GRASS 0x5C  /* RGB332 (2, 7, 0) */
#define DIRT 0x8D   /* (4, 3, 1) */
#define STONE 0x92  /* (4, 4, 2) */
#define DIRT_DEPTH 6.0f
#define HEIGHT_SCALE 512.0f
#define OCTAVES 5

inline uint hash3(int x, int y, int z, uint seed)
{
    uint h = seed ^ 0x9E3779B9u;
    h ^= (uint)x * 0x85EBCA6Bu; h = (h << 13) | (h >> 19);
    h ^= (uint)y * 0xC2B2AE35u; h = (h << 13) | (h >> 19);
    h ^= (uint)z * 0x27D4EB2Fu;
    h ^= h >> 16; h *= 0x7FEB352Du; h ^= h >> 15; h *= 0x846CA68Bu; h ^= h >> 16;
    return h;
}

inline float lattice(int x, int y, int z, uint seed)
{
    return (float)(hash3(x, y, z, seed) >> 8) * (1.0f / 16777216.0f);  /* [0, 1) */
}

/* Trilinear value noise with smoothstep weights: [0, 1). */
inline float value_noise(float3 p, uint seed)
{
    const float3 f = floor(p);
    const int x = (int)f.x, y = (int)f.y, z = (int)f.z;
    const float3 t = p - f;
    const float3 w = t * t * (3.0f - 2.0f * t);
    const float a = mix(lattice(x, y, z, seed), lattice(x + 1, y, z, seed), w.x);
    const float b = mix(lattice(x, y + 1, z, seed), lattice(x + 1, y + 1, z, seed), w.x);
    const float c = mix(lattice(x, y, z + 1, seed), lattice(x + 1, y, z + 1, seed), w.x);
    const float d = mix(lattice(x, y + 1, z + 1, seed), lattice(x + 1, y + 1, z + 1, seed), w.x);
    return mix(mix(a, b, w.y), mix(c, d, w.y), w.z);
}

/* Surface height of column (x, z): base + amplitude * [-1, 1). */
inline float terrain_height(int x, int z, uint seed, float base, float amplitude)
{
    float sum = 0.0f, weight = 0.5f, norm = 0.0f;
    float2 p = (float2)((float)x, (float)z) / HEIGHT_SCALE;
    for (int o = 0; o < OCTAVES; ++o) {
        sum += weight * value_noise((float3)(p.x, 0.5f, p.y), seed + (uint)o);
        norm += weight;
        weight *= 0.5f;
        p *= 2.03f;
    }
    return base + amplitude * (2.0f * sum / norm - 1.0f);
}

inline uchar terrain_voxel(int x, int y, int z, uint seed, float base, float amplitude, float overhang,
                           float cave_depth)
{
    const float h = terrain_height(x, z, seed, base, amplitude);
    const float3 p = (float3)((float)x, (float)y, (float)z);
    const float lift = overhang * (2.0f * value_noise(p / 24.0f, seed ^ 0xA511E9B3u) - 1.0f);
    const float depth = h + lift - (float)y;  /* > 0 inside the ground */
    if (depth <= 0.0f)
        return 0;
    if (depth < cave_depth && depth > 3.0f) {
        const float cave = value_noise(p / 32.0f, seed ^ 0x63D83595u);
        if (fabs(cave - 0.5f) < 0.035f)
            return 0;
    }
    if (depth < 1.5f)
        return GRASS;
    return depth < DIRT_DEPTH ? DIRT : STONE;
}

/* The voxels of a box (extent dims at world corner origin). */
__kernel void terrain_voxels(__global uchar *voxels, int4 dims, int4 origin, uint seed, float base,
                             float amplitude, float overhang, float cave_depth)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= dims.x || y >= dims.y || z >= dims.z)
        return;
    voxels[world_index(x, y, z, dims)] =
        terrain_voxel(origin.x + x, origin.y + y, origin.z + z, seed, base, amplitude, overhang, cave_depth);
}

/* Per brick column (bx, first_z + bz) of the world, for columns_z rows from first_z: the lowest
 * and highest surface height of its brick x brick columns, floor and ceiling. One work-item per
 * brick column. */
__kernel void terrain_columns(__global int2 *bounds, int columns_x, int first_z, int columns_z, int brick,
                              uint seed, float base, float amplitude)
{
    const int bx = get_global_id(0), row = get_global_id(1), bz = first_z + row;
    if (bx >= columns_x || row >= columns_z)
        return;
    float lo = INFINITY, hi = -INFINITY;
    for (int dz = 0; dz < brick; ++dz)
        for (int dx = 0; dx < brick; ++dx) {
            const float h = terrain_height(bx * brick + dx, bz * brick + dz, seed, base, amplitude);
            lo = fmin(lo, h);
            hi = fmax(hi, h);
        }
    bounds[(size_t)row * columns_x + bx] = (int2)((int)floor(lo), (int)ceil(hi));
}
