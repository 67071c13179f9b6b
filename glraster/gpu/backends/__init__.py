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

``create_backend("auto")`` tries EGL first, then OSMesa.
"""

from __future__ import annotations

import os

from glraster.errors import BackendUnavailable, DriverTooOld, LibraryMissing
from glraster.gpu.backends.egl import EGLBackend
from glraster.gpu.backends.osmesa import OSMesaBackend

BACKENDS = {"egl": EGLBackend, "osmesa": OSMesaBackend}
INSTALL_HINT = (
    "install Mesa's headless libraries, e.g. on Debian/Ubuntu: "
    "sudo apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6"
)


def resolve_backend_name(backend: str | None) -> str:
    """The backend to use: the argument, else $GLRASTER_BACKEND, else "auto"."""
    name = backend if backend is not None else os.environ.get("GLRASTER_BACKEND", "auto")
    if not isinstance(name, str) or name.lower() not in ("auto", *BACKENDS):
        raise ValueError(
            f"backend must be one of 'auto', 'egl', 'osmesa', got {name!r}"
            + (" (from GLRASTER_BACKEND)" if backend is None else "")
        )
    return name.lower()


def create_backend(backend: str | None = None):
    """Create a backend and its moderngl context: ``(backend, moderngl.Context)``."""
    name = resolve_backend_name(backend)
    candidates = list(BACKENDS) if name == "auto" else [name]
    failures, errors = [], []
    for candidate in candidates:
        instance = BACKENDS[candidate]()
        try:
            return instance, instance.create()
        except BackendUnavailable as exc:
            failures.append(f"{candidate}: {exc}")
            errors.append(exc)
    message = "no headless OpenGL 3.3+ core context could be created (" + "; ".join(failures) + ")"
    # The install hint helps where a library is missing (or the cause is unknown), not
    # where the driver answered with an older OpenGL.
    too_old = [e for e in errors if isinstance(e, DriverTooOld)]
    if too_old and len(too_old) == len(errors):
        raise DriverTooOld(message, too_old[0].offered, too_old[0].needed)
    if errors and all(isinstance(e, LibraryMissing) for e in errors):
        raise LibraryMissing(f"{message}; {INSTALL_HINT}")
    raise BackendUnavailable(f"{message}; {INSTALL_HINT}")


def available_backends() -> list[str]:
    """Names of the backends that can create a context on this machine."""
    names = []
    for name, cls in BACKENDS.items():
        instance = cls()
        try:
            ctx = instance.create()
        except BackendUnavailable:
            continue
        ctx.release()
        instance.release()
        names.append(name)
    return names
