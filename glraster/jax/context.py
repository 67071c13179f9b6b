"""Rasterizer contexts with nvdiffrast's names on JAX: :class:`RasterizeGLContext` and its
alias :class:`RasterizeCudaContext` (a thin holder of a :class:`glraster.Context`, made on
first use; :class:`glraster.diff.rasterizer_context.RasterizerContext`).

``RasterizeGLContext(output_db=True, mode="automatic", device=None)`` is nvdiffrast's
signature; ``backend`` and ``context`` are glraster's keyword-only additions. Arrays live
on the CPU: ``device`` must be None, "cpu" or a JAX CPU device (OpenGL reads back to host
memory, and ``jax.pure_callback`` hands NumPy arrays to it).
"""

from __future__ import annotations

import jax

from glraster.diff.rasterizer_context import RasterizerContext
from glraster.errors import ArgumentError

__all__ = ["RasterizeCudaContext", "RasterizeGLContext"]


def _cpu_device(device):
    """``device`` as accepted by both contexts: None, "cpu" or a JAX CPU device."""
    if device is None or device == "cpu":
        return jax.devices("cpu")[0]
    if isinstance(device, jax.Device) and device.platform == "cpu":
        return device
    raise ArgumentError("device", f"device must be None, 'cpu' or a JAX CPU device "
                                  f"(glraster.jax's ops run on the host), got {device!r}")


class RasterizeGLContext(RasterizerContext):
    """A rasterizer context for :func:`glraster.jax.rasterize` and :class:`DepthPeeler`.

    Parameters
    ----------
    output_db : bool
        True: ``rasterize`` returns ``rast_db`` (B, H, W, 4); False: (B, H, W, 0).
    mode : {"automatic", "manual"}
        Accepted for nvdiffrast compatibility; both behave the same.
    device : None, "cpu" or a JAX CPU device
    backend : {"auto", "egl", "osmesa"} or None, keyword-only
    context : glraster.Context, keyword-only
        Draw with this existing context instead of making one.

    Attributes: ``output_db``, ``mode``, ``device`` (a JAX CPU device),
    ``active_depth_peeler``, ``context`` (the glraster.Context, made on first use).
    """

    def __init__(self, output_db: bool = True, mode: str = "automatic", device=None, *,
                 backend: str | None = "auto", context=None):
        super().__init__(output_db, mode, backend=backend, context=context)
        self.device = _cpu_device(device)


class RasterizeCudaContext(RasterizeGLContext):
    """nvdiffrast's other context name: the same OpenGL rasterizer with ``output_db=True``
    (glraster has no CUDA rasterizer; ``device`` must be None, "cpu" or a CPU device)."""

    def __init__(self, device=None, *, backend: str | None = "auto", context=None):
        super().__init__(output_db=True, mode="automatic", device=device, backend=backend,
                         context=context)


def check_glctx(glctx, *, optional: bool = False):
    """``glctx`` if it is a :class:`RasterizeGLContext` (or None when ``optional``)."""
    if glctx is None and optional:
        return None
    if not isinstance(glctx, RasterizeGLContext):
        raise ArgumentError("glctx", f"glctx must be a glraster.jax.RasterizeGLContext (or "
                                     f"RasterizeCudaContext), got {type(glctx).__name__}")
    return glctx


def gl_context(glctx, array):
    """The glraster.Context the ops draw with for ``array``'s dtype: ``glctx.context`` for
    float32 (made on first use), None for float64 (the reference never opens OpenGL) or
    without ``glctx`` (None: the ops' default context)."""
    if glctx is None or getattr(array, "dtype", None) == "float64":
        return None
    return glctx.context
