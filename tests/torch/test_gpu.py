"""The float32 path (OpenGL: glraster.diff's GPU ops) against the float64 reference path,
forward and backward, on scenes whose pixel centres stay >= 0.04 px from every edge (so
both paths cover the same pixels with the same triangles: ids must match exactly).

Tolerances, relative to the largest magnitude of the compared quantity (at least 1):
- forward values (rast u, v, z/w; rast_db; out; out_da): 2e-6. The GPU evaluates the
  closed forms in float32 from float64 per-triangle setup; measured <= 1.5e-7 here, a few
  float32 roundings (6e-8 each) of O(1) quantities.
- gradients (pos, attr, rast, rast_db): 2e-5. Per-vertex gradients are float32 sums over
  the ~15-60 pixels of a vertex's triangles, accumulated by atomics in any order; measured
  <= 5e-7 relative.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

import glraster.torch as dr
from glraster.diff.ids import decode_ids
from tests.torch import scenes

FORWARD_TOL = 2e-6
GRAD_TOL = 2e-5

TRI = torch.tensor(scenes.TRI)


@pytest.fixture
def glctx(ctx):
    return dr.RasterizeGLContext(context=ctx)


def _close(name, got, want, tol):
    got, want = got.detach().double(), want.detach().double()
    assert got.shape == want.shape, name
    scale = max(1.0, want.abs().max().item())
    err = (got - want).abs().max().item() if want.numel() else 0.0
    assert err <= tol * scale, f"{name}: max error {err:.3g} > {tol} * {scale:.3g}"


def _run(glctx, pos_np, dtype, ranges=None, diff_attrs=(0, 2), attr_np=scenes.COLORS, seed=0):
    """Forward and backward of rasterize -> interpolate with fixed random upstream grads."""
    pos = torch.tensor(pos_np, dtype=dtype, requires_grad=True)
    attr = torch.tensor(attr_np, dtype=dtype, requires_grad=True)
    rast, rast_db = dr.rasterize(glctx, pos, TRI, scenes.RESOLUTION, ranges=ranges)
    rast.retain_grad()
    rast_db.retain_grad()
    out, out_da = dr.interpolate(attr, rast, TRI, rast_db, diff_attrs=list(diff_attrs),
                                 glctx=glctx)
    rng = np.random.default_rng(seed)
    g_out = torch.tensor(rng.standard_normal(out.shape), dtype=dtype)
    g_da = torch.tensor(rng.standard_normal(out_da.shape), dtype=dtype)
    g_rast = torch.tensor(rng.standard_normal(rast.shape), dtype=dtype)
    g_db = torch.tensor(rng.standard_normal(rast_db.shape), dtype=dtype)
    # direct terms on rast and rast_db too, so pos gets the gradient of both outputs
    loss = ((out * g_out).sum() + (out_da * g_da).sum()
            + (rast[..., :2] * g_rast[..., :2]).sum() + (rast_db * g_db).sum())
    loss.backward()
    return dict(rast=rast, rast_db=rast_db, out=out, out_da=out_da, pos=pos.grad,
                attr=attr.grad, grad_rast=rast.grad, grad_rast_db=rast_db.grad)


@pytest.mark.parametrize("mode", ["single", "instanced", "ranges"])
def test_gpu_path_matches_float64_reference(glctx, mode):
    ranges = None
    pos = scenes.POS
    if mode == "instanced":
        pos = np.stack([scenes.POS, scenes.mirrored(scenes.POS)])
    elif mode == "ranges":
        ranges = torch.tensor([[0, 2], [1, 2]], dtype=torch.int32)
    gpu = _run(glctx, pos, torch.float32, ranges)
    ref = _run(glctx, pos, torch.float64, ranges)
    assert gpu["rast"].dtype == torch.float32 and ref["rast"].dtype == torch.float64
    ids = gpu["rast"][..., 3].detach().numpy()
    np.testing.assert_array_equal(ids, ref["rast"][..., 3].detach().numpy().astype(np.float32))
    assert (decode_ids(ids) >= 0).sum() > 50
    _close("rast", gpu["rast"][..., :3], ref["rast"][..., :3], FORWARD_TOL)
    for name in ("rast_db", "out", "out_da"):
        _close(name, gpu[name], ref[name], FORWARD_TOL)
    for name in ("pos", "attr", "grad_rast", "grad_rast_db"):
        _close(f"grad {name}", gpu[name], ref[name], GRAD_TOL)


@pytest.mark.parametrize("attr_batch", [None, 1, 2])
def test_gpu_interpolate_broadcasts_attr_like_the_reference(glctx, attr_batch):
    # attr (V, A) and (1, V, A) broadcast over an instanced batch of 2; (2, V, A) does not
    attr = scenes.COLORS if attr_batch is None else np.stack(
        [scenes.COLORS, scenes.COLORS[::-1]][:attr_batch])
    pos = np.stack([scenes.POS, scenes.mirrored(scenes.POS)])
    gpu = _run(glctx, pos, torch.float32, attr_np=attr, diff_attrs=(1, 1, 0))
    ref = _run(glctx, pos, torch.float64, attr_np=attr, diff_attrs=(1, 1, 0))
    assert gpu["attr"].shape == attr.shape and gpu["out_da"].shape[-1] == 6
    for name in ("out", "out_da"):
        _close(name, gpu[name], ref[name], FORWARD_TOL)
    for name in ("pos", "attr", "grad_rast", "grad_rast_db"):
        _close(f"grad {name}", gpu[name], ref[name], GRAD_TOL)


def test_rast_layout_ids_and_rows_from_the_bottom(glctx):
    # one triangle over the bottom half only: row 0 (the bottom) covered, the top row not
    pos = torch.tensor([[-3, -1.2, 0, 1], [3, -1.2, 0, 1], [0, -0.05, 0, 1]],
                       dtype=torch.float32)
    tri = torch.tensor([[0, 1, 2]], dtype=torch.int32)
    rast, rast_db = dr.rasterize(glctx, pos, tri, (8, 8))
    assert rast.shape == (1, 8, 8, 4) and rast_db.shape == (1, 8, 8, 4)
    assert (rast[0, 0, :, 3] == 1).all() and (rast[0, -1, :, 3] == 0).all()
    covered = rast[..., 3] > 0
    u, v = rast[..., 0][covered], rast[..., 1][covered]
    assert (u >= 0).all() and (v >= 0).all() and (u + v <= 1 + 1e-6).all()
    # u = b0 grows towards vertex 0 (left), so du/dx < 0 on every covered pixel
    assert (rast_db[..., 0][covered] < 0).all()
    assert (rast[~covered] == 0).all()


def test_output_db_false_gives_an_empty_rast_db(ctx):
    glctx = dr.RasterizeGLContext(output_db=False, context=ctx)
    pos = torch.tensor(scenes.POS, dtype=torch.float32, requires_grad=True)
    rast, rast_db = dr.rasterize(glctx, pos, TRI, scenes.RESOLUTION)
    assert rast_db.shape == (1,) + scenes.RESOLUTION + (0,)
    rast[..., :2].sum().backward()
    assert pos.grad.abs().sum() > 0
    with pytest.raises(ValueError, match="rast_db"):
        dr.interpolate(torch.ones(7, 1), rast, TRI, rast_db, diff_attrs="all")


def test_cuda_context_name_draws_with_opengl(ctx):
    glctx = dr.RasterizeCudaContext(context=ctx)
    assert glctx.output_db
    rast, rast_db = dr.rasterize(glctx, torch.tensor(scenes.POS, dtype=torch.float32), TRI,
                                 scenes.RESOLUTION)
    assert rast_db.shape == rast.shape and (rast[..., 3] > 0).any()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_depth_peeler_layers_and_their_gradients(glctx, dtype):
    # triangle 2 lies in front of 0 and 1: layer 0 shows it, layer 1 what is behind it
    pos = torch.tensor(scenes.POS, dtype=dtype, requires_grad=True)
    first, _ = dr.rasterize(glctx, pos, TRI, scenes.RESOLUTION)
    layers = []
    with dr.DepthPeeler(glctx, pos, TRI, scenes.RESOLUTION) as peeler:
        with pytest.raises(RuntimeError, match="DepthPeeler"):
            dr.rasterize(glctx, pos, TRI, scenes.RESOLUTION)
        for _ in range(3):
            layers.append(peeler.rasterize_next_layer())
    assert glctx.active_depth_peeler is None
    ids = [decode_ids(r[..., 3].detach().numpy()) for r, _ in layers]
    np.testing.assert_array_equal(layers[0][0].detach().numpy(), first.detach().numpy())
    front = ids[0] == 2
    assert front.sum() > 5
    assert set(np.unique(ids[1][front])) <= {-1, 0, 1} and (ids[1][front] >= 0).any()
    assert (ids[1][~front] == -1).all() and (ids[2] == -1).all()
    layers[1][0][..., :2].sum().backward()     # layer 1's u, v depend on triangles 0, 1
    assert pos.grad[:4].abs().sum() > 0 and pos.grad[4:].abs().sum() == 0


def test_depth_peeler_gpu_layer_matches_reference(glctx):
    out = {}
    for dtype in (torch.float32, torch.float64):
        pos = torch.tensor(scenes.POS, dtype=dtype, requires_grad=True)
        with dr.DepthPeeler(glctx, pos, TRI, scenes.RESOLUTION) as peeler:
            peeler.rasterize_next_layer()
            rast, rast_db = peeler.rasterize_next_layer()
        (rast[..., :2].sum() + rast_db.sum()).backward()
        out[dtype] = (rast, rast_db, pos.grad)
    (r32, db32, g32), (r64, db64, g64) = out[torch.float32], out[torch.float64]
    np.testing.assert_array_equal(r32[..., 3].detach().numpy(),
                                  r64[..., 3].detach().numpy().astype(np.float32))
    _close("layer 1 rast", r32[..., :3], r64[..., :3], FORWARD_TOL)
    _close("layer 1 rast_db", db32, db64, FORWARD_TOL)
    _close("layer 1 grad pos", g32, g64, GRAD_TOL)
