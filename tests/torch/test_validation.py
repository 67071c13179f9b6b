"""Bad input raises a ValueError naming the argument, before anything is drawn (these tests
are not marked gl: reaching OpenGL would fail them)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import glraster.torch as dr
from tests.no_gl import BLOCK_GL
from tests.torch import scenes

RES = scenes.RESOLUTION


@pytest.fixture
def glctx():
    return dr.RasterizeGLContext()


def _pos(dtype=torch.float32):
    return torch.tensor(scenes.POS, dtype=dtype)


TRI = torch.tensor(scenes.TRI)


def test_contexts_open_no_gl_until_a_float32_call():
    glctx = dr.RasterizeGLContext()
    assert glctx.output_db and glctx.mode == "automatic" and glctx.active_depth_peeler is None
    assert "not made yet" in repr(glctx)
    cuda = dr.RasterizeCudaContext()
    assert cuda.output_db and isinstance(cuda, dr.RasterizeGLContext)
    manual = dr.RasterizeGLContext(mode="manual", device="cpu")
    manual.set_context()
    manual.release_context()
    with pytest.raises(RuntimeError, match="manual"):
        glctx.set_context()


@pytest.mark.parametrize("kwargs, match", [
    (dict(output_db=1), "output_db"),
    (dict(mode="lazy"), "mode"),
    (dict(device="cuda:0"), "device"),
    (dict(device="nonsense"), "device"),
    (dict(context="egl"), "context"),
])
def test_context_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        dr.RasterizeGLContext(**kwargs)


def test_cuda_context_rejects_a_cuda_device():
    with pytest.raises(ValueError, match="device"):
        dr.RasterizeCudaContext(device="cuda")


RASTERIZE_CASES = [
    ("glctx", dict(glctx="not a context")),
    ("pos must be a torch.Tensor", dict(pos=scenes.POS)),
    ("pos must have dtype", dict(pos=_pos(torch.float16))),
    ("pos must have dtype", dict(pos=torch.zeros(3, 4, dtype=torch.int32))),
    (r"pos must have shape \(V, 4\)", dict(pos=torch.zeros(3, 3))),
    (r"pos must have shape \(V, 4\)", dict(pos=torch.zeros(2, 3, 3, 4))),
    ("pos must be on the CPU", dict(pos=torch.zeros(7, 4, device="meta"))),
    ("pos must be finite", dict(pos=_pos().index_put((torch.tensor([2]), torch.tensor([1])),
                                                     torch.tensor(float("nan"))))),
    ("pos must be finite", dict(pos=torch.full((7, 4), float("inf")))),
    ("tri must have dtype", dict(tri=TRI.float())),
    (r"tri must have shape \(T, 3\)", dict(tri=TRI[:, :2].contiguous())),
    ("tri index 7 is out of range", dict(tri=torch.tensor([[0, 1, 7]], dtype=torch.int32))),
    ("tri must hold indices >= 0", dict(tri=torch.tensor([[0, -1, 2]], dtype=torch.int32))),
    ("resolution", dict(resolution=(0, 4))),
    ("resolution", dict(resolution=(4.5, 4))),
    ("resolution", dict(resolution=16)),
    ("ranges must have dtype", dict(ranges=torch.tensor([[0, 1.0]]))),
    ("ranges must be on the CPU", dict(ranges=torch.zeros(1, 2, dtype=torch.int32,
                                                          device="meta"))),
    (r"ranges must have shape \(B, 2\)", dict(ranges=torch.tensor([0, 3], dtype=torch.int32))),
    ("ranges row 1 .* beyond tri's 3 triangles",
     dict(ranges=torch.tensor([[0, 3], [2, 2]], dtype=torch.int32))),
    ("ranges row 0 must have first >= 0",
     dict(ranges=torch.tensor([[-1, 1]], dtype=torch.int32))),
    ("grad_db", dict(grad_db="yes")),
]


@pytest.mark.parametrize("match, change", RASTERIZE_CASES,
                         ids=[m.split(" ")[0] + f"-{i}" for i, (m, _) in
                              enumerate(RASTERIZE_CASES)])
def test_rasterize_rejects_bad_input(glctx, match, change):
    args = dict(glctx=glctx, pos=_pos(), tri=TRI, resolution=RES, ranges=None, grad_db=True)
    args.update(change)
    with pytest.raises(ValueError, match=match):
        dr.rasterize(**args)
    with pytest.raises(ValueError, match=match):
        dr.DepthPeeler(**args)


def test_ranges_are_ignored_in_instanced_mode(glctx):
    # as nvdiffrast: ranges only mean something with 2-D pos (float64: no GL needed)
    pos = torch.tensor(np.stack([scenes.POS] * 2))
    bad = torch.tensor([[5, 9]], dtype=torch.int32)
    rast, _ = dr.rasterize(glctx, pos, TRI, RES, ranges=bad)
    assert rast.shape[0] == 2


@pytest.fixture
def raster(glctx):
    return dr.rasterize(glctx, _pos(torch.float64), TRI, RES)


def _attr(dtype=torch.float64):
    return torch.tensor(scenes.COLORS, dtype=dtype)


INTERPOLATE_CASES = [
    ("attr must be a torch.Tensor", dict(attr=scenes.COLORS)),
    ("attr must have dtype", dict(attr=torch.ones(7, 3, dtype=torch.int64))),
    (r"attr must have shape \(V, A\)", dict(attr=torch.ones(7, dtype=torch.float64))),
    ("attr has a batch of 2", dict(attr=torch.ones(2, 7, 3, dtype=torch.float64))),
    ("attr must be finite", dict(attr=torch.full((7, 3), float("nan"), dtype=torch.float64))),
    ("attr must be on the CPU", dict(attr=torch.ones(7, 3, dtype=torch.float64,
                                                     device="meta"))),
    ("rast must have the dtype of attr", dict(attr=_attr(torch.float32))),
    (r"rast must have shape \(B, H, W, 4\)", dict(rast=torch.zeros(1, 4, 4, 3,
                                                                   dtype=torch.float64))),
    ("rast channel 3", dict(rast=torch.full((1, 4, 4, 4), 0.5, dtype=torch.float64))),
    # an image of no pixels (NumPy's "cannot reshape array of size 0" before)
    ("rast must have B, H and W >= 1", dict(rast=torch.zeros(1, 0, 4, 4, dtype=torch.float64))),
    ("rast must have B, H and W >= 1", dict(rast=torch.zeros(0, 4, 4, 4, dtype=torch.float64))),
    ("rast holds triangle id 9", dict(rast=torch.tensor([0, 0, 0, 9.0],
                                                        dtype=torch.float64).expand(1, 2, 2, 4))),
    ("tri index 7 is out of range", dict(tri=torch.tensor([[0, 1, 7]], dtype=torch.int32))),
    ("tri must have dtype", dict(tri=TRI.double())),
    ("diff_attrs index 3 is out of range", dict(diff_attrs=[0, 3])),
    ("diff_attrs must be None, 'all'", dict(diff_attrs="some")),
    ("diff_attrs must hold integer", dict(diff_attrs=[0.5])),
    ("needs rast_db", dict(rast_db=None, diff_attrs=[0])),  # the INTERPOLATE op's check
    ("rast_db must have the dtype of attr", dict(rast_db="float32", diff_attrs=[0])),
    (r"rast_db must have shape \(1, 10, 12, 4\)",
     dict(rast_db=torch.zeros(1, 10, 11, 4, dtype=torch.float64), diff_attrs=[0])),
    ("glctx", dict(glctx=object())),
]


@pytest.mark.parametrize("match, change", INTERPOLATE_CASES,
                         ids=[m.split(" ")[0] + f"-{i}" for i, (m, _) in
                              enumerate(INTERPOLATE_CASES)])
def test_interpolate_rejects_bad_input(raster, match, change):
    rast, rast_db = raster
    if isinstance(change.get("rast_db"), str):
        change = dict(change, rast_db=rast_db.float())
    args = dict(attr=_attr(), rast=rast, tri=TRI, rast_db=rast_db, diff_attrs=None)
    args.update(change)
    with pytest.raises(ValueError, match=match):
        dr.interpolate(**args)


def test_interpolate_without_diff_attrs_ignores_rast_db(raster):
    rast, _ = raster
    out, out_da = dr.interpolate(_attr(), rast, TRI, rast_db="never looked at")
    assert out.shape == rast.shape[:3] + (3,) and out_da.shape == rast.shape[:3] + (0,)
    out, out_da = dr.interpolate(_attr(), rast, TRI, diff_attrs=[])
    assert out_da.shape == rast.shape[:3] + (0,)


NO_GL = BLOCK_GL + """

import torch
import glraster.torch as dr
pos = torch.tensor([[-0.8, -0.8, 0, 1], [0.8, -0.8, 0, 2], [0, 0.8, 0, 1]],
                   dtype=torch.float64, requires_grad=True)
tri = torch.tensor([[0, 1, 2]], dtype=torch.int32)
rast, rast_db = dr.rasterize(dr.RasterizeGLContext(), pos, tri, (8, 8))
out, _ = dr.interpolate(pos[:, :2], rast, tri)
out.sum().backward()
assert pos.grad.abs().sum() > 0
assert not any(m.startswith(("moderngl", "glraster.gpu")) for m in sys.modules)
print("ok")
"""


def test_the_float64_path_runs_without_moderngl():
    import subprocess
    import sys
    from pathlib import Path

    proc = subprocess.run([sys.executable, "-c", NO_GL], capture_output=True, text=True,
                          cwd=Path(__file__).resolve().parents[2], timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "ok"
