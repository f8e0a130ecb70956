/* Evaluates the shared index functions of sdf_common.h at given coordinates,
 * so the tests can prove they are 64-bit without a buffer past 2^31 elements.
 * points[i] = (x, y, z, -), dims the world or box extent. */
#include "sdf_common.h"

__kernel void index_of(__global const int4 *points, int4 dims, int n,
                       __global ulong *world_out, __global ulong *box_out)
{
    const int i = get_global_id(0);
    if (i >= n)
        return;
    const int4 p = points[i];
    world_out[i] = world_index(p.x, p.y, p.z, dims);
    box_out[i] = box_index(p.x, p.y, p.z, dims);
}
