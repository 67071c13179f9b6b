"""What one op call through glraster.torch switches and reads: one make-current around a
whole core call (nested blocks of the same context switch nothing, a block of another
context in between still gets its own), and an empty readback (antialias with no
silhouette pixel) reads nothing."""

from __future__ import annotations

import numpy as np
import torch

import glraster.torch as dr
from glraster.geometry.shapes import box
from glraster.gpu import context as gpu_context
from glraster.gpu.context import Context


def test_nested_blocks_of_one_context_switch_once(ctx, monkeypatch):
    switches = []
    real = type(ctx.mgl).__enter__

    def counting(mgl):
        switches.append(mgl)
        return real(mgl)

    monkeypatch.setattr(type(ctx.mgl), "__enter__", counting)
    with ctx:
        with ctx:
            with ctx:
                assert ctx.mgl.error == "GL_NO_ERROR"
    assert switches == [ctx.mgl]
    assert gpu_context._entered() == []


def test_a_block_of_another_context_in_between_switches_back(ctx):
    other = Context(backend=ctx.backend)
    try:
        with ctx:
            data = ctx.storage_buffer("test.nested", np.arange(4, dtype=np.float32))
            with other:
                other.storage_buffer("test.nested", np.zeros(4, np.float32))
                with ctx:   # ctx again, inside other's block: made current again
                    got = np.frombuffer(data.read(size=16), np.float32)
            np.testing.assert_array_equal(got, np.arange(4, dtype=np.float32))
    finally:
        other.release()


def test_antialias_without_silhouette_pixels_returns_color(ctx):
    glctx = dr.RasterizeGLContext(context=ctx)
    vertices, triangles = box()
    tri = torch.tensor(triangles, dtype=torch.int32)
    v = torch.tensor(vertices, dtype=torch.float32)
    pos = torch.cat([v * 0.8, torch.full((len(v), 1), 2.0)], 1)[None].repeat(4, 1, 1)
    pos.requires_grad_()
    colors = torch.rand(len(v), 3, requires_grad=True)
    rast, _ = dr.rasterize(glctx, pos, tri, (4, 4))   # the cube covers every pixel
    color, _ = dr.interpolate(colors, rast, tri, glctx=glctx)
    out = dr.antialias(color, rast, pos, tri, glctx=glctx)
    assert out.equal(color)
    out.sum().backward()
    assert pos.grad.abs().max() == 0 and colors.grad is not None


def test_a_raster_rasterize_made_is_not_decoded_again_until_it_changes(ctx, monkeypatch):
    from glraster.diff import layout
    from glraster.errors import ArgumentError

    glctx = dr.RasterizeGLContext(context=ctx)
    vertices, triangles = box()
    tri = torch.tensor(triangles, dtype=torch.int32)
    v = torch.tensor(vertices, dtype=torch.float32)
    pos = torch.cat([v * 0.5, torch.full((len(v), 1), 2.0)], 1)
    colors = torch.rand(len(v), 3)
    decoded = []
    real = layout.rast_ids
    monkeypatch.setattr(layout, "rast_ids", lambda *a: decoded.append(1) or real(*a))
    rast, _ = dr.rasterize(glctx, pos, tri, (8, 8))
    color, _ = dr.interpolate(colors, rast, tri, glctx=glctx)
    dr.antialias(color, rast, pos, tri, glctx=glctx)
    assert decoded == []                       # rasterize's own ids, unchanged
    by_hand = rast.clone()                     # the same values, not rasterize's
    dr.interpolate(colors, by_hand, tri, glctx=glctx)
    assert decoded == [1]
    with torch.no_grad():
        rast[0, 4, 4, 3] = 99.0                # an in-place change: checked again
    for call in (lambda: dr.interpolate(colors, rast, tri, glctx=glctx),
                 lambda: dr.antialias(color, rast, pos, tri, glctx=glctx)):
        try:
            call()
        except ArgumentError as exc:
            assert exc.argument == "rast" and "99" in str(exc)
        else:
            raise AssertionError("an id beyond tri was not caught")
    # fewer triangles than rasterize drew: the ids are checked against them
    try:
        dr.interpolate(colors, dr.rasterize(glctx, pos, tri, (8, 8))[0], tri[:2], glctx=glctx)
    except ArgumentError as exc:
        assert exc.argument == "rast"
    else:
        raise AssertionError("ids beyond a shorter tri were not caught")
