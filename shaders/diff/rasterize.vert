#version 450 core
// The differentiable rasterize's vertex stage (glraster/diff/rasterize.py): an indexed draw
// (glDrawElements over tri, glraster.gpu.pipeline's Draw.indexed), so the driver's vertex
// cache shades a vertex shared by neighbouring triangles once. The fragment shader computes
// everything from per-triangle records fetched by gl_PrimitiveID: there are no varyings.

layout(location = 0) in vec4 a_position;  // clip space, pos[tri[t, j]]

void main() {
    gl_Position = a_position;
}
