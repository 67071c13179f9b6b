"""Rasterizer contexts with nvdiffrast's names (:class:`glraster.diff.rasterizer_context.
RasterizerContext` with torch's ``device``): a holder of a :class:`glraster.Context`, made on
the first float32 call (float64 runs the float64 reference, never opening OpenGL)."""

from __future__ import annotations

import torch

from glraster.diff.rasterizer_context import MODES, RasterizerContext
from glraster.errors import ArgumentError

__all__ = ["MODES", "RasterizeCudaContext", "RasterizeGLContext"]


class RasterizeGLContext(RasterizerContext):
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
        if str(device) not in ("None", "cpu"):
            raise ArgumentError("device", f"device must be None or 'cpu' (glraster.torch runs "
                                          f"on the CPU, OpenGL reads back to host memory), "
                                          f"got {device!r}")
        super().__init__(output_db, mode, backend=backend, context=context)
        self.device = torch.device("cpu")


class RasterizeCudaContext(RasterizeGLContext):
    """nvdiffrast's other context name, so that code written for it runs: the same OpenGL
    rasterizer with ``output_db=True`` (glraster has no CUDA rasterizer)."""

    def __init__(self, device=None, *, backend: str | None = "auto", context=None):
        super().__init__(True, "automatic", device, backend=backend, context=context)
