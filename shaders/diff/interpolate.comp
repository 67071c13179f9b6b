#version 450
// Forward of attribute interpolation, one invocation per pixel:
//   out = u a[t0] + v a[t1] + (1 - u - v) a[t2]
// and, with N_DIFF > 0, the screen derivatives of the chosen attributes through rast_db:
//   dA/dx = (a0 - a2) du/dx + (a1 - a2) dv/dx,  dA/dy = (a0 - a2) du/dy + (a1 - a2) dv/dy
// stored (dA_k/dx, dA_k/dy) per chosen attribute k. Empty pixels get zeros.

layout(local_size_x = 64) in;

layout(std430, binding = 0) readonly buffer Attr { float attr[]; };
layout(std430, binding = 1) readonly buffer Tri { int tri[]; };
layout(std430, binding = 2) readonly buffer Rast { vec4 rast[]; };
layout(std430, binding = 3) writeonly buffer Out { float out_attr[]; };
#if N_DIFF > 0
layout(std430, binding = 4) readonly buffer RastDb { vec4 rast_db[]; };
layout(std430, binding = 5) readonly buffer DiffIndex { int diff_index[]; };
layout(std430, binding = 6) writeonly buffer OutDa { float out_da[]; };
#endif

uniform uint n_pixels;       // pixels in this dispatch
uniform uint first_pixel;    // flat index (b, y, x) of the first one
uniform uint pixels_per_image;
uniform uint vertex_stride;  // V when attr is batched, else 0
uniform int n_tri;
uniform int n_attr;

#include "include/triangle_id.glsl"

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= n_pixels) return;
    uint A = uint(n_attr);
    vec4 r = rast[i];
    int t = decode_id(r.w) - 1;
    if (t < 0 || t >= n_tri) {
        for (uint k = 0u; k < A; ++k) out_attr[i * A + k] = 0.0;
#if N_DIFF > 0
        for (uint k = 0u; k < 2u * uint(N_DIFF); ++k) out_da[i * 2u * uint(N_DIFF) + k] = 0.0;
#endif
        return;
    }
    uint base = ((first_pixel + i) / pixels_per_image) * vertex_stride;
    uint o0 = (uint(tri[3 * t]) + base) * A;
    uint o1 = (uint(tri[3 * t + 1]) + base) * A;
    uint o2 = (uint(tri[3 * t + 2]) + base) * A;
    float u = r.x, v = r.y, w = 1.0 - r.x - r.y;
    for (uint k = 0u; k < A; ++k)
        out_attr[i * A + k] = u * attr[o0 + k] + v * attr[o1 + k] + w * attr[o2 + k];
#if N_DIFF > 0
    vec4 db = rast_db[i];
    for (uint j = 0u; j < uint(N_DIFF); ++j) {
        uint k = uint(diff_index[j]);
        float a2 = attr[o2 + k];
        float d0 = attr[o0 + k] - a2, d1 = attr[o1 + k] - a2;
        out_da[(i * uint(N_DIFF) + j) * 2u] = d0 * db.x + d1 * db.z;
        out_da[(i * uint(N_DIFF) + j) * 2u + 1u] = d0 * db.y + d1 * db.w;
    }
#endif
}
