"""glraster.jax's ops: float32 (OpenGL) against the float64 reference, against glraster.torch
on the same inputs, float64 gradients against central differences, jit, vmap and the
errors.

Tolerances and why:
- float32 against float64 (FORWARD_TOL 2e-6, GRAD_TOL 2e-5 of the largest magnitude, at
  least 1): the bounds of tests/torch/test_gpu.py, since both front ends call the same
  cores: forward values are a few float32 roundings of O(1) quantities; per-vertex
  gradients are float32 sums over the ~15-60 pixels of a vertex's triangles.
- JAX against torch (SAME_TOL 1e-5 of the largest magnitude, at least 1): both run the
  same GPU core on the same float32 inputs, so forwards are bit for bit equal; backward
  sums are accumulated by GPU atomics in an unspecified order, and a sum of n float32
  terms can differ by about n * 2^-24 of its largest term between two orders (n <= ~100
  pixels per vertex here: 6e-6).
- check_grads (float64, eps 1e-6, atol 1e-5, rtol 1e-4): the gradcheck bounds of
  tests/torch/test_gradcheck.py: coverage is frozen and the scene keeps pixel centres
  >= 0.04 px from every edge, far beyond the ~1e-5 px a step moves a vertex.
"""

from __future__ import annotations

import numpy as np
import pytest

jax = pytest.importorskip("jax")
import jax.numpy as jnp  # noqa: E402
from jax.test_util import check_grads  # noqa: E402

import glraster.jax as dr  # noqa: E402
from glraster.diff.ids import decode_ids  # noqa: E402
from glraster.diff.ops import INTERPOLATE, RASTERIZE  # noqa: E402
from glraster.errors import ArgumentError  # noqa: E402
from tests.diff.test_antialias_reference import soup_scene  # noqa: E402
from tests.torch import scenes  # noqa: E402

FORWARD_TOL = 2e-6
GRAD_TOL = 2e-5
SAME_TOL = 1e-5
ATOL, RTOL, EPS = 1e-5, 1e-4, 1e-6
TRI = scenes.TRI
RES = scenes.RESOLUTION


@pytest.fixture
def glctx(ctx):
    return dr.RasterizeGLContext(context=ctx)


@pytest.fixture
def x64():
    with jax.enable_x64(True):
        yield


def close(name, got, want, tol):
    got, want = np.asarray(got, np.float64), np.asarray(want, np.float64)
    assert got.shape == want.shape, f"{name}: shape {got.shape} != {want.shape}"
    scale = max(1.0, float(np.abs(want).max(initial=0.0)))
    err = float(np.abs(got - want).max(initial=0.0))
    assert err <= tol * scale, f"{name}: max error {err:.3g} > {tol} * {scale:.3g}"


def pipeline(glctx, pos, attr, ranges=None, diff_attrs=(0, 2), seed=0):
    """Outputs of rasterize -> interpolate and the gradients of a fixed random linear loss
    with respect to pos and attr (jax.vjp)."""
    rng = np.random.default_rng(seed)

    def f(p, a):
        rast, rast_db = dr.rasterize(glctx, p, TRI, RES, ranges=ranges)
        out, out_da = dr.interpolate(a, rast, TRI, rast_db, diff_attrs=list(diff_attrs),
                                     glctx=glctx)
        return rast, rast_db, out, out_da

    outputs, vjp = jax.vjp(f, pos, attr)
    cotangents = tuple(jnp.asarray(rng.standard_normal(o.shape), o.dtype) for o in outputs)
    # rast's id and depth channels get no gradient
    cotangents = (cotangents[0].at[..., 2:].set(0),) + cotangents[1:]
    return outputs, vjp(cotangents)


@pytest.mark.parametrize("mode", ["single", "instanced", "ranges"])
def test_float32_matches_the_float64_reference(glctx, x64, mode):
    pos, ranges = scenes.POS, None
    if mode == "instanced":
        pos = np.stack([scenes.POS, scenes.mirrored(scenes.POS)])
    elif mode == "ranges":
        ranges = np.array([[0, 2], [1, 2]], np.int32)
    gpu = pipeline(glctx, jnp.asarray(pos, jnp.float32),
                   jnp.asarray(scenes.COLORS, jnp.float32), ranges)
    cpu = pipeline(glctx, jnp.asarray(pos, jnp.float64),
                   jnp.asarray(scenes.COLORS, jnp.float64), ranges)
    assert gpu[0][0].dtype == jnp.float32 and cpu[0][0].dtype == jnp.float64
    ids = np.asarray(gpu[0][0][..., 3])
    np.testing.assert_array_equal(ids, np.asarray(cpu[0][0][..., 3]).astype(np.float32))
    assert (decode_ids(ids) >= 0).sum() > 50
    close("rast", gpu[0][0][..., :3], cpu[0][0][..., :3], FORWARD_TOL)
    for k, name in enumerate(("rast", "rast_db", "out", "out_da")[1:], start=1):
        close(name, gpu[0][k], cpu[0][k], FORWARD_TOL)
    for k, name in enumerate(("pos", "attr")):
        close(f"grad {name}", gpu[1][k], cpu[1][k], GRAD_TOL)


def test_float64_rasterize_interpolate_gradients_match_central_differences(x64):
    glctx = dr.RasterizeGLContext()    # float64 never opens OpenGL
    rng = np.random.default_rng(1)
    weights = [jnp.asarray(rng.standard_normal(s)) for s in
               [(1, *RES, 4), (1, *RES, 4), (1, *RES, 3), (1, *RES, 4)]]

    def f(p, a):
        rast, rast_db = dr.rasterize(glctx, p, TRI, RES)
        out, out_da = dr.interpolate(a, rast, TRI, rast_db, diff_attrs=[0, 2])
        return (jnp.sum(rast[..., :2] * weights[0][..., :2]) + jnp.sum(rast_db * weights[1])
                + jnp.sum(out * weights[2]) + jnp.sum(out_da * weights[3]))

    check_grads(f, (jnp.asarray(scenes.POS), jnp.asarray(scenes.COLORS)), order=1,
                modes=["rev"], eps=EPS, atol=ATOL, rtol=RTOL)


def test_float64_antialias_gradients_match_central_differences(x64):
    pos, tri, colors = soup_scene((14, 18), count=5, seed=3, layered=True)
    (rast, _), _ = RASTERIZE.forward(np.asarray(pos, np.float64), tri=tri, resolution=(14, 18))
    (col, _), _ = INTERPOLATE.forward(np.asarray(colors, np.float64), rast, tri=tri)
    th = dr.antialias_construct_topology_hash(tri)
    g = jnp.asarray(np.random.default_rng(2).standard_normal(col.shape))

    def f(c, p):
        return jnp.sum(dr.antialias(c, jnp.asarray(rast), p, tri, th) * g)

    grad_pos = jax.grad(f, argnums=1)(jnp.asarray(col), jnp.asarray(pos))
    assert float(jnp.abs(grad_pos).max()) > 0      # visibility gradients reach pos
    check_grads(f, (jnp.asarray(col), jnp.asarray(pos)), order=1, modes=["rev"], eps=EPS,
                atol=ATOL, rtol=RTOL)


def test_float64_texture_gradients_match_central_differences(x64):
    from tests.jax.test_texture import smooth_inputs

    tex, uv, da, bias = smooth_inputs(7, "wrap", "linear-mipmap-linear")

    def f(*args):
        out = dr.texture(*args, filter_mode="linear-mipmap-linear", boundary_mode="wrap")
        return jnp.sum(out * jnp.linspace(-1, 1, out.size).reshape(out.shape))

    check_grads(f, tuple(map(jnp.asarray, (tex, uv, da, bias))), order=1, modes=["rev"],
                eps=EPS, atol=ATOL, rtol=RTOL)


# --------------------------------------------------------------------------- against torch


def test_jax_and_torch_agree_on_the_same_inputs(ctx):
    torch = pytest.importorskip("torch")
    import glraster.torch as tdr

    pos_np = np.stack([scenes.POS, scenes.mirrored(scenes.POS)]).astype(np.float32)
    attr_np = scenes.COLORS.astype(np.float32)
    rng = np.random.default_rng(4)
    g_out = rng.standard_normal((2, *RES, 3)).astype(np.float32)
    g_da = rng.standard_normal((2, *RES, 2)).astype(np.float32)
    th = dr.antialias_construct_topology_hash(TRI)

    jctx = dr.RasterizeGLContext(context=ctx)

    def jax_loss(p, a):
        rast, rast_db = dr.rasterize(jctx, p, TRI, RES)
        out, out_da = dr.interpolate(a, rast, TRI, rast_db, diff_attrs=[1], glctx=jctx)
        out = dr.antialias(out, rast, p, TRI, th, glctx=jctx)
        return jnp.sum(out * g_out) + jnp.sum(out_da * g_da), out

    (_, j_out), (j_pos, j_attr) = jax.value_and_grad(jax_loss, argnums=(0, 1),
                                                     has_aux=True)(pos_np, attr_np)

    tctx = tdr.RasterizeGLContext(context=ctx)
    pos = torch.tensor(pos_np, requires_grad=True)
    attr = torch.tensor(attr_np, requires_grad=True)
    tri = torch.tensor(TRI)
    rast, rast_db = tdr.rasterize(tctx, pos, tri, RES)
    out, out_da = tdr.interpolate(attr, rast, tri, rast_db, diff_attrs=[1], glctx=tctx)
    out = tdr.antialias(out, rast, pos, tri, tdr.antialias_construct_topology_hash(tri),
                        glctx=tctx)
    ((out * torch.tensor(g_out)).sum() + (out_da * torch.tensor(g_da)).sum()).backward()
    np.testing.assert_array_equal(np.asarray(j_out), out.detach().numpy())  # same core
    close("grad pos", j_pos, pos.grad.numpy(), SAME_TOL)
    close("grad attr", j_attr, attr.grad.numpy(), SAME_TOL)
    assert np.abs(np.asarray(j_pos)).max() > 0


# --------------------------------------------------------------------------- jit and vmap


def test_jit_gives_the_eager_values_and_gradients(glctx):
    th = dr.antialias_construct_topology_hash(TRI)

    def loss(p, a):
        rast, _ = dr.rasterize(glctx, p, TRI, RES)
        out, _ = dr.interpolate(a, rast, TRI, glctx=glctx)
        return jnp.sum(dr.antialias(out, rast, p, TRI, th, glctx=glctx) ** 2)

    args = (jnp.asarray(scenes.POS, jnp.float32), jnp.asarray(scenes.COLORS, jnp.float32))
    eager = jax.value_and_grad(loss, argnums=(0, 1))(*args)
    jitted = jax.jit(jax.value_and_grad(loss, argnums=(0, 1)))(*args)
    # the loss's jnp.sum is fused differently by XLA under jit: equal up to float32 sums
    close("jit loss", jitted[0], eager[0], SAME_TOL)
    for a, b in zip(eager[1], jitted[1]):
        close("jit grad", a, b, SAME_TOL)


def test_vmap_over_pos_is_the_instanced_batch(glctx):
    batch = np.stack([scenes.POS, scenes.mirrored(scenes.POS),
                      scenes.POS * np.array([0.9, 1.1, 1, 1])]).astype(np.float32)
    attr = jnp.asarray(scenes.COLORS, jnp.float32)
    th = dr.antialias_construct_topology_hash(TRI)

    def image(p, a):
        rast, rast_db = dr.rasterize(glctx, p, TRI, RES)
        out, out_da = dr.interpolate(a, rast, TRI, rast_db, diff_attrs="all", glctx=glctx)
        return dr.antialias(out, rast, p, TRI, th, glctx=glctx), out_da

    mapped = jax.vmap(image, in_axes=(0, None))(batch, attr)
    instanced = image(batch, attr)
    assert mapped[0].shape == (3, 1, *RES, 3)
    for m, i in zip(mapped, instanced):
        np.testing.assert_array_equal(np.asarray(m)[:, 0], np.asarray(i))

    def loss(p, a):
        out, out_da = image(p, a)
        return jnp.sum(out ** 2) + jnp.sum(out_da)

    per_image = jax.vmap(jax.grad(loss, argnums=(0, 1)), in_axes=(0, None))(batch, attr)
    one_by_one = [jax.grad(loss, argnums=(0, 1))(p, attr) for p in batch]
    for k in range(3):
        close("vmapped grad pos", per_image[0][k], one_by_one[k][0], SAME_TOL)
        close("vmapped grad attr", per_image[1][k], one_by_one[k][1], SAME_TOL)


def test_vmap_over_range_mode_runs_each_entry(glctx):
    ranges = np.array([[0, 2], [1, 2]], np.int32)
    batch = np.stack([scenes.POS, scenes.mirrored(scenes.POS)]).astype(np.float32)
    mapped = jax.vmap(lambda p: dr.rasterize(glctx, p, TRI, RES, ranges=ranges)[0])(batch)
    assert mapped.shape == (2, 2, *RES, 4)
    for k in range(2):
        np.testing.assert_array_equal(np.asarray(mapped[k]),
                                      np.asarray(dr.rasterize(glctx, batch[k], TRI, RES,
                                                              ranges=ranges)[0]))


def test_vmap_of_texture_folds_into_the_batch(glctx):
    rng = np.random.default_rng(5)
    tex = rng.uniform(size=(1, 8, 8, 3)).astype(np.float32)
    uv = rng.uniform(size=(4, 1, 3, 5, 2)).astype(np.float32)
    mapped = jax.vmap(lambda u: dr.texture(tex, u, filter_mode="linear", glctx=glctx))(uv)
    direct = dr.texture(tex, uv[:, 0], filter_mode="linear", glctx=glctx)
    np.testing.assert_array_equal(np.asarray(mapped)[:, 0], np.asarray(direct))
    grad = jax.vmap(jax.grad(lambda t, u: jnp.sum(dr.texture(t, u, filter_mode="linear",
                                                             glctx=glctx))),
                    in_axes=(None, 0))(jnp.asarray(tex), uv)
    each = [jax.grad(lambda t: jnp.sum(dr.texture(t, u, filter_mode="linear",
                                                  glctx=glctx)))(jnp.asarray(tex)) for u in uv]
    assert grad.shape == (4, 1, 8, 8, 3)
    for k in range(4):
        close("vmapped grad tex", grad[k], each[k], SAME_TOL)


# --------------------------------------------------------------------------- peeling


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_depth_peeler_layers_match_torch_and_have_gradients(glctx, dtype):
    torch = pytest.importorskip("torch")
    import glraster.torch as tdr

    with jax.enable_x64(dtype == "float64"):
        pos = jnp.asarray(scenes.POS, dtype)

        def layers(p):
            with dr.DepthPeeler(glctx, p, TRI, RES) as peeler:
                return [peeler.rasterize_next_layer()[0] for _ in range(2)]

        first, second = layers(pos)
        np.testing.assert_array_equal(np.asarray(first),
                                      np.asarray(dr.rasterize(glctx, pos, TRI, RES)[0]))
        grad = jax.grad(lambda p: sum(jnp.sum(r[..., :2]) for r in layers(p)))(pos)
        tctx = tdr.RasterizeGLContext(context=glctx.context)
        tpos = torch.tensor(np.asarray(pos), requires_grad=True)
        with tdr.DepthPeeler(tctx, tpos, torch.tensor(TRI), RES) as peeler:
            t_layers = [peeler.rasterize_next_layer()[0] for _ in range(2)]
        sum(r[..., :2].sum() for r in t_layers).backward()
    np.testing.assert_array_equal(np.asarray(second), t_layers[1].detach().numpy())
    assert (decode_ids(np.asarray(second[..., 3]).astype(np.float32)) >= 0).any()
    close("peeled grad pos", grad, tpos.grad.numpy(), SAME_TOL)


def test_depth_peeler_refuses_rasterize_while_active(glctx):
    with dr.DepthPeeler(glctx, scenes.POS.astype(np.float32), TRI, RES):
        with pytest.raises(RuntimeError, match="DepthPeeler is active"):
            dr.rasterize(glctx, scenes.POS.astype(np.float32), TRI, RES)


# --------------------------------------------------------------------------- errors


@pytest.mark.parametrize("call, argument, message", [
    (lambda c, p: dr.rasterize("gl", p, TRI, RES), "glctx", "glctx must be a"),
    (lambda c, p: dr.rasterize(c, p, TRI, RES, grad_db=1), "grad_db", "grad_db must be"),
    (lambda c, p: dr.rasterize(c, p.astype(jnp.int32), TRI, RES), "pos",
     "pos must be a float32 or float64"),
    # half precision is refused as glraster.torch refuses it, not rounded up in silence
    (lambda c, p: dr.rasterize(c, p.astype(jnp.float16), TRI, RES), "pos",
     "pos must be a float32 or float64 array, got float16"),
    (lambda c, p: dr.interpolate(jnp.ones((3, 2), jnp.bfloat16), p, TRI), "attr",
     "attr must be a float32 or float64 array, got bfloat16"),
    (lambda c, p: dr.interpolate(np.ones((7, 1), np.float32), p, TRI, p, diff_attrs="all"),
     "rast_db", "rast_db is empty"),
    (lambda c, p: dr.RasterizeGLContext(device="cuda"), "device", "device must be None"),
    (lambda c, p: dr.texture_construct_mip(np.ones((1, 4, 4, 1), np.float32), cube_mode=2),
     "cube_mode", "cube_mode must be"),
])
def test_bad_input_raises_argument_error(call, argument, message):
    glctx = dr.RasterizeGLContext()
    pos = jnp.asarray(scenes.POS, jnp.float32)
    if argument == "rast_db":
        pos = jnp.zeros((1, *RES, 0), jnp.float32)
    with pytest.raises(ArgumentError, match=message) as info:
        call(glctx, pos)
    assert info.value.argument == argument


@pytest.mark.parametrize("jit", [False, True])
def test_shape_errors_come_from_op_check_eagerly_and_under_jit(jit):
    glctx = dr.RasterizeGLContext()
    f = lambda p: dr.rasterize(glctx, p, TRI, RES)[0]   # noqa: E731
    with pytest.raises(ValueError, match=r"pos must have shape \(V, 4\)"):
        (jax.jit(f) if jit else f)(jnp.zeros((7, 3), jnp.float32))


def test_a_traced_tri_resolution_or_parameter_is_refused_with_a_clear_error():
    glctx = dr.RasterizeGLContext()
    pos = jnp.asarray(scenes.POS, jnp.float32)
    with pytest.raises(ArgumentError, match="tri must be concrete") as info:
        jax.jit(lambda p, t: dr.rasterize(glctx, p, t, RES)[0])(pos, jnp.asarray(TRI))
    assert info.value.argument == "tri"
    # (a traced height used to read "resolution height must be an integer, got JitTracer")
    with pytest.raises(ArgumentError, match="resolution must be concrete") as info:
        jax.jit(lambda p, r: dr.rasterize(glctx, p, TRI, r)[0])(pos, RES)
    assert info.value.argument == "resolution"
    tex, uv = jnp.ones((1, 8, 8, 3)), jnp.zeros((1, 4, 4, 2))   # every static parameter
    with pytest.raises(ArgumentError, match="max_mip_level must be concrete") as info:
        jax.jit(lambda t, m: dr.texture(t, uv, mip_level_bias=jnp.zeros((1, 4, 4)),
                                        max_mip_level=m))(tex, 2)
    assert info.value.argument == "max_mip_level"


def test_non_finite_values_under_jit_are_reported_from_the_callback(x64):
    glctx = dr.RasterizeGLContext()
    pos = jnp.asarray(scenes.POS).at[2, 0].set(jnp.nan)
    with pytest.raises(Exception, match="pos must be finite"):
        jax.block_until_ready(jax.jit(lambda p: dr.rasterize(glctx, p, TRI, RES)[0])(pos))
    with pytest.raises(ValueError, match="pos must be finite"):
        dr.rasterize(glctx, pos, TRI, RES)


def test_a_dropped_context_is_not_kept_alive_by_the_call_cache(gl_backend):
    """The jitted calls are cached per context (glraster.jax.bridge._CACHE) under a token,
    not the context: a RasterizeGLContext made per call and dropped is collected (and its
    OpenGL context with it, when the next one is made), and its cached calls go too. Over
    100 such calls RSS grew by 6.8 MB each before, 1.5 MB after (JAX's own compile caches:
    flat with jax.clear_caches())."""
    import gc
    import weakref

    from glraster.jax import bridge

    pos = jnp.asarray(scenes.POS[None], jnp.float32)
    glctx = dr.RasterizeGLContext(backend=gl_backend)
    rast, _ = dr.rasterize(glctx, pos, TRI, RES)
    rast.block_until_ready()
    token = bridge._CONTEXT_TOKENS[glctx]
    assert any(("ctx", token) in key[-1] for key in bridge._CACHE)
    dropped, inner = weakref.ref(glctx), weakref.ref(glctx.context)
    del glctx, rast
    gc.collect()
    assert dropped() is None and inner() is None
    assert not any(("ctx", token) in key[-1] for key in bridge._CACHE)


def test_gradients_are_reverse_mode_only(glctx):
    """docs/jax.md: jacrev works, forward mode stops with JAX's custom_vjp error."""
    pos = jnp.asarray(scenes.POS, jnp.float32)
    f = lambda p: jnp.sum(dr.rasterize(glctx, p, TRI, RES)[0][..., :2], axis=(1, 2))  # noqa: E731
    jacobian = jax.jacrev(f)(pos)
    assert jacobian.shape == (1, 2) + pos.shape and bool(jnp.any(jacobian != 0))
    with pytest.raises(TypeError, match="can't apply forward-mode autodiff"):
        jax.jvp(f, (pos,), (jnp.ones_like(pos),))
