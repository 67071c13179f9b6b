"""Checks not repeated on arrays known unchanged: the id decoding of a ``rast`` a core made,
and the finiteness test of an array that passed it before (a constant texture and its
mip pyramid, checked on every texture call otherwise: 6 x 512^2 x 3 texels cost about
5 ms a call).

``Op.check`` of interpolate and antialias decodes every id of ``rast`` (each an encoded
index of one of tri's T triangles, or 0): O(pixels) per call, 2 ms for 4 x 256^2. When
``rast`` is rasterize's output, unchanged since, rasterize's core has made exactly such
ids (of the triangles it drew), and finite values (barycentrics and z/w of covered
points, zeros elsewhere, from finite positions: its own check), so the finiteness test of
``rast`` (0.1 ms per 2 x 256^2 pixels, twice per shading pass) need not run either. A front
end that can tell an array is unchanged (glraster.torch: the keys of
:mod:`glraster.gpu.uploads`, with torch's version counter) records each raster made
(:func:`made`) and declares the inputs of a check (:func:`declared`); :func:`vouched` then
says the decoding can be skipped, :func:`raster` skips the finiteness test of such a
raster, and every finiteness test of :mod:`glraster.validate` (:func:`validate.finite
<glraster.validate.finite>`: pos, attr, color, rast_db, tex, uv, uv_da, mip levels, ...)
skips that of a declared array that passed it under the same key (:func:`_seen`). Without
declarations (glraster.jax, NumPy callers) every check runs. Writes that bypass the
version counter (through a NumPy view of a tensor or ``.data``) are not seen, as for the
upload cache.

Entries are ``(region, key, owner)`` as in :mod:`glraster.gpu.uploads`: the owner is
held weakly, so a raster whose tensor was collected is never vouched for.

:func:`made` also hands the key to the upload cache whose buffer a core left the raster's
bytes in (:func:`produced`, :meth:`glraster.gpu.uploads.UploadCache.adopt`): the ops that
read the raster next bind that buffer instead of uploading it again.
"""

from __future__ import annotations

import threading
import weakref

import numpy as np

from glraster import validate
from glraster.diff.address import address

__all__ = ["declared", "finite_array", "made", "raster", "vouched"]

# key -> (owner ref, T): rasters made from T triangles; at most LIMIT live ones
_made: dict = {}
# key -> owner ref: declared arrays that passed validate.finite_array; at most LIMIT live
_finite: dict = {}
LIMIT = 64
_local = threading.local()


def produced(array: np.ndarray | None, uploads, name: str) -> None:
    """A core read ``array`` (its output) back whole from its buffer ``name`` of the
    upload cache ``uploads`` (``UploadCache.produced``); the next :func:`made` of this
    thread for the array hands the array's key there (only the last such array of a
    thread is kept). None: the buffer holds no such array (the last one is dropped)."""
    if array is None:
        _local.produced = None
        uploads.forget(name)
        return
    region = (address(array), array.nbytes)
    uploads.produced(name, region)
    _local.produced = (region, weakref.ref(uploads))


def made(entry, triangles: int) -> None:
    """``entry``'s array is a raster whose ids index ``triangles`` triangles (as made)."""
    if entry is None:
        return
    pending = getattr(_local, "produced", None)
    if pending is not None and pending[0] == entry[0]:
        _local.produced = None
        uploads = pending[1]()
        if uploads is not None:
            uploads.adopt(entry)
    _make_room(_made, lambda value: value[0])
    _made[entry[1]] = (entry[2], int(triangles))


def _make_room(table: dict, owner_of) -> None:
    """Drop the entries whose owner was collected (all of them if none was) once full."""
    if len(table) >= LIMIT:
        for key in [k for k, v in table.items() if owner_of(v)() is None] or list(table):
            del table[key]


class declared:  # (lower case: used as a function, ``with declared(entries):``)
    """Within the block (this thread), the arrays of ``entries`` are known by their key (a
    plain context manager: a generator-based one costs 3.5 us a call, run per op call)."""

    __slots__ = ("_regions", "_previous")

    def __init__(self, entries):
        self._regions = {e[0]: (e[1], e[2]) for e in entries if e is not None}

    def __enter__(self):
        self._previous = getattr(_local, "regions", None)
        _local.regions = self._regions

    def __exit__(self, *_):
        _local.regions = self._previous


def _made_from(rast: np.ndarray) -> int | None:
    """The triangle count of the declared raster ``rast`` was made from, or None when it
    is none (not declared, not made, or its owner collected)."""
    regions = getattr(_local, "regions", None)
    if not regions or not rast.flags.c_contiguous or not rast.nbytes:
        return None
    key, _ = regions.get((address(rast), rast.nbytes), (None, None))
    got = _made.get(key)
    return got[1] if got is not None and got[0]() is not None else None


def vouched(rast: np.ndarray, triangles: int) -> bool:
    """True when ``rast`` is a declared raster made from at most ``triangles`` triangles
    (so every id indexes one of them): its ids need no decoding."""
    made_from = _made_from(rast)
    return made_from is not None and made_from <= triangles


def raster(value, dtype) -> np.ndarray:
    """``rast`` as :func:`glraster.validate.image` checks it (a finite (B, H, W, 4) array of
    ``dtype``), the finiteness test skipped when ``value`` is a declared raster made by
    rasterize (:func:`made`) of that dtype, unchanged since: finite as made."""
    if (isinstance(value, np.ndarray) and value.dtype == dtype
            and _made_from(value) is not None):
        return validate.image_shape("rast", value)
    return validate.image("rast", value, dtype=dtype)


def finite_array(name: str, value, dtype) -> np.ndarray:
    """:func:`glraster.validate.finite_array`, its finiteness test skipped when ``value`` is
    a declared C-contiguous ``dtype`` array that passed it under the same key (unchanged
    since, by the front end's version counter): as every finiteness test now is."""
    return validate.finite_array(name, value, dtype)


def _seen(arr: np.ndarray):
    """True when ``arr`` is declared under a key it passed the finiteness test with (the
    same memory, version, shape and dtype; the owner alive); else ``(key, owner)`` of its
    declaration, or None when it is not declared (:func:`validate._remember_finite`)."""
    regions = getattr(_local, "regions", None)
    if not regions or not arr.nbytes or not arr.flags.c_contiguous:
        return None
    declared_as = regions.get((address(arr), arr.nbytes))
    if declared_as is None:
        return None
    owner = _finite.get(declared_as[0])
    return True if owner is not None and owner() is not None else declared_as


def _passed(declared_as) -> None:
    _make_room(_finite, lambda owner: owner)
    _finite[declared_as[0]] = declared_as[1]


validate._remember_finite(_seen, _passed)
