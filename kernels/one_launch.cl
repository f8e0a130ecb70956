/* Small boxes in one launch: a work-group loads a whole box into local memory,
 * runs every pass of its algorithm there, barriers between passes, and writes
 * the result, so a small region costs one launch instead of one per pass (and,
 * for FIM, no host round trip to learn that a pass changed nothing).
 *
 * A box is the job's whole work box (one work-group), or with padding
 * (chunk > 0) one chunk of the region, one work-group per chunk: padded chunks
 * are computed alone, so work-groups never read each other's voxels. Groups
 * are numbered x fastest over the region's chunks, from `first_group`.
 *
 * Built with:
 *   ONE_LAUNCH_FLOOD  1: jump flooding (jfa.cl's passes, candidate order and
 *                     strict ties, so the same nearest seeds), then its resolve.
 *   ONE_LAUNCH_RELAX  1: FIM passes (fim.cl) until one changes nothing, on the
 *                     initial distances or on the flood's result.
 *   ONE_LAUNCH_WEIGHTED 0: every seed weighs nothing (jfa.py's
 *                     seeds_weigh_nothing), so no seed's weight is read.
 * The initial distances are init_work's and the write-back pack_region's
 * (region.cl), so the results are the multi-launch algorithms'.
 *
 * Work-items own column segments: item u of a box's `units` takes column
 * u % (n.x * n.y) and z-segment u / (n.x * n.y), and walks its segment in z
 * (a flood pass's items take pieces of chains instead: flood_pass).
 * FIM relaxes in place and alternates the walk's direction pass by pass, so a
 * distance travels a whole segment in one pass; any order of in-place
 * relaxation reaches the same least fixed point.
 *
 * A seed is its box coordinates packed into a ushort, ceil(log2(side)) bits
 * per axis; SEED_NONE when none is known (the host sees that no seed packs to
 * it: one_launch.py's SEED_BITS).
 *
 * ONE_LAUNCH_CREW 1: one box (no padding), too much work for one compute
 * unit, taken by a crew of work-groups (crew.h). Each member holds the whole
 * box in its local memory and runs its share of the units of each step (the
 * initial distances, each pass); it writes that share to global memory
 * (`crew_seeds`: a flood pass's seeds, two halves in turn, so a member still
 * reading one pass's seeds never sees the next's; `crew_dist`: distances),
 * and after a crew barrier every member copies what it reads back into local
 * memory (a FIM pass: the planes around its share). What is cheap for the
 * whole box (the flood's first seeds, its resolve) each member does for all
 * of it. FIM passes read what
 * other members wrote in the pass before; a late copy can only see smaller
 * distances, which relaxation allows, and a pass that changed nothing anywhere
 * still proves the fixed point. */
#include "sdf_common.h"
#include "chunk_padding.h"
#include "crew.h"

#ifndef ONE_LAUNCH_CREW
#define ONE_LAUNCH_CREW 0
#endif


#define SEED_NONE 0xffffu

typedef struct {
    int4 n;        /* the box's extent */
    int nxy;       /* columns */
    int seg_len;   /* z-planes a work-item walks per column segment */
    int units;     /* column segments */
    int bx, bxy;   /* seed packing: bits for x, for x and y */
} Box;

/* `items`: the work-items that share the box's units (a crew's, or a group's). */
inline Box make_box(int4 n, int items)
{
    Box b;
    b.n = n;
    b.nxy = n.x * n.y;
    const int segments = items >= b.nxy ? min(n.z, items / b.nxy) : 1;
    b.seg_len = (n.z + segments - 1) / segments;
    b.units = b.nxy * segments;
    b.bx = n.x > 1 ? 32 - clz(n.x - 1) : 0;
    b.bxy = b.bx + (n.y > 1 ? 32 - clz(n.y - 1) : 0);
    return b;
}

inline int local_index(int x, int y, int z, const Box *b)
{
    return (z * b->n.y + y) * b->n.x + x;
}

/* Work-item's unit u: its column (x, y) and z-planes [z0, z1). */
inline void unit_span(int u, const Box *b, int *x, int *y, int *z0, int *z1)
{
    const int c = u % b->nxy;
    *x = c % b->n.x;
    *y = c / b->n.x;
    *z0 = (u / b->nxy) * b->seg_len;
    *z1 = min(b->n.z, *z0 + b->seg_len);
}

#if ONE_LAUNCH_FLOOD
#include "one_launch_flood.h"
#endif

#if ONE_LAUNCH_RELAX
/* fim_pass over the box until a pass changes nothing; returns the passes that
 * changed something. `flags` (a crew's: the control block's) holds three pass
 * flags in rotation: pass p sets flags[p % 3] and clears flags[(p + 1) % 3],
 * which everyone read before the barrier that ended pass p - 1, so one barrier
 * a pass suffices. A crew member relaxes its share and writes what changed
 * to `shared_dist` too; after the barrier it copies the whole box back. */
inline int relax(__local uchar *dist, __local volatile int *local_flags, const Box *b,
                 __global uchar *shared_dist, volatile __global int *crew, Crew *c)
{
    int first, last;
    crew_share(b->units, c, &first, &last);
#if ONE_LAUNCH_CREW
    volatile __global int *flags = crew + CREW_FLAGS;
    /* A share's units lie in z-segments [first, last) / nxy: it reads the planes from one below
     * them to one above, which is all it copies back after a pass (as 16-byte words). */
    const int plane_lo = max(first / b->nxy * b->seg_len - 1, 0);
    const int plane_hi = min(((last - 1) / b->nxy + 1) * b->seg_len + 1, b->n.z);
    const int words_lo = plane_lo * b->nxy / 16, words_hi = (plane_hi * b->nxy + 15) / 16;
    for (int u = first + get_local_id(0); u < last; u += get_local_size(0)) {
        int x, y, z0, z1;
        unit_span(u, b, &x, &y, &z0, &z1);
        for (int z = z0; z < z1; ++z)
            shared_dist[local_index(x, y, z, b)] = dist[local_index(x, y, z, b)];
    }
#else
    __local volatile int *flags = local_flags;
    if (get_local_id(0) < 3)
        flags[get_local_id(0)] = 0;
    barrier(CLK_LOCAL_MEM_FENCE);
#endif
    const int sy = b->n.x, sz = b->nxy;
    int pass = 0;
    for (;;) {
        int changed = 0;
        const int up = (pass & 1) == 0;
        for (int u = first + get_local_id(0); u < last; u += get_local_size(0)) {
            int x, y, z0, z1;
            unit_span(u, b, &x, &y, &z0, &z1);
            for (int k = 0; k < z1 - z0; ++k) {
                const int z = up ? z0 + k : z1 - 1 - k;
                const int i = local_index(x, y, z, b);
                const uint here = dist[i];
                if (here == 0u)
                    continue;
                uint best = here;
                if (x > 0) best = min(best, (uint)dist[i - 1] + 1u);
                if (x + 1 < b->n.x) best = min(best, (uint)dist[i + 1] + 1u);
                if (y > 0) best = min(best, (uint)dist[i - sy] + 1u);
                if (y + 1 < b->n.y) best = min(best, (uint)dist[i + sy] + 1u);
                if (z > 0) best = min(best, (uint)dist[i - sz] + 1u);
                if (z + 1 < b->n.z) best = min(best, (uint)dist[i + sz] + 1u);
                if (best < here) {
                    dist[i] = (uchar)best;
#if ONE_LAUNCH_CREW
                    shared_dist[i] = (uchar)best;
#endif
                    changed = 1;
                }
            }
        }
        if (changed)
            flags[pass % 3] = 1;
        if (get_local_id(0) == 0 && c->member == 0)
            flags[(pass + 1) % 3] = 0;
#if ONE_LAUNCH_CREW
        crew_barrier(crew, c);
#else
        barrier(CLK_LOCAL_MEM_FENCE);
#endif
        const int any = flags[pass % 3];
        ++pass;
        if (!any)
            return pass - 1;
#if ONE_LAUNCH_CREW
        crew_gather((__local uint4 *)dist, (volatile __global const uint4 *)shared_dist, words_lo, words_hi);
#endif
    }
}
#endif

/* `n`: a box's extent (the work box, or the chunk when padded). `to_work`: write
 * the distances into `work` at work-box coordinates (pack_region writes the
 * field later: a run in pieces), else the field over R. `passes`: the FIM
 * passes that changed something, the most of any group (atomic_max over a
 * zeroed int where `accumulate`, else written). `crew_seeds`, `crew_dist`,
 * `crew`: a crew's exchange and control block (unused without ONE_LAUNCH_CREW). */
__kernel void one_launch(__global const uchar *voxels, __global ushort *field, __global uchar *work,
                         int4 dims, int4 w_lo, int4 w_n, int4 r_lo, int4 r_hi, int4 n,
                         int seeded, int cap, int chunk, int first_group, int to_work,
                         int first_step, int extra_passes, __global int *passes, int accumulate,
                         __local uchar *dist, __local ushort *seeds_a, __local ushort *seeds_b,
                         __global ushort *crew_seeds, __global uchar *crew_dist, volatile __global int *crew)
{
    __local volatile int flags[3];
#if ONE_LAUNCH_CREW
    Crew c = crew_join(crew, flags);
    if (c.member < 0) {
        crew_finish(crew);
        return;
    }
    const Box b = make_box(n, (int)get_local_size(0) * c.members);
    const int group = 0;
#else
    Crew c = {0, 1, 0};
    const Box b = make_box(n, (int)get_local_size(0));
    const int group = first_group + (int)get_group_id(0);
#endif
    const int gx = w_n.x / n.x, gy = w_n.y / n.y;
    const int4 o = (int4)(group % gx * n.x, group / gx % gy * n.y, group / (gx * gy) * n.z, 0);

#if ONE_LAUNCH_CREW
    {   /* each member its share of the initial distances, then all of them */
        int first, last;
        crew_share(b.units, &c, &first, &last);
        for (int u = first + get_local_id(0); u < last; u += get_local_size(0)) {
            int x, y, z0, z1;
            unit_span(u, &b, &x, &y, &z0, &z1);
            for (int z = z0; z < z1; ++z) {
                const uint d = init_distance(voxels, field, w_lo.x + x, w_lo.y + y, w_lo.z + z, dims, r_lo, r_hi,
                                             seeded, cap);
                crew_dist[local_index(x, y, z, &b)] = (uchar)d;
            }
        }
        crew_barrier(crew, &c);
        crew_gather((__local uint4 *)dist, (volatile __global const uint4 *)crew_dist, 0, (b.nxy * b.n.z + 15) / 16);
    }
#else
    for (int u = get_local_id(0); u < b.units; u += get_local_size(0)) {
        int x, y, z0, z1;
        unit_span(u, &b, &x, &y, &z0, &z1);
        const int wx = w_lo.x + o.x + x, wy = w_lo.y + o.y + y;
        for (int z = z0; z < z1; ++z) {
            const int wz = w_lo.z + o.z + z;
            uint d = init_distance(voxels, field, wx, wy, wz, dims, r_lo, r_hi, seeded, cap);
            if (chunk > 0)
                d = min(d, frame_distance(wx, wy, wz, chunk));
            dist[local_index(x, y, z, &b)] = (uchar)d;
        }
    }
    barrier(CLK_LOCAL_MEM_FENCE);
#endif
#if ONE_LAUNCH_FLOOD
    flood(dist, seeds_a, seeds_b, first_step, extra_passes, cap, chunk, &b, crew_seeds, crew, &c);
#endif
#if ONE_LAUNCH_RELAX
    const int changed_passes = relax(dist, flags, &b, crew_dist, crew, &c);
    if (get_local_id(0) == 0 && c.member == 0) {
        if (accumulate)
            atomic_max(passes, changed_passes);
        else
            *passes = changed_passes;
    }
#endif

    int first, last;
    crew_share(b.units, &c, &first, &last);
    for (int u = first + get_local_id(0); u < last; u += get_local_size(0)) {
        int x, y, z0, z1;
        unit_span(u, &b, &x, &y, &z0, &z1);
        const int wx = w_lo.x + o.x + x, wy = w_lo.y + o.y + y;
        for (int z = z0; z < z1; ++z) {
            const int wz = w_lo.z + o.z + z;
            const uint d = dist[local_index(x, y, z, &b)];
            if (to_work) {
                work[box_index(o.x + x, o.y + y, o.z + z, w_n)] = (uchar)d;
            } else if (in_box(wx, wy, wz, r_lo, r_hi)) {
                const size_t i = world_index(wx, wy, wz, dims);
                field[i] = pack_field(min(d, (uint)cap), voxels[i]);
            }
        }
    }
#if ONE_LAUNCH_CREW
    crew_finish(crew);
#endif
}
