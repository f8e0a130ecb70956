/* Jump Flooding (Rong & Tan 2006; the dissertation's Algorithm 6 with its
 * ping-pong buffers): every voxel keeps the nearest seed found so far, and
 * each pass offers it the seeds of its 26 neighbours `step` voxels away.
 *
 * Seeds are the voxels whose initial distance in `work` is below the cap:
 * solids (weight 0) and, in a seeded job, the seed shell, whose weight is its
 * distance from the current field. A candidate seed s is worth
 * work[s] + |p - s|, the length of a real path, so the result is never below
 * the true distance: jump flooding can only overestimate, where a voxel's
 * nearest seed never reached it. Candidates are offered in a fixed order (the
 * voxel's own seed, then z, y, x from -step) and only a strictly cheaper one
 * replaces the best, so ties go to the first. Where no weight is read, a
 * candidate's rank in that order sits below its cost in one key, the best is
 * the smallest key, and the winner's seed is read again once it is known.
 *
 * A seed is stored as its offset from the voxel, each axis biased by 512 in
 * 10 bits (x low), in one uint. Only candidates worth less than the cap (at
 * most 255) are kept and a step is at most 128, so a component seen from a
 * neighbour stays within 382 of 0: moving an offset by a neighbour's is one
 * add, never carrying between fields. SEED_NONE is a far-away offset that an
 * add keeps in range and whose length is above any cap, so it never wins and
 * needs no test. With padding (chunk > 0, work box chunk-aligned) neighbours
 * in other chunks are not read, so each chunk floods alone; its frame is in
 * `work` and joins at the last pass.
 *
 * Built per pass (sdfserver/algorithms/jfa.py):
 *   JFA_STEP      the pass's step (0: a box too small for any pass; each voxel
 *                 is offered its own seed alone, which finds and resolves it).
 *   JFA_WEIGHTED  1: seeds may weigh more than 0 (a seed shell), so a
 *                 candidate that could win has its weight read from `work`;
 *                 0: every seed is a solid of weight 0 and costs its offset's
 *                 length. The same candidates win either way.
 *   JFA_FIRST     1: the first pass, which finds the seeds in `work` itself
 *                 (every seed starts as its own) instead of reading `src`.
 *   JFA_LAST      1: the last pass, which writes the distance found, never
 *                 above the voxel's own initial value (its frame distance,
 *                 with padding), to `out` instead of seeds to `dst`.
 *   JFA_WIDE      1: neighbour offsets need 64 bits (huge z-planes). */
#include "sdf_common.h"
#include "chunk_padding.h"

#ifndef JFA_STEP
#error "JFA_STEP: the pass's step"
#endif
#ifndef JFA_WEIGHTED
#define JFA_WEIGHTED 1
#endif
#ifndef JFA_FIRST
#define JFA_FIRST 0
#endif
#ifndef JFA_LAST
#define JFA_LAST 0
#endif
#ifndef JFA_WIDE
#define JFA_WIDE 0
#endif
#define STEP JFA_STEP

#if JFA_WIDE
typedef long jfa_offset;
#else
typedef int jfa_offset;
#endif

#define SEED_MASK 1023u
#define SEED_BIAS 512
#define SEED_SELF (512u | 512u << 10 | 512u << 20)
#define SEED_NONE (895u | 895u << 10 | 895u << 20)
#define RANK_BITS 5u  /* ranks 0 (the own seed) to 27 */
#define RANK_MASK 31u

/* What adding (dx, dy, dz) to an offset adds to its packed form. */
inline int seed_shift(int dx, int dy, int dz)
{
    return dx + dy * 1024 + dz * 1048576;
}

/* The length of seed v moved by (dx, dy, dz): its Manhattan distance from the voxel there. */
inline uint moved_length(uint v, int dx, int dy, int dz)
{
    return (uint)(abs((int)(v & SEED_MASK) + (dx - SEED_BIAS)) + abs((int)((v >> 10) & SEED_MASK) + (dy - SEED_BIAS))
                  + abs((int)(v >> 20) + (dz - SEED_BIAS)));
}

/* The weight of the seed at offset s from voxel i. */
inline uint seed_weight(__global const uchar *work, size_t i, uint s, int4 w_n)
{
    const long ox = (int)(s & SEED_MASK) - SEED_BIAS, oy = (int)((s >> 10) & SEED_MASK) - SEED_BIAS,
               oz = (int)(s >> 20) - SEED_BIAS;
    return work[(long)i + ox + (oy + oz * w_n.y) * w_n.x];
}

inline int is_seed(uint w, int cap, int chunk)
{
    /* With padding only solids are seeds: frame distances are not voxels of the chunk. */
    return chunk > 0 ? w == 0u : w < (uint)cap;
}

#define NEIGHBOUR_DX(k) ((k) % 3 - 1)
#define NEIGHBOUR_DY(k) ((k) / 3 % 3 - 1)
#define NEIGHBOUR_DZ(k) ((k) / 9 - 1)

/* One voxel per work-item. */
__kernel void jfa_seed_pass(__global const uchar *restrict work, __global const uint *restrict src,
                            __global uint *restrict dst, __global uchar *restrict out,
                            int4 w_n, int cap, int chunk)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= w_n.x || y >= w_n.y || z >= w_n.z)
        return;
    const size_t i = box_index(x, y, z, w_n);
#if JFA_FIRST
    const uint own = work[i];
    uint best = is_seed(own, cap, chunk) ? SEED_SELF : SEED_NONE;
    uint best_cost = best == SEED_SELF ? own : (uint)cap;
#else
    uint best = src[i];
    uint best_cost = min(moved_length(best, 0, 0, 0), (uint)cap);
    if (JFA_WEIGHTED && best_cost < (uint)cap)
        best_cost += seed_weight(work, i, best, w_n);
#endif
    /* Below 2 nothing can win: a cost of 0 is a solid, which is its own seed. */
    if (best_cost > 1u) {
        const int c[3] = {x - STEP, x, x + STEP}, r[3] = {y - STEP, y, y + STEP}, p[3] = {z - STEP, z, z + STEP};
        int in_x[3], in_y[3], in_z[3];
        for (int k = 0; k < 3; ++k) {
            in_x[k] = c[k] >= 0 && c[k] < w_n.x && same_chunk(x, c[k], chunk);
            in_y[k] = r[k] >= 0 && r[k] < w_n.y && same_chunk(y, r[k], chunk);
            in_z[k] = p[k] >= 0 && p[k] < w_n.z && same_chunk(z, p[k], chunk);
        }
        const jfa_offset row = (jfa_offset)STEP * w_n.x, plane = row * w_n.y;
#if JFA_FIRST || !JFA_WEIGHTED
        /* The cheapest key: cost above rank. */
        uint key = best_cost << RANK_BITS;
#pragma unroll
        for (int k = 0; k < 27; ++k) {
            if (k == 13)
                continue;
            const int dx = NEIGHBOUR_DX(k), dy = NEIGHBOUR_DY(k), dz = NEIGHBOUR_DZ(k);
            const int in = in_x[dx + 1] && in_y[dy + 1] && in_z[dz + 1];
            const jfa_offset at = dz * plane + dy * row + dx * STEP;
#if JFA_FIRST
            /* The neighbour's seed is the neighbour itself, STEP * |d| away. */
            const uint w = in ? work[i + at] : (uint)cap;
            const uint cost = (uint)((abs(dx) + abs(dy) + abs(dz)) * STEP) + (JFA_WEIGHTED ? w : 0u);
            if (is_seed(w, cap, chunk))
                key = min(key, cost << RANK_BITS | (uint)(k + 1));
#else
            const uint v = in ? src[i + at] : SEED_NONE;
            key = min(key, moved_length(v, dx * STEP, dy * STEP, dz * STEP) << RANK_BITS | (uint)(k + 1));
#endif
        }
        best_cost = key >> RANK_BITS;
#if !JFA_LAST
        if ((key & RANK_MASK) != 0u) {  /* a neighbour's seed won: take it again */
            const int k = (int)(key & RANK_MASK) - 1;
            const int dx = NEIGHBOUR_DX(k), dy = NEIGHBOUR_DY(k), dz = NEIGHBOUR_DZ(k);
#if JFA_FIRST
            best = SEED_SELF + (uint)seed_shift(dx * STEP, dy * STEP, dz * STEP);
#else
            best = src[i + (dz * plane + dy * row + dx * STEP)] + (uint)seed_shift(dx * STEP, dy * STEP, dz * STEP);
#endif
        }
#endif
#else
        /* Weighted: a candidate's weight is read only where its length alone could win. */
#pragma unroll
        for (int k = 0; k < 27; ++k) {
            if (k == 13)
                continue;
            const int dx = NEIGHBOUR_DX(k), dy = NEIGHBOUR_DY(k), dz = NEIGHBOUR_DZ(k);
            const int in = in_x[dx + 1] && in_y[dy + 1] && in_z[dz + 1];
            const uint v = in ? src[i + (dz * plane + dy * row + dx * STEP)] : SEED_NONE;
            const uint length = moved_length(v, dx * STEP, dy * STEP, dz * STEP);
            if (length < best_cost) {  /* weights are never negative */
                const uint s = v + (uint)seed_shift(dx * STEP, dy * STEP, dz * STEP);
                const uint cost = length + seed_weight(work, i, s, w_n);
                if (cost < best_cost) {
                    best_cost = cost;
                    best = s;
                }
            }
        }
#endif
    }
#if JFA_LAST
    out[i] = (uchar)min((uint)work[i], best_cost);
#else
    dst[i] = best;
#endif
}

#if !JFA_WEIGHTED
/* Four voxels along x per work-item (x from 4 * global id 0), for a box whose
 * x side is a multiple of 4: each row of neighbours is read as three aligned
 * 4-vectors, at -STEP, 0 and +STEP when STEP is a multiple of 4, else at -4,
 * 0 and +4 (the x-neighbours of the four lie there). Weight 0 only. The
 * vectors are read and written through vector pointers, which promise the
 * alignment (x and the x side are multiples of 4), so each is one access. */
#define SEEDS4(p) (*(__global const uint4 *)(p))
#define BYTES4(p) (*(__global const uchar4 *)(p))

/* Element `lane` (0..3) of vector L, M or R (seg -1, 0, 1); constants after unrolling. */
#define LANE(V, lane) ((lane) == 0 ? (V).s0 : (lane) == 1 ? (V).s1 : (lane) == 2 ? (V).s2 : (V).s3)
#define PICK(L, M, R, seg, lane) ((seg) < 0 ? LANE(L, lane) : (seg) == 0 ? LANE(M, lane) : LANE(R, lane))
#define SEG_STRIDE (STEP >= 4 ? STEP : 4)
/* Where voxel j's neighbour dx steps away lies: segment and lane. */
#define SEG_OF(j, dx) (STEP >= 4 ? (dx) : ((j) + (dx) * STEP + 4) / 4 - 1)
#define LANE_OF(j, dx) (STEP >= 4 ? (j) : ((j) + (dx) * STEP + 4) % 4)

__kernel void jfa_seed_pass4(__global const uchar *restrict work, __global const uint *restrict src,
                             __global uint *restrict dst, __global uchar *restrict out,
                             int4 w_n, int cap, int chunk)
{
    const int x = 4 * (int)get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= w_n.x || y >= w_n.y || z >= w_n.z)
        return;
    const size_t i = box_index(x, y, z, w_n);
    uint key[4];
#if JFA_FIRST
    const uchar4 own = BYTES4(work + i);
    const uint own_w[4] = {own.s0, own.s1, own.s2, own.s3};
    for (int j = 0; j < 4; ++j)
        key[j] = (is_seed(own_w[j], cap, chunk) ? 0u : (uint)cap) << RANK_BITS;
#else
    const uint4 own = SEEDS4(src + i);
    const uint own_s[4] = {own.s0, own.s1, own.s2, own.s3};
    for (int j = 0; j < 4; ++j)
        key[j] = min(moved_length(own_s[j], 0, 0, 0), (uint)cap) << RANK_BITS;
#endif
    const jfa_offset row = (jfa_offset)STEP * w_n.x, plane = row * w_n.y;
    if (max(max(key[0], key[1]), max(key[2], key[3])) > (1u << RANK_BITS)) {
        const int c[3] = {x - SEG_STRIDE, x, x + SEG_STRIDE};
        const int r[3] = {y - STEP, y, y + STEP}, p[3] = {z - STEP, z, z + STEP};
        int in_x[3], in_y[3], in_z[3];
        for (int k = 0; k < 3; ++k) {
            in_x[k] = c[k] >= 0 && c[k] < w_n.x && same_chunk(x, c[k], chunk);
            in_y[k] = r[k] >= 0 && r[k] < w_n.y && same_chunk(y, r[k], chunk);
            in_z[k] = p[k] >= 0 && p[k] < w_n.z && same_chunk(z, p[k], chunk);
        }
#pragma unroll
        for (int rz = 0; rz < 3; ++rz) {
#pragma unroll
            for (int ry = 0; ry < 3; ++ry) {
                const int in = in_y[ry] && in_z[rz];
                const jfa_offset at = (rz - 1) * plane + (ry - 1) * row;
#if JFA_FIRST
                const uint4 none = (uint4)(cap);
                const uint4 L = in && in_x[0] ? convert_uint4(BYTES4(work + i + at - SEG_STRIDE)) : none;
                const uint4 M = in ? convert_uint4(BYTES4(work + i + at)) : none;
                const uint4 R = in && in_x[2] ? convert_uint4(BYTES4(work + i + at + SEG_STRIDE)) : none;
#else
                const uint4 none = (uint4)(SEED_NONE);
                const uint4 L = in && in_x[0] ? SEEDS4(src + i + at - SEG_STRIDE) : none;
                const uint4 M = in ? SEEDS4(src + i + at) : none;
                const uint4 R = in && in_x[2] ? SEEDS4(src + i + at + SEG_STRIDE) : none;
#endif
#pragma unroll
                for (int dx = -1; dx <= 1; ++dx) {
                    const int k = rz * 9 + ry * 3 + dx + 1;
                    if (k == 13)
                        continue;
#pragma unroll
                    for (int j = 0; j < 4; ++j) {
                        const uint v = PICK(L, M, R, SEG_OF(j, dx), LANE_OF(j, dx));
#if JFA_FIRST
                        const uint cost = (uint)((abs(dx) + abs(ry - 1) + abs(rz - 1)) * STEP);
                        if (is_seed(v, cap, chunk))
                            key[j] = min(key[j], cost << RANK_BITS | (uint)(k + 1));
#else
                        key[j] = min(key[j], moved_length(v, dx * STEP, (ry - 1) * STEP, (rz - 1) * STEP) << RANK_BITS
                                                 | (uint)(k + 1));
#endif
                    }
                }
            }
        }
    }
#if JFA_LAST
    const uint4 w = convert_uint4(BYTES4(work + i));
    *(__global uchar4 *)(out + i) = convert_uchar4(min(w, (uint4)(key[0], key[1], key[2], key[3]) >> RANK_BITS));
#else
    uint best[4];
    for (int j = 0; j < 4; ++j) {
#if JFA_FIRST
        best[j] = key[j] >> RANK_BITS < (uint)cap ? SEED_SELF : SEED_NONE;
#else
        best[j] = own_s[j];
#endif
        if ((key[j] & RANK_MASK) != 0u) {  /* a neighbour's seed won: take it again */
            const int k = (int)(key[j] & RANK_MASK) - 1;
            const int dx = NEIGHBOUR_DX(k), dy = NEIGHBOUR_DY(k), dz = NEIGHBOUR_DZ(k);
            const uint shift = (uint)seed_shift(dx * STEP, dy * STEP, dz * STEP);
#if JFA_FIRST
            best[j] = SEED_SELF + shift;
#else
            best[j] = src[i + j + (dz * plane + dy * row + dx * STEP)] + shift;
#endif
        }
    }
    *(__global uint4 *)(dst + i) = (uint4)(best[0], best[1], best[2], best[3]);
#endif
}
#endif
