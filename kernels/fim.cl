/* One Fast Iterative Method relaxation over the work box (the dissertation's
 * Algorithm 5): every non-solid voxel takes the least of its six face
 * neighbours plus one. Updates are in place and monotone (values only fall),
 * so reading a neighbour that another work-item is rewriting is harmless; a
 * pass in which nothing changes proves the fixed point, which is the exact
 * distance. Voxels outside the work box do not exist here. With padding
 * (chunk > 0, work box chunk-aligned) a neighbour in another chunk is not
 * read: the frame it stands for is already in the initial distances. */
#include "sdf_common.h"
#include "chunk_padding.h"

__kernel void fim_pass(__global uchar *work, int4 w_n, __global int *changed, int iteration, int chunk)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= w_n.x || y >= w_n.y || z >= w_n.z)
        return;
    const size_t i = box_index(x, y, z, w_n);
    const uint here = work[i];
    if (here == 0)
        return;
    const size_t sy = (size_t)w_n.x, sz = (size_t)w_n.x * (size_t)w_n.y;
    uint best = here;
    if (x > 0 && same_chunk(x, x - 1, chunk)) best = min(best, (uint)work[i - 1] + 1);
    if (x + 1 < w_n.x && same_chunk(x, x + 1, chunk)) best = min(best, (uint)work[i + 1] + 1);
    if (y > 0 && same_chunk(y, y - 1, chunk)) best = min(best, (uint)work[i - sy] + 1);
    if (y + 1 < w_n.y && same_chunk(y, y + 1, chunk)) best = min(best, (uint)work[i + sy] + 1);
    if (z > 0 && same_chunk(z, z - 1, chunk)) best = min(best, (uint)work[i - sz] + 1);
    if (z + 1 < w_n.z && same_chunk(z, z + 1, chunk)) best = min(best, (uint)work[i + sz] + 1);
    if (best < here) {
        work[i] = (uchar)best;
        changed[iteration] = 1;
    }
}
