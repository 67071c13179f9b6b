"""OSMesa backend: Mesa's off-screen library (libOSMesa) through ctypes.

glcontext has no OSMesa backend, but moderngl accepts any loader object with
``load_opengl_function(name) -> int`` and ``release()``; it also calls the loader's
``__enter__``/``__exit__`` on ``with ctx:``. This module is that loader. OSMesa was removed
from Mesa in 25.1, so it is a fallback where the library still exists, never the only path.
"""

from __future__ import annotations

import ctypes
import ctypes.util
from collections import deque

from glraster.errors import BackendUnavailable

# Attribute names and values from GL/osmesa.h.
OSMESA_FORMAT = 0x22
OSMESA_RGBA = 0x1908
OSMESA_DEPTH_BITS = 0x30
OSMESA_PROFILE = 0x33
OSMESA_CORE_PROFILE = 0x34
OSMESA_CONTEXT_MAJOR_VERSION = 0x36
OSMESA_CONTEXT_MINOR_VERSION = 0x37
GL_UNSIGNED_BYTE = 0x1401

LIBRARY_NAMES = ("libOSMesa.so.8", "libOSMesa.so.6", "libOSMesa.so")


def _load_library():
    names = list(LIBRARY_NAMES)
    found = ctypes.util.find_library("OSMesa")
    if found:
        names.insert(0, found)
    for name in names:
        try:
            lib = ctypes.CDLL(name)
        except OSError:
            continue
        lib.OSMesaCreateContextAttribs.restype = ctypes.c_void_p
        lib.OSMesaCreateContextAttribs.argtypes = [ctypes.POINTER(ctypes.c_int), ctypes.c_void_p]
        lib.OSMesaMakeCurrent.restype = ctypes.c_ubyte
        lib.OSMesaMakeCurrent.argtypes = [
            ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint, ctypes.c_int, ctypes.c_int,
        ]
        lib.OSMesaGetCurrentContext.restype = ctypes.c_void_p
        lib.OSMesaGetProcAddress.restype = ctypes.c_void_p
        lib.OSMesaGetProcAddress.argtypes = [ctypes.c_char_p]
        lib.OSMesaDestroyContext.argtypes = [ctypes.c_void_p]
        return lib
    raise BackendUnavailable("libOSMesa not found (Debian package libosmesa6)")


class _OSMesaLoader:
    """The object moderngl calls to resolve GL functions and to make the context current."""

    # OSMesa needs a color buffer to make a context current; glraster renders into its own
    # framebuffer objects, so a 1x1 RGBA buffer is enough.
    def __init__(self, lib, handle):
        self._lib = lib
        self._handle = handle
        self._buffer = (ctypes.c_ubyte * 4)()
        self._previous = []

    def make_current(self):
        if not self._lib.OSMesaMakeCurrent(self._handle, self._buffer, GL_UNSIGNED_BYTE, 1, 1):
            raise BackendUnavailable("OSMesaMakeCurrent failed")

    def load_opengl_function(self, name: str) -> int:
        return self._lib.OSMesaGetProcAddress(name.encode("ascii")) or 0

    def __enter__(self):
        self._previous.append(self._lib.OSMesaGetCurrentContext())
        self.make_current()

    def __exit__(self, *exc):
        self._previous.pop()

    def release(self):
        if self._handle:
            self._lib.OSMesaDestroyContext(self._handle)
            self._handle = None


class OSMesaBackend:
    """Headless OpenGL 4.5 core context through libOSMesa (Mesa's llvmpipe)."""

    name = "osmesa"

    def __init__(self):
        self._loader = None

    def create(self):
        import moderngl

        lib = _load_library()
        attribs = (ctypes.c_int * 11)(
            OSMESA_FORMAT, OSMESA_RGBA,
            OSMESA_DEPTH_BITS, 0,
            OSMESA_PROFILE, OSMESA_CORE_PROFILE,
            OSMESA_CONTEXT_MAJOR_VERSION, 4,
            OSMESA_CONTEXT_MINOR_VERSION, 5,
            0,
        )
        handle = lib.OSMesaCreateContextAttribs(attribs, None)
        if not handle:
            raise BackendUnavailable("OSMesaCreateContextAttribs failed for OpenGL 4.5 core")
        self._loader = _OSMesaLoader(lib, handle)
        self._loader.make_current()
        try:
            return _wrap_loader(moderngl, self._loader)
        except Exception as exc:  # moderngl raises bare errors on a loader failure
            self._loader.release()
            raise BackendUnavailable(f"moderngl could not use the OSMesa context: {exc}") from exc

    def release(self):
        self._loader = None


def _wrap_loader(moderngl, loader):
    """A moderngl.Context over ``loader``, like ``moderngl.init_context`` but not global."""
    ctx = moderngl.Context.__new__(moderngl.Context)
    ctx.mglo, ctx.version_code = moderngl.mgl.create_context(context=loader)
    ctx._info = None
    ctx._extensions = None
    ctx.extra = None
    ctx._gc_mode = None
    ctx._objects = deque()
    ctx._screen = ctx.detect_framebuffer(0)
    ctx.fbo = ctx.detect_framebuffer()
    ctx.mglo.fbo = ctx.fbo.mglo
    return ctx
