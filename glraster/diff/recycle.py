"""Image-sized output arrays whose memory is used again once nobody holds them.

A fit makes the same image-sized arrays every iteration (antialias' output, interpolate's,
their gradients, the loss' difference). A new one costs more than its bytes: memory freed
by the last iteration has often gone back to the kernel (glibc returns a freed block this
large to it: ``mallopt(3)``, M_MMAP_THRESHOLD, M_TRIM_THRESHOLD), and every page of the
new array is then faulted in and zeroed again; at 8 x 256² x 3 floats that is about a
millisecond an array on a busy machine, several per fit iteration.

:func:`empty` hands out an array of this pool that no one else references any more (its
reference count: a NumPy view holds its base, a tensor from ``torch.from_numpy`` holds
the array), else a new one, kept for later. What it returns is as good as ``np.empty``'s:
its values are arbitrary and nothing else can see them, so a caller writes every element
before use, as with ``np.empty``. Each call returns a new view of the kept array (its
base): the view's life is the hand-out's, so that caches that know an array by a weak
reference to its owner (:mod:`glraster.gpu.uploads`, :mod:`glraster.diff.checked`) see
it end as they would a new array's. A few arrays per shape and dtype are kept (the rest are
ordinary arrays), and only arrays of :data:`MIN_BYTES` or more go through the pool.
"""

from __future__ import annotations

import math
import sys
import threading

import numpy as np

__all__ = ["MIN_BYTES", "empty"]

MIN_BYTES = 1 << 20     # smaller arrays: malloc keeps their memory anyway
PER_SHAPE = 4           # arrays kept per (shape, dtype)
SHAPES = 16             # (shape, dtype) kinds kept; the least recently asked for goes

_pool: dict = {}        # (shape, dtype) -> [arrays], most recently used kind last
_lock = threading.Lock()


def _free_count() -> int:
    """The reference count :func:`empty`'s loop sees for a kept array nobody else holds
    (the list's, the loop variable's and getrefcount's argument on CPython 3.11; measured
    here the same way, so that an interpreter counting differently cannot make a held
    array look free)."""
    for array in [np.empty(1)]:
        return sys.getrefcount(array)


_FREE = _free_count()


def empty(shape, dtype=np.float32) -> np.ndarray:
    """A C-contiguous array of ``shape`` and ``dtype`` that nothing else references, its
    values arbitrary (as ``np.empty``'s)."""
    dtype = np.dtype(dtype)
    shape = tuple(map(int, shape)) if isinstance(shape, (tuple, list)) else (int(shape),)
    if math.prod(shape) * dtype.itemsize < MIN_BYTES:
        return np.empty(shape, dtype)
    key = (shape, dtype.str)
    with _lock:
        arrays = _pool.pop(key, None)
        if arrays is None:
            arrays = []
            while len(_pool) >= SHAPES:
                del _pool[next(iter(_pool))]
        _pool[key] = arrays
        for array in arrays:
            if sys.getrefcount(array) == _FREE:
                return array.view()
        array = np.empty(shape, dtype)
        if len(arrays) < PER_SHAPE:
            arrays.append(array)
        return array.view()
