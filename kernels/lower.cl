/* Lowering a Manhattan field after edits that only add solids.
 *
 * Adding solids can only lower distances: with S the solid voxels of an edited box D, the new
 * field is min(old, T_S), T_S the capped distance to S, and it changes only where T_S < cap —
 * within the cap of D, a rounded octahedron about a sixth of D grown by the cap. T_S is
 * separable like any L1 transform, and its seeds lie in D, so each stage is small:
 *   lower_x   lines along x through D's (y, z) footprint, x over G = D grown by the cap:  t1
 *   lower_y   lines along y, (x, z) over G's x and D's z-range, y over G:                t2
 *   lower_z   each (x, y) column of G, z only where the column is within the cap of D:
 *             field = pack(min(old, T), voxel), written where it is lower or inside D
 *             (where a voxel's colour may have changed).
 * Each stage is a 1-D transform along its axis of values given inside D's range there, so every
 * output costs O(1) whatever D's size: inside that range it is the forward and backward sweeps
 * d = min(own, neighbour + 1), outside it a closed form of the sweeps' end values. lower_x sweeps
 * a row with a work-group's lanes (a scan); lower_y and lower_z give each line to a few
 * work-items ("shares") that sweep their own parts, each starting from the minima over the rest
 * of D's range (about D's depth in reads, so the host gives each share a few times as many
 * outputs).
 * Layouts: t1[(z * d_n.y + y) * g_n.x + x] (z, y in D; x in G),
 *          t2[(z * g_n.y + y) * g_n.x + x] (z in D; x, y in G), all relative to their boxes.
 */
#include "sdf_common.h"

/* Beyond any distance a stage adds up, as a position or a minimum with none to take. */
#define FAR (1 << 20)
/* lower_x's work-group: the lanes sharing one row (host: algorithms/lower.py ROW_LANES). */
#define ROW_LANES 64

/* |a - b| as an int (OpenCL's abs of an int is a uint, which min would not mix with an int). */
inline int gap(int a, int b) { return a > b ? a - b : b - a; }

/* The distance along x from wx to the nearest solid of the row's n voxels from x0 (`row` its
 * first), capped. */
inline int nearest_along_x(__global const uchar *voxels, size_t row, int x0, int n, int wx, int cap)
{
    int best = cap;
    for (int i = 0; i < n; ++i)
        if (voxels[row + i])
            best = min(best, gap(wx, x0 + i));
    return best;
}

/* The inclusive scan of v across the group's lanes: by max from lane 0 up with `up`, else by min
 * from the last lane down; *whole is the group's result (Hillis and Steele). */
inline int scan_lanes(__local int *lanes, int v, int lane, bool up, int *whole)
{
    lanes[lane] = v;
    barrier(CLK_LOCAL_MEM_FENCE);
    for (int step = 1; step < ROW_LANES; step <<= 1) {
        const int from = up ? lane - step : lane + step;
        const int other = from >= 0 && from < ROW_LANES ? lanes[from] : v;
        barrier(CLK_LOCAL_MEM_FENCE);
        v = up ? max(v, other) : min(v, other);
        lanes[lane] = v;
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    *whole = lanes[up ? ROW_LANES - 1 : 0];
    barrier(CLK_LOCAL_MEM_FENCE);
    return v;
}

/* One work-group a row of D (global (ROW_LANES, d_n.y, d_n.z)): inside D's x-range the nearest
 * solid before each voxel (a forward scan of positions by max) and after it (backward, by min),
 * each lane keeping the same voxels both ways; outside it, the row's first or last solid. */
__kernel __attribute__((reqd_work_group_size(ROW_LANES, 1, 1)))
void lower_x(__global const uchar *voxels, __global uchar *t1, int4 dims, int4 d_lo, int4 d_n,
             int4 g_lo, int4 g_n, int cap)
{
    __local int lanes[ROW_LANES];
    const int lane = get_local_id(0), y = get_group_id(1), z = get_group_id(2);
    const size_t row = world_index(0, d_lo.y + y, d_lo.z + z, dims);
    __global uchar *out = t1 + ((size_t)z * d_n.y + y) * g_n.x;  /* out[wx - g_lo.x] */
    const int dl = d_lo.x, dh = d_lo.x + d_n.x;
    int last = -FAR, first = FAR, whole;
    for (int s = dl; s < dh; s += ROW_LANES) {
        const int wx = s + lane;
        const bool in = wx < dh;
        const int before = max(scan_lanes(lanes, in && voxels[row + wx] ? wx : -FAR, lane, true, &whole), last);
        last = max(last, whole);
        if (in)
            out[wx - g_lo.x] = (uchar)min(cap, wx - before);
    }
    for (int s = dl + (d_n.x - 1) / ROW_LANES * ROW_LANES; s >= dl; s -= ROW_LANES) {
        const int wx = s + lane;
        const bool in = wx < dh;
        const int after = min(scan_lanes(lanes, in && voxels[row + wx] ? wx : FAR, lane, false, &whole), first);
        first = min(first, whole);
        if (in)
            out[wx - g_lo.x] = (uchar)min((int)out[wx - g_lo.x], after - wx);
    }
    for (int wx = g_lo.x + lane; wx < g_lo.x + g_n.x; wx += ROW_LANES) {
        if (wx < dl)
            out[wx - g_lo.x] = (uchar)min(cap, first - wx);
        else if (wx >= dh)
            out[wx - g_lo.x] = (uchar)min(cap, wx - last);
    }
}

/* A share's part [w0, w1) of a line whose values inside D's range [dl, dh) along it are
 * src[(k - dl) * stride]: T(w) = min over k of src(k) + |w - k| is hi - w before D (hi: the
 * minimum of src(k) + k), lo + w after it (lo: of src(k) - k), and inside it the lesser of the
 * two taken over k up to w (lo) and from w on (hi). The part's [a, b) inside D is swept backward
 * here, its hi - k kept in `later` (same indexing), which leaves hi the minimum from a on; lo
 * starts as the minimum before a (D's voxels outside the part, read here, are other shares' to
 * sweep), for the forward sweep to take on through the part, and lo_after is where it ends. */
typedef struct { int a, b, lo, hi, lo_after; } line_part;

inline line_part begin_part(__global const uchar *src, __global uchar *later, size_t stride, int dl, int dh,
                            int w0, int w1)
{
    line_part p = { clamp(w0, dl, dh), clamp(w1, dl, dh), FAR, FAR, FAR };
    __global const uchar *at = src;
    for (int k = dl; k < p.a; ++k, at += stride)
        p.lo = min(p.lo, (int)*at - k);
    at = src + (size_t)(p.b - dl) * stride;
    for (int k = p.b; k < dh; ++k, at += stride)
        p.hi = min(p.hi, (int)*at + k);
    at = src + (size_t)(p.b - dl) * stride;
    __global uchar *keep = later + (size_t)(p.b - dl) * stride;
    p.lo_after = p.lo;
    for (int k = p.b - 1; k >= p.a; --k) {
        at -= stride;
        keep -= stride;
        const int own = *at;
        p.hi = min(p.hi, own + k);
        p.lo_after = min(p.lo_after, own - k);
        *keep = (uchar)(p.hi - k);
    }
    return p;
}

/* T at w (uncapped), for w rising through the part from w0 or, where it is before D, any later w;
 * `at` and `kept` point at src(a) and later(a), and move on inside D. */
inline int part_value(line_part *p, __global const uchar **at, __global const uchar **kept, size_t stride, int w)
{
    if (w < p->a)
        return p->hi - w;
    if (w >= p->b)
        return p->lo_after + w;
    p->lo = min(p->lo, (int)**at - w);
    const int t = min(p->lo + w, (int)**kept);
    *at += stride;
    *kept += stride;
    return t;
}

/* Global (g_n.x, d_n.z, shares): each (x, z) line along y over G. The backward sweep's values go
 * straight into t2, where the forward sweep overwrites them with T. */
__kernel void lower_y(__global const uchar *t1, __global uchar *t2, int4 d_lo, int4 d_n, int4 g_lo, int4 g_n,
                      int cap)
{
    const int x = get_global_id(0), z = get_global_id(1);
    if (x >= g_n.x || z >= d_n.z)
        return;
    const int share = (g_n.y + (int)get_global_size(2) - 1) / (int)get_global_size(2);
    const int w0 = g_lo.y + (int)get_global_id(2) * share, w1 = min(w0 + share, g_lo.y + g_n.y);
    const size_t stride = g_n.x;
    __global const uchar *src = t1 + (size_t)z * d_n.y * g_n.x + x;
    __global uchar *out = t2 + (size_t)z * g_n.y * g_n.x + x;  /* out[(w - g_lo.y) * stride] */
    __global uchar *later = out + (size_t)(d_lo.y - g_lo.y) * stride;
    line_part p = begin_part(src, later, stride, d_lo.y, d_lo.y + d_n.y, w0, w1);
    __global const uchar *at = src + (size_t)(p.a - d_lo.y) * stride, *kept = later + (size_t)(p.a - d_lo.y) * stride;
    out += (size_t)(w0 - g_lo.y) * stride;
    for (int w = w0; w < w1; ++w, out += stride)
        *out = (uchar)min(part_value(&p, &at, &kept, stride, w), cap);
}

/* The z-range of the work-group's (x, y) columns within the cap of D: its nearest column's, so
 * that adjacent x walk the same z (coalesced); empty where none is within it. */
inline int2 group_z_range(int4 dims, int4 d_lo, int4 d_hi, int4 g_lo, int4 g_n, int cap)
{
    const int x0 = g_lo.x + (int)(get_group_id(0) * get_local_size(0));
    const int y0 = g_lo.y + (int)(get_group_id(1) * get_local_size(1));
    const int x1 = min(x0 + (int)get_local_size(0), g_lo.x + g_n.x) - 1;
    const int y1 = min(y0 + (int)get_local_size(1), g_lo.y + g_n.y) - 1;
    const int reach = cap - max(max(d_lo.x - x1, x0 - (d_hi.x - 1)), 0) - max(max(d_lo.y - y1, y0 - (d_hi.y - 1)), 0);
    if (reach <= 0)
        return (int2)(0, 0);
    return (int2)(max(d_lo.z - reach, 0), min(d_hi.z + reach, dims.z));
}

/* Global (g_n.x, g_n.y, shares): each (x, y) column of G within the cap of D, its work-group's
 * z-range cut into shares. Before and after D only where T is below the cap (the field is capped,
 * so nothing lowers beyond); inside D every voxel, as lo runs on. `later` is scratch laid out as
 * t2. */
__kernel void lower_z(__global const uchar *t2, __global uchar *later, __global const uchar *voxels,
                      __global ushort *field, int4 dims, int4 d_lo, int4 d_n, int4 g_lo, int4 g_n, int cap)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= g_n.x || y >= g_n.y)
        return;
    const int wx = g_lo.x + x, wy = g_lo.y + y;
    const int4 d_hi = d_lo + d_n;
    /* the column's L1 distance to D's footprint: nothing nearer than the cap beyond its reach */
    const int dxy = max(max(d_lo.x - wx, wx - (d_hi.x - 1)), 0) + max(max(d_lo.y - wy, wy - (d_hi.y - 1)), 0);
    if (dxy >= cap)
        return;
    const int2 c = group_z_range(dims, d_lo, d_hi, g_lo, g_n, cap);
    const int share = (c.y - c.x + (int)get_global_size(2) - 1) / (int)get_global_size(2);
    const int z0 = c.x + (int)get_global_id(2) * share, z1 = min(z0 + share, c.y);
    const bool in_footprint = dxy == 0;
    const size_t stride = (size_t)g_n.y * g_n.x, column = (size_t)y * g_n.x + x;
    line_part p = begin_part(t2 + column, later + column, stride, d_lo.z, d_hi.z, z0, z1);
    __global const uchar *at = t2 + column + (size_t)(p.a - d_lo.z) * stride;
    __global const uchar *kept = later + column + (size_t)(p.a - d_lo.z) * stride;
    /* from where T = hi - wz is below the cap, to where lo_after + wz reaches it */
    const int from = max(z0, min(p.a, p.hi - cap + 1)), to = min(z1, max(p.b, cap - p.lo_after));
    const size_t plane = (size_t)dims.x * dims.y;
    size_t i = world_index(wx, wy, from, dims);
    for (int wz = from; wz < to; ++wz, i += plane) {
        const int t = min(part_value(&p, &at, &kept, stride, wz), cap);
        const bool recolour = in_footprint && wz >= d_lo.z && wz < d_hi.z;
        if (t == cap && !recolour)
            continue;
        const uint old = field[i] >> 8;
        if ((uint)t < old || recolour)
            field[i] = pack_field(min((uint)t, old), voxels[i]);
    }
}

/* The same for a Euclidean world, whose field is the last of three stages the world keeps
 * (kernels/edt.cl): the line (1-D distance along x, uchar, in `work`), the plane (min over z of
 * line^2 + dz^2, ushort, in `edt_plane`) and the field (min over y of plane + dy^2), each capped
 * (cap, cap^2). Every stage is a minimum, so with solids only added each becomes min(old, the
 * stage of S alone), written where lower: the stages the next recompute reads stay current.
 *   elower_x  the line of S over G's x for D's (y, z) footprint:            t1, and `line`
 *   elower_z  the plane of S for D's y-range, z over G:                     t2 (ushort), and `plane`
 *   elower_y  the field, each (x, z) column of G within the cap of D.
 * Layouts: t1 as lower_x's; t2[(z * d_n.y + y) * g_n.x + x] (z in G, y in D, x in G). */
__kernel void elower_x(__global const uchar *voxels, __global uchar *t1, __global uchar *line, int4 dims,
                       int4 d_lo, int4 d_n, int4 g_lo, int4 g_n, int cap)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= g_n.x || y >= d_n.y || z >= d_n.z)
        return;
    const int wx = g_lo.x + x;
    const int best = nearest_along_x(voxels, world_index(d_lo.x, d_lo.y + y, d_lo.z + z, dims), d_lo.x, d_n.x, wx, cap);
    t1[((size_t)z * d_n.y + y) * g_n.x + x] = (uchar)best;
    const size_t at = world_index(wx, d_lo.y + y, d_lo.z + z, dims);
    if (best < (int)line[at])
        line[at] = (uchar)best;
}

__kernel void elower_z(__global const uchar *t1, __global ushort *t2, __global ushort *plane, int4 dims,
                       int4 d_lo, int4 d_n, int4 g_lo, int4 g_n, int cap)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= g_n.x || y >= d_n.y || z >= g_n.z)
        return;
    const int wz = g_lo.z + z, cap2 = cap * cap;
    int best = cap2;
    for (int k = 0; k < d_n.z; ++k) {
        const int t = t1[((size_t)k * d_n.y + y) * g_n.x + x];
        if (t < cap) {
            const int dz = wz - (d_lo.z + k);
            best = min(best, t * t + dz * dz);
        }
    }
    t2[((size_t)z * d_n.y + y) * g_n.x + x] = (ushort)best;
    const size_t at = world_index(g_lo.x + x, d_lo.y + y, wz, dims);
    if (best < (int)plane[at])
        plane[at] = (ushort)best;
}

__kernel void elower_y(__global const ushort *t2, __global ushort *field, int4 dims, int4 d_lo, int4 d_n,
                       int4 g_lo, int4 g_n, int cap)
{
    const int x = get_global_id(0), z = get_global_id(1);
    if (x >= g_n.x || z >= g_n.z)
        return;
    const int wx = g_lo.x + x, wz = g_lo.z + z, cap2 = cap * cap;
    const int4 d_hi = d_lo + d_n;
    const int dx = max(max(d_lo.x - wx, wx - (d_hi.x - 1)), 0), dz = max(max(d_lo.z - wz, wz - (d_hi.z - 1)), 0);
    const int dxz2 = dx * dx + dz * dz;
    if (dxz2 >= cap2)
        return;
    /* past `reach` along y the distance to D alone reaches the cap */
    const int reach = (int)sqrt((float)(cap2 - dxz2)) + 1;
    const int c0 = max(d_lo.y - reach, 0), c1 = min(d_hi.y + reach, dims.y);
    const int share = (c1 - c0 + (int)get_global_size(2) - 1) / (int)get_global_size(2);
    const int y0 = c0 + (int)get_global_id(2) * share, y1 = min(y0 + share, c1);
    for (int wy = y0; wy < y1; ++wy) {
        int best = cap2;
        for (int k = 0; k < d_n.y; ++k) {
            const int dy = wy - (d_lo.y + k);
            best = min(best, (int)t2[((size_t)z * d_n.y + k) * g_n.x + x] + dy * dy);
        }
        const size_t at = world_index(wx, wy, wz, dims);
        if (best < (int)field[at])
            field[at] = (ushort)best;
    }
}

/* Where removing solids from D can raise the field: voxels within the cap of D whose distance is
 * below the cap and not below their distance to D (their nearest solid may have been in D); every
 * other voxel's nearest solid is still there. `euclid`: the field holds squared Euclidean
 * distances (a Euclidean world's), compared with the squared distance to D; else Manhattan ones.
 * Their bounding box, reduced in each work-group and then into bounds: min x, y, z, then max x, y,
 * z (inclusive). A transform of that box, seeded from the unchanged field around it, is exact.
 * Launched like lower_z. */
__kernel void raise_bounds(__global const ushort *field, int4 dims, int4 d_lo, int4 d_n, int4 g_lo, int4 g_n,
                           int cap, int euclid, __global int *bounds)
{
    __local int group[6];
    const int lid = get_local_id(0) + get_local_size(0) * (get_local_id(1) + get_local_size(1) * get_local_id(2));
    if (lid < 6)
        group[lid] = lid < 3 ? INT_MAX : INT_MIN;
    barrier(CLK_LOCAL_MEM_FENCE);
    const int x = get_global_id(0), y = get_global_id(1);
    int lo_z = INT_MAX, hi_z = INT_MIN;
    const int wx = g_lo.x + x, wy = g_lo.y + y;
    const int4 d_hi = d_lo + d_n;
    const int dx = max(max(d_lo.x - wx, wx - (d_hi.x - 1)), 0), dy = max(max(d_lo.y - wy, wy - (d_hi.y - 1)), 0);
    const int limit = euclid ? cap * cap : cap;
    const int dxy = euclid ? dx * dx + dy * dy : dx + dy;
    if (x < g_n.x && y < g_n.y && dxy < limit) {
        const int reach = euclid ? (int)sqrt((float)(limit - dxy)) + 1 : cap - dxy;
        const int c0 = max(d_lo.z - reach, 0), c1 = min(d_hi.z + reach, dims.z);
        const int share = (c1 - c0 + (int)get_global_size(2) - 1) / (int)get_global_size(2);
        const int z0 = c0 + (int)get_global_id(2) * share, z1 = min(z0 + share, c1);
        for (int wz = z0; wz < z1; ++wz) {
            const ushort value = field[world_index(wx, wy, wz, dims)];
            const int old = euclid ? value : value >> 8;
            const int dz = max(max(d_lo.z - wz, wz - (d_hi.z - 1)), 0);
            const int to_d = dxy + (euclid ? dz * dz : dz);
            if (old < limit && old >= to_d) {
                lo_z = min(lo_z, wz);
                hi_z = max(hi_z, wz);
            }
        }
    }
    if (lo_z <= hi_z) {
        atomic_min(&group[0], wx);
        atomic_min(&group[1], wy);
        atomic_min(&group[2], lo_z);
        atomic_max(&group[3], wx);
        atomic_max(&group[4], wy);
        atomic_max(&group[5], hi_z);
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    if (lid < 3 && group[lid] != INT_MAX)
        atomic_min(&bounds[lid], group[lid]);
    else if (lid >= 3 && lid < 6 && group[lid] != INT_MIN)
        atomic_max(&bounds[lid], group[lid]);
}
