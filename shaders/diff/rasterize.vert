#version 450 core
// Vertex pulling for the differentiable rasterize (glraster/diff/rasterize.py).
// glDrawArrays(GL_TRIANGLES, 0, 3 T): vertex k is corner k % 3 of triangle k / 3. The
// fragment shader computes everything from per-triangle records fetched by gl_PrimitiveID,
// so there are no varyings.

layout(std430, binding = 0) readonly buffer Positions { vec4 positions[]; };  // (V, 4) clip space
layout(std430, binding = 1) readonly buffer Indices { int indices[]; };       // (T, 3) flattened

void main() {
    gl_Position = positions[indices[gl_VertexID]];
}
