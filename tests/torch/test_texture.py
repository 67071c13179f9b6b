"""glraster.torch.texture: gradcheck in float64 through the float64 reference (no OpenGL),
float32 (OpenGL) against float64, layouts, and the ValueErrors.

gradcheck (eps 1e-6, atol 1e-5, rtol 1e-4) perturbs every entry, so its pixels are chosen
where the lookup is smooth: each pixel's texel positions >= 0.02 texels from every texel
boundary at the levels it reads, its level fraction >= 0.02 from 0 and 1 (0.5 for
linear-mipmap-nearest) and inside (0, top), its cube direction's two largest components
>= 2% apart (tests.diff.test_texture_reference.safe), far beyond the 1e-5 texels and
~1e-5 levels a step moves them.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

import glraster.torch as dr
from glraster.diff import texture_args as ta
from tests.diff.test_texture_reference import BOUNDARIES_2D, MODES_2D, make_inputs, safe

ATOL, RTOL, EPS = 1e-5, 1e-4, 1e-6


def smooth_inputs(seed, boundary, mode, count=12, **kwargs):
    """(tex, uv, uv_da, bias) as float64 tensors of ``count`` smooth pixels, (1, 3, 4, .)."""
    tex, uv, da, bias = make_inputs(seed, boundary, batch=1, image=(16, 16), **kwargs)
    args = ta.check(tex, uv, da, bias, filter_mode=mode, boundary_mode=boundary)
    keep = np.nonzero(safe(args, 0.02))[0][:count]
    assert len(keep) == count, "not enough smooth pixels"
    pick = lambda a: a.reshape(256, -1)[keep].reshape((1, 3, 4) + a.shape[3:])
    t = lambda a: torch.tensor(a, dtype=torch.float64, requires_grad=True)
    return t(tex), t(pick(uv)), t(pick(da)), t(pick(bias[..., None])[..., 0])


@pytest.mark.parametrize("boundary", BOUNDARIES_2D)
@pytest.mark.parametrize("mode", MODES_2D)
def test_gradcheck_2d(mode, boundary):
    tex, uv, da, bias = smooth_inputs(40, boundary, mode, tex_size=(6, 8), channels=2)
    fn = lambda *a: dr.texture(*a, filter_mode=mode, boundary_mode=boundary)
    assert torch.autograd.gradcheck(fn, (tex, uv, da, bias), eps=EPS, atol=ATOL, rtol=RTOL)


@pytest.mark.parametrize("mode", ["nearest", "linear", "linear-mipmap-nearest",
                                  "linear-mipmap-linear"])
def test_gradcheck_cube(mode):
    tex, uv, da, bias = smooth_inputs(41, "cube", mode, tex_size=(4, 4), channels=2)
    fn = lambda *a: dr.texture(*a, filter_mode=mode, boundary_mode="cube")
    assert torch.autograd.gradcheck(fn, (tex, uv, da, bias), eps=EPS, atol=ATOL, rtol=RTOL)


def test_gradcheck_user_mip_stack_and_auto_mode():
    tex, uv, da, bias = smooth_inputs(42, "clamp", "linear-mipmap-linear", tex_size=(6, 8),
                                      channels=2)
    rng = np.random.default_rng(43)
    mip = [torch.tensor(rng.normal(size=(1,) + s + (2,)), requires_grad=True)
           for s in ta.level_shapes(6, 8)[1:]]
    fn = lambda t, u, d, b, *m: dr.texture(t, u, d, b, mip=list(m),
                                           boundary_mode="clamp")
    assert torch.autograd.gradcheck(fn, (tex, uv, da, bias, *mip), eps=EPS, atol=ATOL,
                                    rtol=RTOL)


def test_gradient_flows_only_where_the_mode_has_one():
    tex, uv, da, bias = smooth_inputs(44, "wrap", "linear-mipmap-nearest", tex_size=(6, 8))
    out = dr.texture(tex, uv, da, bias, filter_mode="linear-mipmap-nearest")
    out.square().sum().backward()
    assert uv.grad.abs().max() > 0 and tex.grad.abs().max() > 0
    assert da.grad.abs().max() == 0 and bias.grad.abs().max() == 0
    # a broadcast tex (batch 1 over uv's 2) sums its gradient over the batch
    tex1 = torch.rand(1, 4, 4, 3, dtype=torch.float64, requires_grad=True)
    uv2 = torch.rand(2, 3, 3, 2, dtype=torch.float64)
    dr.texture(tex1, uv2).sum().backward()
    assert tex1.grad.shape == tex1.shape
    assert tex1.grad.sum().item() == pytest.approx(2 * 3 * 3 * 3)


def test_float32_runs_on_opengl_and_matches_float64(ctx):
    glctx = dr.RasterizeGLContext(context=ctx)
    for boundary, mode in [("wrap", "linear-mipmap-linear"), ("cube", "linear-mipmap-linear"),
                           ("zero", "linear"), ("clamp", "nearest")]:
        tex, uv, da, bias = smooth_inputs(45, boundary, mode, count=12,
                                          tex_size=(8, 8) if boundary == "cube" else (8, 16))
        results = []
        for dtype in (torch.float64, torch.float32):
            inputs = [x.detach().to(dtype).requires_grad_() for x in (tex, uv, da, bias)]
            out = dr.texture(*inputs, filter_mode=mode, boundary_mode=boundary, glctx=glctx)
            assert out.dtype == dtype and out.shape == (1, 3, 4, tex.shape[-1])
            g = torch.linspace(-1, 1, out.numel(), dtype=dtype).reshape(out.shape)
            out.backward(g)
            results.append([out.detach()] + [x.grad for x in inputs])
        for a, b in zip(*results):
            scale = max(a.abs().max().item(), 1e-30)
            # float32 bound of test_texture_gpu at these sizes, with margin: 1e-5 of the scale
            assert (a - b.double()).abs().max().item() <= 1e-5 * scale


@pytest.mark.parametrize("call, message", [
    (lambda t, u: dr.texture(t.numpy(), u), "tex must be a torch.Tensor"),
    (lambda t, u: dr.texture(t.int(), u), "tex must have dtype"),
    (lambda t, u: dr.texture(t, u.float()), "uv must have the dtype of tex"),
    (lambda t, u: dr.texture(t, u[..., :1]), "uv must have shape (B, H, W, 2)"),
    (lambda t, u: dr.texture(t, u, uv_da=u), "uv_da must have shape (2, 3, 3, 4)"),
    (lambda t, u: dr.texture(t, u, mip_level_bias=u), "mip_level_bias must have shape (2, 3, 3)"),
    (lambda t, u: dr.texture(t, u, mip=t, filter_mode="linear-mipmap-linear"),
     "mip must be None, a TextureMip (texture_construct_mip) or a list"),
    (lambda t, u: dr.texture(t, u, mip=[t], filter_mode="linear-mipmap-linear"),
     "mip[0] (mip level 1) must have shape (1, 2, 2, 3)"),
    (lambda t, u: dr.texture(t, u, filter_mode="bilinear"), "filter_mode must be one of"),
    (lambda t, u: dr.texture(t, u, boundary_mode="cube"), "tex must have shape (B, 6, N, N, C)"),
    (lambda t, u: dr.texture(t, u, max_mip_level=-2), "max_mip_level must be None"),
    (lambda t, u: dr.texture(t, u, glctx="gl"), "glctx must be a RasterizeGLContext"),
    (lambda t, u: dr.texture(t, u * float("nan")), "uv must be finite"),
    # an image of no pixels (NumPy's "cannot reshape array of size 0" before)
    (lambda t, u: dr.texture(t, u[:, :0]), "uv must have B, H and W >= 1"),
    (lambda t, u: dr.texture(t, u[:, :, :0]), "uv must have B, H and W >= 1"),
])
def test_bad_input_raises_value_error_naming_the_argument(call, message):
    tex = torch.zeros(1, 4, 4, 3, dtype=torch.float64)
    uv = torch.zeros(2, 3, 3, 2, dtype=torch.float64)
    with pytest.raises(ValueError) as info:
        call(tex, uv)
    assert message in str(info.value)


def test_a_pyramid_entry_is_forgotten_without_module_globals(monkeypatch):
    """The weak reference that forgets a texture's cached pyramid may fire at interpreter
    exit, once the module's globals are None (it printed "Exception ignored in ...
    AttributeError: 'NoneType' object has no attribute 'get'" at the end of test runs):
    it reaches the cache through its own reference."""
    import gc
    import sys

    module = sys.modules["glraster.torch.texture"]   # (glraster.torch.texture: the op)
    tex = torch.rand(1, 8, 8, 3, dtype=torch.float64)
    uv, uv_da = torch.rand(1, 4, 4, 2, dtype=torch.float64), torch.zeros(1, 4, 4, 4,
                                                                        dtype=torch.float64)
    dr.texture(tex, uv, uv_da, filter_mode="linear-mipmap-linear")
    cache = module._PYRAMIDS
    assert id(tex) in cache
    key, raised = id(tex), []
    monkeypatch.setattr(sys, "unraisablehook", raised.append)
    monkeypatch.setattr(module, "_PYRAMIDS", None)   # as at interpreter exit
    del tex
    gc.collect()
    assert not raised, raised[0].exc_value
    assert key not in cache
