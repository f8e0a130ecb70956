/* Voxel edits applied on the device. Every edit is pre-validated and clipped
 * to the world on the host; these kernels only write. Coordinates are the world's; the buffer
 * written holds the box of extent dims at world coordinates `origin` (0 for a dense world, a
 * scratch box's corner for a sparse one), so a brush decides which voxels it covers the same
 * way whichever buffer it writes. */
#include "sdf_common.h"

/* list[i] = (x, y, z, colour); the host removed duplicate positions. */
__kernel void set_voxels(__global uchar *voxels, int4 dims, int4 origin, __global const ushort4 *list, int n)
{
    const int i = get_global_id(0);
    if (i >= n)
        return;
    const ushort4 v = list[i];
    voxels[world_index(v.x - origin.x, v.y - origin.y, v.z - origin.z, dims)] = (uchar)v.w;
}

/* Launched over the clipped box extent n, starting at lo. */
__kernel void fill_box(__global uchar *voxels, int4 dims, int4 origin, int4 lo, int4 n, uint colour)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= n.x || y >= n.y || z >= n.z)
        return;
    voxels[world_index(lo.x + x - origin.x, lo.y + y - origin.y, lo.z + z - origin.z, dims)] = (uchar)colour;
}

/* Voxel p is inside when |p - center|^2 <= radius^2, p taken at integer
 * coordinates. Launched over the clipped bounding box. */
__kernel void fill_sphere(__global uchar *voxels, int4 dims, int4 origin, int4 lo, int4 n,
                          float4 center, float radius_sq, uint colour)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= n.x || y >= n.y || z >= n.z)
        return;
    const float3 p = (float3)((float)(lo.x + x), (float)(lo.y + y), (float)(lo.z + z));
    const float3 d = p - center.xyz;
    if (dot(d, d) <= radius_sq)
        voxels[world_index(lo.x + x - origin.x, lo.y + y - origin.y, lo.z + z - origin.z, dims)] = (uchar)colour;
}

/* Several box and sphere edits in one launch, in the order given; where two overlap, the later
 * one wins. Brush i is four int4: (lo.xyz, colour), (n.xyz, first work-item), its sphere as
 * float bits (center.xyz, radius^2; radius^2 < 0 for a box), and (slot, end): the worlds of a
 * slot pool take one launch together (gpu/slots.py), brush i writing the world `slot`
 * voxel_stride voxels on, whose brushes end before brush `end` (a lone world: slot 0, end
 * count). Brush i owns work-items first_i .. first_{i+1} - 1 over its clipped box lo..lo+n,
 * x fastest; ``total`` is the sum. */
inline int brush_covers(__global const int4 *brushes, int j, int x, int y, int z)
{
    const int4 lo = brushes[4 * j], n = brushes[4 * j + 1];
    if (x < lo.x || y < lo.y || z < lo.z || x >= lo.x + n.x || y >= lo.y + n.y || z >= lo.z + n.z)
        return 0;
    const float4 sphere = as_float4(brushes[4 * j + 2]);
    if (sphere.w < 0.0f)
        return 1;
    const float3 p = (float3)((float)x, (float)y, (float)z);
    const float3 d = p - sphere.xyz;
    return dot(d, d) <= sphere.w;
}

__kernel void fill_brushes(__global uchar *voxels, int4 dims, int4 origin, __global const int4 *brushes, int count, uint total,
                           long voxel_stride)
{
    const uint gid = get_global_id(0);
    if (gid >= total)
        return;
    int a = 0, b = count;  /* first_a <= gid < first_b (first_count = total) */
    while (b - a > 1) {
        const int m = (a + b) / 2;
        if ((uint)brushes[4 * m + 1].w <= gid)
            a = m;
        else
            b = m;
    }
    const int4 lo = brushes[4 * a], n = brushes[4 * a + 1], world = brushes[4 * a + 3];
    const uint k = gid - (uint)n.w;
    const int x = lo.x + (int)(k % (uint)n.x);
    const int y = lo.y + (int)((k / (uint)n.x) % (uint)n.y);
    const int z = lo.z + (int)(k / ((uint)n.x * (uint)n.y));
    if (!brush_covers(brushes, a, x, y, z))
        return;
    for (int j = a + 1; j < world.y; ++j)
        if (brush_covers(brushes, j, x, y, z))
            return;  /* a later brush writes this voxel */
    voxels[(size_t)world.x * (size_t)voxel_stride + world_index(x - origin.x, y - origin.y, z - origin.z, dims)] = (uchar)lo.w;
}
