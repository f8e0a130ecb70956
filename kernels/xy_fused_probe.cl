/* Feasibility prototype: the exact Manhattan transform's x and y passes as
 *   bits_pass  voxels (1 B/voxel) -> one bit per voxel (solid = 1), rows of 32-bit words
 *   fused_xy   bits -> the uint8 scratch the project's z pass reads (kernels/exact.cl's `work`
 *              after its y pass: x then y min-plus transforms of each z plane, capped at cap)
 * The project's own pass_x + y pass are run from sdfserver (probe.py), not from here.
 *
 * Layouts (nx multiple of 8, any ny <= the tile's rows, any nz):
 *   voxels  uchar [z][y][x]
 *   bits    uint  [z][y][NW], NW = ceil(nx / 32); bit (x % 32) of word x / 32; zero past nx.
 *           bits_pass writes it as ushort halves (a warp reads 512 contiguous voxel bytes and
 *           writes 64 contiguous bytes; little-endian halves of a word).
 *   work    uchar, plane z at z * plane, row y at y * nx (plane = nx * ny + 32, as sdfserver's).
 *
 * fused_xy: one work-group of 256 items per (tile of TX columns along x, z plane); the tile's
 * rows 0..SYT-1 (SYT >= ny) sit in local memory as uchar, row y at word ROW(y) (row stride RSW
 * words, plus SPAD words per segment of SEG rows: the host picks both so neither phase has bank
 * conflicts).
 *   Phase 1: an item takes two rows (p and p + SYT/2), one per 16-bit lane of a word: it reads
 *     the rows' TX/32 tile words, finds the nearest solid left of the tile and right of it within
 *     HW = ceil(cap/32) words (loads only while not found: the halo), and sweeps the TX columns
 *     forward and backward (init cap on air, 0 on solid, so no value exceeds cap), storing gx as
 *     bytes (one uint of 4 columns per row per store, 32 lanes on 32 rows: conflict-free).
 *   Phase 2: item (lane l, segment s) holds 2 columns (x0 + 2l, +1) in 16-bit lanes over SEG
 *     rows in registers (one ushort local load a row: a warp reads a row's 64 contiguous bytes);
 *     forward/backward sweeps, segment carries scanned through local memory as in exact.cl.
 *   Output: PHASE3 0 writes each item's ushort straight to global (a warp writes 2*LANES
 *     contiguous bytes of a row, whole 32-byte sectors); PHASE3 1 puts the results back into the
 *     tile and writes its rows as 8-byte chunks.
 * Build defines: TX, SYT, SEG, NSEG, LANES (= TX/2), RSW, SPAD, HW, TILE_WORDS, PHASE3,
 * SDF_PTX_16X2.
 */
#define BIG 0x3fffu
#define ONES 0x00010001u
#define BIG2 (BIG * ONES)
#define GROUP 256

#if SDF_PTX_16X2
inline uint min_u16x2(uint a, uint b)
{
    uint r;
    asm("min.u16x2 %0, %1, %2;" : "=r"(r) : "r"(a), "r"(b));
    return r;
}
inline uint prmt(uint a, uint b, uint sel)
{
    uint r;
    asm("prmt.b32 %0, %1, %2, %3;" : "=r"(r) : "r"(a), "r"(b), "r"(sel));
    return r;
}
#else
inline uint min_u16x2(uint a, uint b) { return as_uint(min(as_ushort2(a), as_ushort2(b))); }
/* PTX prmt without sign replication: byte k of the result is byte (sel >> 4k) & 7 of {b, a}. */
inline uint prmt(uint a, uint b, uint sel)
{
    const ulong ab = ((ulong)b << 32) | a;
    uint r = 0;
    for (int k = 0; k < 4; ++k)
        r |= (uint)((ab >> (8 * ((sel >> (4 * k)) & 7))) & 0xff) << (8 * k);
    return r;
}
#endif

/* ---------------------------------------------------------------- bits pass */

/* 4 bits (bit k: byte k != 0) of a word of 4 voxels. */
inline uint nibble(uint v)
{
    const uint t = ((v & 0x7f7f7f7fu) + 0x7f7f7f7fu) | v;
    return (((t >> 7) & 0x01010101u) * 0x01020408u) >> 24;
}

/* global (>= nh, >= rows), one item per 16 voxels of a row; nh = 2 * NW halfwords a row. */
__kernel void bits_pass(__global const uchar *voxels, __global ushort *bits16, int nx, int nh, int rows)
{
    const int h = get_global_id(0), r = get_global_id(1);
    if (h >= nh || r >= rows)
        return;
    const int x = 16 * h;
    uint out = 0;
    if (x < nx) {
        __global const uchar *p = voxels + (size_t)r * (size_t)nx + (size_t)x;
        uint4 v;
        if (x + 16 <= nx) {
            if ((nx & 15) == 0) {
                v = *(__global const uint4 *)p;
            } else {
                const uint2 a = *(__global const uint2 *)p, b = *(__global const uint2 *)(p + 8);
                v = (uint4)(a, b);
            }
        } else {  /* nx % 16 == 8: the row's last 8 voxels */
            v = (uint4)(*(__global const uint2 *)p, 0u, 0u);
        }
        out = nibble(v.x) | (nibble(v.y) << 4) | (nibble(v.z) << 8) | (nibble(v.w) << 12);
    }
    bits16[(size_t)r * (size_t)nh + (size_t)h] = (ushort)out;
}

/* ---------------------------------------------------------------- fused x+y pass */
#ifdef TX

#define TW (TX / 32)      /* tile words a row */
#define HALF (SYT / 2)    /* row pairs */
#define ROW(y) ((y) * RSW + ((y) / SEG) * SPAD)  /* a tile row's first word */

/* The 1-D transform of one line cut into NSEG segments of SEG elements (kernels/exact.cl,
 * SWEEP_SEGMENT, unchanged but for the macro name): scan -> 4 * NSEG words of this line. */
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
        const T from_left_ = (seg) > 0                                                 \
            ? fr_[(seg) - 1] - (uint)((NSEG - (seg)) * SEG - 1) * ONES : (T)(BIG2);    \
        const T from_right_ = (seg) < NSEG - 1                                         \
            ? br_[(seg) + 1] - (uint)((seg) * SEG) * ONES : (T)(BIG2 + SEG * ONES);    \
        _Pragma("unroll") for (int k = 0; k < SEG; ++k)                                \
            d[k] = MIN(d[k], MIN(from_left_ + (uint)k * ONES, from_right_ - (uint)k * ONES)); \
    } while (0)

/* One row of the tile for phase 1: its TW words and its distances to the nearest solid left of
 * the tile (from column x0 - 1) and right of it (from column x0 + TX), BIG when none lies within
 * HW words (then none lies within cap). Rows past ny are all air with no solid anywhere. */
inline void tile_row(__global const uint *bits, int y, int ny, int z, int nw, int w0,
                     uint *w, uint *left, uint *right)
{
    _Pragma("unroll") for (int k = 0; k < TW; ++k)
        w[k] = 0u;
    *left = *right = BIG;
    if (y >= ny)
        return;
    __global const uint *row = bits + ((size_t)z * (size_t)ny + (size_t)y) * (size_t)nw;
    _Pragma("unroll") for (int k = 0; k < TW; ++k)
        if (w0 + k < nw)
            w[k] = row[w0 + k];
    uint l = BIG, r = BIG;
    /* The halo: the few words beyond the tile, read only while the nearest solid is unknown. */
    _Pragma("unroll") for (int k = 1; k <= HW; ++k) {
        if (l == BIG && w0 - k >= 0) {
            const uint v = row[w0 - k];
            if (v)
                l = 32u * (uint)(k - 1) + clz(v);  /* (x0 - 1) - (32 (w0 - k) + 31 - clz) */
        }
        if (r == BIG && w0 + TW - 1 + k < nw) {
            const uint v = row[w0 + TW - 1 + k];
            if (v)
                r = 32u * (uint)(k - 1) + (31u - clz(v & (0u - v)));  /* ctz */
        }
    }
    *left = l;
    *right = r;
}

__kernel __attribute__((reqd_work_group_size(GROUP, 1, 1)))
void fused_xy(__global const uint *bits, __global uchar *work, int nx, int ny, int nw, int plane, int cap)
{
    __local uint tile[TILE_WORDS];
    const int lid = get_local_id(0);
    const int x0 = get_group_id(0) * TX;
    const int z = get_group_id(1);
    const int w0 = x0 >> 5;
    const uint capw = (uint)cap * ONES;

    /* Phase 1: gx of rows p (low lanes) and p + HALF (high lanes). */
    for (int p = lid; p < HALF; p += GROUP) {
        uint wa[TW], wb[TW], la, lb, ra, rb;
        tile_row(bits, p, ny, z, nw, w0, wa, &la, &ra);
        tile_row(bits, p + HALF, ny, z, nw, w0, wb, &lb, &rb);
        /* The solids of 16 columns of both rows, one per 16-bit lane: bit c of each lane. */
        uint solid[TX / 16];
        _Pragma("unroll") for (int q = 0; q < TX / 16; ++q)
            solid[q] = (q & 1) ? prmt(wa[q >> 1], wb[q >> 1], 0x7632) : prmt(wa[q >> 1], wb[q >> 1], 0x5410);
        uint f[TX];
        uint run = min(la, BIG) | (min(lb, BIG) << 16);
        _Pragma("unroll") for (int c = 0; c < TX; ++c) {
            const uint air = (~solid[c >> 4] >> (c & 15)) & ONES;
            run = min_u16x2(run + ONES, air * (uint)cap);
            f[c] = run;
        }
        run = ra | (rb << 16);
        _Pragma("unroll") for (int c = TX - 1; c >= 0; --c) {
            const uint air = (~solid[c >> 4] >> (c & 15)) & ONES;
            run = min_u16x2(run + ONES, air * (uint)cap);
            f[c] = min_u16x2(f[c], run);
        }
        __local uint *rowa = tile + ROW(p), *rowb = tile + ROW(p + HALF);
        _Pragma("unroll") for (int g = 0; g < TX / 4; ++g) {
            /* bytes 0 and 2 of f[4g..4g+3]: row a's 4 columns, row b's 4 columns */
            const uint lo = prmt(f[4 * g], f[4 * g + 1], 0x6240), hi = prmt(f[4 * g + 2], f[4 * g + 3], 0x6240);
            rowa[g] = prmt(lo, hi, 0x5410);
            rowb[g] = prmt(lo, hi, 0x7632);
        }
    }
    barrier(CLK_LOCAL_MEM_FENCE);

    /* Phase 2: columns x0 + 2l and x0 + 2l + 1 along y, SEG rows per segment. */
    const int l = lid % LANES, s = lid / LANES;
    __local ushort *tile16 = (__local ushort *)tile;
    uint d[SEG];
    _Pragma("unroll") for (int k = 0; k < SEG; ++k) {
        const uint v = tile16[2 * ROW(s * SEG + k) + l];
        d[k] = (v & 0xffu) | ((v & 0xff00u) << 8);
    }
    barrier(CLK_LOCAL_MEM_FENCE);  /* the scan reuses the tile */
    SWEEP_SEGMENT(uint, min_u16x2, d, tile + 4 * NSEG * l, s);
    /* values never exceed cap: every input does not */

#if PHASE3
    barrier(CLK_LOCAL_MEM_FENCE);
    _Pragma("unroll") for (int k = 0; k < SEG; ++k)
        tile16[2 * ROW(s * SEG + k) + l] = (ushort)prmt(d[k], 0u, 0x0020);
    barrier(CLK_LOCAL_MEM_FENCE);
#define CPR (TX / 8)  /* 8-byte chunks a row */
    for (int i = lid; i < SYT * CPR; i += GROUP) {
        const int y = i / CPR, c = i % CPR;
        if (y < ny && x0 + 8 * c < nx) {
            const uint2 v = (uint2)(tile[ROW(y) + 2 * c], tile[ROW(y) + 2 * c + 1]);
            *(__global uint2 *)(work + (size_t)z * (size_t)plane + (size_t)y * (size_t)nx + (size_t)(x0 + 8 * c)) = v;
        }
    }
#else
    if (x0 + 2 * l < nx) {
        __global uchar *out = work + (size_t)z * (size_t)plane + (size_t)(x0 + 2 * l);
        _Pragma("unroll") for (int k = 0; k < SEG; ++k) {
            const int y = s * SEG + k;
            if (y < ny)
                *(__global ushort *)(out + (size_t)y * (size_t)nx) = (ushort)prmt(d[k], 0u, 0x0020);
        }
    }
#endif
}
#endif
