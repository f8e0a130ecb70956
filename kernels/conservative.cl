/* A lower bound of the capped Manhattan distance from a coarse grid of bricks
 * (sdfserver/algorithms/conservative.py has the proof).
 *
 * Bricks are BRICK^3 voxels on the world's grid (brick (i, j, k) covers
 * [i*BRICK, (i+1)*BRICK) on x, ...); the coarse box holds the bricks that meet
 * the work box W, origin c_lo and extent c_n in bricks, one uchar per brick.
 *   brick_init     per brick: the least initial distance of its voxels in W
 *                  (init_distance: 0 on solids, the seed shell's field, else cap)
 *   brick_spread   x, then y: per line, the 1-D transform from bricks to voxels
 *                  (the distance from a voxel coordinate to each brick's interval)
 *   brick_pack     z, per (x, y) of R: the same along z, written to the field
 * The result at voxel p is min over bricks Q of init(Q) + the L1 distance from
 * p to Q's box, capped. Build option: BRICK (4 or 8; default 8).
 */
#include "sdf_common.h"

#ifndef BRICK
#define BRICK 8
#endif

#if BRICK == 8
#define ROW_SOLID(p) (as_ulong(vload8(0, (p))) != 0)
#elif BRICK == 4
#define ROW_SOLID(p) (as_uint(vload4(0, (p))) != 0)
#else
#error "BRICK must be 4 or 8"
#endif

/* w_lo, w_hi: the work box; r_lo, r_hi: the region. One work-item per brick. */
__kernel void brick_init(__global const uchar *voxels, __global const ushort *field,
                         __global uchar *coarse, int4 dims, int4 w_lo, int4 w_hi,
                         int4 r_lo, int4 r_hi, int4 c_lo, int4 c_n, int seeded, int cap)
{
    const int cx = get_global_id(0), cy = get_global_id(1), cz = get_global_id(2);
    if (cx >= c_n.x || cy >= c_n.y || cz >= c_n.z)
        return;
    const int x0 = max((c_lo.x + cx) * BRICK, w_lo.x), x1 = min((c_lo.x + cx + 1) * BRICK, w_hi.x);
    const int y0 = max((c_lo.y + cy) * BRICK, w_lo.y), y1 = min((c_lo.y + cy + 1) * BRICK, w_hi.y);
    const int z0 = max((c_lo.z + cz) * BRICK, w_lo.z), z1 = min((c_lo.z + cz + 1) * BRICK, w_hi.z);
    uint best = (uint)cap;
    for (int z = z0; z < z1 && best != 0; ++z) {
        for (int y = y0; y < y1 && best != 0; ++y) {
            /* A whole brick row read from voxels alone (no seed shell in it): one vector load. */
            const int voxels_only = !seeded || (y >= r_lo.y && y < r_hi.y && z >= r_lo.z && z < r_hi.z
                                                && x0 >= r_lo.x && x1 <= r_hi.x);
            if (voxels_only && x1 - x0 == BRICK) {
                if (ROW_SOLID(voxels + world_index(x0, y, z, dims)))
                    best = 0;
                continue;
            }
            for (int x = x0; x < x1; ++x)
                best = min(best, init_distance(voxels, field, x, y, z, dims, r_lo, r_hi, seeded, cap));
        }
    }
    coarse[box_index(cx, cy, cz, c_n)] = (uchar)best;
}

/* The 1-D step of the bound along `axis`: out(v) = min over bricks Q of in(Q) + the distance
 * from voxel coordinate v to Q's interval [Q * BRICK, Q * BRICK + BRICK - 1]. For v at offset o
 * in brick P that is min(in(P), F(P) + o + 1, B(P) + BRICK - o), where
 *   F(P) = min over Q < P of in(Q) + (P - Q - 1) * BRICK   (forward sweep over bricks)
 *   B(P) = min over Q > P of in(Q) + (Q - P - 1) * BRICK   (backward sweep over bricks).
 * Values are capped at cap (every term added is >= 0, so capping keeps the capped result). */
inline uint spread(uint own, uint f, uint b, int o, uint cap)
{
    return min(min(own, cap), min(f + (uint)o + 1u, b + (uint)(BRICK - o)));
}

inline void line_of(int axis, int4 n, int u, int v, size_t *base, size_t *stride)
{
    if (axis == 0) {
        *base = box_index(0, u, v, n);
        *stride = 1;
    } else if (axis == 1) {
        *base = box_index(u, 0, v, n);
        *stride = (size_t)n.x;
    } else {
        *base = box_index(u, v, 0, n);
        *stride = (size_t)n.x * (size_t)n.y;
    }
}

/* src has extent s_n (bricks along `axis`), dst the same with BRICK voxels a brick along
 * `axis`. One work-item per line: (u, v) are the other two axes in order. B(P) waits in dst
 * at P's first voxel until the forward sweep reads it. */
__kernel void brick_spread(__global const uchar *src, __global uchar *dst, int4 s_n, int axis, int cap)
{
    const int u = get_global_id(0), v = get_global_id(1);
    const int nu = axis == 0 ? s_n.y : s_n.x, nv = axis == 2 ? s_n.y : s_n.z;
    if (u >= nu || v >= nv)
        return;
    int4 d_n = s_n;
    if (axis == 0) d_n.x *= BRICK;
    else if (axis == 1) d_n.y *= BRICK;
    else d_n.z *= BRICK;
    const int n = axis == 0 ? s_n.x : axis == 1 ? s_n.y : s_n.z;
    size_t s_base, s_stride, d_base, d_stride;
    line_of(axis, s_n, u, v, &s_base, &s_stride);
    line_of(axis, d_n, u, v, &d_base, &d_stride);
    const uint c = (uint)cap;
    uint run = c;
    for (int p = n - 1; p >= 0; --p) {
        dst[d_base + (size_t)p * BRICK * d_stride] = (uchar)min(run, c);
        run = min(run + BRICK, (uint)src[s_base + (size_t)p * s_stride]);
    }
    run = c;
    for (int p = 0; p < n; ++p) {
        const uint own = src[s_base + (size_t)p * s_stride];
        const size_t first = d_base + (size_t)p * BRICK * d_stride;
        const uint back = dst[first];
        for (int o = 0; o < BRICK; ++o)
            dst[first + (size_t)o * d_stride] = (uchar)spread(own, run, back, o, c);
        run = min(run + BRICK, own);
    }
}

/* The z step, written to the field over R (r_lo, r_n): src has extent s_n (voxels along x and
 * y from voxel origin v_lo.xy, bricks along z from brick c_lo_z); back holds B(P) per brick.
 * One work-item per (x, y) of R. Solids get 0 and their colour; air max(1, bound). */
__kernel void brick_pack(__global const uchar *src, __global uchar *back, __global const uchar *voxels,
                         __global ushort *field, int4 dims, int4 s_n, int4 v_lo, int4 r_lo,
                         int4 r_n, int cap)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= r_n.x || y >= r_n.y)
        return;
    const int wx = r_lo.x + x, wy = r_lo.y + y;
    const size_t base = box_index(wx - v_lo.x, wy - v_lo.y, 0, s_n);
    const size_t stride = (size_t)s_n.x * (size_t)s_n.y;
    const uint c = (uint)cap;
    uint run = c;
    for (int p = s_n.z - 1; p >= 0; --p) {
        back[base + (size_t)p * stride] = (uchar)min(run, c);
        run = min(run + BRICK, (uint)src[base + (size_t)p * stride]);
    }
    run = c;
    const int z_end = r_lo.z + r_n.z;
    for (int p = 0; p < s_n.z; ++p) {
        const uint own = src[base + (size_t)p * stride];
        const int z0 = (v_lo.z / BRICK + p) * BRICK;
        if (z0 + BRICK > r_lo.z && z0 < z_end) {
            const uint b = back[base + (size_t)p * stride];
            for (int wz = max(z0, r_lo.z); wz < min(z0 + BRICK, z_end); ++wz) {
                const size_t i = world_index(wx, wy, wz, dims);
                const uchar voxel = voxels[i];
                const uint d = voxel ? 0u : max(1u, spread(own, run, b, wz - z0, c));
                field[i] = pack_field(d, voxel);
            }
        }
        run = min(run + BRICK, own);
    }
}
