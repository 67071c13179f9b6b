"""glraster.torch inside ``torch.compile``d code: its ops are graph breaks
(``bridge.eager``), run as written, so a compiled render gives the same image and
gradients as the plain one. Backends "eager" and "aot_eager" run TorchDynamo's tracing
(with fake tensors, where glraster's ops used to fail) and AOTAutograd without a C++
compiler."""

from __future__ import annotations

import pytest
import torch

import glraster.torch as dr


@pytest.fixture
def glctx(ctx):
    return dr.RasterizeGLContext(context=ctx)


def _inputs():
    g = torch.Generator().manual_seed(1)
    pos = torch.rand(1, 32, 4, generator=g) * 1.6 - 0.8
    pos[..., 2], pos[..., 3] = 0.5, 1.0
    tri = torch.randint(0, 32, (20, 3), generator=g, dtype=torch.int32)
    return (pos.requires_grad_(), tri, torch.rand(1, 32, 3, generator=g).requires_grad_(),
            torch.rand(1, 16, 16, 3, generator=g).requires_grad_())


@pytest.mark.parametrize("backend", ["eager", "aot_eager"])
def test_a_compiled_render_matches_the_plain_one(glctx, backend):
    pos, tri, col, tex = _inputs()

    def loss(pos, col, tex):
        rast, rast_db = dr.rasterize(glctx, pos, tri, (32, 32))
        c, _ = dr.interpolate(col, rast, tri)
        uv, uv_da = dr.interpolate(col[..., :2], rast, tri, rast_db=rast_db, diff_attrs="all")
        t = dr.texture(tex, uv, uv_da, filter_mode="linear-mipmap-linear")
        return (dr.antialias(c * t, rast, pos, tri) ** 2).mean()

    torch._dynamo.reset()
    expected = loss(pos, col, tex)
    expected_grads = torch.autograd.grad(expected, [pos, col, tex])
    compiled = torch.compile(loss, backend=backend)
    value = compiled(pos, col, tex)
    grads = torch.autograd.grad(value, [pos, col, tex])
    assert torch.equal(value, expected)            # forwards are deterministic
    for got, want in zip(grads, expected_grads):
        # float atomics sum a texel's or vertex's terms in a run-dependent order: a few
        # ulps apart between any two runs, compiled or not
        torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-8)
