"""TEMPORARY: the current cores behind the one op signature of :mod:`glraster.diff.op`.

Each op's cores are being rewritten to have that signature natively; when one is, its
:class:`~glraster.diff.op.Op` in :mod:`glraster.diff.ops` points at the module itself and its
two adapters here are deleted. Nothing outside :mod:`glraster.diff.ops` may use this module.
"""

from __future__ import annotations

import numpy as np


def _wanted(needs, k: int) -> bool:
    return needs is None or bool(needs[k])


def _empty_db(rast: np.ndarray) -> np.ndarray:
    return np.zeros(rast.shape[:-1] + (0,), rast.dtype)


class _RasterizeGPU:
    @staticmethod
    def forward(pos, *, tri, resolution, ranges=None, grad_db=True, space="persp", ctx=None):
        from glraster.diff import rasterize

        rast, rast_db, saved = rasterize.forward(pos, tri, resolution, ctx=ctx, ranges=ranges,
                                                 grad_db=grad_db, space=space)
        return (rast, _empty_db(rast) if rast_db is None else rast_db), saved

    @staticmethod
    def backward(saved, grad_rast, grad_db, *, needs=None):
        from glraster.diff import backward_gpu

        if not _wanted(needs, 0):
            return (None,)
        rast = saved.rast
        if grad_rast is None:
            grad_rast = np.zeros(rast.shape, rast.dtype)
        if grad_db is not None and grad_db.shape[-1] == 0:
            grad_db = None
        return (backward_gpu.rasterize_backward(
            saved.pos, saved.tri, rast, grad_rast, grad_db, ctx=getattr(saved, "ctx", None),
            resolution=saved.resolution, space=saved.space),)


class _RasterizeReference:
    @staticmethod
    def forward(pos, *, tri, resolution, ranges=None, grad_db=True, space="persp", ctx=None):
        from glraster.diff import reference

        rast, rast_db, saved = reference.rasterize_forward(pos, tri, resolution, ranges=ranges,
                                                           space=space)
        return (rast, rast_db if grad_db else _empty_db(rast)), saved

    @staticmethod
    def backward(saved, grad_rast, grad_db, *, needs=None):
        from glraster.diff import reference

        if not _wanted(needs, 0):
            return (None,)
        if grad_rast is None:
            grad_rast = np.zeros(saved.tri_id.shape + (4,))
        if grad_db is not None and grad_db.shape[-1] == 0:
            grad_db = None
        return (reference.rasterize_backward(saved, grad_rast, grad_db),)


class _Interpolate:
    def __init__(self, gpu: bool):
        self.gpu = gpu

    def _cores(self):
        if self.gpu:
            from glraster.diff import interpolate

            return interpolate.forward, interpolate.backward
        from glraster.diff import reference

        return reference.interpolate_forward, reference.interpolate_backward

    def forward(self, attr, rast, rast_db=None, *, tri, diff_attrs=None, ctx=None):
        forward, _ = self._cores()
        kwargs = {"ctx": ctx} if self.gpu else {}
        out, out_da, saved = forward(attr, rast, tri, rast_db, diff_attrs, **kwargs)
        if out_da is None:
            out_da = np.zeros(out.shape[:-1] + (0,), out.dtype)
        return (out, out_da), saved

    def backward(self, saved, grad_out, grad_out_da, *, needs=None):
        _, backward = self._cores()
        rast = saved.rast
        if grad_out is None:
            grad_out = np.zeros(rast.shape[:3] + (saved.attr.shape[-1],), rast.dtype)
        if grad_out_da is not None and grad_out_da.shape[-1] == 0:
            grad_out_da = None
        grads = backward(saved, grad_out, grad_out_da)
        return tuple(g if _wanted(needs, k) else None for k, g in enumerate(grads))


RASTERIZE_GPU = _RasterizeGPU()
RASTERIZE_REFERENCE = _RasterizeReference()
INTERPOLATE_GPU = _Interpolate(gpu=True)
INTERPOLATE_REFERENCE = _Interpolate(gpu=False)


class _GPUPeeler:
    def __init__(self, pos, *, tri, resolution, ranges=None, grad_db=True, space="persp",
                 ctx=None):
        from glraster.diff import rasterize

        self._peeler = rasterize.DepthPeeler(pos, tri, resolution, ctx=ctx, ranges=ranges,
                                             grad_db=grad_db, space=space)

    def rasterize_next_layer(self):
        rast, rast_db, saved = self._peeler.rasterize_next_layer()
        return (rast, _empty_db(rast) if rast_db is None else rast_db), saved

    def release(self):
        self._peeler.release()


class _ReferencePeeler:
    def __init__(self, pos, *, tri, resolution, ranges=None, grad_db=True, space="persp",
                 ctx=None):
        self.pos, self.tri, self.resolution = pos, tri, resolution
        self.ranges, self.grad_db, self.space = ranges, grad_db, space
        self.layer = 0

    def rasterize_next_layer(self):
        from glraster.diff import reference

        self.layer += 1
        rast, rast_db = reference.depth_peel(self.pos, self.tri, self.resolution, self.layer,
                                             self.ranges, space=self.space)[-1]
        saved = reference.RasterizeSaved.from_rast(self.pos, self.tri, rast, space=self.space,
                                                   ranges=self.ranges)
        return (rast, rast_db if self.grad_db else _empty_db(rast)), saved

    def release(self):
        pass


def depth_peeler(pos, **params):
    return (_ReferencePeeler if pos.dtype == np.float64 else _GPUPeeler)(pos, **params)
