#version 330 core
// GL 3.3 core variant of raster/raster.vert, for method "hw" on drivers without shader
// storage buffers (Mesa's softpipe). The host de-indexes the triangles into one vertex
// buffer, vertex k = corner k % 3 of triangle k / 3, drawn with glDrawArrays(GL_TRIANGLES,
// 0, 3 T): every corner still gets its own barycentric unit vector, and the clip position
// is a plain vertex attribute. k itself is an integer attribute too, not gl_VertexID:
// softpipe's gl_VertexID restarts where its draw module splits a long draw (measured: ids
// off by multiples of 1365 and 341 triangles). The triangle index k / 3 goes to the
// fragment shader as an exact flat integer (GL 3.3 defines gl_PrimitiveID only with a
// geometry shader).
//
// From "#ifdef OUT_PERSP" on, the text is that of raster/raster.vert (plus the id line at
// the end of main), so the fault-injection mutants' patches apply to both files.
//
// Host defines (one line each, inserted after #version): OUT_PERSP, OUT_SCREEN, OUT_TRI_ID;
// AUX_QUALIFIERS (multisampling: see raster33/raster.frag).
#ifdef AUX_QUALIFIERS
#extension GL_ARB_shading_language_420pack : require
#extension GL_ARB_gpu_shader5 : require
#endif

layout(location = 0) in vec4 a_position;  // (3 T, 4) clip space, one vertex per corner
layout(location = 1) in int a_vertex;     // k = 3 * (triangle in this draw) + corner
#define VERTEX_ID a_vertex
#define CORNER_POSITION a_position
#ifdef OUT_TRI_ID
flat out int v_primitive;  // triangle index in this draw
#endif

// INTERPOLATION (host define, multisampling): "centroid" or "sample", the auxiliary
// qualifier of the barycentric outputs, the same as raster.frag's inputs (GLSL 3.30
// section 4.5); empty: the pixel center.
#ifndef INTERPOLATION
#define INTERPOLATION
#endif

#ifdef OUT_PERSP
INTERPOLATION smooth out vec3 v_persp;          // perspective-correct: GL 4.5 core eq. 14.9
#endif
#ifdef OUT_SCREEN
INTERPOLATION noperspective out vec3 v_screen;  // linear in window space: GL 4.5 core eq. 14.10
#endif

void main() {
    int corner = VERTEX_ID % 3;
    vec3 unit = vec3(corner == 0, corner == 1, corner == 2);
    gl_Position = CORNER_POSITION;
#ifdef OUT_PERSP
    v_persp = unit;
#endif
#ifdef OUT_SCREEN
    v_screen = unit;
#endif
#ifdef OUT_TRI_ID
    v_primitive = VERTEX_ID / 3;
#endif
}
