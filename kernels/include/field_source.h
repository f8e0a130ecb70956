/* Where a world's packed field lives, for kernels that walk it themselves (render.cl,
 * query.cl): FIELD_ARGS is the kernel arguments that reach it, FIELD_PASS passes them on, and
 * field_at(FIELD_PASS, v, dims) reads voxel v (inside the world).
 *
 * SPARSE_FIELD 0 (the default): a dense world's one field buffer.
 * SPARSE_FIELD 1: a sparse world's field pool (up to 4 segments of `seg` bricks: a slot's segment
 * is slot / seg) and its two-level brick table mirrored on the device (codes as in bricks.cl; sdfserver/sparse/device_table.py): `top` holds, per block of
 * TABLE_BLOCK^3 bricks, the block's one code (< 0: AIR or a solid colour) or the index of its
 * codes in `blocks`; implicit bricks read as their value.
 *
 * field_step also gives how many face-steps a ray may take from v without passing a solid.
 * Dense: the distance read. Sparse, in an implicit air brick (or a block of them): every voxel
 * of that box is at least the cap from every solid, and a shortest path from v to a solid leaves
 * the box through a voxel of its boundary layer, so the cap plus v's distance to that layer
 * (along its nearest axis) is still no more than the truth: a ray crosses empty space in steps
 * longer than the cap.
 */
#ifndef FIELD_SOURCE_H
#define FIELD_SOURCE_H
#include "sdf_common.h"

#ifndef SPARSE_FIELD
#define SPARSE_FIELD 0
#endif
#define TABLE_BLOCK 16

#if SPARSE_FIELD
#define FIELD_ARGS __global const ushort *field, __global const ushort *field1, __global const ushort *field2, \
                   __global const ushort *field3, int seg, __global const int *top, __global const int *blocks, \
                   int4 top_n, int brick, int cap
#define FIELD_PASS field, field1, field2, field3, seg, top, blocks, top_n, brick, cap

/* Face-steps from v (inside the cube of `side` at `lo`) to the cube's boundary layer. */
inline uint steps_to_boundary(int3 v, int3 lo, int side)
{
    const int3 a = v - lo, m = min(a, (int3)(side - 1) - a);
    return (uint)min(m.x, min(m.y, m.z));
}

inline ushort field_step(FIELD_ARGS, int3 v, int4 dims, uint *step)
{
    const int3 b = v / brick, k = b / TABLE_BLOCK;
    const int t = top[box_index(k.x, k.y, k.z, top_n)];
    int code = t;
    if (t == -1) {
        *step = (uint)cap + steps_to_boundary(v, k * (TABLE_BLOCK * brick), TABLE_BLOCK * brick);
        return pack_field((uint)cap, 0);
    }
    if (t >= 0)
        code = blocks[(size_t)t * (TABLE_BLOCK * TABLE_BLOCK * TABLE_BLOCK)
            + (size_t)(((b.z % TABLE_BLOCK) * TABLE_BLOCK + b.y % TABLE_BLOCK) * TABLE_BLOCK + b.x % TABLE_BLOCK)];
    if (code >= 0) {
        const size_t s = (size_t)brick;
        const int k = code / seg;
        __global const ushort *pool = k == 0 ? field : k == 1 ? field1 : k == 2 ? field2 : field3;
        const ushort f = pool[(((size_t)(code % seg) * s + (size_t)(v.z % brick)) * s + (size_t)(v.y % brick)) * s
                              + (size_t)(v.x % brick)];
        *step = f >> 8;
        return f;
    }
    if (code == -1) {
        *step = (uint)cap + steps_to_boundary(v, b * brick, brick);
        return pack_field((uint)cap, 0);
    }
    *step = 0;
    return (ushort)(-2 - code);
}
#else
#define FIELD_ARGS __global const ushort *field
#define FIELD_PASS field
inline ushort field_step(FIELD_ARGS, int3 v, int4 dims, uint *step)
{
    const ushort f = field[world_index(v.x, v.y, v.z, dims)];
    *step = f >> 8;
    return f;
}
#endif

inline ushort field_at(FIELD_ARGS, int3 v, int4 dims)
{
    uint step;
    return field_step(FIELD_PASS, v, dims, &step);
}

#endif
