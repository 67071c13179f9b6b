"""``texture`` with nvdiffrast's signature and layouts: one private autograd Function around
:data:`glraster.diff.ops.TEXTURE`'s cores: :mod:`glraster.diff.texture` (float32, OpenGL
compute shaders) and :mod:`glraster.diff.texture_reference` (float64, NumPy; for
``gradcheck``).

Layouts (B batch, H x W image):

    tex             (B or 1, Ht, Wt, C); cube map (B or 1, 6, N, N, C) with
                    boundary_mode="cube" (faces +x, -x, +y, -y, +z, -z)
    uv              (B, H, W, 2) (s, t): texel (i, j) = tex[b, j, i] is centred at
                    ((i + 0.5)/Wt, (j + 0.5)/Ht); cube (B, H, W, 3) directions
    uv_da           (B, H, W, 4) (ds/dX, ds/dY, dt/dX, dt/dY); cube (B, H, W, 6)
    mip_level_bias  (B, H, W)
    mip             list of tensors, levels 1, 2, ... (each half the previous, floor, >= 1),
                    or a :class:`TextureMip` from :func:`texture_construct_mip`
    out             (B, H, W, C)
"""

from __future__ import annotations

import logging
import threading

import numpy as np
import torch
from torch.autograd.function import once_differentiable

from glraster.torch import _checks
from glraster.torch.context import RasterizeGLContext

__all__ = ["TextureMip", "texture", "texture_construct_mip"]

_log = logging.getLogger(__name__)


def _source_key(tex: torch.Tensor) -> tuple:
    """What identifies ``tex``'s values while the tensor is alive: its memory, view and
    version counter (bumped by every in-place change, optimizer steps included)."""
    return (tex.untyped_storage().data_ptr(), tex.storage_offset(), tuple(tex.shape),
            tuple(tex.stride()), tex.dtype, tex._version)


class TextureMip:
    """A mip pyramid built once by :func:`texture_construct_mip`, for ``texture(..., mip=)``.

    While the texture it was built from is unchanged (the same tensor, or a view of the same
    memory, with no in-place change since), ``texture`` uses :attr:`levels` instead of
    building the pyramid; a changed texture (an optimizer step, another tensor) rebuilds them
    once, with a warning (nvdiffrast would use the stale levels). The pyramid is tex's own,
    so tex's gradient is the same as without ``mip`` (the levels' gradients are pulled back
    into it through the box filter); :attr:`levels` get none of their own.

    Attributes
    ----------
    levels : list of torch.Tensor
        Levels 1, 2, ...: (B or 1, Ht_k, Wt_k, C) (cube: (B or 1, 6, N_k, N_k, C)) with
        Ht_k = max(1, Ht_{k-1} // 2), tex's dtype, no grad; the base is tex itself.
    max_mip_level : int or None
        At most this many levels below the base (None: down to 1 x 1).
    cube_mode : bool
        True: built from a cube map (texture it with boundary_mode="cube").
    """

    def __init__(self, tex: torch.Tensor, max_mip_level, cube_mode: bool, glctx):
        self.max_mip_level = max_mip_level
        self.cube_mode = cube_mode
        self._glctx = glctx
        self._lock = threading.Lock()
        self._build(tex)

    def _build(self, tex: torch.Tensor) -> None:
        from glraster.diff import texture_args, texture_reference

        array = _checks.numpy(tex)
        boundary = "cube" if self.cube_mode else "wrap"
        if array.dtype == np.float64:
            shapes = texture_args.level_shapes(array.shape[-3], array.shape[-2],
                                               self.max_mip_level)
            texture_args.check(array, np.zeros((array.shape[0], 1, 1, 3 if self.cube_mode
                                                else 2)), boundary_mode=boundary)
            levels = texture_reference.build_mips(array, shapes)
        else:
            from glraster.diff import texture as gpu_texture

            ctx = None if self._glctx is None else self._glctx.context
            levels = gpu_texture.build_mips(array, self.max_mip_level, boundary_mode=boundary,
                                            ctx=ctx)
        self.levels = [_checks.to_torch(np.asarray(m, array.dtype)) for m in levels]
        self._source = tex.detach()   # held, so that its memory is not reused by another
        self._key = _source_key(tex)
        _log.info("texture_construct_mip: %d levels below the %s base: %s", len(levels),
                  "x".join(map(str, tex.shape[-3:-1])),
                  ", ".join("x".join(map(str, m.shape[-3:-1])) for m in levels) or "none")

    def levels_for(self, tex: torch.Tensor) -> list[torch.Tensor]:
        """:attr:`levels`, rebuilt first when ``tex`` is not the texture they were built
        from (with a warning)."""
        with self._lock:
            if _source_key(tex) != self._key:
                _log.warning("texture: mip= was built from another texture or before an "
                             "in-place change of this one: rebuilding it (call "
                             "texture_construct_mip again after changing the texture, or "
                             "pass mip=None for a texture that changes every call)")
                self._build(tex)
            return self.levels

    def __repr__(self):
        shapes = ", ".join("x".join(map(str, m.shape[-3:-1])) for m in self.levels)
        return (f"TextureMip({len(self.levels)} levels [{shapes}], "
                f"max_mip_level={self.max_mip_level}, cube_mode={self.cube_mode})")


def texture_construct_mip(tex, max_mip_level=None, cube_mode=False, *, glctx=None):
    """The mip pyramid of ``tex``, built once for ``texture(..., mip=)`` (nvdiffrast's
    ``texture_construct_mip``).

    Arguments
    ---------
    tex : torch.Tensor (B or 1, Ht, Wt, C), or (B or 1, 6, N, N, C) with cube_mode=True;
        float32 (built on OpenGL) or float64 (the float64 reference), CPU
    max_mip_level : int >= 0, optional
        Build at most this many levels below the base (None: down to 1 x 1).
    cube_mode : bool
        True when tex is a cube map.
    glctx : RasterizeGLContext, keyword-only, optional (glraster's addition)
        The context a float32 pyramid is built on; None: glraster's default context.

    Returns
    -------
    TextureMip: the levels 1, 2, ... as tensors (a box filter over each texel's footprint,
    the same as ``texture`` builds), reused by ``texture`` while tex is unchanged.
    """
    if glctx is not None and not isinstance(glctx, RasterizeGLContext):
        raise ValueError(f"glctx must be a RasterizeGLContext (or RasterizeCudaContext), got "
                         f"{type(glctx).__name__}")
    _checks.tensor("tex", tex, _checks.FLOAT_DTYPES)
    cube_mode = _checks.flag("cube_mode", cube_mode)
    if max_mip_level is not None and (isinstance(max_mip_level, (bool, np.bool_)) or not
                                      isinstance(max_mip_level, (int, np.integer))
                                      or max_mip_level < 0):
        raise ValueError(f"max_mip_level must be None or an integer >= 0, got {max_mip_level!r}")
    with torch.no_grad():
        return TextureMip(tex, None if max_mip_level is None else int(max_mip_level), cube_mode,
                          glctx)


class _TextureFunction(torch.autograd.Function):
    @staticmethod
    def forward(fctx, op, tex, uv, uv_da, bias, *mip):
        from glraster.diff.ops import TEXTURE

        dtype = _checks.numpy(tex).dtype
        arrays = [None if t is None else _checks.numpy(t) for t in (tex, uv, uv_da, bias)]
        mip_np = [_checks.numpy(m) for m in mip] if op["mip_given"] else list(op["own_mips"])
        glctx = op["glctx"]
        inputs, params = TEXTURE.check(
            *arrays, *mip_np, filter_mode=op["filter_mode"], boundary_mode=op["boundary_mode"],
            max_mip_level=op["max_mip_level"], own_mips=not op["mip_given"] and bool(mip_np),
            ctx=None if glctx is None else glctx.context)
        (out,), saved = TEXTURE.core(dtype).forward(*inputs, **params)
        fctx.save_for_backward(tex, uv, uv_da, bias, *mip)  # in-place changes are refused
        fctx.saved, fctx.dtype, fctx.core_inputs = saved, dtype, len(inputs)
        fctx.set_materialize_grads(False)
        return _checks.to_torch(np.asarray(out, dtype))

    @staticmethod
    @once_differentiable
    def backward(fctx, grad_out):
        from glraster.diff.ops import TEXTURE

        need = fctx.needs_input_grad
        n_inputs = len(need)
        if grad_out is None or not any(need[1:]):
            return (None,) * n_inputs
        fctx.saved_tensors  # raises if an input changed in place since the forward
        dtype = fctx.dtype
        g = _checks.numpy(grad_out).astype(dtype, copy=False)
        # core inputs: tex, uv, uv_da, bias, then the mip tensors (or own mips: no grads)
        needs = list(need[1:]) + [False] * (fctx.core_inputs - (n_inputs - 1))
        grads = TEXTURE.core(dtype).backward(fctx.saved, g, needs=tuple(needs))

        def wrap(k, value):
            if not need[k] or value is None:
                return None
            return _checks.to_torch(np.asarray(value, dtype))

        return (None, *(wrap(k + 1, grads[k]) for k in range(n_inputs - 1)))


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
    mip : TextureMip or list of torch.Tensor, optional
        A :class:`TextureMip` from :func:`texture_construct_mip`: its levels instead of
        building the pyramid (rebuilt if tex changed since); tex's gradient is unchanged.
        A list: the mip levels 1, 2, ... (instead of the built pyramid); each gets its own
        gradient and none goes through them to tex.
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
    built pyramid's or a TextureMip's level gradients pulled back into the base; summed
    over the batch where tex broadcast), uv, uv_da and mip_level_bias (these two only in
    linear-mipmap-linear), and each tensor of a ``mip`` list.
    """
    if glctx is not None and not isinstance(glctx, RasterizeGLContext):
        raise ValueError(f"glctx must be a RasterizeGLContext (or RasterizeCudaContext), got "
                         f"{type(glctx).__name__}")
    _checks.tensor("tex", tex, _checks.FLOAT_DTYPES)
    named = [("uv", uv), ("uv_da", uv_da), ("mip_level_bias", mip_level_bias)]
    own_mips = ()
    if isinstance(mip, TextureMip):
        if mip.cube_mode != (boundary_mode == "cube"):
            raise ValueError(f"mip was built with cube_mode={mip.cube_mode}, which needs "
                             f"boundary_mode {'' if mip.cube_mode else 'other than '}'cube', "
                             f"got boundary_mode={boundary_mode!r}")
        if mip.levels and mip.levels[0].dtype != tex.dtype:
            raise ValueError(f"mip was built from a {mip.levels[0].dtype} texture, tex is "
                             f"{tex.dtype}: build it from tex")
    elif mip is not None:
        if isinstance(mip, torch.Tensor) or not isinstance(mip, (list, tuple)):
            raise ValueError(f"mip must be None, a TextureMip (texture_construct_mip) or a "
                             f"list of tensors (mip levels 1, 2, ...), got {type(mip).__name__}")
        named += [(f"mip[{k}]", m) for k, m in enumerate(mip)]
    for name, value in named:
        if value is None:
            continue
        _checks.tensor(name, value, _checks.FLOAT_DTYPES)
        _checks.same_dtype(name, value, "tex", tex.dtype)
    if isinstance(mip, TextureMip):
        from glraster.diff.texture_args import MIP_MODES

        auto = ("linear-mipmap-linear" if uv_da is not None or mip_level_bias is not None
                else "linear")
        if (auto if filter_mode == "auto" else filter_mode) in MIP_MODES:
            # the other modes read the base only
            own_mips = tuple(_checks.numpy(m) for m in mip.levels_for(tex))
        mip = None
    op = {"filter_mode": filter_mode, "boundary_mode": boundary_mode,
          "max_mip_level": max_mip_level, "glctx": glctx, "mip_given": mip is not None,
          "own_mips": own_mips}
    return _TextureFunction.apply(op, tex, uv, uv_da, mip_level_bias, *(mip or ()))
