/* Voxel edits applied on the device. Every edit is pre-validated and clipped
 * to the world on the host; these kernels only write. */
#include "sdf_common.h"

/* list[i] = (x, y, z, colour); the host removed duplicate positions. */
__kernel void set_voxels(__global uchar *voxels, int4 dims, __global const ushort4 *list, int n)
{
    const int i = get_global_id(0);
    if (i >= n)
        return;
    const ushort4 v = list[i];
    voxels[world_index(v.x, v.y, v.z, dims)] = (uchar)v.w;
}

/* Launched over the clipped box extent n, starting at lo. */
__kernel void fill_box(__global uchar *voxels, int4 dims, int4 lo, int4 n, uint colour)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= n.x || y >= n.y || z >= n.z)
        return;
    voxels[world_index(lo.x + x, lo.y + y, lo.z + z, dims)] = (uchar)colour;
}

/* Voxel p is inside when |p - center|^2 <= radius^2, p taken at integer
 * coordinates. Launched over the clipped bounding box. */
__kernel void fill_sphere(__global uchar *voxels, int4 dims, int4 lo, int4 n,
                          float4 center, float radius_sq, uint colour)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= n.x || y >= n.y || z >= n.z)
        return;
    const float3 p = (float3)((float)(lo.x + x), (float)(lo.y + y), (float)(lo.z + z));
    const float3 d = p - center.xyz;
    if (dot(d, d) <= radius_sq)
        voxels[world_index(lo.x + x, lo.y + y, lo.z + z, dims)] = (uchar)colour;
}
