#version 450
// Backward of point-sampled rasterization: dL/d(pos) from dL/d(u, v) and, with GRAD_DB,
// dL/d(du/dx, du/dy, dv/dx, dv/dy), at frozen coverage (one invocation per pixel).
//
// Defines: SPACE_SCREEN (u, v are window-space barycentrics, else perspective-correct);
// ACCUM_ATOMIC_FLOAT (atomicAdd on float, GL_NV_shader_atomic_float) | ACCUM_CAS
// (atomicCompSwap loop on the float's bits) | ACCUM_FIXED_POINT (64-bit fixed-point integer
// sums, include/fixed_point.glsl: bit-reproducible) | ACCUM_PER_PIXEL (each pixel writes
// its three vertex contributions, for backward_pixels); RUN (pixels per invocation, local
// sums), TILE_RUNS (runs per tile row): see main; GRAD_DB.
//
// Mathematics (docs/differentiable.md, "Backward on the GPU"). In the pixel-relative window
// frame V'_j = (X_j - p_x w_j, Y_j - p_y w_j, w_j), with X = (x + w) W/2, Y = (y + w) H/2,
// each edge row N_k = V'_{k+1} x V'_{k+2} = (A_k, B_k, e_k): e_k is the edge function at the
// pixel centre, (A_k, B_k) its screen gradient; b_k = e_k / S, S = e_0 + e_1 + e_2
// (window space: b_k = e_k w_k / det, det = V'_0 . N_0).
// With n_k = dL/dN_k, dL/dV'_{k+1} += V'_{k+2} x n_k and dL/dV'_{k+2} += n_k x V'_{k+1}.
#ifdef ACCUM_ATOMIC_FLOAT
#extension GL_NV_shader_atomic_float : require
#endif

layout(local_size_x = 64) in;

// The gathered inputs, read through buffer textures over their buffers (GL 4.6 section
// 8.9, texelFetch: on llvmpipe a vector gather, where a storage-buffer load at per-lane
// addresses is one scalar load per lane; the same bits). Units from TEXEL_UNIT: + 0 pos
// (RGBA32F, one vertex a texel), + 1 tri (RGB32I, one triangle a texel), + 2 rast,
// + 3 dL/d rast, + 4 dL/d rast_db (RGBA32F, one pixel a texel).
layout(binding = TEXEL_UNIT) uniform samplerBuffer pos;
layout(binding = TEXEL_UNIT + 1) uniform isamplerBuffer tri;
layout(binding = TEXEL_UNIT + 2) uniform samplerBuffer rast;
layout(binding = TEXEL_UNIT + 3) uniform samplerBuffer grad_rast;
#ifdef GRAD_DB
layout(binding = TEXEL_UNIT + 4) uniform samplerBuffer grad_db;
#endif
#if defined(ACCUM_ATOMIC_FLOAT)
layout(std430, binding = 5) buffer GradPos { float grad_pos[]; };
#elif defined(ACCUM_CAS) || defined(ACCUM_FIXED_POINT)
layout(std430, binding = 5) buffer GradPos { uint grad_pos[]; };
#else
// (dL/dx, dL/dy, 0, dL/dw) of the pixel's vertex 0, 1, 2: three vec4 per pixel
layout(std430, binding = 5) writeonly buffer Contrib { vec4 contrib[]; };
#endif

uniform uint n_pixels;       // pixels in this dispatch
uniform uint first_pixel;    // flat index (b, y, x) of the first one
uniform uvec2 size;          // (W, H)
uniform uint vertex_stride;  // V when pos is batched, else 0
uniform int n_tri;
uniform uint fixed_groups;   // ACCUM_FIXED_POINT: B with batched pos (one scale per image), else 1

#include "include/triangle_id.glsl"
#include "include/atomic_add_float.glsl"
#include "include/fixed_point.glsl"

// one pixel's terms g = (x, y, w) to a vertex (image b), one atomic each (RUN undefined)
void add(uint vertex, uint b, vec3 g) {
    uint o = 4u * vertex;
#if defined(ACCUM_ATOMIC_FLOAT) || defined(ACCUM_CAS)
    ATOMIC_ADD_FLOAT(grad_pos[o + 0u], g.x);
    ATOMIC_ADD_FLOAT(grad_pos[o + 1u], g.y);
    ATOMIC_ADD_FLOAT(grad_pos[o + 3u], g.z);
#elif defined(ACCUM_FIXED_POINT)
    uint group = vertex_stride == 0u ? 0u : b;
    FIXED_ADD(grad_pos, fixed_groups, group, o + 0u, g.x);
    FIXED_ADD(grad_pos, fixed_groups, group, o + 1u, g.y);
    FIXED_ADD(grad_pos, fixed_groups, group, o + 3u, g.z);
#endif
}

// Pixel i (of this dispatch): its triangle t, image b, the pixel centre in NDC and the
// upstream gradients; false when it adds nothing (empty, or a zero upstream gradient
// outside ACCUM_PER_PIXEL).
struct Pixel {
    int t;
    uint b;
    vec2 ndc;
    vec2 gbary;
    vec4 gdb;
};

// (x, y, image) of flat pixel g = first_pixel + i (integer divisions: one per invocation,
// since llvmpipe runs each lane's division on its own)
uvec3 pixel_position(uint g) {
    uint hw = size.x * size.y;
    uint b = g / hw;
    uint r = g - b * hw;
    uint y = r / size.x;
    return uvec3(r - y * size.x, y, b);
}

bool pixel_at(uint i, uvec3 at, out Pixel px) {
    px.t = decode_id(texelFetch(rast, int(i)).w) - 1;
    if (px.t < 0 || px.t >= n_tri) return false;
    px.gbary = texelFetch(grad_rast, int(i)).xy;
#ifdef GRAD_DB
    px.gdb = texelFetch(grad_db, int(i));
#else
    px.gdb = vec4(0.0);
#endif
#ifndef ACCUM_PER_PIXEL
    if (px.gbary == vec2(0.0) && px.gdb == vec4(0.0)) return false;
#endif
    px.b = at.z;
    px.ndc = (2.0 * vec2(at.xy) + 1.0) / vec2(size) - 1.0;
    return true;
}

// the vertices idx (batch offset included) of triangle t in image b, and their positions
void corners(int t, uint b, out uint idx[3], out vec4 p[3]) {
    uint base = b * vertex_stride;
    uvec3 c = uvec3(texelFetch(tri, t).xyz) + base;
    idx = uint[3](c.x, c.y, c.z);
    for (int j = 0; j < 3; ++j) p[j] = texelFetch(pos, int(idx[j]));
}

// The pixel's terms to the clip-space (x, y, w) of its triangle's vertices, positions p.
void pixel_terms(Pixel px, vec4 p[3], out vec3 terms[3]) {
    vec2 half_size = 0.5 * vec2(size);
    vec2 ndc = px.ndc;
    vec2 gbary = px.gbary;
#ifdef GRAD_DB
    vec4 gdb = px.gdb;
#endif
    vec3 V[3];
    for (int j = 0; j < 3; ++j) {
        // pixel-relative homogeneous window coordinates: X' = (W/2) (x - w ndc_x)
        V[j] = vec3(half_size * fma(-vec2(p[j].w), ndc, p[j].xy), p[j].w);
    }
    vec3 N[3];
    for (int k = 0; k < 3; ++k) N[k] = cross(V[(k + 1) % 3], V[(k + 2) % 3]);
    vec3 G[3] = vec3[3](vec3(0.0), vec3(0.0), vec3(0.0));
    vec3 ge = vec3(0.0), gA = vec3(0.0), gB = vec3(0.0);
    vec3 g3 = vec3(gbary, 0.0);
#ifdef GRAD_DB
    vec3 hx = vec3(gdb.x, gdb.z, 0.0);   // dL/d(db_i/dx), i = 0, 1
    vec3 hy = vec3(gdb.y, gdb.w, 0.0);   // dL/d(db_i/dy)
#endif
#ifdef SPACE_SCREEN
    // window-space barycentrics b_i = e_i w_i / det, db_i/dx = A_i w_i / det
    float det = dot(V[0], N[0]);
    if (det != 0.0) {
        float invD = 1.0 / det;
        vec3 w = vec3(V[0].z, V[1].z, V[2].z);
        vec3 e = vec3(N[0].z, N[1].z, N[2].z);
        ge = g3 * w * invD;
        vec3 gw = g3 * e * invD;
        float gdet = -dot(g3, e * w);
#ifdef GRAD_DB
        vec3 A = vec3(N[0].x, N[1].x, N[2].x), B = vec3(N[0].y, N[1].y, N[2].y);
        gA = hx * w * invD;
        gB = hy * w * invD;
        gw += (hx * A + hy * B) * invD;
        gdet -= dot(hx * A + hy * B, w);
#endif
        gdet *= invD * invD;
        for (int j = 0; j < 3; ++j) G[j] = gdet * N[j] + vec3(0.0, 0.0, gw[j]);
    }
#else
    // perspective-correct barycentrics b_i = e_i / S, db_i/dx = (A_i - b_i sum_j A_j) / S
    float S = N[0].z + N[1].z + N[2].z;
    if (S != 0.0) {
        float invS = 1.0 / S;
        float b0 = N[0].z * invS, b1 = N[1].z * invS;
        // dL/de_k = (g_k - sum_i g_i b_i) / S
        ge = (g3 - (g3.x * b0 + g3.y * b1)) * invS;
#ifdef GRAD_DB
        float SA = N[0].x + N[1].x + N[2].x, SB = N[0].y + N[1].y + N[2].y;
        vec4 db = vec4(N[0].x - b0 * SA, N[0].y - b0 * SB, N[1].x - b1 * SA, N[1].y - b1 * SB) * invS;
        vec3 gx = hx - (hx.x * b0 + hx.y * b1);
        vec3 gy = hy - (hy.x * b0 + hy.y * b1);
        gA = gx * invS;
        gB = gy * invS;
        ge -= (dot(gdb, db) + (SA * invS) * gx + (SB * invS) * gy) * invS;
#endif
    }
#endif
    for (int k = 0; k < 3; ++k) {
        vec3 n = vec3(gA[k], gB[k], ge[k]);   // dL/d(A_k, B_k, e_k)
        int k1 = (k + 1) % 3, k2 = (k + 2) % 3;
        G[k1] += cross(V[k2], n);
        G[k2] += cross(n, V[k1]);
    }
    for (int j = 0; j < 3; ++j) {
        // back to clip space: X' = (W/2)(x - w ndc_x), Y' = (H/2)(y - w ndc_y)
        vec2 gxy = half_size * G[j].xy;
        terms[j] = vec3(gxy, G[j].z - dot(ndc, gxy));
    }
}

#ifdef RUN
// A work group is a tile of TILE_ROWS rows of TILE_RUNS runs of RUN consecutive pixels (of
// the chunk's rows: the B H image rows stacked), one run per invocation, so an invocation
// stays in one image (one fixed-point group: one scale, one FIXED_TRACK). The terms of a
// stretch of a run's pixels on one triangle are summed locally and added with one atomic
// per vertex coordinate (fixed point: one or two word atomics; 64-bit integer sums are
// associative, so the same bits), instead of one per pixel.
#define TILE_ROWS (64 / TILE_RUNS)
#define TILE_WIDTH (TILE_RUNS * RUN)
#ifdef ACCUM_FIXED_POINT
#define TERM uvec2
#define TERM_ZERO uvec2(0u)
#else
#define TERM float
#define TERM_ZERO 0.0
#endif

// sums `sum` (vertex, coordinate) to the vertices idx, added to grad_pos
void flush(uint idx[3], TERM sum[9]) {
    for (int j = 0; j < 3; ++j) {
        uint o = 4u * idx[j];
#ifdef ACCUM_FIXED_POINT
        FIXED_ADD_WORDS(grad_pos, fixed_groups, o + 0u, sum[3 * j]);
        FIXED_ADD_WORDS(grad_pos, fixed_groups, o + 1u, sum[3 * j + 1]);
        FIXED_ADD_WORDS(grad_pos, fixed_groups, o + 3u, sum[3 * j + 2]);
#else
        ATOMIC_ADD_FLOAT(grad_pos[o + 0u], sum[3 * j]);
        ATOMIC_ADD_FLOAT(grad_pos[o + 1u], sum[3 * j + 1]);
        ATOMIC_ADD_FLOAT(grad_pos[o + 3u], sum[3 * j + 2]);
#endif
    }
}

void main() {
    uint l = gl_LocalInvocationIndex;
    uint tiles_x = (size.x + uint(TILE_WIDTH) - 1u) / uint(TILE_WIDTH);
    uint row = (gl_WorkGroupID.x / tiles_x) * uint(TILE_ROWS) + l / uint(TILE_RUNS);
    uint x0 = (gl_WorkGroupID.x % tiles_x) * uint(TILE_WIDTH) + (l % uint(TILE_RUNS)) * uint(RUN);
    if (row >= n_pixels / size.x || x0 >= size.x) return;
    uint count = min(uint(RUN), size.x - x0);
    uint start = row * size.x + x0;               // the run's first pixel in this chunk
    uint image_row = first_pixel / size.x + row;  // its row among the B H
    uint image = image_row / size.y;
    uvec3 at = uvec3(x0, image_row - image * size.y, image);
    int open_t = -1;
    uint open_idx[3];        // the open triangle's vertices and positions, loaded once
    vec4 open_p[3];          // per stretch
    TERM sum[9];
    uint largest = 0u;       // fixed point: fixed_point_magnitude of the largest term
#ifdef ACCUM_FIXED_POINT
    uint group = vertex_stride == 0u ? 0u : image;
    float scale = uintBitsToFloat(grad_pos[fixed_groups + group]);
#endif
    for (uint r = 0u; r < count; ++r, ++at.x) {
        Pixel px;
        if (!pixel_at(start + r, at, px)) continue;
        if (px.t != open_t) {
            if (open_t >= 0) flush(open_idx, sum);
            open_t = px.t;
            corners(open_t, image, open_idx, open_p);
            for (int m = 0; m < 9; ++m) sum[m] = TERM_ZERO;
        }
        vec3 terms[3];
        pixel_terms(px, open_p, terms);
        for (int j = 0; j < 3; ++j) {
            for (int c = 0; c < 3; ++c) {
#ifdef ACCUM_FIXED_POINT
                largest = max(largest, fixed_point_magnitude(terms[j][c]));
                sum[3 * j + c] = fixed_point_add(sum[3 * j + c],
                                                 fixed_point_words(terms[j][c], scale));
#else
                sum[3 * j + c] += terms[j][c];
#endif
            }
        }
    }
    if (open_t >= 0) flush(open_idx, sum);
#ifdef ACCUM_FIXED_POINT
    FIXED_TRACK(grad_pos, group, largest);
#endif
}
#else
void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= n_pixels) return;
    Pixel px;
    uint idx[3];
    vec4 p[3];
    vec3 terms[3];
    bool live = pixel_at(i, pixel_position(first_pixel + i), px);
    if (live) {
        corners(px.t, px.b, idx, p);
        pixel_terms(px, p, terms);
    }
    for (int j = 0; j < 3; ++j) {
#ifdef ACCUM_PER_PIXEL
        contrib[3u * i + uint(j)] = live ? vec4(terms[j].xy, 0.0, terms[j].z) : vec4(0.0);
#else
        if (live) add(idx[j], px.b, terms[j]);
#endif
    }
}
#endif
