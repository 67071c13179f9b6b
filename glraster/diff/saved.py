"""What the backward of rasterize and of interpolate needs from their forward: one record
per op, made by the GPU core and by the float64 reference alike (NumPy only, no GL).

Arrays are the checked inputs (:meth:`glraster.diff.op.Op.check`) in the core's float
dtype (float32 on the GPU, float64 in the reference); layouts as
:mod:`glraster.diff.layout` describes them.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from glraster.diff.ids import decode_ids

__all__ = ["InterpolateSaved", "RasterizeSaved"]


@dataclass(frozen=True)
class RasterizeSaved:
    """One rasterization (a forward or one depth-peeling layer).

    pos        : (V, 4) or (B, V, 4) clip-space positions, as checked
    tri        : (T, 3) int32
    resolution : (H, W)
    ranges     : (B, 2) int64 [first, count] rows (range mode) or None
    rast       : (B, H, W, 4) the forward's (u, v, z/w, id); its ids freeze the coverage
    space      : "persp" or "screen"
    ctx        : the GPU context the forward ran on (None in the reference)
    """

    pos: np.ndarray
    tri: np.ndarray
    resolution: tuple[int, int]
    ranges: np.ndarray | None
    rast: np.ndarray
    space: str = "persp"
    ctx: Any = None

    @cached_property
    def tri_id(self) -> np.ndarray:
        """(B, H, W) int64 winning triangle of every pixel (index into tri, -1 empty)."""
        return decode_ids(self.rast[..., 3], "rast channel 3 (triangle id)")


@dataclass(frozen=True)
class InterpolateSaved:
    """One interpolation.

    attr       : (V, A) or (B', V, A) attributes, as checked (B' = 1 broadcasts over B)
    rast       : (B, H, W, 4)
    tri        : (T, 3) int32
    rast_db    : (B, H, W, 4), or None when no attribute's derivatives were asked for
    diff_attrs : the chosen attribute indices in out_da's order (empty: no out_da)
    ctx        : the GPU context the forward ran on (None in the reference)
    """

    attr: np.ndarray
    rast: np.ndarray
    tri: np.ndarray
    rast_db: np.ndarray | None
    diff_attrs: tuple[int, ...] = ()
    ctx: Any = None

    @cached_property
    def tri_id(self) -> np.ndarray:
        """(B, H, W) int64 triangle of every pixel (index into tri, -1 empty)."""
        return decode_ids(self.rast[..., 3], "rast channel 3 (triangle id)")

    @property
    def attr_batches(self) -> np.ndarray:
        """attr as (B', V, A): a 2-D attr is one batch that broadcasts."""
        return self.attr if self.attr.ndim == 3 else self.attr[None]
