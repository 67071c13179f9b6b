"""EGL backend: moderngl's standalone EGL context (libEGL, Mesa's EGL driver)."""

from __future__ import annotations

import ctypes.util

from glraster.errors import BackendUnavailable

REQUIRED_GL = 450


class EGLBackend:
    """Headless OpenGL 4.5 core context through EGL.

    moderngl (glcontext) enumerates EGL devices; Mesa's llvmpipe shows up as its software
    device. ``GLCONTEXT_DEVICE_INDEX`` picks another device. glcontext raises bare
    exceptions; they are turned into :class:`BackendUnavailable` here.
    """

    name = "egl"

    def __init__(self):
        self._ctx = None

    def create(self):
        import moderngl

        if ctypes.util.find_library("EGL") is None:
            raise BackendUnavailable("libEGL.so.1 not found (Debian package libegl1)")
        try:
            self._ctx = moderngl.create_context(
                standalone=True, backend="egl", require=REQUIRED_GL
            )
        except Exception as exc:  # glcontext raises bare Exception
            raise BackendUnavailable(f"EGL context creation failed: {exc}") from exc
        return self._ctx

    def release(self):
        self._ctx = None
