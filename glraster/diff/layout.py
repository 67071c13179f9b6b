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

Triangle ids: channel 3 of ``rast`` holds triangle index + 1 in the encoding of
:mod:`glraster.diff.ids`.
"""

from __future__ import annotations

import numpy as np

from glraster import validate
from glraster.diff.ids import decode_ids
from glraster.errors import ArgumentError


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
