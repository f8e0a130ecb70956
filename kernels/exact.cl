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
 * output once. The first pass (LOAD_INIT) computes initial distances straight
 * from voxels and the seed shell; the last (STORE_PACK) writes the packed field
 * over R instead of the work box.
 *
 * Build options: AXIS (0 = x, 1 = y, 2 = z), SEG (elements per work-item),
 * LOAD_INIT, STORE_PACK.
 * Local size: AXIS 0 -> (segments, lines); AXIS 1, 2 -> (32 x-lanes, segments).
 */
#include "sdf_common.h"

#if AXIS == 0
#define LINE_LEN(n) ((n).x)
#define STRIDE(n) ((size_t)1)
#elif AXIS == 1
#define LINE_LEN(n) ((n).y)
#define STRIDE(n) ((size_t)(n).x)
#else
#define LINE_LEN(n) ((n).z)
#define STRIDE(n) ((size_t)(n).x * (size_t)(n).y)
#endif

__kernel void line_pass(__global uchar *work, __global const uchar *voxels,
                        __global ushort *field, int4 dims, int4 w_lo, int4 w_n,
                        int4 r_lo, int4 r_hi, int seeded, int cap, int nseg)
{
    __local ushort seg_end[1024];

    /* Which line, which segment of it, and where its element 0 sits in W. */
#if AXIS == 0
    const int seg = get_local_id(0);
    const int slot = get_local_id(1) * nseg;
    const int line = get_global_id(1);
    const int valid = line < w_n.y * w_n.z;
    const int lx = 0, ly = valid ? line % w_n.y : 0, lz = valid ? line / w_n.y : 0;
#else
    const int seg = get_local_id(1);
    const int slot = get_local_id(0) * nseg;
    const int lx = get_global_id(0);
    const int valid = lx < w_n.x;
#if AXIS == 1
    const int ly = 0, lz = get_group_id(1);
#else
    const int ly = get_group_id(1), lz = 0;
#endif
#endif
    const int len = LINE_LEN(w_n);
    const size_t stride = STRIDE(w_n);
    const size_t base = box_index(lx, ly, lz, w_n);
    const int t0 = seg * SEG;

    int d[SEG];
#pragma unroll
    for (int k = 0; k < SEG; ++k) {
        const int t = t0 + k;
        int v = SDF_INF;
        if (valid && t < len) {
#if LOAD_INIT
            const int wx = w_lo.x + lx + (AXIS == 0 ? t : 0);
            const int wy = w_lo.y + ly + (AXIS == 1 ? t : 0);
            const int wz = w_lo.z + lz + (AXIS == 2 ? t : 0);
            v = (int)init_distance(voxels, field, wx, wy, wz, dims, r_lo, r_hi, seeded, cap);
#else
            v = work[base + (size_t)t * stride];
#endif
        }
        d[k] = v;
    }

    /* Forward sweep inside the segment. */
    int run = SDF_INF;
#pragma unroll
    for (int k = 0; k < SEG; ++k) {
        run = min(d[k], run + 1);
        d[k] = run;
    }
    seg_end[slot + seg] = (ushort)min(run, SDF_INF);
    barrier(CLK_LOCAL_MEM_FENCE);
    int carry = SDF_INF;
    for (int j = 0; j < seg; ++j)
        carry = min(carry, (int)seg_end[slot + j] + (seg - 1 - j) * SEG);
    barrier(CLK_LOCAL_MEM_FENCE);

    /* Apply the carry from the left, then the backward sweep. */
    run = SDF_INF;
#pragma unroll
    for (int k = SEG - 1; k >= 0; --k) {
        const int f = min(d[k], carry + k + 1);
        run = min(f, run + 1);
        d[k] = run;
    }
    seg_end[slot + seg] = (ushort)min(run, SDF_INF);
    barrier(CLK_LOCAL_MEM_FENCE);
    carry = SDF_INF;
    for (int j = seg + 1; j < nseg; ++j)
        carry = min(carry, (int)seg_end[slot + j] + (j - seg - 1) * SEG);

#pragma unroll
    for (int k = 0; k < SEG; ++k) {
        const int t = t0 + k;
        if (!valid || t >= len)
            continue;
        const uint out = (uint)min(min(d[k], carry + SEG - k), cap);
#if STORE_PACK
        const int wx = w_lo.x + lx + (AXIS == 0 ? t : 0);
        const int wy = w_lo.y + ly + (AXIS == 1 ? t : 0);
        const int wz = w_lo.z + lz + (AXIS == 2 ? t : 0);
        if (in_box(wx, wy, wz, r_lo, r_hi)) {
            const size_t i = world_index(wx, wy, wz, dims);
            field[i] = pack_field(out, voxels[i]);
        }
#else
        work[base + (size_t)t * stride] = (uchar)out;
#endif
    }
}
