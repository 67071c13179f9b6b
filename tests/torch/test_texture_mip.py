"""glraster.torch.texture_construct_mip and texture(..., mip=TextureMip): the pyramid built
once, reused while its texture is unchanged and rebuilt (with a warning) when it changed,
and tex's gradient through it against central differences of the float64 reference.

The output is linear in tex, so the central differences of the reference (pyramid built
from the perturbed texture) use a step of 1 and agree with the analytic gradient to
rounding: relative 1e-9 of the largest entry (sums of ~100 float64 products of O(1)).
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
import torch

import glraster.torch as dr
from glraster.diff import texture_args as ta
from glraster.diff import texture_reference as tr
from tests.diff.test_texture_reference import make_inputs

MODE = "linear-mipmap-linear"


def tensors(seed, boundary="wrap", **kwargs):
    tex, uv, da, bias = make_inputs(seed, boundary, batch=1, image=(4, 5), **kwargs)
    t = lambda a: torch.tensor(a, dtype=torch.float64, requires_grad=True)
    return t(tex), t(uv), t(da), t(bias)


def grads(out, grad_out, *inputs):
    return torch.autograd.grad(out, inputs, grad_out)


@pytest.mark.parametrize("boundary", ["wrap", "clamp", "cube"])
def test_texture_gradient_through_a_built_mip_matches_central_differences(boundary):
    size = (4, 4) if boundary == "cube" else (6, 9)
    tex, uv, da, bias = tensors(60, boundary, tex_size=size, channels=2)
    mip = dr.texture_construct_mip(tex, cube_mode=boundary == "cube")
    out = dr.texture(tex, uv, da, bias, mip=mip, filter_mode=MODE, boundary_mode=boundary)
    grad_out = torch.tensor(np.random.default_rng(61).normal(size=out.shape))
    (grad_tex,) = grads(out, grad_out, tex)

    base = tex.detach().numpy()
    g = grad_out.numpy()
    loss = lambda t: np.sum(g * tr.forward(t, uv.detach().numpy(), da.detach().numpy(),
                                           bias.detach().numpy(), filter_mode=MODE,
                                           boundary_mode=boundary)[0][0])
    numeric = np.zeros_like(base)
    for index in np.ndindex(base.shape):
        step = np.zeros_like(base)
        step[index] = 1.0
        numeric[index] = (loss(base + step) - loss(base - step)) / 2
    assert np.abs(numeric).max() > 0.1
    assert np.abs(grad_tex.numpy() - numeric).max() <= 1e-9 * np.abs(numeric).max()


def test_a_built_mip_gives_the_same_output_and_gradients_as_none():
    # float64: texture_construct_mip runs the same box filter as texture, so bit for bit
    tex, uv, da, bias = tensors(62, tex_size=(7, 10), channels=3)
    mip = dr.texture_construct_mip(tex)
    with_mip = dr.texture(tex, uv, da, bias, mip=mip)
    without = dr.texture(tex, uv, da, bias)
    grad_out = torch.rand_like(without)
    assert torch.equal(with_mip, without)
    for a, b in zip(grads(with_mip, grad_out, tex, uv, da, bias),
                    grads(without, grad_out, tex, uv, da, bias)):
        assert torch.equal(a, b)
    assert all(not level.requires_grad for level in mip.levels)


def test_max_mip_level_of_the_mip_limits_the_levels_used():
    tex, uv, da, bias = tensors(63, tex_size=(8, 8), channels=1)
    mip = dr.texture_construct_mip(tex, max_mip_level=1)
    assert [tuple(m.shape) for m in mip.levels] == [(1, 4, 4, 1)]
    assert torch.equal(dr.texture(tex, uv, da, bias, mip=mip),
                       dr.texture(tex, uv, da, bias, max_mip_level=1))
    # and texture's own max_mip_level still applies below it
    mip = dr.texture_construct_mip(tex)
    assert torch.equal(dr.texture(tex, uv, da, bias, mip=mip, max_mip_level=2),
                       dr.texture(tex, uv, da, bias, max_mip_level=2))


def test_the_levels_are_the_reference_pyramid():
    tex = torch.rand(2, 6, 5, 5, 3, dtype=torch.float64)
    mip = dr.texture_construct_mip(tex, cube_mode=True)
    expected = tr.build_mips(tex.numpy(), ta.level_shapes(5, 5))
    assert [tuple(m.shape) for m in mip.levels] == [(2, 6, 2, 2, 3), (2, 6, 1, 1, 3)]
    for level, want in zip(mip.levels, expected):
        np.testing.assert_array_equal(level.numpy(), want)


def test_the_pyramid_is_built_once_and_rebuilt_after_the_texture_changes(monkeypatch, caplog):
    builds = []
    real = tr.build_mips
    monkeypatch.setattr(tr, "build_mips", lambda *a: builds.append(1) or real(*a))
    tex, uv, da, bias = tensors(64, tex_size=(8, 6), channels=2)
    mip = dr.texture_construct_mip(tex.detach())   # a view of the same memory counts
    levels = mip.levels
    assert len(builds) == 1
    with caplog.at_level(logging.WARNING, logger="glraster"):
        for _ in range(3):
            dr.texture(tex, uv, da, bias, mip=mip).sum().backward()
        assert len(builds) == 1 and mip.levels is levels and not caplog.records
        dr.texture(tex, uv, da, bias)                   # without mip: built in the call
        assert len(builds) == 2

        with torch.no_grad():
            tex.mul_(0.5)                               # an optimizer step, say
        out = dr.texture(tex, uv, da, bias, mip=mip)
        assert len(builds) == 3                         # the rebuild, which the lookup uses
    assert torch.equal(out, dr.texture(tex, uv, da, bias))
    assert mip.levels is not levels
    assert [r.levelname for r in caplog.records] == ["WARNING"]
    assert "rebuilding" in caplog.records[0].getMessage()
    builds.clear()
    dr.texture(tex, uv, da, bias, mip=mip)              # reused again after the rebuild
    assert builds == []

    other = tex.detach().clone()                        # equal values, another tensor
    dr.texture(other, uv, da, bias, mip=mip)
    assert builds == [1]


def test_modes_without_mipmaps_ignore_the_mip(monkeypatch):
    tex, uv, _, _ = tensors(65, tex_size=(4, 4), channels=1)
    mip = dr.texture_construct_mip(tex)
    with torch.no_grad():
        tex.add_(1.0)
    monkeypatch.setattr(tr, "build_mips", lambda *a: pytest.fail("rebuilt for 'linear'"))
    assert torch.equal(dr.texture(tex, uv, mip=mip, filter_mode="linear"),
                       dr.texture(tex, uv, filter_mode="linear"))


def test_float32_mip_on_opengl_matches_no_mip_bit_for_bit(ctx):
    glctx = dr.RasterizeGLContext(context=ctx)
    for boundary, size in [("wrap", (9, 12)), ("cube", (6, 6))]:
        tex, uv, da, bias = (t.detach().float().requires_grad_()
                             for t in tensors(66, boundary, tex_size=size, channels=3))
        mip = dr.texture_construct_mip(tex, cube_mode=boundary == "cube", glctx=glctx)
        ref_levels = tr.build_mips(tex.detach().numpy().astype(np.float64),
                                   ta.level_shapes(*size))
        for level, want in zip(mip.levels, ref_levels):   # float32 box filter vs float64
            assert level.dtype == torch.float32
            np.testing.assert_allclose(level.numpy(), want, rtol=0, atol=1e-6)
        kw = dict(filter_mode=MODE, boundary_mode=boundary, glctx=glctx)
        with_mip = dr.texture(tex, uv, da, bias, mip=mip, **kw)
        without = dr.texture(tex, uv, da, bias, **kw)
        assert torch.equal(with_mip, without)     # the same levels uploaded as built
        grad_out = torch.rand_like(without)
        (a,) = grads(with_mip, grad_out, tex)
        (b,) = grads(without, grad_out, tex)
        # the same per-texel sums pulled back by the same pass; atomics may reorder them
        torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("call, message", [
    (lambda t: dr.texture_construct_mip(t.numpy()), "tex must be a torch.Tensor"),
    (lambda t: dr.texture_construct_mip(t, max_mip_level=-1), "max_mip_level must be"),
    (lambda t: dr.texture_construct_mip(t, max_mip_level=1.5), "max_mip_level must be"),
    (lambda t: dr.texture_construct_mip(t, max_mip_level=True), "max_mip_level must be"),
    (lambda t: dr.texture_construct_mip(t, cube_mode=1), "cube_mode must be True or False"),
    (lambda t: dr.texture_construct_mip(t, cube_mode=True), "tex must have shape"),
    (lambda t: dr.texture_construct_mip(t, glctx="gl"), "glctx must be"),
    (lambda t: dr.texture_construct_mip(t.int()), "tex must have dtype"),
    (lambda t: dr.texture_construct_mip(t * np.nan), "tex must be finite"),
    (lambda t: dr.texture(t, torch.rand(1, 2, 2, 3, dtype=t.dtype),
                          mip_level_bias=torch.zeros(1, 2, 2, dtype=t.dtype),
                          mip=dr.texture_construct_mip(t), boundary_mode="cube"),
     "mip was built with cube_mode=False"),
    (lambda t: dr.texture(t.float(), torch.rand(1, 2, 2, 2),
                          mip=dr.texture_construct_mip(t)),
     "mip was built from a torch.float64 texture"),
    (lambda t: dr.texture(t, torch.rand(1, 2, 2, 2, dtype=t.dtype), mip=object()),
     "mip must be None, a TextureMip"),
])
def test_bad_input_raises_value_error_naming_the_argument(call, message):
    with pytest.raises(ValueError, match=message):
        call(torch.rand(1, 4, 4, 2, dtype=torch.float64))


def test_the_reuse_benchmark_runs_its_short_form(ctx, capsys):
    # docs/differentiable.md quotes the long form (minutes); this is its 16² single round
    from glraster.studies import texture_mip_reuse

    assert texture_mip_reuse.main(["--sizes", "16", "--rounds", "1", "--calls", "1"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| 16²")]
    assert len(rows) == 2 and all(len(row.split("|")) == 8 for row in rows)
