/* The exact transform's first pass where a work box has no seed shell (a whole world, a halo
 * job): every initial distance then comes from the voxels, 0 on a solid and the cap on air, and
 * an x-line's 1-D transform is each voxel's distance to the nearest solid of its row, which the
 * y pass reads from bits (kernels/include/solid_bits.h, FROM_BITS in kernels/exact.cl) instead of
 * a pass of its own. This pass reads each voxel once and writes a bit for it with, for each word of
 * 32 voxels, the row's nearest solids on either side (the world's `work2`, a quarter of a byte a
 * voxel, which the y pass then reads, mostly from L2).
 * One work-item a word; a work-group holds ROWS_LOCAL whole rows (RW_LOCAL >= the words a row).
 * Arguments as kernels/exact.cl's passes take them.
 */
#include "sdf_common.h"
#include "solid_bits.h"

#ifndef __ENDIAN_LITTLE__
#error a row's bits are built a byte at a time into little-endian words
#endif

/* One bit a voxel for 8 voxels of a row, voxel k in bit k. */
inline uint solid_bits8(uchar8 v)
{
    return (uint)(v.s0 != 0) | (uint)(v.s1 != 0) << 1 | (uint)(v.s2 != 0) << 2 | (uint)(v.s3 != 0) << 3
         | (uint)(v.s4 != 0) << 4 | (uint)(v.s5 != 0) << 5 | (uint)(v.s6 != 0) << 6 | (uint)(v.s7 != 0) << 7;
}

__kernel __attribute__((reqd_work_group_size(RW_LOCAL, ROWS_LOCAL, 1)))
void solid_bits(__global uchar *work, __global const uchar *voxels, __global ushort *field,
                __global uint *bits, int4 dims, int4 w_lo, int4 w_n, int4 r_lo, int4 r_hi, int seeded,
                int cap, int plane, int4 world_lo, int4 world_hi, int8 slots, long voxel_stride,
                long work_stride)
{
    __local uint row_bits[ROWS_LOCAL * RW_LOCAL];
    __local int first[ROWS_LOCAL], last[ROWS_LOCAL];
    const int w = get_local_id(0), r = get_local_id(1);
    const int row = get_global_id(1), rows = w_n.y * w_n.z, words = row_words(w_n);
    __local const uint *mine = row_bits + r * RW_LOCAL;
    if (w == 0) {
        first[r] = INT_MAX;
        last[r] = -1;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    uint m = 0;
    if (row < rows && w < words) {
        const int ly = row % w_n.y, lz = row / w_n.y;
        const size_t at = world_index(w_lo.x + 32 * w, w_lo.y + ly, w_lo.z + lz, dims);
        _Pragma("unroll") for (int q = 0; q < 4; ++q)
            if (32 * w + 8 * q < w_n.x)  /* the row's x-extent is a multiple of 8 */
                m |= solid_bits8(*(__global const uchar8 *)(voxels + at + 8 * q)) << (8 * q);
        if (m) {
            atomic_min(&first[r], 32 * w + 31 - (int)clz(m & (0u - m)));
            atomic_max(&last[r], 32 * w + 31 - (int)clz(m));
        }
    }
    row_bits[r * RW_LOCAL + w] = m;
    barrier(CLK_LOCAL_MEM_FENCE);
    if (row >= rows || w >= words)
        return;
    /* the nearest solids either side of this word: words between are looked at only where the
     * row's first solid lies left of it and its last right of it (or the other way round) */
    const int start = 32 * w, end = start + 32;
    uint before = NO_SOLID, after = NO_SOLID;
    if (last[r] >= 0 && first[r] < start) {
        before = last[r] < start ? (uint)last[r] : NO_SOLID;
        for (int k = w - 1; before == NO_SOLID; --k)
            if (mine[k])
                before = (uint)(32 * k + 31 - (int)clz(mine[k]));
    }
    if (last[r] >= end) {
        after = first[r] >= end ? (uint)first[r] : NO_SOLID;
        for (int k = w + 1; after == NO_SOLID; ++k)
            if (mine[k])
                after = (uint)(32 * k + 31 - (int)clz(mine[k] & (0u - mine[k])));
    }
    ((__global uint2 *)bits)[(size_t)row * (size_t)words + (size_t)w] = (uint2)(m, before | after << 16);
}
