"""Array layouts shared by the differentiable ops: the triangle-id channel and the checks of
every argument (NumPy only; used by the float64 reference, the GPU ops and the adapters).

Layouts (docs/differentiable.md, "Conventions"). B is the batch size, always present:

    pos      (V, 4) or (B, V, 4)  clip-space positions; 3-D pos is instanced mode
    tri      (T, 3) int           vertex indices, shared by every batch
    ranges   (B, 2) int           range mode (pos 2-D): batch b draws triangles
                                  first_b .. first_b + count_b - 1 of ``tri``
    rast     (B, H, W, 4)         (u, v, z/w, id); id = the encoded triangle index + 1
    rast_db  (B, H, W, 4)         (du/dx, du/dy, dv/dx, dv/dy) in window pixels
    attr     (V, A) or (B, V, A)  vertex attributes (a batch of 1 broadcasts)

Rows are [y, x] with row 0 at the bottom (GL window coordinates).

Triangle ids: channel 3 of ``rast`` holds triangle index + 1 in the encoding of
:mod:`glraster.diff.ids` (re-exported here: :func:`encode_ids`, :func:`decode_ids`).
"""

from __future__ import annotations

import numbers

import numpy as np

from glraster import validate
from glraster.diff.ids import (  # noqa: F401  (re-exported)
    EXACT_FLOAT_IDS, ID_BIAS, MAX_ID, decode_ids, encode_ids)

SPACES = ("persp", "screen")


# --------------------------------------------------------------------------- argument checks


def real_array(name: str, value, dtype=None) -> np.ndarray:
    """``value`` as an array of real numbers (float or int), or ValueError naming ``name``."""
    arr = np.asarray(value)
    if arr.dtype == object or arr.dtype == np.bool_ or not (
        np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)
    ):
        raise ValueError(f"{name} must hold real numbers (float or int), got dtype {arr.dtype}")
    return arr


def _finite(name: str, arr: np.ndarray, out: np.ndarray) -> np.ndarray:
    bad = ~np.isfinite(out)
    if bad.any():
        where = tuple(int(i) for i in np.argwhere(bad)[0])
        what = "NaN or Inf" if not np.isfinite(arr[where]) else f"a value beyond {out.dtype}"
        raise ValueError(f"{name} must be finite, got {what} at index {where}")
    return out


def float_array(name: str, value, dtype=np.float64) -> np.ndarray:
    """``value`` (any shape) as a C-contiguous finite array of ``dtype``, or ValueError
    naming ``name`` (not real numbers; NaN, Inf or a value beyond ``dtype``)."""
    arr = real_array(name, value, dtype)
    with np.errstate(over="ignore"):
        out = np.ascontiguousarray(arr, dtype=dtype)
    return _finite(name, arr, out)


def positions(pos, dtype=np.float64) -> np.ndarray:
    """``pos`` (V, 4) or (B, V, 4) as a C-contiguous finite array of ``dtype``."""
    arr = real_array("pos", pos, dtype)
    if arr.ndim not in (2, 3) or arr.shape[-1] != 4:
        raise ValueError(f"pos must have shape (V, 4) or (B, V, 4), got {arr.shape}")
    if arr.ndim == 3 and arr.shape[0] == 0:
        raise ValueError(f"pos must have a batch of at least 1, got shape {arr.shape}")
    with np.errstate(over="ignore"):
        out = np.ascontiguousarray(arr, dtype=dtype)
    return _finite("pos", arr, out)


def triangles(tri, num_vertices: int, of: str = "pos") -> np.ndarray:
    """``tri`` (T, 3) as int32 indices in [0, num_vertices), rows of ``of`` ("pos" or
    "attr"; see :func:`validate.triangles`)."""
    return validate.triangles(tri, num_vertices, of)


def resolution(res) -> tuple[int, int]:
    """``res`` as (height, width) python ints > 0."""
    return validate.resolution(res)


def space(value) -> str:
    """The barycentric space: "persp" (perspective-correct) or "screen" (window space)."""
    if not isinstance(value, str) or value not in SPACES:
        raise ValueError(f"space must be one of {SPACES}, got {value!r}")
    return value


def ranges(value, num_triangles: int, pos_ndim: int) -> np.ndarray | None:
    """``ranges`` (B, 2) as int64 [first, count] rows, each inside the T triangles, or None.
    Range mode needs 2-D ``pos``."""
    if value is None:
        return None
    if pos_ndim != 2:
        raise ValueError("ranges needs pos of shape (V, 4) (range mode); pos is 3-D "
                         "(instanced mode) and must come without ranges")
    arr = np.asarray(value)
    if arr.dtype == np.bool_ or not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"ranges must have an integer dtype, got {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] == 0:
        raise ValueError(f"ranges must have shape (B, 2) with B >= 1, got {arr.shape}")
    arr = arr.astype(np.int64)
    first, count = arr[:, 0], arr[:, 1]
    for b in range(len(arr)):
        if first[b] < 0 or count[b] < 0:
            raise ValueError(f"ranges row {b} must have first >= 0 and count >= 0, "
                             f"got {arr[b].tolist()}")
        if first[b] + count[b] > num_triangles:
            raise ValueError(f"ranges row {b} = {arr[b].tolist()} reaches triangle "
                             f"{first[b] + count[b] - 1}, beyond tri's {num_triangles} triangles")
    return np.ascontiguousarray(arr)


def batch_size(pos: np.ndarray, ranges_: np.ndarray | None) -> int:
    """B: ranges' rows in range mode, pos' first axis when instanced, else 1."""
    if ranges_ is not None:
        return len(ranges_)
    return pos.shape[0] if pos.ndim == 3 else 1


def image(name: str, value, shape=None, dtype=np.float64, channels: int | None = 4) -> np.ndarray:
    """A finite (B, H, W, C) array (``rast``, ``rast_db``, a gradient) as ``dtype``.

    shape : the exact expected shape, or None for any (B, H, W, ``channels``)
    """
    arr = real_array(name, value, dtype)
    if shape is not None:
        if arr.shape != tuple(shape):
            raise ValueError(f"{name} must have shape {tuple(shape)}, got {arr.shape}")
    elif arr.ndim != 4 or (channels is not None and arr.shape[-1] != channels):
        c = "C" if channels is None else channels
        raise ValueError(f"{name} must have shape (B, H, W, {c}), got {arr.shape}")
    with np.errstate(over="ignore"):
        out = np.ascontiguousarray(arr, dtype=dtype)
    return _finite(name, arr, out)


def rast_ids(rast: np.ndarray, num_triangles: int) -> np.ndarray:
    """(B, H, W) int64 triangle indices (-1 empty) of ``rast``'s id channel, each < T."""
    ids = decode_ids(rast[..., 3], "rast channel 3 (triangle id)")
    if ids.size and ids.max() >= num_triangles:
        raise ValueError(f"rast holds triangle id {int(ids.max()) + 1} (index {int(ids.max())}), "
                         f"beyond tri's {num_triangles} triangles")
    return ids


def attributes(attr, batch: int, dtype=np.float64) -> np.ndarray:
    """``attr`` (V, A) or (B', V, A) with B' in (1, ``batch``) as a finite array."""
    arr = real_array("attr", attr, dtype)
    if arr.ndim not in (2, 3):
        raise ValueError(f"attr must have shape (V, A) or (B, V, A), got {arr.shape}")
    if arr.ndim == 3 and arr.shape[0] not in (1, batch):
        raise ValueError(f"attr has a batch of {arr.shape[0]}, rast of {batch}: they must "
                         "match (or attr's be 1)")
    with np.errstate(over="ignore"):
        out = np.ascontiguousarray(arr, dtype=dtype)
    return _finite("attr", arr, out)


def diff_attrs(value, num_attrs: int) -> tuple[int, ...] | None:
    """``diff_attrs`` None | "all" | a sequence of attribute indices, as a tuple (or None)."""
    if value is None:
        return None
    if isinstance(value, str):
        if value != "all":
            raise ValueError(f"diff_attrs must be None, 'all' or a list of attribute indices, "
                             f"got {value!r}")
        return tuple(range(num_attrs))
    try:
        items = list(value)
    except TypeError:
        raise ValueError(f"diff_attrs must be None, 'all' or a list of attribute indices, "
                         f"got {value!r}") from None
    out = []
    for k in items:
        if isinstance(k, (bool, np.bool_)) or not isinstance(k, numbers.Integral):
            raise ValueError(f"diff_attrs must hold integer attribute indices, got {k!r}")
        if not 0 <= k < num_attrs:
            raise ValueError(f"diff_attrs index {int(k)} is out of range for attr with "
                             f"{num_attrs} attributes")
        out.append(int(k))
    return tuple(out)


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
