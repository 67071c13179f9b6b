"""glraster.torch under ``torch.inference_mode()`` (an evaluation loop's usual setting):
inference tensors have no version counter, so nothing keyed on one is reused (uploads,
remembered calls, mip pyramids); every result is bit for bit that of the same calls
outside inference mode, an in-place change of an inference tensor included."""

from __future__ import annotations

import pytest
import torch

import glraster.torch as dr
from glraster.diff import memo


@pytest.fixture
def glctx(ctx):
    memo.forget()
    yield dr.RasterizeGLContext(context=ctx)
    memo.forget()


def _scene():
    """(pos (1, 64, 4), tri (40, 3), colour (1, 64, 3), uv (1, 64, 2), tex (1, 64, 64, 3))
    of a random triangle soup (large enough that its uploads are keyed)."""
    g = torch.Generator().manual_seed(0)
    pos = torch.rand(1, 64, 4, generator=g) * 1.6 - 0.8
    pos[..., 2], pos[..., 3] = 0.5, 1.0
    tri = torch.randint(0, 64, (40, 3), generator=g, dtype=torch.int32)
    return (pos, tri, torch.rand(1, 64, 3, generator=g), torch.rand(1, 64, 2, generator=g),
            torch.rand(1, 64, 64, 3, generator=g))


def _render(glctx, pos, tri, colour, uv_attr, tex):
    """rasterize -> interpolate (with derivatives) -> mipmapped texture -> antialias."""
    rast, rast_db = dr.rasterize(glctx, pos, tri, (64, 64))
    c, _ = dr.interpolate(colour, rast, tri)
    uv, uv_da = dr.interpolate(uv_attr, rast, tri, rast_db=rast_db, diff_attrs="all")
    t = dr.texture(tex, uv, uv_da, filter_mode="linear-mipmap-linear")
    return dr.antialias(c * t, rast, pos, tri)


def test_inference_mode_renders_bit_for_bit_as_outside_it(glctx):
    scene = _scene()
    expected = _render(glctx, *scene)
    with torch.inference_mode():
        first, again = _render(glctx, *scene), _render(glctx, *scene)
        inference_scene = [t.clone() for t in scene]      # inference tensors themselves
        from_inference = _render(glctx, *inference_scene)
    assert torch.equal(first, expected) and torch.equal(again, expected)
    assert torch.equal(from_inference, expected)


def test_an_inference_tensor_changed_in_place_is_seen(glctx):
    scene = _scene()
    with torch.inference_mode():
        pos, tri, colour, uv_attr, tex = [t.clone() for t in scene]
        before = _render(glctx, pos, tri, colour, uv_attr, tex)
        tex.mul_(0.5)                  # no version counter tells of these changes
        pos[..., :2] *= 0.9
        after = _render(glctx, pos, tri, colour, uv_attr, tex)
    changed = [t.clone() for t in scene]
    changed[4] *= 0.5
    changed[0][..., :2] *= 0.9
    assert torch.equal(before, _render(glctx, *scene))
    assert torch.equal(after, _render(glctx, *changed))
