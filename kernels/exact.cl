/* Exact Manhattan distance transform by separable min-plus passes.
 *
 * The L1 distance transform of an initial distance f is
 *   D(p) = min_q f(q) + |px-qx| + |py-qy| + |pz-qz|,
 * and because the L1 kernel is a sum of 1-D kernels it factors into three 1-D
 * transforms, one per axis (Meijster et al. 2000; Felzenszwalb & Huttenlocher
 * 2012). Along one line the 1-D transform with kernel |i-j| is exactly a forward
 * sweep d[i] = min(d[i], d[i-1] + 1) followed by a backward sweep.
 *
 * One work-item holds SEG consecutive elements of a line in registers. The
 * sweeps run locally, then carries between the segments of a line are combined
 * through local memory: a segment's incoming forward value is
 *   min_j<s (end_j + (s-1-j) * SEG)
 * and likewise from the right. Each pass reads its input once and writes its
 * output once:
 *   pass_x   voxels (+ the seed shell from the field) -> work
 *   pass_yz  work -> work (AXIS 1), work + voxels -> packed field over R (AXIS 2)
 * Distances travel as uchar capped at the world's cap (a value of cap means
 * "at least cap", which keeps min-plus exact for the capped result) and are
 * swept as 32-bit ints.
 *
 * Layout: the work box's x-origin and x-extent are multiples of 8 (the host
 * aligns them), so uchar8 accesses along x and VEC-wide accesses across
 * x-lanes are aligned in both the work box and the world arrays; they are
 * written as vector pointer accesses because vloadn promises only byte
 * alignment and compiles to byte loads.
 * One program holds one pass: pass_yz when VEC is defined, else pass_x.
 * Build options: SEG (elements per work-item), AXIS (pass_yz: 1 = y, 2 = z),
 * VEC (pass_yz: x-columns per work-item, 2 or 4), LOCAL_X, LOCAL_Y (the
 * work-group: pass_x (segments, lines); pass_yz (x-lanes, segments)).
 */
#include "sdf_common.h"

/* Larger than any distance plus any line length. */
#define BIG 0x3fff

/* The host compiles each pass for its exact work-group shape, which lets the
 * compiler budget registers for full work-groups instead of guessing. */
#define GROUP_SHAPE __attribute__((reqd_work_group_size(LOCAL_X, LOCAL_Y, 1)))

/* Forward and backward sweeps of one segment, with the carries between the
 * segments of a line passed through local memory; NSEG (segments per line) is
 * a compile-time constant so the carry loops unroll and their local reads
 * overlap. T is int or an int vector: native
 * 32-bit min and add (saturating byte arithmetic costs several instructions a
 * step on NVIDIA, and this kernel is bound by instruction issue, not bytes). */
#define SWEEP_SEGMENT(T, d, seg_end, seg, nseg)                                        \
    do {                                                                               \
        T run_ = (T)(BIG);                                                             \
        _Pragma("unroll") for (int k = 0; k < SEG; ++k) {                              \
            run_ = min(d[k], run_ + 1);                                                \
            d[k] = run_;                                                               \
        }                                                                              \
        seg_end[seg] = run_;                                                           \
        barrier(CLK_LOCAL_MEM_FENCE);                                                  \
        T carry_ = (T)(BIG);                                                           \
        _Pragma("unroll") for (int j = 0; j < NSEG - 1; ++j)                           \
            if (j < seg)                                                               \
                carry_ = min(carry_, seg_end[j] + (seg - 1 - j) * SEG);                \
        barrier(CLK_LOCAL_MEM_FENCE);                                                  \
        run_ = (T)(BIG);                                                               \
        carry_ += 1;                                                                   \
        _Pragma("unroll") for (int k = SEG - 1; k >= 0; --k) {                         \
            run_ = min(min(d[k], carry_ + k), run_ + 1);                               \
            d[k] = run_;                                                               \
        }                                                                              \
        seg_end[seg] = run_;                                                           \
        barrier(CLK_LOCAL_MEM_FENCE);                                                  \
        carry_ = (T)(BIG);                                                             \
        _Pragma("unroll") for (int j = 1; j < NSEG; ++j)                               \
            if (j > seg)                                                               \
                carry_ = min(carry_, seg_end[j] + (j - seg - 1) * SEG);                \
        carry_ += SEG;                                                                 \
        _Pragma("unroll") for (int k = 0; k < SEG; ++k)                                \
            d[k] = min(d[k], carry_ - k);                                              \
    } while (0)

#define INIT_OF(v) ((v) ? 0 : cap)
#define UNPACK8(d, c, v)                                                               \
    do {                                                                               \
        d[c] = INIT_OF(v.s0); d[c + 1] = INIT_OF(v.s1); d[c + 2] = INIT_OF(v.s2);      \
        d[c + 3] = INIT_OF(v.s3); d[c + 4] = INIT_OF(v.s4); d[c + 5] = INIT_OF(v.s5);  \
        d[c + 6] = INIT_OF(v.s6); d[c + 7] = INIT_OF(v.s7);                            \
    } while (0)
#define PACK8(d, c) convert_uchar8(min((int8)(d[c], d[c + 1], d[c + 2], d[c + 3],           \
                                              d[c + 4], d[c + 5], d[c + 6], d[c + 7]), (int8)(cap)))

#ifndef VEC
#define NSEG LOCAL_X
/* x: lines are contiguous; each work-item loads SEG bytes as uchar8 vectors. */
__kernel GROUP_SHAPE void pass_x(__global uchar *work, __global const uchar *voxels,
                     __global const ushort *field, int4 dims, int4 w_lo, int4 w_n,
                     int4 r_lo, int4 r_hi, int seeded, int cap, int nseg)
{
    __local int ends[LOCAL_X * LOCAL_Y];
    const int seg = get_local_id(0);
    __local int *seg_end = ends + get_local_id(1) * nseg;
    const int line = get_global_id(1);
    const int valid = line < w_n.y * w_n.z;
    const int ly = valid ? line % w_n.y : 0, lz = valid ? line / w_n.y : 0;
    const int wy = w_lo.y + ly, wz = w_lo.z + lz;
    const size_t world_row = world_index(w_lo.x, wy, wz, dims);
    const size_t work_row = box_index(0, ly, lz, w_n);
    /* A seed-shell line (outside R in y or z) takes every distance from the field. */
    const int line_in_r = wy >= r_lo.y && wy < r_hi.y && wz >= r_lo.z && wz < r_hi.z;
    const int t0 = seg * SEG;

    int d[SEG];
    _Pragma("unroll") for (int c = 0; c < SEG; c += 8) {
        const int t = t0 + c;
        if (valid && t < w_n.x) {
            const uchar8 v = *(__global const uchar8 *)(voxels + world_row + t);
            UNPACK8(d, c, v);
            const int wx = w_lo.x + t;
            if (seeded && (!line_in_r || wx < r_lo.x || wx + 8 > r_hi.x)) {
                /* The seed shell: rare, so plain scalar reads. */
                _Pragma("unroll") for (int k = 0; k < 8; ++k) {
                    const int x = wx + k;
                    if (!line_in_r || x < r_lo.x || x >= r_hi.x)
                        d[c + k] = min((int)(field[world_row + t + k] >> 8), cap);
                }
            }
        } else {
            _Pragma("unroll") for (int k = 0; k < 8; ++k)
                d[c + k] = BIG;
        }
    }

    SWEEP_SEGMENT(int, d, seg_end, seg, nseg);

    _Pragma("unroll") for (int c = 0; c < SEG; c += 8) {
        const int t = t0 + c;
        if (valid && t < w_n.x)
            *(__global uchar8 *)(work + work_row + t) = PACK8(d, c);
    }
}

#else
#define NSEG LOCAL_Y
/* y or z: each work-item sweeps VEC adjacent x-columns (VEC = 2 or 4), so a
 * warp touches 32 * VEC contiguous bytes of a row. */
#define CAT_(a, b) a##b
#define CAT(a, b) CAT_(a, b)
#define intV CAT(int, VEC)
#define ucharV CAT(uchar, VEC)
#define ushortV CAT(ushort, VEC)
#define convert_intV CAT(convert_int, VEC)
#define convert_ucharV CAT(convert_uchar, VEC)
#define convert_ushortV CAT(convert_ushort, VEC)

__kernel GROUP_SHAPE void pass_yz(__global uchar *work, __global const uchar *voxels,
                      __global ushort *field, int4 dims, int4 w_lo, int4 w_n,
                      int4 r_lo, int4 r_hi, int seeded, int cap, int nseg)
{
    __local intV ends[LOCAL_X * LOCAL_Y];
    const int seg = get_local_id(1);
    __local intV *seg_end = ends + get_local_id(0) * nseg;
    const int lx = get_global_id(0) * VEC;
    const int valid = lx < w_n.x;
#if AXIS == 1
    const int ly = 0, lz = get_group_id(1);
    const int len = w_n.y;
    const size_t stride = (size_t)w_n.x;
#else
    const int ly = get_group_id(1), lz = 0;
    const int len = w_n.z;
    const size_t stride = (size_t)w_n.x * (size_t)w_n.y;
#endif
    const size_t base = box_index(lx, ly, lz, w_n);
    const int t0 = seg * SEG;

    intV d[SEG];
    _Pragma("unroll") for (int k = 0; k < SEG; ++k) {
        const int t = t0 + k;
        d[k] = (valid && t < len) ? convert_intV(*(__global const ucharV *)(work + base + (size_t)t * stride))
                                  : (intV)(BIG);
    }

    SWEEP_SEGMENT(intV, d, seg_end, seg, nseg);

    const intV capv = (intV)(cap);
    _Pragma("unroll") for (int k = 0; k < SEG; ++k) {
        const int t = t0 + k;
        if (!valid || t >= len)
            continue;
        const intV out = min(d[k], capv);
#if AXIS == 2
        /* x-lanes are VEC-aligned and R's x-bounds are multiples of 8: a lane is all in or all out. */
        const int wx = w_lo.x + lx, wy = w_lo.y + ly, wz = w_lo.z + t;
        if (in_box(wx, wy, wz, r_lo, r_hi)) {
            const size_t i = world_index(wx, wy, wz, dims);
            /* Only solids (distance 0) carry a colour: air-only lanes skip the voxel read. */
            const ushortV colour = any(out == (intV)(0))
                ? convert_ushortV(*(__global const ucharV *)(voxels + i)) : (ushortV)(0);
            *(__global ushortV *)(field + i) = (convert_ushortV(out) << (ushort)8) | colour;
        }
#else
        *(__global ucharV *)(work + base + (size_t)t * stride) = convert_ucharV(out);
#endif
    }
}
#endif
