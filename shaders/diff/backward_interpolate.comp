#version 450
// Backward of attribute interpolation, one invocation per pixel. From dL/d(out) (and, with
// N_DIFF > 0, dL/d(out_da)):
//   dL/da[t0] += u g + (g_x du/dx + g_y du/dy),  dL/da[t1] += v g + (g_x dv/dx + g_y dv/dy),
//   dL/da[t2] += (1 - u - v) g - (both brackets)      (g_x, g_y: the chosen attributes only)
//   dL/du = sum_k g_k (a0 - a2)_k,  dL/dv = sum_k g_k (a1 - a2)_k          -> grad_rast
//   dL/d(du/dx, du/dy, dv/dx, dv/dy) = sum_k (g_x (a0-a2), g_y (a0-a2), g_x (a1-a2), g_y (a1-a2))
// Accumulation into dL/da as in backward_rasterize.comp: ACCUM_ATOMIC_FLOAT | ACCUM_CAS |
// ACCUM_FIXED_POINT (one fixed-point add per term; the local sums over runs of pixels of
// backward_rasterize.comp measured no faster here); NO_GRAD_ATTR: dL/da not wanted (no accumulation at all), NO_GRAD_RAST:
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

// a corner's term of dL/d attr[slot] (group: the image when attr is batched, else 0)
void add(uint slot, uint group, float value) {
#if defined(NO_GRAD_ATTR)
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
        add(o0 + k, group, u * g + c0);
        add(o1 + k, group, v * g + c1);
        add(o2 + k, group, w * g - (c0 + c1));
    }
#ifndef NO_GRAD_RAST
    grad_rast[i] = vec4(gu, gv, 0.0, 0.0);
#if N_DIFF > 0
    grad_rast_db[i] = gdb;
#endif
#endif
}

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i < n_pixels) pixel(i);
}
