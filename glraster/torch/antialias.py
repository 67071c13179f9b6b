"""``antialias`` and ``antialias_construct_topology_hash`` with nvdiffrast's signatures, a
call of :mod:`glraster.torch.bridge` on :data:`glraster.diff.ops.ANTIALIAS`.

Layouts (rows ``[y, x]`` with row 0 at the bottom): color (B, H, W, C); rast (B, H, W, 4)
from :func:`glraster.torch.rasterize`; pos (V, 4) or (B, V, 4), the positions rast was made
from; tri (T, 3) int32 or int64; out (B, H, W, C), color's dtype. Gradients go to
``color`` and ``pos`` (the two vertices of each crossing silhouette edge, times
``pos_gradient_boost``); none to ``rast``. docs/differentiable.md, "Antialias".
"""

from __future__ import annotations

from glraster.diff.antialias_reference import antialias_construct_topology_hash as _hash
from glraster.diff.ops import ANTIALIAS
from glraster.torch import bridge


@bridge.eager
def antialias_construct_topology_hash(tri, *, pos=None):
    """The topology hash of ``tri`` (nvdiffrast's ``antialias_construct_topology_hash``):
    build it once for triangles that do not change and pass it to :func:`antialias`.

    pos (glraster's addition): (V, 3) or (V, 4) positions; vertices with exactly equal
    positions are welded, so that duplicated vertices (texture seams) do not make every
    edge a silhouette. Returns an opaque :class:`~glraster.diff.antialias_reference.TopologyHash`.
    """
    return _hash(bridge.integers("tri", tri),
                 pos=None if pos is None else bridge.tensor("pos", pos))


@bridge.eager
def antialias(color, rast, pos, tri, topology_hash=None, pos_gradient_boost=1.0, *,
              glctx=None, convex=True):
    """Antialias ``color`` across the mesh's silhouette edges (nvdiffrast's ``antialias``).

    topology_hash: from :func:`antialias_construct_topology_hash` (None: built from tri);
    pos_gradient_boost: factor on pos' gradients. glraster's: glctx, the context float32
    runs on; convex, scale a pixel's blend weights to sum to 1 where they would sum past it
    (out stays within the inputs' range; False: the plain sum)."""
    return bridge.Call(ANTIALIAS, (color, rast, pos), glctx, tri=tri,
                       topology_hash=topology_hash, pos_gradient_boost=pos_gradient_boost,
                       convex=convex)()[0]
