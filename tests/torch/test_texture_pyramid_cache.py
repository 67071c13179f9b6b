"""glraster.torch.texture with mip=None on a texture that requires no gradient: the pyramid
is built once and reused while the tensor is unchanged, rebuilt after an in-place change
or for another tensor, and the results are bit for bit those of the pyramid built in the
call (a tex that requires grad takes that path: the cache is never used for it).

Bit for bit, no tolerance: the cached levels come from the same box filter the call runs
(glraster.diff.texture.build_mips on OpenGL, the reference's build_mips in float64), so
the lookups and the uv / uv_da gradients see the same numbers in the same order.
"""

from __future__ import annotations

import gc
import importlib

import pytest
import torch

import glraster.torch as dr
from tests.diff.test_texture_reference import make_inputs

torch_texture = importlib.import_module("glraster.torch.texture")  # the module, not the function
MODE = "linear-mipmap-linear"


def inputs(dtype, boundary="wrap", seed=70):
    size = (8, 8) if boundary == "cube" else (16, 12)
    arrays = make_inputs(seed, boundary, batch=1, image=(6, 7), tex_size=size, channels=3)
    return [torch.tensor(a, dtype=dtype) for a in arrays]


def run(glctx, tex, uv, da, bias, boundary):
    """out and the gradients of uv, uv_da, bias (tex's as well when it requires one)."""
    uv, da, bias = (x.detach().requires_grad_() for x in (uv, da, bias))
    out = dr.texture(tex, uv, da, bias, filter_mode=MODE, boundary_mode=boundary,
                     glctx=glctx)
    g = torch.linspace(-1, 1, out.numel(), dtype=out.dtype).reshape(out.shape)
    out.backward(g)
    return [out.detach(), uv.grad, da.grad, bias.grad]


def same(a, b):
    return all(torch.equal(x, y) for x, y in zip(a, b))


@pytest.mark.parametrize("boundary", ["wrap", "clamp", "cube"])
def test_cached_pyramid_gives_the_results_of_the_pyramid_built_in_the_call(ctx, boundary):
    glctx = dr.RasterizeGLContext(context=ctx)
    for dtype in (torch.float32, torch.float64):
        tex, uv, da, bias = inputs(dtype, boundary)
        # tex requiring grad: the pyramid built inside the call (the path before the cache)
        built = run(glctx, tex.clone().requires_grad_(), uv, da, bias, boundary)
        first = run(glctx, tex, uv, da, bias, boundary)     # builds and keeps the pyramid
        second = run(glctx, tex, uv, da, bias, boundary)    # reuses it
        assert same(built, first) and same(first, second), (boundary, dtype)


class Counted(torch_texture.TextureMip):
    """TextureMip counting the pyramids built through it."""

    builds = 0

    def __init__(self, *args):
        type(self).builds += 1
        super().__init__(*args)


def test_pyramid_built_once_per_unchanged_tensor_and_rebuilt_when_it_changes(ctx, monkeypatch):
    monkeypatch.setattr(torch_texture, "TextureMip", Counted)
    glctx = dr.RasterizeGLContext(context=ctx)
    tex, uv, da, bias = inputs(torch.float32)
    cache = Counted
    start = cache.builds
    before = run(glctx, tex, uv, da, bias, "wrap")
    for _ in range(3):
        assert same(run(glctx, tex, uv, da, bias, "wrap"), before)
    assert cache.builds == start + 1
    # a texture that requires grad never goes through the cache
    run(glctx, tex.clone().requires_grad_(), uv, da, bias, "wrap")
    assert cache.builds == start + 1

    tex.mul_(0.5)               # in place: the version counter moves, the pyramid is rebuilt
    changed = run(glctx, tex, uv, da, bias, "wrap")
    assert cache.builds == start + 2
    fresh = run(glctx, tex.clone().requires_grad_(), uv, da, bias, "wrap")
    assert same(changed, fresh) and not torch.equal(changed[0], before[0])

    other = tex.clone()         # another tensor with the same values: its own pyramid
    assert same(run(glctx, other, uv, da, bias, "wrap"), changed)
    assert cache.builds == start + 3


def test_cache_entry_dies_with_its_texture(ctx):
    glctx = dr.RasterizeGLContext(context=ctx)
    tex, uv, da, bias = inputs(torch.float32)
    cache = torch_texture._PYRAMIDS
    run(glctx, tex, uv, da, bias, "wrap")
    key = id(tex)
    assert key in cache
    del tex
    gc.collect()
    assert key not in cache


def test_bad_max_mip_level_still_names_the_argument():
    tex, uv, da, bias = inputs(torch.float64)
    with pytest.raises(ValueError, match="max_mip_level"):
        dr.texture(tex, uv, da, bias, filter_mode=MODE, max_mip_level=[1])
    with pytest.raises(ValueError, match="max_mip_level"):
        dr.texture(tex, uv, da, bias, filter_mode=MODE, max_mip_level=-2)


def test_levels_of_an_unchanged_texture_stay_on_the_gpu(ctx, monkeypatch):
    """A texture requiring grad, unchanged between calls: the second call neither uploads
    it nor builds its pyramid again (its levels are still in the levels buffer, known by
    the bridge's upload keys); after an in-place change they are, and the results are
    bit for bit those of a fresh tensor."""
    texture_core = importlib.import_module("glraster.diff.texture")
    builds = []
    passes = texture_core._pyramid_passes

    def counted(ctx_, buffer, args, firsts, images, backward, top=None):
        builds.append(backward)
        return passes(ctx_, buffer, args, firsts, images, backward, top)

    monkeypatch.setattr(texture_core, "_pyramid_passes", counted)
    glctx = dr.RasterizeGLContext(context=ctx)
    tex, uv, da, bias = inputs(torch.float32)
    tex.requires_grad_()
    first = run(glctx, tex, uv, da, bias, "wrap") + [tex.grad.clone()]
    tex.grad = None
    second = run(glctx, tex, uv, da, bias, "wrap") + [tex.grad.clone()]
    assert same(first, second) and builds.count(False) == 1, builds
    with torch.no_grad():
        tex.mul_(0.5)
    tex.grad = None
    changed = run(glctx, tex, uv, da, bias, "wrap")
    assert builds.count(False) == 2
    fresh = run(glctx, tex.detach().clone().requires_grad_(), uv, da, bias, "wrap")
    assert same(changed, fresh) and not torch.equal(changed[0], first[0])
