/* Min-plus sweeps of lines held in registers, shared by the exact transform's passes
 * (kernels/exact.cl, kernels/exact_xz.cl): distances in 16-bit lanes of 32-bit words, segments of a
 * line combined through local memory, and a stacked run's slot lookup.
 * Build options used here: SEG, LOCAL_X, LOCAL_Y, NSEG (set by the including pass), VEC (x-columns
 * per work-item, 2, 4 or 8, where a pass sweeps across x-columns), SDF_PTX_16X2. */
#ifndef MIN_PLUS_LINES_H
#define MIN_PLUS_LINES_H

#include "sdf_common.h"

/* Larger than any distance plus any line length. */
#define BIG 0x3fff
/* One in each 16-bit lane of a word. */
#define ONES 0x00010001u
#define BIG2 (BIG * ONES)

#if SDF_PTX_16X2
inline uint min_u16x2(uint a, uint b)
{
    uint r;
    asm("min.u16x2 %0, %1, %2;" : "=r"(r) : "r"(a), "r"(b));
    return r;
}
#else
inline uint min_u16x2(uint a, uint b) { return as_uint(min(as_ushort2(a), as_ushort2(b))); }
#endif
inline uint2 min_u16x2_v2(uint2 a, uint2 b) { return (uint2)(min_u16x2(a.x, b.x), min_u16x2(a.y, b.y)); }
inline uint4 min_u16x2_v4(uint4 a, uint4 b) { return (uint4)(min_u16x2_v2(a.lo, b.lo), min_u16x2_v2(a.hi, b.hi)); }

/* The host compiles each pass for its exact work-group shape, which lets the
 * compiler budget registers for full work-groups instead of guessing. */
#define GROUP_SHAPE __attribute__((reqd_work_group_size(LOCAL_X, LOCAL_Y, 1)))

/* A stacked run transforms whole worlds of one slot pool in one launch (exact.py, run_slots):
 * `slots` is a mask of the pool's slots it covers (slot s is bit s % 32 of lane s / 32), the
 * launch's third dimension picks the k-th of them in order, and that slot's world and work box
 * lie that many strides further on (voxel_stride voxels, work_stride bytes); the rest of the pass
 * sees one world. The mask is passed by value (a pool has at most 256 slots), so a run that
 * repeats sets no argument; a run of one world passes zeros. */
inline size_t kth_slot(int8 slots, int k)
{
    int lanes[8];
    vstore8(slots, 0, lanes);
    for (int lane = 0; lane < 8; ++lane) {
        uint bits = (uint)lanes[lane];
        const int count = popcount(bits);
        if (k < count) {
            for (int j = 0; j < k; ++j)
                bits &= bits - 1u;  /* drop the lowest set bit */
            return (size_t)(32 * lane + 31 - clz(bits & (0u - bits)));
        }
        k -= count;
    }
    return 0;
}

#define SLOT_PROLOGUE                                                           \
    do {                                                                        \
        const size_t slot_ = kth_slot(slots, get_group_id(2));                  \
        work += slot_ * (size_t)work_stride;                                    \
        voxels += slot_ * (size_t)voxel_stride;                                 \
        field += slot_ * (size_t)voxel_stride;                                  \
    } while (0)

/* The 1-D transform of one line cut into NSEG segments of SEG elements, one
 * segment per work-item. Each segment first sweeps forward and backward on its
 * own; then its last element holds its best offer to the segments on its right
 * (min over its elements of value + distance to its end) and its first element
 * its offer to the left. A segment's carry from the left is the minimum over the
 * segments before it of their offer plus the distance between them; shifting
 * each offer by its distance to the line's end turns that into a plain prefix
 * minimum, scanned in log2(NSEG) steps through local memory (ping-pong buffers,
 * one barrier a step), and likewise a suffix minimum from the right. NSEG is a
 * compile-time constant so the steps unroll. T is a word type of 16-bit lane
 * pairs, MIN its lane-wise min; scan points at 4 * NSEG words of this line's
 * local memory (two buffers per direction). */
#define SWEEP_SEGMENT(T, MIN, d, scan, seg)                                            \
    do {                                                                               \
        T run_ = (T)(BIG2);                                                            \
        _Pragma("unroll") for (int k = 0; k < SEG; ++k) {                              \
            run_ = MIN(d[k], run_ + ONES);                                             \
            d[k] = run_;                                                               \
        }                                                                              \
        run_ = (T)(BIG2);                                                              \
        _Pragma("unroll") for (int k = SEG - 1; k >= 0; --k) {                         \
            run_ = MIN(d[k], run_ + ONES);                                             \
            d[k] = run_;                                                               \
        }                                                                              \
        T right_offer_ = d[SEG - 1] + (uint)((NSEG - 1 - (seg)) * SEG) * ONES;         \
        T left_offer_ = d[0] + (uint)((seg) * SEG) * ONES;                             \
        __local T *fr_ = (scan), *fw_ = (scan) + NSEG;                                 \
        __local T *br_ = (scan) + 2 * NSEG, *bw_ = (scan) + 3 * NSEG;                  \
        fr_[seg] = right_offer_;                                                       \
        br_[seg] = left_offer_;                                                        \
        barrier(CLK_LOCAL_MEM_FENCE);                                                  \
        _Pragma("unroll") for (int step = 1; step < NSEG; step <<= 1) {                \
            if ((seg) >= step)                                                         \
                right_offer_ = MIN(right_offer_, fr_[(seg) - step]);                   \
            if ((seg) + step < NSEG)                                                   \
                left_offer_ = MIN(left_offer_, br_[(seg) + step]);                     \
            fw_[seg] = right_offer_;                                                   \
            bw_[seg] = left_offer_;                                                    \
            barrier(CLK_LOCAL_MEM_FENCE);                                              \
            __local T *t_ = fr_; fr_ = fw_; fw_ = t_;                                  \
            t_ = br_; br_ = bw_; bw_ = t_;                                             \
        }                                                                              \
        /* element k gets from_left + k and from_right - k (never below 1) */          \
        const T from_left_ = (seg) > 0                                                 \
            ? fr_[(seg) - 1] - (uint)((NSEG - (seg)) * SEG - 1) * ONES : (T)(BIG2);    \
        const T from_right_ = (seg) < NSEG - 1                                         \
            ? br_[(seg) + 1] - (uint)((seg) * SEG) * ONES : (T)(BIG2 + SEG * ONES);    \
        _Pragma("unroll") for (int k = 0; k < SEG; ++k)                                \
            d[k] = MIN(d[k], MIN(from_left_ + (uint)k * ONES, from_right_ - (uint)k * ONES)); \
    } while (0)

#ifdef VEC
/* Passes across x-columns: each work-item sweeps VEC adjacent x-columns, two per 32-bit word,
 * so a warp touches 32 * VEC contiguous bytes of a row. */
#define CAT_(a, b) a##b
#define CAT(a, b) CAT_(a, b)
#define ucharV CAT(uchar, VEC)
#define ushortV CAT(ushort, VEC)
#define intV CAT(int, VEC)
#define convert_ucharV CAT(convert_uchar, VEC)
#define convert_ushortV CAT(convert_ushort, VEC)
#define as_ushortV CAT(as_ushort, VEC)
#if VEC == 2
#define LANE_OFFSETS ((int2)(0, 1))
#elif VEC == 4
#define LANE_OFFSETS ((int4)(0, 1, 2, 3))
#else
#define LANE_OFFSETS ((int8)(0, 1, 2, 3, 4, 5, 6, 7))
#endif
#if VEC == 2
#define wordV uint
#define as_wordV as_uint
#define MINV min_u16x2
#elif VEC == 4
#define wordV uint2
#define as_wordV as_uint2
#define MINV min_u16x2_v2
#elif VEC == 8
#define wordV uint4
#define as_wordV as_uint4
#define MINV min_u16x2_v4
#else
#error VEC must be 2, 4 or 8
#endif
#endif

#endif
