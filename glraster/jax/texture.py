"""``texture`` and ``texture_construct_mip`` with nvdiffrast's signatures on JAX arrays
(the one bridge, :func:`glraster.jax.bridge.apply`).

Layouts (B batch, H x W image):

    tex             (B or 1, Ht, Wt, C); cube map (B or 1, 6, N, N, C) with
                    boundary_mode="cube" (faces +x, -x, +y, -y, +z, -z)
    uv              (B, H, W, 2) (s, t): texel (i, j) = tex[b, j, i] is centred at
                    ((i + 0.5)/Wt, (j + 0.5)/Ht); cube (B, H, W, 3) directions
    uv_da           (B, H, W, 4) (ds/dX, ds/dY, dt/dX, dt/dY); cube (B, H, W, 6)
    mip_level_bias  (B, H, W)
    mip             list of arrays, levels 1, 2, ... (each half the previous, floor, >= 1),
                    or a :class:`TextureMip` from :func:`texture_construct_mip`
    out             (B, H, W, C)
"""

from __future__ import annotations

import logging

import jax.numpy as jnp
import numpy as np

from glraster.diff import texture_args
from glraster.diff import texture_reference as _ref
from glraster.diff.ops import TEXTURE
from glraster.errors import ArgumentError
from glraster.jax import bridge
from glraster.jax.context import check_glctx, gl_context

__all__ = ["TextureMip", "texture", "texture_construct_mip"]

_log = logging.getLogger(__name__)


class TextureMip:
    """A mip pyramid built once by :func:`texture_construct_mip`, for ``texture(..., mip=)``.

    JAX arrays are immutable, so "the texture is unchanged" means: ``texture`` is given the
    same array the pyramid was built from (or a concrete array equal to it). Then it uses
    :attr:`levels` instead of building the pyramid; another concrete texture rebuilds them
    once, with a warning. Inside ``jax.jit`` / ``jax.grad`` with respect to the texture,
    ``tex`` is traced (its values are not known while tracing, and it usually changes
    between calls), so the lookup builds the pyramid from ``tex`` itself and ``mip`` is
    not used. The pyramid is tex's own: tex's gradient is the same as without ``mip``.

    Attributes
    ----------
    levels : list of jax.Array, levels 1, 2, ... of tex's dtype (the base is tex itself)
    max_mip_level : int or None
    cube_mode : bool
    """

    def __init__(self, tex, max_mip_level, cube_mode: bool, glctx):
        self.max_mip_level = max_mip_level
        self.cube_mode = cube_mode
        self._glctx = glctx
        self._build(tex)

    def _build(self, tex) -> None:
        array = np.asarray(tex)
        boundary = "cube" if self.cube_mode else "wrap"
        texture_args.check(array, np.zeros((array.shape[0], 1, 1, 3 if self.cube_mode
                                            else 2), array.dtype),
                           filter_mode="linear", boundary_mode=boundary, dtype=array.dtype)
        if array.dtype == np.float64:
            shapes = _ref.level_shapes(array.shape[-3], array.shape[-2], self.max_mip_level)
            levels = _ref.build_mips(array, shapes)
        else:
            from glraster.diff import texture as gpu_texture

            levels = gpu_texture.build_mips(array, self.max_mip_level, boundary_mode=boundary,
                                            ctx=gl_context(self._glctx, array))
        self.levels = [jnp.asarray(np.asarray(m, array.dtype)) for m in levels]
        self._levels_np = tuple(np.asarray(m, array.dtype) for m in levels)
        self._source = tex
        self._source_np = array
        _log.info("texture_construct_mip: %d levels below the %s base: %s", len(levels),
                  "x".join(map(str, array.shape[-3:-1])),
                  ", ".join("x".join(map(str, m.shape[-3:-1])) for m in levels) or "none")

    def levels_for(self, tex) -> tuple[np.ndarray, ...] | None:
        """The levels as NumPy arrays for a concrete ``tex`` (rebuilt, with a warning, when
        tex is not the texture they were built from), or None for a traced ``tex``."""
        if bridge.is_traced(tex):
            return None
        if tex is not self._source:
            array = np.asarray(tex)
            if array.shape != self._source_np.shape or array.dtype != self._source_np.dtype \
                    or not np.array_equal(array, self._source_np):
                _log.warning("texture: mip= was built from another texture: rebuilding it "
                             "(call texture_construct_mip again after changing the "
                             "texture, or pass mip=None for a texture that changes)")
                self._build(tex)
        return self._levels_np

    def __repr__(self):
        shapes = ", ".join("x".join(map(str, m.shape[-3:-1])) for m in self.levels)
        return (f"TextureMip({len(self.levels)} levels [{shapes}], "
                f"max_mip_level={self.max_mip_level}, cube_mode={self.cube_mode})")


def texture_construct_mip(tex, max_mip_level=None, cube_mode=False, *, glctx=None):
    """The mip pyramid of ``tex``, built once for ``texture(..., mip=)`` (nvdiffrast's
    ``texture_construct_mip``).

    tex : (B or 1, Ht, Wt, C), or (B or 1, 6, N, N, C) with cube_mode=True; float32 (built
        on OpenGL) or float64 (the float64 reference); a concrete array (not traced)
    max_mip_level : int >= 0, optional: at most this many levels below the base
    cube_mode : bool
    glctx : RasterizeGLContext, keyword-only, optional (glraster's addition)

    Returns a :class:`TextureMip`.
    """
    check_glctx(glctx, optional=True)
    if not isinstance(cube_mode, (bool, np.bool_)):
        raise ArgumentError("cube_mode", f"cube_mode must be True or False, got {cube_mode!r}")
    if max_mip_level is not None and (isinstance(max_mip_level, (bool, np.bool_)) or not
                                      isinstance(max_mip_level, (int, np.integer))
                                      or max_mip_level < 0):
        raise ArgumentError("max_mip_level", f"max_mip_level must be None or an integer >= 0, "
                                             f"got {max_mip_level!r}")
    if bridge.is_traced(tex):
        raise ArgumentError("tex", "texture_construct_mip needs a concrete tex (call it "
                                   "outside jax.jit); inside a traced function pass mip=None")
    tex = jnp.asarray(tex)
    if tex.dtype not in (jnp.float32, jnp.float64):
        raise ArgumentError("tex", f"tex must be a float32 or float64 array, got {tex.dtype}")
    return TextureMip(tex, None if max_mip_level is None else int(max_mip_level),
                      bool(cube_mode), glctx)


def _mipmapped(filter_mode, uv_da, mip_level_bias) -> bool:
    if filter_mode == "auto":
        return uv_da is not None or mip_level_bias is not None
    return filter_mode in texture_args.MIP_MODES


def texture(tex, uv, uv_da=None, mip_level_bias=None, mip=None, filter_mode="auto",
            boundary_mode="wrap", max_mip_level=None, *, glctx=None):
    """Filtered texture lookups (nvdiffrast's ``texture``).

    Arguments
    ---------
    tex : jax.Array (B or 1, Ht, Wt, C), or (B or 1, 6, N, N, C) for a cube map;
        float32 (OpenGL) or float64 (the float64 reference)
    uv : (B, H, W, 2) texture coordinates (cube: (B, H, W, 3) directions)
    uv_da : (B, H, W, 4) (cube: 6), optional: image-space derivatives of uv
    mip_level_bias : (B, H, W), optional
    mip : TextureMip or list of arrays, optional: a :class:`TextureMip` (its levels are
        used while tex is unchanged; tex's gradient is unchanged), or the levels 1, 2, ...
        (each gets its own gradient and none goes through them to tex)
    filter_mode : "auto" | "nearest" | "linear" | "linear-mipmap-nearest" | "linear-mipmap-linear"
    boundary_mode : "wrap" | "clamp" | "zero" | "cube"
    max_mip_level : int, optional
    glctx : RasterizeGLContext, keyword-only, optional (glraster's addition)

    Returns
    -------
    jax.Array (B, H, W, C) of tex's dtype. Gradients go to tex, uv, uv_da and
    mip_level_bias (these two only in linear-mipmap-linear), and each array of a ``mip``
    list.
    """
    check_glctx(glctx, optional=True)
    tex = jnp.asarray(tex) if not bridge.is_traced(tex) else tex
    levels, own = (), False
    if isinstance(mip, TextureMip):
        if mip.cube_mode != (boundary_mode == "cube"):
            raise ArgumentError("mip", f"mip was built with cube_mode={mip.cube_mode}, which "
                                       f"needs boundary_mode "
                                       f"{'' if mip.cube_mode else 'other than '}'cube', got "
                                       f"boundary_mode={boundary_mode!r}")
        if mip.levels and mip.levels[0].dtype != jnp.asarray(tex).dtype:
            raise ArgumentError("mip", f"mip was built from a {mip.levels[0].dtype} texture, "
                                       f"tex is {jnp.asarray(tex).dtype}: build it from tex")
        if _mipmapped(filter_mode, uv_da, mip_level_bias):   # the others read the base only
            found = mip.levels_for(tex)
            if found is not None:
                levels, own = found, True
    elif mip is not None:
        if not isinstance(mip, (list, tuple)):
            raise ArgumentError("mip", f"mip must be None, a TextureMip "
                                       f"(texture_construct_mip) or a list of arrays (mip "
                                       f"levels 1, 2, ...), got {type(mip).__name__}")
        levels = tuple(mip)
    (out,) = bridge.apply(TEXTURE, (tex, uv, uv_da, mip_level_bias, *levels),
                          dict(filter_mode=filter_mode, boundary_mode=boundary_mode,
                               max_mip_level=max_mip_level, own_mips=own,
                               ctx=glctx))
    return out
