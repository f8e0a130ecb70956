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
 *   JFA_WIDE      1: neighbour offsets need 64 bits (huge z-planes).
 *   JFA_BX, JFA_BY, JFA_BZ  jfa_seed_pass4's block: groups of four voxels a
 *                 work-item takes along x, y and z (1 or 2 each; below). */
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
/* Groups of four voxels along x per work-item, for a box whose x side is a
 * multiple of 4. A group's x-neighbours lie in three aligned 4-vectors of a
 * row, at -STEP, 0 and +STEP when STEP is a multiple of 4, else at -4, 0 and
 * +4: segments SEG_STRIDE apart. A work-item takes JFA_BX groups along x
 * (SEG_STRIDE apart) and JFA_BY, JFA_BZ voxels along y and z (STEP apart),
 * 1 or 2 each: along an axis whose items are a stride t apart, item j starts
 * at j / t * 2t + j % t and its second voxel t further, where the box has it.
 * Each segment of each row of neighbours is read once for every voxel that
 * sees it (a block of 2 x 2 x 2 groups reads 4 x 4 x 4 vectors for 32
 * voxels, one group 3 x 3 x 3 for 4). Every voxel is offered the same
 * candidates as one voxel an item, ranked alike, and the best is the
 * smallest key, so the order rows are read in does not change the winner.
 * With padding a block must lie in one chunk (the chunk a multiple of twice
 * each stride): a row is then in a voxel's chunk when it is in the block's.
 * Weight 0 only. The vectors are read and written through vector pointers,
 * which promise the alignment (x and the x side are multiples of 4), so each
 * is one access. */
#ifndef JFA_BX
#define JFA_BX 1
#endif
#ifndef JFA_BY
#define JFA_BY 1
#endif
#ifndef JFA_BZ
#define JFA_BZ 1
#endif
#define BX JFA_BX
#define BY JFA_BY
#define BZ JFA_BZ
#if (BX != 1 && BX != 2) || (BY != 1 && BY != 2) || (BZ != 1 && BZ != 2) || (STEP == 0 && BX * BY * BZ != 1)
#error "JFA_BX, JFA_BY, JFA_BZ: 1 or 2 an item, 1 with no step"
#endif
#define SEEDS4(p) (*(__global const uint4 *)(p))
#define BYTES4(p) (*(__global const uchar4 *)(p))

/* Element `lane` (0..3) of vector V; a constant after unrolling. */
#define LANE(V, lane) ((lane) == 0 ? (V).s0 : (lane) == 1 ? (V).s1 : (lane) == 2 ? (V).s2 : (V).s3)
#define SEG_STRIDE (STEP >= 4 ? STEP : 4)
/* Where voxel j's neighbour dx steps away lies: segment (-1, 0, 1 from its group's) and lane. */
#define SEG_OF(j, dx) (STEP >= 4 ? (dx) : ((j) + (dx) * STEP + 4) / 4 - 1)
#define LANE_OF(j, dx) (STEP >= 4 ? (j) : ((j) + (dx) * STEP + 4) % 4)
/* The first of work-item j's voxels along an axis of stride t with b an item. */
#define BLOCK_FIRST(j, t, b) ((b) == 2 ? (j) / (t) * (2 * (t)) + (j) % (t) : (j))

__kernel void jfa_seed_pass4(__global const uchar *restrict work, __global const uint *restrict src,
                             __global uint *restrict dst, __global uchar *restrict out,
                             int4 w_n, int cap, int chunk)
{
    const int x = 4 * BLOCK_FIRST((int)get_global_id(0), SEG_STRIDE / 4, BX);
    const int y = BLOCK_FIRST((int)get_global_id(1), STEP, BY), z = BLOCK_FIRST((int)get_global_id(2), STEP, BZ);
    if (x >= w_n.x || y >= w_n.y || z >= w_n.z)
        return;
    const size_t i = box_index(x, y, z, w_n);
    const jfa_offset row = (jfa_offset)STEP * w_n.x, plane = row * w_n.y;
    /* Segments x + (r - 1) * SEG_STRIDE, rows y + (r - 1) * STEP and planes z + (r - 1) * STEP: in the
     * box and the block's chunk. Group (bx, by, bz) is in the box when its own are. */
    int in_x[BX + 2], in_y[BY + 2], in_z[BZ + 2];
    for (int r = 0; r < BX + 2; ++r) {
        const int at = x + (r - 1) * SEG_STRIDE;
        in_x[r] = at >= 0 && at < w_n.x && same_chunk(x, at, chunk);
    }
    for (int r = 0; r < BY + 2; ++r) {
        const int at = y + (r - 1) * STEP;
        in_y[r] = at >= 0 && at < w_n.y && same_chunk(y, at, chunk);
    }
    for (int r = 0; r < BZ + 2; ++r) {
        const int at = z + (r - 1) * STEP;
        in_z[r] = at >= 0 && at < w_n.z && same_chunk(z, at, chunk);
    }
    /* Each group's keys from its own seeds (or on the first pass its initial distances); a group
     * outside the box keeps keys 0, which nothing replaces, and is never written. */
    uint key[BZ][BY][BX][4];
    uint most = 0u;
#pragma unroll
    for (int bz = 0; bz < BZ; ++bz) {
#pragma unroll
        for (int by = 0; by < BY; ++by) {
#pragma unroll
            for (int bx = 0; bx < BX; ++bx) {
                const int mine = in_x[bx + 1] && in_y[by + 1] && in_z[bz + 1];
                const jfa_offset at = bz * plane + by * row + bx * SEG_STRIDE;
#if JFA_FIRST
                const uint4 own = mine ? convert_uint4(BYTES4(work + i + at)) : (uint4)(cap);
#else
                const uint4 own = mine ? SEEDS4(src + i + at) : (uint4)(SEED_NONE);
#endif
#pragma unroll
                for (int j = 0; j < 4; ++j) {
#if JFA_FIRST
                    const uint cost = is_seed(LANE(own, j), cap, chunk) ? 0u : (uint)cap;
#else
                    const uint cost = min(moved_length(LANE(own, j), 0, 0, 0), (uint)cap);
#endif
                    key[bz][by][bx][j] = mine ? cost << RANK_BITS : 0u;
                    most = max(most, key[bz][by][bx][j]);
                }
            }
        }
    }
    if (most > (1u << RANK_BITS)) {
#pragma unroll
        for (int rz = 0; rz < BZ + 2; ++rz) {
#pragma unroll
            for (int ry = 0; ry < BY + 2; ++ry) {
                const int in = in_y[ry] && in_z[rz];
                const jfa_offset at = (rz - 1) * plane + (ry - 1) * row;
                uint4 seg[BX + 2];
#pragma unroll
                for (int sx = 0; sx < BX + 2; ++sx) {
                    const jfa_offset a = at + (sx - 1) * SEG_STRIDE;
#if JFA_FIRST
                    seg[sx] = in && in_x[sx] ? convert_uint4(BYTES4(work + i + a)) : (uint4)(cap);
#else
                    seg[sx] = in && in_x[sx] ? SEEDS4(src + i + a) : (uint4)(SEED_NONE);
#endif
                }
#pragma unroll
                for (int bz = 0; bz < BZ; ++bz) {
                    const int dz = rz - 1 - bz;
                    if (dz < -1 || dz > 1)
                        continue;
#pragma unroll
                    for (int by = 0; by < BY; ++by) {
                        const int dy = ry - 1 - by;
                        if (dy < -1 || dy > 1)
                            continue;
#pragma unroll
                        for (int bx = 0; bx < BX; ++bx) {
#pragma unroll
                            for (int dx = -1; dx <= 1; ++dx) {
                                const int k = (dz + 1) * 9 + (dy + 1) * 3 + dx + 1;
                                if (k == 13)
                                    continue;
#pragma unroll
                                for (int j = 0; j < 4; ++j) {
                                    const uint v = LANE(seg[bx + 1 + SEG_OF(j, dx)], LANE_OF(j, dx));
#if JFA_FIRST
                                    const uint cost = (uint)((abs(dx) + abs(dy) + abs(dz)) * STEP);
                                    if (is_seed(v, cap, chunk))
                                        key[bz][by][bx][j] = min(key[bz][by][bx][j],
                                                                 cost << RANK_BITS | (uint)(k + 1));
#else
                                    key[bz][by][bx][j] = min(key[bz][by][bx][j],
                                                             moved_length(v, dx * STEP, dy * STEP, dz * STEP) << RANK_BITS
                                                                 | (uint)(k + 1));
#endif
                                }
                            }
                        }
                    }
                }
            }
        }
    }
#pragma unroll
    for (int bz = 0; bz < BZ; ++bz) {
#pragma unroll
        for (int by = 0; by < BY; ++by) {
#pragma unroll
            for (int bx = 0; bx < BX; ++bx) {
                if (!(in_x[bx + 1] && in_y[by + 1] && in_z[bz + 1]))
                    continue;
                const size_t iv = i + (bz * plane + by * row + bx * SEG_STRIDE);
                const uint *mine = key[bz][by][bx];
#if JFA_LAST
                const uint4 w = convert_uint4(BYTES4(work + iv));
                const uint4 found = (uint4)(mine[0], mine[1], mine[2], mine[3]) >> RANK_BITS;
                *(__global uchar4 *)(out + iv) = convert_uchar4(min(w, found));
#else
                /* The winner's seed, read again (keeping every group's own seeds in registers costs
                 * more than the reads): its neighbour's moved by the neighbour's offset, or with rank 0
                 * (k 13, no offset) the voxel's own. */
                uint best[4];
#pragma unroll
                for (int j = 0; j < 4; ++j) {
                    const uint rank = mine[j] & RANK_MASK;
                    const int k = rank != 0u ? (int)rank - 1 : 13;
                    const int dx = NEIGHBOUR_DX(k), dy = NEIGHBOUR_DY(k), dz = NEIGHBOUR_DZ(k);
                    const uint shift = (uint)seed_shift(dx * STEP, dy * STEP, dz * STEP);
#if JFA_FIRST
                    best[j] = mine[j] >> RANK_BITS < (uint)cap ? SEED_SELF + shift : SEED_NONE;
#else
                    best[j] = src[iv + j + (dz * plane + dy * row + dx * STEP)] + shift;
#endif
                }
                *(__global uint4 *)(dst + iv) = (uint4)(best[0], best[1], best[2], best[3]);
#endif
            }
        }
    }
}
#endif
