/* The exact transform's x and z passes in one launch, for a work box without a seed shell.
 *
 * Without a shell every initial distance comes from the voxels: 0 on a solid, the cap on air. An
 * x-line's 1-D transform is then each voxel's distance to the nearest solid of its line, which a
 * bit per voxel is enough to find. A work-group takes one xz-plane of the work box (one y): it
 * reads the plane's voxels once into bits in local memory, with each row's first and last solid,
 * then walks the plane's bands of x-columns. In a band each work-item takes VEC adjacent columns
 * and SEG z-rows of them, derives their x-distances from the bits, sweeps the z-lines as
 * kernels/exact.cl's pass_yz does (SWEEP_SEGMENT) and writes the work box, which pass_yz along y
 * (AXIS 1, LAST) turns into the field. The plane moves 2 bytes a voxel (voxels in, work out)
 * where pass_x and a z pass move 4, and its rows are read whole, not a slice apart.
 *
 * Layout and arguments as in kernels/exact.cl (the work box's x-extent a multiple of 8, z-planes
 * `plane` bytes apart; a stacked run's slot from SLOT_PROLOGUE). Build options: SEG, VEC,
 * LOCAL_X (x-lanes of a band), LOCAL_Y (segments of a z-line), PLANE_WORDS (at least
 * ceil(w_n.x / 32) * w_n.z), ROWS (at least w_n.z), SDF_PTX_16X2. The host takes this pass only
 * where these fit the device's local memory (algorithms/exact.py, fuses_x_and_z).
 */
#include "min_plus_lines.h"

#ifndef __ENDIAN_LITTLE__
#error the plane's bits are written a byte of voxels at a time into little-endian words
#endif
#define NSEG LOCAL_Y
#define uintV CAT(uint, VEC)
#define convert_uintV CAT(convert_uint, VEC)
#define convert_intV CAT(convert_int, VEC)
/* Positions no solid can have, so far from any voxel that the distance is past every cap. */
#define NONE_LEFT (-0x4000)
#define NONE_RIGHT 0x4000

/* One bit a voxel for 8 voxels of a row, voxel k in bit k. */
inline uint solid_bits8(uchar8 v)
{
    return (uint)(v.s0 != 0) | (uint)(v.s1 != 0) << 1 | (uint)(v.s2 != 0) << 2 | (uint)(v.s3 != 0) << 3
         | (uint)(v.s4 != 0) << 4 | (uint)(v.s5 != 0) << 5 | (uint)(v.s6 != 0) << 6 | (uint)(v.s7 != 0) << 7;
}

/* The nearest solid of a row left of word w (x < 32 w), or NONE_LEFT where there is none within
 * the cap: the words in between are scanned only where the row's first solid lies left of w and
 * its last solid right of it. */
inline int solid_before(__local const uint *row, int w, int first, int last, int cap)
{
    const int start = 32 * w;
    if (first >= start)
        return NONE_LEFT;
    if (last < start)
        return last;
    for (int k = w - 1; 32 * (w - 1 - k) < cap; --k) {  /* a word further on is past the cap */
        const uint m = row[k];
        if (m)
            return 32 * k + 31 - (int)clz(m);
    }
    return NONE_LEFT;
}

/* The nearest solid of a row right of word w (x >= 32 (w + 1)), or NONE_RIGHT. */
inline int solid_after(__local const uint *row, int w, int first, int last, int cap)
{
    const int end = 32 * (w + 1);
    if (last < end)
        return NONE_RIGHT;
    if (first >= end)
        return first;
    for (int k = w + 1; 32 * (k - w - 1) < cap; ++k) {
        const uint m = row[k];
        if (m)
            return 32 * k + 31 - (int)clz(m & (0u - m));
    }
    return NONE_RIGHT;
}

/* The x-distances, capped, of VEC adjacent voxels of a row from lx on (all in one word). */
inline ushortV x_distances(__local const uint *row, int first, int last, int lx, int cap)
{
    if (last < 0)
        return (ushortV)(cap);
    const int w = lx >> 5;
    const uint m = row[w];
    const intV x = (intV)(lx) + LANE_OFFSETS;
    const uintV bit = convert_uintV(x & 31);
    const uintV at_or_below = (uintV)(m) & ((uintV)(0xffffffffu) >> ((uintV)(31) - bit));
    const uintV at_or_above = (uintV)(m) & ((uintV)(0xffffffffu) << bit);
    /* lanes rise along the word, so the first lane alone may lack a solid to its left in it */
    const int before = (m & (0xffffffffu >> (31 - (lx & 31)))) ? 0 : solid_before(row, w, first, last, cap);
    const int after = (m & (0xffffffffu << ((lx + VEC - 1) & 31))) ? 0 : solid_after(row, w, first, last, cap);
    const intV left = select((intV)(before), (intV)(32 * w + 31) - convert_intV(clz(at_or_below)),
                             at_or_below != (uintV)(0));
    const intV lowest = convert_intV(clz(at_or_above & ((uintV)(0) - at_or_above)));
    const intV right = select((intV)(after), (intV)(32 * w + 31) - lowest, at_or_above != (uintV)(0));
    return convert_ushortV(min(min(x - left, right - x), (intV)(cap)));
}

__kernel GROUP_SHAPE void pass_xz(__global uchar *work, __global const uchar *voxels,
                                  __global ushort *field, int4 dims, int4 w_lo, int4 w_n,
                                  int4 r_lo, int4 r_hi, int seeded, int cap, int plane, int4 world_lo,
                                  int4 world_hi, int8 slots, long voxel_stride, long work_stride)
{
    SLOT_PROLOGUE;
    __local uint bits[PLANE_WORDS];
    __local int first_solid[ROWS], last_solid[ROWS];
    __local wordV scan[4 * LOCAL_X * LOCAL_Y];
    const int lane = get_local_id(0), seg = get_local_id(1);
    const int id = seg * LOCAL_X + lane, threads = LOCAL_X * LOCAL_Y;
    const int ly = get_group_id(1), wy = w_lo.y + ly;
    const int nx = w_n.x, nz = w_n.z, row_words = (nx + 31) >> 5;

    for (int z = id; z < nz; z += threads) {
        first_solid[z] = nx;
        last_solid[z] = -1;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    for (int i = id; i < row_words * nz; i += threads) {
        const int z = i / row_words, w = i - z * row_words;
        const size_t row = world_index(w_lo.x, wy, w_lo.z + z, dims);
        uint m = 0;
        _Pragma("unroll") for (int q = 0; q < 4; ++q) {
            const int x = 32 * w + 8 * q;
            if (x < nx)
                m |= solid_bits8(*(__global const uchar8 *)(voxels + row + x)) << (8 * q);
        }
        bits[i] = m;
        if (m) {
            atomic_min(&first_solid[z], 32 * w + 31 - (int)clz(m & (0u - m)));
            atomic_max(&last_solid[z], 32 * w + 31 - (int)clz(m));
        }
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    __local wordV *line_scan = scan + 4 * NSEG * lane;
    const int t0 = seg * SEG;
    const wordV capv = (wordV)((uint)cap * ONES);
    const int bands = (nx + LOCAL_X * VEC - 1) / (LOCAL_X * VEC);
    for (int band = 0; band < bands; ++band) {  /* every work-item takes every band: barriers */
        const int lx = (band * LOCAL_X + lane) * VEC;
        const int valid = lx < nx;
        wordV d[SEG];
        _Pragma("unroll") for (int k = 0; k < SEG; ++k) {
            const int z = t0 + k;
            d[k] = valid && z < nz
                ? as_wordV(x_distances(bits + z * row_words, first_solid[z], last_solid[z], lx, cap))
                : (wordV)(BIG2);
        }

        SWEEP_SEGMENT(wordV, MINV, d, line_scan, seg);

        const size_t base = (size_t)ly * (size_t)nx + (size_t)lx;
        _Pragma("unroll") for (int k = 0; k < SEG; ++k) {
            const int z = t0 + k;
            if (valid && z < nz)
                *(__global ucharV *)(work + base + (size_t)z * (size_t)plane) = convert_ucharV(as_ushortV(MINV(d[k], capv)));
        }
        barrier(CLK_LOCAL_MEM_FENCE);  /* the next band's sweep writes the scan buffers again */
    }
}
