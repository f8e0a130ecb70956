/* Sparse worlds: bricks (one chunk each) kept in pools, gathered into a dense scratch box that
 * the world's algorithm runs on exactly as on a dense world, classified and scattered back.
 *
 * A brick code (int) says where a brick lives:
 *   code >= 0          slot in the pools: brick^3 voxels (z, y, x inside the brick) at
 *                      (code % seg) * brick^3 in segment code / seg of the pools (POOL_ARGS:
 *                      up to 4 segments, each a voxels and a field buffer of seg bricks);
 *   BRICK_AIR (-1)     every voxel air, every distance at the cap (nothing stored);
 *   code <= -2         every voxel solid of colour -2 - code, distance 0, or minus the cap in a
 *                      signed world (nothing stored).
 * The field values these stand for follow the world's metric and sign (FIELD_EUCLID,
 * FIELD_SIGNED: kernels/include/field_source.h).
 * Codes for a box of bricks are laid out (z, y, x) with extent codes_n, brick coordinates
 * codes_lo at index 0; `brick` is the brick side in voxels (the world's chunk size). */
#include "sdf_common.h"
#include "field_values.h"

#define BRICK_AIR (-1)
#define POOL_ARGS __global uchar *pv0, __global uchar *pv1, __global uchar *pv2, __global uchar *pv3, \
                  __global ushort *pf0, __global ushort *pf1, __global ushort *pf2, __global ushort *pf3, int seg

inline __global uchar *voxel_segment(int code, POOL_ARGS)
{
    const int k = code / seg;
    return k == 0 ? pv0 : k == 1 ? pv1 : k == 2 ? pv2 : pv3;
}

inline __global ushort *field_segment(int code, POOL_ARGS)
{
    const int k = code / seg;
    return k == 0 ? pf0 : k == 1 ? pf1 : k == 2 ? pf2 : pf3;
}

inline size_t brick_voxel_index(int code, int brick, int wx, int wy, int wz)
{
    const size_t b = (size_t)brick;
    return (((size_t)code * b + (size_t)(wz % brick)) * b + (size_t)(wy % brick)) * b + (size_t)(wx % brick);
}

inline int brick_code(__global const int *codes, int4 codes_lo, int4 codes_n, int brick, int wx, int wy, int wz)
{
    return codes[box_index(wx / brick - codes_lo.x, wy / brick - codes_lo.y, wz / brick - codes_lo.z, codes_n)];
}

/* Fill the scratch box (extent dims, world origin `origin`) from bricks: stored ones copied,
 * implicit ones written as their value. One work-item per scratch voxel. */
__kernel void gather_bricks(POOL_ARGS, __global const int *codes, int4 codes_lo, int4 codes_n, int brick,
                            __global uchar *voxels, __global ushort *field, int4 dims, int4 origin, int cap)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= dims.x || y >= dims.y || z >= dims.z)
        return;
    const int wx = origin.x + x, wy = origin.y + y, wz = origin.z + z;
    const int code = brick_code(codes, codes_lo, codes_n, brick, wx, wy, wz);
    const size_t i = world_index(x, y, z, dims);
    if (code >= 0) {
        const size_t j = brick_voxel_index(code % seg, brick, wx, wy, wz);
        voxels[i] = voxel_segment(code, pv0, pv1, pv2, pv3, pf0, pf1, pf2, pf3, seg)[j];
        field[i] = field_segment(code, pv0, pv1, pv2, pv3, pf0, pf1, pf2, pf3, seg)[j];
    } else if (code == BRICK_AIR) {
        voxels[i] = 0;
        field[i] = implicit_air(cap);
    } else {
        const uchar colour = (uchar)(-2 - code);
        voxels[i] = colour;
        field[i] = implicit_solid(cap, colour);
    }
}

/* Over the bricks of box r (scratch coordinates r_lo, extent r_n, brick-aligned): mixed[b] = 1
 * where a voxel differs (voxel or field) from its brick's first voxel, or where the first voxel's
 * field is not what an implicit brick of its kind stands for; first[b] = the brick's first voxel. `mixed` starts at 0; the stores race
 * but all write 1. */
__kernel void classify_bricks(__global const uchar *voxels, __global const ushort *field, int4 dims,
                              int4 r_lo, int4 r_n, int brick, int cap, __global int *mixed, __global int *first)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= r_n.x || y >= r_n.y || z >= r_n.z)
        return;
    const int4 bricks_n = (int4)(r_n.x / brick, r_n.y / brick, r_n.z / brick, 0);
    const size_t b = box_index(x / brick, y / brick, z / brick, bricks_n);
    const int bx0 = r_lo.x + x / brick * brick, by0 = r_lo.y + y / brick * brick, bz0 = r_lo.z + z / brick * brick;
    const size_t i = world_index(r_lo.x + x, r_lo.y + y, r_lo.z + z, dims);
    const size_t i0 = world_index(bx0, by0, bz0, dims);
    if (i == i0) {
        first[b] = voxels[i];
        if (field[i] != (voxels[i] == 0 ? implicit_air(cap) : implicit_solid(cap, voxels[i])))
            mixed[b] = 1;
    } else if (voxels[i] != voxels[i0] || field[i] != field[i0]) {
        mixed[b] = 1;
    }
}

/* Write the scratch box's stored bricks of box r (codes over r's bricks) back to their slots. */
__kernel void scatter_bricks(__global const uchar *voxels, __global const ushort *field, int4 dims, int4 origin,
                             int4 r_lo, int4 r_n, __global const int *codes, int4 codes_lo, int4 codes_n, int brick,
                             POOL_ARGS)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= r_n.x || y >= r_n.y || z >= r_n.z)
        return;
    const int sx = r_lo.x + x, sy = r_lo.y + y, sz = r_lo.z + z;
    const int wx = origin.x + sx, wy = origin.y + sy, wz = origin.z + sz;
    const int code = brick_code(codes, codes_lo, codes_n, brick, wx, wy, wz);
    if (code < 0)
        return;
    const size_t i = world_index(sx, sy, sz, dims);
    const size_t j = brick_voxel_index(code % seg, brick, wx, wy, wz);
    voxel_segment(code, pv0, pv1, pv2, pv3, pf0, pf1, pf2, pf3, seg)[j] = voxels[i];
    field_segment(code, pv0, pv1, pv2, pv3, pf0, pf1, pf2, pf3, seg)[j] = field[i];
}
