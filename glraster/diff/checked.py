"""Checks not repeated on a raster a core made: the id decoding of an unchanged ``rast``.

``Op.check`` of interpolate and antialias decodes every id of ``rast`` (each an encoded
index of one of tri's T triangles, or 0): O(pixels) per call, 2 ms for 4 x 256^2. When
``rast`` is rasterize's output, unchanged since, rasterize's core has made exactly such
ids (of the triangles it drew). A front end that can tell an array is unchanged
(glraster.torch: the keys of :mod:`glraster.gpu.uploads`, with torch's version counter)
records each raster made (:func:`made`) and declares the inputs of a check
(:func:`declared`); :func:`vouched` then says the decoding can be skipped. Without
declarations (glraster.jax, NumPy callers) every check runs.

Entries are ``(region, key, owner)`` as in :mod:`glraster.gpu.uploads`: the owner is
held weakly, so a raster whose tensor was collected is never vouched for.
"""

from __future__ import annotations

import threading
from contextlib import contextmanager

import numpy as np

__all__ = ["declared", "made", "vouched"]

# key -> (owner ref, T): rasters made from T triangles; at most LIMIT live ones
_made: dict = {}
LIMIT = 64
_local = threading.local()


def made(entry, triangles: int) -> None:
    """``entry``'s array is a raster whose ids index ``triangles`` triangles (as made)."""
    if entry is None:
        return
    if len(_made) >= LIMIT:
        for key in [k for k, (owner, _) in _made.items() if owner() is None] or list(_made):
            del _made[key]
    _made[entry[1]] = (entry[2], int(triangles))


@contextmanager
def declared(entries):
    """Within the block (this thread), the arrays of ``entries`` are known by their key."""
    previous = getattr(_local, "regions", None)
    _local.regions = {e[0]: e[1] for e in entries if e is not None}
    try:
        yield
    finally:
        _local.regions = previous


def vouched(rast: np.ndarray, triangles: int) -> bool:
    """True when ``rast`` is a declared raster made from at most ``triangles`` triangles
    (so every id indexes one of them): its ids need no decoding."""
    regions = getattr(_local, "regions", None)
    if not regions or not rast.flags.c_contiguous:
        return False
    got = _made.get(regions.get((rast.ctypes.data, rast.nbytes)))
    return got is not None and got[0]() is not None and got[1] <= triangles
