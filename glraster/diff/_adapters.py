"""TEMPORARY: the current cores behind the one op signature of :mod:`glraster.diff.op`.

Each op's cores are being rewritten to have that signature natively; when one is, its
:class:`~glraster.diff.op.Op` in :mod:`glraster.diff.ops` points at the module itself and its
two adapters here are deleted. Nothing outside :mod:`glraster.diff.ops` may use this module.
"""

from __future__ import annotations

import numpy as np


def _wanted(needs, k: int) -> bool:
    return needs is None or bool(needs[k])


class _Texture:
    def __init__(self, gpu: bool):
        self.gpu = gpu

    def _core(self):
        if self.gpu:
            from glraster.diff import texture

            return texture
        from glraster.diff import texture_reference

        return texture_reference

    def forward(self, tex, uv, uv_da=None, mip_level_bias=None, *mip, filter_mode="auto",
                boundary_mode="wrap", max_mip_level=None, own_mips=False, ctx=None):
        from glraster.diff import texture_reference as ref

        levels = list(mip) if mip else None
        if levels is not None and own_mips:
            levels = ref.OwnMips(levels)
        kwargs = {"ctx": ctx} if self.gpu else {}
        out, saved = self._core().forward(tex, uv, uv_da, mip_level_bias, levels, filter_mode,
                                          boundary_mode, max_mip_level, **kwargs)
        return (out,), saved

    def backward(self, saved, grad_out, *, needs=None):
        args = saved.args
        if grad_out is None:
            grad_out = np.zeros(args.uv.shape[:3] + (args.channels,), args.tex.dtype)
        grad_tex, grad_uv, grad_da, grad_bias, grad_mip = self._core().backward(saved, grad_out)
        grads = (grad_tex, grad_uv, grad_da, grad_bias, *(grad_mip or ()))
        return tuple(g if _wanted(needs, k) else None for k, g in enumerate(grads))


class _Antialias:
    def __init__(self, gpu: bool):
        self.gpu = gpu

    def forward(self, color, rast, pos, *, tri, topology_hash=None, pos_gradient_boost=1.0,
                convex=True, ctx=None):
        if self.gpu:
            from glraster.diff import antialias

            out, saved = antialias.antialias(color, rast, pos, tri, topology_hash,
                                             pos_gradient_boost, ctx=ctx, convex=convex)
        else:
            from glraster.diff import antialias_reference

            out, saved = antialias_reference.antialias_forward(
                color, rast, pos, tri, topology_hash, pos_gradient_boost, convex=convex)
        return (out,), saved

    def backward(self, saved, grad_out, *, needs=None):
        if grad_out is None:
            grad_out = np.zeros(saved.color.shape, saved.color.dtype)
        if self.gpu:
            from glraster.diff import antialias

            grad_color, grad_pos = antialias.backward(saved, grad_out)
        else:
            from glraster.diff import antialias_reference

            grad_color, grad_pos = antialias_reference.antialias_backward(saved, grad_out)
        grads = (grad_color, None, grad_pos)
        return tuple(g if _wanted(needs, k) else None for k, g in enumerate(grads))


TEXTURE_GPU = _Texture(gpu=True)
TEXTURE_REFERENCE = _Texture(gpu=False)
ANTIALIAS_GPU = _Antialias(gpu=True)
ANTIALIAS_REFERENCE = _Antialias(gpu=False)
