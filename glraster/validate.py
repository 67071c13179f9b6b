"""Checking and converting user input once, with errors that name the argument."""

from __future__ import annotations

import math
import numbers

import numpy as np

from glraster.types import INTERPOLATIONS, OUTPUTS


def positions(pos) -> np.ndarray:
    """``pos`` as a C-contiguous (V, 4) float32 array of finite clip-space positions."""
    arr = np.asarray(pos)
    if arr.dtype == object or not (
        np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)
    ) or arr.dtype == np.bool_:
        raise ValueError(f"pos must hold real numbers (float or int), got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 4:
        raise ValueError(f"pos must have shape (V, 4), got {arr.shape}")
    with np.errstate(over="ignore"):
        out = np.ascontiguousarray(arr, dtype=np.float32)
    bad = ~np.isfinite(out)
    if bad.any():
        row = int(np.argwhere(bad)[0][0])
        what = "NaN or Inf" if not np.isfinite(arr[row]).all() else "values beyond float32 range"
        raise ValueError(f"pos must be finite, row {row} has {what}: {arr[row].tolist()}")
    return out


def triangles(tri, num_vertices: int, of: str = "pos") -> np.ndarray:
    """``tri`` as a C-contiguous (T, 3) int32 array of indices in [0, num_vertices), the
    rows of the array named ``of`` ("pos", or "attr" where tri indexes attributes)."""
    arr = np.asarray(tri)
    if arr.size == 0 and arr.ndim <= 2 and (arr.ndim < 2 or arr.shape[-1] in (0, 3)):
        return np.zeros((0, 3), np.int32)
    if not np.issubdtype(arr.dtype, np.integer) or arr.dtype == np.bool_:
        raise ValueError(f"tri must have an integer dtype, got {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"tri must have shape (T, 3), got {arr.shape}")
    low, high = int(arr.min()), int(arr.max())
    if low < 0:
        raise ValueError(f"tri must hold indices >= 0, got {low}")
    if high >= num_vertices:
        raise ValueError(f"tri index {high} is out of range for {of} with {num_vertices} "
                         f"{'vertices' if of == 'pos' else 'rows (vertices)'}")
    return np.ascontiguousarray(arr, dtype=np.int32)


def resolution(res, max_size: int | None = None) -> tuple[int, int]:
    """``res`` as (height, width) python ints, each in [1, max_size]."""
    try:
        height, width = res
    except (TypeError, ValueError):
        raise ValueError(f"resolution must be (height, width), got {res!r}") from None
    for name, value in (("height", height), ("width", width)):
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
            raise ValueError(f"resolution {name} must be an integer, got {value!r}")
        if value <= 0:
            raise ValueError(f"resolution {name} must be > 0, got {value}")
        if max_size is not None and value > max_size:
            raise ValueError(
                f"resolution {name} {value} exceeds the driver's maximum of {max_size}"
            )
    return int(height), int(width)


def outputs(names) -> tuple[str, ...]:
    """``names`` as a tuple of output names in canonical order, at least one."""
    if isinstance(names, str):
        names = (names,)
    try:
        names = tuple(names)
    except TypeError:
        raise ValueError(f"outputs must be a sequence of names from {OUTPUTS}, got {names!r}") from None
    unknown = [n for n in names if n not in OUTPUTS]
    if unknown:
        raise ValueError(f"outputs has unknown names {unknown}; choose from {OUTPUTS}")
    if not names:
        raise ValueError(f"outputs must name at least one of {OUTPUTS}")
    return tuple(n for n in OUTPUTS if n in names)


def real(name: str, value, *, positive: bool = False) -> float:
    """``value`` as a finite float (> 0 with ``positive``), or ValueError naming ``name``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {v}")
    if positive and v <= 0:
        raise ValueError(f"{name} must be > 0, got {v}")
    return v


def positive_int(name: str, value) -> int:
    """``value`` as a python int > 0 (not a bool), or ValueError naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    if value <= 0:
        raise ValueError(f"{name} must be a positive integer, got {value}")
    return int(value)


def float_array(name: str, value, shape: tuple) -> np.ndarray:
    """float64 copy of ``value`` with ``shape`` (-1 = any length), finite, or ValueError."""
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a numeric array of shape {_fmt(shape)}") from None
    if a.ndim != len(shape) or any(s != -1 and s != d for s, d in zip(shape, a.shape)):
        raise ValueError(f"{name} must have shape {_fmt(shape)}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite")
    return a


def _fmt(shape: tuple) -> str:
    names = iter("NM")
    return "(" + ", ".join(next(names) if s == -1 else str(s) for s in shape) + ")"


def matrix4(name: str, value) -> np.ndarray:
    """A finite (4, 4) float64 matrix; None is the identity."""
    if value is None:
        return np.eye(4)
    return float_array(name, value, (4, 4))


def intrinsics(K) -> np.ndarray:
    """An OpenCV pinhole matrix K (3, 3) float64: upper triangular, K[2, 2] = 1, fx, fy > 0."""
    K = float_array("K", K, (3, 3))
    if K[1, 0] != 0.0 or K[2, 0] != 0.0 or K[2, 1] != 0.0 or K[2, 2] != 1.0:
        raise ValueError(
            "K must be an upper-triangular pinhole matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]], "
            f"got rows {K.tolist()}")
    if K[0, 0] <= 0.0 or K[1, 1] <= 0.0:
        raise ValueError(f"K must have fx > 0 and fy > 0, got fx={K[0, 0]}, fy={K[1, 1]}")
    return K


def samples(value, offered: tuple | None = None, where: str = "") -> int:
    """``samples`` as a python int: a power of two >= 1, one of ``offered`` when given (the
    counts a driver offers, e.g. ``Context.sample_counts``; ``where`` names it)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1 \
            or value & (value - 1):
        raise ValueError(f"samples must be a power of two >= 1 (1, 2, 4, 8, ...), got {value!r}")
    value = int(value)
    if offered is not None and value not in offered:
        raise ValueError(f"samples={value} is not offered{where}: choose one of "
                         f"{tuple(offered)}")
    return value


def interpolation(value) -> str:
    """``interpolation`` as one of :data:`glraster.types.INTERPOLATIONS`."""
    if not isinstance(value, str) or value not in INTERPOLATIONS:
        raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, got {value!r}")
    return value


def sample_positions(value, count: int) -> np.ndarray:
    """``value`` as (count, 2) float64 offsets inside the pixel, each in [0, 1)."""
    array = np.asarray(value, dtype=np.float64) if value is not None else None
    if array is None or array.shape != (count, 2):
        raise ValueError(f"sample_positions must have shape ({count}, 2) (samples, (x, y)), "
                         f"got {None if array is None else array.shape}")
    if not (np.isfinite(array).all() and (array >= 0).all() and (array < 1).all()):
        raise ValueError("sample_positions must be offsets inside the pixel, each coordinate "
                         f"in [0, 1), got {array.tolist()}")
    return array
