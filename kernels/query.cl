/* Collision and navigation queries: points, spheres and rays against a world's field
 * (sdfserver/engine/query.py). World unit w lies at voxel coordinate (w - origin) / voxel_size
 * (voxel v spans [v, v + 1) on each axis): points and spheres arrive in world units, with `place`
 * = (origin, voxel_size), rays already in voxel coordinates; the host has checked every input.
 * Distances leave in world units. These kernels only read the field, through field_source.h.
 *
 * Distances at a point are the trilinear interpolant of field_distance between voxel centres
 * (voxel v's centre at v + 0.5), its argument clamped to the outermost centres: in the half voxel
 * between them and the world's faces the value is the face's. The gradient is the interpolant's,
 * taken in the cell that holds the clamped point (zero along an axis one voxel thick), and is not
 * normalised: distances and coordinates scale alike with voxel_size, so it needs no scaling.
 *
 * Rays march like render.cl's `march`: DDA face-steps over the voxels, with jumps of as many
 * face-steps as field_step allows where they are long. A ray that starts in a solid hits it at
 * t = 0 with no face; a ray outside the world is clipped to its box first. */
#include "sdf_common.h"
#include "field_source.h"
#include "ray_box.h"


/* A corner's distance. Corners pass as three ints and become an int3 here: Intel's CPU runtime
 * miscompiled a sparse world's reads (wrong distances in some work-items) when handed int3s built
 * in place from the lanes of two vectors. */
inline float at(FIELD_ARGS, int x, int y, int z, int4 dims)
{
    return field_distance(FIELD_PASS, (int3)(x, y, z), dims);
}

/* The interpolated distance (voxels) at q in centre coordinates (voxel v's centre at v), and in
 * *grad its gradient. */
inline float trilinear(FIELD_ARGS, float3 q, int4 dims, float3 *grad)
{
    const int3 hi = dims.xyz - 1;
    q = clamp(q, (float3)(0.0f), convert_float3(hi));
    const int3 a = min(convert_int3_rtn(q), max(hi - 1, (int3)(0)));
    const int3 b = min(a + 1, hi);
    const float3 f = q - convert_float3(a);
    const float d000 = at(FIELD_PASS, a.x, a.y, a.z, dims);
    const float d100 = at(FIELD_PASS, b.x, a.y, a.z, dims);
    const float d010 = at(FIELD_PASS, a.x, b.y, a.z, dims);
    const float d110 = at(FIELD_PASS, b.x, b.y, a.z, dims);
    const float d001 = at(FIELD_PASS, a.x, a.y, b.z, dims);
    const float d101 = at(FIELD_PASS, b.x, a.y, b.z, dims);
    const float d011 = at(FIELD_PASS, a.x, b.y, b.z, dims);
    const float d111 = at(FIELD_PASS, b.x, b.y, b.z, dims);
    const float c00 = mix(d000, d100, f.x), c10 = mix(d010, d110, f.x);
    const float c01 = mix(d001, d101, f.x), c11 = mix(d011, d111, f.x);
    const float c0 = mix(c00, c10, f.y), c1 = mix(c01, c11, f.y);
    *grad = (float3)(mix(mix(d100 - d000, d110 - d010, f.y), mix(d101 - d001, d111 - d011, f.y), f.z),
                     mix(c10 - c00, c11 - c01, f.z),
                     c1 - c0);
    return mix(c0, c1, f.z);
}

/* Each kernel writes its answers as whole arrays one after another in `out`, so that the host
 * downloads once and hands each on without a copy (engine/query.py's `answers`). */

/* points: n packed (x, y, z), world units. out: n distances (world units), n packed gradients
 * (x, y, z), n uchar colours (the value of the voxel holding the point). */
__kernel void query_points(FIELD_ARGS, int4 dims, float4 place, __global const float *points, int n,
                           __global float *out)
{
    const int i = get_global_id(0);
    if (i >= n)
        return;
    const float3 p = (vload3(i, points) - place.xyz) / place.w;
    float3 g;
    const float d = trilinear(FIELD_PASS, p - 0.5f, dims, &g);
    const int3 v = clamp(convert_int3_rtn(p), (int3)(0), dims.xyz - 1);
    uint colour, steps;
    field_step(FIELD_PASS, v, dims, &colour, &steps);
    out[i] = d * place.w;
    vstore3(g, i, out + n);
    ((__global uchar *)(out + 4 * (size_t)n))[i] = (uchar)colour;
}

/* spheres: (x, y, z, r), world units. out: n clearances (world units), n packed directions out of
 * collision: the unit gradient, zero where the field is flat. */
__kernel void query_spheres(FIELD_ARGS, int4 dims, float4 place, __global const float4 *spheres, int n,
                            __global float *out)
{
    const int i = get_global_id(0);
    if (i >= n)
        return;
    const float4 s = spheres[i];
    float3 g;
    const float d = trilinear(FIELD_PASS, (s.xyz - place.xyz) / place.w - 0.5f, dims, &g);
    const float len = length(g);
    out[i] = d * place.w - s.w;
    vstore3(len > 0.0f ? g / len : (float3)(0.0f), i, out + n);
}

/* The first solid voxel along o + t d (|d| = 1, voxel units) with t <= t_end: 1 and its voxel,
 * colour, entry t and entered face's axis (-1: the ray starts in it); 0 when there is none. */
inline int first_hit(FIELD_ARGS, int4 dims, float3 o, float3 d, float t_end, int3 *voxel, uint *colour,
                     float *t_hit, int *face)
{
    Walk w;
    if (!walk_start(&w, o, d, dims) || w.t > t_end)
        return 0;
    /* Each pass takes at least one step, and a ray crosses at most sx + sy + sz voxels. */
    const int max_passes = dims.x + dims.y + dims.z + 3;
    for (int pass = 0; pass < max_passes; ++pass) {
        uint distance_steps;
        const uint steps = field_step(FIELD_PASS, w.v, dims, colour, &distance_steps);
        if (*colour) {
            *voxel = w.v;
            *t_hit = w.t;
            *face = w.face;
            return w.t <= t_end;
        }
        if (steps >= JUMP_MIN_STEPS) {
            walk_jump(&w, steps);
            if (w.t > t_end || !in_world(w.v, dims))
                return 0;
            continue;
        }
        for (uint k = 0; k < steps; ++k) {
            walk_step(&w);
            if (w.t > t_end || !in_world(w.v, dims))
                return 0;
        }
    }
    return 0;
}

/* rays: per ray two float4, (origin in voxel coordinates, max length in voxels) and (unit
 * direction, 0). out: n t (world units; a miss: the max length), n packed normals of the entered
 * face (a miss: 0), n packed int hit voxels (a miss: -1s), n uchar voxel values (a miss: 0). */
__kernel void query_rays(FIELD_ARGS, int4 dims, float4 place, __global const float4 *rays, int n,
                         __global float *out)
{
    const float voxel_size = place.w;
    const int i = get_global_id(0);
    if (i >= n)
        return;
    const float4 o = rays[2 * i], d = rays[2 * i + 1];
    int3 voxel;
    uint colour = 0;
    float t = 0.0f;
    int face = -1;
    __global int *hit_voxels = (__global int *)(out + 4 * (size_t)n);
    __global uchar *colours = (__global uchar *)(out + 7 * (size_t)n);
    if (first_hit(FIELD_PASS, dims, o.xyz, d.xyz, o.w, &voxel, &colour, &t, &face)) {
        const float3 normal = (float3)(face == 0 ? (d.x > 0.0f ? -1.0f : 1.0f) : 0.0f,
                                       face == 1 ? (d.y > 0.0f ? -1.0f : 1.0f) : 0.0f,
                                       face == 2 ? (d.z > 0.0f ? -1.0f : 1.0f) : 0.0f);
        out[i] = t * voxel_size;
        vstore3(normal, i, out + n);
        vstore3(voxel, i, hit_voxels);
        colours[i] = (uchar)colour;
    } else {
        out[i] = o.w * voxel_size;
        vstore3((float3)(0.0f), i, out + n);
        vstore3((int3)(-1), i, hit_voxels);
        colours[i] = 0;
    }
}
