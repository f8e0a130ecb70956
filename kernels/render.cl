/* The DDA ray marcher of the dissertation's §3.3 (Figure 3.4).
 *
 * One work-item per pixel. A ray from the camera is clipped to the world box
 * [0, dims); outside it everything is air. Inside, the voxel traversal of
 * Amanatides & Woo (1987) walks voxel by voxel, but reads the packed field
 * only where it must: a voxel whose Manhattan distance is d > 0 has no solid
 * within d - 1 face-steps, and every DDA step is one face-step, so the ray
 * takes d steps without reading and reads again where it lands (Figure 3.4:
 * read 3, advance 3, read 1, advance 1, read 0: hit). A long run of clear steps is not walked
 * voxel by voxel: the ray jumps along itself by a length that cannot cross more faces than the
 * run allows, and the traversal starts again where it lands (shadow rays, whose softness
 * depends on where they read, always step). The field is exact or a
 * lower bound for the exact algorithms; an approximate field that overestimates
 * (JFA outside a focus box) can let a ray step over a thin solid.
 *
 * Conventions (sdf_common.h): C-ordered (z, y, x); voxel (x, y, z) covers [x, x+1) x [y, y+1) x
 * [z, z+1); y is up; image row 0 is the top. What a field value means (Manhattan or Euclidean,
 * signed or not) is field_source.h's alone: the marcher asks it for face-steps and colours, so
 * the hit surface is the same on every field of the same voxels.
 *
 * Shading: the voxel's value v is drawn as the world's palette[v - 1] (`palette`, 255 RGBA
 * entries; the default is RGB332 expanded to RGB888), times an integer brightness per entered
 * face (top 256/256, x faces 204, z faces 166, bottom 128), so the result is exact integer
 * arithmetic. Flags add ambient occlusion (from distances along the face normal) and a soft
 * shadow toward `light` (a second DDA march whose penumbra is the least clearance / t, the
 * clearance being field_distance: Euclidean where the world is), both floating point.
 *
 * Ties between axes in the DDA (a ray through an edge) go to x, then y, then z.
 *
 * Where the field lives is field_source.h's (FIELD_ARGS, field_step): a dense world's buffer or
 * a sparse world's bricks. The marcher is the same for both; in a sparse world's implicit air
 * bricks and blocks field_step lets a ray step further than the cap (field_source.h says why).
 * A shadow ray steps by the distance alone: its softness is the least distance over the points
 * it reads, so reading at the same points keeps frames the same either way.
 */
#include "sdf_common.h"

#include "field_source.h"
#include "ray_box.h"

#define RENDER_AO 1
#define RENDER_SHADOW 2
#define RENDER_STATS 4

typedef struct {
    int hit;       /* 1: a solid voxel was reached */
    int3 voxel;    /* the voxel hit */
    int face;      /* the axis of the face the ray entered through; -1 if it started inside */
    int3 step;     /* the ray's step direction per axis */
    uint colour;   /* the voxel's value, a palette index */
    uint reads;    /* field reads */
    float shade;   /* min over reads of clearance / t (soft shadows) */
} march_result;

inline march_result march(FIELD_ARGS, int4 dims, float3 o, float3 d, int long_steps)
{
    march_result r;
    r.hit = 0;
    r.reads = 0;
    r.shade = 1e30f;
    r.colour = 0;
    r.face = -1;
    Walk w;
    const int enters = walk_start(&w, o, d, dims);
    r.step = w.step;
    if (!enters)
        return r;
    /* Each pass takes at least one step, and a ray crosses at most sx + sy + sz voxels. */
    const int max_passes = dims.x + dims.y + dims.z + 3;
    for (int pass = 0; pass < max_passes; ++pass) {
        uint colour, dist;  /* steps: face-steps known to be clear: the distance, or more across empty bricks */
        uint steps = field_step(FIELD_PASS, w.v, dims, &colour, &dist);
        r.reads++;
        if (colour) {
            r.hit = 1;
            r.voxel = w.v;
            r.colour = colour;
            r.face = w.face;
            return r;
        }
        /* The penumbra wants the true clearance: a Euclidean distance is below the step count
         * (ceil), and in a Manhattan world the two are the same number, read once. */
#if FIELD_EUCLID
        const float clearance = long_steps ? 0.0f : fmax(field_distance(FIELD_PASS, w.v, dims), 0.0f);
#else
        const float clearance = (float)dist;
#endif
        r.shade = fmin(r.shade, clearance / fmax(w.t, 1e-3f));
        if (!long_steps)
            steps = dist;
        if (steps >= JUMP_MIN_STEPS) {
            walk_jump(&w, steps);
            if (!in_world(w.v, dims)) {
                r.face = w.face;
                return r;
            }
            continue;
        }
        for (uint k = 0; k < steps; ++k) {
            walk_step(&w);
            if (!in_world(w.v, dims)) {
                r.face = w.face;
                return r;
            }
        }
    }
    r.face = w.face;
    return r;
}

inline uint face_brightness(int face, int3 step)
{
    if (face == 1)
        return step.y < 0 ? 256u : 128u;  /* moving down enters a top face */
    if (face == 0)
        return 204u;
    if (face == 2)
        return 166u;
    return 256u;                          /* the camera started inside this voxel */
}

/* Value v (1..255) is drawn as the world's palette[v - 1] (the default holds RGB332 expanded). */
inline uint3 palette_rgb(__global const uchar4 *palette, uint c)
{
    return convert_uint3(palette[c - 1u].xyz);
}

/* 1 - occlusion, from distances k = 2..4 voxels out along the face normal: in the open
 * the distance there is k; a nearby wall or crease makes it smaller. */
inline float ambient(FIELD_ARGS, int4 dims, int3 v, int3 normal)
{
    float occ = 0.0f;
    for (int k = 2; k <= 4; ++k) {
        const int3 a = v + normal * k;
        if (!in_world(a, dims))
            continue;
        const float dist = clamp(field_distance(FIELD_PASS, a, dims), 0.0f, (float)k);
        occ += ((float)k - dist) / (float)k;
    }
    return 1.0f - 0.45f * occ / 3.0f;
}

/* Light reaching the face of voxel v with this normal, marching from the air voxel in front. */
inline float shadow(FIELD_ARGS, int4 dims, int3 v, int3 normal, float3 light)
{
    const int3 a = v + normal;
    if (!in_world(a, dims))
        return 1.0f;
    const march_result s = march(FIELD_PASS, dims, convert_float3(a) + 0.5f, light, 0);
    if (s.hit)
        return 0.55f;
    return 0.55f + 0.45f * clamp(s.shade * 4.0f, 0.0f, 1.0f);
}

/* cam_origin: camera position (voxels). cam_forward: unit view direction; cam_right and
 * cam_up: scaled so that pixel centre (u, v) in [-1, 1] looks along forward + u*right + v*up.
 * highlight: xyz a voxel, w its radius squared (tinted brush preview); w < 0: none. */
__kernel void render(FIELD_ARGS, int4 dims,
                     float4 cam_origin, float4 cam_forward, float4 cam_right, float4 cam_up,
                     int width, int height, uint sky_rgb, uint flags, float4 light,
                     int4 highlight, __global const uchar4 *palette, __global uchar4 *out,
                     __global uint *reads)
{
    const int px = get_global_id(0), py = get_global_id(1);
    if (px >= width || py >= height)
        return;
    const float u = ((float)px + 0.5f) / (float)width * 2.0f - 1.0f;
    const float w = 1.0f - ((float)py + 0.5f) / (float)height * 2.0f;
    const float3 d = cam_forward.xyz + u * cam_right.xyz + w * cam_up.xyz;
    const march_result r = march(FIELD_PASS, dims, cam_origin.xyz, d, 1);
    const size_t pixel = (size_t)py * (size_t)width + (size_t)px;
    if (flags & RENDER_STATS)
        reads[pixel] = r.reads;
    if (!r.hit) {
        out[pixel] = (uchar4)((sky_rgb >> 16) & 0xff, (sky_rgb >> 8) & 0xff, sky_rgb & 0xff, 255);
        return;
    }
    uint3 rgb = (palette_rgb(palette, r.colour) * face_brightness(r.face, r.step)) >> 8;
    if (flags & (RENDER_AO | RENDER_SHADOW)) {
        int3 normal = (int3)(0);
        if (r.face == 0) normal.x = -r.step.x;
        if (r.face == 1) normal.y = -r.step.y;
        if (r.face == 2) normal.z = -r.step.z;
        float light_factor = 1.0f;
        if (r.face >= 0 && (flags & RENDER_AO))
            light_factor *= ambient(FIELD_PASS, dims, r.voxel, normal);
        if (r.face >= 0 && (flags & RENDER_SHADOW))
            light_factor *= shadow(FIELD_PASS, dims, r.voxel, normal, light.xyz);
        rgb = convert_uint3_sat_rte(convert_float3(rgb) * light_factor);
    }
    if (highlight.w >= 0) {
        const int3 e = r.voxel - highlight.xyz;
        if (e.x * e.x + e.y * e.y + e.z * e.z <= highlight.w)
            rgb = (rgb + (uint3)(255u)) / 2u;
    }
    out[pixel] = (uchar4)(rgb.x, rgb.y, rgb.z, 255);
}

/* One ray (a click): out[0] = (hit voxel, hit), out[1] = (normal of the entered face, face). */
__kernel void pick(FIELD_ARGS, int4 dims, float4 origin, float4 direction,
                   __global int4 *out)
{
    if (get_global_id(0) != 0)
        return;
    const march_result r = march(FIELD_PASS, dims, origin.xyz, direction.xyz, 1);
    int3 normal = (int3)(0);
    if (r.face == 0) normal.x = -r.step.x;
    if (r.face == 1) normal.y = -r.step.y;
    if (r.face == 2) normal.z = -r.step.z;
    out[0] = r.hit ? (int4)(r.voxel, 1) : (int4)(0);
    out[1] = (int4)(normal, r.face);
}
