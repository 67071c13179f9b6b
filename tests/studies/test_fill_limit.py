"""glraster.studies.fill_limit: the yardsticks run on a fresh context and draw what
rasterize draws. Their speed is a benchmark figure (bench.headline), not judged here."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

import glraster as gr
from glraster.geometry import synthetic
from glraster.studies import bench
from glraster.studies.fill_limit import FillLimit, LeanDraw

RESOLUTION = (48, 64)


def _scene():
    """A jittered grid (shared vertices) under a random soup, plus one triangle outside the
    view that rasterize culls (its ids are remapped; the yardsticks just draw nothing)."""
    grid_pos, grid_tri = synthetic.grid(6, 5, seed=1, w_range=(0.5, 3.0))
    soup_pos, soup_tri = synthetic.random_soup(40, seed=2)
    outside = np.array([[3.0, 3.0, 0.0, 1.0], [4.0, 3.0, 0.0, 1.0], [3.0, 4.0, 0.0, 1.0]],
                       np.float32)
    pos = np.concatenate([grid_pos, outside, soup_pos]).astype(np.float32)
    tri = np.concatenate([grid_tri, [[len(grid_pos), len(grid_pos) + 1, len(grid_pos) + 2]],
                          soup_tri + len(grid_pos) + 3])
    return pos, tri


def _same_as_rasterize(outputs, raster, ids_plus_one: bool):
    persp, screen, tri_id, depth = outputs
    np.testing.assert_array_equal(persp, raster.persp)
    np.testing.assert_array_equal(screen, raster.screen)
    np.testing.assert_array_equal(depth, raster.depth)
    np.testing.assert_array_equal(tri_id - 1 if ids_plus_one else tri_id, raster.tri_id)


@pytest.mark.parametrize("cls", [FillLimit, LeanDraw])
def test_runs_on_a_fresh_context(ctx, cls):
    pos, tri = _scene()
    fresh = gr.Context(ctx.backend)
    try:
        draw = cls(fresh, pos, tri, RESOLUTION)
        outputs = draw.run()
        draw.release()
        raster = gr.rasterize(pos, tri, RESOLUTION, ctx=fresh)
        assert fresh.gl_error() == "GL_NO_ERROR"
    finally:
        fresh.release()
    assert raster.mask.sum() > 1000
    _same_as_rasterize(outputs, raster, ids_plus_one=cls is FillLimit)


@pytest.mark.parametrize("cls", [FillLimit, LeanDraw])
def test_runs_when_no_framebuffer_is_bound(ctx, cls, monkeypatch):
    # a standalone moderngl context starts with ctx.fbo None
    pos, tri = _scene()
    fresh = gr.Context(ctx.backend)
    try:
        monkeypatch.setattr(fresh.mgl, "fbo", None)
        draw = cls(fresh, pos, tri, RESOLUTION)
        draw.run()
        draw.run()
        draw.release()
        gr.rasterize(pos, tri, RESOLUTION, ctx=fresh)  # creating new targets still works
        assert fresh.gl_error() == "GL_NO_ERROR"
    finally:
        fresh.release()


def test_lean_draw_equals_rasterize_and_reuses_its_arrays(ctx):
    pos, tri = _scene()
    raster = gr.rasterize(pos, tri, RESOLUTION, ctx=ctx)
    lean = LeanDraw(ctx, pos, tri, RESOLUTION)
    try:
        first = lean.run()
        _same_as_rasterize(first, raster, ids_plus_one=False)
        second = lean.run()
        assert all(a is b for a, b in zip(first, second))
        _same_as_rasterize(second, raster, ids_plus_one=False)
        shapes = [a.shape for a in second]
        assert shapes == [(48, 64, 3), (48, 64, 3), (48, 64), (48, 64)]
        assert [a.dtype for a in second] == [np.float32, np.float32, np.int32, np.float32]
    finally:
        lean.release()
    # rasterize's own results are untouched by the yardstick's draws
    _same_as_rasterize(
        (raster.persp, raster.screen, raster.tri_id, raster.depth),
        gr.rasterize(pos, tri, RESOLUTION, ctx=ctx), ids_plus_one=False)


def test_fill_limit_equals_rasterize(ctx):
    pos, tri = _scene()
    fill = FillLimit(ctx, pos, tri, RESOLUTION)
    try:
        _same_as_rasterize(fill.run(), gr.rasterize(pos, tri, RESOLUTION, ctx=ctx),
                           ids_plus_one=True)
    finally:
        fill.release()


@pytest.mark.parametrize("cls", [FillLimit, LeanDraw])
def test_bad_input_names_the_argument(ctx, cls):
    pos, tri = _scene()
    with pytest.raises(ValueError, match=r"pos must have shape \(V, 4\), got \(5, 3\)"):
        cls(ctx, np.zeros((5, 3)), [[0, 1, 2]], RESOLUTION)
    with pytest.raises(ValueError, match="tri index 999 is out of range"):
        cls(ctx, pos, [[0, 1, 999]], RESOLUTION)
    with pytest.raises(ValueError, match="tri must hold at least one triangle"):
        cls(ctx, pos, np.zeros((0, 3), int), RESOLUTION)
    with pytest.raises(ValueError, match="resolution height must be > 0"):
        cls(ctx, pos, tri, (0, 8))
    with pytest.raises(ValueError, match="resolution must be"):
        cls(ctx, pos, tri, 64)


@pytest.mark.skipif(importlib.util.find_spec("pyrender") is None, reason="pyrender not installed")
def test_headline_reports_rasterize_against_both_yardsticks(ctx):
    head = bench.headline(backend=ctx.backend, repeats=2, resolution=(48, 64), count=50)
    for key in ("hw_over_fill", "hw_over_lean", "hw_out_over_fill", "hw_out_over_lean"):
        assert head[key]["pairs"] == 2 and head[key]["min"] <= head[key]["median"] <= head[key]["max"]
    for key in ("hw_ms", "hw_out_ms", "fill_ms", "lean_ms"):
        assert head[key] > 0
    assert head["overhead_64x64_ms"]["median_out"] > 0
