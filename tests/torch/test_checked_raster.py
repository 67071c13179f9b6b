"""glraster.diff.checked.raster through glraster.torch: a raster rasterize made, unchanged
since, is not scanned for NaN / Inf by interpolate and antialias (finite as made); the same
values in another tensor, or the raster after an in-place change, are."""

from __future__ import annotations

import pytest
import torch

import glraster.torch as dr
from glraster import validate
from glraster.errors import ArgumentError
from glraster.geometry.shapes import box


@pytest.fixture()
def scene(ctx):
    glctx = dr.RasterizeGLContext(context=ctx)
    vertices, triangles = box()
    tri = torch.tensor(triangles, dtype=torch.int32)
    v = torch.tensor(vertices, dtype=torch.float32)
    pos = torch.cat([v * 0.5, torch.full((len(v), 1), 2.0)], 1)
    return glctx, pos, tri, torch.rand(len(v), 3)


def _scanned(monkeypatch):
    """The names of the arrays validate.finite scans from now on."""
    names = []
    real = validate.finite
    monkeypatch.setattr(validate, "finite", lambda name, *a: names.append(name) or real(name, *a))
    return names


def test_rasterize_s_own_raster_is_not_scanned_until_it_changes(scene, monkeypatch):
    glctx, pos, tri, colors = scene
    rast, _ = dr.rasterize(glctx, pos, tri, (8, 8))
    scanned = _scanned(monkeypatch)
    color, _ = dr.interpolate(colors, rast, tri, glctx=glctx)
    dr.antialias(color, rast, pos, tri, glctx=glctx)
    assert "rast" not in scanned and "color" in scanned      # (color: interpolate's output)
    dr.interpolate(colors, rast.clone(), tri, glctx=glctx)   # the same values, not made
    assert scanned.count("rast") == 1


@pytest.mark.parametrize("op", ["interpolate", "antialias"])
def test_a_nan_written_into_rasterize_s_raster_is_caught(scene, op):
    glctx, pos, tri, colors = scene
    rast, _ = dr.rasterize(glctx, pos, tri, (8, 8))
    color, _ = dr.interpolate(colors, rast, tri, glctx=glctx)
    with torch.no_grad():
        rast[0, 4, 4, 0] = float("nan")      # an in-place change: checked again
    with pytest.raises(ArgumentError, match="rast must be finite") as info:
        if op == "interpolate":
            dr.interpolate(colors, rast, tri, glctx=glctx)
        else:
            dr.antialias(color, rast, pos, tri, glctx=glctx)
    assert info.value.argument == "rast"
