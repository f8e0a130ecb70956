/* Point queries: the distance, colour and gradient direction of the field at
 * voxel positions (the collision and navigation query). The host floors each
 * point to its voxel and checks it lies in the world; this kernel only reads.
 *
 * The gradient is the central difference of the capped distance along each
 * axis (one-sided at the world's faces), normalised to unit length; it is zero
 * where the field is flat, e.g. everywhere at the cap. */
#include "sdf_common.h"
#include "field_source.h"

inline float distance_at(FIELD_ARGS, int x, int y, int z, int4 dims)
{
    const int3 v = (int3)(clamp(x, 0, dims.x - 1), clamp(y, 0, dims.y - 1), clamp(z, 0, dims.z - 1));
    return field_distance(FIELD_PASS, v, dims);
}

inline float central(FIELD_ARGS, int4 p, int4 step, int4 dims)
{
    const int4 lo = p - step, hi = p + step;
    const int lo_in = lo.x >= 0 && lo.y >= 0 && lo.z >= 0;
    const int hi_in = hi.x < dims.x && hi.y < dims.y && hi.z < dims.z;
    const float span = (float)(lo_in + hi_in);
    if (span == 0.0f)
        return 0.0f;
    return (distance_at(FIELD_PASS, hi.x, hi.y, hi.z, dims) - distance_at(FIELD_PASS, lo.x, lo.y, lo.z, dims)) / span;
}

__kernel void query_points(FIELD_ARGS, int4 dims, __global const int4 *points, int n,
                           __global ushort *packed_out, __global float4 *gradient_out)
{
    const int i = get_global_id(0);
    if (i >= n)
        return;
    const int4 p = points[i];
    uint colour, steps;
    field_step(FIELD_PASS, p.xyz, dims, &colour, &steps);
    packed_out[i] = (ushort)((min((uint)fabs(distance_at(FIELD_PASS, p.x, p.y, p.z, dims)), 255u) << 8) | colour);
    float3 g = (float3)(central(FIELD_PASS, p, (int4)(1, 0, 0, 0), dims),
                        central(FIELD_PASS, p, (int4)(0, 1, 0, 0), dims),
                        central(FIELD_PASS, p, (int4)(0, 0, 1, 0), dims));
    const float len = length(g);
    g = len > 0.0f ? g / len : (float3)(0.0f);
    gradient_out[i] = (float4)(g, 0.0f);
}
