"""Texture and antialias: both cores of each op take the same call, return the same Saved
class and agree; ``needs`` leaves out exactly the gradients not wanted; the float64
references and the shared argument modules import no GL.

The call: the op's check on float32 inputs (the GPU core's arrays), and the same checked
arrays cast to float64 (exactly) for the reference, with the same parameters. Agreement
tolerances are float32 rounding with a wide margin (the per-pixel error bounds of the GPU
against the reference are asserted in test_texture_gpu.py and test_antialias_gpu.py):

- texture, linear-mipmap-linear (continuous in every input): out and every gradient
  within 1e-5 of its largest entry (~170 u; a lookup is ~10 roundings on texel positions
  of ~50 texels, K u T X in test_texture_gpu.py), the gradients on the pixels away from
  the lookup's kinks (``safe``; upstream gradient 0 elsewhere).
- antialias: pixels of pairs whose decisions the reference flags as ambiguous (within
  its float32 error band) get upstream gradient 0 and are not compared; out, grad_color
  and grad_pos within 1e-5 of their largest entry.

Measured on llvmpipe (EGL): 1.2e-6 at most (out, wrap), 1.1e-6 (grad_tex, cube), 2e-7
(grad_pos): the tolerances leave a margin of 8 or more.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from glraster.diff.antialias_args import AntialiasSaved
from glraster.diff.ops import ANTIALIAS, INTERPOLATE, RASTERIZE, TEXTURE
from glraster.diff.texture_args import TextureSaved, level_shapes
from tests.diff.test_antialias_reference import mesh_scene
from tests.diff.test_texture_reference import make_inputs, safe

MODE = "linear-mipmap-linear"


def _cores(op, inputs, params):
    """Run both cores on the same checked call: ((gpu outputs, saved), (ref outputs,
    saved), the float64 inputs)."""
    wide = tuple(None if a is None else a.astype(np.float64) for a in inputs)
    return (op.core(np.float32).forward(*inputs, **params),
            op.core(np.float64).forward(*wide, **params), wide)


def _close(got, want, rel, what):
    scale = max(np.abs(want).max(), 1e-30)
    err = np.abs(np.asarray(got, np.float64) - want).max()
    assert err <= rel * scale, f"{what}: {err:.3e} > {rel} x {scale:.3e}"


# --------------------------------------------------------------------------- texture


def _texture_call(ctx, boundary="wrap", mip=False):
    tex, uv, da, bias = make_inputs(41, boundary, batch=2, image=(12, 14), tex_size=(16, 24))
    levels = ()
    if mip:
        rng = np.random.default_rng(42)
        levels = [rng.normal(size=tex.shape[:1] + s + tex.shape[-1:])
                  for s in level_shapes(*tex.shape[1:3])[1:]]
    f32 = [None if a is None else np.asarray(a, np.float32)
           for a in (tex, uv, da, bias, *levels)]
    return TEXTURE.check(*f32, filter_mode=MODE, boundary_mode=boundary, ctx=ctx)


@pytest.mark.parametrize("boundary", ["wrap", "cube"])
def test_texture_cores_take_the_same_call_and_agree(ctx, boundary):
    inputs, params = _texture_call(ctx, boundary)
    ((out32,), saved32), ((out64,), saved64), _ = _cores(TEXTURE, inputs, params)
    assert type(saved32) is type(saved64) is TextureSaved
    assert out32.dtype == np.float32 and out64.dtype == np.float64
    _close(out32, out64, 1e-5, "out")
    mask = safe(saved64.args, 1e-3)
    assert mask.mean() > 0.5
    g = np.random.default_rng(43).normal(size=out64.shape)
    g.reshape(mask.size, -1)[~mask] = 0.0
    grads32 = TEXTURE.core(np.float32).backward(saved32, g.astype(np.float32))
    grads64 = TEXTURE.core(np.float64).backward(saved64, g)
    assert len(grads32) == len(grads64) == len(inputs)
    for name, a, b, x in zip(TEXTURE.inputs, grads32, grads64, inputs):
        assert a.shape == b.shape == x.shape, name
        assert a.dtype == np.float32 and b.dtype == np.float64, name
        _close(a, b, 1e-5, name)


def test_texture_needs_leaves_out_exactly_the_unwanted_gradients(ctx):
    inputs, params = _texture_call(ctx, mip=True)
    n = len(inputs)
    assert n > 5                              # tex, uv, uv_da, bias and the mip levels
    ((out32,), saved32), ((out64,), saved64), _ = _cores(TEXTURE, inputs, params)
    g = np.random.default_rng(44).normal(size=out64.shape)
    for dtype, saved in ((np.float32, saved32), (np.float64, saved64)):
        core = TEXTURE.core(dtype)
        # deterministic: the GPU's texel sums in a fixed order, comparable bit for bit
        full = core.backward(saved, g.astype(dtype), deterministic=True)
        assert all(x is not None for x in full)
        assert core.backward(saved, g.astype(dtype), needs=(False,) * n) == (None,) * n
        for wanted in ([0], [1], [2, 3], [4], [0, n - 1]):
            needs = tuple(k in wanted for k in range(n))
            part = core.backward(saved, g.astype(dtype), needs=needs, deterministic=True)
            for k in range(n):
                if k in wanted:
                    # the same sums in the same order: identical to the full backward's
                    np.testing.assert_array_equal(part[k], full[k])
                else:
                    assert part[k] is None, (dtype, wanted, k)
    # the driver's accumulation (atomics: sums in any order, so float32 rounding apart)
    core = TEXTURE.core(np.float32)
    full = core.backward(saved32, g.astype(np.float32))
    for wanted in ([0], [n - 1]):
        needs = tuple(k in wanted for k in range(n))
        part = core.backward(saved32, g.astype(np.float32), needs=needs)
        assert all((part[k] is None) == (k not in wanted) for k in range(n))
        for k in wanted:
            _close(part[k], full[k].astype(np.float64), 1e-5, TEXTURE.inputs[min(k, 4)])


# --------------------------------------------------------------------------- antialias


def _antialias_call(ctx):
    res = (48, 64)
    pos, tri, colors = mesh_scene(res, level=2)
    pos = pos.astype(np.float32)
    (rast, _), _ = RASTERIZE.forward(pos, tri=tri, resolution=res, ctx=ctx)
    (col, _), _ = INTERPOLATE.forward(colors.astype(np.float32), rast, tri=tri, ctx=ctx)
    return ANTIALIAS.check(col, rast, pos, tri=tri, ctx=ctx)


def test_antialias_cores_take_the_same_call_and_agree(ctx):
    inputs, params = _antialias_call(ctx)
    ((out32,), saved32), ((out64,), saved64), _ = _cores(ANTIALIAS, inputs, params)
    assert type(saved32) is type(saved64) is AntialiasSaved
    assert len(saved64.pairs.tau) > 50
    clear = ~saved64.pairs.ambiguous
    _close(out32[clear], out64[clear], 1e-5, "out")
    g = np.random.default_rng(45).normal(size=out64.shape)
    g[~clear] = 0.0
    gc32, gr32, gp32 = ANTIALIAS.core(np.float32).backward(saved32, g.astype(np.float32))
    gc64, gr64, gp64 = ANTIALIAS.core(np.float64).backward(saved64, g)
    assert gr32 is None and gr64 is None
    assert gc32.shape == gc64.shape == inputs[0].shape
    assert gp32.shape == gp64.shape == inputs[2].shape
    _close(gc32, gc64, 1e-5, "grad_color")
    _close(gp32, gp64, 1e-5, "grad_pos")


def test_antialias_needs_leaves_out_exactly_the_unwanted_gradients(ctx):
    inputs, params = _antialias_call(ctx)
    ((out32,), saved32), ((out64,), saved64), _ = _cores(ANTIALIAS, inputs, params)
    g = np.random.default_rng(46).normal(size=out64.shape)
    for dtype, saved in ((np.float32, saved32), (np.float64, saved64)):
        core = ANTIALIAS.core(dtype)
        # deterministic: the GPU's position sums in a fixed order, comparable bit for bit
        full = core.backward(saved, g.astype(dtype), deterministic=True)
        assert core.backward(saved, g.astype(dtype), needs=(False, True, False)) == \
            (None, None, None)
        color_only = core.backward(saved, g.astype(dtype), needs=(True, False, False),
                                   deterministic=True)
        pos_only = core.backward(saved, g.astype(dtype), needs=(False, False, True),
                                 deterministic=True)
        assert color_only[2] is None and pos_only[0] is None
        np.testing.assert_array_equal(color_only[0], full[0])
        np.testing.assert_array_equal(pos_only[2], full[2])


# --------------------------------------------------------------------------- no GL


def test_references_and_argument_modules_import_no_gl():
    code = ("import sys\n"
            "import glraster.diff.texture_reference, glraster.diff.antialias_reference\n"
            "import glraster.diff.texture_args, glraster.diff.antialias_args\n"
            "import glraster.diff.topology_hash, glraster.diff.ops\n"
            "gl = [m for m in sys.modules if m.startswith('glraster.gpu') or m == 'moderngl']\n"
            "assert not gl, gl\n")
    subprocess.run([sys.executable, "-c", code], check=True)
