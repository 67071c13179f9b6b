"""The antialias passes' work lists: neighbouring pixels whose triangle ids differ, and the
pixels of those pairs, in one compiled pass over the ids (numba; NumPy only otherwise).

Over B images of H x W pixels, row-major (pixel index p = (b H + y) W + x), a pair is a
pixel A and its right neighbour (axis 0, code 2 A) or the neighbour above (axis 1, code
2 A + 1) with a different id; pairs never wrap around a row or an image. The codes come
out sorted (A grows, and 2 A < 2 A + 1), and so do the listed pixels (the A and B of every
pair): the order the shaders' lists have always had, so their results do not change.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["pair_lists"]


def pair_lists(ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(codes, pixels) of the images ``ids`` (B, H, W), any real dtype and strides (only
    equality matters: decoded ids, or rast's encoded id channel ``rast[..., 3]`` as it
    is), both sorted uint32: codes 2 A + axis of the pairs, pixels the indices of every
    pixel in some pair."""
    if ids.ndim != 3:
        raise ValueError(f"ids must have shape (B, H, W), got {ids.shape}")
    n = ids.size
    codes = np.empty(2 * n, np.uint32)
    pixels = np.empty(n, np.uint32)
    n_codes, n_pixels = _lists(ids, codes, pixels)
    return codes[:n_codes], pixels[:n_pixels]


@numba.njit(cache=True, nogil=True)
def _lists(ids, codes, pixels):
    """Fill codes and pixels; returns how many of each. A pixel is listed when it is the A
    of a pair (right or above) or the B of the pair of its left or lower neighbour."""
    batch, height, width = ids.shape
    n_codes = 0
    n_pixels = 0
    p = 0
    for b in range(batch):
        for y in range(height):
            for x in range(width):
                t = ids[b, y, x]
                listed = False
                if x + 1 < width and ids[b, y, x + 1] != t:
                    codes[n_codes] = 2 * p
                    n_codes += 1
                    listed = True
                if y + 1 < height and ids[b, y + 1, x] != t:
                    codes[n_codes] = 2 * p + 1
                    n_codes += 1
                    listed = True
                if not listed and x > 0 and ids[b, y, x - 1] != t:
                    listed = True
                if not listed and y > 0 and ids[b, y - 1, x] != t:
                    listed = True
                if listed:
                    pixels[n_pixels] = p
                    n_pixels += 1
                p += 1
    return n_codes, n_pixels
