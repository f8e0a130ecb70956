/* Exact Manhattan distance transform by separable min-plus passes.
 *
 * The L1 distance transform of an initial distance f is
 *   D(p) = min_q f(q) + |px-qx| + |py-qy| + |pz-qz|,
 * and because the L1 kernel is a sum of 1-D kernels it factors into three 1-D
 * transforms, one per axis (Meijster et al. 2000; Felzenszwalb & Huttenlocher
 * 2012). Along one line the 1-D transform with kernel |i-j| is exactly a forward
 * sweep d[i] = min(d[i], d[i-1] + 1) followed by a backward sweep.
 *
 * One work-item holds SEG consecutive elements of a line in registers. The
 * sweeps run locally, then carries between the segments of a line are combined
 * through local memory (prefix and suffix minimums, SWEEP_SEGMENT below).
 * Each pass reads its input once and writes its output once:
 *   pass_x   voxels (+ the seed shell from the field) -> work
 *   pass_yz  work -> work (AXIS 1), work + voxels -> packed field over R (AXIS 2)
 * Distances travel as uchar capped at the world's cap (a value of cap means
 * "at least cap", which keeps min-plus exact for the capped result) and are
 * swept two at a time: two independent lines share a 32-bit word in 16-bit
 * lanes (pass_x: two lines of x; pass_yz: two adjacent x-columns), so one
 * 16x2 min and one 32-bit add advance both. Values stay below 0x8000 (BIG plus
 * a line length), so the add never carries from one lane into the other.
 * On NVIDIA sm_90 the min is one instruction (PTX min.u16x2, SDF_PTX_16X2=1);
 * elsewhere it is OpenCL's ushort2 min.
 *
 * Layout: the work box's x-origin and x-extent are multiples of 8 (the host
 * aligns them), so uchar8 accesses along x and VEC-wide accesses across
 * x-lanes are aligned in both the work box and the world arrays; they are
 * written as vector pointer accesses because vloadn promises only byte
 * alignment and compiles to byte loads. The work box's z-planes lie `plane`
 * bytes apart, 32 more than a plane (a multiple of 8, so alignment holds):
 * z rows exactly a power of two apart (a 512^2 plane is 2^18 bytes) read
 * about 10% slower in the z pass.
 * One program holds one pass: pass_yz when VEC is defined, else pass_x.
 * Build options: SEG (elements per work-item), AXIS (pass_yz: 1 = y, 2 = z),
 * VEC (pass_yz: x-columns per work-item, 2, 4 or 8), LOCAL_X, LOCAL_Y (the
 * work-group: pass_x (segments, line pairs); pass_yz (x-lanes, segments)),
 * FIRST, LAST, SDF_PTX_16X2, INVERT, SIGNED_WORLD, WORLD_OUT.
 *
 * WORLD_OUT 1 (pass_x with FIRST and not LAST): the Euclidean transform's x stage
 * (kernels/edt.cl) — the 1-D distances written into `work` in the world's layout, over R only
 * (R's x-bounds multiples of 8; W is R grown along x), where they stay between recomputes.
 *
 * INVERT 1 computes a signed world's other transform: the distance from each solid to the
 * nearest air voxel (the seeds are the air voxels; the world's outside is air, so the last pass
 * also takes each solid's distance to the nearest face of the world, whose box in the buffer's
 * coordinates is world_lo..world_hi: a sparse world's scratch box is not the world) and writes
 * it over R's solids only,
 * after the plain transform has written R. On the seed shell a voxel of the seeds' kind starts at
 * 0 whatever the field holds there (a signed world's solids hold their inside distance).
 */
#include "sdf_common.h"

/* Larger than any distance plus any line length. */
#define BIG 0x3fff
/* One in each 16-bit lane of a word. */
#define ONES 0x00010001u
#define BIG2 (BIG * ONES)
#ifndef INVERT
#define INVERT 0
#endif
/* A signed world's runs: on the seed shell a seed keeps 0 (its field holds the other transform's
 * distance); an unsigned world's solids hold 0 there already. */
#ifndef SIGNED_WORLD
#define SIGNED_WORLD INVERT
#endif

#if SDF_PTX_16X2
inline uint min_u16x2(uint a, uint b)
{
    uint r;
    asm("min.u16x2 %0, %1, %2;" : "=r"(r) : "r"(a), "r"(b));
    return r;
}
#else
inline uint min_u16x2(uint a, uint b) { return as_uint(min(as_ushort2(a), as_ushort2(b))); }
#endif
inline uint2 min_u16x2_v2(uint2 a, uint2 b) { return (uint2)(min_u16x2(a.x, b.x), min_u16x2(a.y, b.y)); }
inline uint4 min_u16x2_v4(uint4 a, uint4 b) { return (uint4)(min_u16x2_v2(a.lo, b.lo), min_u16x2_v2(a.hi, b.hi)); }

/* The host compiles each pass for its exact work-group shape, which lets the
 * compiler budget registers for full work-groups instead of guessing. */
#define GROUP_SHAPE __attribute__((reqd_work_group_size(LOCAL_X, LOCAL_Y, 1)))

/* A stacked run transforms whole worlds of one slot pool in one launch (exact.py, run_slots):
 * `slots` is a mask of the pool's slots it covers (slot s is bit s % 32 of lane s / 32), the
 * launch's third dimension picks the k-th of them in order, and that slot's world and work box
 * lie that many strides further on (voxel_stride voxels, work_stride bytes); the rest of the pass
 * sees one world. The mask is passed by value (a pool has at most 256 slots), so a run that
 * repeats sets no argument; a run of one world passes zeros. */
inline size_t kth_slot(int8 slots, int k)
{
    int lanes[8];
    vstore8(slots, 0, lanes);
    for (int lane = 0; lane < 8; ++lane) {
        uint bits = (uint)lanes[lane];
        const int count = popcount(bits);
        if (k < count) {
            for (int j = 0; j < k; ++j)
                bits &= bits - 1u;  /* drop the lowest set bit */
            return (size_t)(32 * lane + 31 - clz(bits & (0u - bits)));
        }
        k -= count;
    }
    return 0;
}

#define SLOT_PROLOGUE                                                           \
    do {                                                                        \
        const size_t slot_ = kth_slot(slots, get_group_id(2));                  \
        work += slot_ * (size_t)work_stride;                                    \
        voxels += slot_ * (size_t)voxel_stride;                                 \
        field += slot_ * (size_t)voxel_stride;                                  \
    } while (0)

/* The 1-D transform of one line cut into NSEG segments of SEG elements, one
 * segment per work-item. Each segment first sweeps forward and backward on its
 * own; then its last element holds its best offer to the segments on its right
 * (min over its elements of value + distance to its end) and its first element
 * its offer to the left. A segment's carry from the left is the minimum over the
 * segments before it of their offer plus the distance between them; shifting
 * each offer by its distance to the line's end turns that into a plain prefix
 * minimum, scanned in log2(NSEG) steps through local memory (ping-pong buffers,
 * one barrier a step), and likewise a suffix minimum from the right. NSEG is a
 * compile-time constant so the steps unroll. T is a word type of 16-bit lane
 * pairs, MIN its lane-wise min; scan points at 4 * NSEG words of this line's
 * local memory (two buffers per direction). */
#define SWEEP_SEGMENT(T, MIN, d, scan, seg)                                            \
    do {                                                                               \
        T run_ = (T)(BIG2);                                                            \
        _Pragma("unroll") for (int k = 0; k < SEG; ++k) {                              \
            run_ = MIN(d[k], run_ + ONES);                                             \
            d[k] = run_;                                                               \
        }                                                                              \
        run_ = (T)(BIG2);                                                              \
        _Pragma("unroll") for (int k = SEG - 1; k >= 0; --k) {                         \
            run_ = MIN(d[k], run_ + ONES);                                             \
            d[k] = run_;                                                               \
        }                                                                              \
        T right_offer_ = d[SEG - 1] + (uint)((NSEG - 1 - (seg)) * SEG) * ONES;         \
        T left_offer_ = d[0] + (uint)((seg) * SEG) * ONES;                             \
        __local T *fr_ = (scan), *fw_ = (scan) + NSEG;                                 \
        __local T *br_ = (scan) + 2 * NSEG, *bw_ = (scan) + 3 * NSEG;                  \
        fr_[seg] = right_offer_;                                                       \
        br_[seg] = left_offer_;                                                        \
        barrier(CLK_LOCAL_MEM_FENCE);                                                  \
        _Pragma("unroll") for (int step = 1; step < NSEG; step <<= 1) {                \
            if ((seg) >= step)                                                         \
                right_offer_ = MIN(right_offer_, fr_[(seg) - step]);                   \
            if ((seg) + step < NSEG)                                                   \
                left_offer_ = MIN(left_offer_, br_[(seg) + step]);                     \
            fw_[seg] = right_offer_;                                                   \
            bw_[seg] = left_offer_;                                                    \
            barrier(CLK_LOCAL_MEM_FENCE);                                              \
            __local T *t_ = fr_; fr_ = fw_; fw_ = t_;                                  \
            t_ = br_; br_ = bw_; bw_ = t_;                                             \
        }                                                                              \
        /* element k gets from_left + k and from_right - k (never below 1) */          \
        const T from_left_ = (seg) > 0                                                 \
            ? fr_[(seg) - 1] - (uint)((NSEG - (seg)) * SEG - 1) * ONES : (T)(BIG2);    \
        const T from_right_ = (seg) < NSEG - 1                                         \
            ? br_[(seg) + 1] - (uint)((seg) * SEG) * ONES : (T)(BIG2 + SEG * ONES);    \
        _Pragma("unroll") for (int k = 0; k < SEG; ++k)                                \
            d[k] = MIN(d[k], MIN(from_left_ + (uint)k * ONES, from_right_ - (uint)k * ONES)); \
    } while (0)

#ifndef VEC
#define NSEG LOCAL_X
/* One x-line of the pair: where it lies and whether it is a seed-shell line. */
typedef struct {
    int valid;
    size_t world_row, work_row;
    int in_r;  /* inside R in y and z */
} XLine;

inline XLine x_line(int line, int4 w_lo, int4 w_n, int plane, int4 r_lo, int4 r_hi, int4 dims)
{
    XLine l;
    l.valid = line < w_n.y * w_n.z;
    const int ly = l.valid ? line % w_n.y : 0, lz = l.valid ? line / w_n.y : 0;
    const int wy = w_lo.y + ly, wz = w_lo.z + lz;
    l.world_row = world_index(w_lo.x, wy, wz, dims);
    l.work_row = (size_t)lz * (size_t)plane + (size_t)ly * (size_t)w_n.x;
    l.in_r = wy >= r_lo.y && wy < r_hi.y && wz >= r_lo.z && wz < r_hi.z;
    return l;
}

#if FIRST
/* Initial distances of 8 voxels of one line: 0 on solids, cap on air, the
 * field's distance on the seed shell (rare, so plain scalar reads). */
inline void init8(uint *out, XLine l, int t, int wx, __global const uchar *voxels,
                  __global const ushort *field, int4 r_lo, int4 r_hi, int seeded, int cap)
{
    const uchar8 v = *(__global const uchar8 *)(voxels + l.world_row + t);
    const uint8 init = select((uint8)(INVERT ? 0 : cap), (uint8)(INVERT ? cap : 0), convert_uint8(v) != (uint8)(0));
    out[0] = init.s0; out[1] = init.s1; out[2] = init.s2; out[3] = init.s3;
    out[4] = init.s4; out[5] = init.s5; out[6] = init.s6; out[7] = init.s7;
    if (seeded && (!l.in_r || wx < r_lo.x || wx + 8 > r_hi.x)) {
        _Pragma("unroll") for (int k = 0; k < 8; ++k) {
            const int x = wx + k;
            if ((!l.in_r || x < r_lo.x || x >= r_hi.x) && (!SIGNED_WORLD || out[k] != 0))
                out[k] = min((uint)(field[l.world_row + t + k] >> 8), (uint)cap);
        }
    }
}

#else
/* 8 distances of one line from the work box. */
inline void load8(uint *out, __global const uchar *row)
{
    const uint8 v = convert_uint8(*(__global const uchar8 *)row);
    out[0] = v.s0; out[1] = v.s1; out[2] = v.s2; out[3] = v.s3;
    out[4] = v.s4; out[5] = v.s5; out[6] = v.s6; out[7] = v.s7;
}
#endif

#ifndef WORLD_OUT
#define WORLD_OUT 0
#endif
#if WORLD_OUT
/* 8 x-stage distances of one line: the plain run writes them all; the inverted one only over the
 * solids, each voxel's distance to the other kind being the one of the two that is not 0. */
inline void store_line8(__global uchar *line, __global const uchar *voxels, uchar8 d)
{
#if INVERT
    const uchar8 v = *(__global const uchar8 *)voxels;
    d = select(*(__global const uchar8 *)line, d, as_uchar8(v != (uchar8)(0)));
#endif
    *(__global uchar8 *)line = d;
}
#endif
#if LAST && INVERT
#error the inverted transform writes the field from pass_yz (PASS_ORDER ends with y or z)
#endif
#if LAST
/* 8 packed field values of one line. Only solids (distance 0) carry a colour:
 * air-only groups skip the voxel read. */
inline void pack8(__global ushort *field, __global const uchar *voxels, ushort8 distance)
{
    const ushort8 colour = any(distance == (ushort8)(0))
        ? convert_ushort8(*(__global const uchar8 *)voxels) : (ushort8)(0);
    *(__global ushort8 *)field = (distance << (ushort)8) | colour;
}
#endif

/* x: lines are contiguous; each work-item holds SEG elements of two lines (one
 * per 16-bit lane) and loads them as uchar8 vectors. */
__kernel GROUP_SHAPE void pass_x(__global uchar *work, __global const uchar *voxels,
                     __global ushort *field, int4 dims, int4 w_lo, int4 w_n,
                     int4 r_lo, int4 r_hi, int seeded, int cap, int plane, int4 world_lo, int4 world_hi,
                     int8 slots, long voxel_stride, long work_stride)
{
    SLOT_PROLOGUE;
    __local uint scan[4 * LOCAL_X * LOCAL_Y];
    const int seg = get_local_id(0);
    __local uint *line_scan = scan + 4 * NSEG * get_local_id(1);
    const XLine a = x_line(2 * (int)get_global_id(1), w_lo, w_n, plane, r_lo, r_hi, dims);
    const XLine b = x_line(2 * (int)get_global_id(1) + 1, w_lo, w_n, plane, r_lo, r_hi, dims);
    const int t0 = seg * SEG;

    uint d[SEG];
    _Pragma("unroll") for (int c = 0; c < SEG; c += 8) {
        const int t = t0 + c;
        uint da[8], db[8];
        _Pragma("unroll") for (int k = 0; k < 8; ++k)
            da[k] = db[k] = BIG;
        if (t < w_n.x) {
#if FIRST
            const int wx = w_lo.x + t;
            if (a.valid)
                init8(da, a, t, wx, voxels, field, r_lo, r_hi, seeded, cap);
            if (b.valid)
                init8(db, b, t, wx, voxels, field, r_lo, r_hi, seeded, cap);
#else
            if (a.valid)
                load8(da, work + a.work_row + t);
            if (b.valid)
                load8(db, work + b.work_row + t);
#endif
        }
        _Pragma("unroll") for (int k = 0; k < 8; ++k)
            d[c + k] = da[k] | (db[k] << 16);
    }

    SWEEP_SEGMENT(uint, min_u16x2, d, line_scan, seg);

    const uint cap2 = (uint)cap * ONES;
    _Pragma("unroll") for (int c = 0; c < SEG; c += 8) {
        const int t = t0 + c;
        if (t >= w_n.x)
            continue;
        uint8 out;
        out.s0 = min_u16x2(d[c], cap2); out.s1 = min_u16x2(d[c + 1], cap2);
        out.s2 = min_u16x2(d[c + 2], cap2); out.s3 = min_u16x2(d[c + 3], cap2);
        out.s4 = min_u16x2(d[c + 4], cap2); out.s5 = min_u16x2(d[c + 5], cap2);
        out.s6 = min_u16x2(d[c + 6], cap2); out.s7 = min_u16x2(d[c + 7], cap2);
        const ushort8 out_a = convert_ushort8(out & 0xffffu), out_b = convert_ushort8(out >> 16);
#if LAST
        /* R's x-bounds are multiples of 8, like t: a group of 8 is all in R or all out. */
        const int wx = w_lo.x + t;
        const int x_in_r = wx >= r_lo.x && wx < r_hi.x;
        if (a.valid && a.in_r && x_in_r)
            pack8(field + a.world_row + t, voxels + a.world_row + t, out_a);
        if (b.valid && b.in_r && x_in_r)
            pack8(field + b.world_row + t, voxels + b.world_row + t, out_b);
#elif WORLD_OUT
        /* The Euclidean transform's x stage (kernels/edt.cl): world layout, R only. */
        const int wx = w_lo.x + t;
        if (wx >= r_lo.x && wx < r_hi.x) {
            if (a.valid)
                store_line8(work + a.world_row + t, voxels + a.world_row + t, convert_uchar8(out_a));
            if (b.valid)
                store_line8(work + b.world_row + t, voxels + b.world_row + t, convert_uchar8(out_b));
        }
#else
        if (a.valid)
            *(__global uchar8 *)(work + a.work_row + t) = convert_uchar8(out_a);
        if (b.valid)
            *(__global uchar8 *)(work + b.work_row + t) = convert_uchar8(out_b);
#endif
    }
}

#else
#define NSEG LOCAL_Y
/* y or z: each work-item sweeps VEC adjacent x-columns, two per 32-bit word,
 * so a warp touches 32 * VEC contiguous bytes of a row. */
#define CAT_(a, b) a##b
#define CAT(a, b) CAT_(a, b)
#define ucharV CAT(uchar, VEC)
#define ushortV CAT(ushort, VEC)
#define intV CAT(int, VEC)
#define convert_ucharV CAT(convert_uchar, VEC)
#define convert_ushortV CAT(convert_ushort, VEC)
#define as_ushortV CAT(as_ushort, VEC)
#if VEC == 2
#define LANE_OFFSETS ((int2)(0, 1))
#elif VEC == 4
#define LANE_OFFSETS ((int4)(0, 1, 2, 3))
#else
#define LANE_OFFSETS ((int8)(0, 1, 2, 3, 4, 5, 6, 7))
#endif
#if VEC == 2
#define wordV uint
#define as_wordV as_uint
#define MINV min_u16x2
#elif VEC == 4
#define wordV uint2
#define as_wordV as_uint2
#define MINV min_u16x2_v2
#elif VEC == 8
#define wordV uint4
#define as_wordV as_uint4
#define MINV min_u16x2_v4
#else
#error VEC must be 2, 4 or 8
#endif

__kernel GROUP_SHAPE void pass_yz(__global uchar *work, __global const uchar *voxels,
                      __global ushort *field, int4 dims, int4 w_lo, int4 w_n,
                      int4 r_lo, int4 r_hi, int seeded, int cap, int plane, int4 world_lo, int4 world_hi,
                      int8 slots, long voxel_stride, long work_stride)
{
    SLOT_PROLOGUE;
    __local wordV scan[4 * LOCAL_X * LOCAL_Y];
    const int seg = get_local_id(1);
    __local wordV *line_scan = scan + 4 * NSEG * get_local_id(0);
    const int lx = get_global_id(0) * VEC;
    const int valid = lx < w_n.x;
#if AXIS == 1
    const int ly = 0, lz = get_group_id(1);
    const int len = w_n.y;
    const size_t stride = (size_t)w_n.x;
#else
    const int ly = get_group_id(1), lz = 0;
    const int len = w_n.z;
    const size_t stride = (size_t)plane;
#endif
    const size_t base = (size_t)lz * (size_t)plane + (size_t)ly * (size_t)w_n.x + (size_t)lx;
    const int t0 = seg * SEG;

#if AXIS == 1
#define WORLD_AT(t) world_index(w_lo.x + lx, w_lo.y + (t), w_lo.z + lz, dims)
#define IN_R(t) (lane_in_r && w_lo.y + (t) >= r_lo.y && w_lo.y + (t) < r_hi.y)
    const int lane_in_r = w_lo.z + lz >= r_lo.z && w_lo.z + lz < r_hi.z;
#else
#define WORLD_AT(t) world_index(w_lo.x + lx, w_lo.y + ly, w_lo.z + (t), dims)
#define IN_R(t) (lane_in_r && w_lo.z + (t) >= r_lo.z && w_lo.z + (t) < r_hi.z)
    const int lane_in_r = w_lo.y + ly >= r_lo.y && w_lo.y + ly < r_hi.y;
#endif
    /* x-lanes are VEC-aligned and R's x-bounds are multiples of 8: a lane is all in or all out. */
    const int lane_x_in_r = w_lo.x + lx >= r_lo.x && w_lo.x + lx < r_hi.x;

    wordV d[SEG];
    _Pragma("unroll") for (int k = 0; k < SEG; ++k) {
        const int t = t0 + k;
        if (valid && t < len) {
#if FIRST
            const size_t i = WORLD_AT(t);
            const ushortV v = convert_ushortV(*(__global const ucharV *)(voxels + i));
            ushortV init = select((ushortV)(INVERT ? 0 : cap), (ushortV)(INVERT ? cap : 0), v != (ushortV)(0));
            if (seeded && !(lane_x_in_r && IN_R(t))) {  /* the seed shell */
                const ushortV shell = min(*(__global const ushortV *)(field + i) >> (ushort)8, (ushortV)(cap));
                init = SIGNED_WORLD ? select(shell, init, init == (ushortV)(0)) : shell;
            }
            d[k] = as_wordV(init);
#else
            d[k] = as_wordV(convert_ushortV(*(__global const ucharV *)(work + base + (size_t)t * stride)));
#endif
        } else {
            d[k] = (wordV)(BIG2);
        }
    }

    SWEEP_SEGMENT(wordV, MINV, d, line_scan, seg);

    const wordV capv = (wordV)((uint)cap * ONES);
    _Pragma("unroll") for (int k = 0; k < SEG; ++k) {
        const int t = t0 + k;
        if (!valid || t >= len)
            continue;
        const wordV out = MINV(d[k], capv);
#if LAST
        if (lane_x_in_r && IN_R(t)) {
            const size_t i = WORLD_AT(t);
#if INVERT
            const ushortV v = convert_ushortV(*(__global const ucharV *)(voxels + i));
            if (any(v != (ushortV)(0))) {
                const int y = AXIS == 1 ? w_lo.y + t : w_lo.y + ly, z = AXIS == 1 ? w_lo.z + lz : w_lo.z + t;
                const int face_yz = min(min(y + 1 - world_lo.y, world_hi.y - y), min(z + 1 - world_lo.z, world_hi.z - z));
                const intV x = (intV)(w_lo.x + lx) + LANE_OFFSETS;
                const intV face = min(min(x + (intV)(1 - world_lo.x), (intV)(world_hi.x) - x), (intV)(min(face_yz, cap)));
                const ushortV inside = min(as_ushortV(out), convert_ushortV(face));
                const ushortV old = *(__global const ushortV *)(field + i);
                *(__global ushortV *)(field + i) = select(old, (inside << (ushort)8) | v, v != (ushortV)(0));
            }
            continue;
#endif
            /* Only solids (distance 0) carry a colour: air-only lanes skip the voxel read. */
            const wordV colour = any(as_ushortV(out) == (ushortV)(0))
                ? as_wordV(convert_ushortV(*(__global const ucharV *)(voxels + i))) : (wordV)(0);
            *(__global wordV *)(field + i) = (out << 8) | colour;
        }
#else
        *(__global ucharV *)(work + base + (size_t)t * stride) = convert_ucharV(as_ushortV(out));
#endif
    }
}
#endif
