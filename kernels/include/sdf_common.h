/* Shared definitions for every sdfserver kernel.
 *
 * World arrays are C-ordered (z, y, x): index = (z * sy + y) * sx + x.
 * Voxel: uchar, 0 is air, 1..255 a solid voxel whose value is a palette index (RGB332 by default).
 * Field of a Manhattan world (field_source.h: every metric and sign): ushort,
 * (distance << 8) | colour, distance the Manhattan distance to the
 * nearest solid voxel capped at the world's cap (1..255).
 *
 * Region kernels work on a "work box" W (origin w_lo, extent w_n) holding one
 * uchar distance per voxel, densely laid out in the same (z, y, x) order. The
 * region R (r_lo..r_hi, world coordinates, half-open) is the part that gets
 * written back to the field; W \ R is either a one-voxel seed shell whose
 * distances come from the current field (seeded = 1) or a halo of voxels
 * (seeded = 0).
 *
 * Device defines, set by the loader for every build (sdfserver/gpu/programs.py):
 *   SDF_PTX_16X2  1 on NVIDIA sm_90 and later, where inline PTX min.u16x2 is one
 *                 instruction; 0 elsewhere.
 *   SDF_NVIDIA    1 on NVIDIA's OpenCL, which compiles inline PTX; 0 elsewhere.
 */
#ifndef SDF_COMMON_H
#define SDF_COMMON_H

/* Larger than any distance plus any line length; fits a ushort. */
#define SDF_INF 0x7fff

inline size_t world_index(int x, int y, int z, int4 dims)
{
    return ((size_t)z * (size_t)dims.y + (size_t)y) * (size_t)dims.x + (size_t)x;
}

inline size_t box_index(int x, int y, int z, int4 n)
{
    return ((size_t)z * (size_t)n.y + (size_t)y) * (size_t)n.x + (size_t)x;
}

inline int in_box(int x, int y, int z, int4 lo, int4 hi)
{
    return x >= lo.x && y >= lo.y && z >= lo.z && x < hi.x && y < hi.y && z < hi.z;
}

/* Initial distance of world voxel (x, y, z): 0 on solids, cap on air, and the
 * current field's distance on the seed shell around R. */
inline uint init_distance(__global const uchar *voxels, __global const ushort *field,
                          int x, int y, int z, int4 dims, int4 r_lo, int4 r_hi,
                          int seeded, int cap)
{
    const size_t i = world_index(x, y, z, dims);
    if (!seeded || in_box(x, y, z, r_lo, r_hi))
        return voxels[i] ? 0u : (uint)cap;
    return min((uint)(field[i] >> 8), (uint)cap);
}

inline ushort pack_field(uint distance, uchar colour)
{
    return (ushort)((distance << 8) | colour);
}

#endif
