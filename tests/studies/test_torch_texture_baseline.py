"""glraster.studies.torch_texture_baseline (the plain-PyTorch texture that
glraster.torch.texture is timed against) computes the same filters as glraster's float64 texture reference: forward
and gradients, every filter mode and boundary it supports, on power-of-two textures.

The reference is reached through glraster.diff.ops.TEXTURE with float64 inputs (the op
interface, which routes float64 to the reference core).

Bound: |baseline - reference| <= 1e-12 x max(1, max |reference|) per array. Both evaluate the
same sums in float64 in other orders, and the baseline's "wrap" maps a coordinate through
((s mod 1) W + 1) / (W + 2) and back (grid_sample's unnormalization), which costs a few ulps
of the coordinate; gradients to uv carry the texture size (d/du = W d/dx). Measured on
these inputs: at most 2.1e-15 on out, 3.1e-15 on grad tex, 9.2e-14 on grad uv and 4.8e-14
on grad uv_da (entries up to ~30), so the bound leaves over 100x room, while a wrong texel,
weight or level (errors of 1e-3 and up) fails it (test_a_wrong_level_fails_the_bound).
"""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")  # the baseline is part of the [torch] extra

from glraster.diff.ops import TEXTURE  # noqa: E402
from glraster.studies import torch_texture_baseline as baseline  # noqa: E402

MODES = ("nearest", "linear", "linear-mipmap-nearest", "linear-mipmap-linear")
BOUNDARIES = ("wrap", "clamp", "zero")
RELATIVE = 1e-12


def make_inputs(seed, shape=(8, 16), image=(6, 7), batch=2, channels=3):
    """tex (1, H, W, C) in [-1, 1]; uv (B, h, w, 2) in [-0.3, 1.3] (so every boundary is
    crossed); uv_da (B, h, w, 4) giving mip levels from below 0 to past the last one."""
    rng = np.random.default_rng(seed)
    tex = rng.uniform(-1, 1, (1, *shape, channels))
    uv = rng.uniform(-0.3, 1.3, (batch, *image, 2))
    scale = 2.0 ** rng.uniform(-1.5, 4.0, (batch, *image, 1)) / max(shape)
    uv_da = rng.normal(size=(batch, *image, 4)) * scale
    bias = rng.uniform(-1, 1, (batch, *image))
    return tex, uv, uv_da, bias


def both(tex, uv, uv_da, bias, grad_out, **params):
    """(out, grad_tex, grad_uv, grad_uv_da, grad_bias) of the reference and of the baseline;
    a gradient the baseline's graph does not reach (uv_da in linear-mipmap-nearest) is 0."""
    (out, ), saved = TEXTURE.forward(tex, uv, uv_da, bias, **params)
    want = (out, *TEXTURE.core(np.float64).backward(saved, grad_out)[:4])
    leaves = [None if a is None else torch.from_numpy(a).requires_grad_()
              for a in (tex, uv, uv_da, bias)]
    got = baseline.texture(*leaves, **params)
    got.backward(torch.from_numpy(grad_out))
    grads = [None if leaf is None else
             (np.zeros(leaf.shape) if leaf.grad is None else leaf.grad.numpy())
             for leaf in leaves]
    return want, (got.detach().numpy(), *grads)


def assert_close(want, got):
    for name, w, g in zip(("out", "grad tex", "grad uv", "grad uv_da", "grad bias"), want, got):
        if g is None:
            continue
        assert w is not None, name
        assert g.shape == w.shape, (name, g.shape, w.shape)
        err = float(np.abs(g - w).max())
        bound = RELATIVE * max(1.0, float(np.abs(w).max()))
        assert err <= bound, f"{name}: max |baseline - reference| {err:.2e} > {bound:.2e}"


@pytest.mark.parametrize("boundary", BOUNDARIES)
@pytest.mark.parametrize("mode", MODES)
def test_baseline_matches_the_float64_reference(mode, boundary):
    for seed in range(3):
        tex, uv, uv_da, _ = make_inputs(seed)
        uv_da = uv_da if mode.startswith("linear-mipmap") else None
        grad_out = np.random.default_rng(100 + seed).normal(size=uv.shape[:3] + (3,))
        want, got = both(tex, uv, uv_da, None, grad_out, filter_mode=mode,
                         boundary_mode=boundary)
        assert_close(want, got)


@pytest.mark.parametrize("mode", MODES[2:])
def test_baseline_matches_the_reference_with_a_bias_and_fewer_levels(mode):
    """mip_level_bias added to the level, and max_mip_level=2 (a pyramid of 3 levels of the
    4 x 8 levels a 16 x 32 texture has)."""
    tex, uv, uv_da, bias = make_inputs(7, shape=(16, 32), image=(5, 9), batch=1, channels=2)
    grad_out = np.random.default_rng(8).normal(size=uv.shape[:3] + (2,))
    want, got = both(tex, uv, uv_da, bias, grad_out, filter_mode=mode, boundary_mode="wrap",
                     max_mip_level=2)
    assert_close(want, got)


def test_a_wrong_level_fails_the_bound():
    """The bound can fail: the baseline with its level one off (bias +1 on one side only)
    differs from the reference far beyond it."""
    tex, uv, uv_da, bias = make_inputs(9)
    grad_out = np.ones(uv.shape[:3] + (3,))
    want, _ = both(tex, uv, uv_da, np.zeros_like(bias), grad_out,
                   filter_mode="linear-mipmap-linear")
    _, got = both(tex, uv, uv_da, np.ones_like(bias), grad_out,
                  filter_mode="linear-mipmap-linear")
    with pytest.raises(AssertionError, match="out: max"):
        assert_close(want, got)


def test_perspective_inputs_are_the_documented_shapes():
    tex, uv, uv_da = baseline.perspective_inputs(16, channels=2)
    assert tex.shape == (1, 16, 16, 2) and uv.shape == (1, 16, 16, 2)
    assert uv_da.shape == (1, 16, 16, 4) and tex.dtype == uv.dtype == torch.float32


def test_the_core_timing_runs_its_short_form(ctx, capsys):
    # docs/differentiable.md quotes `--cores --sizes 1024` (minutes); this is its 16² round
    assert baseline.main(["--cores", "--sizes", "16", "--repeat", "1",
                          "--modes", "linear", "linear-mipmap-linear"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| 16²")]
    assert [row.split("|")[2].strip() for row in rows] == ["linear", "linear-mipmap-linear"]
    assert all(len(row.split("|")) == 8 for row in rows)
