#version 450
// Backward of attribute interpolation, RUN (default 1) consecutive pixels per invocation.
// From dL/d(out) (and, with N_DIFF > 0, dL/d(out_da)):
//   dL/da[t0] += u g + (g_x du/dx + g_y du/dy),  dL/da[t1] += v g + (g_x dv/dx + g_y dv/dy),
//   dL/da[t2] += (1 - u - v) g - (both brackets)      (g_x, g_y: the chosen attributes only)
//   dL/du = sum_k g_k (a0 - a2)_k,  dL/dv = sum_k g_k (a1 - a2)_k          -> grad_rast
//   dL/d(du/dx, du/dy, dv/dx, dv/dy) = sum_k (g_x (a0-a2), g_y (a0-a2), g_x (a1-a2), g_y (a1-a2))
// Accumulation into dL/da as in backward_rasterize.comp: ACCUM_ATOMIC_FLOAT | ACCUM_CAS |
// ACCUM_FIXED_POINT, the terms of the invocation's pixels on one triangle summed locally
// (N_ATTR: the attribute count, so the 3 N_ATTR local sums are an array) and each sum
// added with one atomic (fixed point: one word atomic, two where it reaches the high
// word). NO_GRAD_ATTR: dL/da not wanted (no accumulation at all), NO_GRAD_RAST: grad_rast and grad_rast_db not wanted
// (not written). The gathered inputs (attributes, triangles, rast, rast_db, dL/d out,
// dL/d out_da) are read through buffer textures (include/interpolate_views.glsl).
#ifdef ACCUM_ATOMIC_FLOAT
#extension GL_NV_shader_atomic_float : require
#endif

layout(local_size_x = 64) in;

#include "include/interpolate_views.glsl"
layout(binding = TEXEL_UNIT + 4) uniform samplerBuffer grad_out;
layout(std430, binding = 4) writeonly buffer GradRast { vec4 grad_rast[]; };
#if defined(ACCUM_ATOMIC_FLOAT)
layout(std430, binding = 5) buffer GradAttr { float grad_attr[]; };
#elif defined(ACCUM_CAS) || defined(ACCUM_FIXED_POINT)
layout(std430, binding = 5) buffer GradAttr { uint grad_attr[]; };
#endif
#if N_DIFF > 0
layout(std430, binding = 7) readonly buffer DiffSlot { int diff_slot[]; };  // per attribute: its place among the chosen, or -1
layout(binding = TEXEL_UNIT + 5) uniform samplerBuffer grad_out_da;
layout(std430, binding = 9) writeonly buffer GradRastDb { vec4 grad_rast_db[]; };
#endif

uniform uint n_pixels;
uniform uint first_pixel;
uniform uint pixels_per_image;
uniform uint vertex_stride;
uniform int n_tri;
uniform uint fixed_groups;   // ACCUM_FIXED_POINT: B with batched attr (one scale per image), else 1

#include "include/triangle_id.glsl"
#include "include/atomic_add_float.glsl"
#include "include/fixed_point.glsl"

#ifndef RUN
#define RUN 1
#endif
#ifdef ACCUM_FIXED_POINT
#define TERM uvec2
#define TERM_ZERO uvec2(0u)
#else
#define TERM float
#define TERM_ZERO 0.0
#endif
#define SUMS (3 * ROW)

// the local sums of a stretch of pixels on one triangle (corner rows o[j], attribute k:
// sum[3 k + j]) to grad_attr; group: the image when attr is batched, else 0
void flush(uint o[3], uint group, TERM sum[SUMS], uint largest) {
#ifndef NO_GRAD_ATTR
#ifdef ACCUM_FIXED_POINT
    FIXED_TRACK(grad_attr, group, largest);
#endif
    for (uint k = 0u; k < uint(N_ATTR); ++k) {
        for (uint j = 0u; j < 3u; ++j) {
#ifdef ACCUM_FIXED_POINT
            FIXED_ADD_WORDS(grad_attr, fixed_groups, o[j] + k, sum[3u * k + j]);
#else
            float value = sum[3u * k + j];
            if (value != 0.0) ATOMIC_ADD_FLOAT(grad_attr[o[j] + k], value);
#endif
        }
    }
#endif
}

void main() {
    uint start = gl_GlobalInvocationID.x * uint(RUN);
    const uint A = uint(N_ATTR);
    int open_t = -1;
    uint open_image = 0u, open_group = 0u;
    uint open_o[3] = uint[3](0u, 0u, 0u);
    float d0[ROW], d1[ROW];   // the open triangle's a0 - a2, a1 - a2
    TERM sum[SUMS];
    uint largest = 0u;      // fixed point: fixed_point_magnitude of the largest term
    float scale = 0.0;
    for (uint r = 0u; r < uint(RUN); ++r) {
        uint i = start + r;
        if (i >= n_pixels) break;
        vec4 rs = texelFetch(rast, int(i));
        int t = decode_id(rs.w) - 1;
        if (t < 0 || t >= n_tri) {
#ifndef NO_GRAD_RAST
            grad_rast[i] = vec4(0.0);
#if N_DIFF > 0
            grad_rast_db[i] = vec4(0.0);
#endif
#endif
            continue;
        }
        uint image = (first_pixel + i) / pixels_per_image;
        if (t != open_t || image != open_image) {
            if (open_t >= 0) flush(open_o, open_group, sum, largest);
            open_t = t;
            open_image = image;
            uint base = image * vertex_stride;
            uvec3 corner = uvec3(texelFetch(tri, t).xyz) + base;
            open_o = uint[3](corner.x * A, corner.y * A, corner.z * A);
            float a0[ROW], a1[ROW], a2[ROW];
            load_row(attr, corner.x, a0);
            load_row(attr, corner.y, a1);
            load_row(attr, corner.z, a2);
            for (uint k = 0u; k < A; ++k) {
                d0[k] = a0[k] - a2[k];
                d1[k] = a1[k] - a2[k];
            }
            open_group = vertex_stride == 0u ? 0u : image;
#ifdef ACCUM_FIXED_POINT
            scale = uintBitsToFloat(grad_attr[fixed_groups + open_group]);
#endif
            for (int m = 0; m < SUMS; ++m) sum[m] = TERM_ZERO;
            largest = 0u;
        }
        float u = rs.x, v = rs.y, w = 1.0 - rs.x - rs.y;
        float gu = 0.0, gv = 0.0;
#if N_DIFF > 0
        vec4 db = texelFetch(rast_db, int(i));
        vec4 gdb = vec4(0.0);
#endif
        float g_row[ROW];
        load_row(grad_out, i, g_row);
        for (uint k = 0u; k < A; ++k) {
            float g = g_row[k];
            gu += g * d0[k];
            gv += g * d1[k];
            float c0 = 0.0, c1 = 0.0;
#if N_DIFF > 0
            int j = diff_slot[k];
            if (j >= 0) {
                vec2 gxy = texelFetch(grad_out_da, int(i) * N_DIFF + j).xy;
                float gx = gxy.x, gy = gxy.y;
                gdb += vec4(gx * d0[k], gy * d0[k], gx * d1[k], gy * d1[k]);
                c0 = gx * db.x + gy * db.y;
                c1 = gx * db.z + gy * db.w;
            }
#endif
#ifndef NO_GRAD_ATTR
            vec3 terms = vec3(u * g + c0, v * g + c1, w * g - (c0 + c1));
            for (uint c = 0u; c < 3u; ++c) {
#ifdef ACCUM_FIXED_POINT
                largest = max(largest, fixed_point_magnitude(terms[c]));
                sum[3u * k + c] = fixed_point_add(sum[3u * k + c],
                                                  fixed_point_words(terms[c], scale));
#else
                sum[3u * k + c] += terms[c];
#endif
            }
#endif
        }
#ifndef NO_GRAD_RAST
        grad_rast[i] = vec4(gu, gv, 0.0, 0.0);
#if N_DIFF > 0
        grad_rast_db[i] = gdb;
#endif
#endif
    }
    if (open_t >= 0) flush(open_o, open_group, sum, largest);
}
