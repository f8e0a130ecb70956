/* One Jump Flooding pass (the dissertation's Algorithm 6) with ping-pong
 * buffers: each voxel takes the least of its own distance and those of its six
 * face neighbours `step` voxels away plus `step`. Every candidate is the length
 * of a real path, so the result never falls below the true distance; it can
 * stay above it where the shortest path needs moves along two axes at one step
 * size. */
#include "sdf_common.h"

__kernel void jfa_pass(__global const uchar *src, __global uchar *dst, int4 w_n, int step)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= w_n.x || y >= w_n.y || z >= w_n.z)
        return;
    const size_t i = box_index(x, y, z, w_n);
    uint best = src[i];
    if (best != 0) {
        const size_t sy = (size_t)w_n.x * step, sz = (size_t)w_n.x * (size_t)w_n.y * step;
        const uint s = (uint)step;
        if (x >= step) best = min(best, (uint)src[i - step] + s);
        if (x + step < w_n.x) best = min(best, (uint)src[i + step] + s);
        if (y >= step) best = min(best, (uint)src[i - sy] + s);
        if (y + step < w_n.y) best = min(best, (uint)src[i + sy] + s);
        if (z >= step) best = min(best, (uint)src[i - sz] + s);
        if (z + step < w_n.z) best = min(best, (uint)src[i + sz] + s);
    }
    dst[i] = (uchar)best;
}
