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

__kernel void lower_x(__global const uchar *voxels, __global uchar *t1, int4 dims, int4 d_lo, int4 d_n,
                      int4 g_lo, int4 g_n, int cap)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= g_n.x || y >= d_n.y || z >= d_n.z)
        return;
    const int wx = g_lo.x + x;
    const size_t row = world_index(d_lo.x, d_lo.y + y, d_lo.z + z, dims);
    int best = cap;
    for (int i = 0; i < d_n.x; ++i)
        if (voxels[row + i])
            best = min(best, gap(wx, d_lo.x + i));
    t1[((size_t)z * d_n.y + y) * g_n.x + x] = (uchar)best;
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
