"""``texture`` and ``texture_construct_mip`` with nvdiffrast's signatures and layouts, calls
of :mod:`glraster.torch.bridge` on :data:`glraster.diff.ops.TEXTURE`. Layouts (B batch):

    tex             (B or 1, Ht, Wt, C); cube map (B or 1, 6, N, N, C) with
                    boundary_mode="cube" (faces +x, -x, +y, -y, +z, -z)
    uv              (B, H, W, 2) (s, t): texel (i, j) = tex[b, j, i] is centred at
                    ((i + 0.5)/Wt, (j + 0.5)/Ht); cube (B, H, W, 3) directions
    uv_da           (B, H, W, 4) (ds/dX, ds/dY, dt/dX, dt/dY); cube (B, H, W, 6)
    mip_level_bias  (B, H, W), added to the level: 0.5 log2 of the largest eigenvalue of
                    J^T J (J: uv_da's Jacobian in texels)
    mip             levels 1, 2, ... (each half the previous, floor, >= 1) or a TextureMip
    out             (B, H, W, C), tex's dtype
"""

from __future__ import annotations

import functools
import logging
import threading
import weakref

import numpy as np
import torch

from glraster.diff.ops import TEXTURE
from glraster.torch import bridge

_log = logging.getLogger(__name__)


def _source_key(tex: torch.Tensor) -> tuple:
    """``tex``'s memory, view and version counter (bumped by every in-place change; an
    inference tensor has none: its key matches no other, its levels are made anew)."""
    return (tex.untyped_storage().data_ptr(), tex.storage_offset(), tuple(tex.shape),
            tuple(tex.stride()), tex.dtype, object() if tex.is_inference() else tex._version)


def _shapes(levels) -> str:
    return ", ".join("x".join(map(str, m.shape[-3:-1])) for m in levels) or "none"


class TextureMip:
    """A mip pyramid built once by :func:`texture_construct_mip`, for ``texture(..., mip=)``:
    used while its texture is unchanged (the same memory, no in-place change since), else
    rebuilt once with a warning (nvdiffrast would use stale levels). It is tex's own, so
    tex's gradient is as without ``mip``; :attr:`levels` get none of their own.

    levels : levels 1, 2, ... as tensors (B or 1, Ht_k, Wt_k, C) (cube: (B or 1, 6, N_k,
        N_k, C)), Ht_k = max(1, Ht_{k-1} // 2); max_mip_level, cube_mode: as built
    """

    def __init__(self, tex: torch.Tensor, max_mip_level, cube_mode: bool, glctx):
        self.max_mip_level, self.cube_mode, self._glctx = max_mip_level, cube_mode, glctx
        self._lock, self._key = threading.Lock(), None
        self.levels_for(tex)

    def levels_for(self, tex: torch.Tensor) -> list[torch.Tensor]:
        """:attr:`levels`, rebuilt first when ``tex`` is not the texture they were built
        from (a warning when they had been built already)."""
        from glraster.diff import texture as gpu, texture_reference as ref

        with self._lock, torch.no_grad():
            if _source_key(tex) == self._key:
                return self.levels
            if self._key is not None and not tex.is_inference():
                _log.warning("texture: mip= was built from another texture or before an "
                             "in-place change of this one: rebuilding it (call "
                             "texture_construct_mip again after changing the texture, or "
                             "pass mip=None for a texture that changes every call)")
            corner = torch.zeros(*tex.shape[:1], 1, 1, 2 + self.cube_mode, dtype=tex.dtype)
            call = bridge.Call(TEXTURE, (tex, corner), self._glctx, filter_mode="linear",
                               boundary_mode="cube" if self.cube_mode else "wrap",
                               max_mip_level=self.max_mip_level)
            base = call.arrays[0]  # checked, as every texture argument
            if base.dtype == np.float64:
                levels = ref.build_mips(base, ref.level_shapes(*base.shape[-3:-1],
                                                               self.max_mip_level))
            else:
                levels = gpu.build_mips(base, self.max_mip_level, ctx=call.params["ctx"],
                                        boundary_mode=call.params["boundary_mode"])
            self.levels = [bridge.to_torch(m, base.dtype) for m in levels]
            self._source = tex.detach()   # held, so that its memory is not reused by another
            self._key = _source_key(tex)
            _log.info("texture_construct_mip: %d levels below the %s base: %s", len(levels),
                      "x".join(map(str, tex.shape[-3:-1])), _shapes(levels))
            return self.levels

    def __repr__(self):
        return (f"TextureMip({len(self.levels)} levels [{_shapes(self.levels)}], "
                f"max_mip_level={self.max_mip_level}, cube_mode={self.cube_mode})")


@bridge.eager
def texture_construct_mip(tex, max_mip_level=None, cube_mode=False, *, glctx=None):
    """The mip pyramid of ``tex`` (the box filter ``texture`` builds) as a :class:`TextureMip`
    (nvdiffrast's ``texture_construct_mip``); float32 builds on ``glctx`` (glraster's)."""
    bridge.tensor("tex", tex)
    return TextureMip(tex, max_mip_level, bridge.flag("cube_mode", cube_mode), glctx)


_PYRAMIDS: dict[int, tuple] = {}  # mip=None, no grad: id(tex) -> (weakref(tex), TextureMip)
_PYRAMIDS_LOCK = threading.Lock()


def _pyramid(tex: torch.Tensor, max_mip_level, cube_mode: bool, glctx) -> list:
    """tex's levels, built once and reused while tex is unchanged (as TextureMip); the
    entry dies with tex (a weak reference), so no texture is held alive by it."""
    with _PYRAMIDS_LOCK:
        ref, mip = _PYRAMIDS.get(id(tex), (None, None))
        if (ref is None or ref() is not tex or mip._key != _source_key(tex)
                or (mip.max_mip_level, mip.cube_mode, mip._glctx) != (max_mip_level,
                                                                       cube_mode, glctx)):
            mip = TextureMip(tex, max_mip_level, cube_mode, glctx)
            forget = functools.partial(_forget, _PYRAMIDS, id(tex))
            _PYRAMIDS[id(tex)] = (weakref.ref(tex, forget), mip)
        return mip.levels


def _forget(pyramids: dict, key: int, ref) -> None:
    # no lock: the collector may run it inside _pyramid; no module global: it may run at
    # interpreter exit, after the module's globals are gone
    if pyramids.get(key, (None,))[0] is ref:
        pyramids.pop(key, None)


def _levels(tex, mip, uv_da, mip_level_bias, filter_mode, boundary_mode, max_mip_level,
            glctx):
    """(mip level tensors, own_mips) for the TEXTURE op from texture's ``mip``."""
    # "auto" is trilinear with uv_da or mip_level_bias (nvdiffrast); the others read the base
    mipmapped = (uv_da is not None or mip_level_bias is not None if filter_mode == "auto"
                 else "mipmap" in str(filter_mode))
    if (mip is None and mipmapped and type(max_mip_level) in (int, type(None))  # hashable
            and isinstance(tex, torch.Tensor) and not tex.requires_grad):
        return tuple(_pyramid(tex, max_mip_level, boundary_mode == "cube", glctx)), True
    if mip is None or isinstance(mip, (list, tuple)):
        return tuple(mip or ()), False
    if not isinstance(mip, TextureMip):
        raise bridge.ArgumentError("mip", "mip must be None, a TextureMip (texture_construct_"
                                   f"mip) or a list of levels, got {type(mip).__name__}")
    if mip.cube_mode != (boundary_mode == "cube"):
        need = "'cube'" if mip.cube_mode else "other than 'cube'"
        raise bridge.ArgumentError("mip", f"mip was built with cube_mode={mip.cube_mode}, "
                                   f"which needs boundary_mode {need}, got {boundary_mode!r}")
    bridge.tensor("tex", tex)
    if mip.levels and mip.levels[0].dtype != tex.dtype:
        raise bridge.ArgumentError("mip", f"mip was built from a {mip.levels[0].dtype} "
                                   f"texture, tex is {tex.dtype}: build it from tex")
    return (tuple(mip.levels_for(tex)) if mipmapped else ()), mipmapped


@bridge.eager
def texture(tex, uv, uv_da=None, mip_level_bias=None, mip=None, filter_mode="auto",
            boundary_mode="wrap", max_mip_level=None, *, glctx=None):
    """Filtered texture lookups (nvdiffrast's ``texture``): ``out`` (layouts above).

    mip: None (tex's pyramid; for a tex requiring no gradient built once and reused while
    that tensor is unchanged), a :class:`TextureMip` (its levels instead of building the
    pyramid, rebuilt if tex changed since; tex's gradient unchanged), or a list of levels 1, 2, ... (used instead
    of the built pyramid; each gets its own gradient, none goes through them to tex).
    filter_mode: "auto" (linear-mipmap-linear with uv_da or mip_level_bias, else linear),
    "nearest", "linear", "linear-mipmap-nearest" or "linear-mipmap-linear"; boundary_mode:
    "wrap", "clamp", "zero" or "cube"; max_mip_level: at most this many levels below the
    base (None: down to 1 x 1); glctx (glraster's addition): the context float32 runs on.
    Gradients go to tex (summed over the batch where it broadcasts), uv, uv_da and
    mip_level_bias (these two in linear-mipmap-linear only) and each tensor of a mip list.
    """
    levels, own = _levels(tex, mip, uv_da, mip_level_bias, filter_mode, boundary_mode,
                          max_mip_level, glctx)
    call = bridge.Call(TEXTURE, (tex, uv, uv_da, mip_level_bias, *levels), glctx,
                       filter_mode=filter_mode, boundary_mode=boundary_mode,
                       max_mip_level=max_mip_level, own_mips=own)
    return call()[0]
