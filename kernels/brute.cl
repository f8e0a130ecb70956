/* Brute force (the dissertation's Algorithms 1 and 3): every voxel of R scans
 * every voxel of the work box within `cap` on each axis and keeps the least
 * initial distance plus Manhattan offset. O(window^3) per voxel: for small
 * worlds and as a reference. Reads `work`, writes `out` (never in place).
 * With padding (chunk > 0, Algorithm 3) the window stops at the voxel's chunk;
 * the frame beyond it is already in the initial distances (region.cl). */
#include "sdf_common.h"

/* Launched over R's extent; r_off is R's origin inside the work box, which is
 * chunk-aligned when chunk > 0. */
__kernel void brute_region(__global const uchar *work, __global uchar *out, int4 w_n,
                           int4 r_off, int4 r_n, int cap, int chunk)
{
    const int rx = get_global_id(0), ry = get_global_id(1), rz = get_global_id(2);
    if (rx >= r_n.x || ry >= r_n.y || rz >= r_n.z)
        return;
    const int x = r_off.x + rx, y = r_off.y + ry, z = r_off.z + rz;
    uint best = work[box_index(x, y, z, w_n)];
    int x0 = max(0, x - cap), x1 = min(w_n.x, x + cap + 1);
    int y0 = max(0, y - cap), y1 = min(w_n.y, y + cap + 1);
    int z0 = max(0, z - cap), z1 = min(w_n.z, z + cap + 1);
    if (chunk > 0) {
        const int cx = x / chunk * chunk, cy = y / chunk * chunk, cz = z / chunk * chunk;
        x0 = max(x0, cx); x1 = min(x1, cx + chunk);
        y0 = max(y0, cy); y1 = min(y1, cy + chunk);
        z0 = max(z0, cz); z1 = min(z1, cz + chunk);
    }
    for (int qz = z0; qz < z1; ++qz)
        for (int qy = y0; qy < y1; ++qy)
            for (int qx = x0; qx < x1; ++qx) {
                const uint d = (uint)work[box_index(qx, qy, qz, w_n)]
                             + (uint)(abs(qx - x) + abs(qy - y) + abs(qz - z));
                best = min(best, d);
            }
    out[box_index(x, y, z, w_n)] = (uchar)min(best, (uint)cap);
}
