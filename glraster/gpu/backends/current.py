"""Leaving the caller's OpenGL context current: what every backend's loader shares.

moderngl calls its loader's ``__enter__()`` / ``__exit__()`` on ``with mgl_ctx:`` and never
makes a context current otherwise. glcontext's EGL object makes its context current on
creation and *unbinds everything* on ``__exit__`` (eglMakeCurrent(dpy, NO_SURFACE,
NO_SURFACE, NO_CONTEXT)), so a caller's own context, current before, stops drawing without
an error: its GL calls go to glraster's context, or to none.

glraster's loaders (:class:`CurrentContextLoader`, one subclass per platform) instead save
the thread's current context on ``__enter__`` and make it current again on ``__exit__``;
backends do the same around context creation. Nested blocks on the same context cost two
queries and switch nothing.

Mesa keeps one *effective* context per thread (libglapi's dispatch), shared by EGL, GLX and
OSMesa: making an OSMesa context current silently takes the GL calls away from a current
EGL context although eglGetCurrentContext still reports it, and eglMakeCurrent of the
context EGL believes current is a no-op. The loaders therefore compare libglapi's current
context (when libglapi is loaded) with their own and, when another API's context was the
effective one, make it current again through that API on exit (EGL: unbind, then bind).
When EGL and OSMesa both report a current context, EGL's is taken as the effective one.
A current GLX context is detected (so it is never mistaken for an OSMesa one) but not
restored.
"""

from __future__ import annotations

import ctypes
import os
import re
import threading

_libc = ctypes.CDLL(None)
_libc.dlopen.restype = ctypes.c_void_p
_libc.dlopen.argtypes = [ctypes.c_char_p, ctypes.c_int]
_libc.dlclose.argtypes = [ctypes.c_void_p]

_loaded: dict = {}


def loaded_library(names) -> ctypes.CDLL | None:
    """The first library of ``names`` that this process has already loaded (never loads
    one; a found library is remembered, a missing one is looked up again next time)."""
    for name in names:
        lib = _loaded.get(name)
        if lib is not None:
            return lib
        handle = _libc.dlopen(name.encode(), os.RTLD_NOLOAD | os.RTLD_LAZY)
        if handle:
            _libc.dlclose(handle)
            lib = _loaded[name] = ctypes.CDLL(name)
            return lib
    return None


_glapi = None


def mesa_current_context(refresh: bool = False) -> int | None:
    """Mesa's effective GL context on this thread (libglapi's ``_glapi_get_context``), None
    when none is, or when libglapi is not loaded (not Mesa: then nothing is compared).
    ``refresh`` looks for libglapi again (done once per context creation)."""
    global _glapi
    if _glapi is None and refresh:
        lib = loaded_library(("libglapi.so.0",))
        if lib is not None and hasattr(lib, "_glapi_get_context"):
            lib._glapi_get_context.restype = ctypes.c_void_p
            lib._glapi_get_context.argtypes = []
            _glapi = lib._glapi_get_context
    return _glapi() if _glapi is not None else None


def glx_has_current_context() -> bool:
    """True when GLX reports a current context on this thread (libGLX already loaded)."""
    lib = loaded_library(("libGLX.so.0", "libGL.so.1"))
    if lib is None or not hasattr(lib, "glXGetCurrentContext"):
        return False
    lib.glXGetCurrentContext.restype = ctypes.c_void_p
    return bool(lib.glXGetCurrentContext())


class CurrentContextLoader:
    """The loader moderngl calls: GL function lookup, release, and a ``with`` block that
    makes this context current and then restores whatever was current before.

    Subclasses (one per platform) implement::

        _save()              -> record, or None when this context is already the current,
                                effective one (then nothing is switched nor restored)
        _make_current()      make this context current (it is not, or not effectively)
        _restore(record)     make current again what ``_save`` recorded; with no context
                             recorded, leave none of this API current
        _load(name)          -> int   GL function address
        _destroy()           free the native context

    Saved records live on a per-thread stack, so blocks nest and threads do not mix.
    """

    def __init__(self):
        self._local = threading.local()

    def _stack(self) -> list:
        stack = getattr(self._local, "stack", None)
        if stack is None:
            stack = self._local.stack = []
        return stack

    def load_opengl_function(self, name: str) -> int:
        return self._load(name) or 0

    def __enter__(self):
        record = self._save()
        if record is not None:
            self._make_current()
        self._stack().append(record)
        return self

    def __exit__(self, *exc):
        record = self._stack().pop()
        if record is not None:
            self._restore(record)

    def release(self):
        self._destroy()

    # -- subclass interface ---------------------------------------------------------------
    def _save(self):  # pragma: no cover - abstract
        raise NotImplementedError

    def _make_current(self):  # pragma: no cover - abstract
        raise NotImplementedError

    def _restore(self, record):  # pragma: no cover - abstract
        raise NotImplementedError

    def _load(self, name: str) -> int:  # pragma: no cover - abstract
        raise NotImplementedError

    def _destroy(self):  # pragma: no cover - abstract
        raise NotImplementedError


# Core profile versions a backend asks for, best first. Mesa (and NVIDIA) return the
# highest version compatible with the one asked for (4.6 for 4.5, 4.4 for 3.3 where a
# driver has that). 4.5 runs every method (GLSL 4.50 shaders with storage buffers), 3.3 is
# the least glraster runs on at all (method "hw" through vertex attributes, e.g. Mesa's
# softpipe).
GL_VERSIONS = (450, 330)
MIN_GL = GL_VERSIONS[-1]


def version_text(code: int) -> str:
    """450 or 45 -> "4.5"."""
    code = code // 10 if code >= 100 else code
    return f"{code // 10}.{code % 10}"


def gl_strings(load) -> tuple[str, str]:
    """(GL_VERSION, GL_RENDERER) of the current context, through ``load(name) -> address``
    (works on a context of any version, below what moderngl accepts)."""
    address = load("glGetString")
    if not address:
        return "", ""
    get_string = ctypes.CFUNCTYPE(ctypes.c_char_p, ctypes.c_uint)(address)
    version, renderer = get_string(0x1F02), get_string(0x1F01)  # GL_VERSION, GL_RENDERER
    return (version or b"").decode(errors="replace"), (renderer or b"").decode(errors="replace")


def driver_too_old(version: str, renderer: str):
    """The :class:`DriverTooOld` for a driver whose best context is ``version`` (GL_VERSION
    text of a context made without a profile)."""
    from glraster.errors import DriverTooOld

    match = re.match(r"\s*(?:OpenGL )?(\d+)\.(\d+)", version)
    offered = f"{match.group(1)}.{match.group(2)}" if match else None
    needed = version_text(MIN_GL)
    driver = f"the driver ({renderer or 'unknown renderer'})"
    if match and (int(match.group(1)), int(match.group(2))) >= divmod(MIN_GL // 10, 10):
        # e.g. MESA_GLSL_VERSION_OVERRIDE=110: a 4.5 compatibility context, no core one
        return DriverTooOld(f"{driver} makes OpenGL {offered} contexts without a profile but "
                            f"no OpenGL {needed} core context", offered, needed)
    return DriverTooOld(
        f"{driver} offers OpenGL {offered or repr(version)}; glraster needs OpenGL "
        f"{needed} core", offered, needed)


def wrap_loader(moderngl, loader, require: int):
    """``moderngl.create_context`` over ``loader`` (current while this runs), with the
    framebuffer bound now as ``ctx.fbo`` (never None), and without leaving it registered as
    moderngl's process-wide default context: a caller's ``moderngl.get_context()`` keeps
    returning the caller's own. Raises ValueError below OpenGL ``require``."""
    store = getattr(moderngl, "_store", None)
    previous = getattr(store, "default_context", None)
    try:
        return moderngl.create_context(require=require, context=loader)
    finally:
        if store is not None:
            store.default_context = previous
