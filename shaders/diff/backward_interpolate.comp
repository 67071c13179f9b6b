#version 450
// Backward of attribute interpolation, one invocation per pixel. From dL/d(out) (and, with
// N_DIFF > 0, dL/d(out_da)):
//   dL/da[t0] += u g + (g_x du/dx + g_y du/dy),  dL/da[t1] += v g + (g_x dv/dx + g_y dv/dy),
//   dL/da[t2] += (1 - u - v) g - (both brackets)      (g_x, g_y: the chosen attributes only)
//   dL/du = sum_k g_k (a0 - a2)_k,  dL/dv = sum_k g_k (a1 - a2)_k          -> grad_rast
//   dL/d(du/dx, du/dy, dv/dx, dv/dy) = sum_k (g_x (a0-a2), g_y (a0-a2), g_x (a1-a2), g_y (a1-a2))
// Accumulation into dL/da as in backward_rasterize.comp: ACCUM_ATOMIC_FLOAT | ACCUM_CAS |
// ACCUM_PER_PIXEL (three rows of n_attr floats per pixel, reduced by the caller).
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
#elif defined(ACCUM_CAS)
layout(std430, binding = 5) buffer GradAttr { uint grad_attr[]; };
#else
layout(std430, binding = 5) writeonly buffer Contrib { float contrib[]; };
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

#include "include/triangle_id.glsl"
#include "include/atomic_add_float.glsl"

// contribution of corner j (0, 1, 2) to attribute k
void add(uint i, uint j, uint slot, uint k, float value) {
#if defined(ACCUM_ATOMIC_FLOAT) || defined(ACCUM_CAS)
    if (value != 0.0) ATOMIC_ADD_FLOAT(grad_attr[slot], value);
#else
    contrib[(3u * i + j) * uint(n_attr) + k] = value;
#endif
}

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= n_pixels) return;
    uint A = uint(n_attr);
    vec4 r = rast[i];
    int t = decode_id(r.w) - 1;
    if (t < 0 || t >= n_tri) {
        grad_rast[i] = vec4(0.0);
#if N_DIFF > 0
        grad_rast_db[i] = vec4(0.0);
#endif
#ifdef ACCUM_PER_PIXEL
        for (uint k = 0u; k < 3u * A; ++k) contrib[3u * i * A + k] = 0.0;
#endif
        return;
    }
    uint base = ((first_pixel + i) / pixels_per_image) * vertex_stride;
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
        add(i, 0u, o0 + k, k, u * g + c0);
        add(i, 1u, o1 + k, k, v * g + c1);
        add(i, 2u, o2 + k, k, w * g - (c0 + c1));
    }
    grad_rast[i] = vec4(gu, gv, 0.0, 0.0);
#if N_DIFF > 0
    grad_rast_db[i] = gdb;
#endif
}
