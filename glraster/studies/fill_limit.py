"""Yardsticks for glraster's overhead: bare moderngl draws writing the same float targets.

Both draw the same triangles, de-indexed into one vertex buffer (3 vertices per triangle,
each corner carrying its unit barycentric vector), into the same RGB32F (persp, screen),
R32I (tri_id) and DEPTH32F targets with the same LESS depth test, and read all four back,
with no validation, no caching logic and no vertex pulling:

- :class:`FillLimit`: triangle ids from ``gl_PrimitiveID``, fresh output arrays per run;
- :class:`LeanDraw`: leaner still, triangle ids from a ``flat`` integer vertex attribute,
  read into output arrays allocated once and reused by every run.

The vertex buffer and targets are made in the constructor, outside the timed part, so
``run()`` measures only clear + draw + readback.
"""

from __future__ import annotations

import numpy as np

from glraster import validate
from glraster.errors import ArgumentError

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

_LEAN_VERT = """
#version 450 core
in vec4 in_pos;
in vec3 in_bary;
in int in_id;
smooth out vec3 v_persp;
noperspective out vec3 v_screen;
flat out int v_id;
void main() { gl_Position = in_pos; v_persp = in_bary; v_screen = in_bary; v_id = in_id; }
"""
_LEAN_FRAG = """
#version 450 core
smooth in vec3 v_persp;
noperspective in vec3 v_screen;
flat in int v_id;
layout(location = 0) out vec3 out_persp;
layout(location = 1) out vec3 out_screen;
layout(location = 2) out int out_tri_id;
void main() { out_persp = v_persp; out_screen = v_screen; out_tri_id = v_id; }
"""


class _BareDraw:
    """Shared setup: checked input, de-indexed corners, targets, framebuffer.

    Parameters
    ----------
    ctx : glraster.Context
    pos : (V, 4) array_like of float     clip-space positions
    tri : (T, 3) array_like of int       vertex indices (at least one triangle)
    resolution : (height, width)

    Bad input is an ArgumentError naming the argument.
    """

    vertex_shader = _VERT
    fragment_shader = _FRAG

    def __init__(self, ctx, pos, tri, resolution):
        pos = validate.positions(pos)
        tri = validate.triangles(tri, len(pos))
        if len(tri) == 0:
            raise ArgumentError("tri", "tri must hold at least one triangle, got shape (0, 3)")
        height, width = validate.resolution(resolution, ctx.max_texture_size)
        self.ctx = ctx
        self.shape = (height, width)
        mgl = ctx.mgl
        with ctx:
            self.program = mgl.program(vertex_shader=self.vertex_shader,
                                       fragment_shader=self.fragment_shader)
            self.vbo = mgl.buffer(self._vertices(pos, tri).tobytes())
            self.vao = mgl.vertex_array(self.program, [(self.vbo, *self._layout)])
            self.textures = [
                mgl.texture((width, height), 3, dtype="f4"),
                mgl.texture((width, height), 3, dtype="f4"),
                mgl.texture((width, height), 1, dtype="i4"),
            ]
            self.depth = mgl.depth_texture((width, height))
            self.fbo = mgl.framebuffer(self.textures, self.depth)

    _layout = ("4f 3f", "in_pos", "in_bary")

    @staticmethod
    def _vertices(pos: np.ndarray, tri: np.ndarray) -> np.ndarray:
        """(3T, 7) float32: each corner's clip position and unit barycentric vector."""
        corners = np.tile(np.eye(3, dtype=np.float32), (len(tri), 1))
        return np.ascontiguousarray(np.concatenate([pos[tri.ravel()], corners], 1))

    def _outputs(self):
        height, width = self.shape
        return (np.empty((height, width, 3), np.float32), np.empty((height, width, 3), np.float32),
                np.empty((height, width), np.int32), np.empty((height, width), np.float32))

    def _draw_into(self, persp, screen, tri_id, depth):
        mgl = self.ctx.mgl
        with self.ctx:
            previous = mgl.fbo
            self.fbo.use()
            self.fbo.clear(0, 0, 0, 0, depth=1.0)
            self.vao.render(mgl.TRIANGLES)
            self.fbo.read_into(persp, components=3, attachment=0, dtype="f4")
            self.fbo.read_into(screen, components=3, attachment=1, dtype="f4")
            self.fbo.read_into(tri_id, components=1, attachment=2, dtype="i4")
            self.fbo.read_into(depth, components=1, attachment=-1, dtype="f4")
            # Leave the previous framebuffer bound (the default one when none was): moderngl
            # re-binds "the bound framebuffer" after creating new ones, which fails once
            # this one is released.
            (previous if previous is not None else mgl.detect_framebuffer(0)).use()

    def release(self):
        """Free the GL objects (binding the default framebuffer first if this one is bound)."""
        with self.ctx:
            if self.ctx.mgl.fbo is self.fbo:
                self.ctx.mgl.detect_framebuffer(0).use()
            for obj in (self.fbo, self.depth, *self.textures, self.vao, self.vbo, self.program):
                obj.release()


class FillLimit(_BareDraw):
    """A prepared bare draw of (pos, tri) at ``resolution`` (the arguments of
    :class:`_BareDraw`); call :meth:`run` to time it."""

    def run(self):
        """Clear, draw, read back all four targets into new arrays:
        ``(persp (H, W, 3) float32, screen (H, W, 3) float32, tri_id (H, W) int32 holding
        the triangle index + 1 (0 = empty), depth (H, W) float32)``."""
        out = self._outputs()
        self._draw_into(*out)
        return out


class LeanDraw(_BareDraw):
    """The leanest draw of the same targets: plain vertex attributes (non-indexed, 3
    vertices per triangle, each corner with its unit barycentric vector and its triangle's
    id as a ``flat`` integer) read into output arrays allocated once and reused; the
    arguments of :class:`_BareDraw`. The outputs follow
    :func:`glraster.rasterize` (tri_id -1 where empty), so they equal its ``hw`` results.
    """

    vertex_shader = _LEAN_VERT
    fragment_shader = _LEAN_FRAG
    _layout = ("4f 3f 1i", "in_pos", "in_bary", "in_id")

    def __init__(self, ctx, pos, tri, resolution):
        super().__init__(ctx, pos, tri, resolution)
        self.outputs = self._outputs()

    @staticmethod
    def _vertices(pos: np.ndarray, tri: np.ndarray) -> np.ndarray:
        """(3T,) records of 32 bytes: position (4 float32), barycentric unit vector
        (3 float32), triangle index + 1 (int32; the cleared 0 means empty)."""
        record = np.dtype([("pos", np.float32, 4), ("bary", np.float32, 3), ("id", np.int32)])
        vertices = np.empty(3 * len(tri), record)
        vertices["pos"] = pos[tri.ravel()]
        vertices["bary"] = np.tile(np.eye(3, dtype=np.float32), (len(tri), 1))
        vertices["id"] = np.repeat(np.arange(1, len(tri) + 1, dtype=np.int32), 3)
        return vertices

    def run(self):
        """Clear, draw, read back all four targets into the preallocated arrays (the same
        ones every run, overwritten by the next): ``(persp (H, W, 3) float32, screen
        (H, W, 3) float32, tri_id (H, W) int32 (-1 = empty), depth (H, W) float32)``."""
        persp, screen, tri_id, depth = self.outputs
        self._draw_into(persp, screen, tri_id, depth)
        tri_id -= 1
        return self.outputs
