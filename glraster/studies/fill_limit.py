"""The fill limit: a bare moderngl draw writing the same float targets, nothing else.

This is the yardstick for glraster's overhead: the same triangles (de-indexed into one
vertex buffer with a barycentric attribute), the same RGB32F / R32I / DEPTH32F targets, the
same readback, with no validation, no caching logic and no vertex pulling.
"""

from __future__ import annotations

import numpy as np

_VERT = """
#version 450 core
in vec4 in_pos;
in vec3 in_bary;
smooth out vec3 v_persp;
noperspective out vec3 v_screen;
void main() { gl_Position = in_pos; v_persp = in_bary; v_screen = in_bary; }
"""
_FRAG = """
#version 450 core
smooth in vec3 v_persp;
noperspective in vec3 v_screen;
layout(location = 0) out vec3 out_persp;
layout(location = 1) out vec3 out_screen;
layout(location = 2) out int out_tri_id;
void main() { out_persp = v_persp; out_screen = v_screen; out_tri_id = gl_PrimitiveID + 1; }
"""


class FillLimit:
    """A prepared bare draw of (pos, tri) at ``resolution``; call :meth:`run` to time it.

    The vertex buffer is built once outside the timed part, so :meth:`run` measures only
    clear + draw + readback of persp, screen, tri_id and depth.
    """

    def __init__(self, ctx, pos, tri, resolution):
        self.ctx = ctx
        mgl = ctx.mgl
        height, width = resolution
        self.shape = (height, width)
        corners = np.tile(np.eye(3, dtype=np.float32), (len(tri), 1))
        vertices = np.concatenate([np.asarray(pos, np.float32)[np.asarray(tri).ravel()], corners], 1)
        with ctx:
            self.program = mgl.program(vertex_shader=_VERT, fragment_shader=_FRAG)
            self.vbo = mgl.buffer(np.ascontiguousarray(vertices).tobytes())
            self.vao = mgl.vertex_array(self.program, [(self.vbo, "4f 3f", "in_pos", "in_bary")])
            self.textures = [
                mgl.texture((width, height), 3, dtype="f4"),
                mgl.texture((width, height), 3, dtype="f4"),
                mgl.texture((width, height), 1, dtype="i4"),
            ]
            self.depth = mgl.depth_texture((width, height))
            self.fbo = mgl.framebuffer(self.textures, self.depth)

    def run(self):
        """Clear, draw, read back all four targets; returns the arrays."""
        height, width = self.shape
        with self.ctx:
            previous = self.ctx.mgl.fbo
            self.fbo.use()
            self.fbo.clear(0, 0, 0, 0, depth=1.0)
            self.vao.render(self.ctx.mgl.TRIANGLES)
            persp = np.empty((height, width, 3), np.float32)
            screen = np.empty((height, width, 3), np.float32)
            tri_id = np.empty((height, width), np.int32)
            depth = np.empty((height, width), np.float32)
            self.fbo.read_into(persp, components=3, attachment=0, dtype="f4")
            self.fbo.read_into(screen, components=3, attachment=1, dtype="f4")
            self.fbo.read_into(tri_id, components=1, attachment=2, dtype="i4")
            self.fbo.read_into(depth, components=1, attachment=-1, dtype="f4")
            # Leave the previous framebuffer bound: moderngl re-binds "the bound framebuffer"
            # after creating new ones, which fails once this one is released.
            previous.use()
        return persp, screen, tri_id, depth

    def release(self):
        with self.ctx:
            for obj in (self.fbo, self.depth, *self.textures, self.vao, self.vbo, self.program):
                obj.release()
