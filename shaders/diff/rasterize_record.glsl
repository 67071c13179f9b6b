// The differentiable rasterize's per-triangle setup record and its evaluation, shared by
// the raster pass (shaders/diff/rasterize.frag, depth peeling) and the resolve pass
// (shaders/diff/rasterize.comp), so that both compute z/w with the same operations.
//
// The record (RECORD_STRIDE floats per triangle, glraster/diff/rasterize.py) is the
// "homogeneous" method's (glraster/gpu/homogeneous.py, shaders/methods/homogeneous.frag),
// everything scaled by k = max_j |w_j|, plus z_j / k:
//   [0, 2) anchor a   [2, 5) k g_i (x) high  [5, 8) low   [8, 11) k g_i (y) high  [11, 14) low
//   [14, 17) k s_i(a) high  [17, 20) low     [20, 23) w_i / k   [24, 27) z_i / k
// It is read as RECORD_VEC4S whole vec4s: by default from an RGBA32F texture of
// RECORDS_PER_ROW records a row (host define; texelFetch returns the stored bits), which
// llvmpipe gathers with vector loads, where it loads a storage buffer's per-invocation
// addresses one invocation at a time (measured: the resolve pass took a third of the time
// at 1024² reading the texture); with RECORDS_IN_BUFFER from the storage buffer at
// binding 2 (the peeler's raster pass, whose draws the pipeline splits by storage block).
//
// s_i(p) = s_i(a) + grad s_i . (p - a) is evaluated compensated (exact p - a,
// include/compensated.glsl), so it is about as accurate as a float64 evaluation rounded
// once to float32, wherever the pixel is.

#define RECORD_STRIDE 28
#define RECORD_VEC4S 7  // RECORD_STRIDE / 4

#ifdef RECORDS_IN_BUFFER
layout(std430, binding = 2) readonly buffer Setup { vec4 records[]; };
#define RECORD_PART(t, k) records[RECORD_VEC4S * (t) + (k)]
#else
uniform sampler2D records;  // record t at row t / RECORDS_PER_ROW, texels RECORD_VEC4S wide
#define RECORD_PART(t, k) texelFetch(records, ivec2(((t) % RECORDS_PER_ROW) * RECORD_VEC4S + (k), \
                                                    (t) / RECORDS_PER_ROW), 0)
#endif

#include "include/compensated.glsl"

// The record of triangle t of the bound records.
void load_record(int t, out float r[RECORD_STRIDE]) {
    for (int k = 0; k < RECORD_VEC4S; k++) {
        vec4 part = RECORD_PART(t, k);
        r[4 * k] = part.x;
        r[4 * k + 1] = part.y;
        r[4 * k + 2] = part.z;
        r[4 * k + 3] = part.w;
    }
}

// k s_i(a) + k grad s_i . d, compensated, from the record r.
float evaluate(float r[RECORD_STRIDE], int i, float dx, float dy) {
    return compensated_plane(r[2 + i], r[5 + i], r[8 + i], r[11 + i], r[14 + i], r[17 + i],
                             dx, dy);
}

// k s_i (i = 0, 1, 2) at the window point p (a pixel centre).
vec3 scaled_coordinates(float r[RECORD_STRIDE], vec2 p) {
    precise float dx = p.x - r[0];
    precise float dy = p.y - r[1];
    return vec3(evaluate(r, 0, dx, dy), evaluate(r, 1, dx, dy), evaluate(r, 2, dx, dy));
}

// z/w = sum_i s_i z_i from the k s_i (M s = (x, y, 1): sum_i s_i w_i = 1).
float depth_of(float r[RECORD_STRIDE], vec3 s) {
    return dot(s, vec3(r[24], r[25], r[26]));
}
