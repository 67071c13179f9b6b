"""``rasterize``, ``interpolate`` and ``DepthPeeler`` with nvdiffrast's signatures on JAX
arrays, through the one bridge :func:`glraster.jax.bridge.apply`.

Layouts (B batch, H x W image, rows ``[y, x]`` with row 0 at the BOTTOM, as GL windows):

    pos      (V, 4) or (B, V, 4)  clip-space positions (3-D: instanced mode)
    tri      (T, 3) int           vertex indices (static: NumPy or a concrete JAX array)
    rast     (B, H, W, 4)  (u, v, z/w, id): u, v the perspective-correct barycentrics of
                           tri[t, 0] and tri[t, 1] at the pixel centre; z/w the clip-space
                           depth; id = t + 1 as a float (the value itself for ids <= 2^24),
                           0 = empty.
    rast_db  (B, H, W, 4)  (du/dx, du/dy, dv/dx, dv/dy) per window pixel, or (B, H, W, 0)
                           when the context was made with ``output_db=False``.
    out      (B, H, W, A)  interpolated attributes (0 on empty pixels).
    out_da   (B, H, W, 2*len(diff_attrs))  (dA/dx, dA/dy) of each selected attribute.

Gradients: rasterize sends the gradients of rast's channels 0 and 1 and, with
``grad_db=True`` on an ``output_db`` context, of rast_db to ``pos`` (coverage frozen: no
visibility gradient, none through z/w or id). interpolate sends gradients to ``attr``,
rast's channels 0 and 1 and, with ``diff_attrs``, ``rast_db``.

float32 arrays run on OpenGL, float64 (``jax.config.update("jax_enable_x64", True)``) on
the float64 reference. ``jax.vmap`` over a leading axis of ``pos`` (or ``attr``/``rast``)
folds it into the batch axis: one draw for all images.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from glraster.diff.ops import INTERPOLATE, RASTERIZE, depth_peeler
from glraster.diff.rasterizer_context import PeelerScope
from glraster.errors import ArgumentError
from glraster.jax import bridge
from glraster.jax.context import check_glctx

__all__ = ["DepthPeeler", "interpolate", "rasterize"]


def _grad_db_flag(grad_db) -> bool:
    if not isinstance(grad_db, bool):
        raise ArgumentError("grad_db", f"grad_db must be True or False, got {grad_db!r}")
    return grad_db


def _rasterize_params(glctx, pos, tri, resolution, ranges):
    return dict(tri=bridge.concrete("tri", tri), resolution=resolution,
                ranges=bridge.concrete("ranges", ranges), grad_db=glctx.output_db,
                ctx=glctx)


def rasterize(glctx, pos, tri, resolution, ranges=None, grad_db=True):
    """Rasterize triangles (nvdiffrast's ``rasterize``).

    Arguments
    ---------
    glctx : RasterizeGLContext (or RasterizeCudaContext)
    pos : jax.Array (V, 4) or (B, V, 4), float32 (OpenGL) or float64 (reference)
    tri : (T, 3) int32/int64, NumPy or concrete JAX array (static under jit)
    resolution : (height, width)
    ranges : (B, 2) int, optional (static): range mode (2-D pos); ignored for 3-D pos
    grad_db : bool
        Propagate the gradient of ``rast_db`` into ``pos`` (ignored with output_db=False).

    Returns
    -------
    (rast, rast_db), layouts in the module docstring.
    """
    check_glctx(glctx)
    grad_db = _grad_db_flag(grad_db)
    if glctx.active_depth_peeler is not None:
        raise RuntimeError("rasterize() cannot run while a DepthPeeler is active on this "
                           "context; use its rasterize_next_layer()")
    pos = jnp.asarray(pos)
    params = _rasterize_params(glctx, pos, tri, resolution, ranges)
    if pos.ndim == 3:
        params["ranges"] = None   # nvdiffrast: ranges are ignored in instanced mode
    rast, rast_db = bridge.apply(RASTERIZE, (pos,), params)
    return rast, rast_db if grad_db else jax.lax.stop_gradient(rast_db)


def interpolate(attr, rast, tri, rast_db=None, diff_attrs=None, *, glctx=None):
    """Interpolate vertex attributes (nvdiffrast's ``interpolate``).

    Arguments
    ---------
    attr : jax.Array (V, A) or (B, V, A), float32 or float64 (a batch of 1 broadcasts)
    rast : jax.Array (B, H, W, 4), :func:`rasterize`'s first output
    tri : (T, 3) int, static: the triangles rast was made with
    rast_db : jax.Array (B, H, W, 4), optional: needed with ``diff_attrs``
    diff_attrs : None, "all" or a list of attribute indices
    glctx : RasterizeGLContext, keyword-only, optional (glraster's addition): the context
        float32 arrays interpolate on (None: glraster's default context)

    Returns
    -------
    (out, out_da): out (B, H, W, A); out_da (B, H, W, 2 * len(diff_attrs)), or
    (B, H, W, 0) without ``diff_attrs``.
    """
    check_glctx(glctx, optional=True)
    attr = jnp.asarray(attr)
    if attr.ndim == 3 and attr.shape[0] == 1:
        attr = attr[0]   # a batch of 1 broadcasts: the (V, A) form every core takes
    if diff_attrs is not None and not isinstance(diff_attrs, str) and len(diff_attrs) == 0:
        diff_attrs = None
    if diff_attrs is None:
        rast_db = None   # as nvdiffrast: without diff_attrs, rast_db is not used
    elif rast_db is not None and jnp.shape(rast_db)[-1:] == (0,):
        raise ArgumentError("rast_db", "rast_db is empty (B, H, W, 0): the context was made "
                                       "with output_db=False, so diff_attrs cannot be computed")
    return bridge.apply(INTERPOLATE, (attr, rast, rast_db),
                        dict(tri=bridge.concrete("tri", tri), diff_attrs=diff_attrs,
                             ctx=glctx))


class DepthPeeler(PeelerScope):
    """Successive depth layers (nvdiffrast's ``DepthPeeler``), as a context manager::

        with DepthPeeler(glctx, pos, tri, resolution) as peeler:
            for _ in range(layers):
                rast, rast_db = peeler.rasterize_next_layer()

    Arguments are those of :func:`rasterize`. Each layer keeps per pixel the nearest
    surface strictly behind the previous layer's (the first equals :func:`rasterize`) and
    is differentiable w.r.t. ``pos`` like :func:`rasterize`'s output (``jax.grad`` works).
    The peeler is stateful, as nvdiffrast's: use it outside ``jax.jit`` and ``jax.vmap``
    (``pos`` may be traced by ``jax.grad``). While it is active, ``rasterize`` on the same
    context raises RuntimeError.
    """

    def __init__(self, glctx, pos, tri, resolution, ranges=None, grad_db=True):
        check_glctx(glctx)
        self.raster_ctx = glctx
        self.pos = jnp.asarray(pos)
        self.grad_db = _grad_db_flag(grad_db)
        params = _rasterize_params(glctx, self.pos, tri, resolution, ranges)
        if self.pos.ndim == 3:
            params["ranges"] = None
        self._params = params
        self._peeler = None

    def _open(self):
        self._layers = []   # each layer's saved record, for its backward

    def rasterize_next_layer(self):
        """The next layer's ``(rast, rast_db)``; layouts as :func:`rasterize`'s."""
        if self.raster_ctx is None or self.raster_ctx.active_depth_peeler is not self:
            raise RuntimeError("rasterize_next_layer() must be called inside the "
                               "DepthPeeler's with block")
        rast, rast_db = _peel(self, self.pos)
        return rast, rast_db if self.grad_db else jax.lax.stop_gradient(rast_db)

    def _next_layer(self, pos_np):
        """The NumPy layer ``((rast, rast_db), saved)`` of this call (the peeler starts on
        the first call, when ``pos``'s values exist)."""
        if self._peeler is None:
            (pos_np,), params = RASTERIZE.check(pos_np, **self._params)
            self._params = params
            glctx = self.raster_ctx
            ctx = glctx.context if pos_np.dtype == np.float32 else None
            self._peeler = depth_peeler(pos_np, **dict(params, ctx=ctx))
        return self._peeler.rasterize_next_layer()


def _peel(peeler: DepthPeeler, pos):
    """One peeled layer as a custom_vjp over pure_callback. The layer's ``saved`` stays on
    the host in ``peeler._layers`` (a layer cannot be recomputed: the peeler moved on), and
    the backward callback finds it by its index."""
    (checked,), params = RASTERIZE.check(np.zeros(pos.shape, pos.dtype),
                                         **peeler._params)
    shapes = RASTERIZE.output_shapes(checked, **params)
    dtype = checked.dtype
    types = tuple(jax.ShapeDtypeStruct(s, dtype) for s in shapes)
    index = len(peeler._layers)
    peeler._layers.append(None)
    core = RASTERIZE.core(dtype)

    def forward_host(pos_np):
        outputs, saved = peeler._next_layer(np.asarray(pos_np))
        peeler._layers[index] = saved
        return tuple(outputs)

    def backward_host(grad_rast, grad_db):
        saved = peeler._layers[index]
        (grad,) = core.backward(saved, np.asarray(grad_rast), np.asarray(grad_db))
        return grad.astype(dtype).reshape(checked.shape)

    @jax.custom_vjp
    def layer(p):
        return tuple(jax.pure_callback(forward_host, types, p))

    def layer_fwd(p):
        return layer(p), None

    def layer_bwd(_, cotangents):
        return (jax.pure_callback(backward_host, jax.ShapeDtypeStruct(checked.shape, dtype),
                                  *cotangents),)

    layer.defvjp(layer_fwd, layer_bwd)
    return layer(pos.astype(dtype))
