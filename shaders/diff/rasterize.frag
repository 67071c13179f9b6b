#version 450 core
// The differentiable rasterize's forward (glraster/diff/rasterize.py, docs/differentiable.md).
//
// Writes, per covered pixel (row 0 at the bottom):
//   rast    = (u, v, z/w, id): u = b0, v = b1, the perspective-correct barycentrics of the
//             triangle's vertices 0 and 1 (SPACE_SCREEN: the window-space ones), z/w the
//             NDC depth z_c / w_c of the surface point, id = triangle index + 1 encoded as
//             a float (include/triangle_id.glsl); the clear value 0 marks empty pixels.
//   rast_db = (du/dx, du/dy, dv/dx, dv/dy) at the pixel centre, in window pixels.
//
// With homogeneous window coordinates X_j = (x_j + w_j) W/2, Y_j = (y_j + w_j) H/2 and
// M = [[X_j], [Y_j], [w_j]], row i of adj(M) is the edge function e_i = A_i x + B_i y + C_i
// and s_i = e_i / det(M) (Olano & Greer 1997). With S = sum_j s_j (= 1 / w of the surface
// point), b_i = s_i / S, and
//   d b_i / dx = (g_i - b_i sum_j g_j) / S,   g_i = d s_i / dx = A_i / det  (y: B_i)
//   window-space barycentrics s_i w_i have d (s_i w_i) / dx = g_i w_i
//   z / w = sum_i s_i z_i                     (M s = (x, y, 1): sum_i s_i w_i = 1)
// All of it is evaluated here at gl_FragCoord from the triangle's setup record: the
// derivatives are the exact closed form at the centre, not a 2x2-quad difference.
//
// The record (RECORD_STRIDE floats per triangle, glraster/diff/rasterize.py) is the
// "homogeneous" method's (glraster/gpu/homogeneous.py, shaders/methods/homogeneous.frag),
// everything scaled by k = max_j |w_j|, plus z_j / k:
//   [0, 2) anchor a   [2, 5) k g_i (x) high  [5, 8) low   [8, 11) k g_i (y) high  [11, 14) low
//   [14, 17) k s_i(a) high  [17, 20) low     [20, 23) w_i / k   [24, 27) z_i / k
// It is read as RECORD_STRIDE / 4 whole vec4s (llvmpipe gathers each load per fragment:
// 7 vector loads cost less than 28 scalar ones, measured).
// s_i(p) = s_i(a) + grad s_i . (p - a) is evaluated compensated (exact p - a,
// include/compensated.glsl), so it is about as accurate as a float64 evaluation rounded
// once to float32, wherever the pixel is.
//
// Host defines: OUT_RAST, OUT_RAST_DB, RAST_LOCATION, RAST_DB_LOCATION; SPACE_SCREEN;
// REMAP (ids[] at binding 3 holds the caller's triangle index of each drawn triangle);
// PEEL (discard fragments at or in front of the previous layer's z/w, prev_depth).

#define RECORD_STRIDE 28
#define RECORD_VEC4S 7  // RECORD_STRIDE / 4

layout(std430, binding = 2) readonly buffer Setup { vec4 records[]; };
#ifdef REMAP
layout(std430, binding = 3) readonly buffer Ids { int ids[]; };
#endif

layout(location = RAST_LOCATION) out vec4 out_rast;
#ifdef OUT_RAST_DB
layout(location = RAST_DB_LOCATION) out vec4 out_rast_db;
#endif
uniform int tri_base;  // index of the storage batch's first triangle (set by the pipeline)
uniform int id_base;   // index in the caller's tri of the draw's first triangle (ranges)
#ifdef PEEL
uniform sampler2D prev_depth;  // (H, W) previous layer's z/w; +inf where it was empty
#endif

#include "include/compensated.glsl"
#include "include/triangle_id.glsl"

// k s_i(a) + k grad s_i . d, compensated, from the record r.
float evaluate(float r[RECORD_STRIDE], int i, float dx, float dy) {
    return compensated_plane(r[2 + i], r[5 + i], r[8 + i], r[11 + i], r[14 + i], r[17 + i],
                             dx, dy);
}

void main() {
    float r[RECORD_STRIDE];  // this fragment's triangle's record
    for (int k = 0; k < RECORD_VEC4S; k++) {
        vec4 part = records[RECORD_VEC4S * gl_PrimitiveID + k];
        r[4 * k] = part.x;
        r[4 * k + 1] = part.y;
        r[4 * k + 2] = part.z;
        r[4 * k + 3] = part.w;
    }
    precise float dx = gl_FragCoord.x - r[0];
    precise float dy = gl_FragCoord.y - r[1];
    vec3 s = vec3(evaluate(r, 0, dx, dy), evaluate(r, 1, dx, dy),
                  evaluate(r, 2, dx, dy));
    vec3 zk = vec3(r[24], r[25], r[26]);
    float z = dot(s, zk);
#ifdef PEEL
    if (z <= texelFetch(prev_depth, ivec2(gl_FragCoord.xy), 0).r) {
        discard;
    }
#endif
    vec3 gx = vec3(r[2], r[3], r[4]);
    vec3 gy = vec3(r[8], r[9], r[10]);
#ifdef SPACE_SCREEN
    vec3 wk = vec3(r[20], r[21], r[22]);
    vec3 b = s * wk;
    vec3 bx = gx * wk;
    vec3 by = gy * wk;
#else
    float total = s.x + s.y + s.z;           // k S = k / w of the surface point
    float inv = total != 0.0 ? 1.0 / total : 0.0;
    vec3 b = vec3(s.x / total, s.y / total, s.z / total);
    if (total == 0.0) {
        b = vec3(0.0);
    }
    vec3 bx = (gx - b * (gx.x + gx.y + gx.z)) * inv;
    vec3 by = (gy - b * (gy.x + gy.y + gy.z)) * inv;
#endif
#ifdef REMAP
    int id = ids[gl_PrimitiveID] + 1;
#else
    int id = id_base + tri_base + gl_PrimitiveID + 1;
#endif
    out_rast = vec4(b.x, b.y, z, encode_id(id));
#ifdef OUT_RAST_DB
    out_rast_db = vec4(bx.x, by.x, bx.y, by.y);
#endif
}
