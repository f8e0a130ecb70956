/* A work box's solids as bits, and each voxel's distance to the nearest solid of its x-row read
 * from them (kernels/exact_bits.cl writes them; kernels/exact.cl's y pass reads them, FROM_BITS).
 *
 * Layout, a uint2 a word of 32 voxels: row r = lz * w_n.y + ly of the work box holds
 * ceil(w_n.x / 32) of them, the word of voxels 32 w .. 32 w + 31 at r * words + w; .x holds voxel
 * lx in bit lx % 32, .y the nearest solid of the row left of the word in its low 16 bits and the
 * nearest right of it in its high 16 (NO_SOLID where there is none). One 8-byte read then gives a
 * work-item the x-distances of up to 32 voxels, with no search.
 */
#ifndef SOLID_BITS_H
#define SOLID_BITS_H

#define NO_SOLID 0xffffu
/* Positions no solid can have, so far from any voxel that the distance is past every cap. */
#define NONE_LEFT (-0x4000)
#define NONE_RIGHT 0x4000

inline int row_words(int4 w_n) { return (w_n.x + 31) >> 5; }

#ifdef VEC
#define uintV CAT(uint, VEC)
#define convert_uintV CAT(convert_uint, VEC)
#define convert_intV CAT(convert_int, VEC)
/* The capped x-distances of VEC adjacent voxels of a row from lx on, all in the word `word`. */
inline ushortV x_distances(uint2 word, int lx, int cap)
{
    const uint m = word.x, before = word.y & NO_SOLID, after = word.y >> 16;
    const int w = lx >> 5;
    const intV x = (intV)(lx) + LANE_OFFSETS;
    const uintV bit = convert_uintV(x & 31);
    const uintV at_or_below = (uintV)(m) & ((uintV)(0xffffffffu) >> ((uintV)(31) - bit));
    const uintV at_or_above = (uintV)(m) & ((uintV)(0xffffffffu) << bit);
    const intV left = select((intV)(before == NO_SOLID ? NONE_LEFT : (int)before),
                             (intV)(32 * w + 31) - convert_intV(clz(at_or_below)), at_or_below != (uintV)(0));
    const intV lowest = convert_intV(clz(at_or_above & ((uintV)(0) - at_or_above)));
    const intV right = select((intV)(after == NO_SOLID ? NONE_RIGHT : (int)after),
                              (intV)(32 * w + 31) - lowest, at_or_above != (uintV)(0));
    return convert_ushortV(min(min(x - left, right - x), (intV)(cap)));
}
#endif

#endif
