"""8-bit PNG images: the one PNG writer of glraster, and the barycentric picture.

:func:`write_png` takes an (H, W, 3) or (H, W, 4) image in glraster orientation (row 0 at
the bottom, as every raster array) and writes it **upright** (file row 0 is the top row),
through OpenImageIO. Values are uint8, or floats in [0, 1] (clipped, rounded to the nearest
of 256 levels). Optional text metadata (``Title``, ``Description``, ``Software``, ...)
goes into PNG text chunks.

Writes are atomic: the image is written next to the target under a temporary name and
renamed over it, so a reader never sees a partial file and a failed write leaves none.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from glraster.errors import ArgumentError
from glraster.io.atomic import write_image

__all__ = ["EMPTY_RGB", "NONFINITE_RGB", "ORIENTATION", "bary_rgb", "to_uint8", "write_png"]

ORIENTATION = "upright: file row 0 is the top row (glraster array row H-1)"
EMPTY_RGB = (32, 32, 32)
NONFINITE_RGB = (255, 0, 255)


def to_uint8(img) -> np.ndarray:
    """uint8 as is; floats clipped to [0, 1] and rounded to 0..255 (NaN becomes 0)."""
    a = np.asarray(img)
    if a.dtype == np.uint8:
        return a
    if a.dtype == bool or not np.issubdtype(a.dtype, np.number):
        raise ArgumentError("image", f"image must be uint8 or float, got dtype {a.dtype}")
    if np.issubdtype(a.dtype, np.integer):
        raise ArgumentError(
            "image", f"integer images must be uint8 (0..255), got dtype {a.dtype}")
    a = np.nan_to_num(a.astype(np.float64), nan=0.0)
    return (np.clip(a, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def write_png(path, rgb, *, bottom_up: bool = True, metadata: dict | None = None) -> Path:
    """Write an (H, W, 3) RGB or (H, W, 4) RGBA image as an 8-bit PNG. Returns the path.

    bottom_up: the array has row 0 at the bottom (glraster orientation, the default); it
        is flipped so the file is upright. False: the array is already upright.
    metadata: str -> str text chunks (e.g. ``{"Title": ..., "Description": ...}``).
    The parent directory is created; the file is written atomically (always PNG,
    whatever the suffix).
    """
    import OpenImageIO as oiio

    img = to_uint8(rgb)
    if img.ndim != 3 or img.shape[2] not in (3, 4) or 0 in img.shape[:2]:
        raise ArgumentError(
            "image", f"image must have shape (H, W, 3) or (H, W, 4), got {img.shape}")
    img = np.ascontiguousarray(img[::-1] if bottom_up else img)
    h, w, c = img.shape
    spec = oiio.ImageSpec(w, h, c, oiio.UINT8)
    for key, value in (metadata or {}).items():
        spec.attribute(str(key), str(value))

    return write_image(path, spec, img, ".png")


def bary_rgb(bary, mask) -> np.ndarray:
    """(H, W, 3) uint8 picture of barycentrics: RGB = (b0, b1, b2) on covered pixels,
    ``EMPTY_RGB`` elsewhere (everywhere when ``bary`` is None), ``NONFINITE_RGB`` where a
    covered pixel holds NaN or Inf."""
    mask = np.asarray(mask, bool)
    rgb = np.empty(mask.shape + (3,), np.uint8)
    rgb[:] = EMPTY_RGB
    if bary is None:
        return rgb
    b = np.asarray(bary, dtype=np.float64)
    fin = np.isfinite(b).all(axis=2)
    ok = mask & fin
    rgb[ok] = (np.clip(b[ok], 0, 1) * 255 + 0.5).astype(np.uint8)
    rgb[mask & ~fin] = NONFINITE_RGB
    return rgb
