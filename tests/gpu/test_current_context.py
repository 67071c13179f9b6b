"""A caller's own GL context keeps working next to glraster's (EGL and OSMesa backends).

Creating a glraster Context and every glraster call leave current whatever context was
current before: a caller's standalone moderngl (EGL) context, or a raw OSMesa context with
its own buffer as pyrender's OSMesa platform makes one. Images are checked exactly.
"""

from __future__ import annotations

import ctypes
import ctypes.util

import moderngl
import numpy as np
import pytest

import glraster as gr
from glraster.gpu.backends import osmesa

SIZE = 8
CLEAR = (10, 20, 30, 255)   # bytes; the GL colors are these / 255
FILL = (51, 102, 204, 255)

_VERT = """
#version 330
in vec2 in_pos;
void main() { gl_Position = vec4(in_pos, 0.0, 1.0); }
"""
_FRAG = """
#version 330
uniform vec4 color;
out vec4 frag;
void main() { frag = color; }
"""
# the left half of the viewport: x_c in [-1, 0], no pixel center on an edge
_LEFT_HALF = np.array([-1, -1, 0, -1, 0, 1, -1, -1, 0, 1, -1, 1], np.float32)


def _egl():
    lib = ctypes.CDLL(ctypes.util.find_library("EGL") or "libEGL.so.1")
    for name in ("eglGetCurrentContext", "eglGetCurrentDisplay"):
        getattr(lib, name).restype = ctypes.c_void_p
    lib.eglGetCurrentSurface.restype = ctypes.c_void_p
    lib.eglGetCurrentSurface.argtypes = [ctypes.c_int]
    lib.eglMakeCurrent.argtypes = [ctypes.c_void_p] * 4
    return lib


def _egl_current(lib):
    return (lib.eglGetCurrentDisplay(), lib.eglGetCurrentSurface(0x3059),
            lib.eglGetCurrentSurface(0x305A), lib.eglGetCurrentContext())


class CallerEGL:
    """A caller's standalone moderngl context that draws a known image on demand."""

    def __init__(self):
        try:
            self.mgl = moderngl.create_context(standalone=True, backend="egl", require=330)
        except Exception as exc:  # glcontext raises bare Exception
            pytest.skip(f"no EGL context for the caller: {exc}")
        mgl = self.mgl
        self.program = mgl.program(vertex_shader=_VERT, fragment_shader=_FRAG)
        self.vbo = mgl.buffer(_LEFT_HALF.tobytes())
        self.vao = mgl.vertex_array(self.program, [(self.vbo, "2f", "in_pos")])
        self.fbo = mgl.simple_framebuffer((SIZE, SIZE))
        self.expected = np.empty((SIZE, SIZE, 4), np.uint8)
        self.expected[:] = CLEAR
        self.expected[:, : SIZE // 2] = FILL

    def draw(self) -> np.ndarray:
        """Clear, draw the left half, read back: (SIZE, SIZE, 4) uint8."""
        self.fbo.use()
        self.fbo.clear(*(c / 255 for c in CLEAR))
        self.program["color"].value = tuple(c / 255 for c in FILL)
        self.vao.render(moderngl.TRIANGLES)
        image = np.zeros((SIZE, SIZE, 4), np.uint8)
        self.fbo.read_into(image, components=4)
        return image

    def check(self, when: str):
        image = self.draw()
        assert self.mgl.error == "GL_NO_ERROR", when
        np.testing.assert_array_equal(image, self.expected, err_msg=when)

    def close(self, lib):
        for obj in (self.fbo, self.vao, self.vbo, self.program):
            obj.release()
        lib.eglMakeCurrent(lib.eglGetCurrentDisplay(), None, None, None)
        self.mgl.release()


@pytest.fixture
def caller_egl():
    lib = _egl()
    caller = CallerEGL()
    yield caller, lib
    caller.close(lib)


def _scene():
    pos = np.array([[-0.9, -0.8, 0.2, 1.0], [2.4, -2.0, 0.9, 4.0], [0.0, 1.6, 0.5, 2.0],
                    [0.5, 0.5, 0.1, 1.0]], np.float32)
    tri = np.array([[0, 1, 2], [0, 3, 2]])
    return pos, tri


def test_callers_egl_context_draws_after_glraster_calls(ctx, caller_egl):
    caller, lib = caller_egl
    caller.check("before glraster")
    current = _egl_current(lib)
    assert current[3], "the caller's context is current"

    own = gr.Context(ctx.backend)
    try:
        assert _egl_current(lib) == current
        assert moderngl.get_context() is caller.mgl  # still moderngl's default context
        caller.check("after creating a glraster Context")
        pos, tri = _scene()
        for context in (own, ctx):
            gr.rasterize(pos, tri, (32, 32), ctx=context)
            caller.check(f"after rasterize on {context.backend}")
            with context:
                pass
            caller.check("after a with block")
            assert context.gl_error() == "GL_NO_ERROR"
            caller.check("after gl_error")
            context.release_targets()
            caller.check("after release_targets")
            assert _egl_current(lib) == current
    finally:
        own.release()
    caller.check("after releasing a glraster Context")
    assert _egl_current(lib) == current


def test_glraster_results_unchanged_next_to_a_callers_context(ctx):
    pos, tri = _scene()
    alone = gr.rasterize(pos, tri, (48, 40), ctx=ctx)
    lib = _egl()
    caller = CallerEGL()
    try:
        caller.check("before")
        beside = gr.rasterize(pos, tri, (48, 40), ctx=ctx)
        caller.check("after")
    finally:
        caller.close(lib)
    assert alone.mask.any()
    for name in ("persp", "screen", "depth", "tri_id", "mask"):
        np.testing.assert_array_equal(getattr(beside, name), getattr(alone, name), err_msg=name)


def test_nothing_current_before_means_nothing_current_after(ctx):
    lib = _egl()
    if lib.eglGetCurrentContext():
        pytest.skip("a context is current on this thread")
    gr.rasterize(*_scene(), (16, 16), ctx=ctx)
    assert not lib.eglGetCurrentContext()
    api = osmesa.OSMesaApi.get()
    if api is not None:
        assert not api.context()


def test_nested_with_blocks_restore_at_the_outermost(ctx, caller_egl):
    caller, lib = caller_egl
    current = _egl_current(lib)
    with ctx:
        with ctx:
            assert ctx.gl_error() == "GL_NO_ERROR"
        # still glraster's context here: its objects work
        ctx.mgl.clear(0.0, 0.0, 0.0, 0.0)
        assert ctx.mgl.error == "GL_NO_ERROR"
    assert _egl_current(lib) == current
    caller.check("after nested blocks")


# -- a raw OSMesa context of the caller's, with its own buffer -------------------------------

OSMESA_RGBA = 0x1908
GL_UNSIGNED_BYTE = 0x1401
GL_COLOR_BUFFER_BIT = 0x4000


class CallerOSMesa:
    """OSMesaCreateContextExt + OSMesaMakeCurrent on a caller's (SIZE, SIZE) RGBA buffer."""

    def __init__(self, depth_bits: int):
        try:
            self.lib = osmesa._load_library()
        except gr.BackendUnavailable as exc:
            pytest.skip(str(exc))
        lib = self.lib
        lib.OSMesaCreateContextExt.restype = ctypes.c_void_p
        lib.OSMesaCreateContextExt.argtypes = [ctypes.c_uint, ctypes.c_int, ctypes.c_int,
                                               ctypes.c_int, ctypes.c_void_p]
        self.handle = lib.OSMesaCreateContextExt(OSMESA_RGBA, depth_bits, 0, 0, None)
        assert self.handle
        self.buffer = np.zeros((SIZE, SIZE, 4), np.uint8)
        assert lib.OSMesaMakeCurrent(self.handle, self.buffer.ctypes.data, GL_UNSIGNED_BYTE,
                                     SIZE, SIZE)

        def gl(name, *argtypes):
            fn = ctypes.CFUNCTYPE(None, *argtypes)(lib.OSMesaGetProcAddress(name.encode()))
            return fn

        f = ctypes.c_float
        self.glClearColor = gl("glClearColor", f, f, f, f)
        self.glClear = gl("glClear", ctypes.c_uint)
        self.glFinish = gl("glFinish")

    def check(self, when: str, color):
        self.buffer[:] = 0
        self.glClearColor(*(c / 255 for c in color))
        self.glClear(GL_COLOR_BUFFER_BIT)
        self.glFinish()
        assert self.lib.OSMesaGetCurrentContext() == self.handle, when
        expected = np.empty_like(self.buffer)
        expected[:] = color
        np.testing.assert_array_equal(self.buffer, expected, err_msg=when)

    def close(self):
        self.lib.OSMesaMakeCurrent(None, None, 0, 0, 0)
        self.lib.OSMesaDestroyContext(self.handle)


@pytest.mark.parametrize("depth_bits", [24, 0])
def test_callers_osmesa_context_draws_after_glraster_calls(ctx, depth_bits):
    # depth 0 is the format of glraster's own OSMesa context, whose buffer Mesa shares
    caller = CallerOSMesa(depth_bits)
    try:
        caller.check("before glraster", CLEAR)
        own = gr.Context(ctx.backend)
        try:
            caller.check("after creating a glraster Context", FILL)
            pos, tri = _scene()
            for context in (own, ctx):
                r = gr.rasterize(pos, tri, (32, 32), ctx=context)
                assert r.mask.any()
                caller.check(f"after rasterize on {context.backend}", CLEAR)
                assert context.gl_error() == "GL_NO_ERROR"
                caller.check("after gl_error", FILL)
        finally:
            own.release()
        caller.check("after releasing a glraster Context", CLEAR)
    finally:
        caller.close()
