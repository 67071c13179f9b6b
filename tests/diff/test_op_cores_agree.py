"""Both cores of rasterize, interpolate and depth peeling take the same call and agree.

One call per op, built once through the op's check: the float32 inputs go to the GPU core
(:func:`glraster.diff.op.Op.core` of float32) and the same inputs as float64 to the
reference core, with the same keyword parameters (``ctx`` included: the reference ignores
it). Outputs and gradients must have the input's dtype and the op's shapes
(:meth:`Op.output_shapes`), the same entries None for the same ``needs``, and agree.

The scene is well shaped (no slivers, w in [1, 2], vertices inside the viewport, float32-
exact positions): there the reference models llvmpipe's coverage bit for bit, so the
triangle ids must be equal on every pixel, and the GPU's compensated float32 evaluation
stays within a few float32 ulps of float64. Tolerances, relative to the largest entry of
the float64 result: 1e-6 for per-pixel values (u, v, z/w, out, out_da; measured <= 1e-7
on llvmpipe) and 1e-5 for rast_db and the gradients (sums of hundreds of float32 terms;
measured <= 8e-7): about ten times what the GPU reaches, far below a wrong formula or a
misplaced pixel (O(1)).
"""

from __future__ import annotations

import numpy as np
import pytest

from glraster.diff.ids import decode_ids
from glraster.diff.ops import INTERPOLATE, RASTERIZE, depth_peeler

RES = (40, 56)

# two overlapping quads' worth of triangles, float32-exact, w in [1, 2]
POS = np.array([
    [-0.75, -0.625, 0.125, 1.0], [0.8125, -0.5, 0.25, 2.0], [0.125, 0.875, -0.25, 1.5],
    [-0.875, 0.75, 0.5, 1.25], [0.625, 0.625, 0.0, 1.75],
    [-0.5, -0.75, -0.5, 1.0], [0.75, 0.0, -0.375, 1.25], [-0.25, 0.5, -0.25, 1.5],
], np.float32)
TRI = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 2], [5, 6, 7]], np.int32)


def both(check, *inputs, **params):
    """The checked (inputs, params) for float32 and for float64, the same parameters."""
    f32 = check(*[None if a is None else np.asarray(a, np.float32) for a in inputs], **params)
    f64 = check(*[None if a is None else np.asarray(a, np.float64) for a in inputs], **params)
    return f32, f64


def agree(got32, want64, tol, what):
    assert got32.dtype == np.float32 and want64.dtype == np.float64, what
    assert got32.shape == want64.shape, what
    scale = np.abs(want64).max()
    assert scale > 0, f"{what}: all zero, nothing compared"
    err = np.abs(got32 - want64).max() / scale
    assert err <= tol, f"{what}: max |float32 - float64| / max = {err:.2e} > {tol}"


def run(op, checked, ctx, grads, needs):
    """Forward and backward of ``op`` on its core for the checked inputs' dtype."""
    (inputs, params) = checked
    core = op.core(inputs[0].dtype)
    outputs, saved = core.forward(*inputs, **dict(params, ctx=ctx))
    assert [o.shape for o in outputs] == list(op.output_shapes(*inputs, **params))
    dtype = inputs[0].dtype
    g = [None if x is None else x.astype(dtype) for x in grads(outputs)]
    return outputs, core.backward(saved, *g, needs=needs)


def upstream(seed):
    rng = np.random.default_rng(seed)
    return lambda outputs: [rng.normal(size=o.shape) for o in outputs]


@pytest.mark.parametrize("space", ["persp", "screen"])
@pytest.mark.parametrize("needs", [None, (False,)], ids=["all", "none"])
def test_rasterize_cores_agree(ctx, space, needs):
    f32, f64 = both(RASTERIZE.check, POS, tri=TRI, resolution=RES, space=space)
    (rast32, db32), (g32,) = run(RASTERIZE, f32, ctx, upstream(1), needs)
    (rast64, db64), (g64,) = run(RASTERIZE, f64, ctx, upstream(1), needs)
    ids = decode_ids(rast32[..., 3])
    np.testing.assert_array_equal(ids, decode_ids(rast64[..., 3]))
    assert (ids >= 0).sum() > 500
    agree(rast32[..., :3], rast64[..., :3], 1e-6, "rast")
    agree(db32, db64, 1e-5, "rast_db")
    if needs is None:
        assert g32.shape == POS.shape
        agree(g32, g64, 1e-5, "grad_pos")
    else:
        assert g32 is None and g64 is None


@pytest.mark.parametrize("needs", [None, (True, False, False), (False, True, True)],
                         ids=["all", "attr", "rast"])
@pytest.mark.parametrize("diff_attrs", [None, [2, 0, 2]], ids=["no_da", "da"])
def test_interpolate_cores_agree(ctx, diff_attrs, needs):
    (inputs, params), _ = both(RASTERIZE.check, POS, tri=TRI, resolution=RES)
    (rast, db), _ = RASTERIZE.core(np.float32).forward(*inputs, **dict(params, ctx=ctx))
    attr = np.random.default_rng(2).normal(size=(len(POS), 3))
    f32, f64 = both(INTERPOLATE.check, attr, rast, db, tri=TRI, diff_attrs=diff_attrs)
    out32, grads32 = run(INTERPOLATE, f32, ctx, upstream(3), needs)
    out64, grads64 = run(INTERPOLATE, f64, ctx, upstream(3), needs)
    agree(out32[0], out64[0], 1e-6, "out")
    if diff_attrs is None:
        assert out32[1].shape[-1] == out64[1].shape[-1] == 0
    else:
        agree(out32[1], out64[1], 1e-6, "out_da")
    for name, g32, g64 in zip(("grad_attr", "grad_rast", "grad_rast_db"), grads32, grads64):
        assert (g32 is None) == (g64 is None), name
        if g32 is not None:
            agree(g32, g64, 1e-5, name)
    wanted = (True, True, True) if needs is None else needs
    assert (grads32[0] is not None) == wanted[0] and (grads32[1] is not None) == wanted[1]
    assert (grads32[2] is not None) == (wanted[2] and diff_attrs is not None)


def test_depth_peelers_agree(ctx):
    """Layer by layer: the same ids, values within the rasterize bounds, and each layer's
    saved state gives the same gradient on both cores."""
    f32, f64 = both(RASTERIZE.check, POS, tri=TRI, resolution=RES)
    rng = np.random.default_rng(4)
    with depth_peeler(*f32[0], **dict(f32[1], ctx=ctx)) as p32, \
            depth_peeler(*f64[0], **dict(f64[1], ctx=ctx)) as p64:
        for layer in range(3):
            (rast32, db32), s32 = p32.rasterize_next_layer()
            (rast64, db64), s64 = p64.rasterize_next_layer()
            ids = decode_ids(rast32[..., 3])
            np.testing.assert_array_equal(ids, decode_ids(rast64[..., 3]))
            if layer == 2:
                assert not (ids >= 0).any(), "two surfaces at most: layer 3 is empty"
                break
            assert (ids >= 0).sum() > 50, layer
            agree(rast32[..., :3], rast64[..., :3], 1e-6, f"layer {layer} rast")
            g = rng.normal(size=rast32.shape)
            (g32,) = RASTERIZE.core(np.float32).backward(s32, g.astype(np.float32), None)
            (g64,) = RASTERIZE.core(np.float64).backward(s64, g, None)
            agree(g32, g64, 1e-5, f"layer {layer} grad_pos")
