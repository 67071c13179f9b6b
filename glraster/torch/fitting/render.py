"""The one differentiable shading path of the fits: rasterize -> interpolate (-> antialias).

:func:`shade` draws vertex colours; without antialias the image has no visibility
gradient (coverage is frozen, and only the colours inside the silhouette move with the
vertices).
"""

from __future__ import annotations

import weakref

import torch

from glraster.torch.antialias import antialias as _antialias
from glraster.torch.antialias import antialias_construct_topology_hash
from glraster.torch.context import RasterizeGLContext
from glraster.torch.ops import interpolate, rasterize

__all__ = ["shade", "topology_hash"]


def topology_hash(tri: torch.Tensor):
    """The antialias topology hash of ``tri``."""
    return antialias_construct_topology_hash(tri)


def shade(glctx, clip: torch.Tensor, tri: torch.Tensor, colors: torch.Tensor, resolution,
          *, antialias: bool = True, topology=None):
    """(B, H, W, C) image of vertex ``colors`` (V, C) on the mesh at clip positions
    ``clip`` (B, V, 4), background 0; with ``antialias`` the silhouettes are blended
    (:func:`glraster.torch.antialias`), which gives the positions their visibility
    gradient. Returns (image, rast)."""
    rast, _ = rasterize(_without_db(glctx), clip, tri, resolution, grad_db=False)
    image, _ = interpolate(colors, rast, tri, glctx=glctx)
    if antialias:
        image = _antialias(image, rast, clip, tri, topology, glctx=glctx)
    return image, rast


_WITHOUT_DB: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _without_db(glctx: RasterizeGLContext) -> RasterizeGLContext:
    """``glctx``, or a context drawing with its OpenGL context and ``output_db=False``:
    :func:`shade` reads no rast_db, so the rasterizer neither draws nor reads it back."""
    if not glctx.output_db:
        return glctx
    sibling = _WITHOUT_DB.get(glctx)
    if sibling is None:
        sibling = _WITHOUT_DB[glctx] = RasterizeGLContext(output_db=False,
                                                          context=glctx.context)
    return sibling
