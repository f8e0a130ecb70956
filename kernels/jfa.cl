/* Jump Flooding (Rong & Tan 2006; the dissertation's Algorithm 6 with its
 * ping-pong buffers): every voxel keeps the nearest seed found so far, and
 * each pass offers it the seeds of its 26 neighbours `step` voxels away.
 *
 * Seeds are the voxels whose initial distance in `work` is below the cap:
 * solids (weight 0) and, in a seeded job, the seed shell, whose weight is its
 * distance from the current field. A candidate seed s is worth
 * work[s] + |p - s|, the length of a real path, so the result is never below
 * the true distance: jump flooding can only overestimate, where a voxel's
 * nearest seed never reached it.
 *
 * A seed is stored as its offset from the voxel, 9 bits per axis biased by
 * 256, in one uint; SEED_NONE when none is known. Only candidates worth less
 * than the cap are kept, so every component is below 255 in magnitude. With
 * padding (chunk > 0, work box chunk-aligned) neighbours in other chunks are
 * not read, so each chunk floods alone; its frame is in `work` and joins at
 * jfa_resolve. */
#include "sdf_common.h"
#include "chunk_padding.h"

#define SEED_NONE 0xffffffffu
#define SEED_BIAS 256

inline uint pack_seed(int dx, int dy, int dz)
{
    return (uint)(dx + SEED_BIAS) | ((uint)(dy + SEED_BIAS) << 9) | ((uint)(dz + SEED_BIAS) << 18);
}

inline int4 unpack_seed(uint s)
{
    return (int4)((int)(s & 511u) - SEED_BIAS, (int)((s >> 9) & 511u) - SEED_BIAS,
                  (int)((s >> 18) & 511u) - SEED_BIAS, 0);
}

/* What voxel (x, y, z) pays for the seed at offset o: the seed's weight plus the way there. */
inline uint seed_cost(__global const uchar *work, int x, int y, int z, int4 o, int4 w_n)
{
    return (uint)work[box_index(x + o.x, y + o.y, z + o.z, w_n)] + (uint)(abs(o.x) + abs(o.y) + abs(o.z));
}

/* Every voxel that is a seed points at itself. With padding only solids are
 * seeds: the frame distances in `work` are not voxels of the chunk. */
__kernel void jfa_seed_init(__global const uchar *work, __global uint *seeds, int4 w_n, int cap, int chunk)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= w_n.x || y >= w_n.y || z >= w_n.z)
        return;
    const size_t i = box_index(x, y, z, w_n);
    const uint w = work[i];
    seeds[i] = (chunk > 0 ? w == 0u : w < (uint)cap) ? pack_seed(0, 0, 0) : SEED_NONE;
}

__kernel void jfa_seed_pass(__global const uchar *work, __global const uint *src, __global uint *dst,
                            int4 w_n, int step, int cap, int chunk)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= w_n.x || y >= w_n.y || z >= w_n.z)
        return;
    const size_t i = box_index(x, y, z, w_n);
    uint best = src[i];
    uint best_cost = (uint)cap;
    if (best != SEED_NONE)
        best_cost = seed_cost(work, x, y, z, unpack_seed(best), w_n);
    if (best_cost > 0u) {
        for (int dz = -1; dz <= 1; ++dz) {
            const int nz = z + dz * step;
            if (nz < 0 || nz >= w_n.z || !same_chunk(z, nz, chunk))
                continue;
            for (int dy = -1; dy <= 1; ++dy) {
                const int ny = y + dy * step;
                if (ny < 0 || ny >= w_n.y || !same_chunk(y, ny, chunk))
                    continue;
                for (int dx = -1; dx <= 1; ++dx) {
                    const int nx = x + dx * step;
                    if ((dx | dy | dz) == 0 || nx < 0 || nx >= w_n.x || !same_chunk(x, nx, chunk))
                        continue;
                    const uint s = src[box_index(nx, ny, nz, w_n)];
                    if (s == SEED_NONE)
                        continue;
                    /* The neighbour's seed, seen from here. */
                    const int4 o = unpack_seed(s) + (int4)(dx * step, dy * step, dz * step, 0);
                    if ((uint)(abs(o.x) + abs(o.y) + abs(o.z)) >= best_cost)
                        continue;  /* weights are never negative */
                    const uint cost = seed_cost(work, x, y, z, o, w_n);
                    if (cost < best_cost) {
                        best_cost = cost;
                        best = pack_seed(o.x, o.y, o.z);
                    }
                }
            }
        }
    }
    dst[i] = best;
}

/* Distances from the seeds found, never above the voxel's own initial value
 * (its frame distance, with padding), into `out`. */
__kernel void jfa_resolve(__global const uchar *work, __global const uint *seeds, __global uchar *out,
                          int4 w_n, int cap)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= w_n.x || y >= w_n.y || z >= w_n.z)
        return;
    const size_t i = box_index(x, y, z, w_n);
    uint d = min((uint)work[i], (uint)cap);
    const uint s = seeds[i];
    if (s != SEED_NONE)
        d = min(d, seed_cost(work, x, y, z, unpack_seed(s), w_n));
    out[i] = (uchar)d;
}
