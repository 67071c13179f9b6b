"""Every finiteness test of the ops' checks (validate.finite) runs once for a tensor
unchanged since it passed it (same storage, torch version, shape, dtype: the keys of
glraster.torch.bridge, tensors of 1 KiB or more) and again after any in-place change, so a
NaN or Inf written in place after a successful call is still refused, with the same
ArgumentError naming the argument."""

from __future__ import annotations

import math

import pytest
import torch

import glraster.torch as dr
from glraster.errors import ArgumentError
from glraster.geometry.shapes import box


def _scene(ctx, dtype=torch.float32, grad=False):
    glctx = dr.RasterizeGLContext(context=ctx)
    vertices, triangles = box()
    tri = torch.tensor(triangles, dtype=torch.int32)
    v = torch.tensor(vertices, dtype=dtype)
    g = torch.Generator().manual_seed(0)
    # (8 boxes, one per image: pos 8 x 8 x 4 values, 1 KiB in float32, keyed)
    pos = torch.cat([v * 0.5, torch.full((len(v), 1), 2.0, dtype=dtype)], 1)
    pos = (pos[None] * torch.linspace(0.8, 1.2, 8, dtype=dtype)[:, None, None]).contiguous()
    attr = torch.rand(len(v), 32, generator=g, dtype=dtype)          # 1 KiB in float32
    rast, rast_db = dr.rasterize(glctx, pos, tri, (16, 16), grad_db=True)
    uv = torch.rand(8, 16, 16, 2, generator=g, dtype=dtype)
    uv_da = torch.full((8, 16, 16, 4), 0.05, dtype=dtype)
    bias = torch.zeros(8, 16, 16, dtype=dtype)
    tex = torch.rand(1, 16, 16, 4, generator=g, dtype=dtype)
    color = torch.rand(8, 16, 16, 4, generator=g, dtype=dtype)
    leaves = dict(pos=pos, attr=attr, uv=uv, uv_da=uv_da, bias=bias, tex=tex, color=color)
    if grad:
        for t in leaves.values():
            t.requires_grad_(True)
    return glctx, tri, rast, rast_db, leaves


def _calls(glctx, tri, rast, rast_db, t):
    """argument -> a call of an op that checks it."""
    mip = "linear-mipmap-linear"
    return {
        "pos": lambda: dr.rasterize(glctx, t["pos"], tri, (16, 16)),
        "attr": lambda: dr.interpolate(t["attr"], rast, tri, glctx=glctx),
        "rast_db": lambda: dr.interpolate(t["attr"], rast, tri, rast_db=rast_db,
                                          diff_attrs="all", glctx=glctx),
        "color": lambda: dr.antialias(t["color"], rast, t["pos"], tri, glctx=glctx),
        "tex": lambda: dr.texture(t["tex"], t["uv"], filter_mode="linear", glctx=glctx),
        "uv": lambda: dr.texture(t["tex"], t["uv"], filter_mode="linear", glctx=glctx),
        "uv_da": lambda: dr.texture(t["tex"], t["uv"], t["uv_da"], filter_mode=mip,
                                    glctx=glctx),
        "mip_level_bias": lambda: dr.texture(t["tex"], t["uv"], t["uv_da"], t["bias"],
                                             filter_mode=mip, glctx=glctx),
    }


def _target(name, rast_db, t):
    return rast_db if name == "rast_db" else t["bias" if name == "mip_level_bias" else name]


ARGUMENTS = ("pos", "attr", "rast_db", "color", "tex", "uv", "uv_da", "mip_level_bias")


@pytest.mark.parametrize("grad", [False, True], ids=["no-grad", "grad"])
@pytest.mark.parametrize("name", ARGUMENTS)
def test_an_unchanged_tensor_is_scanned_once_a_changed_one_again(ctx, scans, name, grad):
    glctx, tri, rast, rast_db, t = _scene(ctx, grad=grad)
    call = _calls(glctx, tri, rast, rast_db, t)[name]
    call()
    first = scans.count(name)          # (texture: also by its pyramid's build, once)
    assert first >= 1, scans
    call()
    assert scans.count(name) == first, scans             # unchanged: not scanned again
    with torch.no_grad():
        _target(name, rast_db, t).mul_(1.0)              # same values, a new version
    call()
    assert scans.count(name) > first, scans


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("grad", [False, True], ids=["no-grad", "grad"])
@pytest.mark.parametrize("name", ARGUMENTS)
def test_a_nan_or_inf_written_in_place_after_a_good_call_is_refused(ctx, name, grad, bad):
    glctx, tri, rast, rast_db, t = _scene(ctx, grad=grad)
    call = _calls(glctx, tri, rast, rast_db, t)[name]
    call()
    call()                                               # (the second: known finite)
    with torch.no_grad():
        _target(name, rast_db, t).view(-1)[5] = bad      # an in-place change
    with pytest.raises(ArgumentError, match=f"^{name} must be finite") as info:
        call()
    assert info.value.argument == name
    with pytest.raises(ArgumentError, match=f"^{name} must be finite"):
        call()                                           # and every time after


def test_a_view_written_in_place_changes_its_base_s_key(ctx):
    """A change through another view bumps the version the views share: uv[None]-style
    views of one tensor are checked again after it."""
    glctx, tri, rast, _, t = _scene(ctx)
    attr = torch.rand(8, 32, generator=torch.Generator().manual_seed(3))
    dr.interpolate(attr[None], rast, tri, glctx=glctx)
    dr.interpolate(attr[None], rast, tri, glctx=glctx)
    attr[2:4][1, 7] = math.nan                           # through another view
    with pytest.raises(ArgumentError, match="^attr must be finite") as info:
        dr.interpolate(attr[None], rast, tri, glctx=glctx)
    assert info.value.argument == "attr"


def test_float64_the_same(ctx, scans):
    glctx, tri, rast, _, t = _scene(ctx, dtype=torch.float64)
    rast = rast.double()
    dr.interpolate(t["attr"], rast, tri, glctx=glctx)
    dr.interpolate(t["attr"], rast, tri, glctx=glctx)
    assert scans.count("attr") == 1, scans
    with torch.no_grad():
        t["attr"][3, 3] = math.inf
    with pytest.raises(ArgumentError, match="^attr must be finite"):
        dr.interpolate(t["attr"], rast, tri, glctx=glctx)
