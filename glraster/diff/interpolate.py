"""Attribute interpolation over a differentiable raster: forward and backward (NumPy API).

For a covered pixel of triangle ``t`` with ``rast = (u, v, z/w, t + 1)``::

    out = u a[tri[t, 0]] + v a[tri[t, 1]] + (1 - u - v) a[tri[t, 2]]

and, for the attributes chosen by ``diff_attrs``, their screen derivatives by the chain
rule through ``rast_db = (du/dx, du/dy, dv/dx, dv/dy)``::

    dA/dx = (a0 - a2) du/dx + (a1 - a2) dv/dx,   dA/dy = (a0 - a2) du/dy + (a1 - a2) dv/dy

Both passes run on the GPU (:mod:`glraster.diff.backward_gpu`); the float64 reference of
both is :mod:`glraster.diff.reference`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from glraster.diff import backward_gpu as _gpu
from glraster.diff import layout
from glraster.gpu.context import Context, default_context

__all__ = ["InterpolateSaved", "backward", "forward"]


@dataclass(frozen=True)
class InterpolateSaved:
    """What :func:`backward` needs from :func:`forward` (checked, float32 / int32 arrays).

    ``attr`` is (B or 1, V, A) with ``batched`` telling which the caller passed;
    ``diff_index`` the chosen attribute indices (empty: no derivatives);
    ``rast_db`` None when the forward had none.
    """

    attr: np.ndarray
    batched: bool
    rast: np.ndarray
    tri: np.ndarray
    rast_db: np.ndarray | None
    diff_index: tuple
    ctx: Context


def _columns(diff_index: tuple) -> tuple[tuple, list]:
    """The distinct chosen attributes (first-listed order) and, per listing, its place
    among them: the GPU derives each attribute once, repeats are copies."""
    unique = tuple(dict.fromkeys(diff_index))
    return unique, [unique.index(k) for k in diff_index]


def forward(attr, rast, tri, rast_db=None, diff_attrs=None, *, ctx: Context | None = None):
    """Interpolate per-vertex attributes over a raster, on the GPU.

    Args:
        attr: (V, A) or (B, V, A) per-vertex attributes (float32; other numbers converted).
        rast: (B, H, W, 4) float32 (u, v, z/w, triangle index + 1; 0 = empty), rows [y, x]
            with row 0 at the bottom.
        tri: (T, 3) integer vertex indices (the rasterized ones).
        rast_db: None or (B, H, W, 4) float32 (du/dx, du/dy, dv/dx, dv/dy) per window pixel;
            needed for ``diff_attrs``.
        diff_attrs: None, "all" or a list of attribute indices whose screen derivatives to
            return (in that order; a repeated index repeats its columns).
        ctx: the context (default: the process-wide one).

    Returns:
        ``(out, out_da, saved)``: out (B, H, W, A) float32; out_da (B, H, W, 2 D) float32 with
        (dA_k/dx, dA_k/dy) for the D chosen attributes in diff_attrs' order, or None when no
        attribute is chosen; saved an :class:`InterpolateSaved` for :func:`backward`.
        Empty pixels are 0 in both.
    """
    ctx = ctx or default_context()
    rast = layout.image("rast", rast, dtype=np.float32)
    attr3, batched = _gpu.check_vertices("attr", attr, None, rast.shape[0])
    tri = layout.triangles(tri, attr3.shape[1], "attr")
    diff_index = layout.diff_attrs(diff_attrs, attr3.shape[2]) or ()
    if rast_db is not None:
        rast_db = layout.image("rast_db", rast_db, rast.shape, np.float32)
    elif diff_index:
        raise ValueError("diff_attrs needs rast_db (the raster's screen derivatives)")
    unique, place = _columns(diff_index)
    out, out_da = _gpu.interpolate_forward(attr3, batched, rast, tri, rast_db, unique, ctx=ctx)
    if out_da is not None and len(unique) != len(diff_index):
        pairs = out_da.reshape(out_da.shape[:3] + (len(unique), 2))
        out_da = np.ascontiguousarray(pairs[..., place, :].reshape(out.shape[:3] + (-1,)))
    saved = InterpolateSaved(attr3, batched, rast, tri, rast_db, diff_index, ctx)
    return out, out_da, saved


def backward(saved: InterpolateSaved, grad_out, grad_out_da=None, *, deterministic: bool = False,
             accumulate: str | None = None):
    """Gradients of :func:`forward`, on the GPU.

    Args:
        saved: the third value :func:`forward` returned.
        grad_out: (B, H, W, A) dL/d out.
        grad_out_da: None or (B, H, W, 2 D) dL/d out_da (ignored when the forward had no
            chosen attribute; None counts as zero).
        deterministic: bit-identical grad_attr from run to run (per-pixel contributions
            summed per vertex in pixel order, in float64); otherwise float atomics.
        accumulate: force one of :data:`glraster.diff.backward_gpu.ACCUMULATIONS`.

    Returns:
        ``(grad_attr, grad_rast, grad_rast_db)``: grad_attr float32 of attr's shape (with
        (V, A) attr the batch is summed); grad_rast (B, H, W, 4) float32 (dL/du, dL/dv, 0, 0);
        grad_rast_db (B, H, W, 4) float32 dL/d(du/dx, du/dy, dv/dx, dv/dy), or None when there
        is no grad_out_da (or the forward had no chosen attribute), as the reference. Empty
        pixels are 0.
    """
    rast = saved.rast
    batch, height, width, _ = rast.shape
    num_attr = saved.attr.shape[2]
    grad_out = layout.image("grad_out", grad_out, dtype=np.float32, channels=None)
    if grad_out.shape != (batch, height, width, num_attr):
        raise ValueError(f"grad_out must have shape {(batch, height, width, num_attr)} "
                         f"(that of out), got {grad_out.shape}")
    n_diff = len(saved.diff_index)
    if n_diff and grad_out_da is not None:
        grad_out_da = layout.image("grad_out_da", grad_out_da, dtype=np.float32, channels=None)
        if grad_out_da.shape != (batch, height, width, 2 * n_diff):
            raise ValueError(f"grad_out_da must have shape {(batch, height, width, 2 * n_diff)}"
                             f" (that of out_da), got {grad_out_da.shape}")
    else:
        grad_out_da = None
    unique, place = _columns(saved.diff_index)
    if grad_out_da is not None and len(unique) != n_diff:
        pairs = grad_out_da.reshape(grad_out_da.shape[:3] + (n_diff, 2))
        folded = np.zeros(pairs.shape[:3] + (len(unique), 2), np.float32)
        for j, col in enumerate(place):
            folded[..., col, :] += pairs[..., j, :]
        grad_out_da = folded.reshape(pairs.shape[:3] + (-1,))
    grad_attr, grad_rast, grad_db = _gpu.interpolate_backward(
        saved.attr, saved.batched, rast, saved.tri, saved.rast_db, unique, grad_out,
        grad_out_da, ctx=saved.ctx, deterministic=deterministic, accumulate=accumulate)
    if not saved.batched:
        grad_attr = grad_attr[0]
    return grad_attr, grad_rast, grad_db
