"""The torch bridge hands every op's core the inputs whose gradient autograd wants
(``needs``, from ``ctx.needs_input_grad``), so the cores skip the rest (their own tests,
tests/diff/test_op_cores.py, check that they do). float64: the reference cores, no GL.
"""

from __future__ import annotations

import importlib

import pytest
import torch

import glraster.torch as dr


@pytest.fixture
def seen(monkeypatch):
    """op name -> the ``needs`` each call of its float64 core's backward received."""
    calls = {}
    for name in ("rasterize", "interpolate", "texture", "antialias"):
        module = importlib.import_module(f"glraster.diff.{name}_reference")
        real = module.backward

        def spy(saved, *grads, needs=None, _real=real, _name=name, **kw):
            calls.setdefault(_name, []).append(needs)
            return _real(saved, *grads, needs=needs, **kw)

        monkeypatch.setattr(module, "backward", spy)
    return calls


def scene(pos_grad: bool):
    pos = torch.tensor([[-0.8, -0.8, 0, 1], [0.8, -0.7, 0, 1.5], [0, 0.8, 0, 1]],
                       dtype=torch.float64, requires_grad=pos_grad)
    tri = torch.tensor([[0, 1, 2]], dtype=torch.int32)
    return pos, tri


@pytest.mark.parametrize("pos_grad, attr_grad", [(True, False), (False, True), (True, True)])
def test_rasterize_interpolate_antialias_get_the_inputs_that_want_gradients(seen, pos_grad,
                                                                           attr_grad):
    pos, tri = scene(pos_grad)
    attr = torch.rand(3, 2, dtype=torch.float64, requires_grad=attr_grad)
    rast, rast_db = dr.rasterize(dr.RasterizeGLContext(), pos, tri, (6, 6))
    out, _ = dr.interpolate(attr, rast, tri)
    dr.antialias(out, rast, pos, tri).sum().backward()
    # antialias: (color, rast, pos); rast wants one when pos does (rasterize's output; the
    # core gives it none), color when anything does
    assert seen["antialias"] == [(True, pos_grad, pos_grad)]
    assert seen["interpolate"] == [(attr_grad, pos_grad, False)]
    assert seen.get("rasterize", []) == ([(True,)] if pos_grad else [])


@pytest.mark.parametrize("wanted", [(True, False, False, False), (False, True, False, False),
                                    (False, False, True, True), (False, True, True, False)])
def test_texture_gets_each_input_that_wants_a_gradient(seen, wanted):
    tex = torch.rand(1, 8, 8, 3, dtype=torch.float64, requires_grad=wanted[0])
    uv = torch.rand(1, 4, 4, 2, dtype=torch.float64, requires_grad=wanted[1])
    uv_da = torch.full((1, 4, 4, 4), 0.05, dtype=torch.float64, requires_grad=wanted[2])
    bias = torch.zeros(1, 4, 4, dtype=torch.float64, requires_grad=wanted[3])
    dr.texture(tex, uv, uv_da, bias, filter_mode="linear-mipmap-linear").sum().backward()
    (needs,) = seen["texture"]
    assert tuple(needs[:4]) == wanted
    # a constant tex takes its cached pyramid as own levels: they want no gradient
    assert not any(needs[4:])
