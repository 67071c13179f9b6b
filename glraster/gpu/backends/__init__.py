"""Headless OpenGL backends: one small class per platform behind one interface.

A backend creates an OpenGL core context without a window, the best of 4.5 and 3.3
that the driver makes (``current.GL_VERSIONS``), and hands it to moderngl.
Every backend class has::

    Backend.name            -> str           "egl" or "osmesa"
    Backend.create()        -> moderngl.Context   (raises BackendUnavailable)
    Backend.release()       -> None

All GL work happens inside ``with mgl_ctx:``, which makes the backend's context current
through the backend's loader (``egl.EGLLoader``, ``osmesa.OSMesaLoader``, both
``current.CurrentContextLoader``). The loader saves the thread's current context on entry
and makes it current again on exit, and ``create()`` does the same around creation, so a
caller's own context (a standalone moderngl context, pyrender's) keeps drawing, and
contexts of both backends can live in one process.

``create_backend("auto")`` tries EGL first, then OSMesa. A backend's first context in an
environment is made in a probe process before this one (``probe``): a driver library that
crashes (Mesa's OSMesa with a ``GALLIUM_DRIVER`` it does not have) is reported as an error;
``environment`` names the driver variables that are set in that error.
"""

from __future__ import annotations

import os

from glraster.errors import (
    ArgumentError,
    BackendCrashed,
    BackendUnavailable,
    BadEnvironment,
    DriverTooOld,
    LibraryMissing,
)
from glraster.gpu.backends import probe
from glraster.gpu.backends.egl import EGLBackend
from glraster.gpu.backends.environment import advice
from glraster.gpu.backends.osmesa import OSMesaBackend

BACKENDS = {"egl": EGLBackend, "osmesa": OSMesaBackend}
INSTALL_HINT = (
    "install Mesa's headless libraries, e.g. on Debian/Ubuntu: "
    "sudo apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6"
)


def resolve_backend_name(backend: str | None) -> str:
    """The backend to use: the argument, else $GLRASTER_BACKEND, else "auto". A bad
    argument is a ValueError, a bad $GLRASTER_BACKEND a :class:`BadEnvironment`."""
    name = backend if backend is not None else os.environ.get("GLRASTER_BACKEND", "auto")
    if not isinstance(name, str) or name.strip().lower() not in ("auto", *BACKENDS):
        message = f"backend must be one of 'auto', 'egl', 'osmesa', got {name!r}"
        if backend is None:
            raise BadEnvironment(f"{message} (from GLRASTER_BACKEND): unset it or set one "
                                 "of those", "GLRASTER_BACKEND")
        raise ArgumentError("backend", message)
    return name.strip().lower()


def _create(name: str):
    """(backend, moderngl.Context) of backend ``name``, after the probe of this
    environment said that creating it neither fails nor crashes."""
    probe.require(name)
    instance = BACKENDS[name]()
    return instance, instance.create()


def create_backend(backend: str | None = None):
    """Create a backend and its moderngl context: ``(backend, moderngl.Context)``.

    Each backend's first context in an environment is made in a probe process first
    (:mod:`glraster.gpu.backends.probe`): a driver that crashes raises
    :class:`~glraster.errors.BackendCrashed` here instead of killing the process.
    """
    name = resolve_backend_name(backend)
    candidates = list(BACKENDS) if name == "auto" else [name]
    failures, errors = [], []
    for candidate in candidates:
        try:
            return _create(candidate)
        except BackendUnavailable as exc:
            failures.append(f"{candidate}: {exc}")
            errors.append(exc)
    raise combined_error(failures, errors)


def combined_error(failures: list[str], errors: list) -> BackendUnavailable:
    """One error for every backend's failure, with the next step: the install hint where
    a library is missing, else what the driver variables that are set do."""
    message = ("no headless OpenGL 3.3+ core context could be created ("
               + "; ".join(failures) + ")")
    missing = [e for e in errors if isinstance(e, LibraryMissing)]
    if missing and len(missing) == len(errors):
        return LibraryMissing(f"{message}; {INSTALL_HINT}")
    # Some library is there: the cause is the driver or the environment, not an install.
    message = f"{message}; {advice()}"
    if missing:
        message += f" (or {INSTALL_HINT})"
    too_old = [e for e in errors if isinstance(e, DriverTooOld)]
    if too_old and len(too_old) == len(errors):
        return DriverTooOld(message, too_old[0].offered, too_old[0].needed)
    crashed = [e for e in errors if isinstance(e, BackendCrashed)]
    if crashed and len(crashed) == len(errors):
        return BackendCrashed(message, crashed[0].backend, crashed[0].signal)
    return BackendUnavailable(message)


def available_backends() -> list[str]:
    """Names of the backends that can create a context on this machine."""
    names = []
    for name in BACKENDS:
        try:
            instance, ctx = _create(name)
        except BackendUnavailable:
            continue
        ctx.release()
        instance.release()
        names.append(name)
    return names
