#version 450
// Backward of attribute interpolation, one invocation per pixel. From dL/d(out) (and, with
// N_DIFF > 0, dL/d(out_da)):
//   dL/da[t0] += u g + (g_x du/dx + g_y du/dy),  dL/da[t1] += v g + (g_x dv/dx + g_y dv/dy),
//   dL/da[t2] += (1 - u - v) g - (both brackets)      (g_x, g_y: the chosen attributes only)
//   dL/du = sum_k g_k (a0 - a2)_k,  dL/dv = sum_k g_k (a1 - a2)_k          -> grad_rast
//   dL/d(du/dx, du/dy, dv/dx, dv/dy) = sum_k (g_x (a0-a2), g_y (a0-a2), g_x (a1-a2), g_y (a1-a2))
// Accumulation into dL/da as in backward_rasterize.comp: ACCUM_ATOMIC_FLOAT | ACCUM_CAS |
// ACCUM_FIXED_POINT (with RUN and N_ATTR: RUN pixels per invocation, local sums);
// NO_GRAD_ATTR: dL/da not wanted (no accumulation at all), NO_GRAD_RAST:
// grad_rast and grad_rast_db not wanted (not written).
#ifdef ACCUM_ATOMIC_FLOAT
#extension GL_NV_shader_atomic_float : require
#endif

layout(local_size_x = 64) in;

layout(std430, binding = 0) readonly buffer Attr { float attr[]; };
layout(std430, binding = 1) readonly buffer Tri { int tri[]; };
layout(std430, binding = 2) readonly buffer Rast { vec4 rast[]; };
layout(std430, binding = 3) readonly buffer GradOut { float grad_out[]; };
layout(std430, binding = 4) writeonly buffer GradRast { vec4 grad_rast[]; };
#if defined(ACCUM_ATOMIC_FLOAT)
layout(std430, binding = 5) buffer GradAttr { float grad_attr[]; };
#elif defined(ACCUM_CAS) || defined(ACCUM_FIXED_POINT)
layout(std430, binding = 5) buffer GradAttr { uint grad_attr[]; };
#endif
#if N_DIFF > 0
layout(std430, binding = 6) readonly buffer RastDb { vec4 rast_db[]; };
layout(std430, binding = 7) readonly buffer DiffSlot { int diff_slot[]; };  // per attribute: its place among the chosen, or -1
layout(std430, binding = 8) readonly buffer GradOutDa { float grad_out_da[]; };
layout(std430, binding = 9) writeonly buffer GradRastDb { vec4 grad_rast_db[]; };
#endif

uniform uint n_pixels;
uniform uint first_pixel;
uniform uint pixels_per_image;
uniform uint vertex_stride;
uniform int n_tri;
uniform int n_attr;
uniform uint fixed_groups;   // ACCUM_FIXED_POINT: B with batched attr (one scale per image), else 1

#include "include/triangle_id.glsl"
#include "include/atomic_add_float.glsl"
#include "include/fixed_point.glsl"

#if defined(ACCUM_FIXED_POINT) && defined(RUN) && !defined(NO_GRAD_ATTR)
// RUN consecutive pixels per invocation (N_ATTR = n_attr, compile-time): the rounded terms
// of a stretch of pixels on one triangle are summed here (64-bit integers: associative, so
// the same bits) and added with one pair of atomics per corner and attribute.
#define LOCAL_SUMS
uvec2 run_sum[3 * N_ATTR];   // [3 k + j]: corner j, attribute k
uint run_largest;        // fixed_point_magnitude of the largest term
float run_scale;
#endif

// corner j's term of dL/d attr[slot] (attribute k; group: the image when attr is batched)
void add(uint j, uint k, uint slot, uint group, float value) {
#if defined(NO_GRAD_ATTR)
#elif defined(LOCAL_SUMS)
    run_largest = max(run_largest, fixed_point_magnitude(value));
    run_sum[3u * k + j] = fixed_point_add(run_sum[3u * k + j],
                                          fixed_point_words(value, run_scale));
#elif defined(ACCUM_FIXED_POINT)
    if (value != 0.0) FIXED_ADD(grad_attr, fixed_groups, group, slot, value);
#else
    if (value != 0.0) ATOMIC_ADD_FLOAT(grad_attr[slot], value);
#endif
}

void pixel(uint i) {
    uint A = uint(n_attr);
    vec4 r = rast[i];
    int t = decode_id(r.w) - 1;
    if (t < 0 || t >= n_tri) {
#ifndef NO_GRAD_RAST
        grad_rast[i] = vec4(0.0);
#if N_DIFF > 0
        grad_rast_db[i] = vec4(0.0);
#endif
#endif
        return;
    }
    uint image = (first_pixel + i) / pixels_per_image;
    uint base = image * vertex_stride;
    uint group = vertex_stride == 0u ? 0u : image;
    uint o0 = (uint(tri[3 * t]) + base) * A;
    uint o1 = (uint(tri[3 * t + 1]) + base) * A;
    uint o2 = (uint(tri[3 * t + 2]) + base) * A;
    float u = r.x, v = r.y, w = 1.0 - r.x - r.y;
    float gu = 0.0, gv = 0.0;
#if N_DIFF > 0
    vec4 db = rast_db[i];
    vec4 gdb = vec4(0.0);
#endif
    for (uint k = 0u; k < A; ++k) {
        float g = grad_out[i * A + k];
        float a2 = attr[o2 + k];
        float d0 = attr[o0 + k] - a2, d1 = attr[o1 + k] - a2;
        gu += g * d0;
        gv += g * d1;
        float c0 = 0.0, c1 = 0.0;
#if N_DIFF > 0
        int j = diff_slot[k];
        if (j >= 0) {
            float gx = grad_out_da[(i * uint(N_DIFF) + uint(j)) * 2u];
            float gy = grad_out_da[(i * uint(N_DIFF) + uint(j)) * 2u + 1u];
            gdb += vec4(gx * d0, gy * d0, gx * d1, gy * d1);
            c0 = gx * db.x + gy * db.y;
            c1 = gx * db.z + gy * db.w;
        }
#endif
        add(0u, k, o0 + k, group, u * g + c0);
        add(1u, k, o1 + k, group, v * g + c1);
        add(2u, k, o2 + k, group, w * g - (c0 + c1));
    }
#ifndef NO_GRAD_RAST
    grad_rast[i] = vec4(gu, gv, 0.0, 0.0);
#if N_DIFF > 0
    grad_rast_db[i] = gdb;
#endif
#endif
}

#ifdef LOCAL_SUMS
void flush(uint group, uint o[3]) {
    FIXED_TRACK(grad_attr, group, run_largest);
    for (uint k = 0u; k < uint(N_ATTR); ++k)
        for (uint j = 0u; j < 3u; ++j)
            FIXED_ADD_WORDS(grad_attr, fixed_groups, o[j] + k, run_sum[3u * k + j]);
}

void main() {
    uint start = gl_GlobalInvocationID.x * uint(RUN);
    int open_t = -1;
    uint open_image = 0u, open_group = 0u;
    uint open_o[3] = uint[3](0u, 0u, 0u);
    for (uint r = 0u; r < uint(RUN); ++r) {
        uint i = start + r;
        if (i >= n_pixels) break;
        int t = decode_id(rast[i].w) - 1;
        uint image = (first_pixel + i) / pixels_per_image;
        if (t >= 0 && t < n_tri && (t != open_t || image != open_image)) {
            if (open_t >= 0) flush(open_group, open_o);
            open_t = t;
            open_image = image;
            open_group = vertex_stride == 0u ? 0u : image;
            uint base = image * vertex_stride;
            for (int j = 0; j < 3; ++j) open_o[j] = (uint(tri[3 * t + j]) + base) * uint(N_ATTR);
            run_scale = uintBitsToFloat(grad_attr[fixed_groups + open_group]);
            run_largest = 0u;
            for (int m = 0; m < 3 * N_ATTR; ++m) run_sum[m] = uvec2(0u);
        }
        pixel(i);
    }
    if (open_t >= 0) flush(open_group, open_o);
}
#else
void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i < n_pixels) pixel(i);
}
#endif
