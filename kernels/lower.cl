/* Lowering a Manhattan field after edits that only add solids.
 *
 * Adding solids can only lower distances: with S the solid voxels of an edited box D, the new
 * field is min(old, T_S), T_S the capped distance to S, and it changes only where T_S < cap —
 * within the cap of D, a rounded octahedron about a sixth of D grown by the cap. T_S is
 * separable like any L1 transform, and its seeds lie in D, so each stage is small:
 *   lower_x   lines along x through D's (y, z) footprint, x over G = D grown by the cap:  t1
 *   lower_y   (x, y) over G's footprint, z over D's z-range:                            t2
 *   lower_z   each (x, y) column of G, z only where the column is within the cap of D (a column
 *             shared by the launch's z work-items):
 *             field = pack(min(old, T), voxel), written where it is lower or inside D
 *             (where a voxel's colour may have changed).
 * Each output reads the seeds' side of D along its axis (D's extent there), so D is kept small
 * by the host (it falls back to the whole-region transform otherwise).
 * Layouts: t1[(z * d_n.y + y) * g_n.x + x] (z, y in D; x in G),
 *          t2[(z * g_n.y + y) * g_n.x + x] (z in D; x, y in G), all relative to their boxes.
 */
#include "sdf_common.h"

/* |a - b| as an int (OpenCL's abs of an int is a uint, which min would not mix with an int). */
inline int gap(int a, int b) { return a > b ? a - b : b - a; }

/* The distance along x from wx to the nearest solid of the row's n voxels from x0 (`row` its
 * first), capped. */
inline int nearest_along_x(__global const uchar *voxels, size_t row, int x0, int n, int wx, int cap)
{
    int best = cap;
    for (int i = 0; i < n; ++i)
        if (voxels[row + i])
            best = min(best, gap(wx, x0 + i));
    return best;
}

__kernel void lower_x(__global const uchar *voxels, __global uchar *t1, int4 dims, int4 d_lo, int4 d_n,
                      int4 g_lo, int4 g_n, int cap)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= g_n.x || y >= d_n.y || z >= d_n.z)
        return;
    t1[((size_t)z * d_n.y + y) * g_n.x + x] =
        (uchar)nearest_along_x(voxels, world_index(d_lo.x, d_lo.y + y, d_lo.z + z, dims), d_lo.x, d_n.x, g_lo.x + x, cap);
}

__kernel void lower_y(__global const uchar *t1, __global uchar *t2, int4 d_lo, int4 d_n, int4 g_lo, int4 g_n,
                      int cap)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= g_n.x || y >= g_n.y || z >= d_n.z)
        return;
    const int wy = g_lo.y + y;
    int best = cap;
    for (int i = 0; i < d_n.y; ++i)
        best = min(best, (int)t1[((size_t)z * d_n.y + i) * g_n.x + x] + gap(wy, d_lo.y + i));
    t2[((size_t)z * g_n.y + y) * g_n.x + x] = (uchar)best;
}

__kernel void lower_z(__global const uchar *t2, __global const uchar *voxels, __global ushort *field, int4 dims,
                      int4 d_lo, int4 d_n, int4 g_lo, int4 g_n, int cap)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= g_n.x || y >= g_n.y)
        return;
    const int wx = g_lo.x + x, wy = g_lo.y + y;
    const int4 d_hi = d_lo + d_n;
    /* the column's L1 distance to D's footprint: nothing nearer than the cap beyond its reach */
    const int dxy = max(max(d_lo.x - wx, wx - (d_hi.x - 1)), 0) + max(max(d_lo.y - wy, wy - (d_hi.y - 1)), 0);
    if (dxy >= cap)
        return;
    const int reach = cap - dxy;
    /* the column's z-range, shared by the launch's z work-items (latency, not bandwidth, bounds
     * a thread walking a long column alone) */
    const int c0 = max(d_lo.z - reach, 0), c1 = min(d_hi.z + reach, dims.z);
    const int share = (c1 - c0 + (int)get_global_size(2) - 1) / (int)get_global_size(2);
    const int z0 = c0 + (int)get_global_id(2) * share, z1 = min(z0 + share, c1);
    const bool in_footprint = dxy == 0;
    /* T below D's z-range is min(t2[k] + k') - z, above it min(t2[k] - k') + z (k' = d_lo.z + k) */
    int below = 1 << 20, above = 1 << 20;
    for (int k = 0; k < d_n.z; ++k) {
        const int t = t2[((size_t)k * g_n.y + y) * g_n.x + x];
        below = min(below, t + d_lo.z + k);
        above = min(above, t - (d_lo.z + k));
    }
    for (int wz = z0; wz < z1; ++wz) {
        int t;
        if (wz < d_lo.z) {
            t = below - wz;
        } else if (wz >= d_hi.z) {
            t = above + wz;
        } else {
            t = cap;
            for (int k = 0; k < d_n.z; ++k)
                t = min(t, (int)t2[((size_t)k * g_n.y + y) * g_n.x + x] + gap(wz, d_lo.z + k));
        }
        t = min(t, cap);
        const size_t i = world_index(wx, wy, wz, dims);
        const uint old = field[i] >> 8;
        if ((uint)t < old || (in_footprint && wz >= d_lo.z && wz < d_hi.z))
            field[i] = pack_field(min((uint)t, old), voxels[i]);
    }
}

/* The same for a Euclidean world, whose field is the last of three stages the world keeps
 * (kernels/edt.cl): the line (1-D distance along x, uchar, in `work`), the plane (min over z of
 * line^2 + dz^2, ushort, in `edt_plane`) and the field (min over y of plane + dy^2), each capped
 * (cap, cap^2). Every stage is a minimum, so with solids only added each becomes min(old, the
 * stage of S alone), written where lower: the stages the next recompute reads stay current.
 *   elower_x  the line of S over G's x for D's (y, z) footprint:            t1, and `line`
 *   elower_z  the plane of S for D's y-range, z over G:                     t2 (ushort), and `plane`
 *   elower_y  the field, each (x, z) column of G within the cap of D.
 * Layouts: t1 as lower_x's; t2[(z * d_n.y + y) * g_n.x + x] (z in G, y in D, x in G). */
__kernel void elower_x(__global const uchar *voxels, __global uchar *t1, __global uchar *line, int4 dims,
                       int4 d_lo, int4 d_n, int4 g_lo, int4 g_n, int cap)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= g_n.x || y >= d_n.y || z >= d_n.z)
        return;
    const int wx = g_lo.x + x;
    const int best = nearest_along_x(voxels, world_index(d_lo.x, d_lo.y + y, d_lo.z + z, dims), d_lo.x, d_n.x, wx, cap);
    t1[((size_t)z * d_n.y + y) * g_n.x + x] = (uchar)best;
    const size_t at = world_index(wx, d_lo.y + y, d_lo.z + z, dims);
    if (best < (int)line[at])
        line[at] = (uchar)best;
}

__kernel void elower_z(__global const uchar *t1, __global ushort *t2, __global ushort *plane, int4 dims,
                       int4 d_lo, int4 d_n, int4 g_lo, int4 g_n, int cap)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= g_n.x || y >= d_n.y || z >= g_n.z)
        return;
    const int wz = g_lo.z + z, cap2 = cap * cap;
    int best = cap2;
    for (int k = 0; k < d_n.z; ++k) {
        const int t = t1[((size_t)k * d_n.y + y) * g_n.x + x];
        if (t < cap) {
            const int dz = wz - (d_lo.z + k);
            best = min(best, t * t + dz * dz);
        }
    }
    t2[((size_t)z * d_n.y + y) * g_n.x + x] = (ushort)best;
    const size_t at = world_index(g_lo.x + x, d_lo.y + y, wz, dims);
    if (best < (int)plane[at])
        plane[at] = (ushort)best;
}

__kernel void elower_y(__global const ushort *t2, __global ushort *field, int4 dims, int4 d_lo, int4 d_n,
                       int4 g_lo, int4 g_n, int cap)
{
    const int x = get_global_id(0), z = get_global_id(1);
    if (x >= g_n.x || z >= g_n.z)
        return;
    const int wx = g_lo.x + x, wz = g_lo.z + z, cap2 = cap * cap;
    const int4 d_hi = d_lo + d_n;
    const int dx = max(max(d_lo.x - wx, wx - (d_hi.x - 1)), 0), dz = max(max(d_lo.z - wz, wz - (d_hi.z - 1)), 0);
    const int dxz2 = dx * dx + dz * dz;
    if (dxz2 >= cap2)
        return;
    /* past `reach` along y the distance to D alone reaches the cap */
    const int reach = (int)sqrt((float)(cap2 - dxz2)) + 1;
    const int c0 = max(d_lo.y - reach, 0), c1 = min(d_hi.y + reach, dims.y);
    const int share = (c1 - c0 + (int)get_global_size(2) - 1) / (int)get_global_size(2);
    const int y0 = c0 + (int)get_global_id(2) * share, y1 = min(y0 + share, c1);
    for (int wy = y0; wy < y1; ++wy) {
        int best = cap2;
        for (int k = 0; k < d_n.y; ++k) {
            const int dy = wy - (d_lo.y + k);
            best = min(best, (int)t2[((size_t)z * d_n.y + k) * g_n.x + x] + dy * dy);
        }
        const size_t at = world_index(wx, wy, wz, dims);
        if (best < (int)field[at])
            field[at] = (ushort)best;
    }
}

/* Where removing solids from D can raise the field: voxels within the cap of D whose distance is
 * below the cap and not below their distance to D (their nearest solid may have been in D); every
 * other voxel's nearest solid is still there. `euclid`: the field holds squared Euclidean
 * distances (a Euclidean world's), compared with the squared distance to D; else Manhattan ones.
 * Their bounding box, reduced in each work-group and then into bounds: min x, y, z, then max x, y,
 * z (inclusive). A transform of that box, seeded from the unchanged field around it, is exact.
 * Launched like lower_z. */
__kernel void raise_bounds(__global const ushort *field, int4 dims, int4 d_lo, int4 d_n, int4 g_lo, int4 g_n,
                           int cap, int euclid, __global int *bounds)
{
    __local int group[6];
    const int lid = get_local_id(0) + get_local_size(0) * (get_local_id(1) + get_local_size(1) * get_local_id(2));
    if (lid < 6)
        group[lid] = lid < 3 ? INT_MAX : INT_MIN;
    barrier(CLK_LOCAL_MEM_FENCE);
    const int x = get_global_id(0), y = get_global_id(1);
    int lo_z = INT_MAX, hi_z = INT_MIN;
    const int wx = g_lo.x + x, wy = g_lo.y + y;
    const int4 d_hi = d_lo + d_n;
    const int dx = max(max(d_lo.x - wx, wx - (d_hi.x - 1)), 0), dy = max(max(d_lo.y - wy, wy - (d_hi.y - 1)), 0);
    const int limit = euclid ? cap * cap : cap;
    const int dxy = euclid ? dx * dx + dy * dy : dx + dy;
    if (x < g_n.x && y < g_n.y && dxy < limit) {
        const int reach = euclid ? (int)sqrt((float)(limit - dxy)) + 1 : cap - dxy;
        const int c0 = max(d_lo.z - reach, 0), c1 = min(d_hi.z + reach, dims.z);
        const int share = (c1 - c0 + (int)get_global_size(2) - 1) / (int)get_global_size(2);
        const int z0 = c0 + (int)get_global_id(2) * share, z1 = min(z0 + share, c1);
        for (int wz = z0; wz < z1; ++wz) {
            const ushort value = field[world_index(wx, wy, wz, dims)];
            const int old = euclid ? value : value >> 8;
            const int dz = max(max(d_lo.z - wz, wz - (d_hi.z - 1)), 0);
            const int to_d = dxy + (euclid ? dz * dz : dz);
            if (old < limit && old >= to_d) {
                lo_z = min(lo_z, wz);
                hi_z = max(hi_z, wz);
            }
        }
    }
    if (lo_z <= hi_z) {
        atomic_min(&group[0], wx);
        atomic_min(&group[1], wy);
        atomic_min(&group[2], lo_z);
        atomic_max(&group[3], wx);
        atomic_max(&group[4], wy);
        atomic_max(&group[5], hi_z);
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    if (lid < 3 && group[lid] != INT_MAX)
        atomic_min(&bounds[lid], group[lid]);
    else if (lid >= 3 && lid < 6 && group[lid] != INT_MIN)
        atomic_max(&bounds[lid], group[lid]);
}
