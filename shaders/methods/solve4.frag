#version 450 core
// "solve4": a 4x4 linear system per pixel. The point of the triangle seen at the
// pixel is P = sum_i b_i q_i (q_i the clip-space vertices, b the perspective-correct
// barycentrics); its NDC position is the pixel's (s_x, s_y), so with w = P_w:
//     sum_i b_i q_ix - s_x w = 0
//     sum_i b_i q_iy - s_y w = 0
//     sum_i b_i q_iw -     w = 0
//     sum_i b_i              = 1
// solved for (b_0, b_1, b_2, w) by Gaussian elimination with partial pivoting in float32.
// persp = b; screen_i = b_i w_i / w (window-space weights, GL 4.5 eq. 14.10).
//
// Equilibration: when every w_i > 0 the unknowns are scaled to u_i = b_i w_i (columns
// times 1 / w_i), which are screen_i * w, all of one magnitude, and the last row is scaled
// by min w_i. Then pivoting keeps the three homogeneous rows (NDC x, NDC y, 1) that alone
// fix screen = u / sum(u), and the last row only sets the scale. Unscaled, a vertex ratio
// w_max / w_min = 3e5 cost screen ~10x the driver's error model (catalog scene
// w_extreme_ratios); scaled, every catalog scene stays below 0.16 of it.
//
// Uniform u_ndc_scale = (2 / W, 2 / H): s = gl_FragCoord.xy * u_ndc_scale - 1.
// Host defines: OUT_PERSP, OUT_SCREEN, OUT_TRI_ID, *_LOCATION; REMAP (see divw.frag).

layout(std430, binding = 0) readonly buffer Positions { vec4 positions[]; };
layout(std430, binding = 1) readonly buffer Indices { int indices[]; };
#ifdef REMAP
layout(std430, binding = 3) readonly buffer Ids { int ids[]; };
#endif
uniform vec2 u_ndc_scale;

#ifdef OUT_PERSP
layout(location = PERSP_LOCATION) out vec3 out_persp;
#endif
#ifdef OUT_SCREEN
layout(location = SCREEN_LOCATION) out vec3 out_screen;
#endif
#ifdef OUT_TRI_ID
layout(location = TRI_ID_LOCATION) out int out_tri_id;
uniform int tri_base;  // index of the draw's first triangle (large meshes draw in batches)
#endif

void main() {
#if defined(OUT_PERSP) || defined(OUT_SCREEN)
    int base = 3 * gl_PrimitiveID;
    vec4 q0 = positions[indices[base]];
    vec4 q1 = positions[indices[base + 1]];
    vec4 q2 = positions[indices[base + 2]];
    vec2 s = gl_FragCoord.xy * u_ndc_scale - 1.0;
    vec3 qw = vec3(q0.w, q1.w, q2.w);
    // column scales c_i = 2^-e_i with |w_i| = f 2^e_i (exact: powers of two), b_i = c_i u_i
    ivec3 e;
    frexp(qw, e);
    vec3 c = ldexp(vec3(1.0), -e);
    float r = ldexp(1.0, min(min(e.x, e.y), e.z) - 1);  // last row: entries <= 1/2
    // augmented rows [A | rhs]
    float m[4][5] = float[4][5](
        float[5](q0.x * c.x, q1.x * c.y, q2.x * c.z, -s.x, 0.0),
        float[5](q0.y * c.x, q1.y * c.y, q2.y * c.z, -s.y, 0.0),
        float[5](q0.w * c.x, q1.w * c.y, q2.w * c.z, -1.0, 0.0),
        float[5](r * c.x, r * c.y, r * c.z, 0.0, r));
    for (int c = 0; c < 4; ++c) {
        int pivot = c;
        for (int r = c + 1; r < 4; ++r)
            if (abs(m[r][c]) > abs(m[pivot][c])) pivot = r;
        if (pivot != c) {
            float tmp[5] = m[c];
            m[c] = m[pivot];
            m[pivot] = tmp;
        }
        for (int r = c + 1; r < 4; ++r) {
            float f = m[r][c] / m[c][c];
            for (int k = c; k < 5; ++k) m[r][k] -= f * m[c][k];
        }
    }
    float x[4];
    for (int r = 3; r >= 0; --r) {
        float acc = m[r][4];
        for (int k = r + 1; k < 4; ++k) acc -= m[r][k] * x[k];
        x[r] = acc / m[r][r];
    }
    vec3 b = vec3(x[0], x[1], x[2]) * c;
    b /= b.x + b.y + b.z;
#endif
#ifdef OUT_PERSP
    out_persp = b;
#endif
#ifdef OUT_SCREEN
    out_screen = b * qw / dot(b, qw);
#endif
#ifdef OUT_TRI_ID
#ifdef REMAP
    out_tri_id = ids[gl_PrimitiveID] + 1;
#else
    out_tri_id = tri_base + gl_PrimitiveID + 1;
#endif
#endif
}
