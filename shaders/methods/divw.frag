#version 450 core
// "divw": window-space barycentrics b_i from the driver's noperspective interpolation,
// corrected by the per-vertex 1/w in this shader (GL 4.5 eq. 14.9; Heckbert &
// Moreton 1991: b'_i = (b_i / w_i) / sum_j (b_j / w_j)). The w_i are fetched by gl_PrimitiveID.
//
// Host defines: OUT_PERSP, OUT_SCREEN, OUT_TRI_ID, *_LOCATION (as in raster.frag);
// AFFINE (every w equal: persp = screen, no division); REMAP (triangles were culled before
// upload: ids[gl_PrimitiveID] is the caller's triangle index).

layout(std430, binding = 0) readonly buffer Positions { vec4 positions[]; };
layout(std430, binding = 1) readonly buffer Indices { int indices[]; };
#ifdef REMAP
layout(std430, binding = 3) readonly buffer Ids { int ids[]; };
#endif

// INTERPOLATION (host define, multisampling): "centroid" or "sample", the auxiliary
// qualifier of the barycentric inputs (GLSL 4.50 section 4.5); empty: the pixel center.
#ifndef INTERPOLATION
#define INTERPOLATION
#endif
INTERPOLATION noperspective in vec3 v_screen;
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
#ifdef OUT_SCREEN
    out_screen = v_screen;
#endif
#ifdef OUT_PERSP
#ifdef AFFINE
    out_persp = v_screen;
#else
    int base = 3 * gl_PrimitiveID;
    vec3 w = vec3(positions[indices[base]].w, positions[indices[base + 1]].w,
                  positions[indices[base + 2]].w);
    vec3 q = v_screen / w;                 // b_i / w_i, linear in window space
    out_persp = q / (q.x + q.y + q.z);     // eq. 2.4.9: normalize by 1 / w_p
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
