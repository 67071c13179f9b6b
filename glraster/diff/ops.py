"""The differentiable ops as :class:`glraster.diff.op.Op` records: rasterize, interpolate,
texture and antialias (depth peeling is rasterize's core driven layer by layer: each core
module has a ``DepthPeeler``, see :func:`depth_peeler`).

The front ends (:mod:`glraster.torch`, :mod:`glraster.jax`) bridge these records and nothing
else of :mod:`glraster.diff`. Signatures, per op (B batch, H x W image):

============  ==========================================  =============================
op            inputs (differentiable)                      outputs
============  ==========================================  =============================
rasterize     pos                                          rast, rast_db
interpolate   attr, rast, rast_db                          out, out_da
texture       tex, uv, uv_da, mip_level_bias, *mip         out
antialias     color, rast, pos                             out
============  ==========================================  =============================

Parameters (keyword): rasterize ``tri, resolution, ranges, grad_db, space, ctx``;
interpolate ``tri, diff_attrs, ctx``; texture ``filter_mode, boundary_mode, max_mip_level,
own_mips, ctx``; antialias ``tri, topology_hash, pos_gradient_boost, convex, ctx``.
"""

from __future__ import annotations

import numpy as np

from glraster import validate
from glraster.diff import antialias_args, checked, layout, texture_args
from glraster.diff.op import Op
from glraster.errors import ArgumentError


def float_dtype(*values) -> np.dtype:
    """float64 when the first array among ``values`` is float64, else float32: the dtype
    that selects the core."""
    for value in values:
        if value is not None and not isinstance(value, (list, tuple)):
            arr = np.asarray(value)
            return np.dtype(np.float64 if arr.dtype == np.float64 else np.float32)
    return np.dtype(np.float32)


# --------------------------------------------------------------------------- rasterize


def _rasterize_check(pos, *, tri, resolution, ranges=None, grad_db=True, space="persp",
                     ctx=None):
    pos = validate.batched_positions(pos, dtype=float_dtype(pos))
    tri = validate.triangles(tri, pos.shape[-2])
    if not isinstance(grad_db, (bool, np.bool_)):
        raise ArgumentError("grad_db", f"grad_db must be True or False, got {grad_db!r}")
    # ranges are ignored in instanced mode (3-D pos), as nvdiffrast does
    params = dict(tri=tri, resolution=validate.resolution(resolution),
                  ranges=validate.ranges(ranges, len(tri), pos.ndim) if pos.ndim == 2 else None,
                  grad_db=bool(grad_db), space=validate.space(space), ctx=ctx)
    return (pos,), params


def _rasterize_shapes(pos, *, tri, resolution, ranges=None, grad_db=True, **_):
    batch = layout.batch_size(pos, ranges)
    shape = (batch, *resolution, 4)
    return shape, (shape if grad_db else (batch, *resolution, 0))


RASTERIZE = Op("rasterize", ("pos",), ("rast", "rast_db"), _rasterize_check, _rasterize_shapes,
               gpu="glraster.diff.rasterize", reference="glraster.diff.rasterize_reference")


# --------------------------------------------------------------------------- interpolate


def _interpolate_check(attr, rast, rast_db=None, *, tri, diff_attrs=None, ctx=None):
    dtype = float_dtype(attr)
    rast = checked.raster(rast, dtype)      # (rasterize's own, unchanged: finite)
    attr = validate.attributes(attr, rast.shape[0], dtype=dtype)
    tri = validate.triangles(tri, attr.shape[-2], "attr")
    diff = validate.diff_attrs(diff_attrs, attr.shape[-1])
    if not checked.vouched(rast, len(tri)):  # (rasterize's own, unchanged: valid)
        layout.rast_ids(rast, len(tri))     # every id a triangle of tri, or empty
    if rast_db is not None:
        rast_db = validate.image("rast_db", rast_db, rast.shape, dtype)
    elif diff:
        raise ArgumentError("rast_db", "diff_attrs needs rast_db (the raster's screen "
                                       "derivatives)")
    return (attr, rast, rast_db), dict(tri=tri, diff_attrs=diff, ctx=ctx)


def _interpolate_shapes(attr, rast, rast_db=None, *, diff_attrs=None, **_):
    lead = rast.shape[:3]
    return lead + (attr.shape[-1],), lead + (2 * len(diff_attrs or ()),)


INTERPOLATE = Op("interpolate", ("attr", "rast", "rast_db"), ("out", "out_da"),
                 _interpolate_check, _interpolate_shapes,
                 gpu="glraster.diff.interpolate",
                 reference="glraster.diff.interpolate_reference")


# --------------------------------------------------------------------------- texture


def _texture_check(tex, uv, uv_da=None, mip_level_bias=None, *mip, filter_mode="auto",
                   boundary_mode="wrap", max_mip_level=None, own_mips=False, ctx=None):
    args = texture_args.check(tex, uv, uv_da, mip_level_bias, *mip, filter_mode=filter_mode,
                              boundary_mode=boundary_mode, max_mip_level=max_mip_level,
                              own_mips=own_mips, dtype=float_dtype(tex))
    arrays = (args.tex, args.uv, args.uv_da, args.bias, *(args.mip or ()))
    return arrays, dict(filter_mode=args.filter_mode, boundary_mode=args.boundary_mode,
                        max_mip_level=max_mip_level, own_mips=args.own_mips, ctx=ctx)


def _texture_shapes(tex, uv, *_, **__):
    return (uv.shape[:3] + (tex.shape[-1],),)


TEXTURE = Op("texture", ("tex", "uv", "uv_da", "mip_level_bias", "*mip"), ("out",),
             _texture_check, _texture_shapes,
             gpu="glraster.diff.texture", reference="glraster.diff.texture_reference")


# --------------------------------------------------------------------------- antialias


def _antialias_check(color, rast, pos, *, tri, topology_hash=None, pos_gradient_boost=1.0,
                     convex=True, ctx=None):
    color, rast, pos, tri, th, boost, convex = antialias_args.check(
        color, rast, pos, tri, topology_hash, pos_gradient_boost, convex,
        dtype=float_dtype(color))
    return (color, rast, pos), dict(tri=tri, topology_hash=th, pos_gradient_boost=boost,
                                    convex=convex, ctx=ctx)


def _antialias_shapes(color, *_, **__):
    return (color.shape,)


ANTIALIAS = Op("antialias", ("color", "rast", "pos"), ("out",), _antialias_check,
               _antialias_shapes,
               gpu="glraster.diff.antialias", reference="glraster.diff.antialias_reference")


OPS = {op.name: op for op in (RASTERIZE, INTERPOLATE, TEXTURE, ANTIALIAS)}


# --------------------------------------------------------------------------- depth peeling


def depth_peeler(pos, **params):
    """A depth peeler on rasterize's core for ``pos``'s dtype, from checked rasterize
    arguments (:meth:`RASTERIZE.check <glraster.diff.op.Op.check>`): an object whose
    ``rasterize_next_layer()`` returns ``((rast, rast_db), saved)``, ``saved`` for
    ``RASTERIZE.core(pos.dtype).backward``, and whose ``release()`` frees what it holds
    (also a context manager)."""
    return RASTERIZE.core(pos.dtype).DepthPeeler(pos, **params)
