/* What a stored field value means, by the world's metric and sign (build defines FIELD_EUCLID,
 * FIELD_SIGNED; sdfserver/field_values.py is the host side, docs/algorithms.md "Metrics and
 * signs" says why): Manhattan (distance << 8) | colour, Euclidean the squared distance; a signed
 * world's solids store their distance to air. Included by field_source.h and bricks.cl. */
#ifndef FIELD_VALUES_H
#define FIELD_VALUES_H
#include "sdf_common.h"

#ifndef FIELD_EUCLID
#define FIELD_EUCLID 0
#endif
#ifndef FIELD_SIGNED
#define FIELD_SIGNED 0
#endif

/* Face-steps that a stored value allows, on air. */
inline uint air_steps(ushort f)
{
#if FIELD_EUCLID
    const uint r = (uint)ceil(sqrt((float)f));
    return r * r < (uint)f ? r + 1u : (r > 0u && (r - 1u) * (r - 1u) >= (uint)f ? r - 1u : r);
#else
    return (uint)(f >> 8);
#endif
}

/* The magnitude a stored value holds, in voxels. */
inline float stored_distance(ushort f)
{
#if FIELD_EUCLID
    return sqrt((float)f);
#else
    return (float)(f >> 8);
#endif
}
/* The stored value of an implicit (sparse) air brick's voxels, and of an implicit solid brick's:
 * air at the cap; a solid at the cap inside a signed world, else 0. */
inline ushort implicit_air(int cap)
{
    return FIELD_EUCLID ? (ushort)(cap * cap) : pack_field((uint)cap, 0);
}

inline ushort implicit_solid(int cap, uchar colour)
{
    const uint inside = FIELD_SIGNED ? (uint)cap : 0u;
    return FIELD_EUCLID ? (ushort)(inside * inside) : pack_field(inside, colour);
}

#endif
