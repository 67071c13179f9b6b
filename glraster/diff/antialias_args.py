"""The antialias op's argument checks and saved state, shared by its two cores (NumPy only,
no GL): :func:`check`, run once at the boundary by :data:`glraster.diff.ops.ANTIALIAS`, and
:class:`AntialiasSaved`, what both cores' ``forward`` hands their ``backward``.

Layouts (rows [y, x] with row 0 at the bottom): color (B, H, W, C); rast (B, H, W, 4) from
the rasterizer (u, v, z/w, id); pos (V, 4) shared by the B images or (B, V, 4) one per
image; tri (T, 3).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from glraster import validate
from glraster.diff import checked, layout
from glraster.diff.topology_hash import TopologyHash, topology_hash_for
from glraster.errors import ArgumentError

__all__ = ["AntialiasSaved", "check", "wanted"]


@dataclass(frozen=True, eq=False)
class AntialiasSaved:
    """What an antialias core's ``backward`` needs from its ``forward``, the same record
    from both cores: the checked arrays (one float dtype), the parameters; ``pairs``:
    the blended pairs the forward
    found, the float64 reference's :class:`glraster.diff.antialias_reference.Pairs`, or
    the GPU core's lists, pair records and scales per image chunk (a tuple of
    ``glraster.diff.antialias._Chunk``); ``ctx``: the GL context the GPU core ran on
    (None for the reference)."""

    color: np.ndarray
    rast: np.ndarray
    pos: np.ndarray
    tri: np.ndarray
    topology_hash: TopologyHash
    pos_gradient_boost: float
    convex: bool
    pairs: Any = None
    ctx: Any = None


def check(color, rast, pos, tri, topology_hash=None, pos_gradient_boost=1.0, convex=True,
          dtype=np.float64):
    """The checked arguments of antialias (an ArgumentError naming the one that is wrong):
    (color, rast, pos, tri, topology_hash, pos_gradient_boost, convex), arrays of
    ``dtype``; the topology hash is built from ``tri`` when None."""
    rast = checked.raster(rast, dtype)      # (rasterize's own, unchanged: finite)
    batch_n, height, width, _ = rast.shape
    color = validate.image("color", color, dtype=dtype, channels=None)
    if color.shape[:3] != rast.shape[:3] or color.shape[3] < 1:
        raise ArgumentError("color", f"color must have shape {(batch_n, height, width)} + (C,) "
                            f"with C >= 1 (rast's B, H, W), got {color.shape}")
    pos = validate.batched_positions(pos, dtype=dtype)
    if pos.ndim == 3 and pos.shape[0] != batch_n:
        raise ArgumentError("pos", f"pos has a batch of {pos.shape[0]}, rast of {batch_n}: "
                            "3-D pos needs one entry per image")
    tri = validate.triangles(tri, pos.shape[-2])
    if not checked.vouched(rast, len(tri)):     # (rasterize's own, unchanged: valid)
        layout.rast_ids(rast, len(tri))
    th = topology_hash_for(topology_hash, tri, pos.shape[-2])
    if isinstance(pos_gradient_boost, (bool, np.bool_)) or not isinstance(
            pos_gradient_boost, (int, float, np.integer, np.floating)) \
            or not np.isfinite(pos_gradient_boost):
        raise ArgumentError("pos_gradient_boost", "pos_gradient_boost must be a finite number, "
                            f"got {pos_gradient_boost!r}")
    if not isinstance(convex, (bool, np.bool_)):
        raise ArgumentError("convex", f"convex must be True or False, got {convex!r}")
    return color, rast, pos, tri, th, float(pos_gradient_boost), bool(convex)


def wanted(needs) -> tuple[bool, bool]:
    """(color, pos) wanted, from the backward's ``needs`` (None: all; or three flags:
    color, rast, pos; rast has no gradient)."""
    if needs is None:
        return True, True
    if len(needs) != 3:
        raise ValueError(f"needs must have one flag per input (3), got {len(needs)}")
    return bool(needs[0]), bool(needs[2])
