"""Checking and converting user input once, with errors that name the argument.

The one validator of glraster (NumPy only, the bottom layer): every check here raises
:class:`glraster.errors.ArgumentError`, a ValueError whose ``.argument`` names the argument
at fault and whose message starts with that name and says what was wrong. Front ends, the
service and the CLI read ``.argument``; the wording is for people.

Layouts (docs/differentiable.md, "Conventions"; B the batch size):

    pos      (V, 4) float32 for :func:`glraster.rasterize` (:func:`positions`);
             (V, 4) or (B, V, 4) for the differentiable ops (:func:`batched_positions`)
    tri      (T, 3) int indices into pos (or attr)
    ranges   (B, 2) int [first, count] rows (range mode: 2-D pos)
    images   (B, H, W, C): rast, rast_db, gradients (:func:`image`)
    attr     (V, A) or (B, V, A), a batch of 1 broadcasting (:func:`attributes`)
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from glraster.errors import ArgumentError
from glraster.types import INTERPOLATIONS, OUTPUTS

# The barycentric spaces: perspective-correct (smooth) and window space (noperspective).
SPACES = ("persp", "screen")
# dtype kinds (numpy.dtype.kind) of integers (signed, unsigned) and of real numbers
INTEGER_KINDS, REAL_KINDS = "iu", "iuf"
# the unsigned integer dtype of each integer itemsize (bytes), for :func:`triangles`
_UNSIGNED = {size: np.dtype(f"u{size}") for size in (1, 2, 4, 8)}


# --------------------------------------------------------------------------- arrays


def real_array(name: str, value) -> np.ndarray:
    """``value`` as an array of real numbers (a float or int dtype; not bool, complex,
    object or text), without copying: convert it after the shape checks, then
    :func:`finite`."""
    arr = np.asarray(value)
    if arr.dtype.kind not in REAL_KINDS:
        raise ArgumentError(name, f"{name} must hold real numbers (float or int), "
                                  f"got dtype {arr.dtype}")
    return arr


# A memory of arrays known unchanged since they passed :func:`finite` (None: none), set by
# a higher layer through :func:`_remember_finite` (glraster.diff.checked).
_memory = None


def _remember_finite(seen, passed) -> None:  # (a hook, not a check: for glraster.diff.checked)
    """Let :func:`finite` skip its test of an array known unchanged since it passed it:
    ``seen(arr)`` is True for such an array, else a token (``arr`` known by a key, not yet
    passed) or None (``arr`` not known); ``passed(token)`` records that the array of the
    token passed. Only arrays tested unconverted ask (``out is arr``)."""
    global _memory
    _memory = (seen, passed)


def finite(name: str, arr: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out`` (``arr`` converted to a float dtype) when every value is finite; else an
    error naming ``name`` and the index of the first bad value, saying whether the input
    held NaN / Inf or a value beyond ``out``'s range (1e39 -> float32 is Inf). The test is
    skipped for an array the memory of :func:`_remember_finite` knows unchanged since it
    passed."""
    memory = _memory
    seen = memory[0](out) if memory is not None and out is arr else None
    if seen is True:
        return out
    if _all_finite(out):
        if seen is not None:
            memory[1](seen)
        return out
    where = tuple(int(i) for i in np.argwhere(~np.isfinite(out))[0])
    what = "NaN or Inf" if not np.isfinite(arr[where]) else f"a value beyond {out.dtype}"
    raise ArgumentError(name, f"{name} must be finite, got {what} at index {where}")


def _all_finite(out: np.ndarray) -> bool:
    """Every value of the float array ``out`` finite: one fused test (measured faster than
    testing a sum, which can also overflow, from 256 to 4.7M float32 values)."""
    return bool(np.isfinite(out).all())


def _converted(arr: np.ndarray, dtype) -> np.ndarray:
    if arr.dtype == dtype and arr.flags.c_contiguous and arr.ndim:
        return arr                          # as ascontiguousarray (errstate costs 2 us)
    with np.errstate(over="ignore"):        # beyond the dtype's range: Inf, reported by finite
        return np.ascontiguousarray(arr, dtype=dtype)


def finite_array(name: str, value, dtype=np.float64) -> np.ndarray:
    """``value`` (any shape) as a C-contiguous finite array of ``dtype``: real numbers, no
    NaN, Inf or value beyond ``dtype``."""
    arr = real_array(name, value)
    return finite(name, arr, _converted(arr, dtype))


def positions(pos) -> np.ndarray:
    """``pos`` as a C-contiguous (V, 4) float32 array of finite clip-space positions (the
    rasterizer's input: converted once, DESIGN Conventions)."""
    arr = real_array("pos", pos)
    if arr.ndim != 2 or arr.shape[1] != 4:
        raise ArgumentError("pos", f"pos must have shape (V, 4), got {arr.shape}")
    out = _converted(arr, np.float32)
    if not _all_finite(out):
        row = int(np.argwhere(~np.isfinite(out))[0][0])
        what = "NaN or Inf" if not np.isfinite(arr[row]).all() else "values beyond float32 range"
        raise ArgumentError("pos", f"pos must be finite, row {row} has {what}: "
                                   f"{arr[row].tolist()}")
    return out


def batched_positions(pos, dtype=np.float64) -> np.ndarray:
    """``pos`` (V, 4) or (B, V, 4) (3-D: instanced mode) as a C-contiguous finite array of
    ``dtype``, for the differentiable ops."""
    arr = real_array("pos", pos)
    if arr.ndim not in (2, 3) or arr.shape[-1] != 4:
        raise ArgumentError("pos", f"pos must have shape (V, 4) or (B, V, 4), got {arr.shape}")
    if arr.ndim == 3 and arr.shape[0] == 0:
        raise ArgumentError("pos", f"pos must have a batch of at least 1, got shape {arr.shape}")
    return finite("pos", arr, _converted(arr, dtype))


def triangles(tri, num_vertices: int, of: str = "pos") -> np.ndarray:
    """``tri`` as a C-contiguous (T, 3) int32 array of indices in [0, num_vertices), the
    rows of the array named ``of`` ("pos", or "attr" where tri indexes attributes)."""
    arr = np.asarray(tri)
    if arr.size == 0 and arr.ndim <= 2 and (arr.ndim < 2 or arr.shape[-1] in (0, 3)):
        return np.zeros((0, 3), np.int32)
    if arr.dtype.kind not in INTEGER_KINDS:
        raise ArgumentError("tri", f"tri must have an integer dtype, got {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ArgumentError("tri", f"tri must have shape (T, 3), got {arr.shape}")
    # One reduction where the unsigned view's max decides: a negative n-bit index reads as
    # 2^(n-1) or more (two's complement), so max < num_vertices <= 2^(n-1) means every
    # index is valid (native byte order only: a swapped one would read other values).
    size = arr.dtype.itemsize
    if arr.dtype.isnative and num_vertices <= 2 ** (8 * size - 1) \
            and int(arr.view(_UNSIGNED[size]).max()) < num_vertices:
        return np.ascontiguousarray(arr, dtype=np.int32)
    low, high = int(arr.min()), int(arr.max())
    if low < 0:
        raise ArgumentError("tri", f"tri must hold indices >= 0, got {low}")
    if high >= num_vertices:
        raise ArgumentError("tri", f"tri index {high} is out of range for {of} with "
                                   f"{num_vertices} "
                                   f"{'vertices' if of == 'pos' else 'rows (vertices)'}")
    return np.ascontiguousarray(arr, dtype=np.int32)


def ranges(value, num_triangles: int, pos_ndim: int) -> np.ndarray | None:
    """``ranges`` (B, 2) as int64 [first, count] rows, each inside the T triangles, or None.
    Range mode needs 2-D ``pos``."""
    if value is None:
        return None
    if pos_ndim != 2:
        raise ArgumentError("ranges", "ranges needs pos of shape (V, 4) (range mode); pos is "
                                      "3-D (instanced mode) and must come without ranges")
    arr = np.asarray(value)
    if arr.dtype.kind not in INTEGER_KINDS:
        raise ArgumentError("ranges", f"ranges must have an integer dtype, got {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] == 0:
        raise ArgumentError("ranges", f"ranges must have shape (B, 2) with B >= 1, "
                                      f"got {arr.shape}")
    arr = arr.astype(np.int64)
    first, count = arr[:, 0], arr[:, 1]
    for b in range(len(arr)):
        if first[b] < 0 or count[b] < 0:
            raise ArgumentError("ranges", f"ranges row {b} must have first >= 0 and count "
                                          f">= 0, got {arr[b].tolist()}")
        if first[b] + count[b] > num_triangles:
            raise ArgumentError("ranges", f"ranges row {b} = {arr[b].tolist()} reaches "
                                          f"triangle {first[b] + count[b] - 1}, beyond tri's "
                                          f"{num_triangles} triangles")
    return np.ascontiguousarray(arr)


def image(name: str, value, shape=None, dtype=np.float64, channels: int | None = 4) -> np.ndarray:
    """A finite (B, H, W, C) array (``rast``, ``rast_db``, a gradient) as ``dtype``.

    shape : the exact expected shape, or None for any (B, H, W, ``channels``)
    """
    arr = image_shape(name, value, shape, channels)
    return finite(name, arr, _converted(arr, dtype))


def image_shape(name: str, value, shape=None, channels: int | None = 4) -> np.ndarray:
    """``value`` as an array of real numbers with :func:`image`'s shape checks, neither
    converted nor tested for finiteness (for an array known finite)."""
    arr = real_array(name, value)
    if shape is not None:
        if arr.shape != tuple(shape):
            raise ArgumentError(name, f"{name} must have shape {tuple(shape)}, got {arr.shape}")
    elif arr.ndim != 4 or (channels is not None and arr.shape[-1] != channels):
        c = "C" if channels is None else channels
        raise ArgumentError(name, f"{name} must have shape (B, H, W, {c}), got {arr.shape}")
    elif min(arr.shape[:3]) < 1:
        raise ArgumentError(name, f"{name} must have B, H and W >= 1 (an image of at least "
                                  f"one pixel), got shape {arr.shape}")
    return arr


def triangle_ids(name: str, ids: np.ndarray, num_triangles: int) -> np.ndarray:
    """``ids`` (decoded triangle indices, -1 empty, any shape) when each is < T; the error
    names ``name``, the array the ids were read from (``rast``)."""
    if ids.size and ids.max() >= num_triangles:
        raise ArgumentError(name, f"{name} holds triangle id {int(ids.max()) + 1} (index "
                                  f"{int(ids.max())}), beyond tri's {num_triangles} triangles")
    return ids


def attributes(attr, batch: int, dtype=np.float64) -> np.ndarray:
    """``attr`` (V, A) or (B', V, A) with B' in (1, ``batch``) as a finite array."""
    arr = real_array("attr", attr)
    if arr.ndim not in (2, 3):
        raise ArgumentError("attr", f"attr must have shape (V, A) or (B, V, A), got {arr.shape}")
    if arr.ndim == 3 and arr.shape[0] not in (1, batch):
        raise ArgumentError("attr", f"attr has a batch of {arr.shape[0]}, rast of {batch}: "
                                    "they must match (or attr's be 1)")
    return finite("attr", arr, _converted(arr, dtype))


def float_array(name: str, value, shape: tuple) -> np.ndarray:
    """float64 copy of ``value`` with ``shape`` (-1 = any length), finite."""
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ArgumentError(name, f"{name} must be a numeric array of shape "
                                  f"{_fmt(shape)}") from None
    if a.ndim != len(shape) or any(s != -1 and s != d for s, d in zip(shape, a.shape)):
        raise ArgumentError(name, f"{name} must have shape {_fmt(shape)}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ArgumentError(name, f"{name} must be finite")
    return a


def _fmt(shape: tuple) -> str:
    """(3, N) style, as NumPy writes shapes ((3,) for one axis); -1 = any length."""
    names = iter("NM")
    parts = [next(names) if s == -1 else str(s) for s in shape]
    return "(" + ", ".join(parts) + ("," if len(parts) == 1 else "") + ")"


def matrix4(name: str, value) -> np.ndarray:
    """A finite (4, 4) float64 matrix; None is the identity."""
    if value is None:
        return np.eye(4)
    return float_array(name, value, (4, 4))


def intrinsics(K) -> np.ndarray:
    """An OpenCV pinhole matrix K (3, 3) float64: upper triangular, K[2, 2] = 1, fx, fy > 0."""
    K = float_array("K", K, (3, 3))
    if K[1, 0] != 0.0 or K[2, 0] != 0.0 or K[2, 1] != 0.0 or K[2, 2] != 1.0:
        raise ArgumentError(
            "K", "K must be an upper-triangular pinhole matrix [[fx, s, cx], [0, fy, cy], "
                 f"[0, 0, 1]], got rows {K.tolist()}")
    if K[0, 0] <= 0.0 or K[1, 1] <= 0.0:
        raise ArgumentError("K", f"K must have fx > 0 and fy > 0, got fx={K[0, 0]}, "
                                 f"fy={K[1, 1]}")
    return K


def sample_positions(value, count: int) -> np.ndarray:
    """``value`` as (count, 2) float64 offsets inside the pixel, each in [0, 1)."""
    array = np.asarray(value, dtype=np.float64) if value is not None else None
    if array is None or array.shape != (count, 2):
        raise ArgumentError("sample_positions",
                            f"sample_positions must have shape ({count}, 2) (samples, (x, y)), "
                            f"got {None if array is None else array.shape}")
    if not (np.isfinite(array).all() and (array >= 0).all() and (array < 1).all()):
        raise ArgumentError("sample_positions",
                            "sample_positions must be offsets inside the pixel, each "
                            f"coordinate in [0, 1), got {array.tolist()}")
    return array


# --------------------------------------------------------------------------- scalars and options


def resolution(res, max_size: int | None = None) -> tuple[int, int]:
    """``res`` as (height, width) python ints, each in [1, max_size]."""
    try:
        height, width = res
    except (TypeError, ValueError):
        raise ArgumentError("resolution", f"resolution must be (height, width), "
                                          f"got {res!r}") from None
    for name, value in (("height", height), ("width", width)):
        if type(value) is not int and (isinstance(value, (bool, np.bool_))  # (int: fast)
                                       or not isinstance(value, numbers.Integral)):
            raise ArgumentError("resolution", f"resolution {name} must be an integer, "
                                              f"got {value!r}")
        if value <= 0:
            raise ArgumentError("resolution", f"resolution {name} must be > 0, got {value}")
        if max_size is not None and value > max_size:
            raise ArgumentError("resolution", f"resolution {name} {value} exceeds the "
                                              f"driver's maximum of {max_size}")
    return int(height), int(width)


def outputs(names) -> tuple[str, ...]:
    """``names`` as a tuple of output names in canonical order, at least one."""
    if isinstance(names, str):
        names = (names,)
    try:
        names = tuple(names)
    except TypeError:
        raise ArgumentError("outputs", f"outputs must be a sequence of names from {OUTPUTS}, "
                                       f"got {names!r}") from None
    unknown = [n for n in names if n not in OUTPUTS]
    if unknown:
        raise ArgumentError("outputs", f"outputs has unknown names {unknown}; "
                                       f"choose from {OUTPUTS}")
    if not names:
        raise ArgumentError("outputs", f"outputs must name at least one of {OUTPUTS}")
    return tuple(n for n in OUTPUTS if n in names)


def choice(name: str, value, choices: tuple):
    """``value`` when it is one of ``choices`` (compared with ==; a container never is)."""
    if isinstance(value, (list, tuple, dict, set, np.ndarray)) or value not in choices:
        raise ArgumentError(name, f"{name} must be one of {choices}, got {value!r}")
    return value


def space(value) -> str:
    """The barycentric space: "persp" (perspective-correct) or "screen" (window space)."""
    return choice("space", value, SPACES)


def interpolation(value) -> str:
    """``interpolation`` as one of :data:`glraster.types.INTERPOLATIONS`."""
    return choice("interpolation", value, INTERPOLATIONS)


def real(name: str, value, *, positive: bool = False) -> float:
    """``value`` as a finite float (> 0 with ``positive``)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ArgumentError(name, f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(v):
        raise ArgumentError(name, f"{name} must be finite, got {v}")
    if positive and v <= 0:
        raise ArgumentError(name, f"{name} must be > 0, got {v}")
    return v


def positive_int(name: str, value) -> int:
    """``value`` as a python int > 0 (not a bool)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ArgumentError(name, f"{name} must be a positive integer, got {value!r}")
    if value <= 0:
        raise ArgumentError(name, f"{name} must be a positive integer, got {value}")
    return int(value)


def samples(value, offered: tuple | None = None, where: str = "") -> int:
    """``samples`` as a python int: a power of two >= 1, one of ``offered`` when given (the
    counts a driver offers, e.g. ``Context.sample_counts``; ``where`` names it)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1 \
            or value & (value - 1):
        raise ArgumentError("samples", f"samples must be a power of two >= 1 (1, 2, 4, 8, "
                                       f"...), got {value!r}")
    value = int(value)
    if offered is not None and value not in offered:
        raise ArgumentError("samples", f"samples={value} is not offered{where}: choose one of "
                                       f"{tuple(offered)}")
    return value


def diff_attrs(value, num_attrs: int) -> tuple[int, ...] | None:
    """``diff_attrs`` None | "all" | a sequence of attribute indices, as a tuple (or None)."""
    if value is None:
        return None
    bad = ArgumentError("diff_attrs", "diff_attrs must be None, 'all' or a list of attribute "
                                      f"indices, got {value!r}")
    if isinstance(value, str):
        if value != "all":
            raise bad
        return tuple(range(num_attrs))
    try:
        items = list(value)
    except TypeError:
        raise bad from None
    out = []
    for k in items:
        if isinstance(k, (bool, np.bool_)) or not isinstance(k, numbers.Integral):
            raise ArgumentError("diff_attrs", f"diff_attrs must hold integer attribute "
                                              f"indices, got {k!r}")
        if not 0 <= k < num_attrs:
            raise ArgumentError("diff_attrs", f"diff_attrs index {int(k)} is out of range for "
                                              f"attr with {num_attrs} attributes")
        out.append(int(k))
    return tuple(out)
