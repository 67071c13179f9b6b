"""glraster.torch.antialias: gradcheck in float64 (the reference path), float32 (GPU) against
float64, nvdiffrast's layouts and call forms, and the ValueErrors."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import glraster.torch as dr
from glraster.diff.ops import INTERPOLATE, RASTERIZE
from tests.diff.test_antialias_reference import mesh_scene, soup_scene

RES = (14, 18)


def scene(dtype=torch.float64):
    """A few independent triangles and a small sphere; rast from the float64 reference."""
    pos, tri, colors = soup_scene(RES, count=5, seed=3, layered=True)
    (rast, _), _ = RASTERIZE.forward(pos, tri=tri, resolution=RES)
    (col, _), _ = INTERPOLATE.forward(colors, rast, tri=tri)
    return (torch.tensor(col, dtype=dtype), torch.tensor(rast, dtype=dtype),
            torch.tensor(pos, dtype=dtype), torch.tensor(tri, dtype=torch.int32))


def test_gradcheck_color_and_pos_through_the_reference():
    col, rast, pos, tri = scene()
    th = dr.antialias_construct_topology_hash(tri)
    col.requires_grad_(True)
    pos.requires_grad_(True)
    out = dr.antialias(col, rast, pos, tri, th)
    assert out.shape == col.shape and out.dtype == torch.float64
    grad = torch.autograd.grad(out.sum(), pos)[0]
    assert grad.abs().max() > 0                      # visibility gradients reach pos

    def fn(c, p):
        return dr.antialias(c, rast, p, tri, th)

    # every entry of pos; the colour (linear, many entries) by gradcheck's random
    # projections (fast_mode)
    assert torch.autograd.gradcheck(lambda p: fn(col.detach(), p), (pos,), eps=1e-6,
                                    atol=1e-5, rtol=1e-4)
    assert torch.autograd.gradcheck(fn, (col, pos), eps=1e-6, atol=1e-5, rtol=1e-4,
                                    fast_mode=True)


def test_gradcheck_instanced_pos():
    pos0, tri, colors = mesh_scene(RES, level=1)
    pos1, _, _ = mesh_scene(RES, level=1, eye=(-0.4, 0.3, 3.0))
    rasts, cols = [], []
    for p in (pos0, pos1):
        (r, _), _ = RASTERIZE.forward(p, tri=tri, resolution=RES)
        (c, _), _ = INTERPOLATE.forward(colors, r, tri=tri)
        rasts.append(r)
        cols.append(c)
    rast = torch.tensor(np.concatenate(rasts))
    col = torch.tensor(np.concatenate(cols), requires_grad=True)
    pos = torch.tensor(np.stack([pos0, pos1]), requires_grad=True)
    tri_t = torch.tensor(tri, dtype=torch.int64)

    def fn(c, p):
        return dr.antialias(c, rast, p, tri_t)

    assert torch.autograd.gradcheck(lambda p: fn(col.detach(), p), (pos,), eps=1e-6,
                                    atol=1e-5, rtol=1e-4)
    assert torch.autograd.gradcheck(fn, (col, pos), eps=1e-6, atol=1e-5, rtol=1e-4,
                                    fast_mode=True)
    # pos_gradient_boost multiplies the gradient of pos only (so gradcheck would fail)
    g = torch.ones_like(col)
    gc1, gp1 = torch.autograd.grad(fn(col, pos), (col, pos), g)
    gc2, gp2 = torch.autograd.grad(dr.antialias(col, rast, pos, tri_t, pos_gradient_boost=2.5),
                                   (col, pos), g)
    assert torch.equal(gc1, gc2) and torch.allclose(gp2, 2.5 * gp1, rtol=1e-14)


def test_float32_runs_on_the_gpu_and_matches_float64(ctx):
    glctx = dr.RasterizeGLContext(context=ctx)
    pos, tri, colors = mesh_scene((48, 64), level=2)
    pos32 = torch.tensor(pos, dtype=torch.float32, requires_grad=True)
    tri_t = torch.tensor(tri)
    rast, _ = dr.rasterize(glctx, pos32, tri_t, (48, 64))
    col, _ = dr.interpolate(torch.tensor(colors, dtype=torch.float32), rast, tri_t, glctx=glctx)
    out32 = dr.antialias(col, rast, pos32, tri_t, glctx=glctx)
    assert out32.dtype == torch.float32 and out32.shape == col.shape
    g = torch.randn(out32.shape, generator=torch.Generator().manual_seed(0))
    (out32 * g).sum().backward()
    pos64 = torch.tensor(pos, dtype=torch.float64, requires_grad=True)
    col64 = col.detach().double().requires_grad_(True)
    out64 = dr.antialias(col64, rast.detach().double(), pos64, tri_t)
    (out64 * g.double()).sum().backward()
    assert (out32.detach().double() - out64.detach()).abs().max() < 1e-5
    # pos32 also gets the rasterize -> interpolate gradient; compare antialias's own part
    col32 = col.detach().requires_grad_(True)
    pos_aa = pos32.detach().clone().requires_grad_(True)
    out_aa = dr.antialias(col32, rast.detach(), pos_aa, tri_t, glctx=glctx)
    (out_aa * g).sum().backward()
    scale = pos64.grad.abs().max()
    assert scale > 0
    assert (pos_aa.grad.double() - pos64.grad).abs().max() < 1e-4 * scale
    assert (col32.grad.double() - col64.grad).abs().max() < 1e-5


def test_welded_topology_hash_from_torch():
    col, rast, pos, tri = scene()
    split = pos[tri.long().ravel()]
    split_tri = torch.arange(tri.numel(), dtype=torch.int32).reshape(-1, 3)
    th = dr.antialias_construct_topology_hash(split_tri, pos=split)
    a = dr.antialias(col, rast, pos, tri)
    b = dr.antialias(col, rast, split, split_tri, th)
    assert torch.equal(a, b)


def test_bad_input_raises_value_errors():
    col, rast, pos, tri = scene()
    with pytest.raises(ValueError, match="color must be a torch.Tensor"):
        dr.antialias(col.numpy(), rast, pos, tri)
    with pytest.raises(ValueError, match="rast must have the dtype of color"):
        dr.antialias(col, rast.float(), pos, tri)
    with pytest.raises(ValueError, match="pos must have the dtype of color"):
        dr.antialias(col, rast, pos.float(), tri)
    with pytest.raises(ValueError, match="tri must have dtype"):
        dr.antialias(col, rast, pos, tri.float())
    with pytest.raises(ValueError, match="color must have shape"):
        dr.antialias(col[:, 1:], rast, pos, tri)
    with pytest.raises(ValueError, match="topology_hash was built for a different tri"):
        dr.antialias(col, rast, pos, tri, dr.antialias_construct_topology_hash(tri[:2]))
    with pytest.raises(ValueError, match="glctx must be a RasterizeGLContext"):
        dr.antialias(col, rast, pos, tri, glctx="gl")
    with pytest.raises(ValueError, match="pos_gradient_boost must be a finite number"):
        dr.antialias(col, rast, pos, tri, pos_gradient_boost=float("inf"))
    with pytest.raises(ValueError, match="tri must be a torch.Tensor"):
        dr.antialias_construct_topology_hash(tri.numpy())
