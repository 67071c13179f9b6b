#version 330 core
// GL 3.3 core variant of raster/raster.frag (see raster33/raster.vert). The triangle index
// comes from the flat varying v_primitive instead of gl_PrimitiveID; from "#ifdef
// OUT_PERSP" on, the text is that of raster/raster.frag, so the mutants' patches apply.
// GL_ARB_gpu_shader5 is enabled where the driver has it (softpipe does) for
// interpolateAtOffset, which only the pixel_corner_sampling mutant uses.
#extension GL_ARB_gpu_shader5 : enable
// GL_ARB_shading_language_420pack lets the auxiliary qualifier of INTERPOLATION come
// before smooth / noperspective as in raster/ (GLSL 3.30 wants it after them); the host
// asks for it, and GL_ARB_gpu_shader5's "sample" qualifier, only when multisampling.
#ifdef AUX_QUALIFIERS
#extension GL_ARB_shading_language_420pack : require
#extension GL_ARB_gpu_shader5 : require
#endif
//
// Host defines: OUT_PERSP, OUT_SCREEN, OUT_TRI_ID and PERSP_LOCATION, SCREEN_LOCATION,
// TRI_ID_LOCATION (the color attachment of each).

#ifdef OUT_TRI_ID
flat in int v_primitive;  // the triangle's index in this draw (a_vertex / 3)
#endif

// INTERPOLATION (host define, multisampling): "centroid" or "sample", the auxiliary
// qualifier of the barycentric inputs (GLSL 3.30 section 4.5); empty: the pixel center.
#ifndef INTERPOLATION
#define INTERPOLATION
#endif

#ifdef OUT_PERSP
INTERPOLATION smooth in vec3 v_persp;
layout(location = PERSP_LOCATION) out vec3 out_persp;
#endif
#ifdef OUT_SCREEN
INTERPOLATION noperspective in vec3 v_screen;
layout(location = SCREEN_LOCATION) out vec3 out_screen;
#endif
#ifdef OUT_TRI_ID
// Triangle index + 1, so that the cleared value 0 means "empty"; exact for any count
// below 2^31 because the target is a 32-bit integer texture.
layout(location = TRI_ID_LOCATION) out int out_tri_id;
uniform int tri_base;  // index of the draw's first triangle (large meshes draw in batches)
#define PRIMITIVE_ID v_primitive  // the triangle's index in this draw
#endif

void main() {
#ifdef OUT_PERSP
    out_persp = v_persp;
#endif
#ifdef OUT_SCREEN
    out_screen = v_screen;
#endif
#ifdef OUT_TRI_ID
    out_tri_id = tri_base + PRIMITIVE_ID + 1;
#endif
}
