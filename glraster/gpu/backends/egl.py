"""EGL backend: a glcontext standalone EGL context (libEGL, Mesa's EGL driver) behind
glraster's own loader, which restores the caller's current context (see ``current``)."""

from __future__ import annotations

import ctypes
import ctypes.util
from typing import NamedTuple

from glraster.errors import BackendUnavailable, LibraryMissing
from glraster.gpu.backends.current import GL_VERSIONS, MIN_GL, CurrentContextLoader
from glraster.gpu.backends.current import driver_too_old, gl_strings, loaded_library
from glraster.gpu.backends.current import glx_has_current_context, mesa_current_context, wrap_loader

# The context made to read what a too old driver offers: version 1.0 has no profile, so
# the driver returns its best, whatever it is (MESA_GL_VERSION_OVERRIDE=2.1 gives 2.1).
PROBE_GL = 100

EGL_DRAW = 0x3059
EGL_READ = 0x305A
EGL_OPENGL_API = 0x30A2
LIBRARY_NAMES = ("libEGL.so.1", "libEGL.so")


class EGLCurrent(NamedTuple):
    """The thread's current EGL state: bound client API, display, draw and read surfaces,
    context (0 / None for none)."""

    api: int
    display: int | None
    draw: int | None
    read: int | None
    context: int | None


class EGLApi:
    """ctypes access to libEGL's current-context calls (one instance per process)."""

    _instance = None

    def __init__(self, lib):
        self.lib = lib
        vp = ctypes.c_void_p
        for name in ("eglGetCurrentContext", "eglGetCurrentDisplay"):
            getattr(lib, name).restype = vp
            getattr(lib, name).argtypes = []
        lib.eglGetCurrentSurface.restype = vp
        lib.eglGetCurrentSurface.argtypes = [ctypes.c_int]
        lib.eglMakeCurrent.restype = ctypes.c_uint
        lib.eglMakeCurrent.argtypes = [vp, vp, vp, vp]
        lib.eglQueryAPI.restype = ctypes.c_uint
        lib.eglQueryAPI.argtypes = []
        lib.eglBindAPI.restype = ctypes.c_uint
        lib.eglBindAPI.argtypes = [ctypes.c_uint]

    @classmethod
    def get(cls, load: bool = False) -> "EGLApi | None":
        """The process's EGL access; None when libEGL is not loaded (and ``load`` is False)."""
        if cls._instance is None:
            lib = loaded_library(LIBRARY_NAMES)
            if lib is None and load:
                name = ctypes.util.find_library("EGL") or LIBRARY_NAMES[0]
                try:
                    lib = ctypes.CDLL(name)
                except OSError as exc:
                    raise BackendUnavailable(f"{name} does not load: {exc}") from None
            if lib is None:
                return None
            try:
                cls._instance = cls(lib)
            except AttributeError as exc:  # a library of that name without EGL's calls
                raise BackendUnavailable(f"{lib._name} is not a usable libEGL: {exc}") from None
        return cls._instance

    def context(self) -> int | None:
        return self.lib.eglGetCurrentContext()

    def snapshot(self) -> EGLCurrent:
        lib = self.lib
        context = lib.eglGetCurrentContext()
        if not context:
            return EGLCurrent(lib.eglQueryAPI(), None, None, None, None)
        return EGLCurrent(lib.eglQueryAPI(), lib.eglGetCurrentDisplay(),
                          lib.eglGetCurrentSurface(EGL_DRAW), lib.eglGetCurrentSurface(EGL_READ),
                          context)

    def make_current(self, state: EGLCurrent) -> None:
        """Bind ``state``'s API and make its context current (state.context must be set)."""
        if self.lib.eglQueryAPI() != state.api:
            self.lib.eglBindAPI(state.api)
        self.lib.eglMakeCurrent(state.display, state.draw, state.read, state.context)

    def unbind(self, display) -> None:
        """No context of the bound API current on this thread."""
        self.lib.eglMakeCurrent(display, None, None, None)

    def force(self, state: EGLCurrent) -> None:
        """Make ``state`` current even where EGL believes it already is (it skips that
        eglMakeCurrent, while another API may hold Mesa's dispatch): unbind, then bind."""
        if self.lib.eglQueryAPI() != state.api:
            self.lib.eglBindAPI(state.api)
        self.unbind(state.display)
        self.make_current(state)


class EGLLoader(CurrentContextLoader):
    """A glcontext EGL context whose ``with`` block restores the previous current context.

    ``record`` = (EGL state before, or the other API's effective context as
    (api object, state) when EGL had none of its own current).
    """

    def __init__(self, api: EGLApi, native):
        super().__init__()
        self._api = api
        self._native = native          # glcontext's object: GL function lookup, destroy
        self._own = api.snapshot()     # called while the new context is current
        self._mesa_own = mesa_current_context(refresh=True)

    def __enter__(self):
        # nothing current on the thread (the usual case): the general path's record, with
        # one query of each kind instead of its repeats
        lib = self._api.lib
        if lib.eglGetCurrentContext() or mesa_current_context() is not None:
            return super().__enter__()
        bound, own = lib.eglQueryAPI(), self._own
        if bound != own.api:
            lib.eglBindAPI(own.api)
        lib.eglMakeCurrent(own.display, own.draw, own.read, own.context)
        self._stack().append((EGLCurrent(bound, None, None, None, None), None))
        return self

    def _save(self):
        api = self._api
        if api.context() == self._own.context and mesa_current_context() == self._mesa_own:
            return None
        return self.save_state(api, self._own.context, self._mesa_own)

    @staticmethod
    def save_state(api: EGLApi, own_context=None, mesa_own=None):
        """What is current now: (EGL state, other API's effective context or None)."""
        before = api.snapshot()
        other = None
        effective = mesa_current_context()
        if (effective is not None and effective != mesa_own
                and before.context in (None, own_context)):
            # Mesa's effective context is not an EGL one: OSMesa's (GLX's is left alone)
            if not glx_has_current_context():
                from glraster.gpu.backends.osmesa import OSMesaApi

                osmesa = OSMesaApi.get()
                if osmesa is not None:
                    current = osmesa.snapshot()
                    if current is not None:
                        other = (osmesa, current)
        return before, other

    def _make_current(self):
        state = self._own
        if self._api.context() == state.context:
            self._api.force(state)
        else:
            self._api.make_current(state)

    def _restore(self, record):
        self.restore_state(self._api, record, self._own)

    @staticmethod
    def restore_state(api: EGLApi, record, own: EGLCurrent | None):
        before, other = record
        if before.context and before.api == EGL_OPENGL_API:
            if own is None or before.context != own.context:
                api.make_current(before)   # a switch from ours: EGL does not skip it
        else:
            if own is not None:
                api.unbind(own.display)
            if before.api != EGL_OPENGL_API:
                api.lib.eglBindAPI(before.api)
                if before.context:
                    api.force(before)
        if other is not None:
            other_api, state = other
            other_api.force(state)

    def _load(self, name: str) -> int:
        return self._native.load_opengl_function(name)

    def _destroy(self):
        if self._native is not None:
            self._native.release()
            self._native = None


class EGLBackend:
    """Headless OpenGL core context through EGL: the first of 4.5, 3.3 that the driver
    makes (:data:`~glraster.gpu.backends.current.GL_VERSIONS`; Mesa returns its highest).
    A driver without a 3.3 core context raises :class:`DriverTooOld` naming the version it
    offers.

    glcontext enumerates EGL devices; Mesa's llvmpipe shows up as its software device.
    ``GLCONTEXT_DEVICE_INDEX`` picks another device. glcontext raises bare exceptions; they
    are turned into :class:`BackendUnavailable` here. The context current before creation
    is current again afterwards, and after every ``with mgl_ctx:`` block.
    """

    name = "egl"

    def __init__(self):
        self._loader = None

    def create(self):
        import glcontext
        import moderngl

        if ctypes.util.find_library("EGL") is None:
            raise LibraryMissing("libEGL.so.1 not found (Debian package libegl1)")
        api = EGLApi.get(load=True)
        record = EGLLoader.save_state(api)
        native = own = None
        created = False
        make = glcontext.get_backend_by_name("egl")
        try:
            failure = None
            for version in GL_VERSIONS:
                try:
                    native = make(mode="standalone", glversion=version)
                    break
                except Exception as exc:  # noqa: BLE001 (glcontext raises bare Exception)
                    failure = exc
            if native is None:
                # no core context of a version glraster runs on: what does the driver offer?
                try:
                    native = make(mode="standalone", glversion=PROBE_GL)
                except Exception:  # noqa: BLE001 (glcontext raises bare Exception)
                    raise BackendUnavailable(f"EGL context creation failed: {failure}") from failure
                own = api.snapshot()
                raise driver_too_old(*gl_strings(native.load_opengl_function))
            own = api.snapshot()  # glcontext leaves the new context current
            self._loader = EGLLoader(api, native)
            mgl = wrap_loader(moderngl, self._loader, MIN_GL)
            created = True
            return mgl
        except BackendUnavailable:
            raise
        except Exception as exc:  # glcontext raises bare Exception
            raise BackendUnavailable(f"EGL context creation failed: {exc}") from exc
        finally:
            EGLLoader.restore_state(api, record, own)
            if not created:
                self._loader = None
                if native is not None:
                    native.release()  # after unbinding: EGL defers destroying a current one

    def release(self):
        self._loader = None
