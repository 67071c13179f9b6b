#version 450
// Forward of attribute interpolation, RUN (default 1) consecutive pixels per invocation:
//   out = u a[t0] + v a[t1] + (1 - u - v) a[t2]
// and, with N_DIFF > 0, the screen derivatives of the chosen attributes through rast_db:
//   dA/dx = (a0 - a2) du/dx + (a1 - a2) dv/dx,  dA/dy = (a0 - a2) du/dy + (a1 - a2) dv/dy
// stored (dA_k/dx, dA_k/dy) per chosen attribute k. Empty pixels get zeros. N_ATTR: the
// attribute count (compile time, so the loops over attributes unroll); the corner
// attributes of a triangle are loaded once per stretch of its pixels in the run.
// The gathered inputs (attributes, triangles, rast, rast_db) are read through buffer
// textures over their buffers (GL 4.6 section 8.9, texelFetch; units TEXEL_UNIT on, see
// include/interpolate_views.glsl), ATTR_VEC attributes a fetch.

layout(local_size_x = 64) in;

#include "include/interpolate_views.glsl"
layout(std430, binding = 3) writeonly buffer Out { float out_attr[]; };
#if N_DIFF > 0
layout(std430, binding = 5) readonly buffer DiffIndex { int diff_index[]; };
layout(std430, binding = 6) writeonly buffer OutDa { float out_da[]; };
#endif

uniform uint n_pixels;       // pixels in this dispatch
uniform uint first_pixel;    // flat index (b, y, x) of the first one
uniform uint pixels_per_image;
uniform uint vertex_stride;  // V when attr is batched, else 0
uniform int n_tri;

#include "include/triangle_id.glsl"

#ifndef RUN
#define RUN 1
#endif

void main() {
    uint start = gl_GlobalInvocationID.x * uint(RUN);
    const uint A = uint(N_ATTR);
    int open_t = -1;
    uint open_image = 0u;
    float a0[ROW], a1[ROW], a2[ROW];   // the open triangle's corner attributes
    for (uint r = 0u; r < uint(RUN); ++r) {
        uint i = start + r;
        if (i >= n_pixels) break;
        vec4 rs = texelFetch(rast, int(i));
        int t = decode_id(rs.w) - 1;
        if (t < 0 || t >= n_tri) {
            for (uint k = 0u; k < A; ++k) out_attr[i * A + k] = 0.0;
#if N_DIFF > 0
            for (uint k = 0u; k < 2u * uint(N_DIFF); ++k)
                out_da[i * 2u * uint(N_DIFF) + k] = 0.0;
#endif
            continue;
        }
        uint image = (first_pixel + i) / pixels_per_image;
        if (t != open_t || image != open_image) {
            open_t = t;
            open_image = image;
            uint base = image * vertex_stride;
            ivec3 c = texelFetch(tri, t).xyz;
            load_row(attr, uint(c.x) + base, a0);
            load_row(attr, uint(c.y) + base, a1);
            load_row(attr, uint(c.z) + base, a2);
        }
        float u = rs.x, v = rs.y, w = 1.0 - rs.x - rs.y;
        for (uint k = 0u; k < A; ++k)
            out_attr[i * A + k] = u * a0[k] + v * a1[k] + w * a2[k];
#if N_DIFF > 0
        vec4 db = texelFetch(rast_db, int(i));
        for (uint j = 0u; j < uint(N_DIFF); ++j) {
            uint k = uint(diff_index[j]);
            float d0 = a0[k] - a2[k], d1 = a1[k] - a2[k];
            out_da[(i * uint(N_DIFF) + j) * 2u] = d0 * db.x + d1 * db.z;
            out_da[(i * uint(N_DIFF) + j) * 2u + 1u] = d0 * db.y + d1 * db.w;
        }
#endif
    }
}
