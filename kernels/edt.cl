/* Exact Euclidean distance transform by three 1-D passes (Meijster, Roerdink & Hesselink 2000;
 * Felzenszwalb & Huttenlocher 2012), over boxes of a world so that an edit recomputes only what
 * it can change (sdfserver/algorithms/euclidean.py says which boxes).
 *
 * The squared Euclidean distance between voxel centres separates:
 *   D(p) = min_q |p - q|^2 = min_z' [ (z - z')^2 + min_y' [ (y - y')^2 + min_x' (x - x')^2 ] ]
 * where q ranges over the seeds. Three stages, each a function of the one before along one axis:
 *   x       voxels -> line:  the 1-D distance along x to the nearest seed, uchar, capped at cap: the
 *           Manhattan transform's x pass (kernels/exact.cl, WORLD_OUT), a 1-D distance being the
 *           same in both metrics
 *   edt_yz  LAST 0:  line -> plane: min over z' of line(z')^2 + (z - z')^2, ushort, capped at cap^2
 *   edt_yz  LAST 1:  plane -> field: min over y' of plane(y')^2 + (y - y')^2, ushort, capped
 * (the order of the last two is free, the transform being separable: sdfserver/algorithms/
 * euclidean.py's STAGE_AXES says which it runs).
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
 * line, the stack of envelope sites kept in `stack` (a uint per entry: position and height, so a
 * pop reads one word; at most one entry per output position of the line). Only sites below cap^2
 * enter, and only sites owning an output position stay. The second scan walks the outputs
 * forward, moving to the next site where the two parabolas cross.
 *
 * Build options: SIGNED (0 or 1); edt_yz: AXIS (1 = y, 2 = z), LAST (1: reads the second
 * stage's squares and writes the field), BATCH (sites a work-item loads at once; default 8).
 */
#include "sdf_common.h"

#define FAR 0x7fffffff

#ifndef SIGNED
#define SIGNED 0
#endif

/* floor(a / b) for b > 0 and |a| < 2^24: a float quotient (exact operands; the rounded quotient
 * is within one of the true one), corrected by the remainder. Integer division costs a GPU many
 * instructions, and the envelope divides once for each site it enters or leaves. */
inline int floor_div(int a, int b)
{
    int q = (int)floor((float)a / (float)b);
    const int r = a - q * b;
    q -= r < 0;
    q += r >= b;
    return q;
}

#ifdef AXIS
/* The height of the parabola a stage's value stands for. */
#if LAST
#define IN_T ushort
#define HEIGHT_OF(v) ((int)(v))
#else
#define IN_T uchar
#define HEIGHT_OF(v) ((int)(v) * (int)(v))
#endif

/* A stack entry: a site's position along the line and its parabola's height. */
#define ENTRY(pos, h) ((uint)(pos) | ((uint)(h) << 16))
#define POS(e) ((int)((e) & 0xffffu))
#define HEIGHT(e) ((int)((e) >> 16))

/* The first position at which parabola b (to the right of a) is no higher than a. */
inline int first_owned(uint a, uint b)
{
    const int sa = POS(a), sb = POS(b);
    return 1 + floor_div(sb * sb - sa * sa + HEIGHT(b) - HEIGHT(a), 2 * (sb - sa));
}

/* The top of a line's stack, the top entries kept in registers: a pop then needs no load right
 * away, and the one it starts is not needed until two pops later. */
typedef struct {
    int q;          /* index of the top entry; -1: empty */
    int top_t;      /* the first output the top entry owns */
    uint e0, e1, e2; /* entries q, q - 1, q - 2 */
} Stack;

/* Enter site u (height hu < cap^2) into the envelope: pop the sites it beats where they start
 * to own outputs, then push it if it owns one before o1. */
inline void enter(int u, int hu, Stack *st, __global uint *stack, size_t stride, int o0, int o1)
{
    const uint e = ENTRY(u, hu);
    while (st->q >= 0) {
        const int a = st->top_t - POS(st->e0), b = st->top_t - u;
        if (a * a + HEIGHT(st->e0) <= b * b + hu)
            break;
        if (--st->q >= 0) {
            st->e0 = st->e1;
            st->e1 = st->e2;
            st->e2 = st->q >= 2 ? stack[(size_t)(st->q - 2) * stride] : 0u;
            st->top_t = st->q > 0 ? first_owned(st->e1, st->e0) : o0;
        }
    }
    if (st->q < 0) {
        st->q = 0;
        st->e0 = e;
        st->top_t = o0;
        stack[0] = e;
    } else {
        const int t = first_owned(st->e0, e);
        if (t < o1) {
            st->e2 = st->e1;
            st->e1 = st->e0;
            st->e0 = e;
            st->top_t = t;
            stack[(size_t)(++st->q) * stride] = e;
        }
    }
}

/* Sites and outputs go BATCH at a time: the batch's loads are issued together, so a work-item
 * waits for memory once a batch rather than once a voxel. */
#ifndef BATCH
#define BATCH 8
#endif

/* The lower envelope of one kind's parabolas (sites over [w0, w1)) on the outputs [o0, o1),
 * written where the voxel is of that kind (every voxel, unsigned). The stack holds at most one
 * entry per output position: each entry owns at least one (its first, `t`, increases). `in`,
 * `voxels` and `out` point at the line's position 0, `step` apart. */
inline void envelope(__global const IN_T *in, __global const uchar *voxels, __global ushort *out, size_t step,
                     __global uint *stack, size_t stride, int len, int w0, int w1, int o0, int o1, int cap2,
                     int kind, int face_lo)
{
    Stack st = {-1, o0, 0u, 0u, 0u};
#if SIGNED
    /* A seed (height 0: a voxel of the other kind) between two seeds along the line is never the
     * lowest at an output (one of its neighbours is nearer to any other position, and outputs are
     * only this kind's voxels), so it does not enter: in a signed world's inside transform most
     * of the line is air, which would otherwise enter site by site. 1 stands for "unknown". */
    int before = 1;
#endif
    for (int u0 = w0; u0 < w1; u0 += BATCH) {
        int h[BATCH + 1];
        _Pragma("unroll") for (int j = 0; j < BATCH + SIGNED; ++j) {
            const size_t at = (size_t)min(u0 + j, w1 - 1) * step;
            h[j] = HEIGHT_OF(in[at]);
#if SIGNED
            if ((voxels[at] != 0) != kind)
                h[j] = 0;
#endif
        }
#if SIGNED
        if (u0 + BATCH >= w1)
            h[BATCH] = 1;
#endif
        _Pragma("unroll") for (int j = 0; j < BATCH; ++j) {
            const int u = u0 + j;
            if (u >= w1 || h[j] >= cap2)
                continue;
#if SIGNED
            const int left = j > 0 ? h[j - 1] : before, right = u + 1 < w1 ? h[j + 1] : 1;
            if (h[j] == 0 && left == 0 && right == 0)
                continue;
#endif
            enter(u, h[j], &st, stack, stride, o0, o1);
        }
#if SIGNED
        before = h[BATCH - 1];
#endif
    }
    /* Forward over the outputs, moving to the next site while it is no higher at u (along the
     * envelope the values at one u fall, then rise: no division needed). */
    /* The next entries are loaded ahead, so that moving on rarely waits for memory. */
    const int q = st.q;
    int k = 0;
    uint cur = q >= 0 ? stack[0] : 0u, n1 = q >= 1 ? stack[stride] : 0u, n2 = q >= 2 ? stack[2 * stride] : 0u;
    uint n3 = q >= 3 ? stack[3 * stride] : 0u;
    for (int u0 = o0; u0 < o1; u0 += BATCH) {
#if SIGNED
        uchar v[BATCH];
        _Pragma("unroll") for (int j = 0; j < BATCH; ++j)
            v[j] = voxels[(size_t)min(u0 + j, o1 - 1) * step];
#endif
        _Pragma("unroll") for (int j = 0; j < BATCH; ++j) {
            const int u = u0 + j;
            if (u >= o1)
                break;
            while (k < q) {
                const int dc = u - POS(cur), dn = u - POS(n1);
                if (dn * dn + HEIGHT(n1) > dc * dc + HEIGHT(cur))
                    break;
                cur = n1;
                n1 = n2;
                n2 = n3;
                ++k;
                n3 = k + 3 <= q ? stack[(size_t)(k + 3) * stride] : 0u;
            }
#if SIGNED
            if ((v[j] != 0) != kind)
                continue;
#endif
            int value = cap2;
            if (q >= 0) {
                const int d = u - POS(cur);
                value = min(value, d * d + HEIGHT(cur));
            }
#if LAST && SIGNED
            if (kind == 1) {  /* a solid: the world's outside is air */
                const int face = min(face_lo, min(u + 1, len - u));
                value = min(value, face * face);
            }
#endif
            out[(size_t)u * step] = (ushort)value;
        }
    }
}

/* One work-item a line along AXIS (1 = y, 2 = z) through O: x across the work-items of a warp
 * (coalesced), the third axis across the second dimension. */
__kernel void edt_yz(__global const IN_T *in, __global const uchar *voxels, __global ushort *out,
                     __global uint *stack, int4 dims, int4 o_lo, int4 o_hi, int cap)
{
    const int lx = get_global_id(0), lo = get_global_id(1);
    const int nx = o_hi.x - o_lo.x;
    const int x = o_lo.x + lx;
#if AXIS == 1
    const int other = o_lo.z + lo, o0 = o_lo.y, o1 = o_hi.y, other_n = o_hi.z - o_lo.z;
    const int len = dims.y, other_len = dims.z;
    const size_t step = (size_t)dims.x, base = world_index(x, 0, other, dims);
#else
    const int other = o_lo.y + lo, o0 = o_lo.z, o1 = o_hi.z, other_n = o_hi.y - o_lo.y;
    const int len = dims.z, other_len = dims.y;
    const size_t step = (size_t)dims.x * (size_t)dims.y, base = world_index(x, other, 0, dims);
#endif
    if (x >= o_hi.x || lo >= other_n)
        return;
    const int w0 = max(0, o0 - cap), w1 = min(len, o1 + cap);
    /* Each line's stack: as many entries as the line has outputs; entry k of every line of the
     * launch together, so that a warp's pushes and reads at similar depths share cache lines. */
    const size_t stride = (size_t)nx * (size_t)other_n;
    __global uint *line_stack = stack + (size_t)lo * (size_t)nx + (size_t)lx;
    const int cap2 = cap * cap;
    /* The nearest face across x and the third axis, for a signed world's solids (the faces
     * along the line come with u). */
    const int face_lo = min(min(x + 1, dims.x - x), min(other + 1, other_len - other));
    envelope(in + base, voxels + base, out + base, step, line_stack, stride, len, w0, w1, o0, o1, cap2, 0, face_lo);
#if SIGNED
    envelope(in + base, voxels + base, out + base, step, line_stack, stride, len, w0, w1, o0, o1, cap2, 1, face_lo);
#endif
}
#endif
