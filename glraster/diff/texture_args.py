"""The texture op's arguments and saved state, shared by its two cores (NumPy only, no GL):
the modes, the mip pyramid's level shapes, the argument checks (:func:`check`, run once at
the boundary by :data:`glraster.diff.ops.TEXTURE`), the checked-argument record
:class:`TextureArgs` the cores rebuild from checked arrays without checking again, and
:class:`TextureSaved`, what both cores' ``forward`` hands their ``backward``.

Layouts (nvdiffrast's documented ones; B the batch, H x W the image, rows [y, x]):

    tex            (Bt, Ht, Wt, C)        2-D texture, Bt = 1 (broadcast) or B;
                   (Bt, 6, N, N, C)       cube map (boundary_mode="cube"), faces +x, -x,
                                          +y, -y, +z, -z
    uv             (B, H, W, 2)           (s, t): texel (i, j) = tex[b, j, i] has its centre
                                          at ((i + 0.5) / Wt, (j + 0.5) / Ht);
                   (B, H, W, 3)           cube: a direction (x, y, z), any length > 0
    uv_da          (B, H, W, 4)           (ds/dX, ds/dY, dt/dX, dt/dY) per image pixel;
                   (B, H, W, 6)           cube: (dx/dX, dx/dY, dy/dX, dy/dY, dz/dX, dz/dY)
    mip_level_bias (B, H, W)              added to the level
    *mip           level 1, level 2, ...  each (Bt, Ht_k, Wt_k, C) (cube (Bt, 6, N_k, N_k, C))
    out            (B, H, W, C)
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass
from typing import Any

import numpy as np

from glraster import validate
from glraster.diff import checked
from glraster.errors import ArgumentError

__all__ = ["BOUNDARY_MODES", "FILTER_MODES", "MIP_MODES", "TextureArgs", "TextureSaved",
           "check", "level_shapes", "wanted"]

FILTER_MODES = ("auto", "nearest", "linear", "linear-mipmap-nearest", "linear-mipmap-linear")
BOUNDARY_MODES = ("wrap", "clamp", "zero", "cube")
MIP_MODES = ("linear-mipmap-nearest", "linear-mipmap-linear")
FILTER_CODE = {"nearest": 0, "linear": 1, "linear-mipmap-nearest": 2, "linear-mipmap-linear": 3}
BOUNDARY_CODE = {"wrap": 0, "clamp": 1, "zero": 2, "cube": 3}


def level_shapes(height: int, width: int, max_mip_level=None) -> list[tuple[int, int]]:
    """(H_k, W_k) of the base and every mip level: halved (floor, at least 1) down to 1 x 1,
    at most ``max_mip_level`` levels after the base (None: all)."""
    shapes = [(int(height), int(width))]
    while shapes[-1] != (1, 1) and (max_mip_level is None or len(shapes) <= max_mip_level):
        h, w = shapes[-1]
        shapes.append((max(1, h // 2), max(1, w // 2)))
    return shapes


@dataclass(frozen=True)
class TextureArgs:
    """Checked arguments of a texture call (arrays C-contiguous, of one float dtype).

    ``mip`` holds the given levels 1, 2, ... (all of them; the first ``levels - 1`` are
    read), or None; ``own_mips``: ``mip`` is tex's own pyramid built earlier, whose level
    gradients the backward pulls back into the base as for a pyramid built in the call
    (so the levels get none of their own); ``filter_mode`` is resolved ('auto' replaced);
    ``shapes`` lists (H_k, W_k) of every level read (base first)."""

    tex: np.ndarray
    uv: np.ndarray
    uv_da: np.ndarray | None
    bias: np.ndarray | None
    mip: tuple | None
    filter_mode: str
    boundary_mode: str
    shapes: tuple
    own_mips: bool = False

    @classmethod
    def of(cls, tex, uv, uv_da, bias, mip, filter_mode, boundary_mode, max_mip_level=None,
           own_mips=False) -> TextureArgs:
        """The record of already checked arrays (:func:`check`): resolves 'auto' and the
        level shapes, checks nothing."""
        if filter_mode == "auto":
            filter_mode = ("linear-mipmap-linear" if uv_da is not None or bias is not None
                           else "linear")
        height, width = tex.shape[-3], tex.shape[-2]
        mip = tuple(mip) if mip else None
        if filter_mode not in MIP_MODES:
            shapes = ((height, width),)
        elif mip is None:
            shapes = tuple(level_shapes(height, width, max_mip_level))
        else:
            used = len(mip) if max_mip_level is None else min(len(mip), int(max_mip_level))
            shapes = tuple(level_shapes(height, width)[:used + 1])
        return cls(tex, uv, uv_da, bias, mip, filter_mode, boundary_mode, shapes,
                   bool(own_mips) and mip is not None)

    @property
    def cube(self) -> bool:
        return self.boundary_mode == "cube"

    @property
    def levels(self) -> int:
        return len(self.shapes)

    @property
    def mipmapped(self) -> bool:
        return self.filter_mode in MIP_MODES

    @property
    def channels(self) -> int:
        return self.tex.shape[-1]

    @property
    def pulls_pyramid(self) -> bool:
        """Whether the levels below the base are tex's own (built in the call, or
        ``own_mips``): their gradients go back into the base through the box filter."""
        return self.levels > 1 and (self.mip is None or self.own_mips)

    @property
    def user_mips(self) -> tuple:
        """The given levels that get gradients of their own (a user's mip stack)."""
        return () if self.mip is None or self.own_mips else self.mip


@dataclass
class TextureSaved:
    """What a texture core's ``backward`` needs from its ``forward``, the same record from
    both cores: the checked arguments; ``levels``: every level read, base first (the
    float64 reference's; None on the GPU); ``ctx``: the GL context the GPU core ran on
    (None for the reference); ``uploaded``: the GPU core's mark of the levels it left in
    the context's levels buffer (its backward uploads and builds them again only when
    another texture call has replaced them since)."""

    args: TextureArgs
    levels: list | None = None
    ctx: Any = None
    uploaded: Any = None


def wanted(needs, count: int) -> list[bool]:
    """The backward's ``needs`` (None: all) as one bool per input (``count`` of them:
    tex, uv, uv_da, mip_level_bias, then the mip levels)."""
    if needs is None:
        return [True] * count
    if len(needs) != count:
        raise ValueError(f"needs must have one flag per input ({count}), got {len(needs)}")
    return [bool(n) for n in needs]


def _mode(name: str, value, modes) -> str:
    if not isinstance(value, str) or value not in modes:
        raise ArgumentError(name, f"{name} must be one of {modes}, got {value!r}")
    return value


def _tex(tex, dtype, cube: bool) -> np.ndarray:
    arr = checked.finite_array("tex", tex, dtype)     # (skipped for an unchanged one)
    if cube:
        if arr.ndim != 5 or arr.shape[1] != 6 or arr.shape[2] != arr.shape[3]:
            raise ArgumentError("tex", "tex must have shape (B, 6, N, N, C) (a cube map of "
                                f"square faces) with boundary_mode='cube', got {arr.shape}")
    elif arr.ndim != 4:
        more = " (a 5-D tex is a cube map: pass boundary_mode='cube')" if arr.ndim == 5 else ""
        raise ArgumentError("tex", f"tex must have shape (B, Ht, Wt, C), got {arr.shape}{more}")
    if min(arr.shape) < 1:
        raise ArgumentError("tex", f"tex must have every extent >= 1, got shape {arr.shape}")
    return arr


def _uv(uv, dtype, cube: bool, tex_batch: int) -> np.ndarray:
    coords = 3 if cube else 2
    arr = validate.finite_array("uv", uv, dtype)
    if arr.ndim != 4 or arr.shape[-1] != coords:
        what = "a direction (x, y, z) per pixel with boundary_mode='cube'" if cube else "(s, t)"
        raise ArgumentError("uv", f"uv must have shape (B, H, W, {coords}) ({what}), got "
                            f"{arr.shape}")
    if min(arr.shape[:3]) < 1:
        raise ArgumentError("uv", f"uv must have B, H and W >= 1 (an image of at least one "
                                  f"pixel), got shape {arr.shape}")
    if tex_batch not in (1, arr.shape[0]):
        raise ArgumentError("tex", f"tex has a batch of {tex_batch}, uv of {arr.shape[0]}: "
                            "they must match (or tex's be 1)")
    return arr


def _mips(mip, tex: np.ndarray, dtype) -> tuple:
    height, width = tex.shape[-3], tex.shape[-2]
    full = level_shapes(height, width)
    if len(mip) > len(full) - 1:
        raise ArgumentError("mip", f"mip has {len(mip)} levels, more than the {len(full) - 1} "
                            f"a {height}x{width} texture has below its base")
    levels = []
    for k, value in enumerate(mip):
        name = f"mip[{k}]"
        level = checked.finite_array(name, value, dtype)
        h, w = full[k + 1]
        want = tex.shape[:-3] + (h, w, tex.shape[-1])
        if level.shape != want:
            raise ArgumentError("mip", f"{name} (mip level {k + 1}) must have shape {want}, "
                                f"got {level.shape}")
        levels.append(level)
    return tuple(levels)


def check(tex, uv, uv_da=None, mip_level_bias=None, *mip, filter_mode="auto",
          boundary_mode="wrap", max_mip_level=None, own_mips=False,
          dtype=np.float64) -> TextureArgs:
    """Every argument of a texture call checked (:class:`~glraster.errors.ArgumentError`
    naming it) and converted to ``dtype``; ``mip``: the levels 1, 2, ... (none: the
    pyramid is built), ``own_mips``: they are tex's own pyramid built earlier."""
    boundary_mode = _mode("boundary_mode", boundary_mode, BOUNDARY_MODES)
    filter_mode = _mode("filter_mode", filter_mode, FILTER_MODES)
    if max_mip_level is not None and (isinstance(max_mip_level, (bool, np.bool_)) or not
                                      isinstance(max_mip_level, numbers.Integral)
                                      or max_mip_level < 0):
        raise ArgumentError("max_mip_level", "max_mip_level must be None or an integer >= 0, "
                            f"got {max_mip_level!r}")
    if not isinstance(own_mips, (bool, np.bool_)):
        raise ArgumentError("own_mips", f"own_mips must be True or False, got {own_mips!r}")
    cube = boundary_mode == "cube"
    tex_ = _tex(tex, dtype, cube)
    uv_ = _uv(uv, dtype, cube, tex_.shape[0])
    da = None
    if uv_da is not None:
        da = validate.finite_array("uv_da", uv_da, dtype)
        want = uv_.shape[:3] + (uv_.shape[-1] * 2,)
        if da.shape != want:
            raise ArgumentError("uv_da", f"uv_da must have shape {want} (uv's with the last "
                                f"axis twice as long), got {da.shape}")
    bias = None
    if mip_level_bias is not None:
        bias = validate.finite_array("mip_level_bias", mip_level_bias, dtype)
        if bias.shape != uv_.shape[:3]:
            raise ArgumentError("mip_level_bias", "mip_level_bias must have shape "
                                f"{uv_.shape[:3]} (B, H, W), got {bias.shape}")
    return TextureArgs.of(tex_, uv_, da, bias, _mips(mip, tex_, dtype), filter_mode,
                          boundary_mode, max_mip_level, bool(own_mips))
