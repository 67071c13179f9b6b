"""The antialias passes' work lists: neighbouring pixels whose triangle ids differ, and the
pixels of those pairs, in two compiled passes over the ids (numba; NumPy only otherwise).

Over B images of H x W pixels, row-major (pixel index p = (b H + y) W + x), a pair is a
pixel A and its right neighbour (axis 0, code 2 A) or the neighbour above (axis 1, code
2 A + 1) with a different id; pairs never wrap around a row or an image. The codes come
out sorted (A grows, and 2 A < 2 A + 1), and so do the listed pixels (the A and B of every
pair): the order the shaders' lists have always had, so their results do not change.
"""

from __future__ import annotations

import numpy as np

from glraster import jit
from glraster.diff import recycle

__all__ = ["pair_lists", "put_rows", "take_rows"]


def pair_lists(ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(codes, pixels) of the images ``ids`` (B, H, W), any real dtype and strides (only
    equality matters: decoded ids, or rast's encoded id channel ``rast[..., 3]`` as it
    is), both sorted uint32: codes 2 A + axis of the pairs, pixels the indices of every
    pixel in some pair."""
    if ids.ndim != 3:
        raise ValueError(f"ids must have shape (B, H, W), got {ids.shape}")
    if not ids.flags.c_contiguous:      # (rows the compares below vectorise over)
        ids = _copy(ids)
    n = ids.size
    padded = -(-n // 8) * 8             # whole 8-byte words for the scan
    pairs = _zeros(padded)
    listed = _zeros(padded)
    _marks(ids, pairs[:n].reshape(ids.shape), listed[:n].reshape(ids.shape))
    codes = recycle.empty(2 * n, np.uint32)
    pixels = recycle.empty(n, np.uint32)
    n_codes, n_pixels = _lists(pairs, listed, codes, pixels)
    return codes[:n_codes], pixels[:n_pixels]


def _copy(values: np.ndarray) -> np.ndarray:
    """A C-contiguous copy of ``values`` (:func:`glraster.diff.recycle.empty`'s memory)."""
    out = recycle.empty(values.shape, values.dtype)
    np.copyto(out, values)
    return out


def _zeros(n: int) -> np.ndarray:
    """(n,) uint8 zeros (:func:`glraster.diff.recycle.empty`'s memory)."""
    out = recycle.empty(n, np.uint8)
    out.fill(0)
    return out


def take_rows(values: np.ndarray, first: int, pixels: np.ndarray) -> np.ndarray:
    """(L, C) the rows of ``values`` (N, C) at pixels ``first + pixels`` (L,) uint32: a
    chunk's listed pixels (np.take: about 6 times faster than fancy indexing here)."""
    return np.take(values[first:], pixels, axis=0)


def put_rows(values: np.ndarray, first: int, pixels: np.ndarray, rows: np.ndarray) -> None:
    """``values[first + pixels[i]] = rows[i]``: (N, C) ``values`` written in place at a
    chunk's listed pixels (L,) uint32 from ``rows`` (L, C) (compiled: fancy assignment
    costs about 8 times as much)."""
    _put_rows(values[first:], pixels, rows)


_compiled = jit.njit(nogil=True)


@_compiled
def _put_rows(values, pixels, rows):
    for i in range(pixels.shape[0]):
        for c in range(rows.shape[1]):
            values[pixels[i], c] = rows[i, c]


@_compiled
def _marks(ids, pairs, listed):
    """Per pixel, pairs: bit 0 set when its right neighbour's id differs, bit 1 when the
    one above's does; listed: nonzero when the pixel is in some pair (its own, or the left
    neighbour's bit 0, or the lower neighbour's bit 1). Loops over whole rows without
    branches, so that they vectorise."""
    batch, height, width = ids.shape
    for b in range(batch):
        for y in range(height):
            row, marks = ids[b, y], pairs[b, y]
            for x in range(width - 1):
                marks[x] = np.uint8(row[x] != row[x + 1])
            if y + 1 < height:
                up = ids[b, y + 1]
                for x in range(width):
                    marks[x] |= np.uint8(row[x] != up[x]) << 1
        for y in range(height):
            marks, out = pairs[b, y], listed[b, y]
            out[0] = marks[0]
            for x in range(1, width):
                out[x] = marks[x] | (marks[x - 1] & 1)
            if y > 0:
                below = pairs[b, y - 1]
                for x in range(width):
                    out[x] |= below[x] & 2


@_compiled
def _lists(pairs, listed, codes, pixels):
    """Fill codes and pixels from the marks (flat, a whole number of 8-byte words: words
    without a mark, most of an image, are skipped whole); returns how many of each."""
    n_codes = 0
    n_pixels = 0
    pair_words, listed_words = pairs.view(np.uint64), listed.view(np.uint64)
    for k in range(pair_words.shape[0]):
        if pair_words[k] != 0:
            for p in range(8 * k, 8 * k + 8):
                if pairs[p] & 1:
                    codes[n_codes] = 2 * p
                    n_codes += 1
                if pairs[p] & 2:
                    codes[n_codes] = 2 * p + 1
                    n_codes += 1
        if listed_words[k] != 0:
            for p in range(8 * k, 8 * k + 8):
                if listed[p]:
                    pixels[n_pixels] = p
                    n_pixels += 1
    return n_codes, n_pixels
