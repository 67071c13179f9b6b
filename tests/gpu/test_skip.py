"""Skipping what a scene does not need: culling before upload leaves the image unchanged
and tri_id still indexes the caller's triangles; GL objects are reused across calls."""

from __future__ import annotations

import numpy as np
import pytest

import glraster as gr
from glraster.geometry import synthetic
from glraster.gpu.cull import cull
from glraster.gpu.rasterize import CULL_MIN_TRIANGLES, METHODS

RES = (80, 112)


def _mixed_scene(seed=0):
    """A soup with triangles outside every clip plane, repeated vertices, snapped-zero
    slivers and both windings, shuffled together (at least CULL_MIN_TRIANGLES)."""
    rng = np.random.default_rng(seed)
    pos, tri = synthetic.random_soup(400, seed=seed)
    pos = pos.copy()
    n = len(tri)
    kinds = rng.integers(0, 5, n)
    for t in np.flatnonzero(kinds == 0):            # outside one plane: shift past x = w
        v = tri[t]
        axis = rng.integers(0, 3)
        sign = rng.choice([-1.0, 1.0])
        pos[v, axis] = sign * pos[v, 3] * rng.uniform(1.01, 3.0, 3)
    for t in np.flatnonzero(kinds == 1):            # repeated vertex position
        pos[tri[t, 1]] = pos[tri[t, 0]]
    for t in np.flatnonzero(kinds == 2):            # sliver thinner than 1/256 px
        v = tri[t]
        pos[v[2]] = pos[v[0]] + (pos[v[1]] - pos[v[0]]) * 0.5
        pos[v[2], 1] += 1e-6 * pos[v[2], 3]
    return pos, tri


@pytest.mark.parametrize("method", sorted(METHODS))
def test_culling_leaves_the_image_unchanged(ctx, method):
    """Bit for bit: the dropped triangles could not produce a fragment."""
    pos, tri = _mixed_scene()
    assert len(tri) >= CULL_MIN_TRIANGLES
    a = gr.rasterize(pos, tri, RES, ctx=ctx, method=method, cull=True)
    b = gr.rasterize(pos, tri, RES, ctx=ctx, method=method, cull=False)
    culled = a.info["culled"]
    assert culled["outside"] > 0 and culled["zero_area"] > 0
    for name in ("persp", "screen", "depth", "tri_id"):
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name


def test_tri_id_indexes_the_callers_triangles_after_culling(ctx):
    """Every covered pixel's id is a triangle that survived culling, in the caller's
    numbering (the shader or the host maps the uploaded index back)."""
    pos, tri = _mixed_scene(seed=1)
    r = gr.rasterize(pos, tri, RES, ctx=ctx, outputs=("tri_id",), cull=True)
    c = cull(pos, tri, RES)
    assert r.info["culled"]["outside"] > 0
    ids = np.unique(r.tri_id[r.mask])
    assert len(ids) > 10
    assert c.keep[ids].all()
    # every id is in range and refers to a triangle covering that pixel center in float64
    assert ids.max() < len(tri)


@pytest.mark.parametrize("cull_option", ["auto", False])
@pytest.mark.parametrize("count", [40, 600])  # below and above CULL_MIN_TRIANGLES
def test_backface_culling_equals_drawing_the_front_faces(ctx, count, cull_option):
    """cull_backfaces=True gives the image of the counter-clockwise triangles alone, with
    ids of the caller's triangles (host pre-cull above the threshold unless cull=False,
    GL_CULL_FACE always)."""
    pos, tri = synthetic.random_soup(count, seed=11)
    win = pos[:, :2] / pos[:, 3:4]
    a, b, c = win[tri[:, 0]], win[tri[:, 1]], win[tri[:, 2]]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    front = np.flatnonzero(area > 0)
    assert 0 < len(front) < count
    culled = gr.rasterize(pos, tri, RES, ctx=ctx, cull_backfaces=True, cull=cull_option)
    host_culled = cull_option == "auto" and count >= CULL_MIN_TRIANGLES
    assert bool(culled.info["culled"].get("backface")) == host_culled
    only_front = gr.rasterize(pos, tri[front], RES, ctx=ctx)
    assert np.array_equal(culled.mask, only_front.mask)
    expected = np.where(only_front.mask, front[np.maximum(only_front.tri_id, 0)], -1)
    assert np.array_equal(culled.tri_id, expected)
    assert np.array_equal(culled.persp, only_front.persp)
    # the context state is restored: the next call draws back faces again
    again = gr.rasterize(pos, tri, RES, ctx=ctx)
    assert again.mask.sum() >= culled.mask.sum()
    assert np.isin(np.setdiff1d(np.arange(count), front), again.tri_id).any()


def test_auto_culling_runs_for_the_host_setup_methods_only(ctx):
    pos, tri = _mixed_scene(seed=4)
    assert gr.rasterize(pos, tri, (16, 16), ctx=ctx, method="homogeneous").info["culled"]
    assert not gr.rasterize(pos, tri, (16, 16), ctx=ctx, method="hw").info["culled"]
    with pytest.raises(ValueError, match="cull must be"):
        gr.rasterize(pos, tri, (16, 16), ctx=ctx, cull="yes")


def test_cull_reports_reasons_and_keeps_indices_sorted():
    pos, tri = _mixed_scene(seed=2)
    c = cull(pos, tri, RES, backfaces=True)
    assert np.all(np.diff(c.kept) > 0)
    assert len(c.kept) == c.keep.sum()
    dropped = len(tri) - len(c.kept)
    assert dropped == sum(c.reasons.values())
    assert c.reasons["backface"] > 0


def test_gl_objects_are_reused_across_calls(ctx):
    """Programs, framebuffers and buffers are cached: repeated calls create nothing new."""
    pos, tri = _mixed_scene(seed=3)
    for method in METHODS:
        gr.rasterize(pos, tri, RES, ctx=ctx, method=method)
    before = ctx.cached_object_count()
    for method in METHODS:
        for _ in range(3):
            gr.rasterize(pos, tri, RES, ctx=ctx, method=method)
    assert ctx.cached_object_count() == before
