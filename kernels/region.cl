/* Region set-up and write-back shared by the iterative algorithms
 * (brute, fim, jfa, jfa_fim): fill the work box with initial distances, and
 * pack a finished work box back into the field over R.
 *
 * With padding (chunk > 0) an air voxel starts at its distance to the solid
 * frame around its chunk (capped). That makes the padded field the plain
 * min-plus transform of these initial values: a voxel q outside p's chunk is
 * at least as far from p as p's frame is, so nothing from another chunk can
 * undercut it, and every algorithm run on them gives the per-chunk answer. */
#include "sdf_common.h"
#include "chunk_padding.h"

__kernel void init_work(__global const uchar *voxels, __global const ushort *field,
                        __global uchar *work, int4 dims, int4 w_lo, int4 w_n,
                        int4 r_lo, int4 r_hi, int seeded, int cap, int chunk)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= w_n.x || y >= w_n.y || z >= w_n.z)
        return;
    const int wx = w_lo.x + x, wy = w_lo.y + y, wz = w_lo.z + z;
    uint d = init_distance(voxels, field, wx, wy, wz, dims, r_lo, r_hi, seeded, cap);
    if (chunk > 0)
        d = min(d, frame_distance(wx, wy, wz, chunk));
    work[box_index(x, y, z, w_n)] = (uchar)d;
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
