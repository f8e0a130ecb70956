/* A ray against a world's box and its voxel grid, for the kernels that march rays (render.cl,
 * query.cl): whether a voxel lies in the world, the slab test that clips a ray to the box, and
 * which axis's face a DDA step crosses next (ties go to x, then y, then z). */
#ifndef RAY_BOX_H
#define RAY_BOX_H

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

#endif
