"""``rasterize``, ``interpolate`` and ``DepthPeeler`` with nvdiffrast's signatures and layouts.

Each op is one private :class:`torch.autograd.Function` around the NumPy core:

============  ===========================================  ================================
dtype         forward                                      backward
============  ===========================================  ================================
float32       ``glraster.diff.rasterize.forward`` (GPU)    ``glraster.diff.rasterize.backward``
              ``glraster.diff.interpolate.forward``        ``diff.interpolate.backward``
float64       ``diff.rasterize_reference.forward``         ``diff.rasterize_reference.backward``
              ``diff.interpolate_reference.forward``       ``diff.interpolate_reference.backward``
============  ===========================================  ================================

so ``torch.autograd.gradcheck`` in float64 runs through the float64 reference, and float32
tensors through OpenGL. All tensors live on the CPU. Bad input raises a ValueError naming the
argument before anything runs. Double backward is not supported (``once_differentiable``).

Layouts (B batch, H x W image, rows ``[y, x]`` with row 0 at the BOTTOM, as GL windows):

    rast     (B, H, W, 4)  (u, v, z/w, id): u, v the perspective-correct barycentrics of
                           tri[t, 0] and tri[t, 1] at the pixel centre; z/w the clip-space
                           depth; id = t + 1 as a float32 (the value itself for ids <= 2^24,
                           else the float32 whose bit pattern is 0x4a800000 + id), 0 = empty.
    rast_db  (B, H, W, 4)  (du/dx, du/dy, dv/dx, dv/dy) per window pixel, or (B, H, W, 0)
                           when the context was made with ``output_db=False``.
    out      (B, H, W, A)  interpolated attributes (0 on empty pixels).
    out_da   (B, H, W, 2*len(diff_attrs))  (dA/dx, dA/dy) of each selected attribute A, in
                           the order of ``diff_attrs``; (B, H, W, 0) without ``diff_attrs``.

Gradients: rasterize sends the gradients of rast's channels 0 and 1 (u, v) and, with
``grad_db=True`` on an ``output_db`` context, of rast_db to ``pos`` (coverage frozen: no
visibility gradient, and none through z/w or id). interpolate sends gradients to ``attr``,
to rast's channels 0 and 1 and, with ``diff_attrs``, to ``rast_db``.
"""

from __future__ import annotations

import numpy as np
import torch
from torch.autograd.function import once_differentiable

from glraster import validate
from glraster.diff import layout
from glraster.diff.ops import INTERPOLATE, RASTERIZE, depth_peeler
from glraster.torch import _checks
from glraster.torch.context import RasterizeGLContext

# --------------------------------------------------------------------------- the cores


def _gl(glctx, dtype):
    """The GL context of ``glctx`` for the GPU core (float32); None for the float64
    reference, which needs none (a context is made on first use)."""
    return None if glctx is None or dtype == np.float64 else glctx.context


class _RasterOp:
    """One rasterization (a call of :func:`rasterize` or one peeled layer): ``forward(pos)``
    gives (rast, rast_db, state), ``backward(state, grad_rast, grad_db)`` the gradient of
    ``pos``, on the core of :data:`glraster.diff.ops.RASTERIZE` the dtype selects."""

    def __init__(self, glctx, tri, resolution, ranges, output_db, grad_db, peeler=None):
        self.glctx = glctx
        self.tri = tri
        self.resolution = resolution
        self.ranges = ranges
        self.output_db = output_db
        self.grad_db = grad_db
        self.peeler = peeler  # the core's depth peeler, for one layer

    def forward(self, pos: np.ndarray):
        if self.peeler is not None:
            (rast, rast_db), saved = self.peeler.rasterize_next_layer()
        else:
            (rast, rast_db), saved = RASTERIZE.core(pos.dtype).forward(
                pos, tri=self.tri, resolution=self.resolution, ranges=self.ranges,
                grad_db=self.output_db, ctx=_gl(self.glctx, pos.dtype))
        return rast, rast_db, (pos, rast, saved)

    def backward(self, state, grad_rast: np.ndarray, grad_db):
        pos, _, saved = state
        if not (self.grad_db and self.output_db):
            grad_db = None
        return RASTERIZE.core(pos.dtype).backward(saved, grad_rast, grad_db)[0]


class _RasterizeFunction(torch.autograd.Function):
    @staticmethod
    def forward(fctx, pos, op):
        pos_np = _checks.numpy(pos)
        rast, rast_db, state = op.forward(pos_np)
        rast_t = _checks.to_torch(rast)
        # the cores keep views of pos and rast: saving the tensors makes autograd refuse a
        # backward after either was modified in place
        fctx.save_for_backward(pos, rast_t)
        fctx.op, fctx.state = op, state
        fctx.set_materialize_grads(False)
        return rast_t, _checks.to_torch(rast_db)

    @staticmethod
    @once_differentiable
    def backward(fctx, grad_rast, grad_db):
        if not fctx.needs_input_grad[0] or (grad_rast is None and grad_db is None):
            return None, None
        fctx.saved_tensors  # raises if pos or rast changed in place since the forward
        op, state = fctx.op, fctx.state
        rast = state[1]
        g_rast = (np.zeros(rast.shape, rast.dtype) if grad_rast is None
                  else _checks.numpy(grad_rast).astype(rast.dtype, copy=False))
        g_db = None
        if grad_db is not None and grad_db.shape[-1] > 0:
            g_db = _checks.numpy(grad_db).astype(rast.dtype, copy=False)
        grad_pos = op.backward(state, g_rast, g_db)
        return _checks.to_torch(np.asarray(grad_pos, state[0].dtype)), None


class _InterpolateOp:
    """One interpolation on the core of :data:`glraster.diff.ops.INTERPOLATE` the dtype
    selects (a ``diff_attrs`` that repeats an attribute gives each repeat its channels;
    gradients of repeats add)."""

    def __init__(self, glctx, tri, diff_attrs):
        self.glctx = glctx
        self.tri = tri
        self.diff_attrs = None if diff_attrs is None else tuple(diff_attrs)

    def forward(self, attr, rast, rast_db):
        (out, out_da), saved = INTERPOLATE.core(attr.dtype).forward(
            attr, rast, rast_db if self.diff_attrs else None, tri=self.tri,
            diff_attrs=self.diff_attrs, ctx=_gl(self.glctx, attr.dtype))
        return out, out_da, saved

    def backward(self, saved, dtype, grad_out, grad_out_da):
        return INTERPOLATE.core(dtype).backward(saved, grad_out, grad_out_da)


def _fit(name, grad, shape, dtype, core_shape=None):
    """A core's gradient as an array of the input's ``shape`` (None: zeros). ``core_shape``:
    the shape the core was given, when the wrapper reshaped the input (attr (1, V, A) is
    passed as (V, A), which broadcasts on every path)."""
    if grad is None:
        return np.zeros(shape, dtype)
    grad = np.asarray(grad, dtype)
    if grad.shape != tuple(core_shape or shape):
        raise RuntimeError(f"the core returned {name} of shape {grad.shape}, expected "
                           f"{tuple(core_shape or shape)}")
    return grad.reshape(shape)


class _InterpolateFunction(torch.autograd.Function):
    @staticmethod
    def forward(fctx, attr, rast, rast_db, op):
        attr_np, rast_np = _checks.numpy(attr), _checks.numpy(rast)
        db_np = None if rast_db is None else _checks.numpy(rast_db)
        core_attr = attr_np[0] if attr_np.ndim == 3 and attr_np.shape[0] == 1 else attr_np
        out, out_da, saved = op.forward(core_attr, rast_np, db_np)
        fctx.save_for_backward(attr, rast, rast_db)  # in-place changes are then refused
        fctx.op, fctx.saved = op, saved
        fctx.shapes = (attr_np.shape, core_attr.shape, rast_np.shape,
                       None if db_np is None else db_np.shape)
        fctx.dtype = attr_np.dtype
        fctx.set_materialize_grads(False)
        return _checks.to_torch(out), _checks.to_torch(out_da)

    @staticmethod
    @once_differentiable
    def backward(fctx, grad_out, grad_out_da):
        if not any(fctx.needs_input_grad[:3]) or (grad_out is None and grad_out_da is None):
            return None, None, None, None
        fctx.saved_tensors  # raises if an input changed in place since the forward
        op, dtype = fctx.op, fctx.dtype
        attr_shape, core_attr_shape, rast_shape, db_shape = fctx.shapes
        out_shape = rast_shape[:-1] + (attr_shape[-1],)
        g_out = (np.zeros(out_shape, dtype) if grad_out is None
                 else _checks.numpy(grad_out).astype(dtype, copy=False))
        g_da = None
        if op.diff_attrs is not None and grad_out_da is not None:
            g_da = _checks.numpy(grad_out_da).astype(dtype, copy=False)
        g_attr, g_rast, g_db = op.backward(fctx.saved, dtype, g_out, g_da)
        need_attr, need_rast, need_db = fctx.needs_input_grad[:3]
        return (
            _checks.to_torch(_fit("grad_attr", g_attr, attr_shape, dtype, core_attr_shape))
            if need_attr else None,
            _checks.to_torch(_fit("grad_rast", g_rast, rast_shape, dtype)) if need_rast else None,
            _checks.to_torch(_fit("grad_rast_db", g_db, db_shape, dtype))
            if need_db and db_shape is not None else None,
            None,
        )


# --------------------------------------------------------------------------- input checks


def _check_glctx(glctx) -> RasterizeGLContext:
    if not isinstance(glctx, RasterizeGLContext):
        raise ValueError(f"glctx must be a RasterizeGLContext (or RasterizeCudaContext), got "
                         f"{type(glctx).__name__}")
    return glctx


def _rasterize_args(glctx, pos, tri, resolution, ranges, grad_db):
    """The checked NumPy arguments of rasterize / DepthPeeler: (tri, resolution, ranges)."""
    _check_glctx(glctx)
    _checks.tensor("pos", pos, _checks.FLOAT_DTYPES)
    pos_np = _checks.numpy(pos)
    pos_np = validate.batched_positions(pos_np, dtype=pos_np.dtype)
    _checks.tensor("tri", tri, _checks.INT_DTYPES)
    tri_np = validate.triangles(_checks.numpy(tri), pos_np.shape[-2])
    res = validate.resolution(resolution)
    ranges_np = None
    if ranges is not None and pos_np.ndim == 2:  # nvdiffrast: ignored in instanced mode
        _checks.tensor("ranges", ranges, _checks.INT_DTYPES)
        ranges_np = validate.ranges(_checks.numpy(ranges), len(tri_np), pos_np.ndim)
    _checks.flag("grad_db", grad_db)
    return tri_np, res, ranges_np


# --------------------------------------------------------------------------- public ops


def rasterize(glctx, pos, tri, resolution, ranges=None, grad_db=True):
    """Rasterize triangles (nvdiffrast's ``rasterize``).

    Arguments
    ---------
    glctx : RasterizeGLContext (or RasterizeCudaContext)
    pos : torch.Tensor (V, 4) or (B, V, 4), float32 or float64, CPU
        Clip-space positions. 2-D is range mode (with ``ranges``, else one image), 3-D is
        instanced mode (one image per batch entry, all sharing ``tri``). float32 draws with
        OpenGL; float64 runs the float64 reference (for gradcheck).
    tri : torch.Tensor (T, 3), int32 (or int64), CPU
        Vertex indices in [0, V).
    resolution : (height, width)
    ranges : torch.Tensor (B, 2), int32 (or int64), CPU, optional
        Range mode: image b draws triangles ranges[b, 0] .. ranges[b, 0] + ranges[b, 1] - 1
        (their ids stay indices into the whole ``tri``). Ignored in instanced mode.
    grad_db : bool
        Propagate the gradient of ``rast_db`` into ``pos``. Ignored when the context was
        made with ``output_db=False``.

    Returns
    -------
    (rast, rast_db): rast (B, H, W, 4) = (u, v, z/w, id) and rast_db (B, H, W, 4) =
    (du/dx, du/dy, dv/dx, dv/dy), or (B, H, W, 0) with ``output_db=False``; both of pos'
    dtype, rows from the bottom (module docstring). B = 1 for 2-D pos without ranges.
    """
    tri_np, res, ranges_np = _rasterize_args(glctx, pos, tri, resolution, ranges, grad_db)
    if glctx.active_depth_peeler is not None:
        raise RuntimeError("rasterize() cannot run while a DepthPeeler is active on this "
                           "context; use its rasterize_next_layer()")
    op = _RasterOp(glctx, tri_np, res, ranges_np, glctx.output_db, bool(grad_db))
    return _RasterizeFunction.apply(pos, op)


def interpolate(attr, rast, tri, rast_db=None, diff_attrs=None, *, glctx=None):
    """Interpolate vertex attributes (nvdiffrast's ``interpolate``).

    Arguments
    ---------
    attr : torch.Tensor (V, A) or (B, V, A), float32 or float64, CPU
        Vertex attributes; a batch of 1 (or 2-D attr) broadcasts over rast's batch.
    rast : torch.Tensor (B, H, W, 4)
        The first output of :func:`rasterize`, attr's dtype.
    tri : torch.Tensor (T, 3), int32 (or int64)
        The triangles rast was made with.
    rast_db : torch.Tensor (B, H, W, 4), optional
        The second output of :func:`rasterize`; needed with ``diff_attrs``.
    diff_attrs : None, "all" or a list of attribute indices
        Attributes whose image-space derivatives go to ``out_da``.
    glctx : RasterizeGLContext, keyword-only, optional (glraster's addition)
        The context to interpolate float32 tensors on; None: glraster's default context.

    Returns
    -------
    (out, out_da): out (B, H, W, A) the perspective-correct interpolation
    sum_i b_i attr[tri[t, i]] (0 on empty pixels); out_da (B, H, W, 2 * len(diff_attrs)) =
    (dA/dx, dA/dy) per selected attribute in the order given, or (B, H, W, 0) without
    ``diff_attrs``.
    """
    if glctx is not None:
        _check_glctx(glctx)
    _checks.tensor("attr", attr, _checks.FLOAT_DTYPES)
    _checks.tensor("rast", rast, _checks.FLOAT_DTYPES)
    _checks.same_dtype("rast", rast, "attr", attr.dtype)
    dtype = _checks.numpy(attr).dtype
    rast_np = validate.image("rast", _checks.numpy(rast), dtype=dtype)
    attr_np = validate.attributes(_checks.numpy(attr), rast_np.shape[0], dtype=dtype)
    _checks.tensor("tri", tri, _checks.INT_DTYPES)
    tri_np = validate.triangles(_checks.numpy(tri), attr_np.shape[-2], "attr")
    layout.rast_ids(rast_np, len(tri_np))
    selected = validate.diff_attrs(diff_attrs, attr_np.shape[-1])
    if selected is not None and len(selected) == 0:
        selected = None
    if selected is None:
        rast_db = None  # as nvdiffrast: without diff_attrs, rast_db is not used
    else:
        if rast_db is None:
            raise ValueError("rast_db is needed with diff_attrs (pass rasterize's second "
                             "output)")
        _checks.tensor("rast_db", rast_db, _checks.FLOAT_DTYPES)
        _checks.same_dtype("rast_db", rast_db, "attr", attr.dtype)
        if rast_db.shape[-1:] == (0,):
            raise ValueError("rast_db is empty (B, H, W, 0): the context was made with "
                             "output_db=False, so diff_attrs cannot be computed")
        validate.image("rast_db", _checks.numpy(rast_db), shape=rast_np.shape, dtype=dtype)
    op = _InterpolateOp(glctx, tri_np, selected)
    return _InterpolateFunction.apply(attr, rast, rast_db, op)


# --------------------------------------------------------------------------- depth peeling


class DepthPeeler:
    """Successive depth layers (nvdiffrast's ``DepthPeeler``), as a context manager::

        with DepthPeeler(glctx, pos, tri, resolution) as peeler:
            for _ in range(layers):
                rast, rast_db = peeler.rasterize_next_layer()

    Arguments are those of :func:`rasterize`. Each :meth:`rasterize_next_layer` returns
    ``(rast, rast_db)`` as :func:`rasterize` does, keeping per pixel the nearest surface
    strictly behind the previous layer's (the first layer equals :func:`rasterize`); a pixel
    empty in one layer is empty in all later ones. Every layer is differentiable w.r.t.
    ``pos`` like :func:`rasterize`'s output. While the peeler is active, ``rasterize`` on
    the same context raises RuntimeError, and one context has one active peeler at a time.
    float32 ``pos`` peels on the GPU; float64 through the float64 reference.
    """

    def __init__(self, glctx, pos, tri, resolution, ranges=None, grad_db=True):
        tri_np, res, ranges_np = _rasterize_args(glctx, pos, tri, resolution, ranges, grad_db)
        self.raster_ctx = glctx
        self.pos = pos
        self._args = (tri_np, res, ranges_np, bool(grad_db))
        self._peeler = None

    def __enter__(self):
        if self.raster_ctx is None:
            raise RuntimeError("cannot re-enter a finished DepthPeeler")
        if self.raster_ctx.active_depth_peeler is not None:
            raise RuntimeError("this context already has an active DepthPeeler")
        tri_np, res, ranges_np, _ = self._args
        pos_np = _checks.numpy(self.pos)
        self._peeler = depth_peeler(pos_np, tri=tri_np, resolution=res, ranges=ranges_np,
                                    grad_db=self.raster_ctx.output_db,
                                    ctx=_gl(self.raster_ctx, pos_np.dtype))
        self.raster_ctx.active_depth_peeler = self
        return self

    def __exit__(self, *exc):
        try:
            if self._peeler is not None:
                self._peeler.release()
        finally:
            if self.raster_ctx is not None and self.raster_ctx.active_depth_peeler is self:
                self.raster_ctx.active_depth_peeler = None
            self.raster_ctx = None
            self.pos = None
            self._peeler = None
        return None

    def rasterize_next_layer(self):
        """The next layer's ``(rast, rast_db)``; layouts as :func:`rasterize`'s."""
        if self._peeler is None or self.raster_ctx is None:
            raise RuntimeError("rasterize_next_layer() must be called inside the DepthPeeler's "
                               "with block")
        tri_np, res, ranges_np, grad_db = self._args
        op = _RasterOp(self.raster_ctx, tri_np, res, ranges_np, self.raster_ctx.output_db,
                       grad_db, peeler=self._peeler)
        return _RasterizeFunction.apply(self.pos, op)
