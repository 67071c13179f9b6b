"""``texture`` with nvdiffrast's signature and layouts: one private autograd Function around
:mod:`glraster.diff.texture` (float32, OpenGL compute shaders) and
:mod:`glraster.diff.texture_reference` (float64, NumPy; for ``gradcheck``).

Layouts (B batch, H x W image):

    tex             (B or 1, Ht, Wt, C); cube map (B or 1, 6, N, N, C) with
                    boundary_mode="cube" (faces +x, -x, +y, -y, +z, -z)
    uv              (B, H, W, 2) (s, t): texel (i, j) = tex[b, j, i] is centred at
                    ((i + 0.5)/Wt, (j + 0.5)/Ht); cube (B, H, W, 3) directions
    uv_da           (B, H, W, 4) (ds/dX, ds/dY, dt/dX, dt/dY); cube (B, H, W, 6)
    mip_level_bias  (B, H, W)
    mip             list of tensors, levels 1, 2, ... (each half the previous, floor, >= 1)
    out             (B, H, W, C)
"""

from __future__ import annotations

import numpy as np
import torch
from torch.autograd.function import once_differentiable

from glraster.torch import _checks
from glraster.torch.context import RasterizeGLContext

__all__ = ["texture"]


def _reference():
    from glraster.diff import texture_reference

    return texture_reference


class _TextureFunction(torch.autograd.Function):
    @staticmethod
    def forward(fctx, op, tex, uv, uv_da, bias, *mip):
        dtype = _checks.numpy(tex).dtype
        arrays = [None if t is None else _checks.numpy(t) for t in (tex, uv, uv_da, bias)]
        mip_np = [_checks.numpy(m) for m in mip] if op["mip_given"] else None
        kwargs = dict(filter_mode=op["filter_mode"], boundary_mode=op["boundary_mode"],
                      max_mip_level=op["max_mip_level"])
        if dtype == np.float64:
            out, saved = _reference().forward(*arrays, mip_np, **kwargs)
        else:
            from glraster.diff import texture as gpu_texture

            glctx = op["glctx"]
            out, saved = gpu_texture.forward(*arrays, mip_np, **kwargs,
                                             ctx=None if glctx is None else glctx.context)
        fctx.save_for_backward(tex, uv, uv_da, bias, *mip)  # in-place changes are refused
        fctx.saved, fctx.dtype = saved, dtype
        fctx.set_materialize_grads(False)
        return _checks.to_torch(np.asarray(out, dtype))

    @staticmethod
    @once_differentiable
    def backward(fctx, grad_out):
        n_inputs = len(fctx.needs_input_grad)
        if grad_out is None or not any(fctx.needs_input_grad[1:]):
            return (None,) * n_inputs
        fctx.saved_tensors  # raises if an input changed in place since the forward
        dtype = fctx.dtype
        g = _checks.numpy(grad_out).astype(dtype, copy=False)
        if dtype == np.float64:
            grads = _reference().backward(fctx.saved, g)
        else:
            from glraster.diff import texture as gpu_texture

            grads = gpu_texture.backward(fctx.saved, g)
        grad_tex, grad_uv, grad_da, grad_bias, grad_mip = grads
        need = fctx.needs_input_grad

        def wrap(k, value):
            if not need[k] or value is None:
                return None
            return _checks.to_torch(np.asarray(value, dtype))

        out = [None, wrap(1, grad_tex), wrap(2, grad_uv), wrap(3, grad_da), wrap(4, grad_bias)]
        for k in range(5, n_inputs):
            out.append(wrap(k, None if grad_mip is None else grad_mip[k - 5]))
        return tuple(out)


def texture(tex, uv, uv_da=None, mip_level_bias=None, mip=None, filter_mode="auto",
            boundary_mode="wrap", max_mip_level=None, *, glctx=None):
    """Filtered texture lookups (nvdiffrast's ``texture``).

    Arguments
    ---------
    tex : torch.Tensor (B or 1, Ht, Wt, C), or (B or 1, 6, N, N, C) for a cube map;
        float32 (OpenGL) or float64 (the float64 reference), CPU
    uv : torch.Tensor (B, H, W, 2) texture coordinates (cube: (B, H, W, 3) directions)
    uv_da : torch.Tensor (B, H, W, 4) (cube: 6), optional
        Image-space derivatives of uv, (ds/dX, ds/dY, dt/dX, dt/dY): set the mip level,
        0.5 log2 of the largest eigenvalue of J^T J (J = the texel-space Jacobian).
    mip_level_bias : torch.Tensor (B, H, W), optional
        Added to the level (the level itself without uv_da).
    mip : list of torch.Tensor, optional
        The mip levels 1, 2, ... (instead of the built pyramid); each gets its gradient.
    filter_mode : "auto" | "nearest" | "linear" | "linear-mipmap-nearest" | "linear-mipmap-linear"
        "auto": linear-mipmap-linear with uv_da or mip_level_bias, else linear.
    boundary_mode : "wrap" | "clamp" | "zero" | "cube"
    max_mip_level : int, optional
        Use at most this many levels below the base (None: down to 1 x 1).
    glctx : RasterizeGLContext, keyword-only, optional (glraster's addition)
        The context float32 lookups run on; None: glraster's default context.

    Returns
    -------
    torch.Tensor (B, H, W, C): the filtered texture, tex's dtype. Gradients go to tex (a
    built pyramid's level gradients pulled back into the base; summed over the batch where
    tex broadcast), uv, uv_da and mip_level_bias (these two only in linear-mipmap-linear),
    and each tensor of ``mip``.
    """
    if glctx is not None and not isinstance(glctx, RasterizeGLContext):
        raise ValueError(f"glctx must be a RasterizeGLContext (or RasterizeCudaContext), got "
                         f"{type(glctx).__name__}")
    _checks.tensor("tex", tex, _checks.FLOAT_DTYPES)
    named = [("uv", uv), ("uv_da", uv_da), ("mip_level_bias", mip_level_bias)]
    if mip is not None:
        if isinstance(mip, torch.Tensor) or not isinstance(mip, (list, tuple)):
            raise ValueError(f"mip must be None or a list of tensors (mip levels 1, 2, ...), "
                             f"got {type(mip).__name__}")
        named += [(f"mip[{k}]", m) for k, m in enumerate(mip)]
    for name, value in named:
        if value is None:
            continue
        _checks.tensor(name, value, _checks.FLOAT_DTYPES)
        _checks.same_dtype(name, value, "tex", tex.dtype)
    dtype = np.float64 if tex.dtype == torch.float64 else np.float32
    # every shape and value check, before anything runs (ValueError naming the argument)
    _reference().check_arguments(
        _checks.numpy(tex), _checks.numpy(uv),
        None if uv_da is None else _checks.numpy(uv_da),
        None if mip_level_bias is None else _checks.numpy(mip_level_bias),
        None if mip is None else [_checks.numpy(m) for m in mip],
        filter_mode, boundary_mode, max_mip_level, dtype=dtype)
    op = {"filter_mode": filter_mode, "boundary_mode": boundary_mode,
          "max_mip_level": max_mip_level, "glctx": glctx, "mip_given": mip is not None}
    return _TextureFunction.apply(op, tex, uv, uv_da, mip_level_bias, *(mip or ()))
