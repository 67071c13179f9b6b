"""glraster.jax.texture and texture_construct_mip: float32 (OpenGL) against float64 and
against glraster.torch, a built pyramid reused and rebuilt, and the errors.

Pixels are chosen where the lookup is smooth (tests.diff.test_texture_reference.safe):
texel positions >= 0.02 texels from every texel boundary, level fractions away from 0
and 1, so central differences and both precisions see the same taps. Tolerances:
float32 against float64 1e-5 of the largest magnitude (test_texture_gpu's float32 bound at
these sizes, with margin); JAX against torch: the same core on the same inputs, outputs
bit for bit, gradients 1e-5 (atomic sums in any order, as tests/jax/test_ops.py says).
"""

from __future__ import annotations

import logging

import numpy as np
import pytest

jax = pytest.importorskip("jax")
import jax.numpy as jnp  # noqa: E402

import glraster.jax as dr  # noqa: E402
from glraster.diff import texture_args  # noqa: E402
from glraster.diff import texture_reference as tr  # noqa: E402
from glraster.errors import ArgumentError  # noqa: E402
from tests.diff.test_texture_reference import make_inputs, safe  # noqa: E402

TOL = 1e-5


def smooth_inputs(seed, boundary, mode, count=12, **kwargs):
    """(tex, uv, uv_da, bias) float64 NumPy arrays of ``count`` smooth pixels, (1, 3, 4, .)."""
    tex, uv, da, bias = make_inputs(seed, boundary, batch=1, image=(16, 16), **kwargs)
    args = texture_args.check(tex, uv, da, bias, filter_mode=mode, boundary_mode=boundary)
    keep = np.nonzero(safe(args, 0.02))[0][:count]
    assert len(keep) == count, "not enough smooth pixels"
    pick = lambda a: a.reshape(256, -1)[keep].reshape((1, 3, 4) + a.shape[3:])  # noqa: E731
    return tex, pick(uv), pick(da), pick(bias[..., None])[..., 0]


def _grads(dtype, inputs, glctx, **kwargs):
    with jax.enable_x64(dtype == "float64"):
        arrays = [jnp.asarray(x, dtype) for x in inputs]

        def f(*args):
            out = dr.texture(*args, glctx=glctx, **kwargs)
            return jnp.sum(out * jnp.linspace(-1, 1, out.size, dtype=out.dtype)
                           .reshape(out.shape)), out

        (_, out), grads = jax.value_and_grad(f, argnums=tuple(range(len(arrays))),
                                             has_aux=True)(*arrays)
        assert out.dtype == dtype
        return [np.asarray(out, np.float64)] + [np.asarray(g, np.float64) for g in grads]


@pytest.mark.parametrize("boundary, mode", [("wrap", "linear-mipmap-linear"),
                                            ("cube", "linear-mipmap-linear"),
                                            ("zero", "linear"), ("clamp", "nearest")])
def test_float32_on_opengl_matches_float64(ctx, boundary, mode):
    glctx = dr.RasterizeGLContext(context=ctx)
    inputs = smooth_inputs(45, boundary, mode, tex_size=(8, 8) if boundary == "cube"
                           else (8, 16))
    kwargs = dict(filter_mode=mode, boundary_mode=boundary)
    for a, b in zip(_grads("float64", inputs, glctx, **kwargs),
                    _grads("float32", inputs, glctx, **kwargs)):
        assert np.abs(a - b).max() <= TOL * max(np.abs(a).max(), 1e-30)


def test_jax_and_torch_texture_agree(ctx):
    torch = pytest.importorskip("torch")
    import glraster.torch as tdr

    inputs = [np.asarray(x, np.float32) for x in
              smooth_inputs(3, "wrap", "linear-mipmap-linear", tex_size=(8, 16))]
    kwargs = dict(filter_mode="linear-mipmap-linear", boundary_mode="wrap")
    j = _grads("float32", inputs, dr.RasterizeGLContext(context=ctx), **kwargs)
    tensors = [torch.tensor(x, requires_grad=True) for x in inputs]
    out = tdr.texture(*tensors, glctx=tdr.RasterizeGLContext(context=ctx), **kwargs)
    out.backward(torch.linspace(-1, 1, out.numel()).reshape(out.shape))
    np.testing.assert_array_equal(j[0], out.detach().double().numpy())
    for got, t in zip(j[1:], tensors):
        want = t.grad.double().numpy()
        assert np.abs(got - want).max() <= TOL * max(np.abs(want).max(), 1.0)


def test_a_built_mip_is_reused_and_gives_the_same_output_and_gradients(x64, monkeypatch):
    tex, uv, da, bias = (jnp.asarray(x) for x in smooth_inputs(11, "wrap",
                                                               "linear-mipmap-linear"))
    mip = dr.texture_construct_mip(tex)
    expected = tr.build_mips(np.asarray(tex), tr.level_shapes(*tex.shape[1:3]))
    assert len(mip.levels) == len(expected)
    for got, want in zip(mip.levels, expected):
        np.testing.assert_array_equal(np.asarray(got), want)
    builds = []
    original = tr.build_mips
    monkeypatch.setattr(tr, "build_mips", lambda *a: builds.append(1) or original(*a))

    def f(t, u, mip):
        out = dr.texture(t, u, da, bias, mip=mip, filter_mode="linear-mipmap-linear")
        return jnp.sum(out ** 2)

    with_mip = jax.value_and_grad(f, argnums=1)(tex, uv, mip)
    assert not builds          # tex unchanged and concrete: the built levels are used
    without = jax.value_and_grad(f, argnums=1)(tex, uv, None)
    assert builds              # without mip the core builds the pyramid
    np.testing.assert_allclose(with_mip[0], without[0], rtol=1e-14)
    np.testing.assert_allclose(with_mip[1], without[1], rtol=1e-12, atol=1e-14)
    # tex's gradient through the built pyramid is tex's own (traced tex builds its own)
    g_mip = jax.grad(f)(tex, uv, mip)
    g_none = jax.grad(f)(tex, uv, None)
    np.testing.assert_allclose(g_mip, g_none, rtol=1e-12, atol=1e-14)


def test_a_changed_texture_rebuilds_the_mip_with_a_warning(x64, caplog):
    tex, uv, da, bias = (jnp.asarray(x) for x in smooth_inputs(12, "wrap",
                                                               "linear-mipmap-linear"))
    mip = dr.texture_construct_mip(tex)
    other = tex * 2.0
    with caplog.at_level(logging.WARNING, logger="glraster"):
        out = dr.texture(other, uv, da, bias, mip=mip)
    assert "rebuilding" in caplog.text
    np.testing.assert_allclose(out, dr.texture(other, uv, da, bias), rtol=1e-14)
    np.testing.assert_array_equal(np.asarray(mip.levels[0]),
                                  tr.build_mips(np.asarray(other),
                                                tr.level_shapes(*tex.shape[1:3]))[0])


def _float64_mip():
    """A 2-D pyramid built by the float64 reference (no OpenGL)."""
    with jax.enable_x64(True):
        return dr.texture_construct_mip(np.ones((1, 4, 4, 3)))


@pytest.mark.parametrize("call, argument, message", [
    (lambda t, u: dr.texture(t, u, mip=t), "mip", "mip must be None, a TextureMip"),
    (lambda t, u: dr.texture(t, u, mip=_float64_mip(), boundary_mode="cube"), "mip",
     "cube_mode=False"),
    (lambda t, u: dr.texture(t, u, glctx="gl"), "glctx", "glctx must be a"),
    (lambda t, u: dr.texture_construct_mip(t, max_mip_level=-1), "max_mip_level",
     "max_mip_level must be None"),
    (lambda t, u: dr.texture(t.astype(jnp.int32), u), "tex", "tex must be a float32"),
])
def test_bad_input_raises_argument_error(call, argument, message):
    tex = jnp.ones((1, 4, 4, 3), jnp.float32)
    uv = jnp.full((1, 2, 2, 2), 0.3, jnp.float32)
    with pytest.raises(ArgumentError, match=message) as info:
        call(tex, uv)
    assert info.value.argument == argument


@pytest.mark.parametrize("call, message", [
    (lambda t, u: dr.texture(t, u[..., :1]), r"uv must have shape \(B, H, W, 2\)"),
    (lambda t, u: dr.texture(t, u, filter_mode="bilinear"), "filter_mode must be one of"),
    (lambda t, u: dr.texture(t, u * jnp.nan), "uv must be finite"),
])
def test_bad_shapes_and_values_raise_value_error_from_op_check(call, message):
    tex = jnp.ones((1, 4, 4, 3), jnp.float32)
    uv = jnp.full((1, 2, 2, 2), 0.3, jnp.float32)
    with pytest.raises(ValueError, match=message):
        call(tex, uv)


@pytest.fixture
def x64():
    with jax.enable_x64(True):
        yield
