#version 450
// Antialias, pass 3: the backward. One invocation per listed pixel P (pixel_list, sorted, as
// pass 2; every other pixel's dL/dc is g), on pass 2's compact outputs of the forward: P's
// four incident records incident[4 li + k] and its scale s = scale_in[li] (a neighbour's
// place in the list found by binary search). With g = dL/d out:
//   dL/dc_P = g_P (1 - s_P sum_k alpha_k) + sum over the pixels N taking colour from P of
//             s_N alpha g_N                                         (deterministic gather)
//   per pair k that P blends: D_k = g_P . (c_k - c_P), dL/dalpha_k = s_P (D_k - [convex and
//             sum alpha > 1] s_P sum_j alpha_j D_j), dL/dtau = -+ dL/dalpha_k (1 at A, 2 at B),
//             times pos_gradient_boost;
//   tau = -r_w / r_d, r = v'_a x v'_b in the frame of the pair's A: dtau/dr = -C / r_d,
//             C = (tau d, 1); G = dL/dr, dL/dv'_a = v'_b x G, dL/dv'_b = G x v'_a; clip:
//             dL/dx = (W/2) G_X, dL/dy = (H/2) G_Y, dL/dw = G_w - n_x dL/dx - n_y dL/dy.
// Colours and dL/d out are those of the listed pixels only, color[li], grad_out[li].
// Defines: CONVEX; ACCUM_ATOMIC_FLOAT | ACCUM_CAS | ACCUM_FIXED_POINT (as
// backward_rasterize.comp); NO_GRAD_POS: the position gradients are not wanted (no atomics).
#ifdef ACCUM_ATOMIC_FLOAT
#extension GL_NV_shader_atomic_float : require
#endif

layout(local_size_x = 64) in;

layout(std430, binding = 0) readonly buffer Color { float color[]; };
layout(std430, binding = 1) readonly buffer Incident { uvec4 incident[]; };
layout(std430, binding = 2) readonly buffer Scale { float scale_in[]; };
layout(std430, binding = 3) readonly buffer GradOut { float grad_out[]; };
layout(std430, binding = 4) writeonly buffer GradColor { float grad_color[]; };
layout(std430, binding = 5) readonly buffer Pos { vec4 pos[]; };
#if defined(ACCUM_ATOMIC_FLOAT)
layout(std430, binding = 6) buffer GradPos { float grad_pos[]; };
#elif defined(ACCUM_CAS) || defined(ACCUM_FIXED_POINT)
layout(std430, binding = 6) buffer GradPos { uint grad_pos[]; };
#endif
layout(std430, binding = 7) readonly buffer PixelList { uint pixel_list[]; };

uniform uint n_list;
uniform ivec2 size;          // (W, H)
uniform int n_channels;
uniform float boost;         // pos_gradient_boost
uniform uint vertex_stride;  // V when pos is batched, else 0
uniform uint fixed_groups;   // ACCUM_FIXED_POINT: B with batched pos (one scale per image), else 1

#include "include/atomic_add_float.glsl"
#include "include/fixed_point.glsl"

void add(uint row, vec3 g) {
#if defined(ACCUM_FIXED_POINT)
    uint group = vertex_stride == 0u ? 0u : row / vertex_stride;
    FIXED_ADD(grad_pos, fixed_groups, group, 4u * row + 0u, g.x);
    FIXED_ADD(grad_pos, fixed_groups, group, 4u * row + 1u, g.y);
    FIXED_ADD(grad_pos, fixed_groups, group, 4u * row + 3u, g.z);
#else
    ATOMIC_ADD_FLOAT(grad_pos[4u * row + 0u], g.x);
    ATOMIC_ADD_FLOAT(grad_pos[4u * row + 1u], g.y);
    ATOMIC_ADD_FLOAT(grad_pos[4u * row + 3u], g.z);
#endif
}

#include "include/frame.glsl"

// dL/dtau of the pair (owner, axis) whose record is rec (owner: its pixel A), to
// the edge's two vertices.
void edge_gradient(uint owner, int axis, uvec4 rec, float dl_dtau) {
    uint W = uint(size.x), hw = W * uint(size.y);
    uint pix = owner % hw, y = pix / W, x = pix % W;
    vec2 n = vec2(float(2u * x + 1u) / float(size.x) - 1.0,
                  float(2u * y + 1u) / float(size.y) - 1.0);
    vec3 va = frame_vertex(pos[rec.y], n, size), vb = frame_vertex(pos[rec.z], n, size);
    vec3 r = cross(va, vb);
    float tau = uintBitsToFloat(rec.w);
    vec3 c = vec3(0.0, 0.0, 1.0);
    c[axis] = tau;
    vec3 G = (-dl_dtau / r[axis]) * c;
    vec3 g[2] = vec3[2](cross(vb, G), cross(G, va));
    uint rows[2] = uint[2](rec.y, rec.z);
    for (int j = 0; j < 2; ++j) {
        float gx = 0.5 * float(size.x) * g[j].x;
        float gy = 0.5 * float(size.y) * g[j].y;
        vec3 clip = vec3(gx, gy, g[j].z - n.x * gx - n.y * gy);
        add(rows[j], clip);
    }
}

// The place of pixel i in the sorted pixel_list (i is listed).
uint place(uint i) {
    uint lo = 0u, hi = n_list - 1u;
    while (lo < hi) {
        uint mid = (lo + hi) / 2u;
        if (pixel_list[mid] < i) lo = mid + 1u; else hi = mid;
    }
    return lo;
}

void main() {
    uint li = gl_GlobalInvocationID.x;
    if (li >= n_list) return;
    uint i = pixel_list[li];
    uint W = uint(size.x);
    uint C = uint(n_channels);
    // the four incident records (zero where the neighbour is outside the image): (owner pixel A, axis, the pixel on P's other side)
    uint owner[4] = uint[4](i, i - 1u, i, i - W);
    int axes[4] = int[4](0, 0, 1, 1);
    uint other[4] = uint[4](i + 1u, i - 1u, i + W, i - W);
    uint own_code[4] = uint[4](1u, 2u, 1u, 2u);   // code with which P itself blends
    uvec4 rec[4];
    float alpha[4];      // P's own weights (P blends)
    float alpha_in[4];   // weights of the neighbour taking P's colour
    bool mine[4];        // P blends with pair k (alpha may be 0: tau = 1/2)
    bool theirs[4];      // the neighbour of pair k blends with P's colour
    for (int k = 0; k < 4; ++k) {
        rec[k] = uvec4(0u);
        alpha[k] = 0.0;
        alpha_in[k] = 0.0;
        mine[k] = false;
        theirs[k] = false;
        rec[k] = incident[4u * li + uint(k)];
        uint code = rec[k].x & 3u;
        if (code == 0u) continue;
        float tau = uintBitsToFloat(rec[k].w);
        float a = code == 1u ? 0.5 - tau : tau - 0.5;
        mine[k] = code == own_code[k];
        theirs[k] = !mine[k];
        if (mine[k]) alpha[k] = a; else alpha_in[k] = a;
    }
    float total = (alpha[0] + alpha[1]) + (alpha[2] + alpha[3]);
    float s = scale_in[li];
    float s_in[4];       // the scale of the neighbour taking P's colour
    uint other_li[4];    // the neighbours' places in the list (listed: pair k blends)
    for (int k = 0; k < 4; ++k) other_li[k] = theirs[k] || mine[k] ? place(other[k]) : li;
    for (int k = 0; k < 4; ++k) s_in[k] = theirs[k] ? scale_in[other_li[k]] : 0.0;
    float sum_w = s * total;
    float D[4] = float[4](0.0, 0.0, 0.0, 0.0);
    for (uint c = 0u; c < C; ++c) {
        float g = grad_out[li * C + c];
        float own = color[li * C + c];
        float gc = g * (1.0 - sum_w);
        for (int k = 0; k < 4; ++k) {
            if (theirs[k])
                gc += s_in[k] * alpha_in[k] * grad_out[other_li[k] * C + c];
            if (mine[k]) D[k] += g * (color[other_li[k] * C + c] - own);
        }
        grad_color[li * C + c] = gc;
    }
#ifndef NO_GRAD_POS
    float weighted = 0.0;
    for (int k = 0; k < 4; ++k) weighted += alpha[k] * D[k];
    for (int k = 0; k < 4; ++k) {
        if (!mine[k]) continue;
        float dl_dalpha = s * D[k];
#ifdef CONVEX
        if (total > 1.0) dl_dalpha = s * (D[k] - s * weighted);
#endif
        float dl_dtau = boost * ((rec[k].x & 3u) == 1u ? -dl_dalpha : dl_dalpha);
        edge_gradient(owner[k], axes[k], rec[k], dl_dtau);
    }
#endif
}
