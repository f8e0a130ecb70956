/* Region set-up and write-back shared by the iterative algorithms
 * (brute, fim, jfa, jfa_fim): fill the work box with initial distances, and
 * pack a finished work box back into the field over R. */
#include "sdf_common.h"

__kernel void init_work(__global const uchar *voxels, __global const ushort *field,
                        __global uchar *work, int4 dims, int4 w_lo, int4 w_n,
                        int4 r_lo, int4 r_hi, int seeded, int cap)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= w_n.x || y >= w_n.y || z >= w_n.z)
        return;
    work[box_index(x, y, z, w_n)] = (uchar)init_distance(
        voxels, field, w_lo.x + x, w_lo.y + y, w_lo.z + z, dims, r_lo, r_hi, seeded, cap);
}

/* Launched over R's extent. */
__kernel void pack_region(__global const uchar *work, __global const uchar *voxels,
                          __global ushort *field, int4 dims, int4 w_lo, int4 w_n,
                          int4 r_lo, int4 r_n, int cap)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= r_n.x || y >= r_n.y || z >= r_n.z)
        return;
    const int wx = r_lo.x + x, wy = r_lo.y + y, wz = r_lo.z + z;
    const size_t i = world_index(wx, wy, wz, dims);
    const uint d = min((uint)work[box_index(wx - w_lo.x, wy - w_lo.y, wz - w_lo.z, w_n)], (uint)cap);
    field[i] = pack_field(d, voxels[i]);
}
