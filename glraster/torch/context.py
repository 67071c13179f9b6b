"""Rasterizer contexts with nvdiffrast's names: a thin holder of a :class:`glraster.Context`.

``RasterizeGLContext(output_db=True, mode="automatic", device=None)`` is nvdiffrast's
signature; ``backend`` and ``context`` are glraster's own keyword-only additions.
``RasterizeCudaContext(device=None)`` is the same class under nvdiffrast's other name, so that
code written for it runs unchanged: it always outputs ``rast_db`` and it draws with OpenGL
like the other (glraster has no CUDA rasterizer).

The OpenGL context is made on the first call that needs it (float32 tensors): float64
tensors run the float64 reference on the CPU and never open OpenGL, so a context object
costs nothing until then. Every tensor lives on the CPU (``device`` must be None or "cpu").
"""

from __future__ import annotations

import logging
import threading

import torch

_log = logging.getLogger(__name__)

MODES = ("automatic", "manual")


def _cpu_device(device):
    """``device`` as accepted by both contexts: None, "cpu" or torch.device("cpu")."""
    if device is None:
        return torch.device("cpu")
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise ValueError(f"device must be None or 'cpu', got {device!r}") from None
    if dev.type != "cpu":
        raise ValueError(f"device must be None or 'cpu' (glraster.torch runs on the CPU, "
                         f"OpenGL reads back to host memory), got {device!r}")
    return dev


class RasterizeGLContext:
    """A rasterizer context for :func:`glraster.torch.rasterize` and :class:`DepthPeeler`.

    Parameters
    ----------
    output_db : bool
        True: ``rasterize`` returns ``rast_db`` (B, H, W, 4) = (du/dx, du/dy, dv/dx, dv/dy);
        False: an empty (B, H, W, 0) tensor, and ``grad_db`` is ignored (as nvdiffrast).
    mode : {"automatic", "manual"}
        Accepted for nvdiffrast compatibility. glraster makes its context current around
        every call and restores the caller's afterwards, so both modes behave the same;
        :meth:`set_context` / :meth:`release_context` are allowed in "manual" mode only.
    device : None or "cpu"
        Where tensors live; anything else is a ValueError.
    backend : {"auto", "egl", "osmesa"} or None, keyword-only
        The OpenGL backend of the context made on first use (None: ``$GLRASTER_BACKEND``).
    context : glraster.Context, keyword-only
        Draw with this existing context instead of making one (``backend`` is then unused).

    Attributes
    ----------
    output_db : bool
    mode : str
    device : torch.device      always cpu
    active_depth_peeler        the :class:`DepthPeeler` inside its ``with`` block, or None
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
        self.output_db = output_db
        self.mode = mode
        self.device = _cpu_device(device)
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


class RasterizeCudaContext(RasterizeGLContext):
    """nvdiffrast's other context name, accepted so that code written for it runs: the same
    OpenGL rasterizer as :class:`RasterizeGLContext` with ``output_db=True`` (glraster has
    no CUDA rasterizer; ``device`` must be None or "cpu")."""

    def __init__(self, device=None, *, backend: str | None = "auto", context=None):
        super().__init__(output_db=True, mode="automatic", device=device, backend=backend,
                         context=context)
