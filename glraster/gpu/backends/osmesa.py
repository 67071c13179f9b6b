"""OSMesa backend: Mesa's off-screen library (libOSMesa) through ctypes.

glcontext has no OSMesa backend, but moderngl accepts any loader object with
``load_opengl_function(name) -> int`` and ``release()``; it also calls the loader's
``__enter__``/``__exit__`` on ``with ctx:``. This module is that loader; like every
glraster loader it makes the previous current context current again on exit (see
``current``). OSMesa was removed from Mesa in 25.1, so it is a fallback where the library
still exists, never the only path.
"""

from __future__ import annotations

import ctypes
import ctypes.util
from typing import NamedTuple

from glraster.errors import BackendUnavailable, LibraryMissing
from glraster.gpu.backends.current import GL_VERSIONS, MIN_GL, CurrentContextLoader
from glraster.gpu.backends.current import driver_too_old, gl_strings, loaded_library
from glraster.gpu.backends.current import glx_has_current_context, wrap_loader

# Attribute names and values from GL/osmesa.h.
OSMESA_FORMAT = 0x22
OSMESA_TYPE = 0x23
OSMESA_RGBA = 0x1908
OSMESA_DEPTH_BITS = 0x30
OSMESA_PROFILE = 0x33
OSMESA_CORE_PROFILE = 0x34
OSMESA_CONTEXT_MAJOR_VERSION = 0x36
OSMESA_CONTEXT_MINOR_VERSION = 0x37
OSMESA_COMPAT_PROFILE = 0x35
GL_UNSIGNED_BYTE = 0x1401

LIBRARY_NAMES = ("libOSMesa.so.8", "libOSMesa.so.6", "libOSMesa.so")


def _load_library():
    """libOSMesa with the prototypes glraster uses."""
    names = list(LIBRARY_NAMES)
    found = ctypes.util.find_library("OSMesa")
    if found:
        names.insert(0, found)
    broken = []
    for name in names:
        try:
            lib = ctypes.CDLL(name)
        except OSError as exc:
            if "No such file" not in str(exc) and "cannot open shared object" not in str(exc):
                broken.append(f"{name}: {exc}")
            continue
        try:
            return _declare(lib)
        except AttributeError as exc:  # a library of that name without OSMesa's calls
            broken.append(f"{name} is not a usable libOSMesa: {exc}")
    if broken:
        raise BackendUnavailable("libOSMesa does not load (" + "; ".join(broken) + ")")
    raise LibraryMissing("libOSMesa not found (Debian package libosmesa6)")


def _declare(lib):
    vp, i = ctypes.c_void_p, ctypes.c_int
    lib.OSMesaCreateContextAttribs.restype = vp
    lib.OSMesaCreateContextAttribs.argtypes = [ctypes.POINTER(i), vp]
    lib.OSMesaMakeCurrent.restype = ctypes.c_ubyte
    lib.OSMesaMakeCurrent.argtypes = [vp, vp, ctypes.c_uint, i, i]
    lib.OSMesaGetCurrentContext.restype = vp
    lib.OSMesaGetCurrentContext.argtypes = []
    lib.OSMesaGetColorBuffer.restype = ctypes.c_ubyte
    lib.OSMesaGetColorBuffer.argtypes = [vp, ctypes.POINTER(i), ctypes.POINTER(i),
                                         ctypes.POINTER(i), ctypes.POINTER(vp)]
    lib.OSMesaGetIntegerv.restype = None
    lib.OSMesaGetIntegerv.argtypes = [i, ctypes.POINTER(i)]
    lib.OSMesaGetProcAddress.restype = vp
    lib.OSMesaGetProcAddress.argtypes = [ctypes.c_char_p]
    lib.OSMesaDestroyContext.argtypes = [vp]
    return lib


class OSMesaCurrent(NamedTuple):
    """An OSMesa context with the color buffer it was made current with: the arguments of
    ``OSMesaMakeCurrent(context, buffer, type, width, height)``."""

    context: int
    buffer: int | None
    type: int
    width: int
    height: int


class OSMesaApi:
    """ctypes access to libOSMesa's current context (one instance per process)."""

    _instance = None

    def __init__(self, lib):
        self.lib = lib

    @classmethod
    def get(cls, load: bool = False) -> "OSMesaApi | None":
        """The process's OSMesa access; None when libOSMesa is not loaded (and ``load``
        is False: then no OSMesa context can be current)."""
        if load:
            lib = _load_library()  # raises BackendUnavailable when it is missing
            if cls._instance is None:
                cls._instance = cls(lib)
        elif cls._instance is None:
            lib = loaded_library(LIBRARY_NAMES)
            if lib is None:
                return None
            cls._instance = cls(_declare(lib))
        return cls._instance

    def context(self) -> int | None:
        """OSMesaGetCurrentContext: derived from Mesa's effective context, so it is
        meaningful only when that context is an OSMesa one."""
        return self.lib.OSMesaGetCurrentContext()

    def snapshot(self) -> OSMesaCurrent | None:
        """The current OSMesa context and its buffer (None when none is current). Call
        only when no EGL / GLX context is the effective one."""
        context = self.lib.OSMesaGetCurrentContext()
        if not context:
            return None
        width, height, fmt = ctypes.c_int(), ctypes.c_int(), ctypes.c_int()
        buffer = ctypes.c_void_p()
        self.lib.OSMesaGetColorBuffer(context, ctypes.byref(width), ctypes.byref(height),
                                      ctypes.byref(fmt), ctypes.byref(buffer))
        kind = ctypes.c_int(GL_UNSIGNED_BYTE)
        self.lib.OSMesaGetIntegerv(OSMESA_TYPE, ctypes.byref(kind))
        return OSMesaCurrent(context, buffer.value, kind.value, width.value, height.value)

    def make_current(self, state: OSMesaCurrent) -> bool:
        return bool(self.lib.OSMesaMakeCurrent(state.context, state.buffer, state.type,
                                               state.width, state.height))

    def unbind(self) -> None:
        self.lib.OSMesaMakeCurrent(None, None, 0, 0, 0)

    def force(self, state: OSMesaCurrent) -> None:
        """OSMesaMakeCurrent rebinds Mesa's dispatch even for the current context."""
        self.make_current(state)


class OSMesaLoader(CurrentContextLoader):
    """The object moderngl calls to resolve GL functions and to make the context current.

    ``record`` = (OSMesa context before or None, the EGL context that was the effective one
    as (api object, state), or None).
    """

    # OSMesa needs a color buffer to make a context current; glraster renders into its own
    # framebuffer objects, so a 1x1 RGBA buffer is enough.
    def __init__(self, api: OSMesaApi, handle):
        super().__init__()
        self._api = api
        self._handle = handle
        self._buffer = (ctypes.c_ubyte * 4)()
        self._own = OSMesaCurrent(handle, ctypes.addressof(self._buffer), GL_UNSIGNED_BYTE, 1, 1)

    def make_current(self):
        if not self._api.make_current(self._own):
            raise BackendUnavailable("OSMesaMakeCurrent failed")

    def _save(self):
        if self._api.context() == self._handle:
            return None  # Mesa's effective context is this one
        return self.save_state(self._api)

    @staticmethod
    def save_state(api: OSMesaApi):
        """What is current now: (OSMesa state or None, effective EGL context or None)."""
        if not api.context():
            return None, None  # no Mesa context is effective on this thread
        from glraster.gpu.backends.egl import EGLApi

        egl = EGLApi.get()
        if egl is not None:
            state = egl.snapshot()
            if state.context:
                return None, (egl, state)  # EGL's is taken as the effective one
        if glx_has_current_context():
            return None, None  # not an OSMesa context: left alone
        return api.snapshot(), None

    def _make_current(self):
        self.make_current()

    def _restore(self, record):
        self.restore_state(self._api, record)

    @staticmethod
    def restore_state(api: OSMesaApi, record):
        before, other = record
        if before is not None:
            api.make_current(before)
        else:
            api.unbind()
        if other is not None:
            other_api, state = other
            other_api.force(state)

    def _load(self, name: str) -> int:
        return self._api.lib.OSMesaGetProcAddress(name.encode("ascii")) or 0

    def _destroy(self):
        if self._handle:
            self._api.lib.OSMesaDestroyContext(self._handle)
            self._handle = None


class OSMesaBackend:
    """Headless OpenGL core context through libOSMesa (Mesa's llvmpipe, or the driver
    ``GALLIUM_DRIVER`` names): the first of 4.5, 3.3 that it makes. The context
    current before creation is current again afterwards, and after every ``with`` block."""

    name = "osmesa"

    def __init__(self):
        self._loader = None

    def create(self):
        import moderngl

        api = OSMesaApi.get(load=True)
        for version in GL_VERSIONS:
            attribs = (ctypes.c_int * 11)(
                OSMESA_FORMAT, OSMESA_RGBA,
                OSMESA_DEPTH_BITS, 0,
                OSMESA_PROFILE, OSMESA_CORE_PROFILE,
                OSMESA_CONTEXT_MAJOR_VERSION, version // 100,
                OSMESA_CONTEXT_MINOR_VERSION, version // 10 % 10,
                0,
            )
            handle = api.lib.OSMesaCreateContextAttribs(attribs, None)
            if handle:
                break
        else:
            raise self._too_old(api)
        loader = OSMesaLoader(api, handle)
        record = OSMesaLoader.save_state(api)
        created = False
        try:
            loader.make_current()
            ctx = wrap_loader(moderngl, loader, MIN_GL)
            created = True
        except Exception as exc:  # moderngl raises bare errors on a loader failure
            raise BackendUnavailable(f"moderngl could not use the OSMesa context: {exc}") from exc
        finally:
            OSMesaLoader.restore_state(api, record)
            if not created:
                loader.release()
        self._loader = loader
        return ctx

    @staticmethod
    def _too_old(api: OSMesaApi) -> BackendUnavailable:
        """Why no core context of GL_VERSIONS was made: :class:`DriverTooOld` naming the
        version of a context without a profile, when one can be made."""
        attribs = (ctypes.c_int * 7)(OSMESA_FORMAT, OSMESA_RGBA, OSMESA_DEPTH_BITS, 0,
                                     OSMESA_PROFILE, OSMESA_COMPAT_PROFILE, 0)
        handle = api.lib.OSMesaCreateContextAttribs(attribs, None)
        if not handle:
            return BackendUnavailable("OSMesaCreateContextAttribs failed for every OpenGL "
                                      "version (4.5 and 3.3 core, and without a profile)")
        probe = OSMesaLoader(api, handle)
        record = OSMesaLoader.save_state(api)
        try:
            probe.make_current()
            strings = gl_strings(probe.load_opengl_function)
        finally:
            OSMesaLoader.restore_state(api, record)
            probe.release()
        return driver_too_old(*strings)

    def release(self):
        self._loader = None
