/* The dissertation's chunk padding (§4.2.1, Algorithms 2 and 3): with a world's
 * borders "padded", each chunk is computed alone and every voxel outside it
 * counts as solid. `chunk` is the chunk side in voxels; 0 means no padding.
 * Coordinates are world coordinates, or box coordinates of a box whose origin
 * is chunk-aligned (a padded region job's work box is its region). */
#ifndef SDF_CHUNK_PADDING_H
#define SDF_CHUNK_PADDING_H

/* Manhattan distance from voxel (x, y, z) to the solid frame around its chunk:
 * 1 on the chunk's faces. Coordinates are non-negative. */
inline uint frame_distance(int x, int y, int z, int chunk)
{
    const int lx = x % chunk, ly = y % chunk, lz = z % chunk;
    const int d = min(min(min(lx, chunk - 1 - lx), min(ly, chunk - 1 - ly)),
                      min(lz, chunk - 1 - lz));
    return (uint)d + 1u;
}

/* Whether coordinates a and b (non-negative, one axis) lie in the same chunk. */
inline int same_chunk(int a, int b, int chunk)
{
    return chunk == 0 || a / chunk == b / chunk;
}

#endif
