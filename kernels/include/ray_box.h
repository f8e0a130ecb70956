/* A ray against a world's box and its voxel grid, for the kernels that march rays (render.cl,
 * query.cl): whether a voxel lies in the world, the slab test that clips a ray to the box, and
 * the walk over the voxels (Amanatides & Woo 1987) — one face-step at a time, or a jump along
 * the ray past as many faces as the field says are clear. Ties between axes go to x, then y,
 * then z. */
#ifndef RAY_BOX_H
#define RAY_BOX_H

#define JUMP_MIN_STEPS 8  /* from this many clear face-steps on, a ray jumps instead of stepping */

inline int argmin3(float3 t)
{
    if (t.x <= t.y && t.x <= t.z)
        return 0;
    return t.y <= t.z ? 1 : 2;
}

inline int in_world(int3 v, int4 dims)
{
    return v.x >= 0 && v.y >= 0 && v.z >= 0 && v.x < dims.x && v.y < dims.y && v.z < dims.z;
}

/* Slab test of one axis: narrows [t0, t1] to where the ray lies in the world along it and records
 * the axis giving t0 in *entry (which stays as it was when the origin lies inside). */
inline void clip_axis(float o, float d, int n, int axis, float *t0, float *t1, int *entry)
{
    if (d == 0.0f) {
        if (o < 0.0f || o >= (float)n)
            *t1 = -1.0f;
        return;
    }
    const float a = (0.0f - o) / d, b = ((float)n - o) / d;
    const float lo = fmin(a, b), hi = fmax(a, b);
    if (lo > *t0) {
        *t0 = lo;
        *entry = axis;
    }
    *t1 = fmin(*t1, hi);
}

/* The ray o + t d walking the grid: the voxel it is in, its step per axis, the t at which it
 * crosses the next face along each axis and between faces, and the axis of the face it last
 * entered through (-1: it has not entered one, it started inside). */
typedef struct {
    float3 o, d;
    int3 v, step;
    float3 t_max, t_delta;
    float t, l1;
    int face;
} Walk;

inline float3 next_faces(int3 v, int3 step, float3 o, float3 d)
{
    const float3 up = convert_float3(v) + (float3)(step.x > 0, step.y > 0, step.z > 0);
    return (float3)(d.x != 0.0f ? (up.x - o.x) / d.x : INFINITY,
                    d.y != 0.0f ? (up.y - o.y) / d.y : INFINITY,
                    d.z != 0.0f ? (up.z - o.z) / d.z : INFINITY);
}

/* Clip the ray to the world's box [0, dims) and put the walk in the first voxel it meets, at the
 * t where it enters (0 when the origin is inside); 0 when the ray misses the box. */
inline int walk_start(Walk *w, float3 o, float3 d, int4 dims)
{
    w->o = o;
    w->d = d;
    w->step = (int3)(d.x > 0.0f ? 1 : -1, d.y > 0.0f ? 1 : -1, d.z > 0.0f ? 1 : -1);
    float t0 = 0.0f, t1 = INFINITY;
    int entry = -1;
    clip_axis(o.x, d.x, dims.x, 0, &t0, &t1, &entry);
    clip_axis(o.y, d.y, dims.y, 1, &t0, &t1, &entry);
    clip_axis(o.z, d.z, dims.z, 2, &t0, &t1, &entry);
    if (!(t1 > t0))
        return 0;
    int3 v = clamp(convert_int3_rtn(o + d * t0), (int3)(0), dims.xyz - 1);
    if (entry == 0) v.x = w->step.x > 0 ? 0 : dims.x - 1;
    if (entry == 1) v.y = w->step.y > 0 ? 0 : dims.y - 1;
    if (entry == 2) v.z = w->step.z > 0 ? 0 : dims.z - 1;
    w->v = v;
    w->face = entry;
    w->t = t0;
    w->t_max = next_faces(v, w->step, o, d);
    w->t_delta = (float3)(d.x != 0.0f ? fabs(1.0f / d.x) : INFINITY,
                          d.y != 0.0f ? fabs(1.0f / d.y) : INFINITY,
                          d.z != 0.0f ? fabs(1.0f / d.z) : INFINITY);
    w->l1 = fabs(d.x) + fabs(d.y) + fabs(d.z);
    return 1;
}

/* One face-step into the next voxel along the ray. */
inline void walk_step(Walk *w)
{
    const int axis = argmin3(w->t_max);
    if (axis == 0) { w->v.x += w->step.x; w->t = w->t_max.x; w->t_max.x += w->t_delta.x; }
    else if (axis == 1) { w->v.y += w->step.y; w->t = w->t_max.y; w->t_max.y += w->t_delta.y; }
    else { w->v.z += w->step.z; w->t = w->t_max.z; w->t_max.z += w->t_delta.z; }
    w->face = axis;
}

/* Jump along the ray where `steps` face-steps from the walk's voxel are known clear (steps >=
 * JUMP_MIN_STEPS):
 * over dt each axis crosses at most |d_a| dt + 1 faces, so dt = (steps - 5) / |d|_1 crosses at
 * most steps - 2 of them; one more for rounding where the ray lands: every voxel passed, and the
 * one landed in, is nearer than `steps` and clear. The landing voxel may lie outside the world. */
inline void walk_jump(Walk *w, uint steps)
{
    w->t += (float)(steps - 5) / w->l1;
    w->v = convert_int3_rtn(w->o + w->d * w->t);
    w->t_max = next_faces(w->v, w->step, w->o, w->d);
}

#endif
