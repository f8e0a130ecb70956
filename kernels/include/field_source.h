/* Where a world's packed field lives, for kernels that walk it themselves (render.cl,
 * query.cl): FIELD_ARGS is the kernel arguments that reach it, FIELD_PASS passes them on, and
 * field_at(FIELD_PASS, v, dims) reads voxel v (inside the world).
 *
 * SPARSE_FIELD 0 (the default): a dense world's one field buffer.
 * SPARSE_FIELD 1: a sparse world's brick pool and its two-level brick table mirrored on the
 * device (codes as in bricks.cl; sdfserver/sparse/device_table.py): `top` holds, per block of
 * TABLE_BLOCK^3 bricks, the block's one code (< 0: AIR or a solid colour) or the index of its
 * codes in `blocks`; implicit bricks read as their value.
 */
#ifndef FIELD_SOURCE_H
#define FIELD_SOURCE_H
#include "sdf_common.h"

#ifndef SPARSE_FIELD
#define SPARSE_FIELD 0
#endif
#define TABLE_BLOCK 16

#if SPARSE_FIELD
#define FIELD_ARGS __global const ushort *field, __global const int *top, __global const int *blocks, \
                   int4 top_n, int brick, int cap
#define FIELD_PASS field, top, blocks, top_n, brick, cap
inline ushort field_at(FIELD_ARGS, int3 v, int4 dims)
{
    const int bx = v.x / brick, by = v.y / brick, bz = v.z / brick;
    const int t = top[box_index(bx / TABLE_BLOCK, by / TABLE_BLOCK, bz / TABLE_BLOCK, top_n)];
    const int code = t < 0 ? t : blocks[(size_t)t * (TABLE_BLOCK * TABLE_BLOCK * TABLE_BLOCK)
        + (size_t)(((bz % TABLE_BLOCK) * TABLE_BLOCK + by % TABLE_BLOCK) * TABLE_BLOCK + bx % TABLE_BLOCK)];
    if (code >= 0) {
        const size_t b = (size_t)brick;
        return field[(((size_t)code * b + (size_t)(v.z % brick)) * b + (size_t)(v.y % brick)) * b
                     + (size_t)(v.x % brick)];
    }
    return code == -1 ? pack_field((uint)cap, 0) : (ushort)(-2 - code);
}
#else
#define FIELD_ARGS __global const ushort *field
#define FIELD_PASS field
inline ushort field_at(FIELD_ARGS, int3 v, int4 dims)
{
    return field[world_index(v.x, v.y, v.z, dims)];
}
#endif

#endif
