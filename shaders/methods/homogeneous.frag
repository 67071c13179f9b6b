#version 450 core
// "homogeneous" / "homogeneous64": 2D homogeneous rasterization (Olano & Greer 1997).
// The edge functions e_i(p) = adj(M)_i . (p_x, p_y, 1) of M = [[X_j], [Y_j], [w_j]]
// (homogeneous window coordinates of the clip-space vertices) are linear in window space;
// s_i = e_i / det(M) gives
//     persp_i  = s_i / sum_j s_j       (GL 4.5 eq. 14.9; Heckbert & Moreton 1991)
//     screen_i = s_i w_i               (eq. 14.10)
// The host computes, per triangle and in extended precision, the gradient of s_i and its
// value at an anchor point a on a 1/256 px grid next to a vertex, each split into a
// high and a low part. Here s_i(p) = s_i(a) + grad s_i . (p - a) is evaluated with
// p - a exact (both on the 1/256 grid, |p - a| < 2^15) and the products and sums made
// error-free (include/compensated.glsl), so the result is about as accurate as if
// computed in twice the working precision and rounded once: the error does
// not grow with the distance from the framebuffer origin nor with the distance from a.
//
// Per-triangle record (SETUP_STRIDE values of type REAL, see glraster/gpu/homogeneous.py):
//   [0, 2)   anchor a (x, y), window pixels
//   [2, 5)   d s_i / dx high      [5, 8)   d s_i / dx low
//   [8, 11)  d s_i / dy high      [11, 14) d s_i / dy low
//   [14, 17) s_i(a) high          [17, 20) s_i(a) low
//   [20, 23) w_i / k  (s is stored scaled by k = max |w_i|, so screen_i = (k s_i)(w_i / k))
//
// Host defines: FP64 (evaluate in double precision: GL 4.0 / ARB_gpu_shader_fp64, and
// write persp / screen as float64, exactly: the unpackDouble2x32 words of b_k in a uvec2
// target of its own, OUT_PERSP_B0 .. OUT_SCREEN_B2 at PERSP_B0_LOCATION ...);
// OUT_PERSP, OUT_SCREEN, OUT_TRI_ID, *_LOCATION; AFFINE; REMAP (see divw.frag).

#ifdef FP64
#define REAL double
#define VEC3 dvec3
#define SPLITTER 134217729.0lf  // 2^27 + 1
#else
#define REAL float
#define VEC3 vec3
#define SPLITTER 4097.0         // 2^12 + 1
#endif
#define SETUP_STRIDE 24

layout(std430, binding = 2) readonly buffer Setup { REAL setup[]; };
#ifdef REMAP
layout(std430, binding = 3) readonly buffer Ids { int ids[]; };
#endif

#ifdef FP64
#ifdef OUT_PERSP_B0
layout(location = PERSP_B0_LOCATION) out uvec2 out_persp_b0;  // (low, high) words of b0
layout(location = PERSP_B1_LOCATION) out uvec2 out_persp_b1;
layout(location = PERSP_B2_LOCATION) out uvec2 out_persp_b2;
#define OUT_PERSP
#endif
#ifdef OUT_SCREEN_B0
layout(location = SCREEN_B0_LOCATION) out uvec2 out_screen_b0;
layout(location = SCREEN_B1_LOCATION) out uvec2 out_screen_b1;
layout(location = SCREEN_B2_LOCATION) out uvec2 out_screen_b2;
#define OUT_SCREEN
#endif
#else
#ifdef OUT_PERSP
layout(location = PERSP_LOCATION) out vec3 out_persp;
#endif
#ifdef OUT_SCREEN
layout(location = SCREEN_LOCATION) out vec3 out_screen;
#endif
#endif
#ifdef OUT_TRI_ID
layout(location = TRI_ID_LOCATION) out int out_tri_id;
uniform int tri_base;  // index of the draw's first triangle (large meshes draw in batches)
#endif

#include "include/compensated.glsl"

// s_i(a) + grad s_i . d, compensated.
REAL evaluate(int base, int i, REAL dx, REAL dy) {
    return compensated_plane(setup[base + 2 + i], setup[base + 5 + i], setup[base + 8 + i],
                             setup[base + 11 + i], setup[base + 14 + i], setup[base + 17 + i],
                             dx, dy);
}

void main() {
    int base = SETUP_STRIDE * gl_PrimitiveID;
#if defined(OUT_PERSP) || defined(OUT_SCREEN)
    // Pixel centers are x + 0.5, exact in float; the anchor is on the 1/256 grid.
    precise REAL dx = REAL(gl_FragCoord.x) - setup[base];
    precise REAL dy = REAL(gl_FragCoord.y) - setup[base + 1];
    REAL s0 = evaluate(base, 0, dx, dy);
    REAL s1 = evaluate(base, 1, dx, dy);
    REAL s2 = evaluate(base, 2, dx, dy);
    REAL w0 = setup[base + 20], w1 = setup[base + 21], w2 = setup[base + 22];
#ifdef AFFINE
    // every w equal: w_i / k = 1 and sum s_i = 1, so screen = persp = s
    VEC3 screen = VEC3(s0, s1, s2);
#else
    VEC3 screen = VEC3(s0 * w0, s1 * w1, s2 * w2);
#endif
#endif
#ifdef OUT_PERSP
#ifdef AFFINE
    VEC3 persp = screen;
#else
    REAL total = s0 + s1 + s2;  // k / w_p
    VEC3 persp = VEC3(s0 / total, s1 / total, s2 / total);
#endif
#endif
#ifdef FP64
#ifdef OUT_SCREEN
    out_screen_b0 = unpackDouble2x32(screen.x);
    out_screen_b1 = unpackDouble2x32(screen.y);
    out_screen_b2 = unpackDouble2x32(screen.z);
#endif
#ifdef OUT_PERSP
    out_persp_b0 = unpackDouble2x32(persp.x);
    out_persp_b1 = unpackDouble2x32(persp.y);
    out_persp_b2 = unpackDouble2x32(persp.z);
#endif
#else
#ifdef OUT_SCREEN
    out_screen = screen;
#endif
#ifdef OUT_PERSP
    out_persp = persp;
#endif
#endif
#ifdef OUT_TRI_ID
#ifdef REMAP
    out_tri_id = ids[gl_PrimitiveID] + 1;
#else
    out_tri_id = tri_base + gl_PrimitiveID + 1;
#endif
#endif
}
