/* A crew: the work-groups of one launch that work on one box together, with
 * barriers between them.
 *
 * OpenCL promises nothing about work-groups running at the same time, so a
 * barrier across all of a launch's groups could wait forever for a group that
 * only starts once the waiting ones finish. A crew therefore holds only the
 * groups that were running together at its start (the occupancy discovery of
 * Sorensen, Donaldson et al., "Portable inter-workgroup barrier
 * synchronisation for GPUs", OOPSLA 2016): each group takes a number as it
 * starts and waits, for at most CREW_GATHER_SPINS polls, until every group of
 * the launch has one; then the poll is closed at the count taken so far. A
 * group numbered below that count is running, and a running work-group runs
 * to its end, so every member reaches every barrier. Groups numbered past it
 * take no part. The crew is those groups, one or all: the work is shared by
 * its size.
 *
 * The control block (`crew`, CREW_INTS ints) is zero before a launch; the last
 * group to finish, member or not, zeroes it again. Data that members exchange
 * goes through global memory and is read back with volatile loads (past the
 * compute unit's own cache, which other compute units' writes do not reach).
 * A barrier orders each member's writes before the others' reads at the scope
 * of the whole device (release and acquire, crew_barrier): OpenCL 1.2's fences
 * order memory within a work-group only (NVIDIA compiles
 * mem_fence(CLK_GLOBAL_MEM_FENCE) to PTX's membar.cta), so a crew needs a
 * device where the kernel can say more (one_launch.py's takes_crews: NVIDIA's
 * PTX).
 */
#ifndef CREW_H
#define CREW_H

#define CREW_POLL 0      /* groups that asked to join */
#define CREW_MEMBERS 1   /* 0 while the poll is open; then CREW_CLOSED | the crew's size */
#define CREW_FINISHED 2  /* groups of the launch that finished */
#define CREW_FLAGS 3     /* three flags for whoever needs them (one_launch.cl's FIM passes) */
/* Arrivals at barriers, counted up through the launch: every member polls it,
 * 128 bytes (a cache line) away from the words above. */
#define CREW_ARRIVED 32
#define CREW_INTS 33
#define CREW_CLOSED 0x40000000
/* How long a member waits for the rest of the launch to join: a GPU starts a
 * small launch's groups within microseconds; a CPU device that runs them one
 * after another gets a crew of one after the wait. */
#define CREW_GATHER_SPINS 20000

/* Device-wide ordering. On NVIDIA: a release add (a reduction, no result) and
 * an acquire load at GPU scope (PTX; cheaper than membar.gl fences);
 * elsewhere (the CPU device, where the tests run crews) OpenCL's global fence
 * around plain ones. */
#if SDF_NVIDIA
/* Adds one to *p, releasing this work-item's earlier accesses (and, after a
 * group barrier, its group's). No result comes back: the arrival does not
 * wait for the atomic's round trip. */
inline void crew_arrive(volatile __global int *p)
{
    asm volatile("red.release.gpu.global.add.u32 [%0], 1;" : : "l"((ulong)p) : "memory");
}

inline int crew_load_acquire(volatile __global int *p)
{
    int value;
    asm volatile("ld.acquire.gpu.global.u32 %0, [%1];" : "=r"(value) : "l"((ulong)p) : "memory");
    return value;
}

#else
inline void crew_arrive(volatile __global int *p)
{
    mem_fence(CLK_GLOBAL_MEM_FENCE);
    atomic_inc(p);
}

inline int crew_load_acquire(volatile __global int *p)
{
    const int value = *p;
    mem_fence(CLK_GLOBAL_MEM_FENCE);
    return value;
}

#endif

typedef struct {
    int member;    /* this group's number in the crew, -1 when it takes no part */
    int members;
    int barriers;  /* barriers passed */
} Crew;

inline Crew crew_join(volatile __global int *crew, __local volatile int *shared)
{
    if (get_local_id(0) == 0) {
        /* Joiners are numbered by one add each; whoever closes the poll fixes the
         * crew's size, so joiners numbered past it (they came too late) take no part. */
        const int asked = atomic_inc(&crew[CREW_POLL]);
        const int groups = (int)get_num_groups(0);
        if (asked + 1 == groups)  /* the last of the launch: everyone is running */
            atomic_cmpxchg(&crew[CREW_MEMBERS], 0, CREW_CLOSED | groups);
        int closed = crew[CREW_MEMBERS];
        for (int spin = 0; closed == 0; ++spin) {
            if (spin >= CREW_GATHER_SPINS)
                atomic_cmpxchg(&crew[CREW_MEMBERS], 0, CREW_CLOSED | crew[CREW_POLL]);
            closed = crew[CREW_MEMBERS];
        }
        const int members = closed & ~CREW_CLOSED;
        shared[0] = asked < members ? asked : -1;
        shared[1] = members;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    const Crew c = {shared[0], shared[1], 0};
    barrier(CLK_LOCAL_MEM_FENCE);
    return c;
}

/* Every member's global writes before it are seen by every member after it. As
 * CUDA's grid sync does it: the group's barrier puts its work-items' writes
 * before its first work-item's arrival (a release), that work-item waits until
 * every member has arrived (an acquire of the count), and the group's barrier
 * puts that before its work-items' reads: one release and one acquire a group,
 * not a fence a work-item (membar.gl costs microseconds). The count only
 * grows, so a member that arrives at the next barrier early releases no one
 * still waiting at this one. */
inline void crew_barrier(volatile __global int *crew, Crew *c)
{
    barrier(CLK_GLOBAL_MEM_FENCE | CLK_LOCAL_MEM_FENCE);
    ++c->barriers;
    if (get_local_id(0) == 0) {
        const int arrivals = c->barriers * c->members;
        crew_arrive(&crew[CREW_ARRIVED]);
        while (crew_load_acquire(&crew[CREW_ARRIVED]) < arrivals)
            ;
    }
    barrier(CLK_GLOBAL_MEM_FENCE | CLK_LOCAL_MEM_FENCE);
}

/* Every group of the launch calls this last; the last one zeroes the block. */
inline void crew_finish(volatile __global int *crew)
{
    barrier(CLK_GLOBAL_MEM_FENCE | CLK_LOCAL_MEM_FENCE);
    if (get_local_id(0) == 0) {
        if (atomic_inc(&crew[CREW_FINISHED]) == (int)get_num_groups(0) - 1)
            for (int k = 0; k < CREW_INTS; ++k)
                crew[k] = 0;
    }
}

/* Copies 16-byte words [first, last) that members wrote into this group's
 * local memory (both buffers' sizes are multiples of 16 bytes). */
inline void crew_gather(__local uint4 *dst, volatile __global const uint4 *src, int first, int last)
{
    for (int k = first + get_local_id(0); k < last; k += get_local_size(0))
        dst[k] = src[k];
    barrier(CLK_LOCAL_MEM_FENCE);
}

/* A member's share [first, last) of `units`. */
inline void crew_share(int units, const Crew *c, int *first, int *last)
{
    *first = (int)((long)units * c->member / c->members);
    *last = (int)((long)units * (c->member + 1) / c->members);
}

#endif
