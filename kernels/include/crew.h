/* A crew: the work-groups of one launch that work on one box together, with
 * barriers between them.
 *
 * OpenCL promises nothing about work-groups running at the same time, so a
 * barrier across all of a launch's groups could wait forever for a group that
 * only starts once the waiting ones finish. A crew therefore holds only the
 * groups that were running together at its start (the occupancy discovery of
 * Sorensen, Donaldson et al., "Portable inter-workgroup barrier
 * synchronisation for GPUs", OOPSLA 2016): each group that starts while the
 * poll is open joins it and waits there, for at most CREW_GATHER_SPINS polls,
 * until every group of the launch has joined; then one closes it. A group that
 * joined is running, and a running work-group runs to its end, so every member
 * reaches every barrier. Groups that find the poll closed take no part. The
 * crew is the groups that joined, one or all: the work is shared by its size.
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

#define CREW_POLL 0      /* groups that joined; | CREW_CLOSED once the poll is closed */
#define CREW_ARRIVED 1   /* arrivals at barriers, counted up through the launch */
#define CREW_FINISHED 2  /* groups of the launch that finished */
#define CREW_FLAGS 3     /* three flags for whoever needs them (one_launch.cl's FIM passes) */
/* The barriers passed, set by each barrier's last arrival: waiting members poll
 * it, 128 bytes (a cache line) away from the counter that arrivals add to. */
#define CREW_RELEASED 32
#define CREW_INTS 33
#define CREW_CLOSED 0x40000000
/* How long a member waits for the rest of the launch to join: a GPU starts a
 * small launch's groups within microseconds; a CPU device that runs them one
 * after another gets a crew of one after the wait. */
#define CREW_GATHER_SPINS 20000

/* Device-wide ordering. On NVIDIA: the acquire and release forms of an atomic,
 * a store and a load at GPU scope (PTX; cheaper than membar.gl fences);
 * elsewhere (the CPU device, where the tests run crews) OpenCL's global fence
 * around plain ones. */
#if SDF_NVIDIA
/* Adds one to *p and returns what it held; releases this work-item's earlier
 * accesses (and, after a group barrier, its group's) and acquires those of
 * every arrival before it. */
inline int crew_arrive(volatile __global int *p)
{
    int old;
    asm volatile("atom.acq_rel.gpu.global.add.u32 %0, [%1], 1;" : "=r"(old) : "l"((ulong)p) : "memory");
    return old;
}

inline int crew_load_acquire(volatile __global int *p)
{
    int value;
    asm volatile("ld.acquire.gpu.global.u32 %0, [%1];" : "=r"(value) : "l"((ulong)p) : "memory");
    return value;
}

inline void crew_store_release(volatile __global int *p, int value)
{
    asm volatile("st.release.gpu.global.u32 [%0], %1;" : : "l"((ulong)p), "r"(value) : "memory");
}
#else
inline int crew_arrive(volatile __global int *p)
{
    mem_fence(CLK_GLOBAL_MEM_FENCE);
    const int old = atomic_inc(p);
    mem_fence(CLK_GLOBAL_MEM_FENCE);
    return old;
}

inline int crew_load_acquire(volatile __global int *p)
{
    const int value = *p;
    mem_fence(CLK_GLOBAL_MEM_FENCE);
    return value;
}

inline void crew_store_release(volatile __global int *p, int value)
{
    mem_fence(CLK_GLOBAL_MEM_FENCE);
    *p = value;
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
        int member = -1, members = 0;
        int poll = crew[CREW_POLL];
        while (!(poll & CREW_CLOSED)) {
            const int seen = atomic_cmpxchg(&crew[CREW_POLL], poll, poll + 1);
            if (seen == poll) {
                member = poll;
                break;
            }
            poll = seen;
        }
        for (int spin = 0; member >= 0; ++spin) {
            poll = crew[CREW_POLL];
            if (poll & CREW_CLOSED) {
                members = poll & ~CREW_CLOSED;
                break;
            }
            if ((poll >= (int)get_num_groups(0) || spin >= CREW_GATHER_SPINS)
                && atomic_cmpxchg(&crew[CREW_POLL], poll, poll | CREW_CLOSED) == poll) {
                members = poll;
                break;
            }
        }
        shared[0] = member;
        shared[1] = members;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    const Crew c = {shared[0], shared[1], 0};
    barrier(CLK_LOCAL_MEM_FENCE);
    return c;
}

/* Every member's global writes before it are seen by every member after it. As
 * CUDA's grid sync does it: the group's barrier puts its work-items' writes
 * before its first work-item's arrival (a release), the others wait for the
 * last arrival's release flag (an acquire), and the group's barrier puts that
 * before its work-items' reads: one release and one acquire a group, not a
 * fence a work-item (membar.gl costs microseconds). */
inline void crew_barrier(volatile __global int *crew, Crew *c)
{
    barrier(CLK_GLOBAL_MEM_FENCE | CLK_LOCAL_MEM_FENCE);
    ++c->barriers;
    if (get_local_id(0) == 0) {
        const int arrivals = c->barriers * c->members;
        if (crew_arrive(&crew[CREW_ARRIVED]) == arrivals - 1)
            crew_store_release(&crew[CREW_RELEASED], c->barriers);
        else
            while (crew_load_acquire(&crew[CREW_RELEASED]) < c->barriers)
                ;
    }
    barrier(CLK_GLOBAL_MEM_FENCE | CLK_LOCAL_MEM_FENCE);
}

/* Every group of the launch calls this last; the last one zeroes the block. */
inline void crew_finish(volatile __global int *crew)
{
    barrier(CLK_GLOBAL_MEM_FENCE | CLK_LOCAL_MEM_FENCE);
    if (get_local_id(0) == 0) {
        if (crew_arrive(&crew[CREW_FINISHED]) == (int)get_num_groups(0) - 1)
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
