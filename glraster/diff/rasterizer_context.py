"""nvdiffrast's rasterizer context, framework-free: a lazily made :class:`glraster.Context`
with ``output_db`` and ``mode`` (the front ends' ``RasterizeGLContext`` subclass it and add
their ``device`` check).

The OpenGL context is made on the first call that needs it (float32 arrays): float64 runs
the float64 reference on the CPU and never opens OpenGL, so a context object costs nothing
until then.
"""

from __future__ import annotations

import logging
import threading

from glraster.errors import ArgumentError

_log = logging.getLogger(__name__)

MODES = ("automatic", "manual")


class RasterizerContext:
    """A rasterizer context: ``output_db``, ``mode``, the OpenGL context made on first use,
    and the active depth peeler.

    output_db : bool
        True: ``rasterize`` returns ``rast_db`` (B, H, W, 4) = (du/dx, du/dy, dv/dx, dv/dy);
        False: an empty (B, H, W, 0) array, and ``grad_db`` is ignored (as nvdiffrast).
    mode : {"automatic", "manual"}
        Accepted for nvdiffrast compatibility. glraster makes its context current around
        every call and restores the caller's afterwards, so both modes behave the same;
        :meth:`set_context` / :meth:`release_context` are allowed in "manual" mode only.
    backend : {"auto", "egl", "osmesa"} or None, keyword-only
        The OpenGL backend of the context made on first use (None: ``$GLRASTER_BACKEND``).
    context : glraster.Context, keyword-only
        Draw with this existing context instead of making one (``backend`` is then unused).
    """

    def __init__(self, output_db: bool = True, mode: str = "automatic", *,
                 backend: str | None = "auto", context=None):
        if not isinstance(output_db, bool):
            raise ArgumentError("output_db", f"output_db must be True or False, got "
                                             f"{output_db!r}")
        if mode not in MODES:
            raise ArgumentError("mode", f"mode must be one of {MODES}, got {mode!r}")
        if context is not None:
            from glraster.gpu.context import Context

            if not isinstance(context, Context):
                raise ArgumentError("context", f"context must be a glraster.Context, got "
                                               f"{type(context).__name__}")
        self.output_db = output_db
        self.mode = mode
        self.backend = backend
        self._context = context
        self._lock = threading.Lock()
        self.active_depth_peeler = None

    @property
    def context(self):
        """The :class:`glraster.Context` this rasterizer draws with (made on first use)."""
        if self._context is None:
            with self._lock:
                if self._context is None:
                    from glraster.gpu.context import Context

                    self._context = Context(backend=self.backend)
                    _log.info("%s: made an OpenGL context: %r", type(self).__name__,
                              self._context)
        return self._context

    def set_context(self):
        """nvdiffrast's manual mode: a no-op here (every call makes the context current)."""
        if self.mode != "manual":
            raise RuntimeError("set_context() is only available in mode='manual'")

    def release_context(self):
        """nvdiffrast's manual mode: a no-op here (every call restores the caller's context)."""
        if self.mode != "manual":
            raise RuntimeError("release_context() is only available in mode='manual'")

    def __repr__(self):
        made = "not made yet" if self._context is None else repr(self._context)
        return (f"{type(self).__name__}(output_db={self.output_db}, mode={self.mode!r}, "
                f"context: {made})")


class PeelerScope:
    """The ``with`` rules of nvdiffrast's ``DepthPeeler``, shared by the front ends: one
    active peeler per context (``raster_ctx.active_depth_peeler``), a finished peeler cannot
    be entered again, and leaving releases what ``_open`` started (``self._peeler``)."""

    raster_ctx = None
    _peeler = None

    def _open(self) -> None:
        """What entering starts (a front end's peeler overrides it)."""

    def __enter__(self):
        if self.raster_ctx is None:
            raise RuntimeError("cannot re-enter a finished DepthPeeler")
        if self.raster_ctx.active_depth_peeler is not None:
            raise RuntimeError("this context already has an active DepthPeeler")
        self._open()
        self.raster_ctx.active_depth_peeler = self
        return self

    def __exit__(self, *exc):
        try:
            if self._peeler is not None:
                self._peeler.release()
        finally:
            if self.raster_ctx is not None and self.raster_ctx.active_depth_peeler is self:
                self.raster_ctx.active_depth_peeler = None
            self.raster_ctx = self._peeler = None
