"""Attribute interpolation in plain PyTorch (gather + autograd): the yardstick that
``glraster.studies.diff_bench`` (``glraster bench-diff``) times
:func:`glraster.torch.interpolate` against. It imports torch itself, on purpose (the
import contract allows exactly the studies written in torch).

The same mathematics as :func:`glraster.torch.interpolate` (and the same float32 operation
order as ``shaders/diff/interpolate.comp``, so the forward outputs are bit-identical): per
covered pixel of triangle ``t`` with ``rast = (u, v, z/w, id = t + 1)``::

    out   = u a0 + v a1 + (1 - u - v) a2,             a_j = attr[tri[t, j]]
    dA/dx = (a0 - a2) du/dx + (a1 - a2) dv/dx          (y: du/dy, dv/dy; rast_db's channels)

and zeros on empty pixels. It is written the way one would without a custom kernel:
decode the ids, gather the three vertex rows of every pixel with ``index_select``, evaluate
the formulas on whole images with torch's elementwise ops and let autograd produce the
backward (the gathers' backward is ``index_add_`` into ``attr``). Layouts and arguments are
those of :func:`glraster.torch.interpolate`; inputs are not validated (pass what
``glraster.torch.rasterize`` returned).
"""

from __future__ import annotations

import time

import torch

from glraster import validate

ID_FLOAT_MAX = 1 << 24          # ids up to here are stored as the float value itself
ID_BITS_OFFSET = 0x4A800000     # above: the float whose bit pattern is this + id


def decode_ids(id_channel: torch.Tensor) -> torch.Tensor:
    """Triangle index + 1 (0 = empty) from rast's channel 3, as int64 (nvdiffrast's encoding,
    :func:`glraster.diff.layout.decode_ids` + 1)."""
    f = id_channel.detach().contiguous()
    small = f.to(torch.int64)
    big = f.view(torch.int32).to(torch.int64) - ID_BITS_OFFSET
    return torch.where(f <= ID_FLOAT_MAX, small, big)


def interpolate(attr: torch.Tensor, rast: torch.Tensor, tri: torch.Tensor,
                rast_db: torch.Tensor | None = None, diff_attrs=None):
    """(out, out_da) as :func:`glraster.torch.interpolate`, in plain PyTorch.

    attr (V, A) or (B, V, A) (a batch of 1 broadcasts), rast (B, H, W, 4), tri (T, 3),
    rast_db (B, H, W, 4) with ``diff_attrs`` (None, "all" or a list of attribute indices).
    Returns out (B, H, W, A) and out_da (B, H, W, 2 D) = (dA_k/dx, dA_k/dy) per chosen k, or
    (B, H, W, 0) without ``diff_attrs``. Differentiable w.r.t. attr, rast and rast_db.
    """
    batch, height, width, _ = rast.shape
    num_attr = attr.shape[-1]
    flat_rast = rast.reshape(-1, 4)
    ids = decode_ids(flat_rast[:, 3])
    covered = ids > 0
    t = (ids - 1).clamp_min(0)
    corners = tri.to(torch.int64).index_select(0, t)           # (N, 3) vertex indices
    if attr.dim() == 3 and attr.shape[0] == batch and batch > 1:
        vertices = attr.shape[1]
        image = torch.arange(batch).repeat_interleave(height * width)
        corners = corners + (image * vertices)[:, None]
        table = attr.reshape(-1, num_attr)
    else:
        table = attr.reshape(-1, num_attr)                     # (V, A) or (1, V, A)
    gathered = table.index_select(0, corners.reshape(-1)).reshape(-1, 3, num_attr)
    a0, a1, a2 = gathered[:, 0], gathered[:, 1], gathered[:, 2]
    u, v = flat_rast[:, 0:1], flat_rast[:, 1:2]
    w = 1.0 - u - v
    keep = covered[:, None]
    zero = torch.zeros((), dtype=attr.dtype)
    out = torch.where(keep, u * a0 + v * a1 + w * a2, zero)
    out = out.reshape(batch, height, width, num_attr)
    selected = list(validate.diff_attrs(diff_attrs, num_attr) or ()) or None
    if selected is None:
        return out, out.new_zeros((batch, height, width, 0))
    index = torch.tensor(selected, dtype=torch.int64)
    s0, s1, s2 = (a.index_select(1, index) for a in (a0, a1, a2))
    d0, d1 = s0 - s2, s1 - s2
    db = rast_db.reshape(-1, 4)
    dx = d0 * db[:, 0:1] + d1 * db[:, 2:3]
    dy = d0 * db[:, 1:2] + d1 * db[:, 3:4]
    out_da = torch.where(keep[:, :, None], torch.stack((dx, dy), -1), zero)
    return out, out_da.reshape(batch, height, width, 2 * len(selected))


class ForwardBackward:
    """Forward + backward of an interpolate on fixed inputs, for timing and comparison
    (``glraster.studies.diff_bench`` runs torch only through here).

    The NumPy inputs become leaf tensors that all require grad (attr, rast, rast_db), so
    the backward produces every gradient, as in a rasterize -> interpolate chain;
    ``grad_out`` and ``grad_out_da`` are the upstream gradients. ``impls`` names the
    implementations: "glraster" (:func:`glraster.torch.interpolate` on ``glctx``) and
    "baseline" (:func:`interpolate` of this module).
    """

    def __init__(self, attr, rast, tri, rast_db, grad_out, grad_out_da, *,
                 diff_attrs="all", glctx=None):
        import glraster.torch as dr

        self.diff_attrs = diff_attrs
        self.tri = torch.from_numpy(tri)
        self.leaves = [torch.from_numpy(a.copy()).requires_grad_()
                       for a in (attr, rast, rast_db)]
        self.grads = (torch.from_numpy(grad_out), torch.from_numpy(grad_out_da))
        self.impls = {"glraster": lambda *a: dr.interpolate(*a, glctx=glctx),
                      "baseline": interpolate}

    def _run(self, which: str):
        for leaf in self.leaves:
            leaf.grad = None
        t0 = time.perf_counter()
        out, out_da = self.impls[which](self.leaves[0], self.leaves[1], self.tri,
                                        self.leaves[2], self.diff_attrs)
        t1 = time.perf_counter()
        torch.autograd.backward([out, out_da], list(self.grads))
        t2 = time.perf_counter()
        return out, out_da, {"forward": t1 - t0, "backward": t2 - t1}

    def __call__(self, which: str, threads: int | None = None) -> dict:
        """One forward + backward of ``which``: {"forward": s, "backward": s}. ``threads``:
        torch's intra-op thread count during the call (None: as set)."""
        if threads is None:
            return self._run(which)[2]
        before = torch.get_num_threads()
        torch.set_num_threads(threads)
        try:
            return self._run(which)[2]
        finally:
            torch.set_num_threads(before)

    def outputs(self, which: str) -> dict:
        """NumPy copies of out, out_da, grad_attr, grad_rast, grad_rast_db of ``which``."""
        out, out_da, _ = self._run(which)
        arrays = {"out": out, "out_da": out_da}
        arrays.update(zip(("grad_attr", "grad_rast", "grad_rast_db"),
                          (leaf.grad for leaf in self.leaves)))
        return {k: v.detach().numpy().copy() for k, v in arrays.items()}


def runtime() -> dict:
    """torch's version and intra-op thread count."""
    return {"torch": torch.__version__, "torch_threads": torch.get_num_threads()}
