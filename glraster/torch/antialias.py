"""``antialias`` and ``antialias_construct_topology_hash`` with nvdiffrast's signatures.

One private :class:`torch.autograd.Function` around the cores of
:data:`glraster.diff.ops.ANTIALIAS`: float32 tensors run
:mod:`glraster.diff.antialias` (OpenGL compute shaders), float64 tensors the float64
reference :mod:`glraster.diff.antialias_reference` (so ``torch.autograd.gradcheck`` checks
the closed-form backward). Tensors live on the CPU.

Layouts (rows ``[y, x]`` with row 0 at the bottom): color (B, H, W, C); rast (B, H, W, 4)
from :func:`glraster.torch.rasterize`; pos (V, 4) or (B, V, 4), the positions rast was made
from; tri (T, 3) int32 or int64. Gradients go to ``color`` and ``pos`` (the two vertices of
each crossing silhouette edge, times ``pos_gradient_boost``); none to ``rast``.
docs/differentiable.md, "Antialias".
"""

from __future__ import annotations

import numpy as np
import torch
from torch.autograd.function import once_differentiable

from glraster.diff import topology_hash as _topology
from glraster.diff.ops import ANTIALIAS
from glraster.torch import _checks
from glraster.torch.context import RasterizeGLContext

__all__ = ["antialias", "antialias_construct_topology_hash"]


class _AntialiasFunction(torch.autograd.Function):
    @staticmethod
    def forward(fctx, color, pos, rast, checked):
        inputs, params = checked   # from ANTIALIAS.check
        dtype = inputs[0].dtype
        (out,), saved = ANTIALIAS.core(dtype).forward(*inputs, **params)
        fctx.save_for_backward(color, pos, rast)  # in-place changes are then refused
        fctx.saved, fctx.dtype = saved, dtype
        fctx.shapes = (inputs[0].shape, inputs[2].shape)
        fctx.set_materialize_grads(False)
        return _checks.to_torch(np.asarray(out, dtype))

    @staticmethod
    @once_differentiable
    def backward(fctx, grad_out):
        need_color, need_pos = fctx.needs_input_grad[:2]
        if grad_out is None or not (need_color or need_pos):
            return None, None, None, None
        fctx.saved_tensors  # raises if an input changed in place since the forward
        dtype = fctx.dtype
        g = _checks.numpy(grad_out).astype(dtype, copy=False)
        grad_color, _, grad_pos = ANTIALIAS.core(dtype).backward(
            fctx.saved, g, needs=(need_color, False, need_pos))
        color_shape, pos_shape = fctx.shapes
        return (_checks.to_torch(np.asarray(grad_color, dtype).reshape(color_shape))
                if need_color else None,
                _checks.to_torch(np.asarray(grad_pos, dtype).reshape(pos_shape))
                if need_pos else None,
                None, None)


def antialias_construct_topology_hash(tri, *, pos=None):
    """The topology hash of ``tri`` (nvdiffrast's ``antialias_construct_topology_hash``):
    build it once for triangles that do not change and pass it to :func:`antialias`.

    tri : torch.Tensor (T, 3), int32 (or int64), CPU
    pos : torch.Tensor (V, 3) or (V, 4), optional (glraster's addition, keyword-only):
        weld vertices with exactly equal positions, so that duplicated vertices (texture
        seams) do not make every edge a silhouette.

    Returns an opaque object (a :class:`glraster.diff.topology_hash.TopologyHash`).
    """
    _checks.tensor("tri", tri, _checks.INT_DTYPES)
    pos_np = None
    if pos is not None:
        _checks.tensor("pos", pos, _checks.FLOAT_DTYPES)
        pos_np = _checks.numpy(pos)
    return _topology.antialias_construct_topology_hash(_checks.numpy(tri), pos=pos_np)


def antialias(color, rast, pos, tri, topology_hash=None, pos_gradient_boost=1.0, *,
              glctx=None, convex=True):
    """Antialias an image across the mesh's silhouette edges (nvdiffrast's ``antialias``).

    Arguments
    ---------
    color : torch.Tensor (B, H, W, C), float32 or float64, CPU
        The shaded image (e.g. :func:`glraster.torch.interpolate`'s output).
    rast : torch.Tensor (B, H, W, 4), color's dtype
        :func:`glraster.torch.rasterize`'s first output, from ``pos`` and ``tri``.
    pos : torch.Tensor (V, 4) or (B, V, 4), color's dtype
        The clip-space positions rast was made from.
    tri : torch.Tensor (T, 3), int32 (or int64)
    topology_hash : from :func:`antialias_construct_topology_hash`, optional (built from
        ``tri`` when None)
    pos_gradient_boost : float
        Factor on the gradients sent to ``pos``.
    glctx : RasterizeGLContext, keyword-only, optional (glraster's addition)
        The context float32 tensors run on; None: glraster's default context.
    convex : bool, keyword-only (glraster's addition)
        Scale a pixel's blend weights to sum to 1 where they would sum past it, so that the
        output stays within the range of the inputs (False: the plain sum).

    Returns
    -------
    The antialiased image, (B, H, W, C) of color's dtype. Gradients go to ``color`` and
    ``pos``.
    """
    if glctx is not None and not isinstance(glctx, RasterizeGLContext):
        raise ValueError(f"glctx must be a RasterizeGLContext (or RasterizeCudaContext), got "
                         f"{type(glctx).__name__}")
    _checks.tensor("color", color, _checks.FLOAT_DTYPES)
    _checks.tensor("rast", rast, _checks.FLOAT_DTYPES)
    _checks.tensor("pos", pos, _checks.FLOAT_DTYPES)
    _checks.same_dtype("rast", rast, "color", color.dtype)
    _checks.same_dtype("pos", pos, "color", color.dtype)
    _checks.tensor("tri", tri, _checks.INT_DTYPES)
    checked = ANTIALIAS.check(
        _checks.numpy(color), _checks.numpy(rast), _checks.numpy(pos), tri=_checks.numpy(tri),
        topology_hash=topology_hash, pos_gradient_boost=pos_gradient_boost, convex=convex,
        ctx=None if glctx is None else glctx.context)
    return _AntialiasFunction.apply(color, pos, rast, checked)
