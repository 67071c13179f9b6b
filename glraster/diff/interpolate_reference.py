"""The interpolate op's float64 reference core: forward and backward.

The core of :data:`glraster.diff.ops.INTERPOLATE` for float64 (the GPU one is
:mod:`glraster.diff.interpolate`, with the same signatures); inputs arrive checked by
:meth:`INTERPOLATE.check <glraster.diff.op.Op.check>`. NumPy only (no GL).

out = u a[tri_0] + v a[tri_1] + (1 - u - v) a[tri_2] on covered pixels (0 elsewhere), and
d out_k/dx = (a0_k - a2_k) du/dx + (a1_k - a2_k) dv/dx for the chosen ``diff_attrs``
(y likewise with du/dy, dv/dy).
"""

from __future__ import annotations

import numpy as np

from glraster.diff.rasterize_reference import scatter_rows
from glraster.diff.saved import InterpolateSaved

__all__ = ["InterpolateSaved", "backward", "forward"]


class _Covered:
    """The covered pixels of an interpolation: batch, py, px (N,), attribute batch ab (N,),
    vertex (N, 3) and their attributes a (N, 3, A); u, v (N, 1) their barycentrics."""

    def __init__(self, attr3: np.ndarray, rast: np.ndarray, tri_id: np.ndarray, tri):
        self.batch, self.py, self.px = np.nonzero(tri_id >= 0)
        t = tri_id[self.batch, self.py, self.px]
        self.ab = self.batch if attr3.shape[0] > 1 else np.zeros_like(self.batch)
        self.vertex = tri[t].astype(np.int64)
        self.a = attr3[self.ab[:, None], self.vertex]
        here = rast[self.batch, self.py, self.px]
        self.u, self.v = here[:, 0:1], here[:, 1:2]

    def at(self, img: np.ndarray) -> np.ndarray:
        """(N, C) values of a (B, H, W, C) image at the covered pixels."""
        return img[self.batch, self.py, self.px]

    def image(self, shape, values: np.ndarray) -> np.ndarray:
        """(N, C) values as a (B, H, W, C) image of ``shape``, 0 on empty pixels."""
        out = np.zeros(shape)
        out[self.batch, self.py, self.px] = values
        return out


def forward(attr, rast, rast_db=None, *, tri, diff_attrs=None, ctx=None):
    """Interpolate vertex attributes with the barycentrics of ``rast`` (float64).

    attr       : (V, A) or (B', V, A) float64 (a batch of 1 broadcasts over rast's B)
    rast       : (B, H, W, 4) float64, a rasterize output
    rast_db    : (B, H, W, 4) float64 or None; needed with ``diff_attrs``
    tri        : (T, 3) int32, the triangles rast's ids index
    diff_attrs : None or a tuple of attribute indices k (repeats repeat their columns)
    ctx        : ignored (the signature of the GPU core)

    Returns ``((out, out_da), saved)``:

    out    (B, H, W, A): u a[tri_0] + v a[tri_1] + (1 - u - v) a[tri_2], 0 on empty pixels
    out_da (B, H, W, 2 K): (dA_k/dx, dA_k/dy) per chosen attribute in the order given,
           dA/dx = (a0 - a2) du/dx + (a1 - a2) dv/dx (window pixels); (B, H, W, 0) when
           none is chosen
    saved  :class:`InterpolateSaved`
    """
    chosen = tuple(diff_attrs or ())
    saved = InterpolateSaved(attr=attr, rast=rast, tri=tri,
                             rast_db=rast_db if chosen else None, diff_attrs=chosen)
    px = _Covered(saved.attr_batches, rast, saved.tri_id, tri)
    a0, a1, a2 = px.a[:, 0], px.a[:, 1], px.a[:, 2]
    lead = rast.shape[:3]
    out = px.image(lead + (attr.shape[-1],), px.u * a0 + px.v * a1 + (1 - px.u - px.v) * a2)
    out_da = np.zeros(lead + (0,))
    if chosen:
        k = list(chosen)
        db = px.at(rast_db)
        d0, d1 = (a0 - a2)[:, k], (a1 - a2)[:, k]
        dx = d0 * db[:, 0:1] + d1 * db[:, 2:3]
        dy = d0 * db[:, 1:2] + d1 * db[:, 3:4]
        out_da = px.image(lead + (2 * len(k),), np.stack([dx, dy], -1).reshape(len(dx), -1))
    return (out, out_da), saved


def backward(saved: InterpolateSaved, grad_out=None, grad_out_da=None, *, needs=None):
    """Gradients of attr, rast and rast_db from those of out (and out_da).

    grad_out    : (B, H, W, A) or None (zero)
    grad_out_da : (B, H, W, 2 K) or None / (B, H, W, 0) (zero; unused without diff_attrs)
    needs       : None or (want_attr, want_rast, want_rast_db); unwanted ones are not
                  computed
    Returns (grad_attr, grad_rast, grad_rast_db):
    grad_attr    shape of attr (summed over the batch where attr broadcasts)
    grad_rast    (B, H, W, 4): channels u, v; z/w and id 0
    grad_rast_db (B, H, W, 4) (du/dx, du/dy, dv/dx, dv/dy), or None when there is no
                 grad_out_da (or the forward had no diff_attrs)
    Unwanted entries are None.
    """
    want_attr, want_rast, want_db = (True, True, True) if needs is None else needs
    rast, attr = saved.rast, saved.attr
    num_a = attr.shape[-1]
    if grad_out_da is not None and (grad_out_da.shape[-1] == 0 or not saved.diff_attrs):
        grad_out_da = None
    if grad_out is None:
        grad_out = np.zeros(rast.shape[:3] + (num_a,))
    px = _Covered(saved.attr_batches, rast, saved.tri_id, saved.tri)
    go = px.at(grad_out)                                        # (N, A)
    a0, a1, a2 = px.a[:, 0], px.a[:, 1], px.a[:, 2]
    grad_rast = grad_rast_db = grad_attr = None
    if want_rast:
        grad_rast = np.zeros(rast.shape)
        grad_rast[px.batch, px.py, px.px, 0] = (go * (a0 - a2)).sum(-1)
        grad_rast[px.batch, px.py, px.px, 1] = (go * (a1 - a2)).sum(-1)
    if want_attr:
        contrib = np.stack([px.u * go, px.v * go, (1 - px.u - px.v) * go], 1)  # (N, 3, A)
    if grad_out_da is not None and (want_attr or want_db):
        k = list(saved.diff_attrs)
        gda = px.at(grad_out_da).reshape(len(go), len(k), 2)
        gx, gy = gda[..., 0], gda[..., 1]
        if want_attr:
            pick = np.zeros((len(k), num_a))                    # chosen -> attribute (sums repeats)
            pick[np.arange(len(k)), k] = 1.0
            db = px.at(saved.rast_db)
            c0 = gx * db[:, 0:1] + gy * db[:, 1:2]              # dL/d a0_k
            c1 = gx * db[:, 2:3] + gy * db[:, 3:4]              # dL/d a1_k
            contrib[:, 0] += c0 @ pick
            contrib[:, 1] += c1 @ pick
            contrib[:, 2] -= (c0 + c1) @ pick
        if want_db:
            d0, d1 = (a0 - a2)[:, k], (a1 - a2)[:, k]
            grad_rast_db = px.image(rast.shape, np.stack(
                [(gx * d0).sum(-1), (gy * d0).sum(-1), (gx * d1).sum(-1), (gy * d1).sum(-1)],
                -1))
    if want_attr:
        attr3 = saved.attr_batches
        num_v = attr3.shape[1]
        index = (px.ab[:, None] * num_v + px.vertex).ravel()
        grad_attr = scatter_rows(index, contrib.reshape(-1, num_a), attr3.shape[0] * num_v
                                 ).reshape(attr.shape)
    return grad_attr, grad_rast, grad_rast_db
