"""The one differentiable shading path of the fits: rasterize -> interpolate (-> antialias).

:func:`shade` draws vertex colours; :func:`antialias_available` says whether
:mod:`glraster.torch.antialias` can be imported (without it the image has no visibility
gradient: coverage is frozen, and only the colours inside the silhouette move with the
vertices).
"""

from __future__ import annotations

import importlib

import torch

from glraster.torch.ops import interpolate, rasterize

__all__ = ["antialias_available", "shade", "topology_hash"]


def _antialias_module():
    # the module, not the function of the same name that glraster.torch exports
    try:
        return importlib.import_module("glraster.torch.antialias")
    except ImportError:
        return None


def antialias_available() -> bool:
    return _antialias_module() is not None


def topology_hash(tri: torch.Tensor):
    """The antialias topology hash of ``tri`` (None when antialias is unavailable)."""
    module = _antialias_module()
    return None if module is None else module.antialias_construct_topology_hash(tri)


def shade(glctx, clip: torch.Tensor, tri: torch.Tensor, colors: torch.Tensor, resolution,
          *, antialias: bool = True, topology=None):
    """(B, H, W, C) image of vertex ``colors`` (V, C) on the mesh at clip positions
    ``clip`` (B, V, 4), background 0; with ``antialias`` the silhouettes are blended
    (:func:`glraster.torch.antialias`), which gives the positions their visibility
    gradient. Returns (image, rast)."""
    rast, _ = rasterize(glctx, clip, tri, resolution, grad_db=False)
    image, _ = interpolate(colors[None] if colors.ndim == 2 else colors, rast, tri, glctx=glctx)
    if antialias:
        module = _antialias_module()
        if module is None:
            raise RuntimeError("antialias=True but glraster.torch.antialias is not available")
        image = module.antialias(image, rast, clip, tri, topology, glctx=glctx)
    return image, rast
