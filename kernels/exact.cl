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
 * aligns them), so uchar8 loads along x and uchar4/ushort4 accesses across
 * x-lanes are aligned in both the work box and the world arrays.
 * Build options: SEG (elements per work-item), AXIS (pass_yz: 1 = y, 2 = z).
 * Local size: pass_x (segments, lines); pass_yz (32 lanes of 4 x-columns, segments).
 */
#include "sdf_common.h"

#define LANES 32
#define SAT 255

/* Forward and backward sweeps of one segment with carries through local memory.
 * d holds the segment; seg_end is this line's slice of local memory. */
#define SWEEP_SEGMENT(T, d, seg_end, seg, nseg, ZERO, CONV)                           \
    do {                                                                              \
        T run_ = (T)(SAT);                                                            \
        _Pragma("unroll") for (int k = 0; k < SEG; ++k) {                            \
            run_ = min(d[k], add_sat(run_, (T)(1)));                                  \
            d[k] = run_;                                                              \
        }                                                                             \
        seg_end[seg] = run_;                                                          \
        barrier(CLK_LOCAL_MEM_FENCE);                                                 \
        T carry_ = (T)(SAT);                                                          \
        for (int j = 0; j < seg; ++j)                                                 \
            carry_ = min(carry_, CONV(ZERO(seg_end[j]) + (seg - 1 - j) * SEG));        \
        barrier(CLK_LOCAL_MEM_FENCE);                                                 \
        run_ = (T)(SAT);                                                              \
        _Pragma("unroll") for (int k = SEG - 1; k >= 0; --k) {                       \
            const T f_ = min(d[k], CONV(ZERO(carry_) + (k + 1)));                     \
            run_ = min(f_, add_sat(run_, (T)(1)));                                    \
            d[k] = run_;                                                              \
        }                                                                             \
        seg_end[seg] = run_;                                                          \
        barrier(CLK_LOCAL_MEM_FENCE);                                                 \
        carry_ = (T)(SAT);                                                            \
        for (int j = seg + 1; j < nseg; ++j)                                          \
            carry_ = min(carry_, CONV(ZERO(seg_end[j]) + (j - seg - 1) * SEG));        \
        _Pragma("unroll") for (int k = 0; k < SEG; ++k)                              \
            d[k] = min(d[k], CONV(ZERO(carry_) + (SEG - k)));                         \
    } while (0)

#define AS_INT(v) ((int)(v))
#define AS_INT4(v) convert_int4(v)
#define SAT_UINT(v) ((uint)min((v), SAT))
#define SAT_UCHAR4(v) convert_uchar4_sat(v)

/* Component k of an 8-vector; k is a constant after unrolling, so this folds
 * away and the private array d never needs an address (it stays in registers). */
inline uint lane8(uint8 v, int k)
{
    switch (k) {
    case 0: return v.s0; case 1: return v.s1; case 2: return v.s2; case 3: return v.s3;
    case 4: return v.s4; case 5: return v.s5; case 6: return v.s6; default: return v.s7;
    }
}

/* x: lines are contiguous; each work-item loads SEG bytes as uchar8 vectors. */
__kernel void pass_x(__global uchar *work, __global const uchar *voxels,
                     __global const ushort *field, int4 dims, int4 w_lo, int4 w_n,
                     int4 r_lo, int4 r_hi, int seeded, int cap, int nseg)
{
    __local uint ends[1024];
    const int seg = get_local_id(0);
    __local uint *seg_end = ends + get_local_id(1) * nseg;
    const int line = get_global_id(1);
    const int valid = line < w_n.y * w_n.z;
    const int ly = valid ? line % w_n.y : 0, lz = valid ? line / w_n.y : 0;
    const int wy = w_lo.y + ly, wz = w_lo.z + lz;
    const size_t world_row = world_index(w_lo.x, wy, wz, dims);
    const size_t work_row = box_index(0, ly, lz, w_n);
    /* A seed-shell line (outside R in y or z) takes every distance from the field. */
    const int line_in_r = wy >= r_lo.y && wy < r_hi.y && wz >= r_lo.z && wz < r_hi.z;
    const int t0 = seg * SEG;

    uint d[SEG];
    _Pragma("unroll") for (int c = 0; c < SEG; c += 8) {
        const int t = t0 + c;
        uint8 init = (uint8)(SAT);
        if (valid && t < w_n.x) {
            const uint8 v = convert_uint8(vload8(0, voxels + world_row + t));
            init = select((uint8)(cap), (uint8)(0), v != (uint8)(0));
            const int wx = w_lo.x + t;
            if (seeded && (!line_in_r || wx < r_lo.x || wx + 8 > r_hi.x)) {
                const uint8 shell = min(convert_uint8(vload8(0, field + world_row + t) >> (ushort)8),
                                        (uint8)(cap));
                const int8 x = (int8)(wx) + (int8)(0, 1, 2, 3, 4, 5, 6, 7);
                const int8 outside = (int8)(!line_in_r) | (x < (int8)(r_lo.x)) | (x >= (int8)(r_hi.x));
                init = select(init, shell, convert_uint8(outside) != (uint8)(0));
            }
        }
        _Pragma("unroll") for (int k = 0; k < 8; ++k)
            d[c + k] = lane8(init, k);
    }

    SWEEP_SEGMENT(uint, d, seg_end, seg, nseg, AS_INT, SAT_UINT);

    _Pragma("unroll") for (int c = 0; c < SEG; c += 8) {
        const int t = t0 + c;
        if (valid && t < w_n.x) {
            const uint8 out = (uint8)(d[c], d[c + 1], d[c + 2], d[c + 3],
                                      d[c + 4], d[c + 5], d[c + 6], d[c + 7]);
            vstore8(convert_uchar8(min(out, (uint8)(cap))), 0, work + work_row + t);
        }
    }
}

/* y or z: 32 lanes of 4 adjacent x-columns, so a warp touches 128 contiguous bytes a row. */
__kernel void pass_yz(__global uchar *work, __global const uchar *voxels,
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
        d[k] = (valid && t < len) ? vload4(0, work + base + (size_t)t * stride) : (uchar4)(SAT);
    }

    SWEEP_SEGMENT(uchar4, d, seg_end, seg, nseg, AS_INT4, SAT_UCHAR4);

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
            const ushort4 colour = convert_ushort4(vload4(0, voxels + i));
            vstore4((convert_ushort4(out) << (ushort)8) | colour, 0, field + i);
        }
#else
        vstore4(out, 0, work + base + (size_t)t * stride);
#endif
    }
}
