/* Where a world's field lives and what it holds, for kernels that walk it themselves (render.cl,
 * query.cl): FIELD_ARGS is the kernel arguments that reach it, FIELD_PASS passes them on.
 *
 * What a field value means (docs/algorithms.md, "Metrics and signs"):
 * FIELD_EUCLID 0 (manhattan): ushort (distance << 8) | colour, the colour byte the voxel's value.
 * FIELD_EUCLID 1 (euclidean): ushort, the squared distance between voxel centres, capped at cap^2;
 *   the colour is the voxel's value, read from the voxels.
 * Either way a solid voxel of a signed world carries its distance to the nearest air voxel, and
 * its sign is the voxel's: a voxel is solid exactly when its value (colour) is not 0. In an
 * unsigned world a solid's stored distance is 0.
 *
 * Readers:
 *   field_step(FIELD_PASS, v, dims, &colour, &distance_steps) -> face-steps a DDA ray may take
 *     from v without passing a solid (0 on a solid; past the cap across a sparse world's empty
 *     bricks), the voxel's colour, and the steps the stored distance alone allows.
 *   field_distance(FIELD_PASS, v, dims) -> the signed distance at v in voxels (float), capped:
 *     the Manhattan distance or the Euclidean one, negative inside solids of a signed world.
 *
 * SPARSE_FIELD 0 (the default): a dense world's field and voxel buffers.
 * SPARSE_FIELD 1: a sparse world's field and voxel pools (up to 4 segments of `seg` bricks: a
 * slot's segment is slot / seg) and its two-level brick table mirrored on the device (codes as in
 * bricks.cl; sdfserver/sparse/device_table.py): `top` holds, per block of TABLE_BLOCK^3 bricks,
 * the block's one code (< 0: AIR or a solid colour) or the index of its codes in `blocks`;
 * implicit bricks read as their value (air at the cap; a solid colour at minus the cap when
 * signed, 0 when not).
 *
 * A step in an implicit air brick (or a block of them): every voxel of that box is at least the
 * cap from every solid, and a shortest face-step path from v to a solid leaves the box through a
 * voxel of its boundary layer, so the cap plus v's distance to that layer (along its nearest axis)
 * is still no more than the truth: a ray crosses empty space in steps longer than the cap. The
 * argument holds for the Euclidean metric too, since a face-step path is never shorter than the
 * straight line. A Euclidean distance d allows ceil(d) face-steps: the voxels they pass are at
 * most ceil(d) - 1 < d face-steps, hence less than d, away.
 */
#ifndef FIELD_SOURCE_H
#define FIELD_SOURCE_H
#include "sdf_common.h"
#include "field_values.h"

#ifndef SPARSE_FIELD
#define SPARSE_FIELD 0
#endif
#define TABLE_BLOCK 16

#if SPARSE_FIELD
#define FIELD_ARGS __global const ushort *field, __global const ushort *field1, __global const ushort *field2, \
                   __global const ushort *field3, __global const uchar *vox0, __global const uchar *vox1, \
                   __global const uchar *vox2, __global const uchar *vox3, int seg, __global const int *top, \
                   __global const int *blocks, int4 top_n, int brick, int cap
#define FIELD_PASS field, field1, field2, field3, vox0, vox1, vox2, vox3, seg, top, blocks, top_n, brick, cap

/* Face-steps from v (inside the cube of `side` at `lo`) to the cube's boundary layer. */
inline uint steps_to_boundary(int3 v, int3 lo, int side)
{
    const int3 a = v - lo, m = min(a, (int3)(side - 1) - a);
    return (uint)min(m.x, min(m.y, m.z));
}

/* The stored value at v, its voxel, and whether v lies in an implicit brick (*implicit_steps:
 * the face-steps an implicit air box allows, 0 in a solid brick). */
inline ushort field_read(FIELD_ARGS, int3 v, uchar *voxel, int *implicit, uint *implicit_steps)
{
    const int3 b = v / brick, k = b / TABLE_BLOCK;
    const int t = top[box_index(k.x, k.y, k.z, top_n)];
    int code = t;
    *implicit = 1;
    if (t == -1) {
        *voxel = 0;
        *implicit_steps = (uint)cap + steps_to_boundary(v, k * (TABLE_BLOCK * brick), TABLE_BLOCK * brick);
        return 0;
    }
    if (t >= 0)
        code = blocks[(size_t)t * (TABLE_BLOCK * TABLE_BLOCK * TABLE_BLOCK)
            + (size_t)(((b.z % TABLE_BLOCK) * TABLE_BLOCK + b.y % TABLE_BLOCK) * TABLE_BLOCK + b.x % TABLE_BLOCK)];
    if (code >= 0) {
        const size_t s = (size_t)brick;
        const int k = code / seg;
        __global const ushort *pool = k == 0 ? field : k == 1 ? field1 : k == 2 ? field2 : field3;
        __global const uchar *vpool = k == 0 ? vox0 : k == 1 ? vox1 : k == 2 ? vox2 : vox3;
        const size_t at = (((size_t)(code % seg) * s + (size_t)(v.z % brick)) * s + (size_t)(v.y % brick)) * s
                          + (size_t)(v.x % brick);
        *implicit = 0;
        *voxel = vpool[at];
        return pool[at];
    }
    if (code == -1) {
        *voxel = 0;
        *implicit_steps = (uint)cap + steps_to_boundary(v, b * brick, brick);
        return 0;
    }
    *voxel = (uchar)(-2 - code);
    *implicit_steps = 0;
    return 0;
}

inline uint field_step(FIELD_ARGS, int3 v, int4 dims, uint *colour, uint *distance_steps)
{
    uchar voxel;
    int implicit;
    uint steps;
    const ushort f = field_read(FIELD_PASS, v, &voxel, &implicit, &steps);
    *colour = voxel;
    *distance_steps = voxel ? 0u : implicit ? (uint)cap : air_steps(f);
    return voxel ? 0u : implicit ? steps : *distance_steps;
}

inline float field_distance(FIELD_ARGS, int3 v, int4 dims)
{
    uchar voxel;
    int implicit;
    uint steps;
    const ushort f = field_read(FIELD_PASS, v, &voxel, &implicit, &steps);
    const float d = implicit ? (FIELD_SIGNED || !voxel ? (float)cap : 0.0f) : stored_distance(f);
    return voxel && d > 0.0f ? -d : d;
}
#else
#define FIELD_ARGS __global const ushort *field, __global const uchar *voxels
#define FIELD_PASS field, voxels

inline uint field_step(FIELD_ARGS, int3 v, int4 dims, uint *colour, uint *distance_steps)
{
    const size_t i = world_index(v.x, v.y, v.z, dims);
#if FIELD_EUCLID
    const uchar voxel = voxels[i];
    *colour = voxel;
    *distance_steps = voxel ? 0u : air_steps(field[i]);
#else
    const ushort f = field[i];  /* the colour byte is the voxel's: no voxel read */
    *colour = f & 0xffu;
    *distance_steps = (f & 0xffu) ? 0u : (uint)(f >> 8);
#endif
    return *distance_steps;
}

inline float field_distance(FIELD_ARGS, int3 v, int4 dims)
{
    const size_t i = world_index(v.x, v.y, v.z, dims);
    const ushort f = field[i];
#if FIELD_EUCLID
    const int solid = voxels[i] != 0;
#else
    const int solid = (f & 0xffu) != 0;
#endif
    const float d = stored_distance(f);
    return solid && d > 0.0f ? -d : d;
}
#endif

#endif
