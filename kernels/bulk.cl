/* Fills and copies of whole device buffers, done here rather than by the driver.
 *
 * A world's buffers reach 2^33 elements (2048^3 voxels). The driver's own fill
 * (clEnqueueFillBuffer) on NVIDIA counts elements in 32 bits: past 2^31 it
 * faults the context or leaves the rest unwritten. These kernels count in
 * 64 bits (ulong) and loop: work-item i handles elements i, i + G, i + 2G, ...
 * with G the launch's global size, so one launch of a fixed size covers any
 * count and consecutive work-items touch consecutive elements.
 *
 * Build option: ELEMENT, the element type (uchar, ushort or int; uchar if unset).
 */
#include "sdf_common.h"

#ifndef ELEMENT
#define ELEMENT uchar
#endif

__kernel void fill(__global ELEMENT *dst, ulong count, ELEMENT value)
{
    const ulong stride = get_global_size(0);
    for (ulong i = get_global_id(0); i < count; i += stride)
        dst[i] = value;
}

/* dst[dst_first + i] = src[src_first + i] for i < count; the ranges must not overlap. */
__kernel void copy(__global ELEMENT *dst, ulong dst_first, __global const ELEMENT *src, ulong src_first,
                   ulong count)
{
    const ulong stride = get_global_size(0);
    for (ulong i = get_global_id(0); i < count; i += stride)
        dst[dst_first + i] = src[src_first + i];
}
