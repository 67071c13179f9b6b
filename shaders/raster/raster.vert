#version 450 core
// Vertex pulling of indexed triangles. The draw is glDrawArrays(GL_TRIANGLES, 0, 3 T):
// vertex k is corner k % 3 of triangle k / 3, so every corner gets its own barycentric
// unit vector even where triangles share a vertex.
//
// Host defines (one line each, inserted after #version): OUT_PERSP, OUT_SCREEN.

layout(std430, binding = 0) readonly buffer Positions { vec4 positions[]; };  // (V, 4) clip space
layout(std430, binding = 1) readonly buffer Indices { int indices[]; };       // (T, 3) flattened
#define VERTEX_ID gl_VertexID  // 3 * triangle + corner (raster33/: a vertex attribute)
#define CORNER_POSITION positions[indices[VERTEX_ID]]

// INTERPOLATION (host define, multisampling): "centroid" or "sample", the auxiliary
// qualifier of the barycentric outputs, the same as raster.frag's inputs (GLSL 4.50
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
}
