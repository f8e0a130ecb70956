/* one_launch.cl's jump flood over a box in local memory (ONE_LAUNCH_FLOOD):
 * seeds packed as box coordinates, flood passes in chains, the resolve. It
 * uses one_launch.cl's Box, local_index and unit_span, and crew.h, and is
 * included there after them. */
#ifndef ONE_LAUNCH_FLOOD_H
#define ONE_LAUNCH_FLOOD_H

inline ushort pack_seed(int x, int y, int z, const Box *b)
{
    return (ushort)(x | (y << b->bx) | (z << b->bxy));
}

/* What voxel (x, y, z) pays for seed s: the seed's weight (read only where a
 * seed can weigh something) plus the way there. */
inline uint seed_cost(__local const uchar *dist, int x, int y, int z, ushort s, const Box *b)
{
    const int sx = s & ((1 << b->bx) - 1), sy = (s >> b->bx) & ((1 << (b->bxy - b->bx)) - 1), sz = s >> b->bxy;
    const uint way = (uint)(abs(sx - x) + abs(sy - y) + abs(sz - z));
#if ONE_LAUNCH_WEIGHTED
    return (uint)dist[local_index(sx, sy, sz, b)] + way;
#else
    return way;
#endif
}

/* A flood pass's work-item takes a piece of a chain: up to FLOOD_CHAIN voxels
 * of one column a step apart in z. They share x and y, so each seed read
 * from a neighbouring column costs its unpacking and its x-y way once for up
 * to three voxels of the piece (dz = +1, 0, -1), and a plane outside the box
 * is skipped by the whole piece. A column of n.z voxels has min(step, n.z)
 * chains: chain r holds z = r, r + step, ...; the first n.z % step chains
 * hold one voxel more. */
#ifndef FLOOD_CHAIN
#define FLOOD_CHAIN 4
#endif

/* A candidate is ranked by a key: its cost, then its place in jfa.cl's order
 * (0 the voxel's own seed, then dz, dy, dx from -1 to 1), then the seed. The
 * least key is the candidate that jfa.cl's strict comparisons keep, ties going
 * to the earlier one. one_launch.py checks that every cost fits COST_SHIFT's
 * 11 bits. */
#define COST_SHIFT 21
#define PLACE_SHIFT 16

inline uint place_of(int dz, int dy, int dx)
{
    const int k = (dz + 1) * 9 + (dy + 1) * 3 + (dx + 1);
    return (uint)(k < 13 ? k + 1 : k);
}

/* Column segments of a flood pass of `step`: chain pieces per column. */
inline int chain_pieces(int step, const Box *b, int *q, int *rem, int *long_pieces, int *short_pieces)
{
    *q = b->n.z / step;
    *rem = b->n.z % step;
    *long_pieces = (*q + FLOOD_CHAIN) / FLOOD_CHAIN;       /* chains of q + 1 voxels */
    *short_pieces = (*q + FLOOD_CHAIN - 1) / FLOOD_CHAIN;  /* chains of q */
    return *rem * *long_pieces + (min(step, b->n.z) - *rem) * *short_pieces;
}

/* One jfa_seed_pass over the box: src's seeds offered `step` away, into dst
 * (a crew member: its share, into `shared_dst`). */
inline void flood_pass(__local const uchar *dist, __local const ushort *src, __local ushort *dst,
                       __global ushort *shared_dst, int step, int cap, const Box *b, const Crew *c)
{
    int q, rem, long_pieces, short_pieces;
    const int pieces = chain_pieces(step, b, &q, &rem, &long_pieces, &short_pieces);
    int first, last;
    crew_share(b->nxy * pieces, c, &first, &last);
    const uint mx = (1u << b->bx) - 1u, my = (1u << (b->bxy - b->bx)) - 1u;
    for (int u = first + get_local_id(0); u < last; u += get_local_size(0)) {
        const int c = u % b->nxy, piece = u / b->nxy;
        const int x = c % b->n.x, y = c / b->n.x;
        int r, k0, length;
        if (piece < rem * long_pieces) {
            r = piece / long_pieces;
            k0 = piece % long_pieces * FLOOD_CHAIN;
            length = q + 1;
        } else {
            const int p = piece - rem * long_pieces;
            r = rem + p / short_pieces;
            k0 = p % short_pieces * FLOOD_CHAIN;
            length = q;
        }
        const int count = min(FLOOD_CHAIN, length - k0);  /* voxels of this piece */
        const int z0 = r + k0 * step;                      /* its first voxel's z */
        uint key[FLOOD_CHAIN];
#pragma unroll
        for (int j = 0; j < FLOOD_CHAIN; ++j) {
            const ushort s = j < count ? src[local_index(x, y, z0 + j * step, b)] : SEED_NONE;
            key[j] = s == SEED_NONE ? (uint)cap << COST_SHIFT | SEED_NONE
                                    : seed_cost(dist, x, y, z0 + j * step, s, b) << COST_SHIFT | s;
        }
        /* Plane k (z0 + k * step) holds the dz = -1, 0, +1 candidates of voxels k + 1, k, k - 1. */
#pragma unroll
        for (int k = -1; k <= FLOOD_CHAIN; ++k) {
            const int z = z0 + k * step;
            if (k > count || z < 0 || z >= b->n.z)
                continue;
#pragma unroll
            for (int dy = -1; dy <= 1; ++dy) {
                const int ny = y + dy * step;
                if (ny < 0 || ny >= b->n.y)
                    continue;
#pragma unroll
                for (int dx = -1; dx <= 1; ++dx) {
                    const int nx = x + dx * step;
                    if (nx < 0 || nx >= b->n.x)
                        continue;
                    const uint s = src[local_index(nx, ny, z, b)];
                    if (s == SEED_NONE)
                        continue;
                    const int sx = (int)(s & mx), sy = (int)(s >> b->bx & my), sz = (int)(s >> b->bxy);
                    uint way_xy = (uint)(abs(sx - x) + abs(sy - y));
#if ONE_LAUNCH_WEIGHTED
                    way_xy += dist[local_index(sx, sy, sz, b)];
#endif
                    const uint base = way_xy << COST_SHIFT | s;
#pragma unroll
                    for (int dz = -1; dz <= 1; ++dz) {
                        const int j = k - dz;
                        if (j < 0 || j >= FLOOD_CHAIN || (dz == 0 && dy == 0 && dx == 0))
                            continue;
                        const uint way_z = (uint)abs(sz - (z0 + j * step));
                        const uint candidate = base + (way_z << COST_SHIFT) + (place_of(dz, dy, dx) << PLACE_SHIFT);
                        key[j] = j < count ? min(key[j], candidate) : key[j];
                    }
                }
            }
        }
#pragma unroll
        for (int j = 0; j < FLOOD_CHAIN; ++j)
            if (j < count) {
#if ONE_LAUNCH_CREW
                shared_dst[local_index(x, y, z0 + j * step, b)] = (ushort)(key[j] & 0xffffu);
#else
                dst[local_index(x, y, z0 + j * step, b)] = (ushort)(key[j] & 0xffffu);
#endif
            }
    }
}

/* jfa_seed_init, every pass of jfa.py's step_sizes (first_step halving to 1,
 * then the extra passes' steps), and jfa_resolve, whose distances replace
 * `dist`. `a` and `b2` are the ping-pong pair. */
inline void flood(__local uchar *dist, __local ushort *a, __local ushort *b2, int first_step,
                  int extra_passes, int cap, int chunk, const Box *b,
                  __global ushort *crew_seeds, volatile __global int *crew, Crew *c)
{
    const int voxels = b->nxy * b->n.z;
    const int seeds_half = (voxels + 7) & ~7;  /* ushorts: each half of crew_seeds starts uint4-aligned */
    for (int u = get_local_id(0); u < b->units; u += get_local_size(0)) {
        int x, y, z0, z1;
        unit_span(u, b, &x, &y, &z0, &z1);
        for (int z = z0; z < z1; ++z) {
            const uint w = dist[local_index(x, y, z, b)];
            a[local_index(x, y, z, b)] = (chunk > 0 ? w == 0u : w < (uint)cap) ? pack_seed(x, y, z, b) : SEED_NONE;
        }
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    __local ushort *src = a, *dst = b2;
    const int halvings = first_step > 0 ? 32 - clz(first_step) : 0;
    for (int k = 0; k < halvings + extra_passes; ++k) {
        const int step = k < halvings ? first_step >> k : extra_passes - (k - halvings);
        __global ushort *shared_dst = crew_seeds + (k & 1) * seeds_half;
        flood_pass(dist, src, dst, shared_dst, step, cap, b, c);
#if ONE_LAUNCH_CREW
        crew_barrier(crew, c);
        crew_gather((__local uint4 *)dst, (volatile __global const uint4 *)shared_dst, 0, (voxels + 7) / 8);
#else
        barrier(CLK_LOCAL_MEM_FENCE);
#endif
        __local ushort *t = src;
        src = dst;
        dst = t;
    }
#if ONE_LAUNCH_WEIGHTED
    /* Resolve into dst (free now), then copy: every seed's weight is read from dist until all are done. */
    for (int u = get_local_id(0); u < b->units; u += get_local_size(0)) {
        int x, y, z0, z1;
        unit_span(u, b, &x, &y, &z0, &z1);
        for (int z = z0; z < z1; ++z) {
            const int i = local_index(x, y, z, b);
            uint d = min((uint)dist[i], (uint)cap);
            if (src[i] != SEED_NONE)
                d = min(d, seed_cost(dist, x, y, z, src[i], b));
            dst[i] = (ushort)d;
        }
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    for (int u = get_local_id(0); u < b->units; u += get_local_size(0)) {
        int x, y, z0, z1;
        unit_span(u, b, &x, &y, &z0, &z1);
        for (int z = z0; z < z1; ++z)
            dist[local_index(x, y, z, b)] = (uchar)dst[local_index(x, y, z, b)];
    }
#else
    /* No seed's weight is read: each voxel's distance is resolved in place. */
    for (int u = get_local_id(0); u < b->units; u += get_local_size(0)) {
        int x, y, z0, z1;
        unit_span(u, b, &x, &y, &z0, &z1);
        for (int z = z0; z < z1; ++z) {
            const int i = local_index(x, y, z, b);
            if (src[i] != SEED_NONE)
                dist[i] = (uchar)min(min((uint)dist[i], (uint)cap), seed_cost(dist, x, y, z, src[i], b));
        }
    }
#endif
    barrier(CLK_LOCAL_MEM_FENCE);
}

#endif
