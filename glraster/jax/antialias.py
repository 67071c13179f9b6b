"""``antialias`` and ``antialias_construct_topology_hash`` with nvdiffrast's signatures on
JAX arrays (the one bridge, :func:`glraster.jax.bridge.apply`).

Layouts (rows ``[y, x]`` with row 0 at the bottom): color (B, H, W, C); rast (B, H, W, 4)
from :func:`glraster.jax.rasterize`; pos (V, 4) or (B, V, 4), the positions rast was made
from; tri (T, 3) int (static). Gradients go to ``color`` and ``pos`` (the two vertices of
each crossing silhouette edge, times ``pos_gradient_boost``); none to ``rast``.
"""

from __future__ import annotations

import jax.numpy as jnp

from glraster.diff.antialias_reference import antialias_construct_topology_hash as _construct
from glraster.diff.ops import ANTIALIAS
from glraster.jax import bridge
from glraster.jax.context import check_glctx

__all__ = ["antialias", "antialias_construct_topology_hash"]


def antialias_construct_topology_hash(tri, *, pos=None):
    """The topology hash of ``tri`` (nvdiffrast's ``antialias_construct_topology_hash``):
    build it once for triangles that do not change and pass it to :func:`antialias`.

    tri : (T, 3) int32/int64 (NumPy or a concrete JAX array)
    pos : (V, 3) or (V, 4), optional (glraster's addition, keyword-only): weld vertices
        with exactly equal positions, so that duplicated vertices (texture seams) do not
        make every edge a silhouette.

    Returns an opaque object (a :class:`glraster.diff.antialias_reference.TopologyHash`).
    """
    return _construct(bridge.concrete("tri", tri), pos=bridge.concrete("pos", pos))


def antialias(color, rast, pos, tri, topology_hash=None, pos_gradient_boost=1.0, *,
              glctx=None, convex=True):
    """Antialias an image across the mesh's silhouette edges (nvdiffrast's ``antialias``).

    Arguments
    ---------
    color : jax.Array (B, H, W, C), float32 or float64
    rast : jax.Array (B, H, W, 4), :func:`glraster.jax.rasterize`'s first output
    pos : jax.Array (V, 4) or (B, V, 4): the clip-space positions rast was made from
    tri : (T, 3) int, static
    topology_hash : from :func:`antialias_construct_topology_hash`, optional (built from
        ``tri`` when None)
    pos_gradient_boost : float, factor on the gradients sent to ``pos``
    glctx : RasterizeGLContext, keyword-only, optional (glraster's addition)
    convex : bool, keyword-only (glraster's addition): scale a pixel's blend weights to sum
        to at most 1, so that the output stays within the range of the inputs

    Returns
    -------
    The antialiased image, (B, H, W, C) of color's dtype.
    """
    check_glctx(glctx, optional=True)
    color = jnp.asarray(color)
    (out,) = bridge.apply(ANTIALIAS, (color, rast, pos),
                          dict(tri=bridge.concrete("tri", tri), topology_hash=topology_hash,
                               pos_gradient_boost=pos_gradient_boost, convex=convex,
                               ctx=glctx))
    return out
