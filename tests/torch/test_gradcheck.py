"""torch.autograd.gradcheck in float64, through the float64 reference (no OpenGL: these
tests are not marked gl, so opening a context would fail them).

gradcheck compares the analytic Jacobian (our backward) with central differences of the
forward (eps = 1e-6). Coverage is frozen in the backward, so the scene keeps every pixel
centre at least 0.04 px from every edge (scenes.edge_margin), far beyond the ~1e-5 px a
step moves a vertex: the finite differences see the same triangles. Tolerances: atol 1e-5,
rtol 1e-4, for central differences of smooth closed forms whose second derivatives are
O(1..100) in these units (truncation error ~ eps^2 * f''' and rounding ~ 1e-16 / eps).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

import glraster.torch as dr
from glraster.diff.ids import decode_ids
from tests.torch import scenes

ATOL, RTOL, EPS = 1e-5, 1e-4, 1e-6


@pytest.fixture
def glctx():
    return dr.RasterizeGLContext()


def _tensor(a, grad=True):
    return torch.tensor(np.asarray(a, np.float64), dtype=torch.float64, requires_grad=grad)


TRI = torch.tensor(scenes.TRI)


def test_scene_keeps_pixel_centres_away_from_edges():
    # the precondition of every gradcheck below
    assert scenes.edge_margin(scenes.POS, scenes.TRI, scenes.RESOLUTION) > 0.04


def test_rasterize_gradcheck_wrt_pos(glctx):
    pos = _tensor(scenes.POS)

    def f(p):
        rast, rast_db = dr.rasterize(glctx, p, TRI, scenes.RESOLUTION)
        return rast[..., :2], rast_db      # z/w and id carry no gradient by design

    rast, _ = dr.rasterize(glctx, pos, TRI, scenes.RESOLUTION)
    ids = decode_ids(rast[..., 3].detach().numpy())
    assert set(np.unique(ids)) == {-1, 0, 1, 2}, "every triangle must cover pixels"
    assert torch.autograd.gradcheck(f, (pos,), eps=EPS, atol=ATOL, rtol=RTOL)


def test_rasterize_gradcheck_without_grad_db(glctx):
    # grad_db=False: rast_db still comes out, but only rast's u, v reach pos
    pos = _tensor(scenes.POS)

    def f(p):
        return dr.rasterize(glctx, p, TRI, scenes.RESOLUTION, grad_db=False)[0][..., :2]

    assert torch.autograd.gradcheck(f, (pos,), eps=EPS, atol=ATOL, rtol=RTOL)
    rast, rast_db = dr.rasterize(glctx, pos, TRI, scenes.RESOLUTION, grad_db=False)
    assert rast_db.shape == rast.shape
    rast_db.sum().backward()
    assert torch.count_nonzero(pos.grad) == 0


def test_rasterize_gradcheck_instanced_batch(glctx):
    # (B, V, 4) pos: one image per batch entry, gradients per entry
    pos = _tensor(np.stack([scenes.POS, scenes.mirrored(scenes.POS)]))

    def f(p):
        rast, rast_db = dr.rasterize(glctx, p, TRI, scenes.RESOLUTION)
        return rast[..., :2], rast_db

    assert f(pos)[0].shape == (2,) + scenes.RESOLUTION + (2,)
    assert torch.autograd.gradcheck(f, (pos,), eps=EPS, atol=ATOL, rtol=RTOL)


def test_rasterize_gradcheck_range_mode(glctx):
    # ranges (B, 2): image 0 draws triangles 0..1, image 1 triangle 2; ids stay global
    pos = _tensor(scenes.POS)
    ranges = torch.tensor([[0, 2], [2, 1]], dtype=torch.int32)

    def f(p):
        rast, rast_db = dr.rasterize(glctx, p, TRI, scenes.RESOLUTION, ranges=ranges)
        return rast[..., :2], rast_db

    rast, _ = dr.rasterize(glctx, pos, TRI, scenes.RESOLUTION, ranges=ranges)
    ids = decode_ids(rast[..., 3].detach().numpy())
    assert set(np.unique(ids[0])) == {-1, 0, 1} and set(np.unique(ids[1])) == {-1, 2}
    assert torch.autograd.gradcheck(f, (pos,), eps=EPS, atol=ATOL, rtol=RTOL)


def _raster(glctx, pos=scenes.POS):
    with torch.no_grad():
        return dr.rasterize(glctx, _tensor(pos, grad=False), TRI, scenes.RESOLUTION)


def test_interpolate_gradcheck_wrt_attr_rast_and_rast_db(glctx):
    rast, rast_db = _raster(glctx)
    attr = _tensor(scenes.COLORS)
    uv = rast[..., :2].clone().requires_grad_(True)
    db = rast_db.clone().requires_grad_(True)
    fixed = rast[..., 2:]                 # z/w and the ids are not differentiable inputs

    def f(a, uv_, db_):
        out, out_da = dr.interpolate(a, torch.cat([uv_, fixed], -1), TRI, db_,
                                     diff_attrs=[2, 0])
        return out, out_da

    out, out_da = f(attr, uv, db)
    assert out.shape == (1,) + scenes.RESOLUTION + (3,)
    assert out_da.shape == (1,) + scenes.RESOLUTION + (4,)
    assert torch.autograd.gradcheck(f, (attr, uv, db), eps=EPS, atol=ATOL, rtol=RTOL)


def test_interpolate_gradcheck_without_diff_attrs(glctx):
    rast, _ = _raster(glctx)
    attr = _tensor(scenes.COLORS)
    uv = rast[..., :2].clone().requires_grad_(True)
    fixed = rast[..., 2:]

    def f(a, uv_):
        out, out_da = dr.interpolate(a, torch.cat([uv_, fixed], -1), TRI)
        assert out_da.shape == rast.shape[:3] + (0,)
        return out

    assert torch.autograd.gradcheck(f, (attr, uv), eps=EPS, atol=ATOL, rtol=RTOL)


def test_interpolate_gradcheck_broadcast_attr_over_batch(glctx):
    # attr (1, V, A) over an instanced batch of 2: its gradient sums both images
    rast, rast_db = _raster(glctx, np.stack([scenes.POS, scenes.mirrored(scenes.POS)]))
    attr = _tensor(scenes.COLORS[None])

    def f(a, db_):
        return dr.interpolate(a, rast, TRI, db_, diff_attrs="all")

    assert torch.autograd.gradcheck(f, (attr, rast_db.clone().requires_grad_(True)),
                                    eps=EPS, atol=ATOL, rtol=RTOL)


def test_interpolate_gradcheck_with_a_repeated_diff_attr(glctx):
    # diff_attrs [1, 1, 0]: out_da's channels 0..3 both hold attribute 1's derivatives
    rast, rast_db = _raster(glctx)
    attr = _tensor(scenes.COLORS)

    def f(a, db_):
        return dr.interpolate(a, rast, TRI, db_, diff_attrs=[1, 1, 0])[1]

    out_da = f(attr, rast_db)
    assert out_da.shape[-1] == 6 and torch.equal(out_da[..., 0:2], out_da[..., 2:4])
    assert torch.autograd.gradcheck(f, (attr, rast_db.clone().requires_grad_(True)),
                                    eps=EPS, atol=ATOL, rtol=RTOL)


def test_rasterize_then_interpolate_gradcheck_wrt_pos_and_attr(glctx):
    # the whole chain: colours and their screen derivatives as functions of pos and attr
    pos, attr = _tensor(scenes.POS), _tensor(scenes.COLORS)

    def f(p, a):
        rast, rast_db = dr.rasterize(glctx, p, TRI, scenes.RESOLUTION)
        return dr.interpolate(a, rast, TRI, rast_db, diff_attrs=[1])

    assert torch.autograd.gradcheck(f, (pos, attr), eps=EPS, atol=ATOL, rtol=RTOL)


def test_backward_refuses_inputs_changed_in_place(glctx):
    # the cores keep views of pos, rast and attr: autograd's version check guards them
    pos, attr = _tensor(scenes.POS), _tensor(scenes.COLORS)
    rast, rast_db = dr.rasterize(glctx, pos, TRI, scenes.RESOLUTION)
    out, _ = dr.interpolate(attr, rast, TRI)
    with torch.no_grad():
        rast[..., 3] = 0
    with pytest.raises(RuntimeError, match="modified by an inplace operation"):
        out.sum().backward()
    leaf = pos.detach().clone().requires_grad_(True)
    p = leaf * 1.0
    rast, _ = dr.rasterize(glctx, p, TRI, scenes.RESOLUTION)
    with torch.no_grad():
        p[0, 0] += 0.1
    with pytest.raises(RuntimeError, match="modified by an inplace operation"):
        rast[..., :2].sum().backward()
