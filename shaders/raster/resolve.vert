#version 330 core
// Full-screen triangle for the exact readback of multisample targets (resolve.frag):
// glDrawArrays(GL_TRIANGLES, 0, 3) with no vertex attributes covers the viewport.

void main() {
    vec2 corner = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2);  // (0,0) (2,0) (0,2)
    gl_Position = vec4(2.0 * corner - 1.0, 0.0, 1.0);
}
