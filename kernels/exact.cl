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
 * Distances are saturating uchar: every value >= cap means "at least cap", and
 * min-plus with saturation at 255 >= cap keeps the capped result exact.
 *
 * Layout: the work box's x-origin and x-extent are multiples of 8 (the host
 * aligns them), so uchar8 accesses along x and uchar4/ushort4 accesses across
 * x-lanes are aligned in both the work box and the world arrays; they are
 * written as vector pointer accesses because vloadn promises only byte
 * alignment and compiles to byte loads.
 * Build options: SEG (elements per work-item), AXIS (pass_yz: 1 = y, 2 = z),
 * LOCAL_X, LOCAL_Y (the work-group: pass_x (segments, lines); pass_yz (lanes of
 * 4 x-columns, segments)).
 */
#include "sdf_common.h"

#define SAT 255

/* The host compiles each pass for its exact work-group shape, which lets the
 * compiler budget registers for full work-groups instead of guessing. */
#define GROUP_SHAPE __attribute__((reqd_work_group_size(LOCAL_X, LOCAL_Y, 1)))

/* min(v, 255) as a uchar: offsets larger than any distance saturate. */
#define SAT_OFFSET(v) ((uchar)min((v), SAT))

/* Forward and backward sweeps of one segment, with the carries between the
 * segments of a line passed through local memory. T is uchar or uchar4; all
 * arithmetic is saturating uchar, so there are no conversions in the hot loops. */
#define SWEEP_SEGMENT(T, d, seg_end, seg, nseg)                                        \
    do {                                                                               \
        const T one_ = (T)(1);                                                         \
        T run_ = (T)(SAT);                                                             \
        _Pragma("unroll") for (int k = 0; k < SEG; ++k) {                              \
            run_ = min(d[k], add_sat(run_, one_));                                     \
            d[k] = run_;                                                               \
        }                                                                              \
        seg_end[seg] = run_;                                                           \
        barrier(CLK_LOCAL_MEM_FENCE);                                                  \
        T carry_ = (T)(SAT);                                                           \
        for (int j = 0; j < seg; ++j)                                                  \
            carry_ = min(carry_, add_sat(seg_end[j], (T)(SAT_OFFSET((seg - 1 - j) * SEG)))); \
        barrier(CLK_LOCAL_MEM_FENCE);                                                  \
        run_ = (T)(SAT);                                                               \
        _Pragma("unroll") for (int k = SEG - 1; k >= 0; --k) {                         \
            const T f_ = min(d[k], add_sat(carry_, (T)((uchar)(k + 1))));              \
            run_ = min(f_, add_sat(run_, one_));                                       \
            d[k] = run_;                                                               \
        }                                                                              \
        seg_end[seg] = run_;                                                           \
        barrier(CLK_LOCAL_MEM_FENCE);                                                  \
        carry_ = (T)(SAT);                                                             \
        for (int j = seg + 1; j < nseg; ++j)                                           \
            carry_ = min(carry_, add_sat(seg_end[j], (T)(SAT_OFFSET((j - seg - 1) * SEG)))); \
        _Pragma("unroll") for (int k = 0; k < SEG; ++k)                                \
            d[k] = min(d[k], add_sat(carry_, (T)((uchar)(SEG - k))));                  \
    } while (0)

#define INIT_OF(v) ((v) ? (uchar)0 : air)
#define UNPACK8(d, c, v)                                                               \
    do {                                                                               \
        d[c] = INIT_OF(v.s0); d[c + 1] = INIT_OF(v.s1); d[c + 2] = INIT_OF(v.s2);      \
        d[c + 3] = INIT_OF(v.s3); d[c + 4] = INIT_OF(v.s4); d[c + 5] = INIT_OF(v.s5);  \
        d[c + 6] = INIT_OF(v.s6); d[c + 7] = INIT_OF(v.s7);                            \
    } while (0)
#define PACK8(d, c) ((uchar8)(d[c], d[c + 1], d[c + 2], d[c + 3], d[c + 4], d[c + 5], d[c + 6], d[c + 7]))

/* x: lines are contiguous; each work-item loads SEG bytes as uchar8 vectors. */
__kernel GROUP_SHAPE void pass_x(__global uchar *work, __global const uchar *voxels,
                     __global const ushort *field, int4 dims, int4 w_lo, int4 w_n,
                     int4 r_lo, int4 r_hi, int seeded, int cap, int nseg)
{
    __local uchar ends[1024];
    const int seg = get_local_id(0);
    __local uchar *seg_end = ends + get_local_id(1) * nseg;
    const int line = get_global_id(1);
    const int valid = line < w_n.y * w_n.z;
    const int ly = valid ? line % w_n.y : 0, lz = valid ? line / w_n.y : 0;
    const int wy = w_lo.y + ly, wz = w_lo.z + lz;
    const size_t world_row = world_index(w_lo.x, wy, wz, dims);
    const size_t work_row = box_index(0, ly, lz, w_n);
    /* A seed-shell line (outside R in y or z) takes every distance from the field. */
    const int line_in_r = wy >= r_lo.y && wy < r_hi.y && wz >= r_lo.z && wz < r_hi.z;
    const uchar air = (uchar)cap;
    const int t0 = seg * SEG;

    uchar d[SEG];
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
                        d[c + k] = (uchar)min((uint)(field[world_row + t + k] >> 8), (uint)cap);
                }
            }
        } else {
            _Pragma("unroll") for (int k = 0; k < 8; ++k)
                d[c + k] = SAT;
        }
    }

    SWEEP_SEGMENT(uchar, d, seg_end, seg, nseg);

    _Pragma("unroll") for (int c = 0; c < SEG; c += 8) {
        const int t = t0 + c;
        if (valid && t < w_n.x)
            *(__global uchar8 *)(work + work_row + t) = min(PACK8(d, c), (uchar8)(air));
    }
}

/* y or z: 32 lanes of 4 adjacent x-columns, so a warp touches 128 contiguous bytes a row. */
__kernel GROUP_SHAPE void pass_yz(__global uchar *work, __global const uchar *voxels,
                      __global ushort *field, int4 dims, int4 w_lo, int4 w_n,
                      int4 r_lo, int4 r_hi, int seeded, int cap, int nseg)
{
    __local uchar4 ends[1024];
    const int seg = get_local_id(1);
    __local uchar4 *seg_end = ends + get_local_id(0) * nseg;
    const int lx = get_global_id(0) * 4;
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

    uchar4 d[SEG];
    _Pragma("unroll") for (int k = 0; k < SEG; ++k) {
        const int t = t0 + k;
        d[k] = (valid && t < len) ? *(__global const uchar4 *)(work + base + (size_t)t * stride)
                                  : (uchar4)(SAT);
    }

    SWEEP_SEGMENT(uchar4, d, seg_end, seg, nseg);

    const uchar4 capv = (uchar4)((uchar)cap);
    _Pragma("unroll") for (int k = 0; k < SEG; ++k) {
        const int t = t0 + k;
        if (!valid || t >= len)
            continue;
        const uchar4 out = min(d[k], capv);
#if AXIS == 2
        /* x-lanes are 4-aligned and R's x-bounds are multiples of 8: a lane is all in or all out. */
        const int wx = w_lo.x + lx, wy = w_lo.y + ly, wz = w_lo.z + t;
        if (in_box(wx, wy, wz, r_lo, r_hi)) {
            const size_t i = world_index(wx, wy, wz, dims);
            const ushort4 colour = convert_ushort4(*(__global const uchar4 *)(voxels + i));
            *(__global ushort4 *)(field + i) = (convert_ushort4(out) << (ushort)8) | colour;
        }
#else
        *(__global uchar4 *)(work + base + (size_t)t * stride) = out;
#endif
    }
}
