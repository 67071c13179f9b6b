#version 450 core
// Vertex pulling for the computed-barycentric methods (divw, homogeneous, homogeneous64,
// solve4). glDrawArrays(GL_TRIANGLES, 0, 3 T): vertex k is corner k % 3 of triangle k / 3.
// These methods compute barycentrics in the fragment shader from per-triangle data fetched
// by gl_PrimitiveID, so the only varying is divw's noperspective unit vector.
//
// Host defines: VARY_SCREEN (divw: pass the window-space barycentric unit vector).

layout(std430, binding = 0) readonly buffer Positions { vec4 positions[]; };  // (V, 4) clip space
layout(std430, binding = 1) readonly buffer Indices { int indices[]; };       // (T, 3) flattened

// INTERPOLATION (host define, multisampling): "centroid" or "sample", the auxiliary
// qualifier of the barycentric outputs, the same as divw.frag's inputs (GLSL 4.50
// section 4.5); empty: the pixel center.
#ifndef INTERPOLATION
#define INTERPOLATION
#endif

#ifdef VARY_SCREEN
INTERPOLATION noperspective out vec3 v_screen;  // linear in window space: GL 4.5 core eq. 14.10
#endif

void main() {
    gl_Position = positions[indices[gl_VertexID]];
#ifdef VARY_SCREEN
    int corner = gl_VertexID % 3;
    v_screen = vec3(corner == 0, corner == 1, corner == 2);
#endif
}
