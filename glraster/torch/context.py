"""Rasterizer contexts with nvdiffrast's names: a holder of a :class:`glraster.Context`,
made on the first float32 call (float64 runs the float64 reference, never opening OpenGL)."""

from __future__ import annotations

import logging
import threading

import torch

_log = logging.getLogger(__name__)

MODES = ("automatic", "manual")


class RasterizeGLContext:
    """A rasterizer context for :func:`glraster.torch.rasterize` and :class:`DepthPeeler`.

    output_db : False: ``rasterize`` returns an empty (B, H, W, 0) ``rast_db``
    mode : "automatic" or "manual" (nvdiffrast's; glraster makes its context current around
        every call, so both behave the same; set/release_context need "manual")
    device : None or "cpu" (tensors live on the CPU)
    backend, context (keyword-only): the OpenGL backend ("auto", "egl", "osmesa"; None:
        ``$GLRASTER_BACKEND``), or an existing glraster.Context to draw with
    active_depth_peeler : the :class:`DepthPeeler` inside its ``with`` block, or None
    """

    def __init__(self, output_db: bool = True, mode: str = "automatic", device=None, *,
                 backend: str | None = "auto", context=None):
        if not isinstance(output_db, bool):
            raise ValueError(f"output_db must be True or False, got {output_db!r}")
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        if context is not None:
            from glraster.gpu.context import Context

            if not isinstance(context, Context):
                raise ValueError(f"context must be a glraster.Context, got "
                                 f"{type(context).__name__}")
        if str(device) not in ("None", "cpu"):
            raise ValueError(f"device must be None or 'cpu' (glraster.torch runs on the CPU, "
                             f"OpenGL reads back to host memory), got {device!r}")
        self.output_db, self.mode, self.backend = output_db, mode, backend
        self.device = torch.device("cpu")
        self._context, self._lock = context, threading.Lock()
        self.active_depth_peeler = None

    @property
    def context(self):
        """The :class:`glraster.Context` this rasterizer draws with (made on first use)."""
        with self._lock:
            if self._context is None:
                from glraster.gpu.context import Context

                self._context = Context(backend=self.backend)
                _log.info("%s: made an OpenGL context: %r", type(self).__name__, self._context)
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


class RasterizeCudaContext(RasterizeGLContext):
    """nvdiffrast's other context name, so that code written for it runs: the same OpenGL
    rasterizer with ``output_db=True`` (glraster has no CUDA rasterizer)."""

    def __init__(self, device=None, *, backend: str | None = "auto", context=None):
        super().__init__(output_db=True, mode="automatic", device=device, backend=backend,
                         context=context)
