/* Exact Euclidean distance transform by three 1-D passes (Meijster, Roerdink & Hesselink 2000;
 * Felzenszwalb & Huttenlocher 2012), over boxes of a world so that an edit recomputes only what
 * it can change (sdfserver/algorithms/euclidean.py says which boxes).
 *
 * The squared Euclidean distance between voxel centres separates:
 *   D(p) = min_q |p - q|^2 = min_z' [ (z - z')^2 + min_y' [ (y - y')^2 + min_x' (x - x')^2 ] ]
 * where q ranges over the seeds. Three stages, each a function of the one before along one axis:
 *   edt_x   voxels -> line:  the 1-D distance along x to the nearest seed, uchar, capped at cap
 *   edt_yz  AXIS 1:  line -> plane: min over y' of line(y')^2 + (y - y')^2, ushort, capped at cap^2
 *   edt_yz  AXIS 2:  plane -> field: min over z' of plane(z')^2 + (z - z')^2, ushort, capped
 * Each stage writes only its output box O, reading its input along its axis over O grown by the
 * cap (values past the cap cannot lower a capped result), so the world-sized `line` and `plane`
 * buffers stay current between recomputes and an edit's stages cover the boxes it can change.
 *
 * Seeds: unsigned, a voxel's seeds are the solids. Signed (SIGNED 1), a voxel's seeds are the
 * voxels of the other kind (an air voxel's the solids, a solid's the air voxels), so one number a
 * voxel carries both transforms through every stage: a stage's value at a voxel of one kind is
 * that kind's partial distance, and for the other transform it counts as 0 (it is a seed). The
 * world's outside is air: a solid's distance is also at most its distance to the nearest face,
 * which the last stage takes (the nearest outside voxel centre is straight across a face).
 *
 * The 1-D lower envelope of parabolas (the y and z stages): Meijster's two scans, one work-item a
 * line, the stack of envelope sites kept in `stack` (ushort positions along the line, one slot a
 * voxel of the output box's lines, slot k of every line together so that a warp's pushes land
 * near each other). Only sites below cap^2 enter. The scan back picks, at each u, the site whose
 * parabola is lowest there by stepping left while the next site is no worse: along the envelope
 * the values at one u fall, then rise.
 *
 * Build options: SIGNED (0 or 1); edt_yz: AXIS (1 = y, 2 = z).
 */
#include "sdf_common.h"

#define FAR 0x7fffffff

#ifndef SIGNED
#define SIGNED 0
#endif

/* floor(a / b) for b > 0 (C division truncates toward zero). */
inline int floor_div(int a, int b)
{
    return a >= 0 ? a / b : -((-a + b - 1) / b);
}

/* One work-item a (y, z) line of O: a forward and a backward scan over the line's window. */
__kernel void edt_x(__global const uchar *voxels, __global uchar *line, int4 dims, int4 o_lo, int4 o_hi,
                    int cap)
{
    const int y = o_lo.y + get_global_id(0), z = o_lo.z + get_global_id(1);
    if (y >= o_hi.y || z >= o_hi.z)
        return;
    const int w0 = max(0, o_lo.x - cap), w1 = min(dims.x, o_hi.x + cap);
    const size_t row = world_index(0, y, z, dims);
    int last_solid = -FAR / 2, last_air = -FAR / 2;
    for (int x = w0; x < o_hi.x; ++x) {
        const int solid = voxels[row + x] != 0;
        if (solid)
            last_solid = x;
        else
            last_air = x;
        if (x >= o_lo.x) {
            const int d = solid ? (SIGNED ? x - last_air : 0) : x - last_solid;
            line[row + x] = (uchar)min(d, cap);
        }
    }
    int next_solid = FAR / 2, next_air = FAR / 2;
    for (int x = w1 - 1; x >= o_lo.x; --x) {
        const int solid = voxels[row + x] != 0;
        if (solid)
            next_solid = x;
        else
            next_air = x;
        if (x < o_hi.x) {
            const int d = solid ? (SIGNED ? next_air - x : 0) : next_solid - x;
            if (d < cap)
                line[row + x] = (uchar)min(d, (int)line[row + x]);
        }
    }
}

#ifdef AXIS
#if AXIS == 1
#define LINE_AT(i) world_index(x, (i), other, dims)
#define LEN dims.y
#define IN_T uchar
#define HEIGHT_OF(v) ((int)(v) * (int)(v))
#else
#define LINE_AT(i) world_index(x, other, (i), dims)
#define LEN dims.z
#define IN_T ushort
#define HEIGHT_OF(v) ((int)(v))
#endif

/* The height of the parabola at position i of the line for the transform whose seeds are of the
 * kind other than `kind` (0 air, 1 solid): 0 on a seed, else the stage's value. */
inline int height(__global const IN_T *in, __global const uchar *voxels, size_t at, int kind)
{
#if SIGNED
    if ((voxels[at] != 0) != kind)
        return 0;
#endif
    return HEIGHT_OF(in[at]);
}

/* The lower envelope of one kind's parabolas over [w0, w1), written at [o0, o1) where the voxel
 * is of that kind (every voxel, unsigned). */
inline void envelope(__global const IN_T *in, __global const uchar *voxels, __global ushort *out,
                     __global ushort *stack, size_t stack_stride, int x, int other, int4 dims,
                     int w0, int w1, int o0, int o1, int cap2, int kind, int face_lo, int face_hi)
{
    int q = -1, top_s = 0, top_h = 0, top_t = 0;
    for (int u = w0; u < w1; ++u) {
        const int hu = height(in, voxels, LINE_AT(u), kind);
        if (hu >= cap2)
            continue;
        while (q >= 0) {
            const int a = top_t - top_s, b = top_t - u;
            if (a * a + top_h <= b * b + hu)
                break;
            if (--q >= 0) {
                top_s = stack[(size_t)q * stack_stride];
                top_h = height(in, voxels, LINE_AT(top_s), kind);
                if (q == 0) {
                    top_t = w0;
                } else {
                    const int s = stack[(size_t)(q - 1) * stack_stride];
                    const int hs = height(in, voxels, LINE_AT(s), kind);
                    top_t = 1 + floor_div(top_s * top_s - s * s + top_h - hs, 2 * (top_s - s));
                }
            }
        }
        if (q < 0) {
            q = 0;
            top_s = u; top_h = hu; top_t = w0;
            stack[0] = (ushort)u;
        } else {
            const int w = 1 + floor_div(u * u - top_s * top_s + hu - top_h, 2 * (u - top_s));
            if (w < w1) {
                ++q;
                top_s = u; top_h = hu; top_t = w;
                stack[(size_t)q * stack_stride] = (ushort)u;
            }
        }
    }
    /* Back over the outputs: the lowest site at u, stepping left while the next is no worse. */
    int s = top_s, hs = top_h;
    int prev_s = 0, prev_h = 0;
    if (q > 0) {
        prev_s = stack[(size_t)(q - 1) * stack_stride];
        prev_h = height(in, voxels, LINE_AT(prev_s), kind);
    }
    for (int u = o1 - 1; u >= o0; --u) {
        const size_t at = LINE_AT(u);
#if SIGNED
        if ((voxels[at] != 0) != kind)
            continue;
#endif
        int value = cap2;
        if (q >= 0) {
            while (q > 0 && (u - prev_s) * (u - prev_s) + prev_h <= (u - s) * (u - s) + hs) {
                s = prev_s; hs = prev_h;
                if (--q > 0) {
                    prev_s = stack[(size_t)(q - 1) * stack_stride];
                    prev_h = height(in, voxels, LINE_AT(prev_s), kind);
                }
            }
            value = min(value, (u - s) * (u - s) + hs);
        }
#if AXIS == 2 && SIGNED
        if (kind == 1) {  /* a solid: the world's outside is air */
            const int face = min(face_lo, min(u + 1, LEN - u));
            value = min(value, face * face);
        }
#endif
        out[at] = (ushort)value;
    }
}

/* One work-item a line along AXIS through O: x across the work-items of a warp (coalesced), the
 * other axis (z for AXIS 1, y for AXIS 2) across the second dimension. */
__kernel void edt_yz(__global const IN_T *in, __global const uchar *voxels, __global ushort *out,
                     __global ushort *stack, int4 dims, int4 o_lo, int4 o_hi, int cap)
{
    const int lx = get_global_id(0), lo = get_global_id(1);
    const int nx = o_hi.x - o_lo.x;
#if AXIS == 1
    const int other = o_lo.z + lo, o0 = o_lo.y, o1 = o_hi.y, other_hi = o_hi.z, other_n = o_hi.z - o_lo.z;
#else
    const int other = o_lo.y + lo, o0 = o_lo.z, o1 = o_hi.z, other_hi = o_hi.y, other_n = o_hi.y - o_lo.y;
#endif
    const int x = o_lo.x + lx;
    if (x >= o_hi.x || other >= other_hi)
        return;
    const int w0 = max(0, o0 - cap), w1 = min(LEN, o1 + cap);
    /* Slot k of line (lx, lo) lies at k * lines + lo * nx + lx. */
    const size_t lines = (size_t)nx * (size_t)other_n;
    __global ushort *line_stack = stack + (size_t)lo * (size_t)nx + (size_t)lx;
    const int cap2 = cap * cap;
    int face_lo = 0x7fff;
#if AXIS == 2 && SIGNED
    /* The nearest x or y face, for solids (the z faces come with u). */
    face_lo = min(min(x + 1, dims.x - x), min(other + 1, dims.y - other));
#endif
    envelope(in, voxels, out, line_stack, lines, x, other, dims, w0, w1, o0, o1, cap2, 0, face_lo, 0);
#if SIGNED
    envelope(in, voxels, out, line_stack, lines, x, other, dims, w0, w1, o0, o1, cap2, 1, face_lo, 0);
#endif
}
#endif
